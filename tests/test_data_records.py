"""Records as loggers write them (issue 11): time columns by other names and in
date-time strings, jittered stamps, NaN gaps, active-low pulses, headers with
spaces and units. Every record is made here; one test per defect."""
import numpy as np
import pytest

from webline import cli
from webline.diagnosis import orders as od
from webline.diagnosis.data import DataError, from_arrays, load, parse_datetimes, two_levels
from webline.diagnosis.runs import RunError, load_run

LBF = 4.4482216152605
FS = 300.0        # Hz, the belt rig's force logger
F_BELT = 2.9936   # Hz, drive pulley revolutions
F_IDLER = 3.9216  # Hz, second pulley


def one_sample_pulses(t, f, phase, low=-6.5, idle=0.03, noise=0.02, rng=None):
    """Active-low once-per-revolution pulse one sample wide (0.998 % of the samples at
    300 Hz / 2.99 Hz: below the 1st percentile the old detector used): idles at
    ``idle`` V with noise and drops to ``low`` at the sample nearest each revolution."""
    rng = rng or np.random.default_rng(0)
    x = idle + rng.normal(0.0, noise, t.size)
    edges = (np.arange(np.ceil(phase), f * t[-1] + phase) - phase) / f  # revolution starts, s
    x[np.clip(np.round(edges * FS).astype(int), 0, t.size - 1)] = low
    return x, edges


def belt_csv(path, *, seconds=20.0, stamps="iso"):
    """A belt-rig record: ``Timestamp`` as ISO 8601 strings with millisecond resolution
    (300 Hz in ms steps 3, 3, 4 ms), force at 300 Hz with the drive pulley's
    harmonics, two active-low once-per-revolution channels with two empty cells."""
    rng = np.random.default_rng(7)
    n = int(seconds * FS)
    t = np.arange(n) / FS
    th = 2 * np.pi * F_BELT * t + 0.3
    force = 50 + 3.0 * np.sin(th + 0.2) + 1.0 * np.sin(2 * th) + 2.0 * np.sin(2 * np.pi * F_IDLER * t) \
        + rng.normal(0, 0.3, n)
    rev1, edges1 = one_sample_pulses(t, F_BELT, 0.05, rng=rng)
    rev2, _ = one_sample_pulses(t, F_IDLER, 0.6, rng=rng)
    rev1[500] = np.nan
    rev2[1234] = np.nan
    start = np.datetime64("2023-03-14T10:15:00.000")
    stamp = start + (t * 1e6).astype("int64").astype("timedelta64[us]")
    lines = ["Timestamp,Force [N],Rev 1 [V],Rev 2 [V]"]
    for k in range(n):
        cells = ["" if np.isnan(v) else f"{v:.4f}" for v in (force[k], rev1[k], rev2[k])]
        lines.append(",".join([str(stamp[k].astype("datetime64[ms]"))] + cells))
    path.write_text("\n".join(lines) + "\n")
    return path, edges1


def run_cli(capsys, *argv):
    code = cli.main(list(map(str, argv)))
    out = capsys.readouterr()
    return code, out.out, out.err


# ----------------------------------------------------------------------------- time column

def test_timestamp_column_in_date_time_strings_is_the_time(tmp_path):
    path, _ = belt_csv(tmp_path / "belt.csv")
    rec = load(path)
    # stamps truncated to 1 ms: the grid's rate comes from the least-squares line through them
    assert rec.fs == pytest.approx(FS, rel=1e-4)
    assert abs(rec.time[0]) < 1e-3 and rec.time[-1] == pytest.approx(19.9967, abs=1 / FS + 1e-3)  # ends inside the stamps
    assert list(rec.columns) == ["Force", "Rev 1", "Rev 2"]


