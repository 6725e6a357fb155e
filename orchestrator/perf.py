"""CPU-time real-time factor and profile split of a layout's co-simulation.

    python -m webline.orchestrator.perf scenarios/ewl_out_of_round.yaml [--stop 10] [--step 1ms]
                                [--algorithm gauss-seidel] [--profile] [--set KEY=VALUE]

Prints the CPU time (``time.process_time``: the machine is shared, wall time
is indicative only) of the stepping loop, the real-time factor
simulated / CPU, and with ``--profile`` the cProfile split by function
(cumulative time of the master loop, FMU ``do_step``, integration, output
refresh, get/set).
"""
import argparse
import sys
import time
from pathlib import Path


def run(layout, stop=10.0, step=None, algorithm=None, profile=False, sets=()):
    from webline.fmus.build import build_all
    from webline.orchestrator import master
    from webline.orchestrator.layout import load_system

    overrides = {"experiment.duration": stop}
    if step is not None:
        overrides["experiment.step"] = step
    if algorithm is not None:
        overrides["experiment.algorithm"] = algorithm
    for kv in sets:
        key, _, value = kv.partition("=")
        overrides[key.strip()] = value.strip()
    system = load_system(layout, overrides)
    paths = build_all(log=lambda m: print(m, file=sys.stderr))
    prof = None
    if profile:
        import cProfile
        prof = cProfile.Profile()
    c0, w0 = time.process_time(), time.perf_counter()
    if prof:
        prof.enable()
    result = master.simulate(system, paths, progress=False)
    if prof:
        prof.disable()
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    m = result.meta
    out = {"status": m["status"], "simulated": m["simulated_time"], "cpu": cpu, "wall": wall,
           "loop_wall": m["wall_time"], "setup_wall": m["setup_time"],
           "rtf_cpu": m["simulated_time"] / cpu if cpu > 0 else float("nan"),
           "loop_cpu": m.get("loop_cpu_time", float("nan")), "master_loop": m.get("master_loop", "?"),
           "step": system.experiment.step, "algorithm": system.experiment.algorithm}
    return out, prof


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m webline.orchestrator.perf", description=__doc__.splitlines()[0])
    ap.add_argument("layout", type=Path)
    ap.add_argument("--stop", type=float, default=10.0, help="simulated seconds (default 10)")
    ap.add_argument("--step", type=float, default=None, help="macro step in s (default: the layout's)")
    ap.add_argument("--algorithm", default=None, choices=("jacobi", "gauss-seidel"))
    ap.add_argument("--profile", action="store_true", help="cProfile split (slows the run down)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="layout override, e.g. experiment.output_interval=10ms (repeatable)")
    ap.add_argument("--top", type=int, default=25)
    a = ap.parse_args(argv)
    out, prof = run(a.layout, a.stop, a.step, a.algorithm, a.profile, a.set)
    print(f"{a.layout}: {out['algorithm']} h={out['step'] * 1e3:g} ms, {out['simulated']:g} s simulated, "
          f"status {out['status']}: CPU {out['cpu']:.2f} s (setup wall {out['setup_wall']:.2f} s), "
          f"wall {out['wall']:.2f} s -> real-time factor {out['rtf_cpu']:.2f}x (CPU); stepping loop "
          f"({out['master_loop']}) CPU {out['loop_cpu']:.2f} s -> {out['simulated'] / out['loop_cpu']:.2f}x")
    if prof:
        import pstats
        st = pstats.Stats(prof)
        st.sort_stats("tottime").print_stats(a.top)
    return 0 if out["status"] == "ok" else 1


if __name__ == "__main__":
    sys.exit(main())
