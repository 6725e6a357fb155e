"""Measured records: CSV and MATLAB files -> one uniformly sampled record in SI.

A record is a ``time`` vector (s) and one vector per sensor. Units come from
the file (CSV header ``lc_unwind [lbf]``, ``v_line [ft/min]``, ``theta [deg]``;
a MATLAB ``units`` struct) and are converted to SI with the project's pint
registry (:mod:`orchestrator.units`: lbf, ft/min = FPM, PLI, ...). A column
without a unit is taken as recorded, assumed SI (N, m/s, rad, ...). Speeds in
rpm become rad/s; Hz stays Hz (pint would turn Hz into rad/s without the 2 pi).

Records as loggers write them: the time column is found by name (``time``,
``t``, ``Timestamp``, ``time_s``, ``Time [s]``, ``t [ms]``, ``Zeit``, ...) or
named by the caller (``time=``); it holds seconds, another unit (header,
name suffix or ``time_unit=``) or ISO 8601 date-time strings (seconds from the
first sample). Headers may carry spaces and units in brackets or parentheses
(``belt speed [m/s]``, ``Tension (lbf)``); a column is referred to by its name
or by its header as written (:meth:`Record.resolve`).

Every defect is a :class:`DataError` naming the file, the column and the
reason: a missing time column, time that goes backwards (the sample index is
named) or has gaps beyond a tolerance, NaN runs longer than ``max_nan_run``
samples (the sample and time range are named), an unknown unit or a unit of
the wrong dimension. Jittered time stamps are resampled onto a uniform grid and
short NaN runs filled by linear interpolation; both are reported in
``Record.notes``.

Public: :class:`Record`, :class:`DataError`, :func:`load`, :func:`load_csv`,
:func:`load_mat`, :func:`from_arrays`, :func:`si_unit`, :func:`two_levels`,
:func:`parse_datetimes`.
"""
import csv
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from webline.orchestrator import units as web_units

TIME_NAMES = ("time", "t")
"""Preferred names of the time column / variable (exact, then case-insensitive)."""

# Other names a time column goes by (case-insensitive); an optional suffix is its unit.
_TIME_LIKE = re.compile(r"^(?:time|t|timestamp|time[ _]?stamp|zeit|zeitstempel|elapsed(?:[ _]?time)?"
                        r"|datetime|date[ _]?time)"
                        r"(?:[ _-]?(?P<unit>s|sec|ms|us|min|h))?$", re.IGNORECASE)
MAX_NAN_RUN = 5
"""NaN runs of at most this many samples are interpolated; longer ones are refused."""
JITTER_TOL = 1e-3
"""Time stamps whose steps vary by more than this (std / mean) are resampled."""

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
    notes: tuple = ()  # what was done to the data on loading (resampling, NaN filled), as sentences
    headers: dict = field(default_factory=dict)  # header cell as written -> column name

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

    def resolve(self, name):
        """The column a user means by ``name``: the column name itself (``Force``),
        its header as written (``Force [N]``), the name with the unit stripped, or
        a unique case- and blank-insensitive match. None if there is none."""
        if name in self.columns:
            return name
        if name in self.headers:
            return self.headers[name]
        bare = split_header(name)[0]
        if bare in self.columns:
            return bare
        key = " ".join(bare.split()).lower()
        hits = [c for c in self.columns if " ".join(c.split()).lower() == key]
        return hits[0] if len(hits) == 1 else None

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

def _runs(mask):
    """(starts, stops) of the runs of True in ``mask`` (stop exclusive)."""
    edges = np.diff(np.concatenate(([0], mask.view(np.int8), [0])))
    return np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)


def _ranges(starts, stops, limit=6):
    """'10-12, 40' for sample runs (inclusive), at most ``limit`` of them."""
    parts = [f"{a}" if b - a == 1 else f"{a}-{b - 1}" for a, b in zip(starts[:limit], stops[:limit])]
    return ", ".join(parts) + (f", ... ({len(starts)} gaps)" if len(starts) > limit else "")


