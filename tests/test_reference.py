"""Monolithic reference (orchestrator.reference) against hand-derived and analytic solutions."""
import math

import numpy as np
import pytest

from webline.orchestrator.reference import (AlgebraicLoop, ReferenceSystem, fmu_classes, output_times,
                                    simulate_reference, solve_reference)
from webline.orchestrator.system import Component, Connection, Experiment, System
from webline.physics.span import steady_state_tension

EA = 2.0e4


def span(name, L0, T0, **inputs):
    return Component(name, "Span", {"EA": EA, "L0": L0, "T0": T0}, inputs)


def two_spans(stop=5.0):
    """s1 fed at 1.0 m/s, leaving at 1.01; s2 from 1.01 to 1.03 m/s, entering tension s1.T."""
    return System([span("s1", 1.0, 50.0, v_in=1.0, v_out=1.01, T_in=0.0),
                   span("s2", 2.0, 100.0, v_in=1.01, v_out=1.03)],
                  [Connection("s1", "T", "s2", "T_in")], Experiment(0.0, stop, 1.0e-3))


def test_span_first_order_response_is_analytic():
    # dT/dt = [v_out (EA - T) - v_in (EA - T_in)]/L: T(t) = T_ss + (T0 - T_ss) exp(-v_out t / L)
    r = simulate_reference(two_spans())
    v_in, v_out, L, T0 = 1.0, 1.01, 1.0, 50.0
    T_ss = steady_state_tension(0.0, v_in, v_out, EA)
    exact = T_ss + (T0 - T_ss) * np.exp(-v_out * r.time / L)
    assert np.max(np.abs(r["s1.T"] - exact)) < 1e-6 * T_ss


def test_cascade_of_two_spans_is_analytic():
    # s2: T2' = -a2 T2 + c2 T1(t) + b2 with T1 = T1ss + D1 exp(-a1 t):
    # T2 = T2ss + A exp(-a1 t) + B exp(-a2 t), A = c2 D1/(a2 - a1), B = T2(0) - T2ss - A.
    r = simulate_reference(two_spans(stop=8.0))
    t = r.time
    a1, T1ss = 1.01 / 1.0, steady_state_tension(0.0, 1.0, 1.01, EA)
    D1 = 50.0 - T1ss
    a2, c2 = 1.03 / 2.0, 1.01 / 2.0
    T2ss = steady_state_tension(T1ss, 1.01, 1.03, EA)
    A = c2 * D1 / (a2 - a1)
    B = 100.0 - T2ss - A
    exact = T2ss + A * np.exp(-a1 * t) + B * np.exp(-a2 * t)
    assert np.max(np.abs(r["s2.T"] - exact)) < 1e-6 * T2ss
    # and it settles to the hand-derived steady state
    assert r["s2.T"][-1] == pytest.approx(T2ss, rel=2e-2)


def test_columns_and_times_match_the_master_convention():
    system = two_spans(stop=0.01)
    r = simulate_reference(system)
    assert list(r.columns) == ["s1.T", "s1.L", "s1.dL", "s1.dT", "s2.T", "s2.L", "s2.dL", "s2.dT"]
    assert np.allclose(r.time, np.linspace(0.0, 0.01, 11))
    assert r["s1.L"][0] == 1.0 and r["s2.L"][0] == 2.0
    system.experiment.output_interval = 0.005
    assert np.allclose(output_times(system.experiment), [0.0, 0.005, 0.01])
    r2 = simulate_reference(system)
    assert len(r2.time) == 3 and r2.columns == r.columns
    assert r2.unit("s1.T") == "N" and r2.ok and r2.meta["kind"] == "reference"


def test_dense_solution_samples_anywhere():
    sol = solve_reference(two_spans(stop=2.0))
    a = sol.sample([0.0, 0.37, 2.0])
    b = sol.sample(np.linspace(0.0, 2.0, 201))
    assert a["s1.T"][1] == pytest.approx(np.interp(0.37, b.time, b["s1.T"]), rel=1e-4)
    with pytest.raises(ValueError):
        sol.sample([2.5])


def test_feed_through_chain_is_ordered():
    # L of a length_mode-1 span is its input L_ext (feed-through): a.L -> b.L_ext, b.L -> c.L_ext,
    # listed in reverse so that only a topological order gets c its length 3 m (time constant 3/v).
    comps = [span("c", 1.0, 0.0, v_in=1.0, v_out=1.02, T_in=0.0),
             span("b", 1.0, 0.0, v_in=1.0, v_out=1.0, T_in=0.0),
             span("a", 1.0, 0.0, v_in=1.0, v_out=1.0, T_in=0.0, L_ext=3.0)]
    for c in comps:
        c.parameters["length_mode"] = 1
    comps[0].inputs["L_ext"] = 99.0  # overwritten by the connection
    conns = [Connection("b", "L", "c", "L_ext"), Connection("a", "L", "b", "L_ext")]
    system = System(comps, conns, Experiment(0.0, 3.0, 1e-2))
    fresh = ReferenceSystem(system)  # one evaluation from the start values must already be right
    y = dict(zip(fresh.columns, fresh.outputs(0.0, fresh.x0)))
    assert (y["a.L"], y["b.L"], y["c.L"]) == (3.0, 3.0, 3.0)
    r = simulate_reference(system)
    assert np.all(r["c.L"] == 3.0)
    T_ss = steady_state_tension(0.0, 1.0, 1.02, EA)
    exact = T_ss * (1.0 - np.exp(-1.02 * r.time / 3.0))
    assert np.max(np.abs(r["c.T"] - exact)) < 1e-6 * T_ss


