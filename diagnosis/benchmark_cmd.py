"""``webline diagnose-bench [--family own|independent|both] [--cases N] [--seed S] [--out DIR] [--quick]``.

Two families of cases, scored side by side against the same targets
(:func:`diagnosis.benchmark_independent.target_scores`): "own" - the truth is
the diagnosis's own co-simulated model plus white noise
(:mod:`diagnosis.benchmark`); "independent" - the truth differs in model form
and parameters, is simulated by the monolithic engine and measured through
coloured noise, drift and 16-bit quantisation
(:mod:`diagnosis.benchmark_independent`).

Per family it draws N cases with hidden effects on a line derived from the EWL layout,
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
    ap.add_argument("--family", choices=("own", "independent", "both"), default="both",
                    help="which family of cases (default both; independent cases go to OUT/independent)")
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
    ap.add_argument("--calibrated-shafts", action="store_true",
                    help="diagnose with --calibrated-shafts (a shaft sought with the line's fast dynamics calibrated)")
    ap.add_argument("--rescore", action="store_true",
                    help="do not simulate or diagnose: score the finished cases in OUT/cases again")
    return ap


def _family_module(family):
    if family == "independent":
        from webline.diagnosis import benchmark_independent as M
    else:
        from webline.diagnosis import benchmark as M
    return M


def family_folder(out, family):
    """Work folder of a family: OUT itself for "own" (as before), OUT/independent."""
    return Path(out) if family == "own" else Path(out) / family


def _worker(args):
    case, root, line_doc, fmu_paths, timeout, extra, family = args
    M = _family_module(family)
    t0 = time.perf_counter()
    res = M.evaluate_case(case, root, line_doc, fmu_paths, timeout=timeout, extra=extra)
    res["case_wall_s"] = time.perf_counter() - t0
    return res


def run(n, seed=0, out=Path("out/diagnose-bench"), quick=False, jobs=2, timeout=1800.0, only=None, log=None,
        family="own", diagnose_args=()):
    """Run one family of the benchmark in ``family_folder(out, family)``; returns (summary, results, meta)."""
    from webline.diagnosis import benchmark as B
    M = _family_module(family)
    out = family_folder(out, family)
    from webline.fmus.build import build_all
    log = log or (lambda m: print(m, file=sys.stderr, flush=True))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    fmu_paths = build_all(log=lambda m: None)
    line_doc = B.derive_line()
    cases = M.draw_cases(n, seed, quick=quick, layout_doc=line_doc)
    if only:
        cases = [c for c in cases if c.id in only]
    t0 = time.perf_counter()
    log(f"diagnose-bench [{family}]: {len(cases)} cases ({'quick' if quick else 'full'}), seed {seed}, {jobs} jobs, in {out}")
    # cases run in parallel: each diagnosis then simulates serially (no oversubscription)
    extra = ["--jobs", "1"] if jobs > 1 and _diagnose_has_option("--jobs") else []
    extra += list(diagnose_args)
    tasks = [(c, out, line_doc, fmu_paths, timeout, extra, family) for c in cases]
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
    meta = {"family": family, "seed": seed, "mode": "quick" if quick else "full", "cases": len(cases), "jobs": jobs,
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


def rescore(out, results_path=None, family="own"):
    """(summary, results, meta) of the finished case folders of ``family`` in
    ``family_folder(out, family)``/cases (the run's meta taken from
    ``results_path`` or OUT/diagnosis_results.json)."""
    from webline.diagnosis import benchmark as B
    work = family_folder(out, family)
    folders = sorted(p for p in (work / "cases").glob("*") if (p / "truth" / "truth.json").exists())
    if family == "independent":  # cases made before detectability (a shaft's profiled) was measured: now
        from webline.diagnosis import benchmark_independent as BI
        for p in folders:
            tr = json.loads((p / "truth" / "truth.json").read_text())
            if any("detectable" not in e or (e["kind"] == "compliance" and "deflection_profiled" not in e["detectable"])
                   for e in tr["effects"]) and tr.get("runs"):
                try:
                    BI.add_detectability(p)
                except Exception as exc:  # noqa: BLE001 - recorded as not known, the rescore goes on
                    print(f"{p.name}: detectability not measured ({str(exc)[:200]})")
    results = [B.load_case(p) for p in folders]
    summary = B.summarize(results)
    summary["generation_failures"] = []
    meta = {}
    # the run's meta: from the results file named, else from the run's own one in OUT
    olds = [Path(p) for p in (results_path, Path(out) / "diagnosis_results.json") if p]
    old = next((p for p in olds if p.exists()), olds[-1])
    if old.exists():
        try:
            d = json.loads(old.read_text())
            meta = ((d.get("families") or {}).get(family) or {}).get("meta") or d.get("meta", {})
        except ValueError:
            meta = {}
    meta.update(family=family, rescored=True, cases=len(results), work_folder=str(work))
    return summary, results, meta


def write(families, path):
    """Write the results of the families run (``families``: {family: (summary,
    results, meta)}): PATH (JSON) and PATH.md - the side-by-side target table,
    then each family's own tables. Returns the Markdown."""
    from webline.diagnosis import benchmark as B
    from webline.diagnosis import benchmark_independent as BI
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    scores = {f: BI.target_scores(results) for f, (_, results, _) in families.items()}
    doc = {"schema": "webline-diagnose-bench-2", "targets": BI.TARGETS,
           "families": {f: {"meta": meta, "summary": summary, "target_scores": scores[f],
                            "forms_applied": BI.forms_summary(results) if f == "independent" else None,
                            "cases": [B.compact(r) for r in results]}
                        for f, (summary, results, meta) in families.items()}}
    path.write_text(json.dumps(doc, indent=1, default=_json_default))
    L = [_intro(families), "", BI.side_by_side(scores)]
    for f, (summary, results, meta) in families.items():
        L.append(f"\n## Family \"{f}\"\n")
        if f == "independent":
            L.append(_independent_text(results, meta) + "\n")
            L.append(B.markdown(summary, list(results), {k: v for k, v in meta.items() if k != "line"}))
        else:
            L.append(B.markdown(summary, list(results), meta))
    md = "\n".join(L)
    path.with_suffix(".md").write_text(md)
    return md


