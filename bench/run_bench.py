"""webline benchmark (``make bench``): one process, one run, so that ratios hold on a noisy machine.

Measures, in this order, and writes ``bench/results.json`` plus a table on stdout:

1. **rtf** - real-time factor (simulated s / wall s of the master loop) of
   ``scenarios/ewl.yaml`` at its default macro step;
2. **fmu_share** - where the master loop's wall time goes: inside the slaves'
   Python ``do_step`` (``webline.fmi_slave.ElementSlave.do_step`` wrapped with a
   ``perf_counter`` accumulator - pythonfmu slaves run in this interpreter), in
   feed-through output refreshes outside ``do_step`` (getters of outputs that
   depend on inputs), and the rest: master, ctypes/FMI boundary, recording;
3. **scaling** - synthetic lines of 10, 20, 40, 80 path elements (generated
   layout YAML, the EWL's element types and controllers): wall time per
   simulated second and its linearity in the number of elements;
4. **cosim_vs_reference** - co-simulation (default step) against the monolithic
   reference (``orchestrator.reference``, LSODA) at equal accuracy: both are
   compared with a tight reference (rtol 1e-9) by the relative RMS error of the
   load-cell tensions (``orchestrator.accuracy``); the reference's loosest rtol
   that is at least as accurate as the co-simulation is timed;
5. **engine** - the fast engine (``orchestrator.engine``: the monolithic ODE
   compiled with numba, fixed-step RK4) against the co-simulation on
   ``scenarios/ewl_out_of_round.yaml``: wall times (compile apart, from a cold
   cache), error of both against the LSODA reference, a batch of variants;
6. **diagnose** - ``webline diagnose`` of one 60 s run (the out-of-round EWL
   as "measured", diagnosed against the nominal EWL), in a subprocess with a
   time limit; "not available" if the command does not exist.

Each section runs in its own child process (a crash is recorded as that
section's error and the others still run) on a private copy of the built
FMUs. Simulated durations are chosen to keep the whole bench near 10 minutes
on a 2-core machine; ``--quick`` shortens everything (a smoke test of the bench).
No timing is asserted anywhere: the numbers are a record, not a test.
"""
import argparse
import json
import math
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
SCEN = ROOT / "scenarios"
OUT_JSON = ROOT / "bench" / "results.json"
# the full default pipeline (other effects, polish, model-form screen, co-simulation confirm):
# the issue's target is for what a user runs
DIAGNOSE_FLAGS = []


# ---- machine ------------------------------------------------------------------------
def machine_info():
    cpu = platform.processor() or ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    physical = None
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, timeout=10).stdout
        kv = dict(l.split(":", 1) for l in out.splitlines() if ":" in l)
        physical = int(kv["Core(s) per socket"].strip()) * int(kv.get("Socket(s)", "1").strip())
    except Exception:
        pass
    try:
        affinity = len(os.sched_getaffinity(0))
    except AttributeError:
        affinity = os.cpu_count()
    versions = {}
    for mod in ("numpy", "scipy", "fmpy", "pythonfmu"):
        try:
            versions[mod] = __import__(mod).__version__
        except Exception:
            versions[mod] = None
    try:
        commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
                                capture_output=True, text=True, timeout=10).stdout.strip()
    except Exception:
        commit = ""
    try:
        load = os.getloadavg()
    except OSError:
        load = None
    return {"cpu_model": cpu, "logical_cores": os.cpu_count(), "physical_cores": physical,
            "usable_cores": affinity, "python": platform.python_version(),
            "implementation": platform.python_implementation(), "platform": platform.platform(),
            "versions": versions, "git_commit": commit, "load_avg_at_start": load,
            "date": time.strftime("%Y-%m-%dT%H:%M:%S%z")}


# ---- helpers ------------------------------------------------------------------------
def fmus():
    from webline.fmus.build import build_all
    return build_all(log=lambda m: print(f"  {m}", file=sys.stderr))


def run(system, fmu_paths):
    """simulate(); (result, loop wall s, setup wall s, total wall s)."""
    from webline.orchestrator.master import simulate
    t = time.perf_counter()
    r = simulate(system, fmu_paths=fmu_paths, progress=False)
    total = time.perf_counter() - t
    if r.status != "ok":
        raise RuntimeError(f"simulation failed: {r.message[:600]}")
    return r, float(r.meta["wall_time"]), float(r.meta.get("setup_time", math.nan)), total


def n_fmus(system):
    return len(system.components)


