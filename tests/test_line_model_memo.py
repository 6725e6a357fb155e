"""LineModel.simulate_many hands back a simulation some caller still holds.

The engine is replaced by a counter: what is tested is which jobs reach it.
"""
import gc
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from webline.diagnosis import layout_edit
from webline.diagnosis.line_model import LineModel, RunColumns, Sim

LAYOUT = Path(__file__).resolve().parents[1] / "scenarios" / "ewl.yaml"


def _model():
    model = LineModel(LAYOUT)
    asked = []

    def uncached(jobs, written=None):
        asked.extend(label for _, _, label in jobs)
        t = np.linspace(0.0, 1.0, 11)
        return [Sim(None, RunColumns(t, {"lc.T": t * (k + 1)}, t)) for k, _ in enumerate(jobs)]

    model._simulate_many_uncached = uncached
    return model, asked


def _run(name="run1", **overrides):
    return SimpleNamespace(name=name, overrides=overrides, t=np.linspace(0.0, 1.0, 11))


def test_repeated_job_in_one_call_is_simulated_once():
    model, asked = _model()
    run = _run()
    doc = layout_edit.with_set(model.copy_doc(), "web.E", "2.3e8 Pa")
    a, b = model.simulate_many([(run, doc, "first"), (run, doc, "again")])
    assert asked == ["first"] and a is b and model.n_reused == 1
    model.cleanup()


def test_held_simulation_is_reused_released_one_is_not():
    model, asked = _model()
    run = _run()
    doc = layout_edit.with_set(model.copy_doc(), "web.E", "2.3e8 Pa")
    held = model.simulate_many([(run, doc, "first")])[0]
    # an equal document built anew, the same run conditions in a new run object
    again = model.simulate_many([(_run(), layout_edit.with_set(model.copy_doc(), "web.E", "2.3e8 Pa"), "second")])[0]
    assert again is held and asked == ["first"]
    del held, again
    gc.collect()
    model.simulate_many([(run, doc, "third")])
    assert asked == ["first", "third"]
    model.cleanup()


def test_other_conditions_or_layout_are_simulated():
    model, asked = _model()
    doc = layout_edit.with_set(model.copy_doc(), "web.E", "2.3e8 Pa")
    other = layout_edit.with_set(model.copy_doc(), "web.E", "2.4e8 Pa")
    held = model.simulate_many([(_run(), doc, "a"), (_run(**{"path.unwind.radius": "5 in"}), doc, "b"),
                                (_run("run2"), doc, "c"), (_run(), other, "d"), (_run(), None, "e")])
    assert asked == ["a", "b", "c", "d", "e"] and model.n_reused == 0
    assert len({id(s) for s in held}) == 5
    model.cleanup()


def test_shared_columns_are_read_only():
    model, _ = _model()
    sim = model.simulate_many([(_run(), None, "a")])[0]
    with pytest.raises(ValueError):
        sim.columns["lc.T"][0] = 1.0
    model.cleanup()
