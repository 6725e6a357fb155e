"""Measured records: CSV and MATLAB files -> one uniformly sampled record in SI.

A record is a ``time`` vector (s) and one vector per sensor. Units come from
the file (CSV header ``lc_unwind [lbf]``, ``v_line [ft/min]``, ``theta [deg]``;
a MATLAB ``units`` struct) and are converted to SI with the project's pint
registry (:mod:`orchestrator.units`: lbf, ft/min = FPM, PLI, ...). A column
without a unit is taken as recorded, assumed SI (N, m/s, rad, ...). Speeds in
rpm become rad/s; Hz stays Hz (pint would turn Hz into rad/s without the 2 pi).

Every defect is a :class:`DataError` naming the file, the column and the
reason: a missing time column, time that goes backwards or is not uniform
beyond a tolerance, NaN runs longer than a few samples, an unknown unit or a
unit of the wrong dimension. Small timing jitter is removed by resampling onto
a uniform grid; short NaN runs are filled by linear interpolation.

Public: :class:`Record`, :class:`DataError`, :func:`load`, :func:`load_csv`,
:func:`load_mat`, :func:`from_arrays`, :func:`si_unit`.
"""
import csv
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from webline.orchestrator import units as web_units

TIME_NAMES = ("time", "t")
"""Accepted names of the time column / variable (case-insensitive), in order of preference."""

# SI unit that a quantity of a given dimension is stored in. Angle-bearing units
# (deg, rpm, rad/s) are told apart from plain ones (Hz, %) by their root units:
# pint counts the radian as dimensionless, so Hz -> rad/s would silently drop 2 pi.
_SI_UNITS = ("s", "N", "m/s", "m", "N/m", "N*m", "kg", "kg*m**2", "m/s**2", "Pa", "W", "V", "A", "K")
_SI_ANGLE = {"dimensionless": "rad", "1 / [time]": "rad/s", "1 / [time] ** 2": "rad/s**2"}
_SI_PLAIN = {"dimensionless": "1", "1 / [time]": "Hz"}


class DataError(ValueError):
    """Bad measured data. ``path``, ``column`` (may be None) and ``reason`` are attributes."""

    def __init__(self, path, column, reason):
        self.path, self.column, self.reason = str(path), column, reason
        where = f"{self.path}" + (f", column {column!r}" if column is not None else "")
        super().__init__(f"{where}: {reason}")


@dataclass(frozen=True)
class Record:
    """A measured record on a uniform time grid, in SI.

    ``time`` (s, uniform, increasing); ``columns`` name -> 1-D array (same length);
    ``units`` name -> SI unit string the column is in, or None where the file gave
    no unit (values taken as recorded, assumed SI); ``source`` the file;
    ``resampled`` True when the time stamps were jittered and the data interpolated
    onto the uniform grid.
    """
    time: np.ndarray
    columns: dict
    units: dict
    source: str = "<arrays>"
    resampled: bool = False
    filled: dict = field(default_factory=dict)  # column -> number of NaN samples interpolated

    @property
    def dt(self):
        """Sample interval (s)."""
        return float(self.time[1] - self.time[0])

    @property
    def fs(self):
        """Sample rate (Hz)."""
        return 1.0 / self.dt

    @property
    def duration(self):
        """Record length n * dt (s): the span the samples represent, as a spectrum sees it."""
        return len(self.time) * self.dt

    def __getitem__(self, name):
        return self.columns[name]

    def __contains__(self, name):
        return name in self.columns


# ----------------------------------------------------------------------------- units

def _quantity(unit):
    """One ``unit`` as a pint Quantity, read by the project's parser
    (:func:`orchestrator.units.parse`: lbf, ft/min = FPM, PLI, mil = thou, ...).
    Raises ``ValueError`` naming the unit. Offset units (degC) are refused."""
    try:
        return web_units.parse(f"1 {unit}")
    except web_units.QuantityError as exc:
        raise ValueError(f"unknown unit {unit!r} ({exc})") from None


