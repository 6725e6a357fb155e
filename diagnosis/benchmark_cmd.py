"""``webline diagnose-bench [--cases N] [--seed S] [--out DIR] [--quick]``.

Draws N cases with hidden effects on a line derived from the EWL layout,
co-simulates the "measured" data, runs ``webline diagnose`` blind on each (a
subprocess that sees only the nominal layout and the run files), scores the
reports against ``truth.json`` and writes ``diagnosis_results.json`` and
``diagnosis_results.md`` (a Markdown table, also printed). See
:mod:`diagnosis.benchmark` for the generator and the scorer.

Run time: every case costs one truth simulation per run plus the diagnosis
(7-20 co-simulations of 8-10 s of line); the default 24 cases take about
20-30 min on a 2-core machine with ``--jobs 2``. ``--quick``: 3 cases of one
4 s run (a smoke test, a few minutes).

Exit codes: 0 done (whatever the scores), 1 no case could be diagnosed,
2 bad arguments.
"""
import argparse
import json
import multiprocessing as mp
import os
import sys
import time
from pathlib import Path

DEFAULT_CASES = 24


def parser():
    ap = argparse.ArgumentParser(prog="webline diagnose-bench",
                                 description="Benchmark webline diagnose on lines with hidden effects.")
    ap.add_argument("--cases", type=int, default=None, help=f"number of cases (default {DEFAULT_CASES}; quick: 3)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the case draw (default 0)")
    ap.add_argument("--out", type=Path, default=Path("out/diagnose-bench"),
                    help="work folder: cases/<id>/{blind,truth,diagnosis} (default out/diagnose-bench)")
    ap.add_argument("--results", type=Path, default=None,
                    help="results JSON (default OUT/diagnosis_results.json); the .md is written beside it")
    ap.add_argument("--quick", action="store_true", help="3 short single-run cases (smoke test)")
    ap.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1), help="cases in parallel (default 2)")
    ap.add_argument("--timeout", type=float, default=1800.0, help="seconds per diagnosis (default 1800)")
    ap.add_argument("--only", nargs="+", default=None, metavar="ID", help="run only these case ids (e.g. c03)")
    ap.add_argument("--rescore", action="store_true",
                    help="do not simulate or diagnose: score the finished cases in OUT/cases again")
    return ap


def _worker(args):
    case, root, line_doc, fmu_paths, timeout, extra = args
    from webline.diagnosis import benchmark as B
    t0 = time.perf_counter()
    res = B.evaluate_case(case, root, line_doc, fmu_paths, timeout=timeout, extra=extra)
    res["case_wall_s"] = time.perf_counter() - t0
    return res


def run(n, seed=0, out=Path("out/diagnose-bench"), quick=False, jobs=2, timeout=1800.0, only=None, log=None):
    """Run the benchmark; returns (summary, results, meta)."""
    from webline.diagnosis import benchmark as B
    from webline.fmus.build import build_all
    log = log or (lambda m: print(m, file=sys.stderr, flush=True))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    fmu_paths = build_all(log=lambda m: None)
    line_doc = B.derive_line()
    cases = B.draw_cases(n, seed, quick=quick, layout_doc=line_doc)
    if only:
        cases = [c for c in cases if c.id in only]
    t0 = time.perf_counter()
    log(f"diagnose-bench: {len(cases)} cases ({'quick' if quick else 'full'}), seed {seed}, {jobs} jobs, in {out}")
    # cases run in parallel: each diagnosis then simulates serially (no oversubscription)
    extra = ["--jobs", "1"] if jobs > 1 and _diagnose_has_option("--jobs") else []
    tasks = [(c, out, line_doc, fmu_paths, timeout, extra) for c in cases]
    results = []
    if jobs <= 1:
        it = map(_worker, tasks)
        pool = None
    else:
        pool = mp.get_context("spawn").Pool(jobs, maxtasksperchild=1)
        it = pool.imap_unordered(_worker, tasks)
    try:
        for res in it:
            results.append(res)
            sc = res["score"]
            tr = res["truth"]
            hid = ", ".join(f"{e['element']}:{e['kind']}" for e in tr["effects"]) or "none"
            got = ", ".join(f"{e['element']}:{e['kind']}" for e in (res.get("report") or {}).get("effects") or [])
            status = ("generation failed" if res.get("generation_error") else
                      f"diagnose rc {res.get('returncode')}" if res.get("report") is None else "ok")
            log(f"  [{len(results)}/{len(cases)}] {tr['id']} {tr['category']}: hidden {hid} | reported "
                f"{got or 'none'} | {len(sc['matches'])} matched, {len(sc['false'])} false, "
                f"{len(sc['missed'])} missed | {status}, {res.get('case_wall_s', 0):.0f} s "
                f"({time.perf_counter() - t0:.0f} s elapsed)")
    finally:
        if pool is not None:
            pool.close()
            pool.join()
    results.sort(key=lambda r: r["truth"]["id"])
    summary = B.summarize([r for r in results if not r.get("generation_error")])
    summary["generation_failures"] = [{"id": r["truth"]["id"], "error": r["generation_error"][:500]}
                                      for r in results if r.get("generation_error")]
    import platform
    meta = {"seed": seed, "mode": "quick" if quick else "full", "cases": len(cases), "jobs": jobs,
            "cpus": os.cpu_count(), "wall_s": time.perf_counter() - t0, "python": platform.python_version(),
            "line": {"derived_from": str(B.EWL.relative_to(B.REPO)), "elements": list(B.KEEP),
                     "step": B.STEP, "algorithm": B.ALGORITHM, "sample_rate_hz": B.FS},
            "load_average_end": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
            "diagnose_extra_args": extra, "code": _code_version(B.REPO), "work_folder": str(out)}
    return summary, results, meta


