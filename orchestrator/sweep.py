"""Parameter sweeps of a line: many runs of one layout with different overrides.

A sweep file (YAML) names a layout and the runs to make of it::

    name: unwind_radius_speed          # optional; default: the file's stem
    layout: ewl.yaml                   # relative to the sweep file
    set:                               # overrides applied to every run
      experiment.duration: 30 s
      unwind.eccentricity: {C: [0.6 mm]}   # mappings/lists are passed as YAML text
    grid:                              # cartesian product, in file order
      unwind.radius: [4.75 in, 5.75 in, 6.75 in]
      experiment.line_speed: {start: 100 ft/min, stop: 300 ft/min, num: 3}
    # or instead of grid:
    monte_carlo:
      n: 20
      seed: 1
      unwind.radius: {dist: uniform, low: 4.75 in, high: 6.75 in}
      experiment.line_speed: {dist: normal, mean: 200 ft/min, std: 10 ft/min}
    metrics:                           # optional
      steady_start: 10 s               # default: the second half of the run
      steady_stop: 30 s                # default: the end of the run
      f_min: 0.2 Hz                    # lowest frequency searched for a dominant peak
      f_max: 50 Hz
    plot: {...}                        # optional, see orchestrator.sweep_plot

Keys of ``set``, ``grid`` and ``monte_carlo`` are the dotted keys of
``orchestrator.layout.load_system(path, overrides)``; values keep their
unit strings (they are handed to the layout as written) and are also
converted to SI for the results table.

Each run is one process (a spawned worker of a local process pool, or a
subprocess started by a Dask worker) and writes its own folder
``runs/<key>/`` with ``results.h5`` and ``summary.json``. ``key`` is a hash
of the layout file's text and the run's overrides: a run whose folder holds a
summary with that key is finished and is not run again (``force`` re-runs
everything, ``retry_failed`` re-runs failed runs). A run that fails or
crashes is recorded with its error; it does not stop the sweep. All
summaries gather into ``sweep.csv``: one row per run.
"""
import hashlib
import itertools
import json
import math
import os
import re
import subprocess
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

SUMMARY = "summary.json"
TABLE = "sweep.csv"
FIXED_COLUMNS = ("run_id", "key", "status", "error", "wall_time", "sim_time", "rtf", "run_dir")


class SweepError(ValueError):
    """An invalid sweep file: names the file and the field."""

    def __init__(self, path, field, message):
        self.path, self.field, self.message = str(path), field, message
        super().__init__(f"{path}: {field}: {message}" if field else f"{path}: {message}")


# ---- values and units --------------------------------------------------------------
_UREG = None


def _ureg():
    """The layout's unit registry (orchestrator.units: fpm, PLI, mil as thou...)."""
    global _UREG
    if _UREG is None:
        try:
            from webline.orchestrator.units import ureg
            _UREG = ureg
        except ImportError:
            import pint
            _UREG = pint.UnitRegistry()
    return _UREG


def _parse(text):
    try:
        from webline.orchestrator.units import parse
    except ImportError:
        return _ureg().Quantity(text)
    return parse(text)


def quantity(text):
    """pint Quantity of a number or a ``"<number> <unit>"`` string; ValueError if it is not one."""
    if isinstance(text, bool):
        raise ValueError(f"{text!r} is not a quantity")
    if isinstance(text, (int, float)):
        return _ureg().Quantity(float(text))
    try:
        q = _parse(str(text))
    except Exception as exc:
        raise ValueError(f"{text!r} is not a number with a unit ({exc})") from None
    if not isinstance(q.magnitude, (int, float)):
        raise ValueError(f"{text!r} is not a scalar quantity")
    return q


def to_si(text):
    """SI value (float) of a number or a number with a unit, or None if it is not a quantity."""
    try:
        q = quantity(text)
    except ValueError:
        return None
    return float(q.to_base_units().magnitude)


