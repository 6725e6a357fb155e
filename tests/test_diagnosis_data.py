"""webline.diagnosis.data: measured CSV / MATLAB records into SI, and every defect named."""
import h5py
import numpy as np
import pytest
import scipy.io

from webline.diagnosis.data import DataError, from_arrays, load, si_unit

LBF = 4.4482216152605  # N
FPM = 0.00508  # m/s


def write_csv(path, header, rows):
    path.write_text(",".join(header) + "\n" + "\n".join(",".join(str(v) for v in r) for r in rows) + "\n")
    return path


def simple_rows(n=20, dt=0.01):
    return [[round(k * dt, 6), 10.0 + k, 200.0, 90.0, 60.0] for k in range(n)]


def test_csv_header_units_converted_to_si(tmp_path):
    path = write_csv(tmp_path / "r.csv", ["time", "lc_unwind [lbf]", "v_line [ft/min]", "theta [deg]", "w [rpm]"],
                     simple_rows())
    rec = load(path)
    assert rec.units == {"lc_unwind": "N", "v_line": "m/s", "theta": "rad", "w": "rad/s"}
    assert rec["lc_unwind"][0] == pytest.approx(10.0 * LBF)
    assert rec["v_line"] == pytest.approx(np.full(20, 200 * FPM))
    assert rec["theta"][0] == pytest.approx(np.pi / 2)
    assert rec["w"][0] == pytest.approx(2 * np.pi)
    assert rec.fs == pytest.approx(100.0) and not rec.resampled
    assert rec.source == str(path)


def test_csv_column_without_unit_is_kept_as_recorded_and_time_unit_converted(tmp_path):
    rows = [[k, 5.0, 1.0] for k in range(10)]
    rec = load(write_csv(tmp_path / "r.csv", ["time [ms]", "T", "p [PLI]"], rows))
    assert rec.units["T"] is None and rec["T"] == pytest.approx(np.full(10, 5.0))
    assert rec.units["p"] == "N/m" and rec["p"][0] == pytest.approx(LBF / 0.0254)
    assert rec.dt == pytest.approx(1e-3)


def test_web_units_known():
    assert (si_unit("lbf"), si_unit("ft/min"), si_unit("FPM"), si_unit("PLI")) == ("N", "m/s", "m/s", "N/m")
    assert si_unit("Hz") == "Hz" and si_unit("rpm") == "rad/s"  # no silent 2 pi between them


def test_jittered_time_is_resampled_to_uniform_grid():
    rng = np.random.default_rng(0)
    t = np.arange(200) * 0.01 + rng.uniform(-0.001, 0.001, 200)
    rec = from_arrays(t, {"x": 3.0 * t + 1.0})
    assert rec.resampled
    assert np.allclose(np.diff(rec.time), rec.dt)
    assert rec["x"] == pytest.approx(3.0 * rec.time + 1.0)  # linear data survives interpolation


def test_short_nan_run_is_interpolated_long_one_is_an_error(tmp_path):
    t = np.arange(50) * 0.1
    x = np.arange(50.0)
    x[10:13] = np.nan
    rec = from_arrays(t, {"x": x})
    assert rec["x"][11] == pytest.approx(11.0) and rec.filled == {"x": 3}
    x[20:30] = np.nan
    with pytest.raises(DataError) as err:
        from_arrays(t, {"x": x}, source="f.csv")
    assert err.value.column == "x" and "10 consecutive NaN" in err.value.reason and "t = 2 s" in str(err.value)


@pytest.mark.parametrize("time, reason", [
    (np.r_[0.0, 0.1, 0.2, 0.15, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9], "not strictly increasing"),
    (np.r_[np.arange(10) * 0.1, 1.5 + np.arange(10) * 0.1], "non-uniform sampling"),
    (np.r_[np.arange(10) * 0.1, 0.9 + np.arange(1, 11) * 0.05], "non-uniform sampling"),  # rate change
])
def test_bad_time_is_an_error(time, reason):
    with pytest.raises(DataError) as err:
        from_arrays(time, {"x": np.zeros_like(time)}, source="rec.csv")
    assert err.value.column == "time" and reason in err.value.reason and err.value.path == "rec.csv"


def test_missing_time_column(tmp_path):
    path = write_csv(tmp_path / "r.csv", ["seconds", "x"], [[0, 1], [1, 2]])
    with pytest.raises(DataError, match="missing time column"):
        load(path)


