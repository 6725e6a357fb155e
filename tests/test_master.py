"""Master on hand-made Systems of Span FMUs: convergence of both algorithms to a
hand-derived steady state, failures that name the component, structural errors,
and results that round-trip through HDF5 and CSV."""
import math

import numpy as np
import pytest

from webline.orchestrator.master import SetupError, simulate
from webline.orchestrator.results import load_results
from webline.orchestrator.system import Component, Connection, Experiment, System

EA = 2.0e4
L0 = 0.2  # time constant L0/v = 0.2 s
V = (1.0, 1.01, 1.025)  # speeds of the three elements bounding two spans


def two_spans(algorithm, stop=4.0, output_interval=0.0, **first):
    """Span a (v0 -> v1, entering tension 0) feeding span b (v1 -> v2, T_in = a.T)."""
    pa = {"EA": EA, "L0": L0, "T0": 0.0, "length_mode": 1}
    pa.update(first)
    comps = [
        Component("a", "Span", pa, {"v_in": V[0], "v_out": V[1], "T_in": 0.0, "L_ext": L0}, element="S1"),
        Component("b", "Span", {"EA": EA, "L0": L0, "T0": 0.0, "length_mode": 1},
                  {"v_in": V[1], "v_out": V[2], "L_ext": L0}, element="S2"),
    ]
    return System(comps, [Connection("a", "T", "b", "T_in")],
                  Experiment(0.0, stop, 1.0e-3, algorithm, output_interval))


def hand_steady_state():
    """{21} at equilibrium: T = EA (v_out - v_in)/v_out + v_in T_in / v_out, span by span."""
    t1 = EA * (V[1] - V[0]) / V[1]
    t2 = EA * (V[2] - V[1]) / V[2] + V[1] * t1 / V[2]
    return t1, t2


@pytest.mark.parametrize("algorithm", ["jacobi", "gauss-seidel"])
def test_two_spans_converge_to_hand_steady_state(fmus, algorithm):
    r = simulate(two_spans(algorithm), fmus, progress=False)
    assert r.status == "ok", r.message
    t1, t2 = hand_steady_state()
    assert r["a.T"][-1] == pytest.approx(t1, rel=1e-6)
    assert r["b.T"][-1] == pytest.approx(t2, rel=1e-6)
    # rows: start + every step; metadata of the run
    assert len(r.time) == 4001 and r.time[-1] == pytest.approx(4.0)
    assert r.meta["algorithm"] == algorithm and r.meta["step"] == 1e-3
    assert r.meta["steps_done"] == 4000 and r.meta["wall_time"] > 0
    assert r.unit("a.T") == "N" and r.unit("a.L") == "m" and r.unit("time") == "s"


def test_gauss_seidel_uses_the_upstream_value_of_the_same_step(fmus):
    """Jacobi feeds b with a.T of the previous communication point, Gauss-Seidel with
    the one just computed: early in the transient the two differ, and Gauss-Seidel's
    downstream tension is ahead."""
    rj = simulate(two_spans("jacobi", stop=0.05), fmus, progress=False)
    rg = simulate(two_spans("gauss-seidel", stop=0.05), fmus, progress=False)
    assert np.allclose(rj["a.T"], rg["a.T"])  # a sees no coupled input
    assert rg["b.T"][-1] > rj["b.T"][-1]


def test_output_interval_thins_the_record(fmus):
    r = simulate(two_spans("jacobi", stop=0.5, output_interval=0.01), fmus, progress=False)
    assert len(r.time) == 51
    assert np.allclose(np.diff(r.time), 0.01)


def test_invalid_parameter_fails_at_init_naming_the_component(fmus):
    s = two_spans("jacobi")
    s.component("b").parameters["EA"] = -5.0
    r = simulate(s, fmus, progress=False)
    assert r.status == "failed" and not r.ok
    assert "'b'" in r.message and "S2" in r.message and "Span" in r.message
    assert "fmi2ExitInitializationMode" in r.message
    assert "parameter 'EA' must be > 0" in r.message  # what the FMU logged
    assert len(r.time) == 0 and "b.T" in r.columns