def as_text(value):
    """The override string for a YAML value: strings unchanged, numbers as written,
    mappings and lists as one-line YAML (the layout reads an override string as YAML)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, (dict, list)):
        import yaml
        return yaml.safe_dump(value, default_flow_style=True, width=10 ** 6).strip()
    return str(value)


def _fmt(magnitude, unit):
    text = f"{magnitude:.10g}"
    return f"{text} {unit}" if unit else text


_NUMBER = re.compile(r"^\s*[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")


def _unit_text(value):
    """The unit of ``value`` as written ("100 ft/min" -> "ft/min"; a plain number -> "")."""
    if isinstance(value, (int, float)):
        return ""
    m = _NUMBER.match(str(value))
    return str(value)[m.end():].strip() if m else ""


# ---- the sweep file -----------------------------------------------------------------
@dataclass
class Run:
    """One run of a sweep: its overrides (swept and fixed), the swept values and its key."""
    index: int
    swept: dict              # dotted key -> value string, as handed to the layout
    overrides: dict          # fixed ``set`` overrides + swept ones
    key: str = ""

    @property
    def run_id(self):
        return f"r{self.index:04d}"

    def si(self):
        return {k: to_si(v) for k, v in self.swept.items()}


@dataclass
class Metrics:
    steady_start: float | None = None  # s; None: the middle of the record
    steady_stop: float | None = None   # s; None: the end
    f_min: float = 0.2                 # Hz
    f_max: float | None = None         # Hz

    def as_dict(self):
        return dict(self.__dict__)


@dataclass
class Sweep:
    path: Path
    name: str
    layout: Path
    mode: str                # "grid" or "monte_carlo"
    fixed: dict
    parameters: list         # swept dotted keys, in order
    runs: list
    metrics: Metrics = field(default_factory=Metrics)
    plot: dict | None = None


def _grid_values(path, key, spec):
    where = f"grid.{key}"
    if isinstance(spec, dict):
        missing = {"start", "stop", "num"} - set(spec)
        extra = set(spec) - {"start", "stop", "num"}
        if missing or extra:
            raise SweepError(path, where, "a range needs exactly start, stop and num"
                             + (f" (missing {sorted(missing)})" if missing else "")
                             + (f" (unknown {sorted(extra)})" if extra else ""))
        num = spec["num"]
        if not isinstance(num, int) or isinstance(num, bool) or num < 1:
            raise SweepError(path, f"{where}.num", f"must be a positive integer (got {num!r})")
        try:
            a, b = quantity(spec["start"]), quantity(spec["stop"])
            b = b.to(a.units)
        except Exception as exc:
            raise SweepError(path, where, f"start/stop: {exc}") from None
        unit = _unit_text(spec["start"])
        if num == 1:
            return [_fmt(a.magnitude, unit)]
        step = (b.magnitude - a.magnitude) / (num - 1)
        return [_fmt(a.magnitude + i * step, unit) for i in range(num)]
    if isinstance(spec, list):
        if not spec:
            raise SweepError(path, where, "empty list of values")
        if any(v is None for v in spec):
            raise SweepError(path, where, "a value is empty (null)")
        return [as_text(v) for v in spec]
    raise SweepError(path, where, "must be a list of values or {start, stop, num}")


def _sampler(path, key, spec):
    """A function rng -> override string for one Monte Carlo parameter."""
    where = f"monte_carlo.{key}"
    if not isinstance(spec, dict) or "dist" not in spec:
        raise SweepError(path, where, "must be {dist: uniform, low, high} or {dist: normal, mean, std[, min, max]}")
    dist = spec["dist"]
    fields = {"uniform": ({"low", "high"}, set()), "normal": ({"mean", "std"}, {"min", "max"})}
    if dist not in fields:
        raise SweepError(path, f"{where}.dist", f"unknown distribution {dist!r} (uniform or normal)")
    need, optional = fields[dist]
    missing, extra = need - set(spec), set(spec) - need - optional - {"dist"}
    if missing:
        raise SweepError(path, where, f"{dist} needs {sorted(need)} (missing {sorted(missing)})")
    if extra:
        raise SweepError(path, where, f"unknown field(s) {sorted(extra)} for {dist}")
    first = "low" if dist == "uniform" else "mean"
    try:
        base = quantity(spec[first])
    except ValueError as exc:
        raise SweepError(path, f"{where}.{first}", str(exc)) from None
    unit = _unit_text(spec[first])
    mags = {first: float(base.magnitude)}
    for name in spec:
        if name in ("dist", first):
            continue
        try:
            mags[name] = float(quantity(spec[name]).to(base.units).magnitude)
        except Exception as exc:
            raise SweepError(path, f"{where}.{name}", f"{exc} (must be in units compatible with {first})") from None
    if dist == "uniform":
        lo, hi = mags["low"], mags["high"]
        if not hi >= lo:
            raise SweepError(path, where, f"high must be >= low (got {spec['low']!r}, {spec['high']!r})")
        return lambda rng: _fmt(rng.uniform(lo, hi), unit)
    mean, std = mags["mean"], mags["std"]
    lo, hi = mags.get("min", -math.inf), mags.get("max", math.inf)
    if not std >= 0:
        raise SweepError(path, f"{where}.std", f"must be >= 0 (got {spec['std']!r})")
    if not lo <= mean <= hi:
        raise SweepError(path, where, "mean must lie between min and max")

    def draw(rng):
        for _ in range(10000):  # truncation by rejection
            x = rng.normal(mean, std)
            if lo <= x <= hi:
                return _fmt(x, unit)
        raise RuntimeError(f"{where}: could not draw a value inside [min, max]")
    return draw


def _dotted(path, section, key):
    if not isinstance(key, str) or "." not in key or any(not p for p in key.split(".")):
        raise SweepError(path, f"{section}.{key}", "keys must be dotted layout keys such as 'experiment.line_speed'")


def _time(path, where, value, dim="[time]"):
    try:
        q = quantity(value)
        if q.dimensionless and dim == "[time]":
            q = q * _ureg().second
        if dim == "[frequency]" and q.dimensionless:
            q = q * _ureg().hertz
        return float(q.to("s" if dim == "[time]" else "Hz").magnitude)
    except Exception as exc:
        raise SweepError(path, where, f"{exc}") from None


def load_sweep(path):
    """Read and validate a sweep file; returns a :class:`Sweep` (raises :class:`SweepError`)."""
    import yaml
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise SweepError(path, "", f"cannot read: {exc.strerror or exc}") from None
    except yaml.YAMLError as exc:
        raise SweepError(path, "", f"not valid YAML: {exc}") from None
    if not isinstance(data, dict):
        raise SweepError(path, "", "must be a mapping with 'layout' and 'grid' or 'monte_carlo'")
    known = {"name", "description", "layout", "set", "grid", "monte_carlo", "metrics", "plot"}
    extra = set(data) - known
    if extra:
        raise SweepError(path, sorted(extra)[0], f"unknown field (known: {', '.join(sorted(known))})")
    if "layout" not in data or not isinstance(data["layout"], str):
        raise SweepError(path, "layout", "required: path of the layout YAML, relative to the sweep file")
    layout = (path.parent / data["layout"]).resolve()
    if not layout.is_file():
        raise SweepError(path, "layout", f"no such file {layout}")
    name = data.get("name", path.stem)
    if not isinstance(name, str) or not name or "/" in name:
        raise SweepError(path, "name", f"must be a plain name (got {name!r})")

    fixed = data.get("set") or {}
    if not isinstance(fixed, dict):
        raise SweepError(path, "set", "must be a mapping dotted key -> value")
    for k, v in fixed.items():
        _dotted(path, "set", k)
        if v is None:
            raise SweepError(path, f"set.{k}", "empty value (null)")
    fixed = {k: as_text(v) for k, v in fixed.items()}

    if ("grid" in data) == ("monte_carlo" in data):
        raise SweepError(path, "grid", "give exactly one of 'grid' or 'monte_carlo'")
    if "grid" in data:
        mode, grid = "grid", data["grid"]
        if not isinstance(grid, dict) or not grid:
            raise SweepError(path, "grid", "must be a non-empty mapping dotted key -> list of values")
        values = {}
        for k, spec in grid.items():
            _dotted(path, "grid", k)
            values[k] = _grid_values(path, k, spec)
        keys = list(values)
        combos = [dict(zip(keys, combo)) for combo in itertools.product(*values.values())]
    else:
        mode, mc = "monte_carlo", data["monte_carlo"]
        if not isinstance(mc, dict):
            raise SweepError(path, "monte_carlo", "must be a mapping with n, seed and dotted key -> distribution")
        n, seed = mc.get("n"), mc.get("seed", 0)
        if not isinstance(n, int) or isinstance(n, bool) or n < 1:
            raise SweepError(path, "monte_carlo.n", f"must be a positive integer (got {n!r})")
        if not isinstance(seed, int) or isinstance(seed, bool):
            raise SweepError(path, "monte_carlo.seed", f"must be an integer (got {seed!r})")
        samplers = {}
        for k, spec in mc.items():
            if k in ("n", "seed"):
                continue
            _dotted(path, "monte_carlo", k)
            samplers[k] = _sampler(path, k, spec)
        if not samplers:
            raise SweepError(path, "monte_carlo", "no parameter to sample")
        import numpy as np
        rng = np.random.default_rng(seed)
        keys = list(samplers)
        combos = [{k: samplers[k](rng) for k in keys} for _ in range(n)]
    clash = set(keys) & set(fixed)
    if clash:
        raise SweepError(path, f"set.{sorted(clash)[0]}", "is also swept")

    m = data.get("metrics") or {}
    if not isinstance(m, dict):
        raise SweepError(path, "metrics", "must be a mapping")
    extra = set(m) - {"steady_start", "steady_stop", "f_min", "f_max"}
    if extra:
        raise SweepError(path, f"metrics.{sorted(extra)[0]}", "unknown field (steady_start, steady_stop, f_min, f_max)")
    metrics = Metrics(
        steady_start=_time(path, "metrics.steady_start", m["steady_start"]) if m.get("steady_start") is not None else None,
        steady_stop=_time(path, "metrics.steady_stop", m["steady_stop"]) if m.get("steady_stop") is not None else None,
        f_min=_time(path, "metrics.f_min", m["f_min"], "[frequency]") if m.get("f_min") is not None else 0.2,
        f_max=_time(path, "metrics.f_max", m["f_max"], "[frequency]") if m.get("f_max") is not None else None)
    plot = data.get("plot")
    if plot is not None and not isinstance(plot, dict):
        raise SweepError(path, "plot", "must be a mapping")

    layout_hash = hashlib.sha256(layout.read_bytes()).hexdigest()
    runs = []
    for i, swept in enumerate(combos):
        overrides = {**fixed, **swept}
        run = Run(i, swept, overrides)
        run.key = run_key(layout_hash, overrides)
        runs.append(run)
    return Sweep(path.resolve(), name, layout, mode, fixed, keys, runs, metrics, plot)


def run_key(layout_hash, overrides):
    """Hash of a layout's text and a run's overrides: the name of the run's folder."""
    blob = json.dumps({"layout": layout_hash, "overrides": sorted(overrides.items())})
    return hashlib.sha256(blob.encode()).hexdigest()[:12]