def test_schedule_evaluates_state_outputs_once_per_component():
    ref = ReferenceSystem(two_spans())
    # s2.dT depends on the connected T_in (a second call to record it); inside the RHS only the
    # outputs that feed an input are computed: one outputs() call, s1's
    assert sorted(c for c, *_ in ref.schedule) == [0, 1, 1]
    assert len(ref.rhs_schedule) == 1


def test_algebraic_loop_is_reported():
    a, b = span("a", 1.0, 0.0), span("b", 1.0, 0.0)
    for c in (a, b):
        c.parameters["length_mode"] = 1
    conns = [Connection("a", "L", "b", "L_ext"), Connection("b", "L", "a", "L_ext")]
    with pytest.raises(AlgebraicLoop, match="a.L"):
        ReferenceSystem(System([a, b], conns))


def test_bad_parameters_name_the_variable():
    with pytest.raises(ValueError, match=r"component .s. \(Span\): EA"):
        simulate_reference(System([Component("s", "Span", {"EA": -1.0})], [], Experiment(0, 0.1, 1e-3)))
    with pytest.raises(KeyError, match="no_such"):
        ReferenceSystem(System([Component("s", "Span", {"no_such": 1.0})], []))
    with pytest.raises(KeyError, match="not an output"):
        ReferenceSystem(System([span("a", 1.0, 0.0), span("b", 1.0, 0.0)],
                               [Connection("a", "v_in", "b", "T_in")]))


def test_every_fmu_script_is_importable_in_process():
    classes = fmu_classes()
    assert "Span" in classes
    for model, cls in classes.items():
        slave = cls(instance_name=f"probe_{model}")
        model_obj = slave.make_model()
        assert tuple(v.name for v in cls.OUTPUTS) == tuple(model_obj.OUTPUTS), model
        assert set(model_obj.INPUTS) <= {v.name for v in cls.INPUTS}, model


def idle_roller_line(b=0.0, stop=40.0):
    """s1 (fed at v0) -> idle roller r -> s2 (pulled at v2)."""
    comps = [span("s1", 1.0, 0.0, v_in=V0, T_in=0.0),
             Component("r", "IdleRoller", {"R": R_ROLLER, "J": J_ROLLER, "b": b, "omega0": V0 / R_ROLLER}),
             span("s2", 1.0, 0.0, v_out=V2)]
    conns = [Connection("r", "v", "s1", "v_out"), Connection("r", "v", "s2", "v_in"),
             Connection("s1", "T", "s2", "T_in"), Connection("s1", "T", "r", "T_in"),
             Connection("s2", "T", "r", "T_out")]
    return System(comps, conns, Experiment(0.0, stop, 1e-3, output_interval=0.1))


V0, V2, R_ROLLER = 1.0, 1.01, 0.05
J_ROLLER, RTOL = 0.01, 1e-8  # idle_roller_line's roller inertia; simulate_reference's default rtol


def settled_speed_rtol(b, stop=40.0, n_states=4):
    """Relative tolerance on the idle roller's final speed, from the solver's rtol and the
    line's modes (linearised idle_roller_line, 1 m spans, roller coupled by both spans).

    Modes: the roller on the two span springs, w_n = sqrt(2 (EA/L) R^2/J) = 100 rad/s, decaying at
    sigma = (v0/L1 + v2/L2 + b/J - v2/(L1 + L2))/2 (trace of the Jacobian less the slow mode
    v/(L1 + L2), the two spans relaxing as one); the slow mode decays at v/(L1 + L2) ~ 0.5 /s.
    Physics: the start deviation (v2 - v0)/v2 left after ``stop`` by the slow mode.
    Solver: LSODA runs the lightly damped mode at its stability-limited step h ~ 0.5/w_n; each
    step's error is within rtol per state in the RMS norm (<= sqrt(n) rtol per component) and
    those errors add up, at worst coherently, over the mode's decay time 1/sigma = 1/(sigma h) steps.
    """
    w_n = math.sqrt(2.0 * EA / 1.0 * R_ROLLER ** 2 / J_ROLLER)
    sigma = 0.5 * (V0 / 1.0 + V2 / 1.0 + b / J_ROLLER - V2 / 2.0)
    h = 0.5 / w_n
    physics = (V2 - V0) / V2 * math.exp(-V0 / 2.0 * stop)
    return physics + math.sqrt(n_states) * RTOL / (sigma * h)


