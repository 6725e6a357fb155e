"""webline sweep: sweep files, run bookkeeping, failure isolation, and a small real
sweep of the EWL on a Dask LocalCluster (2 worker processes)."""
import csv
import json
import math
import sys
from pathlib import Path

import pytest

from webline.orchestrator.sweep import (SweepError, dominant_frequency, load_sweep, read_table, run_sweep)
from webline.orchestrator import sweep_cmd

ROOT = Path(__file__).resolve().parent.parent
FAKE = "sweep_fakes:fake_run"


def write(path, text):
    path.write_text(text)
    return path


@pytest.fixture
def layout(tmp_path):
    return write(tmp_path / "line.yaml", "name: dummy\n")


# ---- sweep files ------------------------------------------------------------------
def test_grid_expands_in_file_order_with_si_values(tmp_path, layout):
    s = load_sweep(write(tmp_path / "s.yaml", """
layout: line.yaml
set: {experiment.duration: 2 s}
grid:
  unwind.radius: [4.75 in, 6.75 in]
  experiment.line_speed: {start: 100 ft/min, stop: 300 ft/min, num: 3}
"""))
    assert s.mode == "grid" and s.name == "s" and len(s.runs) == 6
    assert s.parameters == ["unwind.radius", "experiment.line_speed"]
    first, last = s.runs[0], s.runs[-1]
    assert first.swept == {"unwind.radius": "4.75 in", "experiment.line_speed": "100 ft/min"}
    assert last.overrides == {"experiment.duration": "2 s", "unwind.radius": "6.75 in",
                              "experiment.line_speed": "300 ft/min"}
    assert first.si()["unwind.radius"] == pytest.approx(0.12065)
    assert first.si()["experiment.line_speed"] == pytest.approx(0.508)
    assert len({r.key for r in s.runs}) == 6 and all(len(r.key) == 12 for r in s.runs)


def test_run_key_depends_on_overrides_and_layout_text(tmp_path, layout):
    text = "layout: line.yaml\ngrid: {a.b: [1, 2]}\n"
    k1 = [r.key for r in load_sweep(write(tmp_path / "s.yaml", text)).runs]
    assert k1 == [r.key for r in load_sweep(tmp_path / "s.yaml").runs]
    write(layout, "name: changed\n")
    assert not set(k1) & {r.key for r in load_sweep(tmp_path / "s.yaml").runs}


def test_monte_carlo_is_reproducible_and_keeps_units(tmp_path, layout):
    text = """
layout: line.yaml
monte_carlo:
  n: 50
  seed: 7
  unwind.radius: {dist: uniform, low: 4.75 in, high: 6.75 in}
  experiment.line_speed: {dist: normal, mean: 200 ft/min, std: 10 ft/min, min: 190 ft/min}
"""
    a = load_sweep(write(tmp_path / "mc.yaml", text))
    b = load_sweep(tmp_path / "mc.yaml")
    assert [r.swept for r in a.runs] == [r.swept for r in b.runs] and len(a.runs) == 50
    radii = [r.si()["unwind.radius"] for r in a.runs]
    assert all(0.12065 <= x <= 0.17145 for x in radii)
    assert all(r.swept["unwind.radius"].endswith(" in") for r in a.runs)
    speeds = [r.si()["experiment.line_speed"] for r in a.runs]
    assert min(speeds) >= 190 * 0.3048 / 60 - 1e-12


