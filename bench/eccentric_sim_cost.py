"""What a simulation of an eccentric line costs on the fast engine.

The diagnosis simulates its candidate lines thousands of times a case, each with
the run-outs estimated so far (several orders on one to three elements). This
times one 60 s run of the EWL-like line at 200 ft/min, round and with six orders
on one, two and three elements (the unwind, idler_u1, roller9), the compiled code
cached: ``python bench/eccentric_sim_cost.py [--repeats N] [--duration S]``.
"""
import argparse
import time
from pathlib import Path

from webline.orchestrator import engine
from webline.orchestrator.layout import load_system

ROOT = Path(__file__).resolve().parent.parent
ORDERS = {"C": ["0.6 mm", "0.9 mm", "0.25 mm", "0.3 mm", "0.1 mm", "0.12 mm"],
          "psi": ["0 deg", "40 deg", "75 deg", "110 deg", "20 deg", "60 deg"]}
ELEMENTS = ("unwind", "idler_u1", "roller9")


def system(n_eccentric, duration):
    over = {"experiment.duration": f"{duration} s", "experiment.line_speed": "200 ft/min"}
    for el in ELEMENTS[:n_eccentric]:
        over[f"path.{el}.eccentricity"] = ORDERS
    return load_system(ROOT / "scenarios" / "ewl.yaml", over)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--duration", type=float, default=60.0)
    a = ap.parse_args(argv)
    for n in range(len(ELEMENTS) + 1):
        s = system(n, a.duration)
        c = engine.compile_system(s)
        engine.simulate(s, compiled=c)      # loads (or compiles) the code once
        times = []
        for _ in range(a.repeats):
            t0 = time.perf_counter()
            engine.simulate(s, compiled=c)
            times.append(time.perf_counter() - t0)
        times.sort()
        print(f"{n} eccentric element(s) x 6 orders, {a.duration:g} s of line: "
              f"min {times[0]:.3f} s, median {times[len(times) // 2]:.3f} s")


if __name__ == "__main__":
    main()