@pytest.mark.parametrize("header, scale", [
    ("Timestamp", 1.0), ("time_s", 1.0), ("Time [s]", 1.0), ("t [ms]", 1e-3), ("Zeit (ms)", 1e-3),
    ("time_ms", 1e-3),
])
def test_time_column_names_and_units(tmp_path, header, scale):
    path = tmp_path / "r.csv"
    path.write_text(f"sample,{header},x\n" + "".join(f"{k},{k * 0.01 / scale:.6g},{k}\n" for k in range(50)))
    rec = load(path)
    assert rec.dt == pytest.approx(0.01) and "sample" in rec and "x" in rec


def test_time_option_and_time_unit(tmp_path):
    path = tmp_path / "r.csv"
    path.write_text("counter,clock,x\n" + "".join(f"{k},{k * 5},{k}\n" for k in range(50)))
    with pytest.raises(DataError, match="missing time column"):
        load(path)
    rec = load(path, time="clock", time_unit="ms")
    assert rec.dt == pytest.approx(5e-3) and "clock" not in rec and "counter" in rec
    with pytest.raises(DataError) as err:
        load(path, time="nope")
    assert err.value.column == "nope" and "no such time column" in err.value.reason
    hdr = tmp_path / "h.csv"
    hdr.write_text("time [s],x\n" + "".join(f"{k * 0.01},{k}\n" for k in range(20)))
    with pytest.raises(DataError, match="the header says 's', the time unit given is 'ms'"):
        load(hdr, time_unit="ms")


def test_date_time_parsing_offsets_and_clock_times():
    s, res = parse_datetimes(["2023-03-14T23:59:59.990+01:00", "2023-03-14 23:00:00.000Z",
                              "2023-03-15T00:00:00.010+01:00"])
    assert s == pytest.approx([0.0, 0.01, 0.02]) and res == pytest.approx(1e-3)
    s, res = parse_datetimes(["23:59:59.5", "23:59:59.9", "00:00:00.3"])  # past midnight
    assert s == pytest.approx([0.0, 0.4, 0.8]) and res == pytest.approx(0.1)
    with pytest.raises(DataError, match="data row 2: '14/03/2023 10:00' is neither"):
        parse_datetimes(["2023-03-14T10:00:00", "14/03/2023 10:00"], "r.csv", "Timestamp")


# ----------------------------------------------------------------------------- jitter

def test_jittered_stamps_are_resampled_and_the_jitter_reported():
    rng = np.random.default_rng(3)
    n, dt = 3000, 1 / FS
    jitter = rng.uniform(-0.1, 0.1, n) * dt  # steps within 20 % of dt: jitter, not gaps
    t = np.arange(n) * dt + jitter
    x, edges = one_sample_pulses(t, F_BELT, 0.1, noise=0.0)
    rec = from_arrays(t, {"ramp": 2.0 * t + 1.0, "pulse": x}, source="j.csv")
    assert rec.resampled and np.allclose(np.diff(rec.time), rec.dt)
    assert rec.dt == pytest.approx(dt, rel=1e-4)
    assert rec["ramp"] == pytest.approx(2.0 * rec.time + 1.0)  # linear data survives linear interpolation
    # the two-level channel takes the nearest sample: every one-sample pulse keeps its full depth
    assert np.sum(rec["pulse"] < -6) == np.sum(x < -6)
    note = rec.notes[0]
    off = t - np.polyval(np.polyfit(np.arange(n), t, 1), np.arange(n))
    assert f"RMS {1e3 * np.sqrt(np.mean(off ** 2)):.3g} ms" in note
    assert f"max {1e3 * np.max(np.abs(off)):.3g} ms" in note and "'pulse': nearest sample" in note
    # a clean grid written to 6 digits is not resampled
    clean = from_arrays(np.round(np.arange(n) * dt, 6), {"x": np.ones(n)})
    assert not clean.resampled and clean.notes == ()


def test_time_going_backwards_names_the_sample():
    t = np.arange(100) * 0.01
    t[37] = t[35]
    with pytest.raises(DataError) as err:
        from_arrays(t, {"x": np.zeros(100)}, source="b.csv")
    assert err.value.column == "time" and "not strictly increasing at sample 37" in err.value.reason


