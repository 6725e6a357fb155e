"""Co-simulation error against the monolithic reference (``webline accuracy``).

For each macro step and master algorithm, the line is co-simulated with
:func:`orchestrator.master.simulate` and compared with one dense solution of
the monolithic ODE (:mod:`orchestrator.reference`, same physics models, scipy
LSODA at rtol 1e-8) sampled at the master's output times. The figure of merit
is the relative RMS error of each load-cell reading (components of model
``LoadCell``, output ``T``)::

    rel_rms = sqrt(mean((T_cosim - T_ref)^2)) / sqrt(mean(T_ref^2))

The fast engine (:mod:`orchestrator.engine`, the same ODE compiled and integrated
with fixed-step RK4) is measured the same way and reported as one more row
(``engine``), with its wall time; its error shows what the co-simulation's
costs buy.

Load-cell noise is switched off (``noise_std`` = 0) for the comparison unless
asked otherwise: it is a function of time only, so it would be the same in
both, but it makes the reference ODE needlessly rough wherever it feeds a
controller.
"""
import copy
import math
import time as _time

import numpy as np

DEFAULT_STEPS = (0.5e-3, 1e-3, 2e-3, 5e-3)
DEFAULT_ALGORITHMS = ("jacobi", "gauss-seidel")
LOAD_CELL = "LoadCell"


def load_cells(system):
    """Columns ``<component>.T`` of every LoadCell component, in system order."""
    return [f"{c.name}.T" for c in system.components if c.model == LOAD_CELL]


def relative_rms(x, ref):
    """sqrt(mean((x - ref)^2)) / sqrt(mean(ref^2)); inf if x is not finite everywhere."""
    x, ref = np.asarray(x, dtype=float), np.asarray(ref, dtype=float)
    if x.shape != ref.shape or not np.all(np.isfinite(x)):
        return math.inf
    den = math.sqrt(float(np.mean(ref * ref)))
    num = math.sqrt(float(np.mean((x - ref) ** 2)))
    return num / den if den > 0 else (0.0 if num == 0 else math.inf)


def without_noise(system):
    """Deep copy of ``system`` with every LoadCell's ``noise_std`` set to 0."""
    s = copy.deepcopy(system)
    for c in s.components:
        if c.model == LOAD_CELL:
            c.parameters["noise_std"] = 0.0
    return s


def master_times(experiment, step):
    """Output times of the master for ``experiment`` run at macro step ``step``."""
    from webline.orchestrator.reference import output_times
    return output_times(experiment, step)


def _result_time(result):
    t = getattr(result, "time", None)
    if t is None:
        t = result["time"]
    return np.asarray(t, dtype=float)


def _result_column(result, name):
    return np.asarray(result[name], dtype=float)