def test_diverging_run_stops_and_keeps_results_so_far(fmus, tmp_path):
    # L_ext much shorter than L0: an explicit step of 10 ms is far beyond stability
    s = two_spans("jacobi", stop=1.0, max_step=1e-2)
    s.component("a").inputs["L_ext"] = 1e-3
    s.component("a").inputs["v_out"] = 300.0
    s.experiment.step = 1e-2
    r = simulate(s, fmus, progress=False)
    assert r.status == "failed"
    assert "'a'" in r.message and "S1" in r.message and "fmi2DoStep" in r.message
    assert "diverged" in r.message
    t_fail = float(r.message.split("at t = ")[1].split()[0])
    assert 0 < t_fail < 1.0
    assert 0 < len(r.time) <= round(t_fail / 1e-2) + 1
    assert np.isfinite(r["b.T"]).all()
    # partial results are saved like complete ones
    r.save(tmp_path)
    back = load_results(tmp_path)
    assert back.status == "failed" and back.message == r.message
    assert len(back.time) == len(r.time)


def test_structural_errors_are_reported_before_running(fmus):
    s = two_spans("jacobi")
    s.component("a").parameters["EB"] = 1.0
    s.connections.append(Connection("a", "T", "b", "T_in"))
    s.connections.append(Connection("a", "nothing", "b", "v_in"))
    s.experiment.algorithm = "newton"
    with pytest.raises(SetupError) as err:
        simulate(s, fmus, progress=False)
    text = str(err.value)
    assert "no variable 'EB'" in text and "fed twice" in text and "'nothing'" in text and "newton" in text
    with pytest.raises(SetupError, match="no FMU for model 'Nope'"):
        simulate(System([Component("x", "Nope")], []), fmus, progress=False)


def test_algebraic_loop_is_detected(fmus):
    """Span.L depends on L_ext: a.L -> b.L_ext and b.L -> a.L_ext is a real loop;
    a.T -> a.T_in is not (T is a state)."""
    comps = [Component("a", "Span", {"length_mode": 1}), Component("b", "Span", {"length_mode": 1})]
    loop = [Connection("a", "T", "a", "T_in"), Connection("a", "L", "b", "L_ext"),
            Connection("b", "L", "a", "L_ext")]
    with pytest.raises(SetupError, match=r"algebraic loop.*a\.L -> b\.L -> a\.L"):
        simulate(System(comps, loop), fmus, progress=False)
    chain = [Connection("a", "T", "a", "T_in"), Connection("a", "L", "b", "L_ext")]
    r = simulate(System(comps, chain, Experiment(0, 0.01, 1e-3)), fmus, progress=False)
    assert r.ok and r["b.L"][-1] == pytest.approx(r["a.L"][-1])


def test_results_round_trip_hdf5_and_csv(fmus, tmp_path):
    import h5py

    r = simulate(two_spans("gauss-seidel", stop=0.2), fmus, progress=False)
    r.meta["layout"] = "hand-made"
    paths = r.save(tmp_path, csv=True)
    assert [p.name for p in paths] == ["results.h5", "results.csv"]

    with h5py.File(tmp_path / "results.h5") as f:  # self-describing without webline
        assert f["a.T"].attrs["unit"] == "N" and f["time"].attrs["unit"] == "s"
        assert "tension" in f["a.T"].attrs["description"].lower()
        assert f.attrs["algorithm"] == "gauss-seidel" and f.attrs["status"] == "ok"
        assert np.array_equal(f["b.T"][()], r["b.T"])

    header = (tmp_path / "results.csv").read_text().splitlines()[0]
    assert header == ",".join(["time", *r.columns])

    for source in (tmp_path, tmp_path / "results.h5", tmp_path / "results.csv"):
        back = load_results(source)
        assert back.columns == r.columns
        assert np.array_equal(back.time, r.time)
        assert np.array_equal(back.data, r.data)  # %.17g: exact
        assert back.units == r.units
        assert back.status == "ok" and back.meta["layout"] == "hand-made"
        assert back.meta["components"]["b"]["element"] == "S2"
        assert back.meta["step"] == 1e-3 and math.isfinite(back.meta["wall_time"])


def test_progress_bar_is_off_without_a_tty(fmus, capsys):
    r = simulate(two_spans("jacobi", stop=0.1), fmus, progress=True)
    assert r.ok
    assert capsys.readouterr().err == ""


