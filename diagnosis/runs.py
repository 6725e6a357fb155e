"""Measured runs: a run file names its data and the conditions it was taken under.

A run file (YAML)::

    data: run1.csv              # relative to the run file; .csv or .mat
    name: r200                  # optional; default: the file's stem
    experiment:                 # same form as the layout's experiment section;
      line_speed: 200 ft/min    # every key given overrides the layout's
      duration: 60 s
      roll_radius: {unwind: 6.375 in}
      tension: {unwind_zone: 15 lbf}
    overrides:                  # optional: any other dotted layout key
      path.unwind.friction: 4e-3 N*m*s/rad
    time_offset: 0 s            # optional: model time of the first sample
    sensors: {tension9: lc9.T}  # optional: data column -> model column

The experiment keys may also stand at the top level (``line_speed: ...``).

Data columns are ``time`` and ``<component>.<variable>`` (units in the
header, converted to SI by :mod:`diagnosis.data`), e.g. ``lc9.T [lbf]``;
``<element>.pulse`` / ``<element>.angle`` columns, when present, give the
true angle of a rotating element.
"""
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml


class RunError(ValueError):
    """A run file or its data that cannot be used; the message names the file."""


@dataclass
class Run:
    name: str
    path: Path
    data_path: Path
    overrides: dict            # dotted layout key -> value text (units kept)
    t: np.ndarray              # uniform time grid (s), from 0 = first sample + time_offset
    columns: dict              # column -> SI array on ``t``
    units: dict = field(default_factory=dict)
    holdout: bool = False
    time_offset: float = 0.0

    @property
    def fs(self):
        return 1.0 / float(self.t[1] - self.t[0])

    @property
    def duration(self):
        return float(self.t[-1] - self.t[0])


EXPERIMENT_KEYS = ("duration", "start", "step", "algorithm", "output_interval", "max_substep",
                   "line_speed", "tension", "roll_radius")
PER_NAME = ("tension", "roll_radius")  # mappings by zone / roll name: override entry by entry


def _value(v):
    """An override value as the layout reads it: strings as written, anything else as YAML text."""
    if isinstance(v, str):
        return v
    if isinstance(v, (dict, list)):
        return yaml.safe_dump(v, default_flow_style=True, width=10 ** 6).strip()
    if isinstance(v, bool):
        return "true" if v else "false"
    return str(v)


def _experiment_overrides(exp, path, out):
    for k, v in exp.items():
        if k not in EXPERIMENT_KEYS:
            raise RunError(f"{path}: experiment.{k}: not a key of the layout's experiment section "
                           f"(one of: {', '.join(EXPERIMENT_KEYS)})")
        if k in PER_NAME and isinstance(v, dict):
            for name, x in v.items():
                out[f"experiment.{k}.{name}"] = _value(x)
        else:
            out[f"experiment.{k}"] = _value(v)
    return out


def _seconds(text, path, key):
    if text is None:
        return 0.0
    if isinstance(text, (int, float)):
        return float(text)
    m = re.fullmatch(r"\s*([-+0-9.eE]+)\s*(s|ms|min)?\s*", str(text))
    if not m:
        raise RunError(f"{path}: {key}: expected a time like '2 s' (got {text!r})")
    return float(m.group(1)) * {"s": 1.0, None: 1.0, "ms": 1e-3, "min": 60.0}[m.group(2)]


RESERVED = {"data", "name", "experiment", "overrides", "time_offset", "sensors", "notes", "description"}


