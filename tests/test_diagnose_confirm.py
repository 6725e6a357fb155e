"""The co-simulation confirms: webline diagnose runs its refined layout once through
the FMU co-simulation at the end and reports both engines' refined NRMSE.

One short record (8 s at 250 Hz) of the test_diagnose line with a hidden
eccentricity, made by the fast engine (cheap), plus noise; and a 5 s held-out record.
The layout's co-simulation step is 1 ms: at 2 ms its step error (6e-4 of the
tension, measured) is 15 % of this record's small fluctuation and the check
rightly warns (docs/diagnose.md); at 1 ms it is 1.4e-4.
"""
import json

import numpy as np
import pytest
import yaml

from test_diagnose import HIDDEN, LAYOUT, NOISE


def _record(folder, name, speed, seconds, seed):
    from webline.diagnosis.runs import write_csv
    from webline.orchestrator import engine
    from webline.orchestrator.layout import load_system
    ov = {"experiment.line_speed": speed, "experiment.duration": f"{seconds} s",
          f"path.{HIDDEN['element']}.eccentricity.C": "[" + ", ".join(HIDDEN["C"]) + "]",
          f"path.{HIDDEN['element']}.eccentricity.psi": "[" + ", ".join(HIDDEN["psi"]) + "]"}
    system = load_system(folder / "line.yaml", ov)
    system.experiment.output_interval = 0.004   # 250 Hz
    result = engine.simulate(system)
    assert result.ok, result.message
    t = np.asarray(result.time)
    y = np.asarray(result["lc.T"]) + np.random.default_rng(seed).normal(0.0, NOISE, len(t))
    write_csv(folder / f"{name}.csv", t, {"lc.T": y})
    (folder / f"{name}.yaml").write_text(yaml.safe_dump(
        {"data": f"{name}.csv", "experiment": {"line_speed": speed, "duration": f"{seconds} s"}}))
    return folder / f"{name}.yaml"


@pytest.fixture(scope="module")
def case(tmp_path_factory, fmus):
    d = tmp_path_factory.mktemp("confirm")
    assert "step: 2 ms" in LAYOUT
    (d / "line.yaml").write_text(LAYOUT.replace("step: 2 ms", "step: 1 ms"))
    return d, _record(d, "fit", "200 ft/min", 8, 1), _record(d, "held", "150 ft/min", 5, 2)


def diagnose(args):
    from webline.diagnosis.diagnose_cmd import main
    return main([str(a) for a in args] + ["--quiet", "--jobs", "1"])


def test_cosim_confirms_refined_gap(case, tmp_path):
    from webline.diagnosis.confirm import EPS_COSIM
    from webline.diagnosis.runs import load_run
    d, fit, held = case
    out = tmp_path / "out"
    assert diagnose([d / "line.yaml", fit, "--out", out, "--holdout", held, "--no-structure"]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert rep["effects"] and rep["effects"][0]["element"] == "idler1", rep["verdict"]
    c = rep["confirm"]
    assert c["status"] == "done" and c["wall_s"] > 0
    assert set(c["runs"]) == {"fit", "held"}                     # fit and held-out runs
    for run, per in c["runs"].items():
        v = per["lc.T"]
        gap = rep["gap"]["lc.T"]["by_run"][run]
        assert v["refined_fast"] == pytest.approx(gap["refined"]["nrmse"], rel=1e-12)
        # the co-simulation ran the refined layout (with the eccentricity), not the nominal one
        assert v["refined_cosim"] < 0.5 * gap["nominal"]["nrmse"]
        # exact: |NRMSE(y, b) - NRMSE(y, a)| <= rms(b - a) / std(y)
        assert abs(v["difference"]) <= v["bound"] * (1 + 1e-9)
        # the two engines' tensions differ by no more than the co-simulation's error at 2 ms
        # (accuracy table, worst load cell 2.2e-3; the fast engine is the reference to ~1e-6),
        # so the NRMSE by no more than EPS_COSIM rms(T) / std(y) (T ~ y: noise 0.05 N of 67 N)
        assert v["tension_rel_rms"] < EPS_COSIM and v["within_step_error"]
        y = load_run(fit if run == "fit" else held).columns["lc.T"]
        assert abs(v["difference"]) <= EPS_COSIM * np.sqrt(np.mean(y ** 2)) / np.std(y)
        # and below the warning threshold (5 % relative, 0.02 absolute)
        assert abs(v["difference"]) <= max(0.02, 0.05 * v["refined_fast"]) and not v["exceeds_threshold"]
    assert c["agrees"] is True
    assert c["in_sample"]["lc.T"]["refined_cosim"] == pytest.approx(c["runs"]["fit"]["lc.T"]["refined_cosim"])
    assert "co-simulation confirms" in rep["verdict"].lower()
    assert "Co-simulation check" in (out / "report.html").read_text()


def test_no_confirm_omits_it_failing_or_differing_confirm_noted(case, tmp_path, monkeypatch):
    d, fit, _ = case
    cheap = ["--no-structure", "--no-other", "--no-polish"]
    out = tmp_path / "off"
    assert diagnose([d / "line.yaml", fit, "--out", out, "--no-confirm", *cheap]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert "confirm" not in rep and "co-simulation" not in rep["verdict"]
    assert rep["effects"]

    from webline.diagnosis.line_model import LineModel

    def broken(self, *a, **k):
        raise RuntimeError("FMU instantiation refused")
    monkeypatch.setattr(LineModel, "confirm", broken)
    out = tmp_path / "failed"
    assert diagnose([d / "line.yaml", fit, "--out", out, *cheap]) == 0
    rep2 = json.loads((out / "report.json").read_text())
    assert rep2["confirm"]["status"] == "failed" and "FMU instantiation refused" in rep2["confirm"]["error"]
    assert any("co-simulation check failed" in n for n in rep2["notes"])
    assert rep2["effects"][0]["element"] == rep["effects"][0]["element"]      # the fast result stands
    assert rep2["gap"]["lc.T"]["refined"]["nrmse"] == pytest.approx(rep["gap"]["lc.T"]["refined"]["nrmse"])
    assert (out / "report.html").is_file() and (out / "refined_layout.yaml").is_file()

    # an engine that disagrees beyond the co-simulation's step error: tension 1 % high
    def off(self, run, doc=None, edits=(), label=""):
        sim = self._simulate_fast(run, doc, edits, label)
        sim.columns = {k: 1.01 * v for k, v in sim.columns.items()}
        return sim
    monkeypatch.setattr(LineModel, "confirm", off)
    out = tmp_path / "differs"
    assert diagnose([d / "line.yaml", fit, "--out", out, *cheap]) == 0
    rep3 = json.loads((out / "report.json").read_text())
    v = rep3["confirm"]["runs"]["fit"]["lc.T"]
    assert v["tension_rel_rms"] == pytest.approx(0.01, rel=1e-9)
    assert v["exceeds_threshold"] and not v["within_step_error"] and rep3["confirm"]["agrees"] is False
    assert any(n.startswith("warning: run fit, lc.T") and "engines disagree" in n for n in rep3["notes"])
    assert "co-simulation differs beyond its step error" in rep3["verdict"].lower()
