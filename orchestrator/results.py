"""Results of a run: the recorder (observer), the Result object, HDF5 and CSV files.

A :class:`Result` is a time vector plus one column per ``<component>.<variable>``
(FMU outputs, SI units taken from the modelDescription) and run metadata
(layout, step, algorithm, wall time, status and message).

Files:

* ``results.h5`` (always). HDF5 because MATLAB (``h5read``), Python (h5py,
  pandas), Julia, R, Octave and HDFView read it natively, without a webline
  reader: the file describes itself. Layout: dataset ``/time`` and one 1-D
  dataset per column at the root, named exactly like the column
  (``h5read('results.h5', '/span1.T')``), each with attributes ``unit`` and
  ``description``; the root attributes hold the run metadata (numbers and
  strings; nested values as JSON strings) and ``columns``, the column order.
* ``results.csv`` (``--csv``): header ``time,<component>.<variable>,...``,
  one row per recorded time, values in SI. Plain, so that every tool reads it
  without options; units and metadata are in ``results.h5`` next to it, and
  :func:`load_results` on a CSV takes them from there when it exists.
"""
import csv
import json
from pathlib import Path

import numpy as np

H5_NAME = "results.h5"
CSV_NAME = "results.csv"
FORMAT = "webline-results-1"


class Recorder:
    """Observer: copies the master's output vector into a preallocated array."""

    def __init__(self, columns, units, descriptions, n_rows):
        self.columns, self.units, self.descriptions = list(columns), dict(units), dict(descriptions)
        self.time = np.empty(n_rows)
        self.data = np.empty((n_rows, len(self.columns)))
        self.n = 0

    def record(self, t, y):
        n = self.n
        self.time[n] = t
        self.data[n] = y
        self.n = n + 1

    def result(self, meta):
        n = self.n
        return Result(self.time[:n].copy(), self.data[:n].copy(), self.columns,
                      self.units, self.descriptions, meta)


class Result:
    """Recorded time series of one run.

    ``result["span1.T"]`` is a column (``result["time"]`` the time vector),
    ``result.unit(name)`` its unit, ``result.meta`` the run metadata,
    ``result.status`` ``"ok"`` or ``"failed"`` and ``result.message`` why.
    """

    def __init__(self, time, data, columns, units=None, descriptions=None, meta=None):
        self.time = np.asarray(time, dtype=float)
        self.data = np.asarray(data, dtype=float).reshape(len(self.time), len(columns))
        self.columns = list(columns)
        self.units = dict(units or {})
        self.descriptions = dict(descriptions or {})
        self.meta = dict(meta or {})
        self._index = {c: i for i, c in enumerate(self.columns)}

    @property
    def status(self):
        return self.meta.get("status", "ok")

    @property
    def message(self):
        return self.meta.get("message", "")

    @property
    def ok(self):
        return self.status == "ok"

    def __getitem__(self, name):
        if name == "time":
            return self.time
        try:
            return self.data[:, self._index[name]]
        except KeyError:
            raise KeyError(f"no column {name!r} in the results") from None

    def __contains__(self, name):
        return name == "time" or name in self._index

    def __len__(self):
        return len(self.time)

    def unit(self, name):
        return "s" if name == "time" else self.units.get(name, "")

    def components(self, model=None):
        """Component names, optionally only those of one FMU model (from the metadata)."""
        comps = self.meta.get("components", {})
        if comps:
            return [n for n, c in comps.items() if model is None or c.get("model") == model]
        names = list(dict.fromkeys(c.split(".", 1)[0] for c in self.columns))
        return names if model is None else []

    def save(self, out_dir, csv=False):
        """Write ``results.h5`` (and ``results.csv``) into ``out_dir``; returns the paths."""
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        paths = [write_hdf5(self, out / H5_NAME)]
        if csv:
            paths.append(write_csv(self, out / CSV_NAME))
        return paths

    def __repr__(self):
        return (f"<Result {self.status}: {len(self.time)} rows x {len(self.columns)} columns, "
                f"t = {self.time[0] if len(self.time) else float('nan'):g}.."
                f"{self.time[-1] if len(self.time) else float('nan'):g} s>")