def validate_overrides(sweep, limit=200):
    """Load the system of the runs (the first ``limit``) in this process, before any run
    starts: a dotted key or value the layout rejects is a :class:`SweepError` naming the
    sweep file and the field."""
    from webline.orchestrator.layout import LayoutError, load_system
    from webline.orchestrator.memory import ResultTooLarge, check_result_memory
    for run in sweep.runs[:limit]:
        try:
            check_result_memory(load_system(sweep.layout, dict(run.overrides)))
        except ResultTooLarge as exc:
            hit = [k for k in run.overrides if k.startswith("experiment.")]
            k = max(hit, key=len) if hit else None
            where = (f"set.{k}" if k in sweep.fixed else f"{sweep.mode}.{k}") if k else sweep.mode
            values = ", ".join(f"{a}={b}" for a, b in run.swept.items())
            raise SweepError(sweep.path, where, f"run {run.run_id} ({values}): {exc}") from None
        except LayoutError as exc:
            text = str(exc)
            hit = [k for k in run.overrides if k in text]
            k = max(hit, key=len) if hit else None
            where = (f"set.{k}" if k in sweep.fixed else f"{sweep.mode}.{k}") if k else sweep.mode
            values = ", ".join(f"{a}={b}" for a, b in run.swept.items())
            raise SweepError(sweep.path, where, f"run {run.run_id} ({values}): "
                             f"the layout {sweep.layout.name} rejects it: {text}") from None


