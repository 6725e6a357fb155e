"""Where the shaft screen's spectral fit would place a hidden shaft, in several model layouts.

A probe of an independent-benchmark case that ``webline diagnose-bench`` kept
(``--out DIR``: ``DIR/independent/cases/cNN`` with ``truth/``, ``blind/`` and
``diagnosis/``). It fits the drives' ripple responses to the residual's spectrum
as :func:`diagnosis.compliance.spectral_fit` does (both load cells, every drive's
ripple level and a white and a 1/f floor per sensor free; misfit = mean squared
log ratio of data to fit over a band), for the rigid line and for model-built
shafts on ``ELEMENT`` at 0.6-1.6 x the truth's torsional mode, in:

* ``refined``: the diagnosis's refined layout;
* ``refined-truth-lines``: that, with the truth's run-outs for the reported ones;
* ``truth-rigid``: the truth's layout with its shaft taken out (the drive's
  inertia rigid);
* ``truth-but-GROUP``: that, with one group of the truth's settings back at the
  layout's values (E, forms, spans, frictions, inertias, the element's inertia,
  run-outs).

``--grid`` instead probes 36 lines around the refined layout (web EA x0.87/1/1.13,
the element's inertia x0.75/1/1.25, load-cell filters of order 1 or 2, feed-forward
none or reference) and prints, per band, the rigid line's best and each shaft's best
over them.

``--lines-out`` takes the reported sources' lines out of the residual first
(every harmonic up to 40 Hz on each source's simulated angle, 5 s blocks), as
:func:`diagnosis.compliance.line_free` does. The fifty-eighth session's numbers
in docs/diagnose.md ("What limits a shaft's recall") came from this recipe::

    webline diagnose-bench --family independent --seed 54 --only c24 --out out/seed54
    .venv/bin/python bench/shaft_probe.py out/seed54/independent/cases/c24 sw_leader
"""
import argparse
import copy
import dataclasses
import itertools
import json
from pathlib import Path

import numpy as np
import yaml

from webline.diagnosis import benchmark as B
from webline.diagnosis import calibrate, candidates, estimate, others, ripple, tolerances
from webline.diagnosis import runs as R
from webline.diagnosis.layout_edit import with_sets
from webline.diagnosis.line_model import LineModel
from webline.orchestrator import units

BANDS = ((2.0, 8.0), (3.15, 12.6), (5.0, 20.0), (8.0, 32.0))
RATIOS = (0.6, 0.7, 0.8, 0.9, 1.0, 1.12, 1.25, 1.4, 1.6)
SENSORS = ("lc9.T", "lc19.T")
PROBE_TORQUE = "0.05 N*m"
GROUPS = {
    "E": lambda k, el: k == "web.E",
    "forms": lambda k, el: is_form(k),
    "spans": lambda k, el: k.endswith(".span"),
    "frictions": lambda k, el: k.endswith(".friction"),
    "inertias": lambda k, el: (k.endswith("inertia") or k.endswith(".mass") or k.endswith("radius"))
    and k != f"path.{el}.inertia",
    "own-inertia": lambda k, el: k == f"path.{el}.inertia",
    "run-outs": lambda k, el: "eccentricity" in k,
}


def is_form(key):
    """A set key of the truth that changes the model's form, not a parameter."""
    return (key.startswith("web.damping") or key.startswith("sensors.") or "feedforward" in key
            or "current_lag" in key)


