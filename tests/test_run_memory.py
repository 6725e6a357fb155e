"""A run whose results cannot fit in memory is refused before it starts (exit code 2,
``file:line: experiment.duration: reason`` with the size and what to change)."""
import re
import subprocess
import sys
from pathlib import Path

import pytest

from webline.orchestrator.memory import (BYTES, COPIES, SHARE, ResultTooLarge, available_memory,
                                         check_result_memory, output_rows, result_columns)
from webline.orchestrator.system import Component, Experiment, System

ROOT = Path(__file__).resolve().parent.parent
EWL = ROOT / "scenarios" / "ewl.yaml"


def two_spans(stop, step=1e-3, output_interval=0.0):
    comps = [Component(n, "Span", {"EA": 2e4, "L0": 1.0, "T0": 0.0}, {"v_in": 1.0, "v_out": 1.01})
             for n in ("a", "b")]
    return System(comps, [], Experiment(0.0, stop, step, output_interval=output_interval))


def test_result_size_is_rows_times_columns_times_eight_bytes():
    # 1 s at 1 ms, a row every 10 ms: 101 rows; two Spans of 4 outputs (T, L, dL, dT) + time = 9 columns
    system = two_spans(1.0, output_interval=0.01)
    assert output_rows(system.experiment) == (101, pytest.approx(0.01))
    assert result_columns(system) == 8
    assert check_result_memory(system, available=1e12) == COPIES * 101 * 9 * BYTES
    # every step recorded (output_interval 0): 1001 rows
    assert check_result_memory(two_spans(1.0), available=1e12) == COPIES * 1001 * 9 * BYTES


def test_a_table_over_the_share_of_memory_is_refused_with_what_to_change():
    system = two_spans(1.0, output_interval=0.01)
    needed = COPIES * 101 * 9 * BYTES
    assert check_result_memory(system, available=needed / SHARE) == needed  # just fits
    with pytest.raises(ResultTooLarge) as info:
        check_result_memory(system, available=needed / SHARE - 1)
    exc = info.value
    assert exc.needed == needed and exc.rows == 101 and exc.columns == 8
    text = str(exc)
    assert "experiment.duration" in text and "experiment.output_interval" in text
    # the suggested duration does fit (at the same output interval)
    duration = float(text.split("to at most ")[1].split(" s")[0])
    assert 0 < duration < 1.0
    check_result_memory(two_spans(duration, output_interval=0.01), available=needed / SHARE - 1)


def test_available_memory_is_read():
    mem = available_memory()
    assert mem is None or mem > 0


@pytest.mark.skipif(not EWL.exists(), reason="no scenarios/ewl.yaml")
def test_run_too_long_for_memory_is_refused_before_it_starts(tmp_path):
    out = tmp_path / "out"
    p = subprocess.run([sys.executable, "-m", "webline.cli", "run", "scenarios/ewl.yaml",
                        "--set", "experiment.duration=1e9s", "--out", str(out), "--no-progress"],
                       cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert p.returncode == 2, p.stderr
    err = p.stderr
    assert "scenarios/ewl.yaml: --set experiment.duration=1e9s: experiment.duration:" in err, err
    # 5e11 rows x ~140 columns: about a PiB (the unit follows the column count)
    assert "experiment.output_interval" in err and re.search(r"need [0-9.]+ [TPE]iB", err), err
    assert "Traceback" not in err and "MemoryError" not in err
    assert not (out / "results.h5").exists() and not out.exists()  # nothing ran, nothing saved


@pytest.mark.skipif(not EWL.exists(), reason="no scenarios/ewl.yaml")
def test_duration_in_the_layout_file_is_named_by_its_line(tmp_path, capsys):
    from webline.orchestrator import run_cmd
    layout = tmp_path / "long.yaml"
    layout.write_text(f"base: {EWL}\nname: long\nexperiment:\n  duration: 1e9 s\n")
    assert run_cmd.main([str(layout), "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert f"{layout}:4: experiment.duration: the results would need" in err, err
    assert not (tmp_path / "out").exists()


@pytest.mark.skipif(not EWL.exists(), reason="no scenarios/ewl.yaml")
def test_sweep_validation_refuses_a_run_too_long_for_memory(tmp_path):
    from webline.orchestrator.sweep import SweepError, load_sweep, validate_overrides
    sweep = tmp_path / "s.yaml"
    sweep.write_text(f"layout: {EWL}\ngrid:\n  experiment.duration: [1 s, 1e9 s]\n")
    with pytest.raises(SweepError, match=r"grid\.experiment\.duration: run .*the results would need"):
        validate_overrides(load_sweep(sweep))


def test_master_refuses_before_instantiating_any_fmu(monkeypatch):
    # sweep workers, diagnose and accuracy runs call master.simulate directly: same check, the
    # master's own column count, before an FMU is instantiated
    from webline.orchestrator import master, memory
    monkeypatch.setattr(memory, "available_memory", lambda: 1000.0)
    monkeypatch.setattr(master.Slave, "instantiate", lambda self: pytest.fail("instantiated"))
    with pytest.raises(ResultTooLarge):
        master.simulate(two_spans(1.0), progress=False)