def test_unknown_unit_and_wrong_dimension(tmp_path):
    path = write_csv(tmp_path / "r.csv", ["time", "lc [furlongs_per_fortnite]"], [[k * 0.1, 1] for k in range(10)])
    with pytest.raises(DataError) as err:
        load(path)
    assert err.value.column == "lc" and "unknown unit" in err.value.reason
    path = write_csv(tmp_path / "s.csv", ["time", "lc [ft/min]"], [[k * 0.1, 1] for k in range(10)])
    with pytest.raises(DataError) as err:
        load(path, expect={"lc": "N"})
    assert err.value.column == "lc" and "'ft/min'" in err.value.reason and "expected 'N'" in err.value.reason
    with pytest.raises(DataError, match="missing column"):
        load(path, expect={"lc_rewind": "N"})


def test_malformed_csv_cells_are_named(tmp_path):
    rows = [[k * 0.1, 1] for k in range(10)]
    rows[4][1] = "12,5"
    path = tmp_path / "r.csv"
    path.write_text("time,x\n" + "\n".join(f"{a},{b}" for a, b in rows) + "\n")
    with pytest.raises(DataError, match="row 5 has 3 fields"):
        load(path)
    rows[4][1] = "high"
    with pytest.raises(DataError) as err:
        load(write_csv(tmp_path / "s.csv", ["time", "x"], rows))
    assert err.value.column == "x" and "'high'" in err.value.reason
    with pytest.raises(DataError, match="unknown file type"):
        load(tmp_path / "r.xlsx")


def test_mat_struct_with_units_and_plain_variables(tmp_path):
    t = np.arange(100) * 0.01
    scipy.io.savemat(tmp_path / "s.mat", {"run1": {"time": t, "lc_unwind": np.full(100, 2.0), "v": np.full(100, 100.0),
                                                   "units": {"lc_unwind": "lbf", "v": "ft/min"}, "fs": 100.0}})
    rec = load(tmp_path / "s.mat")
    assert set(rec.columns) == {"lc_unwind", "v"}  # scalars are metadata
    assert rec["lc_unwind"][0] == pytest.approx(2 * LBF) and rec["v"][0] == pytest.approx(100 * FPM)
    scipy.io.savemat(tmp_path / "p.mat", {"t": t[:, None], "T": np.sin(t)[None, :]})  # column and row vectors
    rec = load(tmp_path / "p.mat")
    assert rec["T"] == pytest.approx(np.sin(t)) and rec.units["T"] is None


def write_mat73(path, t, columns, units):
    """A file laid out as MATLAB -v7.3 writes it: HDF5 with a 512-byte user block,
    a struct as a group, doubles as (1, n) datasets, chars as uint16."""
    with h5py.File(path, "w", userblock_size=512) as fh:
        g = fh.create_group("rec")
        g.attrs["MATLAB_class"] = np.bytes_("struct")
        for name, values in {"time": t, **columns}.items():
            g.create_dataset(name, data=np.asarray(values)[None, :]).attrs["MATLAB_class"] = np.bytes_("double")
        u = g.create_group("units")
        u.attrs["MATLAB_class"] = np.bytes_("struct")
        for name, text in units.items():
            u.create_dataset(name, data=np.array([ord(c) for c in text], dtype=np.uint16)[:, None]
                             ).attrs["MATLAB_class"] = np.bytes_("char")
    with open(path, "r+b") as fh:
        fh.write(b"MATLAB 7.3 MAT-file, written by a test".ljust(116))


def test_mat_v73_via_h5py(tmp_path):
    t = np.arange(50) * 0.02
    write_mat73(tmp_path / "r.mat", t, {"lc": np.full(50, 3.0)}, {"lc": "lbf"})
    rec = load(tmp_path / "r.mat")
    assert rec["lc"][0] == pytest.approx(3 * LBF) and rec.units["lc"] == "N" and rec.dt == pytest.approx(0.02)


def test_mat_errors(tmp_path):
    scipy.io.savemat(tmp_path / "a.mat", {"x": np.arange(10.0)})
    with pytest.raises(DataError, match="missing time column"):
        load(tmp_path / "a.mat")
    scipy.io.savemat(tmp_path / "b.mat", {"t": np.arange(10.0), "x": np.arange(9.0)})
    with pytest.raises(DataError) as err:
        load(tmp_path / "b.mat")
    assert err.value.column == "x" and "9 samples" in err.value.reason
    (tmp_path / "c.mat").write_bytes(b"not a mat file at all" * 20)
    with pytest.raises(DataError, match="not a readable MATLAB file"):
        load(tmp_path / "c.mat")
    with pytest.raises(DataError, match="no such file"):
        load(tmp_path / "missing.mat")