# ---- one run ------------------------------------------------------------------------
def _columns(result):
    """(time array, {column: array}) of a master Result."""
    import numpy as np
    t = np.asarray(result.time, dtype=float)
    cols = getattr(result, "columns", None)
    if isinstance(cols, dict):
        return t, {k: np.asarray(v, dtype=float) for k, v in cols.items()}
    names = list(cols) if cols is not None else list(result.names)
    return t, {k: np.asarray(result[k], dtype=float) for k in names}


def dominant_frequency(t, x, f_min=0.2, f_max=None):
    """(frequency Hz, amplitude) of the largest spectral peak of ``x(t)`` in [f_min, f_max].

    Mean and linear trend removed, Hann window, amplitude-corrected one-sided
    spectrum; the largest local maximum in the band (so that leakage from a
    stronger component just below ``f_min`` does not win at the band's edge)
    is refined by a parabola through the log magnitudes of
    the three bins around it. (nan, nan) if there is no bin in the band or the
    signal is constant.
    """
    import numpy as np
    t, x = np.asarray(t, float), np.asarray(x, float)
    if len(t) < 16:
        return math.nan, math.nan
    dt = float(np.median(np.diff(t)))
    if not dt > 0:
        return math.nan, math.nan
    # resample onto a uniform grid (the master may record at uneven times)
    n = int(round((t[-1] - t[0]) / dt)) + 1
    tu = t[0] + dt * np.arange(n)
    xu = np.interp(tu, t, x)
    scale = max(1.0, float(np.max(np.abs(xu))))
    xu = xu - np.polyval(np.polyfit(tu - tu[0], xu, 1), tu - tu[0])
    if np.ptp(xu) <= 1e-10 * scale:  # constant (or a pure ramp): no oscillation
        return math.nan, math.nan
    w = np.hanning(n)
    spec = np.abs(np.fft.rfft(xu * w)) * 2.0 / w.sum()
    f = np.fft.rfftfreq(n, dt)
    band = (f >= max(f_min, 2.0 / (n * dt))) & (f <= (f_max if f_max else f[-1]))
    if not band.any():
        return math.nan, math.nan
    idx = np.flatnonzero(band)
    # the largest true local maximum in the band (not leakage from below f_min at its edge)
    peaks = idx[(idx > 0) & (idx < len(spec) - 1)]
    peaks = peaks[(spec[peaks] >= spec[peaks - 1]) & (spec[peaks] >= spec[peaks + 1])]
    k = int(peaks[np.argmax(spec[peaks])] if peaks.size else idx[np.argmax(spec[idx])])
    if spec[k] <= 0:
        return math.nan, math.nan
    fk, ak = f[k], spec[k]
    if 0 < k < len(spec) - 1 and spec[k - 1] > 0 and spec[k + 1] > 0:
        a, b, c = np.log(spec[k - 1]), np.log(spec[k]), np.log(spec[k + 1])
        den = a - 2 * b + c
        if den < 0:
            p = 0.5 * (a - c) / den
            fk = f[k] + p * (f[1] - f[0])
            ak = float(np.exp(b - 0.25 * (a - c) * p))
    return float(fk), float(ak)


