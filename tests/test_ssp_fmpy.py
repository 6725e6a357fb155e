"""A webline SSP in fmpy (docs/fmus-in-other-tools.md, "fmpy").

fmpy 0.3.32's own runner, ``fmpy.ssp.simulation.simulate_ssp``, cannot run the
EWL; the first two tests pin down the two reasons. ``webline.orchestrator.ssp_fmpy``
(fmpy's FMU2Slave, no webline imports) runs it and gives webline's Jacobi master's
numbers."""
from pathlib import Path

import numpy as np
import pytest

from webline.orchestrator.layout import load_system
from webline.orchestrator.master import simulate as webline_simulate
from webline.orchestrator.ssp import export_ssp
from ssp_bindings import full_parameter_set

ROOT = Path(__file__).resolve().parent.parent
EWL = ROOT / "scenarios" / "ewl.yaml"
EWL_OOR = ROOT / "scenarios" / "ewl_out_of_round.yaml"
LOAD_CELLS = ("lc9.T", "lc15.T", "lc19.T")


def _system(path, stop, step=1.0e-3):
    s = load_system(path)
    # Jacobi, as every fixed-step SSP runner steps; the EWL needs 1 ms with it (docs/performance.md)
    s.experiment.stop, s.experiment.step, s.experiment.algorithm = stop, step, "jacobi"
    return s


@pytest.fixture(scope="module")
def ewl_ssp(tmp_path_factory):
    """The issue's package: ``webline export-ssp scenarios/ewl.yaml`` with .ssv parameter files."""
    s = _system(EWL, 0.1)
    return s, export_ssp(s, tmp_path_factory.mktemp("ewl") / "ewl.ssp", parameter_files=True)




def test_fmpy_simulate_ssp_applies_parameters_by_bare_name_prefix(ewl_ssp):
    """Reason 1: ``set_parameters`` gives component ``a`` every parameter whose name starts
    with ``a``, without the dot: ``unwind`` also receives ``unwind_v_ref.n`` and looks up a
    variable ``v_ref.n``. The EWL has 17 such name pairs (unwind/unwind_speed_pi, span1/span10, ...)."""
    from fmpy.ssp.simulation import simulate_ssp
    ssd, ps = full_parameter_set(ewl_ssp[1])
    names = [c.name for c in ssd.system.elements]
    pairs = [(a, b) for a in names for b in names if a != b and b.startswith(a)]
    assert ("unwind", "unwind_speed_pi") in pairs and ("span1", "span10") in pairs
    with pytest.raises(KeyError) as exc:
        simulate_ssp(str(ewl_ssp[1]), stop_time=1e-3, step_size=1e-3, parameter_set=ps)
    bad = exc.value.args[0]
    # the name looked up is another component's parameter with a shorter component name cut off
    assert any(p.name.startswith(a) and not p.name.startswith(a + ".") and p.name[len(a) + 1:] == bad
               for a, _ in pairs for p in ps.parameters), bad