@pytest.mark.skipif("IdleRoller" not in fmu_classes(), reason="no IdleRoller FMU yet")
def test_idle_roller_between_driven_ends_frictionless_steady_state():
    # b = 0: T1 = T2 = T, and s2's balance gives T = EA (v2 - v0)/v2, the roller at v0 EA/(EA - T).
    r = simulate_reference(idle_roller_line())
    T = EA * (V2 - V0) / V2
    assert r["s1.T"][-1] == pytest.approx(T, rel=1e-4)
    assert r["s2.T"][-1] == pytest.approx(T, rel=1e-4)
    # 5.3e-6: settled_speed_rtol (rtol 1e-8 summed over the 100 rad/s mode's 1.3 s decay, zeta 0.0076)
    assert r["r.v"][-1] == pytest.approx(V0 * EA / (EA - T), rel=settled_speed_rtol(0.0))
    # the angle is the integral of the speed
    assert r["r.theta"][-1] == pytest.approx(np.trapezoid(r["r.omega"], r.time), rel=1e-4)


@pytest.mark.skipif("IdleRoller" not in fmu_classes(), reason="no IdleRoller FMU yet")
def test_idle_roller_with_friction_steady_state():
    # T1 = EA (v - v0)/v, T2 = EA (v2 - v)/v2 + v T1/v2, R (T2 - T1) = b v/R: solve for the roller speed v.
    from scipy.optimize import brentq
    b = 0.05

    def tensions(v):
        T1 = EA * (v - V0) / v
        return T1, EA * (V2 - v) / V2 + v * T1 / V2

    def balance(v):
        T1, T2 = tensions(v)
        return R_ROLLER * (T2 - T1) - b * v / R_ROLLER

    v = brentq(balance, V0 * 1.0000001, V2)
    T1, T2 = tensions(v)
    r = simulate_reference(idle_roller_line(b=b))
    # 1.2e-6: settled_speed_rtol (friction b/J = 5 /s shortens the mode's decay to 0.3 s)
    assert r["r.v"][-1] == pytest.approx(v, rel=settled_speed_rtol(b))
    assert r["s1.T"][-1] == pytest.approx(T1, rel=1e-4)
    assert r["s2.T"][-1] == pytest.approx(T2, rel=1e-4)
    assert T2 > T1  # friction: the web pulls harder on the way out


@pytest.mark.skipif("Profile" not in fmu_classes(), reason="no Profile FMU yet")
def test_profile_ramp_drives_a_span_exactly():
    # v_out ramps 1.0 -> 1.02 over [0.5, 1.5] s; the integration restarts at the knots.
    prof = Component("p", "Profile", {"n": 3, "t[1]": 0.5, "y[1]": 1.0, "t[2]": 1.5, "y[2]": 1.02,
                                      "t[3]": 4.0, "y[3]": 1.02})
    s = System([prof, span("s", 1.0, 0.0, v_in=1.0, T_in=0.0)], [Connection("p", "y", "s", "v_out")],
               Experiment(0.0, 4.0, 1e-3))
    ref = ReferenceSystem(s)
    assert ref.breakpoints() == [0.5, 1.5]
    r = simulate_reference(s)
    assert np.max(np.abs(r["s.T"][r.time <= 0.5])) < 1e-9
    assert r["p.y"][r.time >= 1.5] == pytest.approx(1.02)
    # a constant-speed tail after the ramp: first-order decay towards the steady state
    T_ss = steady_state_tension(0.0, 1.0, 1.02, EA)
    i = np.searchsorted(r.time, 1.5)
    tail = T_ss + (r["s.T"][i] - T_ss) * np.exp(-1.02 * (r.time[i:] - r.time[i]))
    assert np.max(np.abs(r["s.T"][i:] - tail)) < 1e-5 * T_ss


def test_ewl_operating_point_is_held_by_the_reference():
    # The layout computes an operating point; the monolithic model must stay there
    # (only angles and roll radii move), which checks layout, FMU scripts and routing together.
    from pathlib import Path
    layout = Path(__file__).resolve().parent.parent / "scenarios" / "ewl.yaml"
    if not layout.exists():
        pytest.skip("no scenarios/ewl.yaml")
    from webline.orchestrator.layout import load_system
    system = load_system(layout)
    system.experiment.stop, system.experiment.output_interval = 1.0, 0.1
    for c in system.components:
        if c.model == "LoadCell":
            c.parameters["noise_std"] = 0.0
    r = simulate_reference(system)
    tensions = [c for c in r.columns if c.endswith(".T")]
    assert len(tensions) > 10
    for col in tensions:
        assert r[col][-1] == pytest.approx(r[col][0], rel=1e-5), col
    assert r.info["n_states"] == len(r.state_names) > 40
