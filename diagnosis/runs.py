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
    time: Timestamp             # optional: the time column (default: detected)
    time_unit: ms               # optional: its unit when the header gives none

The experiment keys may also stand at the top level (``line_speed: ...``).

Data columns are a time column (``time``, ``Timestamp``, ``Time [s]``, date-time
strings, ...: see :mod:`diagnosis.data`) and ``<component>.<variable>`` (units in the
header, converted to SI by :mod:`diagnosis.data`), e.g. ``lc9.T [lbf]``;
``<element>.pulse`` / ``<element>.angle`` columns, when present, give the
true angle of a rotating element.
"""
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
    notes: list = field(default_factory=list)  # what loading did to the data (resampling, gaps filled)

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


RESERVED = {"data", "name", "experiment", "overrides", "time_offset", "sensors", "notes", "description",
            "time", "time_unit"}


def load_run(path, holdout=False, *, time=None, time_unit=None):
    """Read a run file and its data; raises :class:`RunError` naming the file.
    ``time`` / ``time_unit``: the time column and its unit for runs whose file
    does not say (``time:`` / ``time_unit:`` in the run file win)."""
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
                           f"time_offset, sensors, time, time_unit, or the experiment keys "
                           f"{', '.join(EXPERIMENT_KEYS)})")
    offset = _seconds(spec.get("time_offset"), path, "time_offset")
    for key in ("time", "time_unit"):
        if key in spec and not isinstance(spec[key], str):
            raise RunError(f"{path}: {key}: expected a column name / unit as text (got {spec[key]!r})")
    rec = read_record(data_path, time=spec.get("time", time), time_unit=spec.get("time_unit", time_unit))
    t, cols, units = rec.time, dict(rec.columns), dict(rec.units)
    rename = spec.get("sensors") or {}
    for src, dst in rename.items():
        col = rec.resolve(str(src))
        if col is None or col not in cols:
            raise RunError(f"{path}: sensors: column {src!r} is not in {data_path.name}")
        cols[dst] = cols.pop(col)
        units[dst] = units.pop(col, None)
    t = t - t[0] + offset
    return Run(name=str(spec.get("name") or path.stem), path=path, data_path=data_path,
               overrides=overrides, t=t, columns=cols, units=units, holdout=holdout,
               time_offset=offset, notes=[f"{data_path.name}: {n}" for n in rec.notes])


# ------------------------------------------------------------------- data ----
MIN_SAMPLES, MIN_DURATION = 16, 2.0


def read_record(path, *, time=None, time_unit=None):
    """The run's data as a :class:`diagnosis.data.Record` (uniform time grid, SI,
    short gaps filled, jitter resampled; see ``Record.notes``), checked for what
    the diagnosis needs: at least 16 samples and 2 s. Raises :class:`RunError`
    naming the file, the column and the reason."""
    from webline.diagnosis.data import DataError, load
    path = Path(path)
    try:
        rec = load(path, time=time, time_unit=time_unit, min_samples=MIN_SAMPLES)
    except DataError as exc:
        raise RunError(str(exc)) from None
    if rec.time[-1] - rec.time[0] < MIN_DURATION:
        raise RunError(f"{path}: only {rec.time[-1] - rec.time[0]:.3g} s of data; the diagnosis needs at least "
                       f"{MIN_DURATION:g} s")
    return rec


def read_data(path, *, time=None, time_unit=None):
    """(t, {column: SI array}, {column: SI unit}) on a uniform time grid (:func:`read_record`)."""
    rec = read_record(path, time=time, time_unit=time_unit)
    return rec.time, dict(rec.columns), dict(rec.units)


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