# ----------------------------------------------------------------------------- NaN gaps

def test_short_nan_gaps_filled_and_reported_long_gap_refused_with_its_range(tmp_path):
    t = np.arange(1000) * 0.01
    x = np.sin(t)
    x[[100, 101, 102, 400]] = np.nan
    rec = from_arrays(t, {"Force": x})
    assert rec.filled == {"Force": 4}
    assert "column 'Force': 4 missing samples interpolated (samples 100-102, 400)" in rec.notes
    # linear interpolation over the 4-step gap: error <= h^2 / 8 * max|sin''| with h = 0.04 s
    assert rec["Force"][101] == pytest.approx(np.sin(1.01), abs=0.04 ** 2 / 8)
    x[600:606] = np.nan  # 6 > 5 samples
    with pytest.raises(DataError) as err:
        from_arrays(t, {"Force": x}, source="g.csv")
    assert err.value.column == "Force" and err.value.path == "g.csv"
    assert "6 consecutive NaN/inf samples, samples 600-605 (t = 6 s to 6.05 s" in err.value.reason


def test_orders_cli_errors_name_file_column_reason(tmp_path, capsys):
    t = np.arange(1000) * 0.01
    f = np.sin(t)
    f[600:606] = np.nan
    path = tmp_path / "gap.csv"
    path.write_text("time,Force [N],w [rad/s]\n" + "".join(
        f"{ti:.2f},{'' if np.isnan(v) else v},6.0\n" for ti, v in zip(t, f)))
    code, _, err = run_cli(capsys, "orders", path, "--signal", "Force", "--tach", "r=w")
    assert code == 2 and str(path) in err and "'Force'" in err and "samples 600-605" in err
    code, _, err = run_cli(capsys, "orders", path, "--signal", "Force", "--tach", "r=w", "--time", "clock")
    assert code == 2 and "'clock'" in err and "no such time column" in err


# ----------------------------------------------------------------------------- pulses

def test_active_low_one_sample_pulse_with_empty_cells_is_found_by_auto(tmp_path, capsys):
    path, _ = belt_csv(tmp_path / "belt.csv")
    rec = load(path)
    assert od.detect_tach_kind(rec["Rev 1"], rec.units["Rev 1"]) == "pulse"  # unit V: the shape decides
    code, out, err = run_cli(capsys, "orders", path, "--signal", "Force [N]", "--tach", "belt=Rev 1",
                             "--tach", "idler=rev 2", "--kind", "auto", "--out", tmp_path / "o")
    assert code == 0, err
    import json
    res = json.loads((tmp_path / "o" / "orders.json").read_text())
    belt, idler = res["shafts"]["belt"], res["shafts"]["idler"]
    assert belt["kind"] == "pulse" and idler["kind"] == "pulse"
    # the rotation frequency within the record's resolution (1 / 20 s = 0.05 Hz), in fact far closer
    assert abs(belt["frequency_hz"]["mean"] - F_BELT) < 0.1 * res["resolution_hz"]
    assert abs(idler["frequency_hz"]["mean"] - F_IDLER) < 0.1 * res["resolution_hz"]
    assert belt["harmonics"][0]["amplitude"] == pytest.approx(3.0, abs=0.1)  # the force's 1st order
    assert "note: time stamps jittered" in out and "note: column 'Rev 1': 1 missing sample" in out
    assert any("sample 500" in n for n in res["notes"])


@pytest.mark.parametrize("low, high, active_low", [(0.03, -6.5, True), (-6.5, 0.03, True),
                                                   (2.0, 7.0, False), (12.0, 9.5, True)])