def _intro(families):
    parts = []
    for f, (summary, results, meta) in families.items():
        parts.append(f"{f}: {summary['cases']} cases, seed {meta.get('seed')}, {meta.get('mode', 'full')} mode, "
                     f"wall {meta.get('wall_s', 0) / 60:.1f} min")
    return ("Targets of `webline diagnose` on two families of cases (`webline diagnose-bench --family both`): "
            "\"own\" - data from the diagnosis's own co-simulated model plus white noise; \"independent\" - a "
            "truth differing in model form and parameters, simulated by the monolithic engine, measured with "
            "coloured noise, drift and 16-bit quantisation. A periodic find counts only with its fundamental "
            "within 2 % of the truth's; closed_share = (nominal - refined) / (nominal - achievable) NRMSE at the "
            "most affected load cell, the achievable one being the measurement error injected. "
            + "; ".join(parts) + ".")


def _independent_text(results, meta):
    from webline.diagnosis import benchmark_independent as BI
    fs = BI.forms_summary(results)
    applied = ", ".join(f"{k} {v['applied']}/{v['drawn']}" for k, v in fs.items())
    rates = sorted({(r.get("spec") or {}).get("fs_hz") for res in results for r in res["truth"].get("runs", [])} - {None})
    engines = sorted({r.get("engine") for res in results for r in res["truth"].get("runs", [])} - {None})
    return (f"Truth engine: {', '.join(engines) or '-'}; sample rates {', '.join(f'{x:g}' for x in rates)} Hz. "
            f"Model-form keys applied (applied/drawn, a key the layout rejects is not applied): {applied or '-'}. "
            "Parameters: EA +-15 %, inertias +-30 %, friction x0.3-3, spans +-5 %, start radii +-2 %.")


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
    if not args.rescore:
        from webline.diagnosis import benchmark as B
        if not B.EWL.is_file():
            # an installed webline (a wheel) ships the package, not the repository's scenarios/
            print(f"webline diagnose-bench: needs a source checkout of webline: the benchmark line is "
                  f"derived from scenarios/ewl.yaml of the repository, not found at {B.EWL} (an installed "
                  f"wheel has no scenarios/); run it in a clone: python -m webline.cli diagnose-bench",
                  file=sys.stderr)
            return 2
    fams = ("own", "independent") if args.family == "both" else (args.family,)
    families = {}
    for fam in fams:
        if args.rescore:
            families[fam] = rescore(args.out, args.results, fam)
        else:
            families[fam] = run(n, args.seed, args.out, args.quick, args.jobs, args.timeout, args.only, family=fam,
                                diagnose_args=["--calibrated-shafts"] if args.calibrated_shafts else [])
    path = args.results or (args.out / "diagnosis_results.json")
    md = write(families, path)
    print(md)
    print(f"results: {path} and {path.with_suffix('.md')}", file=sys.stderr)
    diagnosed = [r for _, results, _ in families.values() for r in results if r.get("report") is not None]
    return 0 if diagnosed else 1


if __name__ == "__main__":
    sys.exit(main())
