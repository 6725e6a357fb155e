"""A roll whose start radius no run sheet sets starts at the layout's radius in every
run, so the radius the fit runs found is every run's condition where the run's own data
gave none (independent seed-52 c08: the rewind 0.094 % smaller than written, found on
both fit runs, left at the written radius in the held-out run; its order 5 drifted
1.5 rad over that record and the held-out lc9 NRMSE rose 1.008 -> 1.146).

No simulation: a stand-in model turns the roll at v / R under each run's conditions."""
import dataclasses
import math
from types import SimpleNamespace

import numpy as np
import pytest

from webline.diagnosis.pipeline import Diagnosis, RunCtx

R_LAYOUT = 0.0762
V = 1.0          # m/s
FS = 50.0
KEY = "experiment.roll_radius.rewind"


class _Model:
    """Simulates the rewind's angle v t / R at the run's radius (its override, else the layout's)."""

    def __init__(self):
        self.jobs = []

    def simulate_many(self, jobs):
        out = []
        for run, _doc, label in jobs:
            self.jobs.append((run.name, label))
            R = float(run.overrides[KEY].split()[0]) if KEY in run.overrides else R_LAYOUT
            out.append(SimpleNamespace(columns={"rewind.theta": V * run.t / R}))
        return out


@dataclasses.dataclass
class _Run:          # the fields of diagnosis.runs.Run the step reads (it replaces ``overrides``)
    name: str
    t: np.ndarray
    overrides: dict


def _ctx(name, fit, overrides=None):
    t = np.arange(0.0, 30.0, 1 / FS)
    c = RunCtx(run=_Run(name, t, dict(overrides or {})), fit=fit, mask=np.ones(t.size, bool))
    c.radius0["rewind"] = R_LAYOUT
    c.theta_src["rw"] = "model"
    c.theta["rw"] = V * t / R_LAYOUT
    return c


def _diagnosis(ctx, corrections):
    d = Diagnosis.__new__(Diagnosis)
    d.ctx, d.notes, d.model = ctx, [], _Model()
    d.run_corrections = {n: {KEY: f"{R:.6g} m", "kappa": {"rewind": R_LAYOUT / R - 1.0}}
                         for n, R in corrections.items()}
    return d


ROLL = SimpleNamespace(element="rewind", component="rewind", key="rw", theta="rewind.theta")


def test_a_run_without_its_own_radius_takes_the_fit_runs_when_no_run_sheet_sets_it():
    ctx = [_ctx("run1", True), _ctx("run2", True), _ctx("run3", False)]
    d = _diagnosis(ctx, {"run1": 0.0761163, "run2": 0.076124})
    d._share_layout_radius([ROLL], {c.name: set(c.run.overrides) for c in ctx})
    R_fit = float(np.median([0.0761163, 0.076124]))
    corr = d.run_corrections["run3"]
    assert float(corr[KEY].split()[0]) == pytest.approx(R_fit, rel=1e-5)
    assert corr["kappa"]["rewind"] == pytest.approx(R_LAYOUT / R_fit - 1.0, rel=1e-4)
    assert "fit runs (run1, run2)" in corr["from"]
    held = ctx[2]
    assert held.run.overrides[KEY].startswith("0.07612")
    # the held-out run's angle is the model's at that radius (one simulation, that run only)
    assert d.model.jobs == [("run3", "nominal, the fit runs' radius")]
    assert held.freq["rw"] == pytest.approx(V / R_fit / (2 * math.pi), rel=1e-4)
    assert held.kappa["rw"] == 0.0
    assert any("rewind's start radius" in n and "run3 turn with it" in n for n in d.notes)
    # the fit runs keep their own
    assert d.run_corrections["run1"][KEY] == "0.0761163 m"


def test_a_radius_a_run_sheet_sets_stays_each_runs_own():
    ctx = [_ctx("run1", True, {KEY: "0.0762 m"}), _ctx("run2", True), _ctx("run3", False)]
    d = _diagnosis(ctx, {"run1": 0.0761163})
    d._share_layout_radius([ROLL], {c.name: set(c.run.overrides) for c in ctx})
    assert "run3" not in d.run_corrections and "run2" not in d.run_corrections
    assert d.model.jobs == [] and d.notes == []


def test_nothing_found_on_the_fit_runs_nothing_shared():
    ctx = [_ctx("run1", True), _ctx("run2", False)]
    d = _diagnosis(ctx, {"run2": 0.0761})     # the held-out run's own radius is not the fit runs'
    d._share_layout_radius([ROLL], {c.name: set(c.run.overrides) for c in ctx})
    assert "run1" not in d.run_corrections
    assert d.model.jobs == []
