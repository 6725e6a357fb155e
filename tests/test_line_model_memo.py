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
        # deterministic, as the engines: the values follow from the layout file and the run
        scales = [1.0 + (hash((str(w), run.name)) % 997) for w, (run, _, _) in zip(written or [None] * len(jobs), jobs)]
        return [Sim(None, RunColumns(t, {"lc.T": t * a, "lc.v": t + a}, t)) for a in scales]

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
    model.RECENT_BYTES = model.READ_BYTES = 0   # nothing kept after its release: only what a caller holds
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


def _size():
    """Bytes of one of the stub's simulations (:func:`_model`) as simulated, and of one column read."""
    t = np.linspace(0.0, 1.0, 11)
    return RunColumns(t, {"lc.T": t, "lc.v": t}, t).nbytes, t.nbytes


def _docs(model, *values):
    return {e: layout_edit.with_set(model.copy_doc(), "web.E", f"{e} Pa") for e in values}


def _released(model, run, doc, label):
    """Simulate, read lc.T, release; returns lc.T's values and the Sim's id."""
    sim = model.simulate_many([(run, doc, label)])[0]
    values, ident = np.array(sim.columns["lc.T"]), id(sim)
    del sim
    gc.collect()
    return values, ident


def test_released_simulation_kept_whole_up_to_the_budget_least_recent_dropped():
    model, asked = _model()
    model.RECENT_BYTES, model.READ_BYTES = 2 * _size()[0], 0   # room for two, nothing after that
    docs = _docs(model, "2.3e8", "2.4e8", "2.5e8")
    _, ident = _released(model, _run(), docs["2.3e8"], "a")
    _released(model, _run(), docs["2.4e8"], "b")
    again = model.simulate_many([(_run(), docs["2.3e8"], "a again")])[0]
    assert id(again) == ident and asked == ["a", "b"] and model.n_reused == 1
    del again
    # "a" was asked for last: a third simulation drops "b", the least recently asked for
    _released(model, _run(), docs["2.5e8"], "c")
    model.simulate_many([(_run(), docs["2.3e8"], "a third"), (_run(), docs["2.4e8"], "b again")])
    assert asked == ["a", "b", "c", "b again"]
    model.cleanup()
    assert not model._recent and not model._read


def test_dropped_simulation_keeps_the_columns_read_another_is_simulated_again():
    model, asked = _model()
    whole, column = _size()
    model.RECENT_BYTES, model.READ_BYTES = whole, 10 * column   # one kept whole
    docs = _docs(model, "2.3e8", "2.4e8")
    first, _ = _released(model, _run(), docs["2.3e8"], "a")
    _released(model, _run(), docs["2.4e8"], "b")   # drops "a" to what its caller read
    sim = model.simulate_many([(_run(), docs["2.3e8"], "a again")])[0]
    assert asked == ["a", "b"] and model.n_reused == 1 and model.n_refilled == 0
    assert np.array_equal(sim.columns["lc.T"], first) and "lc.v" in sim.columns and len(sim.columns) == 2
    # a column no caller read: the run simulated again, once, with the same values
    v = np.array(sim.columns["lc.v"])
    assert asked == ["a", "b", "a"] and model.n_refilled == 1
    assert np.array_equal(v, np.linspace(0.0, 1.0, 11) + first[-1])   # the stub's lc.v = t + a, lc.T = t a
    sim.columns["lc.v"]
    assert model.n_refilled == 1
    with pytest.raises(KeyError):
        sim.columns["nothing"]
    model.cleanup()


def test_columns_read_kept_up_to_their_budget():
    model, asked = _model()
    whole, column = _size()
    model.RECENT_BYTES, model.READ_BYTES = 0, column   # nothing whole; one column read
    docs = _docs(model, "2.3e8", "2.4e8")
    _released(model, _run(), docs["2.3e8"], "a")
    model.simulate_many([(_run(), docs["2.3e8"], "a again")])
    gc.collect()
    assert asked == ["a"]
    _released(model, _run(), docs["2.4e8"], "b")   # its column read drops "a"'s
    model.simulate_many([(_run(), docs["2.3e8"], "a third")])
    assert asked == ["a", "b", "a third"]
    model.cleanup()