# ---- 1 + 2: real-time factor and the share outside do_step ---------------------------
def bench_rtf(fmu_paths, duration):
    from webline.orchestrator.layout import load_system
    system = load_system(SCEN / "ewl.yaml", {"experiment.duration": f"{duration} s"} if duration else None)
    c0 = time.process_time()
    r, loop, setup, total = run(system, fmu_paths)
    cpu = time.process_time() - c0
    sim = float(r.time[-1] - r.time[0])
    return {"scenario": "scenarios/ewl.yaml", "duration_s": sim, "step_s": system.experiment.step,
            "algorithm": system.experiment.algorithm, "n_fmus": n_fmus(system),
            "master_loop": r.meta.get("master_loop"),
            "loop_wall_s": loop, "setup_wall_s": setup, "total_wall_s": total, "cpu_s": cpu,
            "rtf": sim / loop, "rtf_incl_setup": sim / total, "rtf_cpu_incl_setup": sim / cpu,
            "us_per_macro_step": 1e6 * loop / round(sim / system.experiment.step),
            "us_per_fmu_step": 1e6 * loop / round(sim / system.experiment.step) / n_fmus(system)}


class DoStepTimer:
    """Wraps ElementSlave.do_step, get_real/set_real (FMI get/set fast paths) and the
    feed-through output refresh with perf_counter accumulators (the FMUs' Python
    code runs in this interpreter). A refresh inside do_step counts as do_step; one
    triggered by get_real counts as get_real and is also reported on its own."""

    WRAPPED = ("do_step", "get_real", "set_real", "_refresh_outputs")

    def __init__(self):
        import webline.fmi_slave as fs
        self.cls = fs.ElementSlave
        self.orig = {name: self.cls.__dict__[name] for name in self.WRAPPED if name in self.cls.__dict__}
        self.t = dict.fromkeys(self.WRAPPED, 0.0)
        self.n = dict.fromkeys(self.WRAPPED, 0)
        self.depth = 0  # inside do_step or get_real

    def _wrap(self, name):
        pc, timer, orig = time.perf_counter, self, self.orig[name]
        outer = name != "_refresh_outputs"

        def wrapper(slave, *args):
            if not outer and timer.depth and name == "_refresh_outputs" and timer._in_step:
                return orig(slave, *args)
            t = pc()
            if outer:
                timer.depth += 1
                timer._in_step = name == "do_step"
            try:
                return orig(slave, *args)
            finally:
                if outer:
                    timer.depth -= 1
                    timer._in_step = False
                timer.t[name] += pc() - t
                timer.n[name] += 1
        return wrapper

    def __enter__(self):
        self._in_step = False
        for name in self.orig:
            setattr(self.cls, name, self._wrap(name))
        return self

    def __exit__(self, *exc):
        for name, fn in self.orig.items():
            setattr(self.cls, name, fn)


