"""What a hidden shaft changes in a line's deterministic output, in the truth and in
the diagnosis's model, against what the data leave: the measurement behind
docs/diagnose-bench.md, "Drive effects: claimable at all?" (independent seed-57 c09).

For one benchmark case folder (blind/ and truth/, as `webline diagnose-bench` makes
them) and the element whose drive holds the truth's shaft, on the first fit run:
the truth simulated with and without its shaft (no torque ripple: a diagnosis
cannot know its sequence), and the nominal line with a shaft on that drive as the
diagnosis writes one (`others._drive_doc`), in the layout's form and in
'feedforward none' on every speed loop. Prints, per load cell, the residual of the
nominal line, each change's rms and its correlation with the truth's own change,
and the relative change of the error each brings.

    python bench/shaft_footprint.py out/diagnose-bench/independent/cases/c09 sw_leader \
        [--modes 7.67,7.11] [--zeta 0.025]
"""
import argparse
import copy
import sys
from pathlib import Path

import numpy as np
import yaml


def _rms(x):
    return float(np.sqrt(np.mean(np.asarray(x, float) ** 2)))


def footprint(case, element, modes=(7.67,), zeta=0.025, settle_s=2.0):
    """{sensor: {name: {rms, corr, error_rise}}, and "_residual" per sensor} (see the module)."""
    from webline.diagnosis import layout_edit, others, runs
    from webline.diagnosis.line_model import LineModel
    case = Path(case)
    run = runs.load_run(case / "blind" / "run1.yaml")
    blind, truth = LineModel(case / "blind" / "line.yaml"), LineModel(case / "truth" / "truth_layout.yaml")
    sensors = [f"{k}.T" for k in run.columns]
    y = {s: np.asarray(run.columns[s[:-2]], float) for s in sensors}
    keep = np.asarray(run.t) > settle_s

    def sim(model, doc=None):
        got = model.simulate(run, doc)
        return {s: np.asarray(got.columns[s], float)[keep] for s in sensors}

    tset = yaml.safe_load((case / "truth" / "truth_layout.yaml").read_text())["set"]
    drive = tset.get(f"drives.speed_loops.{element}.drive")
    if drive is None:
        sys.exit(f"{case}: the truth has no non-ideal drive on {element}")
    comp = next(c for c in blind.system(None).components
                if c.element == element and ("J" in c.parameters or "J_core" in c.parameters))
    if "J" not in comp.parameters:
        sys.exit(f"{element}: a roll's drive; this script handles rollers only")
    spec = (element, comp.parameters["J"], ("inertia", comp.parameters["J"]))
    # the truth without its shaft: the drive rigid, the motor's inertia back on the element
    tdoc = layout_edit.with_set(truth.copy_doc(), f"drives.speed_loops.{element}.drive", None)
    jm = float(str(drive["motor_inertia"]).split()[0])
    jr = float(str(tset[f"path.{element}.inertia"]).split()[0])
    tdoc = layout_edit.with_set(tdoc, f"path.{element}.inertia", f"{jr + jm:.6g} kg*m^2")
    t1, t0 = sim(truth), sim(truth, tdoc)
    n0 = sim(blind)
    bdoc = blind.copy_doc()
    ffn = bdoc
    line = yaml.safe_load((case / "blind" / "line.yaml").read_text())
    for el in (line.get("drives", {}) or {}).get("speed_loops", {}) or {}:
        ffn = layout_edit.with_set(ffn, f"drives.speed_loops.{el}.feedforward", "none")
    n0_ffn = sim(blind, ffn)
    changes = {"truth's shaft": (t1, t0), "form 'feedforward none' alone": (n0_ffn, n0)}
    for f in modes:
        changes[f"shaft {f:g} Hz, layout's form"] = (sim(blind, others._drive_doc(copy.deepcopy(bdoc), spec, f, 0.0,
                                                                                   zeta=zeta)), n0)
        changes[f"shaft {f:g} Hz, in 'feedforward none'"] = (
            sim(blind, others._drive_doc(copy.deepcopy(ffn), spec, f, 0.0, zeta=zeta)), n0_ffn)
    out = {}
    for s in sensors:
        ys = y[s][keep]
        dt = t1[s] - t0[s]
        rows = {"_residual": {"nominal": _rms(ys - n0[s]), "truth": _rms(ys - t1[s]),
                              "truth without its shaft": _rms(ys - t0[s])}}
        for name, (a, b) in changes.items():
            d = a[s] - b[s]
            corr = float(np.dot(d, dt) / (np.linalg.norm(d) * np.linalg.norm(dt) + 1e-300))
            rows[name] = {"rms": _rms(d), "corr": corr, "error_rise": _rms(ys - a[s]) / _rms(ys - b[s]) - 1.0}
        out[s] = rows
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("case", help="a benchmark case folder (blind/, truth/)")
    ap.add_argument("element", help="the element whose drive holds the truth's shaft")
    ap.add_argument("--modes", default="7.67", help="torsional modes of the diagnosis's shaft, Hz (comma-separated)")
    ap.add_argument("--zeta", type=float, default=0.025, help="its damping ratio")
    args = ap.parse_args(argv)
    got = footprint(args.case, args.element, [float(x) for x in args.modes.split(",")], args.zeta)
    for s, rows in got.items():
        r = rows.pop("_residual")
        print(f"{s}: residual rms, N: nominal {r['nominal']:.5f}, truth {r['truth']:.5f}, "
              f"truth without its shaft {r['truth without its shaft']:.5f}")
        for name, v in rows.items():
            print(f"  {name:40s} change {v['rms']:.4f} N rms, corr. with the truth's {v['corr']:+.2f}, "
                  f"error {100 * v['error_rise']:+.4f} %")


if __name__ == "__main__":
    main()
