"""The shaft screen's spectral fit with the line's fast dynamics calibrated, on the linearised line.

A research probe of a case that ``webline diagnose-bench --out`` kept, beside
``bench/shaft_probe.py`` (whose residual, line removal and misfit it reuses):
the drives' ripple responses come from the linearised line
(``orchestrator.modes.torque_transfer``, |T(f)|^2 from each drive's motor
torque to each load cell) rather than a simulation per drive, so that a
layout costs one linearisation (about 0.6 s) and is free of the simulated
probe's Welch noise. Checked against the simulated responses of seed-54 c24's
truth layout without its run-outs: the ratio is flat over 1-25 Hz within that
noise (about +-30 %).

Each candidate, the rigid line and a shaft on ``ELEMENT`` at each trial mode
alike, is then fitted to the residual's spectrum over its own parameters (Nelder-Mead on log
scale factors): web EA (+-30 %), every drive's inertia, the load cells' filter
time constant and the speed loops' K_ref (+-50 %), and with ``--lag`` a current
lag in every drive (0.3-6 ms), in each of the ``--forms`` (feed-forward as
the layout has it, 'reference' or 'none'; ``+o2``: second-order load-cell
filters). ``--fixed-residual`` keeps the base layout's residual for every
candidate (the lines taken out first, ``--lines-out`` or ``--lines``); without
it each candidate is simulated too, and the run-outs' lines pass through it.

The fifty-ninth session's protocol (docs/diagnose.md, "The ripple spectrum with
the line calibrated")::

    .venv/bin/python bench/shaft_lin_probe.py CASE ELEMENT --layout refined --fixed-residual \
        --forms as ref none --lag --mode 10 --ratios 0.5 0.7 1.0 1.4 2.0 --maxfev 60 --band 4 24 [--lines-out]
"""
import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np
import yaml
from scipy import optimize

sys.path.insert(0, str(Path(__file__).resolve().parent))
import shaft_probe as SP  # noqa: E402

from webline.diagnosis import others, ripple, tolerances  # noqa: E402
from webline.orchestrator import modes as M  # noqa: E402
from webline.orchestrator import units  # noqa: E402
from webline.orchestrator.layout_source import load_located, plain  # noqa: E402


def lin_responses(probe, doc, f, speed):
    """{drive: {sensor: |T|^2 on f}} of ``doc`` linearised at ``speed`` (m/s)."""
    run = dataclasses.replace(probe.run, overrides={**dict(probe.run.overrides),
                                                    "experiment.line_speed": f"{speed:.12g} m/s"})
    system = probe.model.system(run, doc)
    lin = M.linearise_system(system)
    # not at 0 Hz: a shaft's twist is an integrator there; every drive in one solve
    T = lin.transfer(np.maximum(f, f[1]), [f"{e}.tau" for e in probe.drives])
    # at the simulated probe's density (white, PROBE_TORQUE held over 2 ms), so that
    # --validate compares the two directly; the fit's free levels absorb the scale
    scale = 2.0 * float(units.quantity(SP.PROBE_TORQUE, "torque")) ** 2 * 2e-3
    G = {e: {s: scale * ripple.fine(np.abs(T[:, lin.outputs.index(s), j]) ** 2, f) for s in SP.SENSORS}
         for j, e in enumerate(probe.drives)}
    return G


def resolved(probe, sets):
    """The blind layout with ``sets`` written in, as the layout loader reads it (plain data)."""
    return plain(load_located(probe.model.path, sets))


LAG0 = 3e-3
BOUNDS = {"EA": (-np.log(1.3), np.log(1.3)), "lag": (np.log(0.1), np.log(2.0))}
FORMS = {"as": {}, "as+o2": {"order": 2}, "ref": {"ff": "reference"}, "ref+o2": {"ff": "reference", "order": 2},
         "none": {"ff": "none"}, "none+o2": {"ff": "none", "order": 2}}