def si_unit(unit):
    """SI unit string that values in ``unit`` are stored in; raises ``ValueError`` if
    the unit is unknown.

    >>> si_unit("lbf"), si_unit("ft/min"), si_unit("deg"), si_unit("rpm"), si_unit("Hz")
    ('N', 'm/s', 'rad', 'rad/s', 'Hz')
    """
    q = _quantity(unit)
    dim = str(q.dimensionality)
    has_angle = "radian" in dict(q.to_root_units().unit_items())
    table = _SI_ANGLE if has_angle else _SI_PLAIN
    if dim in table:
        return table[dim]
    for target in _SI_UNITS:
        if web_units.ureg.get_dimensionality(target) == q.dimensionality:
            return target
    return f"{q.to_base_units().units:~}"


def _to_si(values, unit, path, column):
    """(values in SI, SI unit string)."""
    try:
        target = si_unit(unit)
        factor = float(_quantity(unit).to(target).magnitude)
    except ValueError as exc:
        raise DataError(path, column, str(exc)) from None
    return np.asarray(values, dtype=float) * factor, target


def _check_expected(unit, expected, path, column):
    """Raise DataError if a column in ``unit`` (as in the file) cannot be converted to
    ``expected``: another dimension, or angle vs plain (rad/s vs Hz)."""
    if unit is None or expected is None:
        return
    try:
        same = si_unit(unit) == si_unit(expected)
    except ValueError as exc:
        raise DataError(path, column, str(exc)) from None
    if not same:
        got, want = _quantity(unit), _quantity(expected)
        raise DataError(path, column, f"unit {unit!r} has dimension {got.dimensionality}, "
                                      f"expected {expected!r} ({want.dimensionality})")


# ----------------------------------------------------------------------------- core

def _nan_fill(x, max_run, path, column, time):
    """Linearly interpolate NaN runs of at most ``max_run`` samples; longer runs are an error."""
    bad = ~np.isfinite(x)
    if not bad.any():
        return x, 0
    if bad.all():
        raise DataError(path, column, "no finite values")
    edges = np.diff(np.concatenate(([0], bad.view(np.int8), [0])))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    longest = int(np.argmax(stops - starts))
    if stops[longest] - starts[longest] > max_run:
        i = starts[longest]
        raise DataError(path, column, f"{stops[longest] - i} consecutive NaN/inf samples from "
                                      f"t = {time[i]:.6g} s (at most {max_run} are interpolated)")
    good = ~bad
    x = x.copy()
    x[bad] = np.interp(np.flatnonzero(bad), np.flatnonzero(good), x[good])
    return x, int(bad.sum())


def from_arrays(time, columns, units=None, *, source="<arrays>", expect=None,
                time_tol=0.25, max_nan_run=3, min_samples=8):
    """Validate and convert raw arrays into a :class:`Record`.

    ``time``: 1-D array in s; ``columns``: name -> 1-D array; ``units``: name ->
    unit string as written in the file (None / missing: already SI). The key
    ``"time"`` in ``units`` gives the unit of ``time``. ``expect``: name -> unit
    whose dimension the column must have (e.g. ``{"lc_unwind": "N"}``).

    Time must increase strictly; each step may differ from the median step by at
    most ``time_tol`` (relative), else a gap or a rate change is reported. Jitter
    within that tolerance is removed by linear interpolation onto
    ``t0 + k * dt`` (dt the mean step). NaN runs of at most ``max_nan_run``
    samples are interpolated.
    """
    units = dict(units or {})
    expect = dict(expect or {})
    t = np.asarray(time, dtype=float).ravel()
    if units.get("time"):
        t, tu = _to_si(t, units["time"], source, "time")
        if tu != "s":
            raise DataError(source, "time", f"unit {units['time']!r} is not a time")
    if len(t) < min_samples:
        raise DataError(source, "time", f"only {len(t)} samples (need at least {min_samples})")
    if not np.all(np.isfinite(t)):
        raise DataError(source, "time", f"NaN/inf time stamp at sample {int(np.argmin(np.isfinite(t)))}")
    steps = np.diff(t)
    if np.any(steps <= 0):
        k = int(np.argmax(steps <= 0)) + 1
        raise DataError(source, "time", f"not strictly increasing at sample {k} "
                                        f"(t = {t[k - 1]:.6g} s then {t[k]:.6g} s)")
    dt_med = float(np.median(steps))
    dev = np.abs(steps / dt_med - 1.0)
    if dev.max() > time_tol:
        k = int(np.argmax(dev))
        raise DataError(source, "time", f"non-uniform sampling: step {steps[k]:.6g} s at t = {t[k]:.6g} s "
                                        f"vs median {dt_med:.6g} s (tolerance {time_tol:.0%}); "
                                        "split the record or resample it first")
    n = len(t)
    uniform = t[0] + np.arange(n) * ((t[-1] - t[0]) / (n - 1))
    resampled = bool(np.max(np.abs(t - uniform)) > 1e-9 * dt_med)

    out, out_units, filled = {}, {}, {}
    for name, values in columns.items():
        x = np.asarray(values, dtype=float).ravel()
        if x.shape != t.shape:
            raise DataError(source, name, f"{x.size} samples, time has {n}")
        unit = units.get(name) or None
        _check_expected(unit, expect.get(name), source, name)
        if unit is not None:
            x, unit = _to_si(x, unit, source, name)
        x, nfill = _nan_fill(x, max_nan_run, source, name, t)
        if nfill:
            filled[name] = nfill
        out[name] = np.interp(uniform, t, x) if resampled else x
        out_units[name] = unit
    missing = set(expect) - set(out)
    if missing:
        raise DataError(source, sorted(missing)[0], f"missing column (have: {', '.join(out) or 'none'})")
    return Record(time=uniform if resampled else t, columns=out, units=out_units,
                  source=str(source), resampled=resampled, filled=filled)


