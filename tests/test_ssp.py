"""SSP export (orchestrator.ssp): schema-valid, readable by fmpy, runnable in libcosim,
and libcosim's results match ours."""
import zipfile
from pathlib import Path

import numpy as np
import pytest

from webline.orchestrator.reference import simulate_reference
from webline.orchestrator.ssp import export_ssp, read_ssp, simulate_libcosim
from webline.orchestrator.system import Component, Connection, Experiment, System
from ssp_bindings import full_parameter_set

EA = 2.0e4


def two_spans(stop=1.0):
    return System([Component("s1", "Span", {"EA": EA, "L0": 1.0, "T0": 50.0}, {"v_in": 1.0, "v_out": 1.01, "T_in": 0.0}),
                   Component("s2", "Span", {"EA": EA, "L0": 2.0, "T0": 100.0}, {"v_in": 1.01, "v_out": 1.03})],
                  [Connection("s1", "T", "s2", "T_in")], Experiment(0.0, stop, 1.0e-3))


@pytest.fixture(scope="module")
def two_span_ssp(tmp_path_factory):
    return export_ssp(two_spans(), tmp_path_factory.mktemp("ssp") / "two.ssp")


def test_package_layout(two_span_ssp):
    names = zipfile.ZipFile(two_span_ssp).namelist()
    assert "SystemStructure.ssd" in names and "resources/Span.fmu" in names
    ssd = zipfile.ZipFile(two_span_ssp).read("SystemStructure.ssd").decode()
    assert "LinearTransformation" not in ssd
    assert 'baseStepSize="0.001"' in ssd and 'stopTime="1.0"' in ssd


def test_read_back_is_the_same_system(two_span_ssp):
    back = read_ssp(two_span_ssp)
    orig = two_spans()
    assert [(c.name, c.model, c.parameters, c.inputs) for c in back.components] == \
           [(c.name, c.model, c.parameters, c.inputs) for c in orig.components]
    assert back.connections == orig.connections
    assert (back.experiment.start, back.experiment.stop, back.experiment.step, back.experiment.algorithm) == \
           (0.0, 1.0, 1.0e-3, "jacobi")


def test_fmpy_validates_and_runs_it(two_span_ssp):
    from fmpy.ssp.simulation import simulate_ssp
    # fmpy's simulate_ssp applies only a parameter set it is given, with <component>.<name> names
    ssd, ps = full_parameter_set(two_span_ssp, validate=True)  # SSP 1.0 schema
    assert [c.name for c in ssd.system.elements] == ["s1", "s2"]
    r = simulate_ssp(str(two_span_ssp), stop_time=0.2, step_size=1e-3, parameter_set=ps)
    ref = simulate_reference(two_spans(stop=0.2), t_eval=r["time"] + 1e-3)  # fmpy labels rows by step start
    assert np.allclose(r["s1.T"], ref["s1.T"], rtol=1e-6)
    assert np.allclose(r["s2.L"], 2.0)


def _rel_err(a, b):
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


def test_libcosim_runs_it_and_matches(two_span_ssp):
    t, d = simulate_libcosim(two_span_ssp)
    assert len(t) == 1000 and t[0] == pytest.approx(1e-3) and t[-1] == pytest.approx(1.0)
    assert np.all(d["s2.L"] == 2.0)  # parameters were applied
    ref = simulate_reference(two_spans(), t_eval=t)
    for col in ("s1.T", "s2.T"):
        assert _rel_err(d[col], ref[col]) < 1e-3, col


def test_libcosim_reads_the_step_from_the_ssd(two_span_ssp):
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    log_output_level(CosimLogLevel.ERROR)
    ex = CosimExecution.from_ssp_file(str(two_span_ssp))  # no step given: osp:FixedStepAlgorithm
    assert ex.num_slaves() == 2
    assert ex.step(3)
    assert ex.status().current_time == 3_000_000  # ns


def test_libcosim_matches_our_master(two_span_ssp):
    from webline.orchestrator.master import simulate
    ours = simulate(two_spans(), progress=False)  # Jacobi, as libcosim's fixed-step algorithm
    assert ours.ok
    t, d = simulate_libcosim(two_span_ssp)
    assert np.allclose(ours.time[1:], t)  # libcosim has no row at the start time
    for col in ("s1.T", "s2.T"):
        assert _rel_err(d[col], ours[col][1:]) < 1e-3, col
    for col in ("s1.L", "s2.L", "s2.dL"):
        assert np.allclose(d[col], ours[col][1:], rtol=1e-3, atol=1e-12), col