class Probe:
    """One case's run, its model and the spectral fit of a layout to its residual."""

    def __init__(self, case, run_name, lines_from=(), window="steady"):
        self.model = LineModel(str(case / "blind" / "line.yaml"))
        self.run_sheet = R.load_run(str(case / "blind" / f"{run_name}.yaml"))
        self.case, self.run_name = case, run_name
        self.conditions("report")
        t = np.asarray(self.run.t)
        self.fs = 1.0 / float(np.median(np.diff(t)))
        self.i0 = len(t) // 6            # the start's transient left out
        self.lines_from = list(lines_from)
        self.window = window
        self.blind = yaml.safe_load(open(case / "blind" / "line.yaml"))
        self.drives = sorted(self.blind["drives"]["speed_loops"])

    def conditions(self, which):
        """Run the record under ``which`` conditions: "report", the run as the diagnosis
        ran it (its per-run corrections, a roll's start radius, over the run sheet's: a
        model roll turning 1 % off the data's beats against its lines, and the beat's
        sidebands fill the ripple's band; seed-56 c08's lc9 at 6-8 Hz, 207 x the floor
        on the run sheet, 6.0 x corrected); "truth", the truth's own conditions (for
        the truth's layouts); "sheet", the run file as written."""
        ov = dict(self.run_sheet.overrides)
        if which == "report":
            rep = json.load(open(self.case / "diagnosis" / "report.json"))
            corr = (rep.get("run_corrections") or {}).get(self.run_name, {})
            ov.update({k: v for k, v in corr.items() if k.startswith("experiment.")})
        elif which == "truth":
            truth = json.load(open(self.case / "truth" / "truth.json"))
            r = next(r for r in truth["runs"] if r["name"] == self.run_name)
            ov.update(B._overrides(r["truth_conditions"]))
        elif which != "sheet":
            raise ValueError(f"conditions {which!r}: report, truth or sheet")
        self.run = dataclasses.replace(self.run_sheet, overrides=ov)
        return self

    def inertia(self, element):
        """The blind layout's inertia of ``element`` (kg m^2)."""
        el = next(x for x in self.blind["path"] if x["name"] == element)
        return float(units.quantity(el["inertia"], "inertia"))

    def pieces(self, sim):
        """Index arrays of the samples the spectrum is taken over, after the start's
        transient: with ``window`` "steady" (the default), each steady-speed window of the
        run as the diagnosis's fit mask has it (``estimate.steady_mask`` of the line speed),
        whose lines keep one amplitude each; "all", every sample in 5 s blocks (the
        fifty-ninth session's recipe: across a ramp a line sweeps through the line's
        response within a block, and seed-56 c10's order 4 left lc9's 12-16 Hz at 5 x the
        floor with the lines projected out)."""
        n = len(self.run.t)
        if self.window == "all":
            B = int(5 * self.fs)
            return [np.arange(a, min(n, a + B)) for a in range(self.i0, n, B)]
        sp = candidates.line_speed_column(sim.system, sim.columns)
        mask = estimate.steady_mask(np.asarray(sim.columns[sp]), self.fs) & (np.arange(n) >= self.i0)
        idx = np.flatnonzero(mask)
        return [p for p in np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1) if len(p) > 1]

    def line_free(self, r, sim):
        """``r`` (over the run's samples) on :meth:`pieces`, concatenated, without the
        harmonics of the sources ``lines_from`` (their simulated angles), each piece fitted
        on its own."""
        out = []
        for b in self.pieces(sim):
            y = r[b] - r[b].mean()
            if self.lines_from and len(b) >= 2.5 * self.fs:
                cols = []
                for e in self.lines_from:
                    th = np.asarray(sim.columns[f"{e}.theta"])[b]
                    f1 = abs(th[-1] - th[0]) / (2 * np.pi) / ((len(b) - 1) / self.fs)
                    cols.append(estimate.harmonic_basis(th, range(1, int(40.0 / f1) + 1)))
                Q = np.linalg.qr(np.hstack(cols))[0]
                y = y - Q @ (Q.T @ y)
            out.append(y)
        return np.concatenate(out)

    def residual(self, doc):
        """(P, S0, f, sim): the fine Welch view of the residual of ``doc``'s simulation per
        load cell (the lines of ``lines_from`` taken out), its white level, the frequencies."""
        s0 = self.model.simulate(self.run, doc)
        P, f = {}, None
        for s in SENSORS:
            r = np.asarray(self.run.columns[s.split(".")[0]]) - np.asarray(s0.columns[s])
            f, p = ripple.welch(self.line_free(r, s0), self.fs)
            P[s] = ripple.fine(p, f)
        # the white floor's scale from the top of the spectrum, where the line is quiet
        S0 = {s: float(np.median(P[s][(f > 0.3 * self.fs) & (f < 0.45 * self.fs)])) for s in SENSORS}
        return P, S0, f, s0

    def responses(self, doc, s0, f):
        """{drive: {sensor: fine PSD}}: each drive's simulated ripple response in ``doc``
        (simulated as ``s0``), one simulation with :data:`PROBE_TORQUE` on that drive."""
        G = {e: {} for e in self.drives}
        for e in self.drives:
            s1 = self.model.simulate(self.run, with_sets(copy.deepcopy(doc),
                                                         {f"drives.speed_loops.{e}.torque_noise": PROBE_TORQUE}))
            for s in SENSORS:
                d = np.asarray(s1.columns[s]) - np.asarray(s0.columns[s])
                _, p = ripple.welch(np.concatenate([d[b] - d[b].mean() for b in self.pieces(s0)]), self.fs)
                G[e][s] = ripple.fine(p, f)
        return G

    def misfits(self, doc):
        """Misfit of ``doc``'s ripple fit over each of :data:`BANDS`."""
        P, S0, f, s0 = self.residual(doc)
        G = self.responses(doc, s0, f)
        return [misfit(P, G, S0, f, band) for band in BANDS]


def misfit(P, G, S0, f, band):
    """:func:`diagnosis.compliance.spectral_fit`'s misfit of the responses ``G`` to ``P``
    over ``band``: every drive's level and the floors free (:func:`diagnosis.calibrate.misfit`)."""
    return calibrate.misfit(P, G, S0, f, band)[0]