def _time_key_or_none(names):
    """The time column among ``names``: an exact TIME_NAMES match first, then a
    case-insensitive one if it is unique (``T`` beside ``t`` is a tension)."""
    names = [str(n) for n in names]
    for cand in TIME_NAMES:
        if cand in names:
            return cand
    for cand in TIME_NAMES:
        hits = [n for n in names if n.lower() == cand]
        if len(hits) == 1:
            return hits[0]
    return None


def _time_key(names, path):
    key = _time_key_or_none(names)
    if key is None:
        raise DataError(path, "time", f"missing time column (looked for {' / '.join(TIME_NAMES)}; "
                                      f"have: {', '.join(map(str, names)) or 'none'})")
    return key


# ----------------------------------------------------------------------------- CSV

_HEADER = re.compile(r"^\s*(?P<name>[^\[\]]*?)\s*(?:\[(?P<unit>[^\[\]]*)\])?\s*$")


def load_csv(path, **kwargs):
    """Load a CSV file: a header row ``time, lc_unwind [lbf], v_line [ft/min], ...``
    then one row per sample. Lines starting with ``#`` before the header are skipped;
    empty fields and ``nan`` are NaN. Keyword arguments go to :func:`from_arrays`."""
    path = Path(path)
    try:
        with open(path, newline="") as fh:
            lines = [ln for ln in fh if ln.strip() and not ln.lstrip().startswith("#")]
    except OSError as exc:
        raise DataError(path, None, f"cannot read ({exc.strerror})") from None
    rows = list(csv.reader(lines))
    if not rows:
        raise DataError(path, None, "empty file")
    names, units = [], {}
    for cell in rows[0]:
        m = _HEADER.match(cell)
        if not m or not m.group("name"):
            raise DataError(path, cell, "cannot parse header cell (expected 'name' or 'name [unit]')")
        name = m.group("name")
        if name in names:
            raise DataError(path, name, "duplicate column")
        names.append(name)
        if m.group("unit") is not None and m.group("unit").strip():
            units[name] = m.group("unit").strip()
    tkey = _time_key(names, path)
    data = np.empty((len(rows) - 1, len(names)))
    for i, row in enumerate(rows[1:]):
        if len(row) != len(names):
            raise DataError(path, None, f"data row {i + 1} has {len(row)} fields, header has {len(names)}")
        for j, cell in enumerate(row):
            cell = cell.strip()
            try:
                data[i, j] = float(cell) if cell else np.nan
            except ValueError:
                raise DataError(path, names[j], f"not a number in data row {i + 1}: {cell!r}") from None
    columns = {name: data[:, j] for j, name in enumerate(names) if name != tkey}
    if tkey in units:
        units["time"] = units.pop(tkey)
    return from_arrays(data[:, names.index(tkey)], columns, units, source=str(path), **kwargs)