def _nan_fill(x, max_run, path, column, time):
    """Linearly interpolate NaN runs of at most ``max_run`` samples; a longer run is a
    DataError naming its sample and time range. Returns (x, count, note or None)."""
    bad = ~np.isfinite(x)
    if not bad.any():
        return x, 0, None
    if bad.all():
        raise DataError(path, column, "no finite values")
    starts, stops = _runs(bad)
    longest = int(np.argmax(stops - starts))
    i, j = int(starts[longest]), int(stops[longest]) - 1
    if j - i + 1 > max_run:
        raise DataError(path, column, f"{j - i + 1} consecutive NaN/inf samples, samples {i}-{j} "
                                      f"(t = {time[i]:.6g} s to {time[j]:.6g} s; at most {max_run} "
                                      "are interpolated): split the record or repair the gap")
    good = ~bad
    x = x.copy()
    x[bad] = np.interp(time[bad], time[good], x[good])
    count = int(bad.sum())
    note = (f"column {column!r}: {count} missing sample{'s' if count > 1 else ''} interpolated "
            f"(sample{'s' if count > 1 else ''} {_ranges(starts, stops)})")
    return x, count, note


def two_levels(x, *, min_separation=8.0, near=0.9):
    """(low, high, threshold) of a signal that sits at two levels, else None.

    The levels are the means of a two-cluster split of the finite samples
    (threshold iterated to the midpoint of the cluster means, so a pulse one
    sample in a hundred wide still forms its own cluster whatever its sign
    and offset). Two levels means: the levels are ``min_separation`` times
    the larger within-level standard deviation apart, and ``near`` of the
    samples lie within a quarter of the separation of one of them (a pulse's
    ramps are the rest). A sawtooth (encoder angle) or a sine (speed) fails
    both tests.
    """
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    if x.size < 8:
        return None
    lo, hi = float(x.min()), float(x.max())
    if not hi > lo:
        return None
    thr = 0.5 * (lo + hi)
    for _ in range(100):
        below = x <= thr
        if below.all() or not below.any():
            return None
        new = 0.5 * (x[below].mean() + x[~below].mean())
        if new == thr:
            break
        thr = new
    below = x <= thr
    a, b = x[below], x[~below]
    low, high = float(a.mean()), float(b.mean())
    sep = high - low
    if not sep >= min_separation * max(a.std(), b.std()):
        return None
    if np.mean((np.abs(x - low) < 0.25 * sep) | (np.abs(x - high) < 0.25 * sep)) < near:
        return None
    return low, high, float(thr)


def _time_seconds(t, units, time_unit, source, name):
    """Time stamps in s: the header's unit, else ``time_unit``, else s."""
    unit = units.get("time") or None
    if time_unit and unit and si_unit(unit) == "s" and not np.isclose(
            _quantity(unit).to("s").magnitude, _quantity(time_unit).to("s").magnitude):
        raise DataError(source, name, f"the header says {unit!r}, the time unit given is {time_unit!r}")
    unit = unit or time_unit
    if not unit:
        return t
    tt, tu = _to_si(t, unit, source, name)
    if tu != "s":
        raise DataError(source, name, f"unit {unit!r} is not a time")
    return tt