def summarize(system, result, metrics=None):
    """Summary metrics of one run: per load cell the mean and peak-to-peak tension and
    the dominant frequency of its tension over the steady window; per roll (unwind,
    rewind) the mean angular speed, its rotation frequency and the mean radius."""
    import numpy as np
    metrics = metrics or Metrics()
    t, cols = _columns(result)
    out = {}
    if len(t) < 2:
        return out
    t0 = metrics.steady_start if metrics.steady_start is not None else t[0] + 0.5 * (t[-1] - t[0])
    t1 = metrics.steady_stop if metrics.steady_stop is not None else t[-1]
    sel = (t >= t0 - 1e-12) & (t <= t1 + 1e-12)
    if sel.sum() < 2:
        raise ValueError(f"steady window [{t0:g}, {t1:g}] s holds fewer than 2 samples "
                         f"(record {t[0]:g}..{t[-1]:g} s)")
    ts = t[sel]
    out["steady_start"], out["steady_stop"] = float(ts[0]), float(ts[-1])
    for c in system.components:
        if c.model == "LoadCell" and f"{c.name}.T" in cols:
            x = cols[f"{c.name}.T"][sel]
            out[f"{c.name}.T.mean"] = float(np.mean(x))
            out[f"{c.name}.T.p2p"] = float(np.ptp(x))
            f, a = dominant_frequency(ts, x, metrics.f_min, metrics.f_max)
            out[f"{c.name}.T.f_dom"] = f
            out[f"{c.name}.T.a_dom"] = a
    for c in system.components:
        if c.model in ("UnwindRoll", "RewindRoll") and f"{c.name}.omega" in cols:
            w = float(np.mean(cols[f"{c.name}.omega"][sel]))
            out[f"{c.name}.omega.mean"] = w
            out[f"{c.name}.f_rot"] = abs(w) / (2 * math.pi)
            if f"{c.name}.R" in cols:
                out[f"{c.name}.R.mean"] = float(np.mean(cols[f"{c.name}.R"][sel]))
            if f"{c.name}.v" in cols:
                out[f"{c.name}.v.mean"] = float(np.mean(cols[f"{c.name}.v"][sel]))
    return out