# ----------------------------------------------------------------------------- MATLAB

def _mat_text(value):
    if isinstance(value, str):
        return value
    if isinstance(value, np.ndarray) and value.dtype.kind in "US":
        return str(value.item()) if value.size == 1 else None
    return None


def _mat_columns(variables, path):
    """Split MATLAB variables into (time, columns, units). ``variables`` is a dict of
    numpy arrays / nested dicts (structs) / strings."""
    variables = {k: v for k, v in variables.items() if not k.startswith("__")}
    if _time_key_or_none(variables) is None:
        structs = [v for v in variables.values() if isinstance(v, dict) and _time_key_or_none(v)]
        if len(structs) == 1:
            variables = structs[0]
        elif len(structs) > 1:
            raise DataError(path, None, "several structs with a time vector; save one record per file")
    tkey = _time_key(list(variables), path)
    units = {}
    raw_units = variables.get("units")
    if isinstance(raw_units, dict):
        for name, u in raw_units.items():
            text = _mat_text(u)
            if text is None:
                raise DataError(path, name, "units entry is not a string")
            if text.strip():
                units["time" if name == tkey else name] = text.strip()
    time = np.asarray(variables[tkey], dtype=float).ravel()
    columns = {}
    for name, value in variables.items():
        if name in (tkey, "units") or isinstance(value, (dict, str)):
            continue
        arr = np.asarray(value)
        if arr.dtype.kind not in "biuf" or arr.size <= 1:
            continue  # metadata: scalars, strings, cell arrays
        if arr.squeeze().ndim != 1:
            raise DataError(path, name, f"not a vector (shape {arr.shape})")
        columns[name] = arr.astype(float).ravel()
    return time, columns, units


def _h5_to_dict(group):
    """A MATLAB v7.3 (HDF5) group as nested dicts of arrays; char arrays as str."""
    out = {}
    for name, item in group.items():
        if name.startswith("#"):
            continue
        if hasattr(item, "keys"):
            out[name] = _h5_to_dict(item)
            continue
        cls = item.attrs.get("MATLAB_class", b"")
        cls = cls.decode() if isinstance(cls, bytes) else str(cls)
        value = item[()]
        if cls == "char":
            out[name] = "".join(map(chr, np.asarray(value).ravel()))
        elif isinstance(value, np.ndarray) and value.dtype.kind in "biuf":
            out[name] = value
        # references (cells), empty arrays and other classes are not sensor vectors
    return out


def load_mat(path, **kwargs):
    """Load a MATLAB ``.mat`` file (v4-v7 via scipy.io.loadmat, v7.3 via h5py).

    Either plain variables (``time``/``t`` plus one vector per sensor) or one struct
    holding them. An optional ``units`` struct maps variable names to unit strings.
    Scalars, strings and cells are ignored as metadata. Keyword arguments go to
    :func:`from_arrays`.
    """
    import h5py
    import scipy.io

    path = Path(path)
    if not path.is_file():
        raise DataError(path, None, "no such file")
    try:
        if h5py.is_hdf5(path):
            with h5py.File(path, "r") as fh:
                variables = _h5_to_dict(fh)
        else:
            variables = scipy.io.loadmat(path, simplify_cells=True)
    except (OSError, ValueError, NotImplementedError, TypeError) as exc:
        raise DataError(path, None, f"not a readable MATLAB file ({exc})") from None
    time, columns, units = _mat_columns(variables, path)
    return from_arrays(time, columns, units, source=str(path), **kwargs)


def load(path, **kwargs):
    """Load a measured record by file suffix: ``.csv`` / ``.txt`` or ``.mat``.
    Keyword arguments go to :func:`from_arrays` (``expect``, ``time_tol``, ``max_nan_run``)."""
    suffix = Path(path).suffix.lower()
    if suffix == ".mat":
        return load_mat(path, **kwargs)
    if suffix in (".csv", ".txt"):
        return load_csv(path, **kwargs)
    raise DataError(path, None, f"unknown file type {suffix!r} (expected .csv or .mat)")
