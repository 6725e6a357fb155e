"""What calibrated shaft fits cost: five fits of 60 Nelder-Mead steps, one a mode.

The sixty-third session's measure of :mod:`diagnosis.calibrate`'s cost (README, "What the
sixty-third session did"): a leader shaft at 5, 7, 10, 14 and 20 Hz on the benchmark line
(:func:`diagnosis.benchmark.derive_line`, 200 ft/min, a 60 s record at 1 kHz), each
calibrated as the diagnosis's stage does, fitted to a spectrum made from the line's own
responses. Time it as a whole process, two checkouts against each other, e.g.::

    /usr/bin/time -v A/.venv/bin/python bench/calibrated_fit_cost.py
    /usr/bin/time -v B/.venv/bin/python bench/calibrated_fit_cost.py

It prints each fit's misfit as written and calibrated: two checkouts that compute the same
fits print the same numbers.
"""
import tempfile
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from webline.diagnosis import benchmark as B
from webline.diagnosis import calibrate, others
from webline.diagnosis.line_model import LineModel

FS, T = 1000.0, 60.0
SENSORS = ["lc9.T", "lc19.T"]
SPEED = 200 * 0.3048 / 60   # the layout's 200 ft/min
MODES_HZ = (5.0, 7.0, 10.0, 14.0, 20.0)


def main():
    path = B.write_yaml(Path(tempfile.mkdtemp()) / "line.yaml", B.derive_line())
    model = LineModel(str(path))
    run = SimpleNamespace(name="run1", overrides={"experiment.duration": f"{T} s",
                                                  "experiment.output_interval": f"{1 / FS} s"},
                          t=np.arange(0.0, T + 0.5 / FS, 1 / FS), holdout=False)
    specs = others.drive_candidates(SimpleNamespace(model=model, system0=model.system(run)))
    drives = [sp[0] for sp in specs]
    f = np.arange(0.0, FS / 2 + 1e-9, 0.25)
    G = calibrate.responses(model, run, model.copy_doc(), drives, SENSORS, f, SPEED)
    P = {s: sum(1e-4 * G[e][s] for e in drives) * 1.3 + 1e-4 for s in SENSORS}
    S0 = {s: 1e-4 for s in SENSORS}
    leader = next(sp for sp in specs if sp[0] == "sw_leader")
    for ft in MODES_HZ:
        cal = calibrate.Calibration(model, run, {}, drives, SENSORS, SPEED, shaft=(leader, ft))
        c0, c1, _, n = cal.fit(P, S0, f, maxfev=calibrate.MAXFEV)
        print(f"leader shaft {ft:g} Hz: misfit {c0:.6g} as written, {c1:.6g} calibrated ({n} steps)")


if __name__ == "__main__":
    main()