class Calib:
    """The layout ``base`` with scale factors x (log) on EA, each drive's inertia,
    the load cells' filter time constant and the speed loops' K_ref."""

    def __init__(self, probe, base_sets, speed, shaft=None, free=("EA", "J", "filter", "K"), J_shaft=None,
                 form=None):
        self.probe, self.base_sets, self.speed, self.shaft, self.free = probe, base_sets, speed, shaft, free
        self.J_shaft = J_shaft
        form = form or {}
        loops = sorted(probe.blind["drives"]["speed_loops"])
        extra = {}
        if form.get("ff"):
            extra.update({f"drives.speed_loops.{x}.feedforward": (False if form["ff"] == "none" else form["ff"])
                          for x in loops})
        if form.get("order") == 2:
            extra.update({f"sensors.{q}.filter_order": 2 for q in probe.blind["sensors"]})
        self.base_sets = {**base_sets, **extra}
        # scale factors apply to the base layout's own values (the truth's, the refined one's)
        self.base = resolved(probe, self.base_sets)
        self.lag = bool(form.get("lag"))
        self.names = []
        if "EA" in free:
            self.names.append("EA")
        if "J" in free:
            self.names += [f"J:{e}" for e in probe.drives]
        if "filter" in free:
            self.names.append("filter")
        if "K" in free:
            self.names.append("K")
        if self.lag:
            self.names.append("lag")
        self.bounds = np.array([BOUNDS.get(n.split(":")[0], (-np.log(1.5), np.log(1.5))) for n in self.names])

    def doc(self, x):
        sc = dict(zip(self.names, np.exp(x)))
        base = self.base
        inert = {e: sc[f"J:{e}"] for e in self.probe.drives if f"J:{e}" in sc}
        sets = tolerances.scaled_set(base, EA=sc.get("EA", 1.0), inertia=inert)
        if "filter" in sc:
            for s, v in base["sensors"].items():
                sets[f"sensors.{s}.filter"] = f"{float(units.quantity(v['filter'], 'time')) * sc['filter']:.9g} s"
        if "K" in sc:
            for e, v in base["drives"]["speed_loops"].items():
                sets[f"drives.speed_loops.{e}.K_ref"] = f"{float(units.quantity(v['K_ref'], 'rate')) * sc['K']:.9g} 1/s"
        if "lag" in sc:
            sets.update({f"drives.speed_loops.{e}.current_lag": f"{LAG0 * sc['lag']:.6g} s"
                         for e in base["drives"]["speed_loops"]})
        doc = SP.with_sets(self.probe.model.copy_doc(), {**self.base_sets, **sets})
        if self.shaft is not None:
            el, mode = self.shaft
            k = inert.get(el, 1.0)
            if isinstance(self.J_shaft, tuple):   # a roll: (total at the run's middle, core)
                spec = (el, self.J_shaft[0] * k, ("core_inertia", self.J_shaft[1] * k))
            else:
                spec = (el, self.J_shaft * k, ("inertia", self.J_shaft * k))
            doc = others._drive_doc(doc, spec, mode, 0.0)
        return doc

    def fit(self, band, x0=None, maxfev=120, fixed=None):
        x0 = np.zeros(len(self.names)) if x0 is None else x0
        lo, hi = self.bounds[:, 0], self.bounds[:, 1]

        def cost(x):
            x = np.clip(x, lo, hi)
            try:
                doc = self.doc(x)
                # the residual of this line: the run-outs' lines pass through it too
                P, S0, f, _ = fixed if fixed is not None else self.probe.residual(doc)
                G = lin_responses(self.probe, doc, f, self.speed)
            except Exception as exc:  # noqa: BLE001 - a layout the line cannot hold
                print("    failed:", str(exc).splitlines()[0] if str(exc) else repr(exc))
                return 1e3
            return SP.misfit(P, G, S0, f, band)

        c0 = cost(x0)
        r = optimize.minimize(cost, x0, method="Nelder-Mead",
                              options={"maxfev": maxfev, "xatol": 0.01, "fatol": 1e-4, "initial_simplex":
                                       np.vstack([x0] + [x0 + 0.15 * np.eye(len(x0))[i] for i in range(len(x0))])})
        return c0, float(r.fun), dict(zip(self.names, np.exp(np.clip(r.x, lo, hi)))), r.nfev


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("case", type=Path)
    ap.add_argument("element", help="a driven element, several joined by commas, or 'all'")
    ap.add_argument("--run", default="run1")
    ap.add_argument("--band", nargs=2, type=float, default=(3.15, 12.6))
    ap.add_argument("--validate", action="store_true")
    ap.add_argument("--lines-out", action="store_true")
    ap.add_argument("--lines", nargs="*", help="take these elements' lines out (instead of the report's)")
    ap.add_argument("--fixed-residual", action="store_true", help="the base layout's residual for every candidate")
    ap.add_argument("--maxfev", type=int, default=120)
    ap.add_argument("--free", nargs="*", default=["EA", "J", "filter", "K"])
    ap.add_argument("--ratios", nargs="*", type=float, default=[0.6, 0.7, 0.8, 0.9, 1.0, 1.12, 1.25, 1.4, 1.6])
    ap.add_argument("--layout", default="refined", help="refined or truth-rigid")
    ap.add_argument("--mode", type=float, help="scan around this mode (Hz) instead of the truth's")
    ap.add_argument("--forms", nargs="*", default=["as"], help=f"of {', '.join(FORMS)}")
    ap.add_argument("--lag", action="store_true", help="a current lag in every drive, calibrated")
    ap.add_argument("--window", default="steady", choices=("steady", "all"), help="see shaft_probe.Probe.pieces")
    ap.add_argument("--json", help="write the rigid line's and each drive's best shaft's misfits here")
    a = ap.parse_args(argv)
    truth = json.load(open(a.case / "truth" / "truth.json"))
    mode = a.mode or next(e["drive"]["mode_hz"] for e in truth["effects"] if e["kind"] == "compliance")
    # (a truth without a shaft needs --mode)
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
    # linearised at the run's mean line speed: the master's surface speed
    master = probe.blind["drives"]["master"]
    speed = float(np.mean(np.asarray(s0.columns[f"{master}.omega"])[probe.i0:])) * float(
        units.quantity(next(x for x in probe.blind["path"] if x["name"] == master)["radius"], "length"))
    print(f"truth's mode {mode:.3g} Hz; band {a.band}; line speed {speed:.4g} m/s; lines out: {a.lines_out}")
    if a.validate:
        Gs = probe.responses(base, s0, f)
        Gl = lin_responses(probe, base, f, speed)
        m = (f >= 1) & (f <= 30)
        for e in probe.drives:
            for s in SP.SENSORS:
                q = Gs[e][s][m] / Gl[e][s][m]
                print(f"  {e:>10s} {s}: sim/lin median {np.median(q):.4g}, spread (p10-p90) "
                      f"{np.percentile(q, 10) / np.median(q):.3f}-{np.percentile(q, 90) / np.median(q):.3f}")
        print(f"  misfit sim {SP.misfit(P, Gs, S0, f, a.band):.4f}, lin {SP.misfit(P, Gl, S0, f, a.band):.4f}")
    mark = " <- " + ("mode" if a.mode else "truth")
    elements = probe.drives if a.element == "all" else a.element.split(",")
    rows = [("rigid", None, None)] + [
        ((f"{e} " if len(elements) > 1 else "") + f"{r * mode:.2f} Hz" + (mark if r == 1.0 else ""), (e, r * mode),
         shaft_inertia(probe, sets, e)) for e in elements for r in a.ratios]
    # forms that write the same layout fit the same; 'none' and 'reference' feed forward
    # a constant at a steady speed, so the linearised line is the same in both
    forms = list(dict.fromkeys(a.forms, None))
    ff0 = resolved(probe, sets)["drives"]["speed_loops"]
    if "as" in forms and all(str(v.get("feedforward", "measured")) in ("reference", "False", "none")
                             for v in ff0.values()):
        forms.remove("as")
    if "ref" in forms and "none" in forms:
        forms.remove("none")
    best = {}
    for label, shaft, J_shaft in rows:
        for fname in forms:
            t0 = time.time()
            cal = Calib(probe, sets, speed, shaft, free=a.free, J_shaft=J_shaft, form={**FORMS[fname], "lag": a.lag})
            c0, c1, sc, n = cal.fit(tuple(a.band), maxfev=a.maxfev,
                                    fixed=(P, S0, f, s0) if a.fixed_residual else None)
            best[label] = min(best.get(label, (9e9, ""))[:2], (c1, fname))
            print(f"  {label:>16s} {fname:>8s}: as written {c0:.4f}, calibrated {c1:.4f}  "
                  + " ".join(f"{k} x{v:.3f}" for k, v in sc.items()) + f"  ({n} evals, {time.time() - t0:.0f} s)",
                  flush=True)
    print("best over forms: " + ", ".join(f"{k} {v[0]:.4f} ({v[1]})" for k, v in best.items()))
    rigid = best["rigid"][0]
    per = {}
    for label, shaft, _ in rows[1:]:
        m = best[label][0]
        if shaft[0] not in per or m < per[shaft[0]][0]:
            per[shaft[0]] = (m, shaft[1], best[label][1])
    for e, (m, hz, fname) in per.items():
        print(f"ratio {e}: rigid {rigid:.4f} / {m:.4f} at {hz:.2f} Hz ({fname}) = {rigid / m:.3f}")
    if a.json:
        json.dump({"case": str(a.case), "run": a.run, "band": list(a.band), "forms": forms, "rigid": rigid,
                   "drives": {e: {"misfit": m, "mode_hz": hz, "form": fn, "ratio": rigid / m}
                              for e, (m, hz, fn) in per.items()}}, open(a.json, "w"), indent=1)


def shaft_inertia(probe, sets, element):
    """What ``others._drive_doc`` splits into motor and roll for ``element``'s shaft: a
    roll's (total at the run's middle, core), a roller's inertia."""
    el = next(x for x in probe.blind["path"] if x["name"] == element)
    ee = next(x for x in resolved(probe, sets)["path"] if x["name"] == element)
    if "core_inertia" in el:
        sim0 = probe.model.simulate(probe.run, SP.with_sets(probe.model.copy_doc(), sets))
        return (float(np.mean(np.asarray(sim0.columns[f"{element}.J"])[probe.i0:])),
                float(units.quantity(ee["core_inertia"], "inertia")))
    return float(units.quantity(ee["inertia"], "inertia"))


if __name__ == "__main__":
    main()