def measure(system, steps=DEFAULT_STEPS, algorithms=DEFAULT_ALGORITHMS, columns=None, rtol=1e-8,
            keep_noise=False, simulate=None, log=None, engine=True):
    """Run the co-simulation per (step, algorithm) and compare with the reference.

    ``columns``: compared columns (default: every load-cell tension);
    ``simulate``: the co-simulation function (default ``orchestrator.master.simulate``;
    called as ``simulate(system)`` with ``system.experiment.step``/``algorithm`` set).
    Returns a JSON-ready report: ``{"columns", "reference": {...}, "runs": [{"step",
    "algorithm", "status", "wall_s", "rel_rms": {col: x}, "max_abs": {col: x},
    "worst"}], "engine": {...} (same fields; with ``engine``)}``.
    """
    from webline.orchestrator.reference import solve_reference
    log = log or (lambda *a: None)
    if simulate is None:
        from functools import partial
        from webline.orchestrator.master import simulate as master_simulate
        simulate = partial(master_simulate, progress=False)
    base = system if keep_noise else without_noise(system)
    columns = list(columns) if columns else load_cells(base)
    if not columns:
        raise ValueError("no load cell (component of model LoadCell) in the system; give columns")
    steps = [float(s) for s in steps]
    exp = base.experiment
    ref_system = copy.deepcopy(base)
    ref_system.experiment.stop = max(float(master_times(exp, h)[-1]) for h in steps)
    log(f"reference: {len(base.components)} components, LSODA rtol={rtol:g}, "
        f"{exp.start:g}..{ref_system.experiment.stop:g} s")
    wall = _time.perf_counter()
    solution = solve_reference(ref_system, rtol=rtol)
    ref_info = dict(solution.info, wall_s=_time.perf_counter() - wall)
    log(f"reference done in {ref_info['wall_s']:.1f} s ({ref_info['nfev']} RHS evaluations)")

    engine_run = _measure_engine(ref_system, solution, columns, log) if engine else None

    runs = []
    for h in steps:
        for alg in algorithms:
            s = copy.deepcopy(base)
            s.experiment.step = h
            s.experiment.algorithm = alg
            log(f"co-simulation: step {fmt_step(h)}, {alg}")
            t0 = _time.perf_counter()
            result = simulate(s)
            run = {"step": h, "algorithm": alg, "wall_s": _time.perf_counter() - t0,
                   "status": getattr(result, "status", "ok"), "message": getattr(result, "message", "")}
            t = _result_time(result)
            ref = solution.sample(t)
            run["n_samples"] = int(t.size)
            run["rel_rms"], run["max_abs"] = {}, {}
            for col in columns:
                x = _result_column(result, col)
                r = ref[col][:x.size]
                run["rel_rms"][col] = relative_rms(x, r)
                run["max_abs"][col] = float(np.max(np.abs(x - r))) if np.all(np.isfinite(x)) else math.inf
            if run["status"] != "ok":  # a failed run covers only part of the time
                run["rel_rms"] = {c: math.inf for c in columns}
            run["worst"] = max(run["rel_rms"].values())
            runs.append(run)
    report = {"columns": columns, "steps": steps, "algorithms": list(algorithms),
              "start": exp.start, "stop": exp.stop, "keep_noise": keep_noise,
              "reference": {k: v for k, v in ref_info.items()}, "runs": runs}
    if engine_run is not None:
        report["engine"] = engine_run
    return report


def _measure_engine(system, solution, columns, log):
    """The fast engine's row: error at the experiment's output times, wall time (compile apart)."""
    from webline.orchestrator import engine
    log("fast engine (compiled monolithic ODE, RK4)")
    t0 = _time.perf_counter()
    compiled = engine.compile_system(system)
    compile_s = _time.perf_counter() - t0
    engine.simulate(system, compiled=compiled)  # first call: numba compiles the integrator if not cached
    t0 = _time.perf_counter()
    result = engine.simulate(system, compiled=compiled)
    run = {"step": result.info["h"], "algorithm": "engine", "wall_s": _time.perf_counter() - t0,
           "compile_s": compile_s, "status": result.status, "message": result.message,
           "n_samples": int(result.time.size), "rel_rms": {}, "max_abs": {}}
    ref = solution.sample(result.time)
    for col in columns:
        x, r = _result_column(result, col), ref[col]
        run["rel_rms"][col] = relative_rms(x, r) if result.ok else math.inf
        run["max_abs"][col] = float(np.max(np.abs(x - r))) if np.all(np.isfinite(x)) else math.inf
    run["worst"] = max(run["rel_rms"].values())
    return run


def fmt_step(h):
    """0.0005 -> '0.5 ms'."""
    ms = h * 1e3
    return f"{ms:g} ms" if ms >= 0.01 else f"{h * 1e6:g} us"


def _fmt(x):
    return "diverged" if not math.isfinite(x) else f"{x:.2e}"


def markdown_table(report):
    """One row per (step, algorithm); a column per compared load cell and the worst."""
    cols = report["columns"]
    head = ["step", "algorithm", *[c.removesuffix(".T") for c in cols], "worst", "wall (s)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    for r in report["runs"]:
        cells = [fmt_step(r["step"]), r["algorithm"], *[_fmt(r["rel_rms"][c]) for c in cols],
                 _fmt(r["worst"]), f"{r['wall_s']:.1f}"]
        lines.append("| " + " | ".join(cells) + " |")
    e = report.get("engine")
    if e:
        cells = [fmt_step(e["step"]), "fast engine (RK4)", *[_fmt(e["rel_rms"][c]) for c in cols],
                 _fmt(e["worst"]), f"{e['wall_s']:.3g}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def json_ready(report):
    """The report with inf as the string "inf" (JSON has no infinity)."""
    def fix(v):
        if isinstance(v, float) and not math.isfinite(v):
            return "inf" if v > 0 else ("-inf" if v < 0 else "nan")
        if isinstance(v, dict):
            return {k: fix(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [fix(x) for x in v]
        if isinstance(v, np.generic):
            return v.item()
        return v
    return fix(report)
