"""Every blind first look of the independent benchmark, one row per seed.

A first look is `webline diagnose-bench --family independent --seed N` run at
the start of a session, before any of that seed's cases was read, and kept as
``bench/diagnosis_results_seedN_first.json``. The rows are read from those
files, nothing else: the table is what was measured, seed after seed, on data
the diagnosis had never seen.

    python bench/first_looks.py            # markdown table on stdout
    python bench/first_looks.py --by-kind [--last N]   # finds and misses per hidden kind
"""
import glob
import json
import os
import statistics
import sys

HERE = os.path.dirname(os.path.abspath(__file__))


def _pct(x):
    return "-" if x is None else f"{100 * x:.0f} %"


def row(path):
    """One seed's first look as a dict of the targets' measured values."""
    with open(path) as fh:
        doc = json.load(fh)
    fam = doc["families"]["independent"]
    meta, t = fam["meta"], fam["target_scores"]
    amp = t.get("amplitude") or {}
    det = t.get("detectable") or {}
    noise = t.get("noise_only") or {}
    cpu = sum(c.get("cpu_s") or 0.0 for c in fam["cases"])
    sims = sum((c.get("simulations") or {}).get("count", 0) for c in fam["cases"])
    return {
        "seed": meta["seed"], "commit": (meta.get("code") or {}).get("commit", "?"),
        "precision": t.get("precision"), "recall": t.get("recall"),
        "recall_detectable": det.get("recall_detectable"),
        "worse": len(t.get("worse_cases") or []), "cases": t.get("cases"),
        "closed_in": (t.get("closed_share_in_sample") or {}).get("median"),
        "closed_out": (t.get("closed_share_held_out") or {}).get("median"),
        "amp_ok": amp.get("ok"), "amp_n": amp.get("n"), "amp_flagged": amp.get("flagged"),
        "invented": noise.get("invented_periodic"),
        "wall_min": meta.get("wall_s", 0.0) / 60.0, "cpu_min": cpu / 60.0, "sims": sims,
    }


def rows(folder=HERE):
    paths = glob.glob(os.path.join(folder, "diagnosis_results_seed*_first.json"))
    got = [row(p) for p in paths]
    return sorted(got, key=lambda r: r["seed"])


def table(rs):
    head = ("| seed | code | precision | recall (detectable) | worse | closed in / held out "
            "| run-out amplitude ok (flagged) | invented | wall / CPU min | simulations |")
    out = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in rs:
        out.append(
            f"| {r['seed']} | {r['commit']} | {_pct(r['precision'])} | {_pct(r['recall'])} "
            f"({_pct(r['recall_detectable'])}) | {r['worse']} of {r['cases']} "
            f"| {r['closed_in'] or 0:.2f} / {r['closed_out'] or 0:.2f} "
            f"| {r['amp_ok']}/{r['amp_n']} ({r['amp_flagged']}) | {r['invented']} "
            f"| {r['wall_min']:.1f} / {r['cpu_min']:.1f} | {r['sims'] or '-'} |")
    if rs:
        med = {k: statistics.median([r[k] for r in rs if r[k] is not None])
               for k in ("precision", "recall", "recall_detectable")}
        met = {k: sum(1 for r in rs if v(r)) for k, v in (
            ("precision", lambda r: (r["precision"] or 0) >= 0.9),
            ("recall", lambda r: (r["recall"] or 0) >= 0.9),
            ("worse", lambda r: r["worse"] == 0),
            ("amplitude", lambda r: r["amp_ok"] == r["amp_n"]),
            ("invented", lambda r: r["invented"] == 0))}
        out.append("")
        out.append(f"{len(rs)} first looks (seeds {rs[0]['seed']}-{rs[-1]['seed']}); median precision "
                   f"{_pct(med['precision'])}, recall {_pct(med['recall'])} ({_pct(med['recall_detectable'])} of "
                   f"the detectable). Targets met in how many: precision >= 90 % {met['precision']}, recall >= 90 % "
                   f"{met['recall']}, no sensor worse {met['worse']}, every run-out amplitude within 20 % or "
                   f"flagged {met['amplitude']}, nothing invented on noise {met['invented']}.")
    return "\n".join(out)


KINDS = ("eccentricity", "out_of_round", "compliance", "backlash")


def _zero():
    return dict(hidden=0, detectable=0, found=0, found_detectable=0, false=0)


def by_kind(folder=HERE, last=None):
    """Per hidden kind over the first looks (the ``last`` N seeds, or all): hidden, of them
    detectable (the benchmark's measure: truth with and without the effect), found (a
    match on element and kind), found of the detectable, and false claims of that kind."""
    paths = sorted(glob.glob(os.path.join(folder, "diagnosis_results_seed*_first.json")),
                   key=lambda p: int(os.path.basename(p).split("seed")[1].split("_")[0]))
    paths = paths[-last:] if last else paths
    count = {k: _zero() for k in KINDS}
    seeds = []
    for p in paths:
        with open(p) as fh:
            fam = json.load(fh)["families"]["independent"]
        seeds.append(fam["meta"]["seed"])
        for case in fam["cases"]:
            score = case.get("score") or {}
            found = {(m["element"], m["kind"]) for m in score.get("matches", [])}
            for e in case["truth"]["effects"]:
                c = count.setdefault(e["kind"], _zero())
                det = bool((e.get("detectable") or {}).get("detectable"))
                hit = (e["element"], e["kind"]) in found
                c["hidden"] += 1
                c["detectable"] += det
                c["found"] += hit
                c["found_detectable"] += hit and det
            for f in score.get("false", []):
                count.setdefault(f["kind"], _zero())["false"] += 1
    return seeds, count


def kind_table(folder=HERE, last=None):
    seeds, count = by_kind(folder, last)
    out = [f"Seeds {min(seeds)}-{max(seeds)} ({len(seeds)} first looks), by hidden kind:", "",
           "| kind | hidden | found | detectable | found of the detectable | false claims |",
           "|---|---|---|---|---|---|"]
    for k, c in count.items():
        out.append(f"| {k} | {c['hidden']} | {c['found']} ({_pct(c['found'] / c['hidden'] if c['hidden'] else None)}) "
                   f"| {c['detectable']} | {c['found_detectable']} "
                   f"({_pct(c['found_detectable'] / c['detectable'] if c['detectable'] else None)}) | {c['false']} |")
    return "\n".join(out)


def main(argv=None):
    import argparse
    ap = argparse.ArgumentParser(description="Every blind first look of the independent benchmark.")
    ap.add_argument("folder", nargs="?", default=HERE)
    ap.add_argument("--by-kind", action="store_true", help="finds and misses per hidden kind instead")
    ap.add_argument("--last", type=int, default=None, help="with --by-kind: the last N seeds only")
    args = ap.parse_args(argv)
    if not glob.glob(os.path.join(args.folder, "diagnosis_results_seed*_first.json")):
        sys.exit(f"no diagnosis_results_seed*_first.json in {args.folder}")
    # each view reads the files itself: --by-kind reads every case, the table each file's summary
    print(kind_table(args.folder, args.last) if args.by_kind else table(rows(args.folder)))


if __name__ == "__main__":
    main()
