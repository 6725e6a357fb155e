"""``webline orders`` end to end on a synthetic measured CSV."""
import json

import numpy as np
import pytest

from webline.diagnosis import orders_cmd
from webline.diagnosis.synthetic import ewl_like
from webline import cli

LBF = 4.4482216152605


@pytest.fixture(scope="module")
def csv_path(tmp_path_factory):
    """The synthetic EWL-like record as a logger would write it: tension in lbf,
    idle roller speed in rpm, the unwind's once-per-rev pulse in volts."""
    rec, truth = ewl_like()
    path = tmp_path_factory.mktemp("orders") / "ewl.csv"
    data = np.column_stack([rec.time, rec["tension"] / LBF, rec["unwind_pulse"], rec["idle_speed"] * 60 / (2 * np.pi),
                            np.degrees(np.mod(truth["unwind"]["theta"], 2 * np.pi))])
    np.savetxt(path, data, delimiter=",", fmt="%.7g",
               header="time,tension [lbf],unwind_pulse [V],idle_speed [rpm],unwind_enc [deg]", comments="")
    return path, truth


def run(capsys, *argv):
    code = cli.main(["orders", *map(str, argv)])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_registered():
    assert cli.COMMANDS["orders"][0] == "webline.diagnosis.orders_cmd"


def test_orders_end_to_end(csv_path, tmp_path, capsys):
    path, truth = csv_path
    code, out, err = run(capsys, path, "--signal", "tension", "--tach", "unwind=unwind_pulse",
                         "--tach", "idle=idle_speed", "--max-harmonic", "6", "--out", tmp_path)
    assert code == 0, err
    result = json.loads((tmp_path / "orders.json").read_text())
    assert (tmp_path / "orders.png").stat().st_size > 10_000
    assert result["signal"] == {"column": "tension", "unit": "N"}
    shafts = result["shafts"]
    assert shafts["unwind"]["kind"] == "pulse" and shafts["idle"]["kind"] == "speed"  # auto-detected
    amps = [h["amplitude"] for h in shafts["unwind"]["harmonics"][:3]]
    assert amps == pytest.approx(truth["unwind"]["amplitude"], abs=0.03)  # in N, from lbf
    tags = {(p["family"], p["harmonic"]) for p in result["peaks"]}
    assert tags == {("unwind", 1), ("unwind", 2), ("unwind", 3), ("idle", 1), ("idle", 2)}
    assert all(p["status"] == "tagged" for p in result["peaks"])
    assert "unwind x3" in out and "idle x1" in out and "orders.json" in out


def test_ambiguous_peak_carries_order_evidence(csv_path, tmp_path, capsys):
    path, _ = csv_path
    # up to harmonic 10 the unwind's 9th (8.98-9.62 Hz) overlaps the idle's 2nd (9.09 Hz)
    code, out, _ = run(capsys, path, "--signal", "tension", "--tach", "unwind=unwind_enc",
                       "--tach", "idle=idle_speed", "--kind", "unwind=angle", "--out", tmp_path)
    assert code == 0
    peak = next(p for p in json.loads((tmp_path / "orders.json").read_text())["peaks"]
                if abs(p["frequency_hz"] - 9.09) < 0.05)
    assert peak["status"] == "ambiguous" and peak["family"] is None
    ev = {c["family"]: c["order_amplitude"] for c in peak["candidates"]}
    assert ev["idle"] == pytest.approx(0.4, abs=0.03) and ev["unwind"] < 0.1
    assert "ambiguous: idle x2" in out


def test_model_angle_kind_is_refined(csv_path, tmp_path, capsys):
    path, truth = csv_path
    rec, _ = ewl_like()
    theta_model = truth["unwind"]["theta"] * 0.995  # 0.5 % off
    csv = tmp_path / "model.csv"
    np.savetxt(csv, np.column_stack([rec.time, rec["tension"], theta_model]), delimiter=",", fmt="%.9g",
               header="time,tension [N],unwind_model [rad]", comments="")
    code, out, err = run(capsys, csv, "--signal", "tension", "--tach", "unwind=unwind_model", "--kind", "model",
                         "--out", tmp_path)
    assert code == 0, err
    unwind = json.loads((tmp_path / "orders.json").read_text())["shafts"]["unwind"]
    assert unwind["kind"] == "model" and unwind["scale"] == pytest.approx(1 / 0.995, abs=2e-3)
    assert [h["amplitude"] for h in unwind["harmonics"][:3]] == pytest.approx(truth["unwind"]["amplitude"], abs=0.05)


@pytest.mark.parametrize("args, message", [
    (["--tach", "unwind=nope"], "no column 'nope'"),
    (["--tach", "unwind"], "expected NAME=VALUE"),
    (["--tach", "unwind=unwind_pulse", "--kind", "roller=pulse"], "no --tach named 'roller'"),
    (["--tach", "unwind=unwind_pulse", "--kind", "laser"], "kind must be one of"),
    (["--tach", "unwind=tension", "--kind", "speed"], "shaft unwind (column 'tension')"),
])
def test_bad_arguments_exit_2(csv_path, capsys, args, message):
    path, _ = csv_path
    code, _, err = run(capsys, path, "--signal", "tension", *args)
    assert code == 2 and message in err


def test_bad_data_exit_2(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("time,tension [N],w [rad/s]\n" + "\n".join(f"{t},{1.0},{1.0}" for t in (0, 0.1, 0.2, 0.15, 0.4,
                                                                                          0.5, 0.6, 0.7, 0.8)))
    code, _, err = run(capsys, bad, "--signal", "tension", "--tach", "r=w")
    assert code == 2 and "not strictly increasing" in err and "bad.csv" in err
    code, _, err = run(capsys, tmp_path / "missing.csv", "--signal", "tension", "--tach", "r=w")
    assert code == 2 and "cannot read" in err
    speed = tmp_path / "speed.csv"
    speed.write_text("time,tension [N],v [ft/min]\n" + "\n".join(f"{k * 0.01},{np.sin(k)},200" for k in range(500)))
    code, _, err = run(capsys, speed, "--signal", "tension", "--tach", "r=v", "--kind", "speed")
    assert code == 2 and "needs the roll radius" in err


def test_main_returns_int_without_out(csv_path, capsys):
    path, _ = csv_path
    assert orders_cmd.main([str(path), "--signal", "tension", "--tach", "idle=idle_speed"]) == 0
    assert "harmonic fit" in capsys.readouterr().out