def _write_json(path, data):
    tmp = Path(path).with_suffix(".tmp")
    tmp.write_text(json.dumps(data, indent=1, default=_json_default, allow_nan=True))
    os.replace(tmp, path)


def _json_default(o):
    try:
        return float(o)
    except Exception:
        return str(o)


def execute_run(task):
    """Run one task (a dict, see :func:`_task`) in this process; writes and returns its summary.

    Never raises for a failing run: the error is in the summary (``status`` "error"
    or "failed") and the traceback in ``error.txt``.
    """
    run_dir = Path(task["run_dir"])
    run_dir.mkdir(parents=True, exist_ok=True)
    summary = {k: task[k] for k in ("run_id", "key", "swept", "overrides")}
    summary.update(layout=task["layout"], status="error", error="", host=os.uname().nodename,
                   pid=os.getpid(), started=time.strftime("%Y-%m-%dT%H:%M:%S"))
    t_wall = time.perf_counter()
    try:
        runner = task.get("runner")
        if runner:  # "module:function" with the task's signature (tests, custom studies)
            import importlib
            mod, fn = runner.split(":")
            info = getattr(importlib.import_module(mod), fn)(task)
            summary.update(info)
        else:
            summary.update(_simulate_task(task))
    except Exception as exc:
        summary["status"] = "error"
        summary["error"] = f"{type(exc).__name__}: {exc}"
        (run_dir / "error.txt").write_text(traceback.format_exc())
    summary["wall_time"] = time.perf_counter() - t_wall
    if summary.get("sim_time"):
        summary["rtf"] = summary["sim_time"] / summary["wall_time"]
    _write_json(run_dir / SUMMARY, summary)
    return summary


def _simulate_task(task):
    from webline.orchestrator.layout import load_system
    from webline.orchestrator.master import simulate
    from webline.orchestrator import results as results_mod
    run_dir = Path(task["run_dir"])
    system = load_system(task["layout"], dict(task["overrides"]))
    fmu_paths = {k: Path(v) for k, v in task["fmu_paths"].items()} if task.get("fmu_paths") else None
    t = time.perf_counter()
    result = simulate(system, fmu_paths=fmu_paths, progress=False)
    sim_wall = time.perf_counter() - t
    _save_results(results_mod, result, system, run_dir)
    status = getattr(result, "status", "ok") or "ok"
    status = "ok" if str(status).lower() in ("ok", "0", "success", "true") else str(status)
    info = {"status": status, "error": "" if status == "ok" else str(getattr(result, "message", "") or ""),
            "sim_wall_time": sim_wall}
    t_arr, _ = _columns(result)
    if len(t_arr):
        info["sim_time"] = float(t_arr[-1] - t_arr[0])
    try:
        info.update(summarize(system, result, Metrics(**task.get("metrics", {}))))
    except Exception as exc:
        if status == "ok":
            raise
        info["error"] += f"; no metrics: {exc}"
    return info


def _save_results(results_mod, result, system, run_dir):
    """Write results.h5 through orchestrator.results (its documented writer)."""
    if hasattr(result, "save"):
        return result.save(run_dir)
    for name in ("write_hdf5", "write_h5", "save_hdf5"):
        fn = getattr(results_mod, name, None)
        if fn is not None:
            try:
                return fn(result, Path(run_dir) / "results.h5", system=system)
            except TypeError:
                return fn(result, Path(run_dir) / "results.h5")
    for name in ("write_results", "write", "save"):
        fn = getattr(results_mod, name, None)
        if fn is not None:
            return fn(result, Path(run_dir))
    raise RuntimeError("webline.orchestrator.results has no known writer")


def execute_run_isolated(task):
    """Run one task in a fresh Python subprocess (used on Dask workers, so that a run
    that crashes the interpreter - an FMU segfault - cannot take the worker down)."""
    run_dir = Path(task["run_dir"])
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / SUMMARY).unlink(missing_ok=True)
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in sys.path if p)
    t = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "webline.orchestrator.sweep", "--run-task"],
                          input=json.dumps(task), text=True, capture_output=True, env=env)
    try:
        summary = json.loads((run_dir / SUMMARY).read_text())
        if summary.get("key") == task["key"]:
            return summary
    except (OSError, ValueError):
        pass
    return _crash_summary(task, f"run process exited with code {proc.returncode} "
                                f"without a summary; stderr: {proc.stderr[-800:].strip()}",
                          time.perf_counter() - t)