@pytest.mark.parametrize("text, field", [
    ("grid: {a.b: [1]}\n", "layout"),
    ("layout: nope.yaml\ngrid: {a.b: [1]}\n", "layout"),
    ("layout: line.yaml\n", "grid"),
    ("layout: line.yaml\ngrid: {a.b: [1]}\nmonte_carlo: {n: 2, a.c: {dist: uniform, low: 0, high: 1}}\n", "grid"),
    ("layout: line.yaml\ngrid: {radius: [1]}\n", "grid.radius"),
    ("layout: line.yaml\ngrid: {a.b: []}\n", "grid.a.b"),
    ("layout: line.yaml\ngrid: {a.b: {start: 1 in, stop: 2 s, num: 3}}\n", "grid.a.b"),
    ("layout: line.yaml\ngrid: {a.b: {start: 1 in, stop: 2 in, num: 0}}\n", "grid.a.b.num"),
    ("layout: line.yaml\nmonte_carlo: {n: 0, a.b: {dist: uniform, low: 0, high: 1}}\n", "monte_carlo.n"),
    ("layout: line.yaml\nmonte_carlo: {n: 3, a.b: {dist: lognormal, mean: 1}}\n", "monte_carlo.a.b.dist"),
    ("layout: line.yaml\nmonte_carlo: {n: 3, a.b: {dist: uniform, low: 1 in}}\n", "monte_carlo.a.b"),
    ("layout: line.yaml\nmonte_carlo: {n: 3, a.b: {dist: normal, mean: 1 in, std: 1 s}}\n", "monte_carlo.a.b.std"),
    ("layout: line.yaml\nmonte_carlo: {n: 3, a.b: {dist: uniform, low: 2 furlongs per banana, high: 1}}\n",
     "monte_carlo.a.b.low"),
    ("layout: line.yaml\ngrid: {a.b: [1]}\nset: {a.b: 2}\n", "set.a.b"),
    ("layout: line.yaml\ngrid: {a.b: [1]}\nextra: 1\n", "extra"),
    ("layout: line.yaml\ngrid: {a.b: [1]}\nmetrics: {steady_start: 3 m}\n", "metrics.steady_start"),
    ("layout: [\n", ""),
])
def test_bad_sweep_files_name_file_and_field(tmp_path, layout, text, field, capsys):
    path = write(tmp_path / "bad.yaml", text)
    with pytest.raises(SweepError) as err:
        load_sweep(path)
    assert err.value.field == field and str(path) in str(err.value)
    assert sweep_cmd.main([str(path), "--out", str(tmp_path / "o")]) == 2
    assert f"{path}: {field}" in capsys.readouterr().err


def test_dominant_frequency_refines_between_bins():
    import numpy as np
    t = np.arange(0.0, 20.0, 1e-3)
    x = 100 + 3 * np.sin(2 * np.pi * 1.2345 * t) + 0.5 * np.sin(2 * np.pi * 7.0 * t) + 0.2 * t
    f, a = dominant_frequency(t, x, f_min=0.2)
    assert f == pytest.approx(1.2345, rel=2e-3) and a == pytest.approx(3.0, rel=0.05)
    assert math.isnan(dominant_frequency(t, np.full_like(t, 5.0))[0])


# ---- running (a fake run stands in for the simulation) ------------------------------
def fake_sweep(tmp_path, layout, modes=("ok", "fail", "crash", "ok2")):
    return load_sweep(write(tmp_path / "fake.yaml", f"""
layout: {layout.name}
set: {{fake.sleep: 0.2}}
grid:
  fake.mode: [{", ".join(modes)}]
"""))


def executions(out, row):
    p = out / row["run_dir"] / "executions"
    return int(p.read_text()) if p.exists() else 0


def test_failures_are_recorded_and_finished_runs_skipped(tmp_path, layout):
    sweep = fake_sweep(tmp_path, layout)
    out = tmp_path / "out"
    rows = run_sweep(sweep, out, workers=2, progress=False, runner=FAKE)
    assert [r["status"] for r in rows] == ["ok", "error", "crashed", "ok"]
    assert "diverged on purpose" in rows[1]["error"] and "RuntimeError" in rows[1]["error"]
    assert "died" in rows[2]["error"]
    assert rows[0]["lc.T.mean"] == 10.0 and rows[0]["wall_time"] > 0
    table = read_table(out / "sweep.csv")
    assert [r["status"] for r in table] == ["ok", "error", "crashed", "ok"]
    assert table[0]["fake.mode"] == "ok" and table[3]["lc.T.mean"] == 10.0
    assert len({r["pid_seen"] for r in table if r["status"] == "ok"}) == 2  # one process per run
    assert json.loads((out / rows[0]["run_dir"] / "summary.json").read_text())["key"] == rows[0]["key"]

    # a crash takes its pool down: the crashed run and runs in flight are retried
    # alone, so the crashed run (and perhaps others) executed twice.
    counts = [executions(out, r) for r in rows]
    assert counts[0] in (1, 2) and counts[1] in (1, 2) and counts[2] == 2
    again = run_sweep(sweep, out, workers=2, progress=False, runner=FAKE)
    assert [executions(out, r) for r in again] == counts  # nothing re-ran
    assert [r["status"] for r in again] == ["ok", "error", "crashed", "ok"]
    run_sweep(sweep, out, workers=2, progress=False, runner=FAKE, retry_failed=True)
    now = [executions(out, r) for r in again]
    assert now[0] == counts[0] and now[3] == counts[3]  # ok runs stay done
    assert now[1] - counts[1] in (1, 2) and now[2] - counts[2] == 2  # failed ones ran again