def bench_fmu_share(fmu_paths, duration):
    from webline.orchestrator.layout import load_system
    system = load_system(SCEN / "ewl.yaml", {"experiment.duration": f"{duration} s"})
    with DoStepTimer() as timer:
        r, loop, _, _ = run(system, fmu_paths)
    steps = round(float(r.time[-1] - r.time[0]) / system.experiment.step)
    # multi-rate instances (Component.step_multiple) step once per multiple macro steps
    expected = sum(-(-steps // max(1, getattr(c, "step_multiple", 1))) for c in system.components)
    if timer.n["do_step"] < 0.99 * expected:
        return {"error": f"do_step wrapper saw {timer.n['do_step']} calls, expected {expected}: "
                         "the FMUs do not use this process's webline.fmi_slave"}
    t, n = timer.t, timer.n
    python_fmu = t["do_step"] + t["get_real"] + t["set_real"]
    return {"scenario": "scenarios/ewl.yaml", "duration_s": steps * system.experiment.step,
            "n_fmus": n_fmus(system), "loop_wall_s": loop, "master_loop": r.meta.get("master_loop"),
            "fmi_calls_per_macro_step": {k: n[k] / steps for k in ("do_step", "get_real", "set_real")},
            "do_step_s": t["do_step"], "do_step_calls": n["do_step"],
            "us_per_do_step": 1e6 * t["do_step"] / max(1, n["do_step"]),
            "get_real_s": t["get_real"], "get_real_calls": n["get_real"],
            "set_real_s": t["set_real"], "set_real_calls": n["set_real"],
            "feedthrough_refresh_in_get_s": t["_refresh_outputs"], "refresh_calls": n["_refresh_outputs"],
            "share_in_do_step": t["do_step"] / loop,
            "share_outside_do_step": 1.0 - t["do_step"] / loop,
            "share_in_get_set_python": (t["get_real"] + t["set_real"]) / loop,
            "share_of_which_feedthrough_refresh": t["_refresh_outputs"] / loop,
            "share_outside_fmu_python": 1.0 - python_fmu / loop,
            "note": "timed with wrappers (~0.2 us per call); 'outside FMU Python' is the master loop, "
                    "ctypes and pythonfmu's C layer, and recording"}


# ---- 3: scaling with line length ----------------------------------------------------
def synthetic_layout(n, duration):
    """Layout data of a line with ``n`` path elements built from the EWL's element types:
    unwind, idlers, unwind load-cell roller, S-wrap-like speed master, idlers, rewind
    load-cell roller, rewind; tension loops in the unwind and rewind zones."""
    import yaml
    ewl = yaml.safe_load((SCEN / "ewl.yaml").read_text())
    by_name = {e["name"]: e for e in ewl["path"]}
    if n < 6:
        raise ValueError("a synthetic line needs at least 6 elements")
    idle = {k: v for k, v in by_name["idler_u1"].items() if k != "name"}
    idle["span"] = "0.8 m"
    lc_roller = {k: v for k, v in by_name["roller9"].items() if k != "name"}
    lc_roller["span"] = "0.8 m"
    master = {k: v for k, v in by_name["sw_leader"].items() if k != "name"}
    master["span"] = "0.8 m"
    n_idle = n - 5
    a = n_idle // 2
    path = [dict(by_name["unwind"], span="0.8 m")]
    path += [dict(idle, name=f"idler_a{i + 1}") for i in range(a)]
    path += [dict(lc_roller, name="lc_roller_u"), dict(master, name="master")]
    path += [dict(idle, name=f"idler_b{i + 1}") for i in range(n_idle - a)]
    path += [dict(lc_roller, name="lc_roller_r"), dict(by_name["rewind"])]
    assert len(path) == n
    speed = ewl["drives"]["speed_loops"]
    return {
        "name": f"synthetic_{n}", "description": f"synthetic line of {n} path elements (bench)",
        "units": ewl.get("units", {}), "web": ewl["web"], "path": path,
        "drives": {"master": "master",
                   "speed_loops": {"unwind": speed["unwind"], "master": speed["sw_leader"],
                                   "rewind": speed["rewind"]},
                   "tension_loops": {
                       "unwind_zone": dict(ewl["drives"]["tension_loops"]["unwind_zone"], load_cell="lc_u"),
                       "rewind_zone": dict(ewl["drives"]["tension_loops"]["rewind_zone"], load_cell="lc_r")}},
        "sensors": {"lc_u": dict(ewl["sensors"]["lc9"], roller="lc_roller_u"),
                    "lc_r": dict(ewl["sensors"]["lc19"], roller="lc_roller_r")},
        "experiment": dict(ewl["experiment"], duration=f"{duration} s"),
    }


def bench_scaling(fmu_paths, sizes, duration, workdir, repeats=3):
    """Each size ``repeats`` times, in interleaved order (10, 20, .., 80, 80, .., 10, 10, ..), keeping
    the fastest: load from other processes only ever slows a run down."""
    import yaml
    from webline.orchestrator.layout import load_system
    systems = {}
    for n in sizes:
        path = Path(workdir) / f"synthetic_{n}.yaml"
        path.write_text(yaml.safe_dump(synthetic_layout(n, duration), sort_keys=False))
        systems[n] = load_system(path)
    order = [n for k in range(repeats) for n in (sizes if k % 2 == 0 else sizes[::-1])]
    best = {}
    for n in order:
        system = systems[n]
        r, loop, setup, _ = run(system, fmu_paths)
        sim = float(r.time[-1] - r.time[0])
        print(f"  scaling: {n} elements ({n_fmus(system)} FMUs): {loop / sim:.2f} s wall per simulated s",
              file=sys.stderr)
        walls = best.setdefault(n, {"walls": [], "setup": [], "sim": sim})
        walls["walls"].append(loop)
        walls["setup"].append(setup)
    rows = []
    for n in sizes:
        b, system = best[n], systems[n]
        loop = min(b["walls"])
        rows.append({"elements": n, "n_fmus": n_fmus(system), "n_connections": len(system.connections),
                     "duration_s": b["sim"], "loop_wall_s": loop, "loop_wall_all_s": b["walls"],
                     "setup_wall_s": min(b["setup"]), "wall_per_sim_s": loop / b["sim"], "rtf": b["sim"] / loop,
                     "us_per_fmu_step": 1e6 * loop / round(b["sim"] / system.experiment.step) / n_fmus(system)})
    import numpy as np
    x = np.array([r["elements"] for r in rows], float)
    y = np.array([r["wall_per_sim_s"] for r in rows])
    slope, icpt = np.polyfit(x, y, 1)
    fit = slope * x + icpt
    per = y / x
    return {"rows": rows,
            "linear_fit": {"s_per_element_per_sim_s": float(slope), "intercept_s": float(icpt),
                           "max_rel_residual": float(np.max(np.abs(y - fit) / y))},
            "ratio_largest_to_smallest": float(y[-1] / y[0]),
            "element_ratio": float(x[-1] / x[0]),
            "per_element_cost_ratio": float(per[-1] / per[0]),
            "doubling_ratios": [float(y[i + 1] / y[i]) for i in range(len(y) - 1)],
            "repeats": repeats,
            "note": "fastest of the repeats; linear: doubling ratios near 2 (below 2 while a fixed "
                    "per-step cost still shows)"}


# ---- 4: co-simulation vs monolithic reference at equal accuracy ----------------------
def bench_cosim_vs_reference(fmu_paths, duration, rtols):
    from webline.orchestrator.accuracy import load_cells, relative_rms, without_noise
    from webline.orchestrator.layout import load_system
    from webline.orchestrator.reference import simulate_reference
    system = without_noise(load_system(SCEN / "ewl_out_of_round.yaml",
                                       {"experiment.duration": f"{duration} s"}))
    cols = load_cells(system)
    t = time.perf_counter()
    truth = simulate_reference(system, rtol=1e-9)
    truth_wall = time.perf_counter() - t
    r, loop, setup, total = run(system, fmu_paths)
    n = min(len(r.time), len(truth.time))

    def err(res):
        return max(relative_rms(res[c][:n], truth[c][:n]) for c in cols)
    e_cs = err(r)
    refs = []
    for rtol in rtols:
        t = time.perf_counter()
        try:
            ref = simulate_reference(system, rtol=rtol)
            wall = time.perf_counter() - t
            refs.append({"rtol": rtol, "wall_s": wall, "rel_rms_error": err(ref),
                         "nfev": ref.info.get("nfev")})
        except Exception as exc:
            refs.append({"rtol": rtol, "error": f"{type(exc).__name__}: {exc}"[:300]})
    ok = [x for x in refs if "wall_s" in x and x["rel_rms_error"] <= e_cs]
    match = max(ok, key=lambda x: x["rtol"]) if ok else None
    out = {"scenario": "scenarios/ewl_out_of_round.yaml (load-cell noise off)", "duration_s": duration,
           "truth": {"rtol": 1e-9, "wall_s": truth_wall},
           "cosim": {"step_s": system.experiment.step, "algorithm": system.experiment.algorithm,
                     "loop_wall_s": loop, "total_wall_s": total, "rel_rms_error": e_cs},
           "reference_sweep": refs,
           "metric": "max over load cells of RMS(T - T_truth)/RMS(T_truth)"}
    if match:
        out["reference_at_equal_accuracy"] = match
        out["cosim_total_over_reference_wall"] = total / match["wall_s"]
    else:
        out["reference_at_equal_accuracy"] = None
        out["note"] = "no reference rtol in the sweep was as accurate as the co-simulation"
    return out


# ---- 1b: the fastest macro step that keeps the error below the target -------------------
ERROR_TARGET = 5e-3  # relative RMS of every load-cell tension against the reference (issue #5)


def bench_step_sweep(fmu_paths, duration, steps, repeats=2):
    """Real-time factor and error at several macro steps, on one scenario in one process:
    the target is "2x real time at a step that keeps the error below 0.5 %", so both are
    measured on the same runs. Each system is built at its own step (the FMUs' RK4
    sub-step is the macro step, as a user running ``--step`` gets); steps interleaved
    ``repeats`` times, the fastest loop kept (others' load only slows a run down)."""
    import numpy as np
    from webline.orchestrator.accuracy import load_cells, relative_rms, without_noise
    from webline.orchestrator.layout import load_system
    from webline.orchestrator.reference import solve_reference
    over = {"experiment.duration": f"{duration} s"}
    base = without_noise(load_system(SCEN / "ewl_out_of_round.yaml", over))
    cols = load_cells(base)
    truth = solve_reference(base, rtol=1e-9)  # dense: sampled where each run recorded
    sampled = {}
    rows = {h: {"step_s": h, "loop_wall_all_s": []} for h in steps}
    for _ in range(repeats):
        for h in steps:
            system = without_noise(load_system(SCEN / "ewl_out_of_round.yaml",
                                               {**over, "experiment.step": f"{h} s"}))
            try:
                r, loop, setup, total = run(system, fmu_paths)
            except RuntimeError as exc:
                rows[h]["error"] = str(exc)[:300]
                continue
            keep = np.asarray(r.time) <= duration + 1e-9  # a step not dividing the duration overshoots it
            if h not in sampled:
                sampled[h] = truth.sample(np.asarray(r.time)[keep])
            ref = sampled[h]
            e = max(relative_rms(np.asarray(r[c])[keep], ref[c]) for c in cols)
            rows[h].update({"rel_rms_error": e, "n_fmus": n_fmus(system), "simulated_s": float(r.time[-1] - r.time[0])})
            rows[h]["loop_wall_all_s"].append(loop)
    out = []
    for h in steps:
        row = rows[h]
        if row["loop_wall_all_s"]:
            row["loop_wall_s"] = min(row["loop_wall_all_s"])
            row["rtf"] = row["simulated_s"] / row["loop_wall_s"]
        out.append(row)
    good = [x for x in out if "rtf" in x and x["rel_rms_error"] < ERROR_TARGET]
    best = max(good, key=lambda x: x["rtf"]) if good else None
    return {"scenario": "scenarios/ewl_out_of_round.yaml (load-cell noise off)", "duration_s": duration,
            "algorithm": base.experiment.algorithm, "error_target": ERROR_TARGET, "rows": out,
            "fastest_within_target": best,
            "metric": "max over load cells of RMS(T - T_truth)/RMS(T_truth); rtf = simulated s / loop wall s"}


# ---- 5: the fast engine against the co-simulation ------------------------------------
def bench_engine(fmu_paths, durations, repeats=3, batch=4):
    """Fast engine vs co-simulation on the out-of-round EWL (noise off), per duration:
    engine wall (fastest of ``repeats``; compile measured apart, from an empty cache), the
    co-simulation's total wall (setup included, as a user waits for it), both errors
    against the LSODA reference (rtol 1e-8); and a batch of ``batch`` variants (span
    stiffness scaled) against as many single runs."""
    import copy
    import numpy as np
    os.environ["WEBLINE_ENGINE_CACHE"] = tempfile.mkdtemp(prefix="webline_engine_cache_")
    from webline.orchestrator import engine
    from webline.orchestrator.accuracy import load_cells, relative_rms, without_noise
    from webline.orchestrator.layout import load_system
    from webline.orchestrator.reference import simulate_reference

    def system(duration):
        return without_noise(load_system(SCEN / "ewl_out_of_round.yaml", {"experiment.duration": f"{duration} s"}))

    s0 = system(0.05)
    t = time.perf_counter()
    compiled = engine.compile_system(s0)
    engine.simulate(s0, compiled=compiled)  # numba compiles the generated code at the first call
    compile_s = time.perf_counter() - t
    rows = []
    for duration in durations:
        s = system(duration)
        cols = load_cells(s)
        c = engine.compile_system(s)
        walls = []
        for _ in range(repeats):
            t = time.perf_counter()
            res = engine.simulate(s, compiled=c)
            walls.append(time.perf_counter() - t)
        t = time.perf_counter()
        ref = simulate_reference(s)
        ref_wall = time.perf_counter() - t
        cs, loop, setup, total = run(s, fmu_paths)
        e_ref = max(relative_rms(res[col], ref[col]) for col in cols)
        cs_ref = max(relative_rms(cs[col], ref[col]) for col in cols)
        n = min(len(cs.time), len(res.time))
        e_cs = max(relative_rms(res[col][:n], cs[col][:n]) for col in cols)
        rows.append({"duration_s": duration, "engine_wall_s": min(walls), "engine_step_s": res.info["h"],
                     "engine_setup_s": c.setup_s, "cosim_total_wall_s": total, "cosim_loop_wall_s": loop,
                     "reference_wall_s": ref_wall, "engine_rel_rms_vs_reference": e_ref,
                     "cosim_rel_rms_vs_reference": cs_ref, "engine_rel_rms_vs_cosim": e_cs,
                     "speedup_vs_cosim": total / min(walls),
                     "speedup_vs_cosim_incl_setup": total / (min(walls) + c.setup_s),
                     "speedup_vs_reference": ref_wall / min(walls)})
    # batch of variants of one structure
    d = durations[0]
    base = system(d)
    variants = []
    for k in range(batch):
        v = copy.deepcopy(base)
        for comp in v.components:
            if comp.model == "Span":
                comp.parameters["EA"] = comp.parameters["EA"] * (1.0 + 0.05 * k)
        variants.append(v)
    comps = [engine.compile_system(v) for v in variants]
    engine.simulate_batch(variants[:2], compiled=comps[:2])  # compile the parallel loop
    t = time.perf_counter()
    engine.simulate_batch(variants, compiled=comps)
    batch_wall = time.perf_counter() - t
    t = time.perf_counter()
    for v, c in zip(variants, comps):
        engine.simulate(v, compiled=c)
    singles_wall = time.perf_counter() - t
    return {"scenario": "scenarios/ewl_out_of_round.yaml (load-cell noise off)",
            "compile_cold_s": compile_s, "n_states": int(compiled.x0.size), "rows": rows,
            "batch": {"duration_s": d, "variants": batch, "batch_wall_s": batch_wall,
                      "singles_wall_s": singles_wall, "threads": os.cpu_count()},
            "metric": "max over load cells of RMS(T - T_ref)/RMS(T_ref); speedup = co-sim total wall / "
                      "engine wall (compile apart: once per structure, cached on disk)"}


# ---- 6: webline diagnose on one 60 s run ----------------------------------------------
def bench_diagnose(fmu_paths, duration, timeout, workdir):
    from webline.cli import COMMANDS
    if "diagnose" not in COMMANDS:
        return {"status": "not available", "reason": "no 'webline diagnose' command in webline/cli.py"}
    import numpy as np
    from webline.orchestrator.layout import load_system
    work = Path(workdir) / "diagnose"
    work.mkdir(parents=True, exist_ok=True)
    # the "measured" run: the out-of-round EWL co-simulated, recorded every 2 ms (500 Hz)
    system = load_system(SCEN / "ewl_out_of_round.yaml",
                         {"experiment.duration": f"{duration} s", "experiment.output_interval": "2 ms"})
    t = time.perf_counter()
    r, loop, _, _ = run(system, fmu_paths)
    gen_wall = time.perf_counter() - t
    cols = [c for c in r.columns if c.startswith("lc") and c.endswith(".T")]
    with open(work / "measured.csv", "w") as f:
        f.write("time [s]," + ",".join(f"{c} [N]" for c in cols) + "\n")
        data = np.column_stack([r.time] + [r[c] for c in cols])
        np.savetxt(f, data, delimiter=",", fmt="%.9g")
    (work / "run.yaml").write_text(
        "data: measured.csv\nname: ewl_out_of_round_60s\n"
        f"experiment:\n  line_speed: 200 ft/min\n  duration: {duration} s\n")
    # the lighter pipeline (no screening of backlash/compliance/sensor effects, no
    # Gauss-Newton polish); its model runs use the fast engine (diagnose --engine fast, the default)
    cmd = [sys.executable, "-m", "webline.cli", "diagnose", str(SCEN / "ewl.yaml"), str(work / "run.yaml"),
           "--out", str(work / "report"), *DIAGNOSE_FLAGS]
    t = time.perf_counter()
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, cwd=ROOT)
    except subprocess.TimeoutExpired as exc:
        err = exc.stderr.decode(errors="replace") if isinstance(exc.stderr, bytes) else (exc.stderr or "")
        return {"status": f"timed out after {timeout:.0f} s (bench budget)", "data_generation_wall_s": gen_wall,
                "run_duration_s": duration, "command": " ".join(cmd[2:]),
                "log_tail": err.strip().splitlines()[-8:]}
    wall = time.perf_counter() - t
    out = {"status": "ok" if p.returncode == 0 else f"exit {p.returncode}", "wall_s": wall,
           "run_duration_s": duration, "data_generation_wall_s": gen_wall,
           "verdict": p.stdout.strip().splitlines()[0][:300] if p.stdout.strip() else "",
           "command": " ".join(cmd[2:])}
    if p.returncode != 0:
        out["stderr_tail"] = p.stderr[-600:]
    return out


# ---- report -------------------------------------------------------------------------
def _f(x, fmt="{:.3g}"):
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else fmt.format(x)


def _section(res, key, label, add):
    """A section's results for the table, or None after a line saying it was skipped or failed."""
    x = res.get(key, {})
    if x.get("status") == "skipped":
        add(f"{key}: skipped")
        return None
    if "error" in x:
        add(f"{label}: ERROR {x['error']}")
        return None
    return x or None


def table(res):
    m = res["machine"]
    lines = [f"webline bench  {m['date']}  commit {m['git_commit']}",
             f"machine: {m['cpu_model']}, {m['logical_cores']} logical / {m['physical_cores']} physical cores, "
             f"Python {m['python']}", ""]
    add = lines.append
    r = _section(res, "rtf", "real-time factor", add)
    if r:
        add(f"real-time factor, ewl.yaml ({r['n_fmus']} FMUs, step {r['step_s'] * 1e3:g} ms, {r['algorithm']}, "
            f"{r['duration_s']:g} s): {r['rtf']:.3f}  ({r['us_per_macro_step']:.0f} us/macro step, "
            f"{r['us_per_fmu_step']:.1f} us per FMU step; setup {r['setup_wall_s']:.2f} s; "
            f"{r.get('master_loop', '?')} master loop; by CPU time incl. setup "
            f"{r.get('rtf_cpu_incl_setup', float('nan')):.2f})")
    s = _section(res, "fmu_share", "share outside do_step", add)
    if s:
        add(f"outside the FMUs' do_step: {100 * s['share_outside_do_step']:.1f} % of the master loop "
            f"({s['us_per_do_step']:.1f} us per do_step)")
        add(f"   loop split: do_step {100 * s['share_in_do_step']:.1f} %, FMI get/set in the slaves' Python "
            f"{100 * s['share_in_get_set_python']:.1f} % (feed-through refresh "
            f"{100 * s['share_of_which_feedthrough_refresh']:.1f} %), master ({s.get('master_loop', '?')} loop) "
            f"+ pythonfmu C + recording {100 * s['share_outside_fmu_python']:.1f} %")
        c = s.get("fmi_calls_per_macro_step")
        if c:
            add(f"   FMI calls per macro step: {c['do_step']:.1f} doStep, {c['set_real']:.1f} setReal, "
                f"{c['get_real']:.1f} getReal")
    st = _section(res, "step_sweep", "step sweep", add)
    if st:
        add("")
        add(f"macro step vs error and speed ({st['duration_s']:g} s of ewl_out_of_round, {st['algorithm']}, "
            f"error target {100 * st['error_target']:g} %):")
        for x in st["rows"]:
            if "rtf" in x:
                add(f"   {x['step_s'] * 1e3:g} ms: error {_f(x['rel_rms_error'])}, real-time factor {x['rtf']:.2f}")
            else:
                add(f"   {x['step_s'] * 1e3:g} ms: {x.get('error', 'no run')}")
        b = st.get("fastest_within_target")
        add(f"   fastest within the target: {b['step_s'] * 1e3:g} ms, {b['rtf']:.2f}x real time" if b
            else "   no step within the target")
    sc = _section(res, "scaling", "scaling", add)
    if sc:
        add("")
        add(f"{'elements':>8} {'FMUs':>5} {'wall s / sim s':>15} {'RTF':>7} {'us/FMU step':>12}")
        for row in sc["rows"]:
            add(f"{row['elements']:>8} {row['n_fmus']:>5} {row['wall_per_sim_s']:>15.3f} {row['rtf']:>7.3f} "
                f"{row.get('us_per_fmu_step', math.nan):>12.1f}")
        lf = sc["linear_fit"]
        add(f"linearity: {sc['element_ratio']:.0f}x elements -> {sc['ratio_largest_to_smallest']:.2f}x time; "
            f"doubling ratios {', '.join(f'{x:.2f}' for x in sc['doubling_ratios'])}; fit "
            f"{lf['s_per_element_per_sim_s'] * 1e3:.1f} ms/element + {lf['intercept_s'] * 1e3:.0f} ms per sim s, "
            f"max residual {100 * lf['max_rel_residual']:.1f} %")
    c = _section(res, "cosim_vs_reference", "co-sim vs reference", add)
    if c:
        add("")
        cs = c["cosim"]
        add(f"co-sim vs monolithic reference ({c['duration_s']:g} s of ewl_out_of_round): co-sim "
            f"{cs['total_wall_s']:.2f} s wall (loop {cs['loop_wall_s']:.2f} s), rel. RMS error {_f(cs['rel_rms_error'])}")
        for x in c["reference_sweep"]:
            if "wall_s" in x:
                add(f"   reference rtol {x['rtol']:.0e}: {x['wall_s']:.2f} s, rel. RMS error {_f(x['rel_rms_error'])}")
            else:
                add(f"   reference rtol {x['rtol']:.0e}: {x['error']}")
        m_ = c.get("reference_at_equal_accuracy")
        if m_:
            add(f"   equal accuracy: reference rtol {m_['rtol']:.0e} in {m_['wall_s']:.2f} s; "
                f"co-sim/reference wall = {c['cosim_total_over_reference_wall']:.2f}")
        else:
            add(f"   {c.get('note', '')}")
    en = _section(res, "engine", "fast engine", add)
    if en:
        add("")
        add(f"fast engine vs co-simulation ({en['scenario']}; compile from a cold cache "
            f"{en['compile_cold_s']:.1f} s, {en['n_states']} states):")
        for x in en["rows"]:
            add(f"   {x['duration_s']:g} s: engine {x['engine_wall_s']:.3f} s (RK4 h {x['engine_step_s'] * 1e3:g} ms), "
                f"co-sim {x['cosim_total_wall_s']:.1f} s -> {x['speedup_vs_cosim']:.0f}x; reference LSODA "
                f"{x['reference_wall_s']:.1f} s; error vs reference: engine {_f(x['engine_rel_rms_vs_reference'])}, "
                f"co-sim {_f(x['cosim_rel_rms_vs_reference'])}")
        b = en["batch"]
        add(f"   batch of {b['variants']} variants ({b['duration_s']:g} s): {b['batch_wall_s']:.3f} s vs "
            f"{b['singles_wall_s']:.3f} s one by one")
    d = res.get("diagnose", {})
    if d:
        add("")
        if d.get("status") == "ok":
            add(f"webline diagnose, one {d['run_duration_s']:g} s run: {d['wall_s']:.1f} s wall "
                f"(+ {d['data_generation_wall_s']:.1f} s to simulate the 'measured' run); {d.get('verdict', '')}")
        else:
            add(f"webline diagnose: {d.get('status')} {d.get('reason', '')}{d.get('error', '')}")
            if d.get("log_tail"):
                add("   last log lines: " + " | ".join(d["log_tail"][-3:])[:400])
    add("")
    add(f"bench wall time: {res['bench_wall_s']:.0f} s")
    return "\n".join(lines)


SECTIONS = ("rtf", "fmu_share", "step_sweep", "scaling", "cosim_vs_reference", "engine", "diagnose")


def run_section(name, cfg, paths, work):
    """One section, in this process."""
    if name == "rtf":
        return bench_rtf(paths, cfg["rtf_duration"])
    if name == "fmu_share":
        return bench_fmu_share(paths, cfg["share_duration"])
    if name == "step_sweep":
        return bench_step_sweep(paths, cfg["step_sweep_duration"], cfg["step_sweep_steps"])
    if name == "scaling":
        return bench_scaling(paths, cfg["scaling_sizes"], cfg["scaling_duration"], work, cfg["scaling_repeats"])
    if name == "cosim_vs_reference":
        return bench_cosim_vs_reference(paths, cfg["compare_duration"], cfg["compare_rtols"])
    if name == "engine":
        return bench_engine(paths, cfg["engine_durations"])
    if name == "diagnose":
        return bench_diagnose(paths, cfg["diagnose_duration"], cfg["diagnose_timeout"], work)
    raise KeyError(name)


def section_child(argv):
    """``run_bench.py --section NAME CONFIG.json RESULT.json``: one section in a child process."""
    import faulthandler
    faulthandler.enable()
    name, cfg_path, out_path = argv
    job = json.loads(Path(cfg_path).read_text())
    paths = {k: Path(v) for k, v in job["fmu_paths"].items()}
    res = run_section(name, job["cfg"], paths, job["work"])
    Path(out_path).write_text(json.dumps(res, default=float))
    return 0


def snapshot_fmus(work):
    """Copy the built FMUs into the bench's folder: a rebuild by someone else during the
    bench cannot change (or truncate) what is being measured."""
    import shutil
    from webline.fmus.build import source_hash
    built = fmus()
    dst = Path(work) / "fmus"
    dst.mkdir()
    return {k: Path(shutil.copy2(v, dst / Path(v).name)) for k, v in built.items()}, source_hash()


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--section"]:
        return section_child(argv[1:])
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="short runs only (smoke test of the bench)")
    ap.add_argument("--out", type=Path, default=OUT_JSON, help=f"results file (default {OUT_JSON})")
    ap.add_argument("--skip", nargs="*", default=[], choices=SECTIONS)
    ap.add_argument("--only", nargs="*", default=[], choices=SECTIONS,
                    help="run only these sections and update them in the existing results file")
    ap.add_argument("--diagnose-timeout", type=float, default=None, help="s (default: what is left of 10 min, >= 60 s)")
    args = ap.parse_args(argv)
    q = args.quick
    cfg = {"rtf_duration": 0.5 if q else None,  # None: the scenario's own duration
           "share_duration": 0.3 if q else 5.0,
           "step_sweep_duration": 0.4 if q else 10.0,
           "step_sweep_steps": [2e-3, 4e-3] if q else [2e-3, 3e-3, 4e-3, 5e-3],
           "scaling_sizes": [10, 20] if q else [10, 20, 40, 80], "scaling_duration": 0.2 if q else 2.0,
           "scaling_repeats": 2 if q else 3, "compare_duration": 0.3 if q else 5.0,
           "compare_rtols": [1e-3, 1e-5] if q else [1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8],
           "engine_durations": [0.5] if q else [10.0, 75.0],
           "diagnose_duration": 60.0, "budget_s": 600.0, "section_timeout_s": 900.0}
    t0 = time.perf_counter()
    res = {"machine": machine_info(), "config": cfg}
    print(f"bench on {res['machine']['cpu_model']} ({res['machine']['logical_cores']} cores), "
          f"Python {res['machine']['python']}", file=sys.stderr)
    with tempfile.TemporaryDirectory(prefix="webline_bench_") as work:
        paths, fmu_hash = snapshot_fmus(work)
        res["fmu_source_hash"] = fmu_hash
        for name in SECTIONS:
            if args.only and name not in args.only:
                continue
            if name in args.skip or (q and name == "diagnose"):
                res[name] = {"status": "skipped"}
                continue
            print(f"bench: {name} ...", file=sys.stderr)
            if name == "diagnose":
                cfg["diagnose_timeout"] = args.diagnose_timeout or max(
                    60.0, cfg["budget_s"] - (time.perf_counter() - t0))
            # each section in its own process: a crash in one (an FMU or the
            # master dying) is recorded and the others still run
            job, out = Path(work) / f"{name}.json", Path(work) / f"{name}.result.json"
            job.write_text(json.dumps({"cfg": cfg, "work": work,
                                       "fmu_paths": {k: str(v) for k, v in paths.items()}}))
            t = time.perf_counter()
            try:
                p = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--section", name,
                                    str(job), str(out)], cwd=ROOT, timeout=cfg["section_timeout_s"]
                                   + cfg.get("diagnose_timeout", 0.0) * (name == "diagnose"))
                if p.returncode == 0 and out.exists():
                    res[name] = json.loads(out.read_text())
                elif p.returncode < 0:
                    res[name] = {"error": f"section process killed by signal {-p.returncode} "
                                          "(a crash: see the fault handler's traceback above)"}
                else:
                    res[name] = {"error": f"section process exited with {p.returncode} (traceback above)"}
            except subprocess.TimeoutExpired:
                res[name] = {"error": f"section timed out after {cfg['section_timeout_s']:.0f} s"}
            res[name]["bench_section_wall_s"] = time.perf_counter() - t
    res["bench_wall_s"] = time.perf_counter() - t0
    if args.only:
        # update the listed sections of the previous results; say when and where they came from
        old = json.loads(args.out.read_text()) if args.out.exists() else {}
        note = {"sections": list(args.only), "machine": res["machine"], "wall_s": res["bench_wall_s"]}
        for name in args.only:
            old[name] = res.get(name, {"status": "skipped"})
            old[name]["updated"] = {k: note["machine"].get(k) for k in ("date", "git_commit")}
        old.setdefault("partial_updates", []).append(note)
        old.setdefault("machine", res["machine"])
        old.setdefault("bench_wall_s", res["bench_wall_s"])
        res = old
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(res, indent=1, default=float))
    os.replace(tmp, args.out)
    print(table(res))
    print(f"\n-> {args.out}")
    return 0 if not any("error" in res.get(n, {}) for n in SECTIONS) else 1


if __name__ == "__main__":
    sys.exit(main())
