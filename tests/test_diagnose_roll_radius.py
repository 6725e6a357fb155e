"""A roll's start radius is a run condition (issue 9 item 2): when the run file's
unwind radius is 1.5 % off the line's, the model's unwind angle slips by half a
revolution over a 30 s record at ~1 Hz and the angle-locked estimate of an
out-of-round unwind decoheres. The diagnosis searches a speed scale per run for a
roll and carries it as a corrected start radius R_true = R_run / (1 + kappa) in
that run's conditions; every simulation of the run uses it.

Data from the fast engine (the diagnosis's own), 30 s at 250 Hz, 0.3 N noise."""
from pathlib import Path

import numpy as np
import pytest

EWL = Path(__file__).resolve().parents[1] / "scenarios" / "ewl.yaml"
INCH = 0.0254


def test_unwind_radius_off_by_1_5_percent_is_corrected_per_run(tmp_path):
    import yaml
    from webline.orchestrator import engine
    from webline.orchestrator.layout import load_system
    from webline.diagnosis.pipeline import Options, diagnose
    from webline.diagnosis.runs import _experiment_overrides

    C = [0.40e-3, 0.15e-3]
    psi = [0.7, -1.2]
    R_file = 6.375 * INCH
    R_true = 1.015 * R_file
    tset = {"path.unwind.eccentricity": {"C": [f"{c * 1e3} mm" for c in C], "psi": [f"{p} rad" for p in psi]}}
    (tmp_path / "truth.yaml").write_text(yaml.safe_dump({"base": str(EWL), "set": tset}))
    exp_file = {"duration": "30 s", "line_speed": "200 ft/min", "roll_radius": {"unwind": f"{R_file:.9g} m"}}
    exp_true = dict(exp_file, roll_radius={"unwind": f"{R_true:.9g} m"})
    system = load_system(tmp_path / "truth.yaml", _experiment_overrides(exp_true, "<run>", {}))
    system.experiment.output_interval = 1.0 / 250.0
    res = engine.simulate(system)
    assert res.ok, res.message
    t = np.asarray(res.time)
    rng = np.random.default_rng(5)
    cols = {f"{lc} [N]": np.asarray(res[f"{lc}.T"]) + rng.normal(0, 0.3, len(t)) for lc in ("lc9", "lc15", "lc19")}
    np.savetxt(tmp_path / "r1.csv", np.column_stack([t] + list(cols.values())), delimiter=",",
               header=",".join(["time [s]"] + list(cols)), comments="", fmt="%.9g")
    (tmp_path / "r1.yaml").write_text(yaml.safe_dump({"data": "r1.csv", "experiment": exp_file}))

    rep = diagnose(EWL, [tmp_path / "r1.yaml"], out=tmp_path / "out",
                   options=Options(fmu_paths={}, jobs=1, harmonics=2, confirm=False, structure=False))
    assert rep["effects"], rep["verdict"]
    eff = rep["effects"][0]
    assert (eff["element"], eff["kind"]) == ("unwind", "out_of_round")
    amp = {h["order"]: h["amplitude"] for h in eff["harmonics"]}
    assert amp[1] == pytest.approx(C[0], rel=0.2)
    corr = rep["run_corrections"]["r1"]
    R_est = float(corr["experiment.roll_radius.unwind"].split()[0])
    assert R_est == pytest.approx(R_true, rel=0.003)
    assert corr["kappa"]["unwind"] == pytest.approx(R_file / R_true - 1.0, abs=0.003)
    # the corrected radius is the run's condition in the report
    run = next(r for r in rep["runs"] if r["name"] == "r1")
    assert run["conditions"]["experiment.roll_radius.unwind"].startswith(f"{R_est:.4g}"[:4])