def layouts(probe, case, element, which):
    """{name: (set entries on the blind layout, the element's total inertia for the scan)}."""
    truth = yaml.safe_load(open(case / "truth" / "truth_layout.yaml"))["set"]
    refined = yaml.safe_load(open(case / "diagnosis" / "refined_layout.yaml"))["set"]
    J_blind = probe.inertia(element)
    drive, own = f"drives.speed_loops.{element}.drive", f"path.{element}.inertia"
    J_truth = (float(units.quantity(truth[own], "inertia"))
               + float(units.quantity(truth[drive]["motor_inertia"], "inertia"))) if drive in truth else J_blind
    rigid = {k: v for k, v in truth.items() if k != drive}
    rigid[own] = f"{J_truth} kg*m^2"
    lines = {k: v for k, v in truth.items() if "eccentricity" in k}
    out = {"refined": (refined, J_blind),
           "refined-truth-lines": ({**{k: v for k, v in refined.items() if "eccentricity" not in k}, **lines},
                                   J_blind),
           "truth-rigid": (rigid, J_truth)}
    for g, pred in GROUPS.items():
        kept = {k: v for k, v in rigid.items() if not pred(k, element)}
        out[f"truth-but-{g}"] = (kept, J_blind if g == "own-inertia" else J_truth)
    return {k: v for k, v in out.items() if which is None or k in which}


GRID = {"EA": (0.87, 1.0, 1.13), "inertia": (0.75, 1.0, 1.25), "filter_order": (1, 2),
        "feedforward": ("none", "reference")}
GRID_RATIOS = (0.7, 0.85, 1.0, 1.2, 1.4)


def grid(probe, case, element, mode):
    """Rigid line and shafts, each at its best over :data:`GRID` around the refined layout."""
    refined = yaml.safe_load(open(case / "diagnosis" / "refined_layout.yaml"))["set"]
    blind, J0 = probe.blind, probe.inertia(element)
    best = {}
    for fE, fJ, order, ff in itertools.product(*GRID.values()):
        sets = {**refined, **tolerances.scaled_set(blind, EA=fE, inertia={element: fJ})}
        if order == 2:
            sets.update({f"sensors.{s}.filter_order": 2 for s in blind["sensors"]})
        if ff == "reference":
            sets.update({f"drives.speed_loops.{e}.feedforward": "reference" for e in probe.drives})
        base = with_sets(probe.model.copy_doc(), sets)
        J = J0 * fJ
        rows = {"rigid": probe.misfits(base)}
        for r in GRID_RATIOS:
            rows[r] = probe.misfits(others._drive_doc(copy.deepcopy(base), (element, J, ("inertia", J)),
                                                      r * mode, 0.0))
        for k, v in rows.items():
            best[k] = [min(a, b) for a, b in zip(best.get(k, v), v)]
        print(f"  EA x{fE:g}, inertia x{fJ:g}, filter order {order}, feed-forward {ff}: rigid "
              + " ".join(f"{x:.4f}" for x in rows["rigid"]), flush=True)
    for k, v in best.items():
        label = "rigid" if k == "rigid" else f"{k * mode:.2f} Hz"
        print(f"  best {label:>9s} " + " ".join(f"{x:.4f}" for x in v))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("case", type=Path, help="a kept case folder (truth/, blind/, diagnosis/)")
    ap.add_argument("element", help="the driven element whose shaft is scanned (inertia given as 'inertia')")
    ap.add_argument("--run", default="run1")
    ap.add_argument("--layouts", nargs="*", help="names of layouts to probe (default: all)")
    ap.add_argument("--grid", action="store_true", help="the 36-line grid around the refined layout")
    ap.add_argument("--lines-out", action="store_true", help="take the reported sources' lines out first")
    ap.add_argument("--window", default="steady", choices=("steady", "all"), help="see Probe.pieces")
    a = ap.parse_args(argv)
    truth = json.load(open(a.case / "truth" / "truth.json"))
    mode = next(e["drive"]["mode_hz"] for e in truth["effects"] if e["kind"] == "compliance")
    report = json.load(open(a.case / "diagnosis" / "report.json"))
    lines = [e["element"] for e in report["effects"] if e["kind"] in ("eccentricity", "out_of_round")]
    probe = Probe(a.case, a.run, lines if a.lines_out else (), window=a.window)
    print(f"truth's mode {mode:.3g} Hz; bands " + ", ".join(f"{lo:g}-{hi:g}" for lo, hi in BANDS) + " Hz"
          + (f"; lines of {', '.join(lines)} taken out" if a.lines_out else ""))
    if a.grid:
        grid(probe, a.case, a.element, mode)
        return
    for name, (sets, J) in layouts(probe, a.case, a.element, a.layouts).items():
        probe.conditions("truth" if name.startswith("truth") else "report")
        base = with_sets(probe.model.copy_doc(), sets)
        print(f"== {name}\n  {'rigid':>9s} " + " ".join(f"{x:.4f}" for x in probe.misfits(base)), flush=True)
        for r in RATIOS:
            doc = others._drive_doc(copy.deepcopy(base), (a.element, J, ("inertia", J)), r * mode, 0.0)
            print(f"  {r * mode:6.2f} Hz " + " ".join(f"{x:.4f}" for x in probe.misfits(doc))
                  + ("  <- truth" if r == 1.0 else ""), flush=True)


if __name__ == "__main__":
    main()
