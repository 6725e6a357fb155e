"""The fast engine's models built without instantiating the FMUs (``reference.model_only``)
are the models the FMU slaves build: every generated line of code, parameter, initial
state and input start equal, on lines with every component form a diagnosis writes."""
from pathlib import Path

import numpy as np
import pytest
import yaml

from webline.orchestrator import engine, reference
from webline.orchestrator.layout import load_system
from webline.orchestrator.system import Component

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"

FORMS = {   # what the diagnosis and the benchmark's truths write into a line
    "path.sw_leader.eccentricity": {"C": ["0.2 mm", "0.05 mm"], "psi": ["10 deg", "80 deg"]},
    "drives.speed_loops.unwind.drive": {"motor_inertia": "0.01 kg*m^2", "stiffness": "40 N*m/rad",
                                        "damping": "0.05 N*m*s/rad", "backlash": "0.01 rad"},
    "drives.speed_loops.rewind.feedforward": "reference",
    "drives.speed_loops.rewind.current_lag": "2 ms",
    "drives.speed_loops.sw_leader.feedforward": "none",
    "web.damping": "2 ms",
    "sensors.lc9.filter_order": 2,
    "sensors.lc9.filter_damping": 0.7,
    "sensors.lc19.filter": "8 ms",
}


def _both(system, monkeypatch):
    """(ReferenceSystem on ModelOnly records, the same on instantiated FMU slaves)."""
    reference._REUSE.clear()
    light = reference.ReferenceSystem(system, reuse=True)
    with monkeypatch.context() as m:
        m.setattr(reference, "_reused", reference.instantiate)   # the same arguments
        full = reference.ReferenceSystem(system, reuse=True)
    return light, full


@pytest.mark.parametrize("layout", ["ewl.yaml", "ewl_out_of_round.yaml", "forms"])
def test_models_equal_the_fmu_slaves(layout, tmp_path, monkeypatch):
    if layout == "forms":
        path = tmp_path / "forms.yaml"
        path.write_text(yaml.safe_dump({"base": str(SCENARIOS / "ewl.yaml"), "set": FORMS}))
    else:
        path = SCENARIOS / layout
    system = load_system(path)
    light, full = _both(system, monkeypatch)
    assert all(isinstance(s, reference.ModelOnly) for s in light.slaves)
    assert not any(isinstance(s, reference.ModelOnly) for s in full.slaves)
    a, b = engine._Builder(light), engine._Builder(full)
    assert a.source() == b.source()
    assert a.pnames == b.pnames and np.array_equal(np.array(a.p), np.array(b.p))
    assert np.array_equal(light.x0, full.x0) and light.u == full.u
    assert light.columns == full.columns and light.units == full.units and light.state_names == full.state_names
    assert [[(o, len(d)) for o, d in e] for *_, e in light.schedule] == \
        [[(o, len(d)) for o, d in e] for *_, e in full.schedule]
    if layout == "forms":   # the forms reached the models
        names = [type(m).__name__ for m in light.models]
        assert "LoadCellModel" in names and any(getattr(m, "drive", None) is not None
                                                and getattr(m.drive, "enabled", False) for m in light.models)


def _component(**parameters):
    return Component(name="idler", model="IdleRoller", parameters=parameters)


def test_errors_name_the_component_as_the_fmu_path_does():
    classes = reference.fmu_classes()
    for comp in (_component(no_such=1.0), _component(R=-0.05), Component(name="x", model="Nope")):
        with pytest.raises((KeyError, ValueError)) as light:
            reference.model_only(comp, classes)
        with pytest.raises((KeyError, ValueError)) as full:
            reference.instantiate(comp, 0.0, 1.0, classes)
        assert type(light.value) is type(full.value)
        if isinstance(light.value, KeyError):
            assert str(light.value) == str(full.value)
        else:   # the parameter's check, named (the FMU path's message repeats it)
            assert str(light.value).split(": ")[0] == str(full.value).split(": ")[0] and "R" in str(light.value)