def load_run(path, holdout=False):
    """Read a run file and its data; raises :class:`RunError` naming the file."""
    path = Path(path)
    try:
        spec = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise RunError(f"{path}: run file not found") from None
    except yaml.YAMLError as exc:
        raise RunError(f"{path}: not valid YAML: {exc}") from None
    if not isinstance(spec, dict):
        raise RunError(f"{path}: a run file is a mapping with at least 'data:'")
    if "data" not in spec:
        raise RunError(f"{path}: missing 'data:' (the measured data file, relative to the run file)")
    data_path = (path.parent / str(spec["data"])).resolve()
    if not data_path.exists():
        raise RunError(f"{path}: data file {data_path} not found")
    overrides = {}
    exp = spec.get("experiment") or {}
    if not isinstance(exp, dict):
        raise RunError(f"{path}: 'experiment' must be a mapping like the layout's experiment section")
    top = {k: v for k, v in spec.items() if k in EXPERIMENT_KEYS}
    _experiment_overrides({**top, **exp}, path, overrides)
    extra = spec.get("overrides") or {}
    if not isinstance(extra, dict):
        raise RunError(f"{path}: 'overrides' must be a mapping of dotted layout keys to values")
    for k, v in extra.items():
        overrides[str(k)] = _value(v)
    for k, v in spec.items():
        if k in RESERVED or k in EXPERIMENT_KEYS:
            continue
        if "." in str(k):
            overrides[str(k)] = _value(v)
        else:
            raise RunError(f"{path}: unknown key {k!r} (run files have data, name, experiment, overrides, "
                           f"time_offset, sensors, or the experiment keys {', '.join(EXPERIMENT_KEYS)})")
    offset = _seconds(spec.get("time_offset"), path, "time_offset")
    t, cols, units = read_data(data_path)
    rename = spec.get("sensors") or {}
    for src, dst in rename.items():
        if src not in cols:
            raise RunError(f"{path}: sensors: column {src!r} is not in {data_path.name}")
        cols[dst] = cols.pop(src)
    t = t - t[0] + offset
    return Run(name=str(spec.get("name") or path.stem), path=path, data_path=data_path,
               overrides=overrides, t=t, columns=cols, units=units, holdout=holdout,
               time_offset=offset)


# ------------------------------------------------------------------- data ----
def read_data(path):
    """(t, {column: SI array}, {column: unit}) on a uniform time grid.

    Uses :mod:`diagnosis.data` for CSV/.mat with units in the headers; checks
    what the diagnosis needs: a time column, increasing times, finite values,
    at least 2 s of data."""
    path = Path(path)
    try:
        t, cols, units = _load_with_data_module(path)
    except RunError:
        raise
    except Exception as exc:  # the loader's own error type, or a parse failure
        raise RunError(f"{path}: {exc}") from None
    t = np.asarray(t, float)
    if t.ndim != 1 or len(t) < 16:
        raise RunError(f"{path}: too few samples ({len(t)})")
    if not np.all(np.isfinite(t)):
        raise RunError(f"{path}: the time column has non-finite values")
    dt = np.diff(t)
    if np.any(dt <= 0):
        k = int(np.argmax(dt <= 0))
        raise RunError(f"{path}: time must increase (row {k + 2}: {t[k + 1]!r} after {t[k]!r})")
    out = {}
    for name, y in cols.items():
        y = np.asarray(y, float)
        if y.shape != t.shape:
            raise RunError(f"{path}: column {name!r} has {y.size} values for {t.size} times")
        bad = ~np.isfinite(y)
        if bad.all():
            raise RunError(f"{path}: column {name!r} has no finite value")
        if bad.mean() > 0.05:
            raise RunError(f"{path}: column {name!r} has {bad.sum()} non-finite values "
                           f"({100 * bad.mean():.0f} %)")
        if bad.any():  # isolated dropouts: interpolate
            y = y.copy()
            y[bad] = np.interp(t[bad], t[~bad], y[~bad])
        out[name] = y
    if t[-1] - t[0] < 2.0:
        raise RunError(f"{path}: only {t[-1] - t[0]:.3g} s of data; the diagnosis needs at least 2 s")
    # uniform grid at the median step (logs are often slightly jittered)
    step = float(np.median(dt))
    if np.max(np.abs(dt - step)) > 1e-3 * step:
        n = int(math.floor((t[-1] - t[0]) / step)) + 1
        tu = t[0] + step * np.arange(n)
        out = {k: np.interp(tu, t, v) for k, v in out.items()}
        t = tu
    return t, out, units


