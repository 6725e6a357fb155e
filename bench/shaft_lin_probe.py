"""The calibrated shaft comparison (``diagnosis.calibrate.scan``) on a case ``diagnose-bench --out`` kept.

A research probe beside ``bench/shaft_probe.py`` (whose run conditions, steady windows
and line removal it reuses): the residual of the diagnosis's refined layout (or the blind
one, or one of the truth's layouts) on one run, the reported sources' lines taken out
(``--lines-out``, or ``--lines EL ...``), and the rigid line against a shaft on each drive
named (or ``all``), each calibrated as ``webline diagnose --calibrated-shafts`` does: web
EA, the drives' inertias, the load cells' filters, K_ref and a current lag, in the
layout's feed-forward form and the set point's, over ``--band`` (default 4-24 Hz) at the
modes ``--modes`` (default 5, 7, 10, 14, 20 Hz). Prints each fit and, per drive, the
ratio rigid line / best shaft that :data:`diagnosis.compliance.CALIBRATED_RATIO` judges.

The sixtieth session's table (docs/diagnose.md, "The ripple spectrum with the line
calibrated")::

    .venv/bin/python bench/shaft_lin_probe.py CASE all --lines-out --json OUT.json

(the fifty-ninth session's numbers came from this script at 622e319, which also fitted
subsets of the parameters and simulated each candidate's own residual; its run sheet
conditions and 5 s blocks over ramps are why its seed-56 c08 and c10 rows differ).
``--validate`` compares the linearised responses with simulated ones.
"""
import argparse
import json
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
import shaft_probe as SP  # noqa: E402

from webline.diagnosis import calibrate, candidates, others  # noqa: E402
from webline.orchestrator import units  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("case", type=Path)
    ap.add_argument("element", help="a driven element, several joined by commas, or 'all'")
    ap.add_argument("--run", default="run1")
    ap.add_argument("--band", nargs=2, type=float, default=calibrate.BAND_HZ)
    ap.add_argument("--modes", nargs="*", type=float, default=calibrate.MODES_HZ)
    ap.add_argument("--maxfev", type=int, default=calibrate.MAXFEV)
    ap.add_argument("--layout", default="refined", help="refined, blind, or a truth layout of shaft_probe.layouts")
    ap.add_argument("--lines-out", action="store_true", help="the report's sources' lines taken out")
    ap.add_argument("--lines", nargs="*", help="these elements' lines taken out (instead of the report's)")
    ap.add_argument("--window", default="steady", choices=("steady", "all"), help="see shaft_probe.Probe.pieces")
    ap.add_argument("--validate", action="store_true", help="linearised against simulated responses, then stop")
    ap.add_argument("--json", help="write the scan here")
    a = ap.parse_args(argv)
    report = json.load(open(a.case / "diagnosis" / "report.json"))
    lines = [e["element"] for e in report["effects"] if e["kind"] in ("eccentricity", "out_of_round")]
    probe = SP.Probe(a.case, a.run, a.lines if a.lines is not None else (lines if a.lines_out else ()),
                     window=a.window)
    if a.layout == "blind":
        sets = {}
    elif a.layout == "refined":
        sets = yaml.safe_load(open(a.case / "diagnosis" / "refined_layout.yaml"))["set"] or {}
    else:
        sets, _ = SP.layouts(probe, a.case, a.element, [a.layout])[a.layout]
        probe.conditions("truth")
    base = SP.with_sets(probe.model.copy_doc(), sets)
    P, S0, f, s0 = probe.residual(base)
    # linearised at the steady windows' mean line speed, as the diagnosis does
    sp = candidates.line_speed_column(s0.system, s0.columns)
    v = np.concatenate([np.asarray(s0.columns[sp])[b] for b in probe.pieces(s0)])
    speed = float(np.mean(v))
    d = SimpleNamespace(model=probe.model, system0=probe.model.system(probe.run, base))
    specs = others.drive_candidates(d)
    if a.element != "all":
        specs = [sp for sp in specs if sp[0] in a.element.split(",")]
    print(f"{a.case} {a.run}: band {a.band} Hz, line speed {speed:.4g} m/s, lines out: {probe.lines_from}, "
          f"window {a.window}", flush=True)
    if a.validate:
        validate(probe, base, s0, P, S0, f, speed, a.band)
        return
    res = calibrate.scan(probe.model, probe.run, sets, specs, list(SP.SENSORS), speed, P, S0, f,
                         band=tuple(a.band), modes_hz=a.modes, maxfev=a.maxfev,
                         progress=lambda t: print("  " + t, flush=True))
    rigid = res["rigid"]["misfit"]
    for r in sorted(res["shafts"], key=lambda r: r["element"]):
        print(f"ratio {r['element']}: rigid {rigid:.4f} / {r['misfit']:.4f} at {r['torsional_hz']:.2f} Hz "
              f"({r['form'] or 'as written'}) = {rigid / r['misfit']:.3f}")
    if res.get("refined"):
        r = res["refined"]["row"]
        print(f"refined: {r['element']} at {r['torsional_hz']:.3g} Hz, misfit {r['misfit']:.4f}; tried "
              + ", ".join(f"{t['torsional_hz']:.3g} Hz {t['misfit']:.4f}" for t in res["refined"]["tried"]))
    if a.json:
        json.dump({"case": str(a.case), "run": a.run, **res}, open(a.json, "w"), indent=1)


def validate(probe, base, s0, P, S0, f, speed, band):
    """The linearised responses against one simulation per drive (``Probe.responses``)."""
    Gs = probe.responses(base, s0, f)
    Gl = calibrate.responses(probe.model, probe.run, base, probe.drives, list(SP.SENSORS), f, speed)
    # the simulated probe's density: white, PROBE_TORQUE held over 2 ms
    scale = 2.0 * float(units.quantity(SP.PROBE_TORQUE, "torque")) ** 2 * 2e-3
    m = (f >= 1) & (f <= 30)
    for e in probe.drives:
        for s in SP.SENSORS:
            q = Gs[e][s][m] / (scale * Gl[e][s][m])
            print(f"  {e:>10s} {s}: sim/lin median {np.median(q):.4g}, spread (p10-p90) "
                  f"{np.percentile(q, 10) / np.median(q):.3f}-{np.percentile(q, 90) / np.median(q):.3f}")
    print(f"  misfit sim {SP.misfit(P, Gs, S0, f, band):.4f}, lin {calibrate.misfit(P, Gl, S0, f, band)[0]:.4f}")


if __name__ == "__main__":
    main()