def test_fake_sweep_on_a_dask_local_cluster(tmp_path, layout):
    distributed = pytest.importorskip("distributed")
    sweep = fake_sweep(tmp_path, layout, modes=("ok", "fail", "crash"))
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        rows = run_sweep(sweep, tmp_path / "out", scheduler=cluster.scheduler_address,
                         progress=False, runner=FAKE)
        assert [r["status"] for r in rows] == ["ok", "error", "crashed"]
        assert "exited with code 3" in rows[2]["error"]


# ---- the real line ----------------------------------------------------------------
def test_bad_layout_key_is_a_sweep_error_before_any_run(tmp_path, capsys):
    path = write(tmp_path / "s.yaml", f"""
layout: {ROOT / "scenarios" / "ewl.yaml"}
grid:
  unwind.radiuss: [5 in]
""")
    assert sweep_cmd.main([str(path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert f"{path}: grid.unwind.radiuss:" in err and "radiuss" in err
    assert not (tmp_path / "o").exists()


def test_small_ewl_sweep_on_a_dask_local_cluster(tmp_path, fmus, capsys):
    """Two 1 s runs of the EWL on a LocalCluster of 2 worker processes, through the CLI."""
    distributed = pytest.importorskip("distributed")
    import h5py
    sweep_file = write(tmp_path / "speed.yaml", f"""
name: ewl_speed
layout: {ROOT / "scenarios" / "ewl.yaml"}
set:
  experiment.duration: 1 s
  unwind.eccentricity: {{C: [0.6 mm]}}
grid:
  experiment.line_speed: [150 ft/min, 250 ft/min]
metrics: {{steady_start: 0.5 s}}
plot: {{type: frequency_vs_rotation, y: lc9.T.f_dom, roll: unwind,
        speed: experiment.line_speed, radius: unwind.radius}}
""")
    out = tmp_path / "out"
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        argv = [str(sweep_file), "--out", str(out), "--scheduler", cluster.scheduler_address, "--no-progress"]
        assert sweep_cmd.main(argv) == 0, capsys.readouterr().err
        rows = read_table(out / "sweep.csv")
        assert [r["status"] for r in rows] == ["ok", "ok"], [r["error"] for r in rows]
        assert [r["experiment.line_speed"] for r in rows] == ["150 ft/min", "250 ft/min"]
        assert rows[0]["experiment.line_speed.si"] == pytest.approx(0.762)
        R = 6.375 * 0.0254
        for r in rows:
            assert r["error"] == "" and r["wall_time"] > 0 and r["sim_time"] == pytest.approx(1.0)
            for lc in ("lc9", "lc15", "lc19"):  # 15 lbf in both zones, held by the controllers
                assert r[f"{lc}.T.mean"] == pytest.approx(15 * 4.4482216, rel=0.05)
                assert r[f"{lc}.T.p2p"] >= 0
            # the roll turns with the unstretched web: within 2 % of v/(2 pi R)
            assert r["unwind.f_rot"] == pytest.approx(r["experiment.line_speed.si"] / (2 * math.pi * R), rel=0.02)
            with h5py.File(out / r["run_dir"] / "results.h5") as f:
                assert f["lc9.T"].shape == f["time"].shape and f["time"][-1] == pytest.approx(1.0)
        assert (out / "frequency_vs_rotation.png").stat().st_size > 0
        stamp = [(out / r["run_dir"] / "summary.json").stat().st_mtime_ns for r in rows]
        assert sweep_cmd.main(argv) == 0  # finished runs are skipped
        assert [(out / r["run_dir"] / "summary.json").stat().st_mtime_ns for r in rows] == stamp


def test_dominant_frequency_ignores_leakage_at_the_band_edge():
    import numpy as np
    t = np.arange(0.0, 10.0, 1e-3)
    x = 20 * np.sin(2 * np.pi * 0.15 * t) + 1.0 * np.sin(2 * np.pi * 3.3 * t)  # strong slow drift below f_min
    f, _ = dominant_frequency(t, x, f_min=0.3)
    assert f == pytest.approx(3.3, rel=5e-3)