@pytest.mark.parametrize("step", [1e-3, 1e-4])
def test_fmpy_simulate_ssp_starts_every_connected_input_at_zero(ewl_ssp, step, monkeypatch):
    """Reason 2, with reason 1 patched away (exact ``<component>.`` match): ``simulate_ssp``
    sets every connector to 0.0 before the first step and copies outputs to inputs only after
    each step, so the first ``fmi2DoStep`` of every component sees all its connected inputs at
    0. A speed loop then has roll radius R = 0 and inertia J = 0 and returns fmi2Discard, at
    t = 0 whatever the step. (An FMU cannot tell these zeros from real inputs.)"""
    import fmpy.ssp.simulation as S
    from fmpy.fmi1 import FMICallException

    def set_parameters(component, parameter_set):
        for p in parameter_set.parameters:
            if p.name.startswith(component.name + "."):
                S.set_value(component, p.name[len(component.name) + 1:], p.value)

    seen = {}
    do_step = S.do_step

    def recording_do_step(component, time, step_size):
        seen.update(component=component, time=time,
                    inputs={c.name: c.value for c in component.connectors if c.kind == "input"})
        do_step(component, time, step_size)

    monkeypatch.setattr(S, "set_parameters", set_parameters)
    monkeypatch.setattr(S, "do_step", recording_do_step)
    ssd, ps = full_parameter_set(ewl_ssp[1])
    with pytest.raises(FMICallException) as exc:
        S.simulate_ssp(str(ewl_ssp[1]), stop_time=0.01, step_size=step, parameter_set=ps)
    assert exc.value.function == "fmi2DoStep" and exc.value.status == 2  # discard
    failed = seen["component"]
    assert seen["time"] == 0.0 and failed.source == "resources/SpeedPI.fmu"
    assert set(seen["inputs"]) >= {"R", "J"} and all(v == 0.0 for v in seen["inputs"].values())
    bound = {p.name: float(p.value) for p in ps.parameters if p.name.startswith(failed.name + ".")}
    assert bound[f"{failed.name}.R"] > 0 and bound[f"{failed.name}.J"] > 0  # what the SSD binds


def test_fmpy_simulate_ssp_without_parameters_fails_in_the_first_step(ewl_ssp, monkeypatch):
    """The plain call (no parameter set): the first speed loop discards its first step."""
    import fmpy.ssp.simulation as S
    from fmpy.fmi1 import FMICallException
    seen = {}
    do_step = S.do_step

    def recording_do_step(component, time, step_size):
        seen.update(name=component.name, time=time)
        do_step(component, time, step_size)

    monkeypatch.setattr(S, "do_step", recording_do_step)
    with pytest.raises(FMICallException) as exc:
        S.simulate_ssp(str(ewl_ssp[1]), stop_time=0.01, step_size=1e-3)
    assert exc.value.function == "fmi2DoStep" and exc.value.status == 2
    assert seen == {"name": "unwind_speed_pi", "time": 0.0}


def _max_rel(a, b):
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


def test_ssp_fmpy_runs_the_out_of_round_ewl_like_webline(tmp_path):
    """0.5 s of the out-of-round EWL (lc9 swings by a few N) through ssp_fmpy equals
    webline's Jacobi master at the same step: same FMUs, same call sequence, so equal to
    rounding (measured: bitwise equal)."""
    from webline.orchestrator.ssp_fmpy import simulate
    system = _system(EWL_OOR, 0.5)
    ssp = export_ssp(system, tmp_path / "oor.ssp")
    r = simulate(ssp)  # stop and step from the SSD's DefaultExperiment
    ours = webline_simulate(system, progress=False)
    assert ours.ok, ours.message
    assert np.allclose(r["time"], ours.time, rtol=0, atol=1e-12) and len(r) == 501
    assert np.ptp(ours["lc9.T"]) > 1.0  # a signal that moves, so that agreement means something
    outputs = [n for n in r.dtype.names[1:]]
    assert set(outputs) <= set(ours.columns) and len(outputs) > 100
    for col in outputs:
        assert _max_rel(r[col], ours[col]) <= 1e-12, col


def test_ssp_fmpy_reads_ssv_parameter_files(ewl_ssp, tmp_path, capsys):
    """The issue's package (bindings in parameters/<component>.ssv), 0.1 s; and the command line."""
    from webline.orchestrator.ssp_fmpy import main
    system, ssp = ewl_ssp
    csv = tmp_path / "ewl.csv"
    assert main([str(ssp), "--csv", str(csv)]) == 0
    assert "101 rows" in capsys.readouterr().out
    data = np.genfromtxt(csv, delimiter=",", names=True, deletechars="")
    ours = webline_simulate(system, progress=False)
    assert ours.ok, ours.message
    for col in LOAD_CELLS:
        assert _max_rel(data[col], ours[col]) <= 1e-12, col
        assert np.allclose(data[col], 15 * 4.4482216152605, rtol=1e-3)  # the zones' 15 lbf references
    assert main([str(tmp_path / "missing.ssp")]) == 2