def from_arrays(time, columns, units=None, *, source="<arrays>", expect=None, time_tol=0.25,
                max_nan_run=MAX_NAN_RUN, min_samples=8, time_unit=None, time_resolution=None,
                jitter_tol=JITTER_TOL, time_name="time", headers=None):
    """Validate and convert raw arrays into a :class:`Record`.

    ``time``: 1-D array (s, or ``time_unit``); ``columns``: name -> 1-D array;
    ``units``: name -> unit string as written in the file (None / missing:
    already SI). The key ``"time"`` in ``units`` gives the unit of ``time``
    (a ``time_unit`` that contradicts it is an error). ``expect``: name -> unit
    whose dimension the column must have (e.g. ``{"lc_unwind": "N"}``).
    ``time_resolution``: the resolution the stamps were written with (s; e.g.
    1 ms for ``10:15:00.123``), allowed on top of ``time_tol``.

    Time must increase strictly (else the sample index is named). The grid is
    ``t0 + k * dt`` with dt the mean step (the median would be biased by stamps
    rounded to a coarse resolution: 300 Hz written in ms steps 3, 3, 4 ms), for
    jittered stamps the least-squares line through them; a step further than
    ``time_tol`` * dt + resolution from dt is a gap or a rate change and refused.
    When the steps vary by more than ``jitter_tol`` (std / mean) the channels are resampled onto the grid: linearly, except
    two-level (pulse) channels, which take the nearest sample so a pulse one
    sample wide keeps its full height. NaN runs of at most ``max_nan_run``
    samples are interpolated (on the recorded times, before any resampling);
    longer runs are refused. What was done is in ``Record.notes``.
    """
    units = dict(units or {})
    expect = dict(expect or {})
    t = np.asarray(time, dtype=float).ravel()
    t = _time_seconds(t, units, time_unit, source, time_name)
    if len(t) < min_samples:
        raise DataError(source, time_name, f"only {len(t)} samples (need at least {min_samples})")
    if not np.all(np.isfinite(t)):
        raise DataError(source, time_name, f"missing or NaN time stamp at sample {int(np.argmin(np.isfinite(t)))}")
    steps = np.diff(t)
    res = float(time_resolution or 0.0)
    if np.any(steps <= 0):
        k = int(np.argmax(steps <= 0)) + 1
        hint = (f"; the stamps' resolution ({res * 1e3:.3g} ms) is coarser than the sampling"
                if steps[k - 1] == 0 and res > 0 else "")
        raise DataError(source, time_name, f"not strictly increasing at sample {k} "
                                           f"(t = {t[k - 1]:.6g} s then {t[k]:.6g} s){hint}")
    n = len(t)
    dt = (t[-1] - t[0]) / (n - 1)
    dev = np.abs(steps - dt)
    allowed = time_tol * dt + res
    if dev.max() > allowed:
        k = int(np.argmax(dev / allowed))
        raise DataError(source, time_name, f"non-uniform sampling: step {steps[k]:.6g} s at sample {k + 1} "
                                           f"(t = {t[k]:.6g} s) vs mean step {dt:.6g} s (tolerance {time_tol:.0%}"
                                           + (f" + resolution {res:.3g} s" if res else "")
                                           + "); split the record or resample it first")
    jitter = float(np.std(steps) / np.mean(steps))
    resampled = jitter > jitter_tol
    k = np.arange(n)
    if resampled:
        # least-squares line through the stamps: stamps truncated to a coarse resolution
        # are late by half of it on average, which biases the end points, not the slope
        dt, t0 = np.polyfit(k, t, 1)
        off = t - (t0 + k * dt)  # jitter: the stamps about the fitted grid
        t0 = max(t0, t[0])  # the grid stays inside the record: no extrapolation at either end
        grid = t0 + np.arange(int(np.floor((t[-1] - t0) / dt + 1e-9)) + 1) * dt
    else:
        grid = t[0] + k * dt
    notes = []

    out, out_units, filled, nearest = {}, {}, {}, []
    for name, values in columns.items():
        x = np.asarray(values, dtype=float).ravel()
        if x.shape != t.shape:
            raise DataError(source, name, f"{x.size} samples, time has {n}")
        unit = units.get(name) or None
        _check_expected(unit, expect.get(name), source, name)
        if unit is not None:
            x, unit = _to_si(x, unit, source, name)
        x, nfill, note = _nan_fill(x, max_nan_run, source, name, t)
        if nfill:
            filled[name], notes = nfill, notes + [note]
        if resampled:
            if two_levels(x) is not None:
                idx = np.clip(np.searchsorted(t, grid), 1, n - 1)  # nearest raw sample to each grid point
                idx -= (grid - t[idx - 1]) < (t[idx] - grid)
                x = x[idx]
                nearest.append(name)
            else:
                x = np.interp(grid, t, x)
        out[name] = x
        out_units[name] = unit
    missing = set(expect) - set(out)
    if missing:
        raise DataError(source, sorted(missing)[0], f"missing column (have: {', '.join(out) or 'none'})")
    if resampled:
        rms = 1e3 * np.sqrt(np.mean(off ** 2))
        notes.insert(0, f"time stamps jittered (step std/mean {jitter:.3g}; RMS {rms:.3g} ms, "
                        f"max {1e3 * np.max(np.abs(off)):.3g} ms from the uniform grid at {1 / dt:.6g} Hz): "
                        "resampled onto the grid, linearly"
                        + (f" (two-level channels {', '.join(map(repr, nearest))}: nearest sample)" if nearest else ""))
    return Record(time=grid, columns=out, units=out_units, source=str(source), resampled=resampled,
                  filled=filled, notes=tuple(notes), headers=dict(headers or {}))