def test_parameter_files_variant(tmp_path):
    p = export_ssp(two_spans(stop=0.05), tmp_path / "two_ssv.ssp", parameter_files=True)
    names = zipfile.ZipFile(p).namelist()
    assert "parameters/s1.ssv" in names and "parameters/s2.ssv" in names
    from fmpy.ssp.ssd import read_ssd
    read_ssd(str(p), validate=True)
    assert read_ssp(p).components[1].parameters["L0"] == 2.0
    t, d = simulate_libcosim(p)
    assert np.all(d["s2.L"] == 2.0) and np.all(d["s1.L"] == 1.0)


def test_export_rejects_unknown_variables(tmp_path):
    bad = two_spans()
    bad.components[0].parameters["nope"] = 1.0
    with pytest.raises(KeyError, match="nope"):
        export_ssp(bad, tmp_path / "bad.ssp")


# ---- the EWL scenario -----------------------------------------------------------------
EWL = Path(__file__).resolve().parent.parent / "scenarios" / "ewl.yaml"


def _outputs_valid_in_initialization_mode():
    """True if an FMU answers a feed-through output with a computed value in
    initialization mode. libcosim reads outputs there to pass initial values
    along connections (our master reads them after initialisation); a wrapper
    that builds its model only in exit_initialization_mode answers the declared
    start value, and the first step of libcosim then starts from wrong inputs."""
    from webline.orchestrator.reference import fmu_classes
    classes = fmu_classes()
    if "SpeedPI" not in classes:
        return True
    slave = classes["SpeedPI"](instance_name="probe")
    v = {x.name: x for x in slave.vars.values()}
    for name, value in (("K_ref", 10.0), ("v_ref", 1.0), ("R", 0.1), ("J", 1.0), ("omega", 5.0)):
        v[name].setter(value)
    slave.setup_experiment(0.0, None, None)
    slave.enter_initialization_mode()
    declared = next(x.start for x in type(slave).OUTPUTS if x.name == "tau")
    return v["tau"].getter() != declared


@pytest.fixture(scope="module")
def ewl_short(tmp_path_factory):
    if not EWL.exists():
        pytest.skip("no scenarios/ewl.yaml")
    from webline.orchestrator.layout import load_system
    system = load_system(EWL)
    # libcosim's fixed-step algorithm is Jacobi-like; the EWL's web-guide mode
    # (~30 Hz, nearly undamped) needs a short step under Jacobi coupling.
    system.experiment.stop = 0.1
    system.experiment.step = 1.0e-4
    system.experiment.algorithm = "jacobi"
    return system, export_ssp(system, tmp_path_factory.mktemp("ewl") / "ewl.ssp")


def test_ewl_exports_valid_ssp(ewl_short):
    system, path = ewl_short
    from fmpy.ssp.ssd import read_ssd
    ssd = read_ssd(str(path), validate=True)
    assert len(ssd.system.elements) == len(system.components)
    assert len(ssd.system.connections) == len(system.connections)
    back = read_ssp(path)
    assert [c.parameters for c in back.components] == [
        {k: float(v) for k, v in c.parameters.items()} for c in system.components]


@pytest.mark.xfail(not _outputs_valid_in_initialization_mode(), strict=True,
                   reason="ElementSlave builds its model only in exit_initialization_mode: libcosim "
                          "propagates declared start values of feed-through outputs (SpeedPI.tau) "
                          "during initialisation, so its first step differs")
def test_ewl_in_libcosim_matches_our_master(ewl_short):
    system, path = ewl_short
    from webline.orchestrator.master import simulate
    ours = simulate(system, progress=False)
    assert ours.ok, ours.message
    t, d = simulate_libcosim(path)
    assert np.allclose(ours.time[1:], t)
    tensions = [c for c in ours.columns if c.endswith(".T")]
    assert len(tensions) > 10
    for col in tensions:  # measured 2.4e-6 (libcosim reads feed-through outputs before new inputs)
        assert _rel_err(d[col], ours[col][1:]) < 1e-4, col


def test_export_ssp_command(tmp_path, capsys):
    if not EWL.exists():
        pytest.skip("no scenarios/ewl.yaml")
    from webline.cli import main
    out = tmp_path / "line.ssp"
    assert main(["export-ssp", str(EWL), str(out), "--stop", "0.5", "--step", "0.002"]) == 0
    assert "components" in capsys.readouterr().out
    back = read_ssp(out)
    assert (back.experiment.stop, back.experiment.step) == (0.5, 0.002)
    assert main(["export-ssp", str(tmp_path / "missing.yaml"), str(out)]) == 2