def _crash_summary(task, message, wall=math.nan):
    summary = {k: task[k] for k in ("run_id", "key", "swept", "overrides", "layout")}
    summary.update(status="crashed", error=message, wall_time=wall)
    try:
        _write_json(Path(task["run_dir"]) / SUMMARY, summary)
    except OSError:
        pass
    return summary


# ---- the sweep ----------------------------------------------------------------------
def _task(sweep, run, out, fmu_paths, runner=None):
    return {"run_id": run.run_id, "key": run.key, "swept": run.swept, "overrides": run.overrides,
            "layout": str(sweep.layout), "run_dir": str(Path(out) / "runs" / run.key),
            "fmu_paths": {k: str(v) for k, v in (fmu_paths or {}).items()},
            "metrics": sweep.metrics.as_dict(), "runner": runner}


def finished_summary(out, run, retry_failed=False):
    """The stored summary of a finished run (None if it has to run)."""
    p = Path(out) / "runs" / run.key / SUMMARY
    try:
        s = json.loads(p.read_text())
    except (OSError, ValueError):
        return None
    if s.get("key") != run.key:
        return None
    if retry_failed and s.get("status") != "ok":
        return None
    return s


def _local(tasks, workers, on_done):
    """Each task in its own spawned process of a local pool; a crashed process is
    retried alone so that it is the only run recorded as crashed."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed
    from concurrent.futures.process import BrokenProcessPool
    ctx = multiprocessing.get_context("spawn")
    broken = []
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx, max_tasks_per_child=1)
    try:
        futures = {pool.submit(execute_run, t): t for t in tasks}
        for fut in as_completed(futures):
            try:
                on_done(fut.result())
            except BrokenProcessPool:
                broken.append(futures[fut])
            except Exception as exc:
                on_done(_crash_summary(futures[fut], f"{type(exc).__name__}: {exc}"))
    except KeyboardInterrupt:  # Ctrl-C: stop the runs in flight, drop the queued ones
        for proc in list((getattr(pool, "_processes", None) or {}).values()):
            proc.terminate()
        pool.shutdown(wait=True, cancel_futures=True)
        raise
    pool.shutdown()
    for t in broken:  # one at a time: find the run that takes its process down
        with ProcessPoolExecutor(max_workers=1, mp_context=ctx, max_tasks_per_child=1) as pool:
            try:
                on_done(pool.submit(execute_run, t).result())
            except BrokenProcessPool:
                on_done(_crash_summary(t, "run process died (crash in the simulation: no Python error)"))
            except Exception as exc:
                on_done(_crash_summary(t, f"{type(exc).__name__}: {exc}"))


def _dask(tasks, address, on_done, isolate=True):
    """Each task on a Dask distributed cluster (by default in a subprocess of its worker)."""
    import uuid
    from distributed import Client, as_completed
    fn = execute_run_isolated if isolate else execute_run
    with Client(address) as client:
        tag = uuid.uuid4().hex[:8]
        futures = {client.submit(fn, t, key=f"webline-run-{t['key']}-{tag}", pure=False): t for t in tasks}
        for fut in as_completed(futures):
            task = futures[fut]
            try:
                on_done(fut.result())
            except Exception as exc:
                on_done(_crash_summary(task, f"{type(exc).__name__}: {exc}"))


def run_sweep(sweep, out, scheduler=None, workers=None, progress=True, force=False,
              retry_failed=False, fmu_paths=None, runner=None, isolate=True, log=print):
    """Run every unfinished run of ``sweep`` into ``out``; gather ``out/sweep.csv``.

    ``scheduler``: address of a Dask scheduler (else a local process pool of
    ``workers`` processes, default the CPU count). ``runner``: "module:function"
    replacing the simulation of one task (tests). Returns the list of rows.
    """
    out = Path(out)
    (out / "runs").mkdir(parents=True, exist_ok=True)
    if fmu_paths is None and runner is None:
        from webline.fmus.build import build_all
        fmu_paths = build_all(log=lambda m: log(f"sweep: {m}"))
    summaries, todo, keys = {}, [], set()
    for run in sweep.runs:
        if run.key in keys:  # identical overrides: one run serves both rows
            continue
        keys.add(run.key)
        done = None if force else finished_summary(out, run, retry_failed)
        if done is not None:
            summaries[run.key] = done
        else:
            todo.append(_task(sweep, run, out, fmu_paths, runner))
    _write_json(out / "sweep.json", {
        "name": sweep.name, "sweep_file": str(sweep.path), "layout": str(sweep.layout),
        "mode": sweep.mode, "fixed": sweep.fixed, "parameters": sweep.parameters,
        "metrics": sweep.metrics.as_dict(), "plot": sweep.plot, "runs": len(sweep.runs)})
    if len(summaries):
        log(f"sweep {sweep.name}: {len(summaries)} of {len(sweep.runs)} runs already finished, "
            f"{len(todo)} to run")
    if todo:
        from tqdm import tqdm
        bar = tqdm(total=len(todo), desc=f"sweep {sweep.name}", unit="run", disable=not progress)
        failed = 0

        def on_done(summary):
            nonlocal failed
            summaries[summary["key"]] = summary
            if summary.get("status") != "ok":
                failed += 1
                bar.set_postfix(failed=failed)
            bar.update(1)
        try:
            if scheduler:
                _dask(todo, scheduler, on_done, isolate=isolate)
            else:
                _local(todo, workers or os.cpu_count() or 1, on_done)
        finally:  # also on Ctrl-C: the table holds what finished ("missing" for the rest)
            bar.close()
            rows = [row(sweep, run, summaries.get(run.key), out) for run in sweep.runs]
            write_table(out / TABLE, rows, sweep.parameters)
        return rows
    rows = [row(sweep, run, summaries.get(run.key), out) for run in sweep.runs]
    write_table(out / TABLE, rows, sweep.parameters)
    return rows


def row(sweep, run, summary, out):
    """One line of sweep.csv: run id, swept values (string and SI), status, error, metrics."""
    r = {"run_id": run.run_id, "key": run.key, "run_dir": str(Path("runs") / run.key)}
    for k, v in run.swept.items():
        r[k] = v
        r[f"{k}.si"] = to_si(v)
    if summary is None:
        r.update(status="missing", error="no summary")
        return r
    r["status"] = summary.get("status", "error")
    r["error"] = " ".join(str(summary.get("error", "")).split())
    skip = {"run_id", "key", "swept", "overrides", "layout", "status", "error", "host", "pid", "started"}
    for k, v in summary.items():
        if k not in skip and not isinstance(v, (dict, list)):
            r[k] = v
    return r


def write_table(path, rows, parameters):
    """sweep.csv: fixed columns, then swept values (string, SI), then metrics (sorted)."""
    import csv
    first = ["run_id", "key", "status", "error"]
    params = [c for p in parameters for c in (p, f"{p}.si")]
    timing = ["wall_time", "sim_wall_time", "sim_time", "rtf"]
    rest = sorted({k for r in rows for k in r} - set(first) - set(params) - set(timing) - {"run_dir"})
    cols = first + params + [c for c in timing if any(c in r for r in rows)] + rest + ["run_dir"]
    tmp = Path(path).with_suffix(".tmp")
    with open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=cols, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: _cell(r.get(k)) for k in cols})
    os.replace(tmp, path)


def _cell(v):
    if v is None:
        return ""
    if isinstance(v, float):
        return "nan" if math.isnan(v) else repr(v)
    return v


def read_table(path):
    """sweep.csv as a list of dicts (numbers as floats where they parse)."""
    import csv
    rows = []
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            for k, v in r.items():
                try:
                    r[k] = float(v) if v not in ("",) and k not in ("run_id", "key", "status", "error", "run_dir") else v
                except ValueError:
                    pass
            rows.append(r)
    return rows


def _run_task_main():
    """``python -m webline.orchestrator.sweep --run-task`` < task.json: one run in this process."""
    task = json.loads(sys.stdin.read())
    summary = execute_run(task)
    return 0 if summary.get("status") == "ok" else 1


if __name__ == "__main__":
    if sys.argv[1:] == ["--run-task"]:
        sys.exit(_run_task_main())
    sys.exit("usage: python -m webline.orchestrator.sweep --run-task < task.json (use 'webline sweep')")