def _time_key_or_none(names):
    """The time column among ``names``: an exact TIME_NAMES match first, then a
    case-insensitive one if it is unique (``T`` beside ``t`` is a tension), then
    the first name that looks like time (``Timestamp``, ``time_s``, ``Zeit``)."""
    names = [str(n) for n in names]
    for cand in TIME_NAMES:
        if cand in names:
            return cand
    for cand in TIME_NAMES:
        hits = [n for n in names if n.lower() == cand]
        if len(hits) == 1:
            return hits[0]
    for n in names:
        if n.lower() not in TIME_NAMES and _TIME_LIKE.match(n.strip()):
            return n
    return None


def _name_unit(name):
    """The unit a time column's name carries (``time_ms`` -> ms), or None."""
    m = _TIME_LIKE.match(str(name).strip())
    u = m.group("unit") if m else None
    return {"sec": "s", "us": "us"}.get(u.lower(), u.lower()) if u else None


def _missing_time(names, path):
    return DataError(path, "time", "missing time column (looked for time / t, a name like Timestamp, time_s, "
                                   "'Time [s]' or Zeit, or date-time values; have: "
                                   f"{', '.join(map(str, names)) or 'none'}); name it with --time COL "
                                   "or 'time: COL' in the run file")


def _time_key(names, path, wanted=None, headers=None):
    """The time column: ``wanted`` (a name or a header as written) if given, else detected."""
    if wanted is not None:
        for cand in (wanted, (headers or {}).get(wanted), split_header(wanted)[0]):
            if cand in names:
                return cand
        raise DataError(path, wanted, f"no such time column (have: {', '.join(map(str, names)) or 'none'})")
    key = _time_key_or_none(names)
    if key is None:
        raise _missing_time(names, path)
    return key


# ----------------------------------------------------------------------------- date-time

_ISO = re.compile(r"^(\d{4}-\d{2}-\d{2})[T ](\d{2}:\d{2}(?::\d{2}(?:[.,](\d+))?)?)\s*(Z|[+-]\d{2}:?\d{2})?$")
_CLOCK = re.compile(r"^(\d{1,2}):(\d{2}):(\d{2}(?:[.,](\d+))?)$")


def is_datetime(text):
    """True if ``text`` is an ISO 8601 date-time or a clock time (hh:mm:ss.fff)."""
    text = str(text).strip()
    return bool(_ISO.match(text) or _CLOCK.match(text))


def parse_datetimes(cells, path="<arrays>", column="time"):
    """Seconds from the first sample, and the stamps' resolution (s), of ISO 8601
    date-times (``2023-03-14T10:15:00.123``, space for T, optional ``Z`` or
    ``+01:00``) or clock times (``10:15:00.123``; past midnight a day is added).
    numpy datetime64[ns] does the calendar. Raises DataError naming the row."""
    cells = [str(c).strip() for c in cells]
    clock = bool(_CLOCK.match(cells[0])) if cells else False
    digits, out = 0, np.empty(len(cells))
    if clock:
        for i, c in enumerate(cells):
            m = _CLOCK.match(c)
            if not m:
                raise _bad_stamp(path, column, i, c)
            out[i] = int(m.group(1)) * 3600 + int(m.group(2)) * 60 + float(m.group(3).replace(",", "."))
            digits = max(digits, len(m.group(4) or ""))
        out += 86400.0 * np.concatenate(([0], np.cumsum(np.diff(out) < -43200.0)))
        return out - out[0], 10.0 ** -digits
    stamps, shift = [], np.zeros(len(cells), dtype=np.int64)
    for i, c in enumerate(cells):
        m = _ISO.match(c)
        if not m:
            raise _bad_stamp(path, column, i, c)
        clock_part = m.group(2).replace(",", ".")
        stamps.append(f"{m.group(1)}T{clock_part}")
        digits = max(digits, len(m.group(3) or ""))
        tz = m.group(4)
        if tz and tz != "Z":
            sign = -1 if tz[0] == "-" else 1
            hh, mm = int(tz[1:3]), int(tz[-2:])
            shift[i] = sign * (hh * 60 + mm) * 60 * 10 ** 9
    try:
        ns = np.array(stamps, dtype="datetime64[ns]").astype(np.int64) - shift
    except ValueError as exc:
        raise DataError(path, column, f"not a valid date-time ({exc})") from None
    return (ns - ns[0]).astype(float) * 1e-9, 10.0 ** -digits