def _attr(value):
    """An HDF5 attribute value: numbers and strings as such, anything else as JSON."""
    if isinstance(value, (bool, np.bool_)):
        return int(value)
    if isinstance(value, (int, float, np.integer, np.floating)):
        return value
    if isinstance(value, str):
        return value
    return "json:" + json.dumps(value, default=_json_default)


def _json_default(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    return repr(obj)


def _from_attr(value):
    if isinstance(value, bytes):
        value = value.decode()
    if isinstance(value, str) and value.startswith("json:"):
        return json.loads(value[5:])
    if isinstance(value, np.generic):
        return value.item()
    return value


def write_hdf5(result, path):
    """Self-describing HDF5 file (see the module docstring); returns ``path``."""
    import h5py

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    opts = {"compression": "gzip", "compression_opts": 4, "shuffle": True} if len(result.time) > 1000 else {}
    with h5py.File(path, "w") as f:
        f.attrs["format"] = FORMAT
        for key, value in result.meta.items():
            f.attrs[key] = _attr(value)
        f.attrs["columns"] = _attr(result.columns)
        d = f.create_dataset("time", data=result.time, **opts)
        d.attrs["unit"] = "s"
        d.attrs["description"] = "Simulation time"
        for i, name in enumerate(result.columns):
            d = f.create_dataset(name, data=result.data[:, i], **opts)
            d.attrs["unit"] = result.units.get(name, "")
            d.attrs["description"] = result.descriptions.get(name, "")
    return path


def write_csv(result, path):
    """``time`` + one column per ``<component>.<variable>``, SI, full precision; returns ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    table = np.column_stack([result.time, result.data]) if len(result.columns) else result.time[:, None]
    with open(path, "w", newline="") as fh:
        fh.write(",".join(["time", *result.columns]) + "\n")
        np.savetxt(fh, table, delimiter=",", fmt="%.17g")
    return path


def load_results(path):
    """Read a ``results.h5`` (or a folder holding one, or a ``results.csv``) back into a Result."""
    path = Path(path)
    if path.is_dir():
        h5 = path / H5_NAME
        path = h5 if h5.exists() else path / CSV_NAME
    if not path.exists():
        raise FileNotFoundError(f"no results at {path}")
    if path.suffix.lower() == ".csv":
        return _load_csv(path)
    import h5py

    with h5py.File(path, "r") as f:
        meta = {k: _from_attr(v) for k, v in f.attrs.items() if k not in ("columns", "format")}
        columns = _from_attr(f.attrs["columns"]) if "columns" in f.attrs else [k for k in f if k != "time"]
        time = f["time"][()]
        data = np.empty((len(time), len(columns)))
        units, descriptions = {}, {}
        for i, name in enumerate(columns):
            d = f[name]
            data[:, i] = d[()]
            units[name] = _from_attr(d.attrs.get("unit", ""))
            descriptions[name] = _from_attr(d.attrs.get("description", ""))
    meta["source"] = str(path)
    return Result(time, data, columns, units, descriptions, meta)


def _load_csv(path):
    with open(path, newline="") as fh:
        header = next(csv.reader(fh))
    if not header or header[0] != "time":
        raise ValueError(f"{path}: first column must be 'time'")
    table = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    columns = header[1:]
    if table.size == 0:
        table = np.empty((0, len(header)))
    units, descriptions, meta = {}, {}, {}
    sibling = path.with_name(H5_NAME)
    if sibling.exists():
        other = load_results(sibling)
        units = {c: other.unit(c) for c in columns if c in other}
        descriptions = {c: other.descriptions.get(c, "") for c in columns}
        meta = dict(other.meta)
    meta["source"] = str(path)
    return Result(table[:, 0], table[:, 1:], columns, units, descriptions, meta)