def _diagnose_has_option(opt):
    try:
        from webline.diagnosis import diagnose_cmd
        return any(opt in a.option_strings for a in diagnose_cmd.parser()._actions)
    except Exception:
        return False


def _code_version(repo):
    """Commit of the code that ran, and the files of diagnosis/ that differed from it."""
    import subprocess
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=repo, capture_output=True,
                              text=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "diagnosis", "orchestrator", "webline",
                                "fmus"], cwd=repo, capture_output=True, text=True, timeout=10).stdout.split("\n")
        if head:
            return {"commit": head, "uncommitted": [ln[3:] for ln in dirty if ln.strip()]}
    except (OSError, subprocess.SubprocessError):
        pass
    stamp = Path(repo) / ".git-commit"  # a snapshot (git archive) of a commit, written by whoever made it
    if stamp.exists():
        return {"commit": stamp.read_text().strip()[:12], "uncommitted": [], "snapshot": str(repo)}
    return {"commit": None, "uncommitted": []}


def rescore(out, results_path=None):
    """(summary, results, meta) of the finished case folders in ``out``/cases
    (the run's meta taken from ``results_path`` or OUT/diagnosis_results.json)."""
    from webline.diagnosis import benchmark as B
    folders = sorted(p for p in (Path(out) / "cases").glob("*") if (p / "truth" / "truth.json").exists())
    results = [B.load_case(p) for p in folders]
    summary = B.summarize(results)
    summary["generation_failures"] = []
    old = Path(results_path) if results_path else Path(out) / "diagnosis_results.json"
    meta = {}
    if old.exists():
        try:
            meta = json.loads(old.read_text()).get("meta", {})
        except ValueError:
            meta = {}
    meta.update(rescored=True, cases=len(results), work_folder=str(out))
    return summary, results, meta


def write(summary, results, meta, path):
    from webline.diagnosis import benchmark as B
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    doc = {"schema": "webline-diagnose-bench-1", "meta": meta, "summary": summary,
           "cases": [B.compact(r) for r in results]}
    path.write_text(json.dumps(doc, indent=1, default=_json_default))
    md = B.markdown(summary, [r for r in results], meta)
    path.with_suffix(".md").write_text(md)
    return md


def _json_default(o):
    import numpy as np
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    return str(o)


def main(argv=None):
    args = parser().parse_args(argv)
    n = args.cases if args.cases is not None else (3 if args.quick else DEFAULT_CASES)
    if n < 1 or args.jobs < 1:
        print("webline diagnose-bench: --cases and --jobs must be >= 1", file=sys.stderr)
        return 2
    if args.rescore:
        summary, results, meta = rescore(args.out, args.results)
    else:
        from webline.diagnosis import benchmark as B
        if not B.EWL.is_file():
            # an installed webline (a wheel) ships the package, not the repository's scenarios/
            print(f"webline diagnose-bench: needs a source checkout of webline: the benchmark line is "
                  f"derived from scenarios/ewl.yaml of the repository, not found at {B.EWL} (an installed "
                  f"wheel has no scenarios/); run it in a clone: python -m webline.cli diagnose-bench",
                  file=sys.stderr)
            return 2
        summary, results, meta = run(n, args.seed, args.out, args.quick, args.jobs, args.timeout, args.only)
    path = args.results or (args.out / "diagnosis_results.json")
    md = write(summary, results, meta, path)
    print(md)
    print(f"results: {path} and {path.with_suffix('.md')}", file=sys.stderr)
    diagnosed = [r for r in results if r.get("report") is not None]
    return 0 if diagnosed else 1


if __name__ == "__main__":
    sys.exit(main())