def _bad_stamp(path, column, i, cell):
    return DataError(path, column, f"data row {i + 1}: {cell!r} is neither a number nor a date-time "
                                   "(ISO 8601 like 2023-03-14T10:15:00.123, or 10:15:00.123)")


# ----------------------------------------------------------------------------- CSV

_HEADER = re.compile(r"^\s*(?P<name>[^\[\]]*?)\s*(?:\[(?P<unit>[^\[\]]*)\])?\s*$")
_PAREN = re.compile(r"^\s*(?P<name>.*?)\s*\((?P<unit>[^()]*)\)\s*$")


def split_header(cell):
    """(name, unit or None) of a header cell: ``Force [N]`` -> (Force, N); ``Tension
    (lbf)`` -> (Tension, lbf) when the parenthesis holds a unit (``Force (left)``
    stays a name); spaces inside names are kept. Raises ValueError for stray brackets."""
    cell = str(cell)
    m = _HEADER.match(cell)
    if not m or not m.group("name"):
        raise ValueError("cannot parse header cell (expected 'name', 'name [unit]' or 'name (unit)')")
    name, unit = m.group("name"), m.group("unit")
    if unit is None:
        p = _PAREN.match(name)
        if p and p.group("name") and p.group("unit").strip():
            try:
                _quantity(p.group("unit").strip())
                name, unit = p.group("name"), p.group("unit")
            except ValueError:
                pass
    unit = unit.strip() if unit is not None and unit.strip() not in ("", "-", "--") else None  # [-]: no unit
    return name, unit


def _decimals(cells):
    """Most digits after the point among numeric cells (no exponent), else None."""
    d = 0
    for c in cells:
        if "e" in c or "E" in c:
            return None
        _, dot, frac = c.partition(".")
        d = max(d, len(frac) if dot else 0)
    return d