def test_pulse_polarity_and_offset(low, high, active_low):
    """Idle level ``low`` (most samples), active level ``high``: either sign, any offset;
    the leading edge (into the active level) is each revolution's start."""
    t = np.arange(6000) / FS
    x, edges = one_sample_pulses(t, F_BELT, 0.05, low=high, idle=low, noise=0.01)
    x[[800, 801]] = np.nan
    assert two_levels(x) is not None
    assert od.detect_tach_kind(x) == "pulse"
    found = od.pulse_edges(t, x)
    # each leading edge within a sample of the true revolution start (the pulse is one sample wide)
    assert len(found) == len(edges)
    assert np.max(np.abs(found - edges)) < 1.0 / FS
    theta, kind = od.shaft_angle(t, x, "auto")
    f = od.shaft_frequency(t, theta)[1]
    assert kind == "pulse" and np.mean(f) == pytest.approx(F_BELT, rel=1e-3)


def test_angle_and_speed_are_not_taken_for_pulses():
    t = np.arange(6000) / FS
    th = 2 * np.pi * F_BELT * t
    assert two_levels(np.mod(th, 2 * np.pi)) is None and od.detect_tach_kind(np.mod(th, 2 * np.pi)) == "angle"
    speed = 18.8 + 0.5 * np.sin(2 * np.pi * 0.2 * t) + np.random.default_rng(0).normal(0, 0.05, t.size)
    assert two_levels(speed) is None and od.detect_tach_kind(speed) == "speed"


# ----------------------------------------------------------------------------- headers

def test_column_names_with_spaces_and_units_in_brackets(tmp_path, capsys):
    t = np.arange(3000) / FS
    th = 2 * np.pi * F_BELT * t
    path = tmp_path / "h.csv"
    rows = [f"{ti:.6f},{3 * np.sin(a) + 40:.5f},{(3 * np.sin(a) + 40) / LBF:.6f},1.5,{np.mod(a, 2 * np.pi):.6f},7"
            for ti, a in zip(t, th)]
    path.write_text("Time [s],Force [N],Tension (lbf),belt speed [m/s],pulley angle [rad],Force (left)\n"
                    + "\n".join(rows) + "\n")
    rec = load(path)
    assert list(rec.columns) == ["Force", "Tension", "belt speed", "pulley angle", "Force (left)"]
    assert rec.units["Tension"] == "N" and rec["Tension"] == pytest.approx(rec["Force"], abs=1e-4)
    assert rec.units["belt speed"] == "m/s" and rec.units["Force (left)"] is None  # (left) is not a unit
    for name in ("Force [N]", "Force", "force", "Tension (lbf)", "belt  speed", "belt speed [m/s]"):
        assert rec.resolve(name) is not None, name
    assert rec.resolve("Force (left)") == "Force (left)" and rec.resolve("Speed") is None
    code, out, err = run_cli(capsys, "orders", path, "--signal", "Tension (lbf)", "--tach", "pulley=pulley angle")
    assert code == 0, err
    assert "pulley       pulley angle     angle" in out


# ----------------------------------------------------------------------------- run files

def test_run_file_time_keys_and_notes(tmp_path):
    rng = np.random.default_rng(1)
    n = 1500
    t_ms = np.arange(n) * 4.0 + rng.uniform(-0.5, 0.5, n)  # 250 Hz in ms, jittered
    (tmp_path / "d.csv").write_text("Zeitpunkt,lc9.T [lbf]\n" + "".join(
        f"{a:.3f},{'' if k == 10 else 3.0}\n" for k, a in enumerate(t_ms)))
    (tmp_path / "r.yaml").write_text("data: d.csv\ntime: Zeitpunkt\ntime_unit: ms\n")
    run = load_run(tmp_path / "r.yaml")
    assert run.fs == pytest.approx(250.0, rel=1e-3) and run.t[0] == 0.0
    assert run.columns["lc9.T"] == pytest.approx(np.full(run.t.size, 3.0 * LBF))
    assert any("jittered" in s for s in run.notes) and any("sample 10" in s for s in run.notes)
    # the caller's default applies when the run file does not say; the run file wins
    (tmp_path / "s.yaml").write_text("data: d.csv\n")
    assert load_run(tmp_path / "s.yaml", time="Zeitpunkt", time_unit="ms").fs == pytest.approx(250.0, rel=1e-3)
    with pytest.raises(RunError, match="missing time column"):
        load_run(tmp_path / "s.yaml")
    (tmp_path / "u.yaml").write_text("data: d.csv\ntime: Zeitpunkt\n")  # the unit from the caller
    assert load_run(tmp_path / "u.yaml", time_unit="ms").fs == pytest.approx(250.0, rel=1e-3)


