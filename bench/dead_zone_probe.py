"""How well a leader dead zone can fit a case's data in the data sheet's parameters.

A probe of an independent-benchmark case (``CASE`` = a folder with ``blind/``,
``truth/`` and ``diagnosis/``, as ``webline diagnose-bench --out DIR`` keeps
them, ``DIR/independent/cases/cNN``). It prints the sum over load cells and fit
runs of NRMSE^2 (the structure screen's score; no ripple in any model) for

* the truth's layout, with and without its dead zone;
* the truth's layout with one group of its settings back at the data sheet's
  (``truth but GROUP``): which of them a dead zone's waveform hangs on;
* the blind layout with the truth's run-outs, in the feed-forward and filter
  forms named by ``--form`` (repeatable, ``+``-joined of ``ffref``, ``ffnone``,
  ``lc2``, ``wd``), with and without a dead zone on ``--element`` at
  ``--widths`` deg and its friction at ``--frictions`` x the sheet's.

The sixty-second session's numbers in docs/diagnose.md ("A shaft whose mode
sits on a source's line") came from::

    .venv/bin/python bench/dead_zone_probe.py out/seed39/independent/cases/c17 \\
        --form ffref+lc2 --form ffref+wd --form ffnone+wd
"""
import argparse
import copy
import dataclasses
import json
import math
import sys
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
from shaft_probe import SENSORS  # noqa: E402

from webline.diagnosis import backlash  # noqa: E402
from webline.diagnosis.layout_edit import with_sets  # noqa: E402
from webline.diagnosis import runs as R  # noqa: E402
from webline.diagnosis.line_model import LineModel  # noqa: E402
from webline.orchestrator import units  # noqa: E402

DRIVES = ("unwind", "sw_leader", "rewind")
FORMS = {
    "ffref": {f"drives.speed_loops.{x}.feedforward": "reference" for x in DRIVES},
    "ffnone": {f"drives.speed_loops.{x}.feedforward": False for x in DRIVES},
    "lc2": {"sensors.lc9.filter_order": 2, "sensors.lc19.filter_order": 2},
    "wd": {"web.damping": "2 ms"},
}
GROUPS = {
    "E": lambda k, el: k == "web.E",
    "web damping": lambda k, el: k.startswith("web.damping"),
    "current lags": lambda k, el: "current_lag" in k,
    "sensor filters": lambda k, el: k.startswith("sensors."),
    "spans": lambda k, el: k.endswith(".span"),
    "frictions": lambda k, el: k.endswith(".friction"),
    "inertias": lambda k, el: (k.endswith("inertia") or k.endswith(".mass") or k.endswith("radius"))
    and k != f"path.{el}.inertia",
}


class Case:
    """A kept case: its fit runs as the diagnosis ran them and the score of a layout on them."""

    def __init__(self, folder):
        self.folder = Path(folder)
        self.model = LineModel(str(self.folder / "blind" / "line.yaml"))
        rep = json.loads((self.folder / "diagnosis" / "report.json").read_text())
        self.runs = []
        for p in sorted((self.folder / "blind").glob("run*.yaml")):
            run = R.load_run(str(p))
            corr = (rep.get("run_corrections") or {}).get(run.name, {})
            ov = {**run.overrides, **{k: v for k, v in corr.items() if k.startswith("experiment.")}}
            self.runs.append(dataclasses.replace(run, overrides=ov))
        self.blind = yaml.safe_load((self.folder / "blind" / "line.yaml").read_text())
        t = self.folder / "truth" / "truth_layout.yaml"
        self.truth = yaml.safe_load(t.read_text())
        self.truth["base"] = str((t.parent / self.truth["base"]).resolve())

    def score(self, doc, label):
        """Sum of NRMSE^2 over the load cells and runs, after the first sixth (the start)."""
        tot, per = 0.0, {}
        for run in self.runs:
            sim = self.model.simulate(run, doc, label=label)
            i0 = len(run.t) // 6
            for k in SENSORS:
                meas = np.asarray(run.columns[k.split(".")[0]])[i0:]
                r = meas - np.asarray(sim.columns[k])[i0:]
                nr = math.sqrt(float(np.sum(r ** 2)) / float(np.sum((meas - meas.mean()) ** 2)))
                per[f"{run.name}.{k}"] = round(nr, 4)
                tot += nr * nr
        print(f"{tot:.4f}  {label}  {per}", flush=True)
        return tot

    def element(self, el):
        return next(x for x in self.blind["path"] if x["name"] == el)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("case")
    ap.add_argument("--element", default="sw_leader")
    ap.add_argument("--form", action="append", default=None, help="e.g. ffref+lc2 (repeatable)")
    ap.add_argument("--widths", type=float, nargs="+", default=[0.5, 1.0, 2.0])
    ap.add_argument("--frictions", type=float, nargs="+", default=[1.0, 2.0, 3.0])
    a = ap.parse_args(argv)
    c, el = Case(a.case), a.element
    key = f"drives.speed_loops.{el}.drive"
    c.score(c.truth, "truth")
    t0 = copy.deepcopy(c.truth)
    t0["set"][key] = {**t0["set"][key], "backlash": "0 rad"}
    c.score(t0, "truth without its dead zone")
    for g, f in GROUPS.items():
        t = copy.deepcopy(c.truth)
        t["set"] = {k: v for k, v in c.truth["set"].items() if not f(k, el)}
        c.score(t, f"truth but {g}")
    lines = {k: v for k, v in c.truth["set"].items() if "eccentricity" in k}
    oracle = with_sets({"base": str((c.folder / "blind" / "line.yaml").resolve()), "set": {}}, lines)
    J = float(units.quantity(c.element(el)["inertia"], "inertia"))
    f0 = float(units.quantity(c.element(el).get("friction", "0 N*m*s/rad"), "rot_damping"))
    for form in a.form or ["ffref+lc2"]:
        doc = with_sets(oracle, {k: v for part in form.split("+") for k, v in FORMS[part].items()})
        c.score(doc, f"the truth's run-outs, {form}")
        for deg in a.widths:
            for fx in a.frictions:
                c.score(backlash.backlash_doc(doc, (el, J, ("inertia", J)), deg, f0 * fx),
                        f"the truth's run-outs, {form} + dead zone {deg:g} deg, friction x{fx:g}")


if __name__ == "__main__":
    main()