def load_csv(path, *, time=None, time_unit=None, **kwargs):
    """Load a CSV file: a header row ``time, lc_unwind [lbf], v_line [ft/min], ...``
    then one row per sample. Lines starting with ``#`` before the header are skipped;
    empty fields and ``nan`` are NaN. Comma-separated, or ``;`` / tab separated
    with decimal commas allowed. ``time``: the time column (name or header as
    written; default: detected); ``time_unit``: its unit when the header gives none.
    Keyword arguments go to :func:`from_arrays`."""
    path = Path(path)
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            lines = [ln for ln in fh if ln.strip() and not ln.lstrip().startswith("#")]
    except OSError as exc:
        raise DataError(path, None, f"cannot read ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise DataError(path, None, "not a text (UTF-8) file") from None
    if not lines:
        raise DataError(path, None, "empty file")
    # the delimiter the header uses most: ',' or, as European spreadsheets write, ';' (with
    # decimal commas) or a tab
    delim = max((",", ";", "\t"), key=lambda d: (lines[0].count(d), d == ","))
    rows = list(csv.reader(lines, delimiter=delim))
    if delim != ",":
        rows = [rows[0]] + [[c.replace(",", ".") for c in r] for r in rows[1:]]
    names, units, headers = [], {}, {}
    for cell in rows[0]:
        try:
            name, unit = split_header(cell)
        except ValueError as exc:
            raise DataError(path, cell, str(exc)) from None
        if name in names:
            raise DataError(path, name, "duplicate column")
        names.append(name)
        headers[cell.strip()] = name
        if unit:
            units[name] = unit
    for i, row in enumerate(rows[1:]):
        if len(row) != len(names):
            raise DataError(path, None, f"data row {i + 1} has {len(row)} fields, header has {len(names)}")
    first = rows[1] if len(rows) > 1 else []
    try:
        tkey = _time_key(names, path, time, headers)
    except DataError:
        if time is not None:
            raise
        # no time-like name: the first column holding date-times is the time
        tkey = next((n for j, n in enumerate(names) if first and is_datetime(first[j])), None)
        if tkey is None:
            raise _missing_time(names, path) from None
    tj = names.index(tkey)
    tcells = [r[tj].strip() for r in rows[1:]]
    resolution, stamps = None, bool(tcells) and is_datetime(tcells[0])
    if stamps:
        if time_unit:
            raise DataError(path, tkey, f"holds date-time strings; a time unit ({time_unit!r}) does not apply")
        tvals, resolution = parse_datetimes(tcells, path, tkey)
        units.pop(tkey, None)
        time_unit = None
    else:
        tvals = np.empty(len(tcells))
        for i, c in enumerate(tcells):
            try:
                tvals[i] = float(c) if c else np.nan
            except ValueError:
                raise _bad_stamp(path, tkey, i, c) from None
        d = _decimals(tcells)
        resolution = 10.0 ** -d if d is not None else None  # in the column's unit; scaled below
    if tkey not in units and _name_unit(tkey) and not time_unit:
        units[tkey] = _name_unit(tkey)
    data = np.empty((len(rows) - 1, len(names)))
    for i, row in enumerate(rows[1:]):
        for j, cell in enumerate(row):
            if j == tj:
                continue
            cell = cell.strip()
            try:
                data[i, j] = float(cell) if cell else np.nan
            except ValueError:
                raise DataError(path, names[j], f"not a number in data row {i + 1}: {cell!r}") from None
    columns = {name: data[:, j] for j, name in enumerate(names) if name != tkey}
    if tkey in units:
        units["time"] = units.pop(tkey)
    if resolution is not None and not stamps and (units.get("time") or time_unit):
        try:
            resolution *= float(_quantity(units.get("time") or time_unit).to("s").magnitude)
        except (ValueError, TypeError):
            resolution = None  # from_arrays names the bad unit
    return from_arrays(tvals, columns, units, source=str(path), time_unit=time_unit,
                       time_resolution=resolution, time_name=tkey, headers=headers, **kwargs)


# ----------------------------------------------------------------------------- MATLAB

def _mat_text(value):
    if isinstance(value, str):
        return value
    if isinstance(value, np.ndarray) and value.dtype.kind in "US":
        return str(value.item()) if value.size == 1 else None
    return None


def _mat_columns(variables, path, time=None):
    """Split MATLAB variables into (time key, time, columns, units). ``variables`` is a
    dict of numpy arrays / nested dicts (structs) / strings; ``time`` names the time
    variable (default: detected)."""
    variables = {k: v for k, v in variables.items() if not k.startswith("__")}

    def has_time(names):
        return (time in names) if time is not None else _time_key_or_none(names) is not None

    if not has_time(variables):
        structs = [v for v in variables.values() if isinstance(v, dict) and has_time(v)]
        if len(structs) == 1:
            variables = structs[0]
        elif len(structs) > 1:
            raise DataError(path, None, "several structs with a time vector; save one record per file")
    tkey = _time_key(list(variables), path, time)
    units = {}
    raw_units = variables.get("units")
    if isinstance(raw_units, dict):
        for name, u in raw_units.items():
            text = _mat_text(u)
            if text is None:
                raise DataError(path, name, "units entry is not a string")
            if text.strip():
                units["time" if name == tkey else name] = text.strip()
    t = np.asarray(variables[tkey], dtype=float).ravel()
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
    if "time" not in units and _name_unit(tkey):
        units["time"] = _name_unit(tkey)
    return tkey, t, columns, units


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


def load_mat(path, *, time=None, **kwargs):
    """Load a MATLAB ``.mat`` file (v4-v7 via scipy.io.loadmat, v7.3 via h5py).

    Either plain variables (``time``/``t`` plus one vector per sensor) or one struct
    holding them. An optional ``units`` struct maps variable names to unit strings.
    Scalars, strings and cells are ignored as metadata. ``time`` names the time
    variable (default: detected). Keyword arguments (``time_unit``, ...) go to
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
    tkey, t, columns, units = _mat_columns(variables, path, time)
    return from_arrays(t, columns, units, source=str(path), time_name=tkey, **kwargs)


def load(path, **kwargs):
    """Load a measured record by file suffix: ``.csv`` / ``.txt`` or ``.mat``.
    ``time`` names the time column and ``time_unit`` its unit when the file does not
    say (both default to detection); other keyword arguments go to
    :func:`from_arrays` (``expect``, ``time_tol``, ``max_nan_run``)."""
    suffix = Path(path).suffix.lower()
    if suffix == ".mat":
        return load_mat(path, **kwargs)
    if suffix in (".csv", ".txt"):
        return load_csv(path, **kwargs)
    raise DataError(path, None, f"unknown file type {suffix!r} (expected .csv or .mat)")
