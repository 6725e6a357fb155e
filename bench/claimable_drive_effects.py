"""Which hidden drive effects of the first looks could be claimed under the target
"no sensor's NRMSE worse" at all: the truth's own model, with and without the effect.

A drive effect (a compliant shaft, a dead zone) is seen by its spectrum, but a claim
must also leave every sensor's NRMSE no worse on the fit runs. A shaft's
deterministic part (what it changes without the drives' torque ripple) is often far
below the noise, and then the rise it brings is a coin toss. This script makes each
first look's drive-effect cases again from its seed (truth simulations only, no
diagnosis; :func:`webline.diagnosis.benchmark_independent.make_case` measures
``claimable`` with the detectability) and sets the measurement beside the first
look's find. A case counts only where the regenerated detect value equals the one the
first look recorded (the generator changed over the sessions: an older seed may draw
other cases now).

    python bench/claimable_drive_effects.py --seeds 54-63 [--out DIR] [--json FILE]
"""
import argparse
import json
import math
import os
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
DRIVE = ("compliance", "backlash")


def _seeds(text):
    out = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out += list(range(int(lo), int(hi or lo) + 1))
    return out


def first_look(seed, folder=HERE):
    """{case id: (found (element, kind) set, {(element, kind): detect value})} of a seed's first look, or None."""
    p = folder / f"diagnosis_results_seed{seed}_first.json"
    if not p.exists():
        return None
    fam = json.loads(p.read_text())["families"]["independent"]
    return {c["truth"]["id"]: ({(m["element"], m["kind"]) for m in c["score"]["matches"]},
                               {(e["element"], e["kind"]): (e.get("detectable") or {}).get("detect_value")
                                for e in c["truth"]["effects"]})
            for c in fam["cases"]}


def measure_seed(seed, out):
    """Rows {seed, case, element, kind, detectable, detect_value, claimable, worst_error_rise,
    found, same_case} of a seed's drive-effect cases, made again in ``out``."""
    from webline.diagnosis import benchmark as B
    from webline.diagnosis import benchmark_independent as BI
    first = first_look(seed)
    if first is None:
        return []
    doc = B.derive_line()
    rows = []
    for case in BI.draw_cases(24, seed, layout_doc=doc):
        if not any(e.kind in DRIVE for e in case.effects) or case.id not in first:
            continue
        found, recorded = first[case.id]
        truth = BI.make_case(case, Path(out) / f"seed{seed}" / case.id, doc)
        for e in truth["effects"]:
            if e["kind"] not in DRIVE:
                continue
            d = e["detectable"]
            old = recorded.get((e["element"], e["kind"]))
            rows.append({"seed": seed, "case": case.id, "element": e["element"], "kind": e["kind"],
                         "detectable": d["detectable"], "detect_value": d["detect_value"],
                         "claimable": d.get("claimable"), "worst_error_rise": d.get("worst_error_rise"),
                         "held_out_claimable": d.get("held_out_claimable"),
                         "found": (e["element"], e["kind"]) in found,
                         "same_case": old is not None and math.isclose(old, d["detect_value"], rel_tol=1e-3)})
    return rows


def table(rows):
    """Markdown: per kind, the detectable effects split by claimable, found in each part."""
    out = ["| kind | detectable (same case as the first look) | claimable: found | not claimable: found "
           "| rise the effect brings to the truth's own error where not claimable (median, max) "
           "| of the claimable, claimable on the held-out run too |",
           "|---|---|---|---|---|---|"]
    for kind in DRIVE:
        det = [r for r in rows if r["kind"] == kind and r["same_case"] and r["detectable"]
               and r["claimable"] is not None]
        yes = [r for r in det if r["claimable"]]
        no = [r for r in det if not r["claimable"]]
        rises = sorted(r["worst_error_rise"] for r in no)
        med = f"{rises[len(rises) // 2]:.2g}, {rises[-1]:.2g}" if rises else "-"
        held = [r for r in yes if r.get("held_out_claimable") is not None]
        out.append(f"| {kind} | {len(det)} | {sum(r['found'] for r in yes)} of {len(yes)} "
                   f"| {sum(r['found'] for r in no)} of {len(no)} | {med} "
                   f"| {sum(r['held_out_claimable'] for r in held)} of {len(held)} |")
    skipped = sum(not r["same_case"] for r in rows)
    if skipped:
        out += ["", f"{skipped} effect(s) left out: the seed now draws another case than its first look did."]
    return "\n".join(out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", required=True, help="first-look seeds, e.g. 54-63 or 2,5,7-9")
    ap.add_argument("--out", default=None, help="work folder for the cases (default: a temporary one)")
    ap.add_argument("--json", default=None, help="write the rows here too")
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory(prefix="webline_claimable_") as tmp:
        for seed in _seeds(args.seeds):
            got = measure_seed(seed, args.out or tmp)
            rows += got
            print(f"seed {seed}: {len(got)} drive effects", file=sys.stderr, flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    print(table(rows))


if __name__ == "__main__":
    sys.path.insert(0, os.fspath(HERE.parent))
    main()