def test_diagnose_time_options_notes_and_bad_data(tmp_path, capsys):
    """``webline diagnose --time/--time-unit`` reach every run; the loading notes reach
    the report's notes; a long gap exits 2 naming file, column and samples."""
    from pathlib import Path

    from webline.diagnosis import diagnose_cmd
    from webline.diagnosis.pipeline import Diagnosis, Options
    args = diagnose_cmd.parser().parse_args(["l.yaml", "r.yaml", "--out", "o", "--time", "clock",
                                             "--time-unit", "ms"])
    assert (args.time, args.time_unit) == ("clock", "ms")
    layout = Path(__file__).resolve().parents[1] / "scenarios" / "ewl.yaml"
    rng = np.random.default_rng(1)
    t_ms = np.arange(1500) * 4.0 + rng.uniform(-0.4, 0.4, 1500)
    (tmp_path / "j.csv").write_text("clock,lc9.T [lbf]\n" + "".join(f"{a:.3f},3.0\n" for a in t_ms))
    (tmp_path / "j.yaml").write_text("data: j.csv\n")
    d = Diagnosis(layout, [tmp_path / "j.yaml"], options=Options(time_column="clock", time_unit="ms"))
    try:
        d.load()  # reads the layout and the runs; no simulation yet
    finally:
        d.model.cleanup()
    assert d.ctx[0].fs == pytest.approx(250.0, rel=1e-3) and d.ctx[0].sensors == ["lc9.T"]
    assert any(n.startswith("run j: j.csv: time stamps jittered") for n in d.notes)

    t = np.arange(1000) * 0.01
    f = np.ones(1000)
    f[300:310] = np.nan
    (tmp_path / "d.csv").write_text("Timestamp [s],lc9.T [N]\n" + "".join(
        f"{a:.2f},{'' if np.isnan(v) else v}\n" for a, v in zip(t, f)))
    (tmp_path / "r.yaml").write_text("data: d.csv\n")
    code, _, err = run_cli(capsys, "diagnose", layout, tmp_path / "r.yaml", "--out", tmp_path / "o", "--quiet")
    assert code == 2 and "d.csv" in err and "'lc9.T'" in err and "samples 300-309 (t = 3 s to 3.09 s" in err


def test_semicolon_csv_with_decimal_commas_and_dimensionless_unit(tmp_path):
    path = tmp_path / "de.csv"
    path.write_text("Zeit [ms];Kraft [N];Schlupf [-]\n" + "".join(f"{10 * k};{1.5 + k / 10:.1f}".replace(".", ",")
                                                                  + ";0,5\n" for k in range(20)))
    rec = load(path)
    assert rec.dt == pytest.approx(0.01) and rec["Kraft"][3] == pytest.approx(1.8)
    assert rec.units == {"Kraft": "N", "Schlupf": None} and rec["Schlupf"][0] == 0.5


def test_mat_time_variable_by_option_and_name(tmp_path):
    import scipy.io
    k = np.arange(100)
    scipy.io.savemat(tmp_path / "a.mat", {"clock": 4.0 * k, "x": np.sin(k / 10)})
    rec = load(tmp_path / "a.mat", time="clock", time_unit="ms")
    assert rec.dt == pytest.approx(4e-3) and list(rec.columns) == ["x"]
    scipy.io.savemat(tmp_path / "b.mat", {"Timestamp_ms": 4.0 * k, "x": np.sin(k / 10)})
    assert load(tmp_path / "b.mat").dt == pytest.approx(4e-3)  # name found, unit from its suffix
    with pytest.raises(DataError, match="missing time column"):
        load(tmp_path / "a.mat")