def _load_with_data_module(path):
    """Load through diagnosis.data if it is there, else a plain CSV reader."""
    try:
        from webline.diagnosis import data as data_mod
    except ImportError:
        data_mod = None
    if data_mod is not None:
        for name in ("load", "load_data", "read", "read_data", "load_measurements"):
            fn = getattr(data_mod, name, None)
            if callable(fn):
                return _normalise(fn(path))
    if path.suffix.lower() == ".mat":
        raise RunError(f"{path}: .mat data needs diagnosis.data")
    return _read_csv(path)


def _normalise(obj):
    """(t, cols, units) from whatever the data module returns."""
    if isinstance(obj, tuple) and len(obj) >= 2:
        t, cols = obj[0], obj[1]
        units = obj[2] if len(obj) > 2 and isinstance(obj[2], dict) else {}
        return np.asarray(t, float), dict(cols), units
    t = getattr(obj, "time", None)
    if t is None:
        t = getattr(obj, "t")
    cols = getattr(obj, "columns", None)
    if cols is None:
        cols = getattr(obj, "data")
    if not isinstance(cols, dict):
        cols = {k: obj[k] for k in cols}
    units = getattr(obj, "units", {}) or {}
    return np.asarray(t, float), {k: np.asarray(v, float) for k, v in cols.items() if k not in ("time", "t")}, dict(units)


_UNIT = {"s": 1.0, "ms": 1e-3, "N": 1.0, "kN": 1e3, "lbf": 4.4482216152605, "m": 1.0, "mm": 1e-3,
         "in": 0.0254, "ft": 0.3048, "rad": 1.0, "deg": math.pi / 180, "m/s": 1.0,
         "ft/min": 0.00508, "rad/s": 1.0, "rpm": 2 * math.pi / 60, "1": 1.0, "": 1.0}


def _read_csv(path):
    import csv
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    if not rows:
        raise RunError(f"{path}: empty file")
    names, units = [], {}
    for h in rows[0]:
        m = re.fullmatch(r"\s*([^\[\(]+?)\s*(?:[\[\(]\s*([^\]\)]*)\s*[\]\)])?\s*", h)
        if not m:
            raise RunError(f"{path}: cannot read header {h!r}")
        names.append(m.group(1))
        units[m.group(1)] = (m.group(2) or "").strip()
    try:
        data = np.array([[float(x) for x in r] for r in rows[1:] if r], float)
    except ValueError as exc:
        raise RunError(f"{path}: non-numeric value: {exc}") from None
    if data.ndim != 2 or data.shape[1] != len(names):
        raise RunError(f"{path}: rows do not match the header ({len(names)} columns)")
    tname = next((n for n in names if n.lower() in ("time", "t")), None)
    if tname is None:
        raise RunError(f"{path}: no 'time' column (header: {', '.join(names)})")
    cols = {}
    for i, n in enumerate(names):
        u = units[n]
        if u not in _UNIT:
            raise RunError(f"{path}: column {n!r}: unknown unit {u!r}")
        cols[n] = data[:, i] * _UNIT[u]
    t = cols.pop(tname)
    return t, cols, units


def write_csv(path, t, columns, units=None):
    """Write ``time [s]`` and the columns (SI) with units in the header."""
    units = units or {}
    names = list(columns)
    head = ["time [s]"] + [f"{n} [{units.get(n, _guess_unit(n))}]" for n in names]
    arr = np.column_stack([t] + [columns[n] for n in names])
    np.savetxt(path, arr, delimiter=",", header=",".join(head), comments="", fmt="%.9g")


def _guess_unit(name):
    var = name.rsplit(".", 1)[-1]
    return {"T": "N", "theta": "rad", "angle": "rad", "omega": "rad/s", "v": "m/s", "R": "m",
            "pulse": "1"}.get(var, "1")