def _compiled_loop_or_skip():
    from webline.orchestrator import cloop
    if not cloop.available():
        pytest.skip("no C compiler: the master keeps its Python loop")


@pytest.mark.parametrize("algorithm, step, interval", [("gauss-seidel", 2e-3, 0.0), ("gauss-seidel", 2e-3, 6e-3),
                                                        ("jacobi", 1e-3, 0.0), ("jacobi", 1e-3, 3e-3)])
def test_compiled_loop_makes_the_python_loop_calls(fmus, algorithm, step, interval):
    # The EWL has every kind of operation: feed-through chains before a step, anchored
    # extrapolated inputs, rate groups resolved after the round, sinks read on recording
    # steps. Same calls in the same order on the same arrays: bit-identical records.
    from pathlib import Path

    from webline.orchestrator.layout import load_system
    _compiled_loop_or_skip()
    layout = Path(__file__).resolve().parent.parent / "scenarios" / "ewl_out_of_round.yaml"
    system = load_system(layout, {"experiment.duration": 0.06, "experiment.step": step,
                                  "experiment.algorithm": algorithm, "experiment.output_interval": interval})
    a = simulate(system, fmus, progress=False, compiled=True)
    b = simulate(system, fmus, progress=False, compiled=False)
    assert a.meta["master_loop"] == "compiled" and b.meta["master_loop"] == "python"
    assert a.status == b.status == "ok"
    assert len(a.time) == round(0.06 / max(step, interval)) + 1
    assert np.array_equal(a.time, b.time)
    assert np.array_equal(a.data, b.data)


def test_compiled_loop_reports_a_failure_like_the_python_loop(fmus):
    _compiled_loop_or_skip()
    runs = []
    for compiled in (True, False):
        s = two_spans("gauss-seidel", stop=1.0, max_step=1e-2)
        s.component("a").inputs["L_ext"] = 1e-3
        s.component("a").inputs["v_out"] = 300.0
        s.experiment.step = 1e-2
        runs.append(simulate(s, fmus, progress=False, compiled=compiled))
    a, b = runs
    assert a.status == b.status == "failed"
    assert "fmi2DoStep" in a.message and "'a'" in a.message
    assert a.message == b.message
    assert np.array_equal(a.data, b.data)


@pytest.mark.parametrize("compiled", [True, False])
def test_multi_rate_source_holds_its_outputs_between_its_steps(fmus, compiled):
    # A ramp y = t stepped once per 4 macro steps of 10 ms: each of its steps covers 40 ms
    # (the last one the 20 ms left), and its output, read after its step, holds the value at
    # the end of that step until the next one; the span it feeds sees the same held value.
    if compiled:
        _compiled_loop_or_skip()
    ramp = Component("ramp", "Profile", {"n": 2, "t[1]": 0.0, "y[1]": 0.0, "t[2]": 1.0, "y[2]": 1.0}, {},
                     step_multiple=4)
    span = Component("s", "Span", {"EA": EA, "L0": L0, "T0": 0.0, "length_mode": 1},
                     {"v_in": 1.0, "v_out": 1.0, "T_in": 0.0, "L_ext": L0})
    system = System([ramp, span], [Connection("ramp", "y", "s", "T_in")], Experiment(0.0, 0.1, 0.01, "gauss-seidel"))
    r = simulate(system, fmus, progress=False, compiled=compiled)
    assert r.status == "ok" and r.meta["master_loop"] == ("compiled" if compiled else "python")
    held = [0.0, 0.04, 0.04, 0.04, 0.04, 0.08, 0.08, 0.08, 0.08, 0.10, 0.10]
    assert np.allclose(r["ramp.y"], held, rtol=0, atol=1e-12)
    assert np.allclose(r["ramp.dy"], 1.0)


def test_multi_rate_needs_an_instance_without_inputs(fmus):
    s = two_spans("gauss-seidel")
    s.components[1].step_multiple = 3
    with pytest.raises(SetupError, match=r"'b': step_multiple 3 needs an instance without connected inputs"):
        simulate(s, fmus, progress=False)
    s.components[1].step_multiple = 0
    with pytest.raises(SetupError, match=r"'b': step_multiple must be an integer >= 1"):
        simulate(s, fmus, progress=False)

