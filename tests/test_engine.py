"""The fast engine (orchestrator.engine) against the monolithic reference and the co-simulation.

Tolerances. The engine integrates the reference's ODE with classical RK4 at a
fixed step h <= 1 ms, h <= 0.5/|lambda| over the Jacobian's modes that oscillate or
grow and h <= 2/|lambda| over its real decaying ones (engine.step_for). Its
global error is O(h^4): on the line's tension-carrying modes (|lambda| h <= 0.1)
the relative error per unit time is about (lambda h)^4/120 < 1e-6, and the
reference (LSODA, rtol 1e-8) adds about 1e-8; the 0.1 % bound of issue 10 is
therefore met with a wide margin, and the tighter 1e-5 bound checked here would
still fail if one model's glue differed from its class (a wrong sign or a
missing term changes the tensions by far more). Against the co-simulation the
bound is the accuracy table's 0.5 % (the co-simulation's own error at its
default macro step).
"""
import copy
from pathlib import Path

import numpy as np
import pytest

from webline.orchestrator import engine
from webline.orchestrator.accuracy import load_cells, relative_rms, without_noise
from webline.orchestrator.layout import load_system
from webline.orchestrator.reference import simulate_reference

ROOT = Path(__file__).resolve().parent.parent
SCENARIOS = sorted(p for p in list((ROOT / "scenarios").glob("*.yaml")) + list((ROOT / "scenarios" / "paper").glob("*.yaml"))
                   if "sweep" not in p.name)
DRIVE = {"motor_inertia": "0.02 kg*m^2", "stiffness": "3000 N*m/rad", "damping": "0.5 N*m*s/rad",
         "backlash": "0.2 deg"}
ENGINE_VS_REFERENCE = 1e-5
COSIM_TOLERANCE = 5e-3


def _system(path, duration=2.0, **overrides):
    ov = {"experiment.duration": f"{duration} s", **overrides}
    return without_noise(load_system(path, ov))


def _worst(a, b, cols):
    return max(relative_rms(a[c], b[c]) for c in cols)


def test_noise_matches_the_load_cell_model():
    from webline.physics.load_cell import standard_normal
    f = engine.nb()["standard_normal"]
    for seed in (0, 1, 7, 2 ** 40 + 3):
        for t in (0.0, 1e-6, 0.002, 0.5, 12.345678, 75.0):
            assert f(np.int64(seed), t) == pytest.approx(standard_normal(seed, t), abs=1e-15)


def test_profile_matches_the_physics_function():
    from webline.physics.profile import profile_value
    ts, ys = [0.0, 1.0, 1.0, 3.0], [2.0, 4.0, 6.0, 0.0]
    f = engine.nb()["profile_value"]
    for t in (-1.0, 0.0, 0.5, 1.0 - 1e-6, 1.0, 2.0, 3.0, 9.0):
        assert f(np.array(ts), np.array(ys), t) == profile_value(ts, ys, t)


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.stem)
def test_engine_matches_the_reference(path):
    s = _system(path)
    eng = engine.simulate(s)
    assert eng.ok, eng.message
    ref = simulate_reference(s)
    cols = load_cells(s)
    assert cols
    np.testing.assert_allclose(eng.time, ref.time)
    assert _worst(eng, ref, cols) < ENGINE_VS_REFERENCE
    assert eng.meta["kind"] == "engine" and eng.columns == ref.columns


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.stem)
def test_engine_matches_the_cosimulation(path):
    from webline.orchestrator.master import simulate
    s = _system(path)
    cs = simulate(s, progress=False)
    assert cs.ok, cs.message
    eng = engine.simulate(s, t_eval=cs.time)
    assert _worst(eng, cs, load_cells(s)) < COSIM_TOLERANCE


def test_non_ideal_drive_matches_the_reference():
    s = _system(ROOT / "scenarios" / "ewl_out_of_round.yaml",
                **{"drives.speed_loops.sw_leader.drive": DRIVE})
    c = engine.compile_system(s)
    assert "sw_leader.theta_motor" in c.state_names
    eng = engine.simulate(s, compiled=c)
    ref = simulate_reference(s)
    assert _worst(eng, ref, load_cells(s)) < ENGINE_VS_REFERENCE
    # the motor speed rings through the backlash: a dead-zone crossing inside a fixed step is
    # integrated to first order only, so its bound is looser than the tensions'
    assert relative_rms(eng["sw_leader.omega_motor"], ref["sw_leader.omega_motor"]) < 1e-4


def test_batch_equals_single_runs():
    base = _system(ROOT / "scenarios" / "ewl_out_of_round.yaml", duration=1.0)
    variants = []
    for scale in (1.0, 0.8, 1.25):
        s = copy.deepcopy(base)
        for comp in s.components:
            if comp.model == "Span":
                comp.parameters["EA"] = comp.parameters.get("EA", 2.0e4) * scale
        variants.append(s)
    assert len({engine.structure_key(s) for s in variants}) == 1
    batch = engine.simulate_batch(variants)
    singles = [engine.simulate(s) for s in variants]
    cols = load_cells(base)
    for b, r in zip(batch, singles):
        assert b.ok
        for c in cols:
            np.testing.assert_allclose(b[c], r[c], rtol=1e-12, atol=0.0)
    # the variants differ: the batch did not run one parameter set three times
    assert relative_rms(batch[1][cols[0]], batch[2][cols[0]]) > 1e-6


def test_steady_line_stays_steady():
    s = _system(ROOT / "scenarios" / "ewl.yaml", duration=3.0)
    eng = engine.simulate(s)
    c = engine.compile_system(s)
    # the layout starts the line at its operating point: the state derivative is ~0 there
    dx = c.rhs_numpy(s.experiment.start, c.x0)
    # (angles turn; the rolls' radii change by one thickness per turn, so their speeds follow)
    rolls = {n for n, m in zip(c.ref.names, c.ref.system.components) if m.model in ("UnwindRoll", "RewindRoll")}
    moving = [i for i, n in enumerate(c.state_names)
              if n.endswith((".theta", ".theta_motor")) or n.split(".")[0] in rolls]
    rest = np.delete(dx, moving)
    assert np.max(np.abs(rest)) < 1e-9 * max(1.0, float(np.max(np.abs(c.x0))))
    for col in load_cells(s):
        T = eng[col]
        assert np.max(np.abs(T - T[0])) < 1e-3 * abs(T[0])


def test_empty_roll_fails_cleanly():
    s = _system(ROOT / "scenarios" / "ewl.yaml", duration=1.0)
    c = engine.compile_system(s)
    i = c.state_names.index("unwind.R")
    R_core = c.ref.models[c.ref.names.index("unwind")].R_core
    c.x0[i] = R_core * (1.0 + 1e-7)
    res = engine.simulate(s, compiled=c)
    assert res.status == "failed"
    assert "unwind" in res.message and "empty" in res.message
    assert res.time.size < 10


def test_diverged_roll_is_not_called_empty():
    """A roll whose radius reaches the core within one sample from far above it diverged:
    at its last recorded speed the radius falls one thickness a turn ({3}-{5})."""
    s = _system(ROOT / "scenarios" / "ewl.yaml", duration=1.0)
    c = engine.compile_system(s)
    k = c.ref.names.index("unwind")
    a = c.ref.offsets[k][0]
    m = c.ref.models[k]
    t = np.array([0.0, 0.002, 0.004])
    X = np.zeros((3, c.x0.size))
    X[:, a], X[:, a + 2] = 10.0, 0.15          # 10 rad/s at R = 0.15 m
    msg = engine._roll_failure(c.ref, k, X, t, 3, 0.006)
    assert "diverged" in msg and "unstable" in msg
    # the same radius change at a speed that does it in one interval: a roll run empty
    w = (0.15 - m.R_core) * 2.0 * np.pi / (m.thickness * 0.002)
    X[:, a] = w
    msg = engine._roll_failure(c.ref, k, X, t, 3, 0.006)
    assert "empty" in msg and "diverged" not in msg
    # nothing recorded before the failure: no speed to judge it by
    assert "empty" in engine._roll_failure(c.ref, k, X, t, 0, 0.002)


def test_bad_t_eval_is_refused():
    s = _system(ROOT / "scenarios" / "ewl.yaml", duration=0.2)
    with pytest.raises(ValueError, match="increasing"):
        engine.simulate(s, t_eval=[0.0, 0.1, 0.05])
    with pytest.raises(ValueError, match="before the experiment"):
        engine.simulate(s, t_eval=[-1.0, 0.1])


LOOPS = ("unwind", "sw_leader", "sw_follower", "pull_roll", "rewind")
FORMS = {  # model-form options (docs/layout.md); skipped where this checkout does not have them yet
    "damping": {"web.damping": "0.02 s"},
    "acceleration_ff_current_lag": {**{f"drives.speed_loops.{k}.acceleration_feedforward": True for k in LOOPS},
                                    **{f"drives.speed_loops.{k}.current_lag": "5 ms" for k in LOOPS}},
    "feedforward_reference": {f"drives.speed_loops.{k}.feedforward": "reference" for k in LOOPS},
    "feedforward_none": {f"drives.speed_loops.{k}.feedforward": "none" for k in LOOPS},
    "filter_order_2": {f"sensors.{s}.filter_order": 2 for s in ("lc9", "lc15", "lc19")},
    # a lag far below the step the line's modes need: the step is set by its stability alone
    "current_lag_fast": {f"drives.speed_loops.{k}.current_lag": "0.2 ms" for k in LOOPS},
}


def test_step_for_keeps_oscillating_modes_accurate_and_decaying_ones_stable():
    h_max = engine.H_MAX
    assert engine.step_for([-1.4 + 295.5j, -1.4 - 295.5j], h_max) == h_max
    # an oscillating (or growing) mode: |lambda| h = 0.5
    assert engine.step_for([-10.0 + 3000.0j, -10.0 - 3000.0j], h_max) == pytest.approx(0.5 / 3000.0, rel=1e-4)
    assert engine.step_for([3000.0], h_max) == pytest.approx(0.5 / 3000.0)
    # a decaying real mode (a 0.2 ms lag): |lambda| h = 2, inside RK4's real-axis limit 2.785
    assert engine.step_for([-5000.0, -1.4 + 295.5j], h_max) == pytest.approx(2.0 / 5000.0)
    z = -2.0 + engine.DECAY_SLOPE * 2.0j   # the edge of what counts as decaying real
    assert abs(1 + z + z ** 2 / 2 + z ** 3 / 6 + z ** 4 / 24) < 1.0
    assert engine.step_for([], h_max) == h_max


def test_a_fast_lag_sets_the_step_by_stability():
    s = _system(ROOT / "scenarios" / "paper" / "f_accel_decel.yaml", duration=0.5,
                **FORMS["current_lag_fast"])
    c = engine.compile_system(s)
    assert c.step() == pytest.approx(2.0 * 0.2e-3, rel=0.05)


@pytest.mark.parametrize("form", sorted(FORMS))
def test_model_forms_match_the_reference(form):
    try:
        s = _system(ROOT / "scenarios" / "paper" / "f_accel_decel.yaml", duration=3.0, **FORMS[form])
    except (ValueError, KeyError) as exc:
        pytest.skip(f"layout option not in this checkout: {exc}")
    eng = engine.simulate(s)
    assert eng.ok, eng.message
    ref = simulate_reference(s)
    assert _worst(eng, ref, load_cells(s)) < ENGINE_VS_REFERENCE


def test_load_cell_noise_is_the_models_noise_at_the_sample_times():
    path = ROOT / "scenarios" / "ewl_out_of_round.yaml"
    noisy = load_system(path, {"experiment.duration": "1 s", "sensors.lc15.noise": "0.5 N"})
    clean = without_noise(noisy)
    a, b = engine.simulate(noisy), engine.simulate(clean)
    c = engine.compile_system(noisy)
    model = c.ref.models[c.ref.names.index("lc15")]
    expected = np.array([model.noise(t) for t in a.time])
    assert np.std(expected) > 0.3
    # lc15 feeds no controller: the reading is the clean one plus the model's own noise sample
    np.testing.assert_allclose(a["lc15.T"] - b["lc15.T"], expected, atol=1e-9)


def test_torque_ripple_is_the_speed_loops_noise_held_at_the_sample_times():
    """The drive's torque ripple (speed loop ``torque_noise``) reaches the element as the
    model's own sample, held between output times, in the engine and in the co-simulation;
    the line's tensions then carry it."""
    from webline.orchestrator.master import simulate
    path = ROOT / "scenarios" / "ewl_out_of_round.yaml"
    ov = {"drives.speed_loops.sw_leader.torque_noise": "0.2 N*m"}
    noisy = _system(path, duration=1.0, **ov)
    clean = _system(path, duration=1.0)
    a, b = engine.simulate(noisy), engine.simulate(clean)
    c = engine.compile_system(noisy)
    model = c.ref.models[c.ref.names.index("sw_leader_speed_pi")]
    expected = np.array([model.noise(t) for t in a.time])
    assert np.std(expected) > 0.15
    # the torque is the law plus the sample; the loop's reaction to the ripple moves with the
    # line's states (a few percent of it per 1 ms sample), the held sample jumps by its full
    # size: sample to sample, the change of the torque is the change of the sample
    dtau = np.diff(a["sw_leader_speed_pi.tau"] - b["sw_leader_speed_pi.tau"])
    assert np.corrcoef(dtau, np.diff(expected))[0, 1] > 0.95
    assert np.std(a["lc15.T"] - b["lc15.T"]) > 1e-3
    # the co-simulation draws the same samples: the ripple's response agrees. Its bound is
    # looser than the tensions' 0.5 %: a white input puts energy up to the Nyquist frequency,
    # where the co-simulation's macro-step coupling error is largest (10 % measured on lc9)
    cs, cs_clean = simulate(noisy, progress=False), simulate(clean, progress=False)
    assert cs.ok, cs.message
    eng, eng_clean = engine.simulate(noisy, t_eval=cs.time), engine.simulate(clean, t_eval=cs.time)
    for col in load_cells(noisy):
        d_eng, d_cs = eng[col] - eng_clean[col], cs[col] - cs_clean[col]
        assert np.std(d_eng - d_cs) < 0.2 * np.std(d_eng), col
    with pytest.raises(ValueError, match="torque_noise"):
        simulate_reference(noisy)


def test_negative_torque_ripple_is_refused():
    with pytest.raises(Exception, match="torque_noise"):
        load_system(ROOT / "scenarios" / "ewl_out_of_round.yaml",
                    {"drives.speed_loops.sw_leader.torque_noise": "-1 N*m"})


def test_torque_ripple_in_user_units_reaches_the_speed_loop_in_si_with_its_seed():
    s = load_system(ROOT / "scenarios" / "ewl_out_of_round.yaml",
                    {"drives.speed_loops.sw_leader.torque_noise": "0.1 lbf*ft",
                     "drives.speed_loops.sw_leader.noise_seed": 9,
                     "drives.speed_loops.unwind.torque_noise": "0.02 N*m"})
    p = {c.name: c.parameters for c in s.components}
    assert p["sw_leader_speed_pi"]["torque_noise"] == pytest.approx(0.1 * 4.4482216152605 * 0.3048, rel=1e-9)
    assert p["sw_leader_speed_pi"]["seed"] == 9.0
    # without a seed, one from the loop's position, apart from the load cells' 1, 2, ...
    assert p["unwind_speed_pi"]["seed"] >= 1000.0 and p["unwind_speed_pi"]["seed"] != 9.0
    assert "torque_noise" not in p["rewind_speed_pi"]  # no ripple: the parameter is not written


def test_reused_slaves_give_the_results_of_fresh_ones():
    """The fast engine shares the slaves of equal components between systems (setting
    up a variant is mostly registering FMU variables): after a variant, the first system
    compiles to the code, parameters and start state of one built from fresh slaves, and
    runs to the same numbers as before the variant."""
    from webline.orchestrator import reference
    base = _system(ROOT / "scenarios" / "ewl_out_of_round.yaml", duration=1.0)
    other = copy.deepcopy(base)
    span = next(c for c in other.components if c.model == "Span")
    span.parameters["EA"] = span.parameters.get("EA", 2.0e4) * 1.3
    reference._REUSE.clear()
    first = engine.simulate(base)
    shared = len(reference._REUSE)
    engine.simulate(other)
    assert len(reference._REUSE) == shared + 1   # only the changed span was made again
    c = engine.compile_system(base)
    fresh = reference.ReferenceSystem(base)      # nothing shared
    assert not any(x is y for x, y in zip(fresh.slaves, c.ref.slaves))
    b = engine._Builder(fresh)
    assert c.source == b.source() and list(c.p) == list(b.p) and list(c.x0) == list(fresh.x0)
    again = engine.simulate(base, compiled=c)
    for col in load_cells(base):
        np.testing.assert_array_equal(first[col], again[col])


def test_profiles_with_other_knots_share_the_compiled_code_and_batch():
    # a run's profile knots (a ramp, a steady run) are parameters, not structure: the
    # same line on two runs compiles once and runs as one batch
    base = _system(ROOT / "scenarios" / "ewl_out_of_round.yaml", duration=1.0)
    more = copy.deepcopy(base)
    prof = next(c for c in more.components if c.model == "Profile")
    n = int(prof.parameters["n"])
    t, y = [prof.parameters[f"t[{k}]"] for k in range(1, n + 1)], [prof.parameters[f"y[{k}]"] for k in range(1, n + 1)]
    # one knot more on the profile's own line (values unchanged): t beyond the record
    t2, y2 = t + [t[-1] + 50.0], y + [y[-1]]
    prof.parameters = {k: v for k, v in prof.parameters.items() if not k.startswith(("t[", "y["))}
    prof.parameters["n"] = float(n + 1)
    for k, (a, b) in enumerate(zip(t2, y2), start=1):
        prof.parameters[f"t[{k}]"], prof.parameters[f"y[{k}]"] = a, b
    ca, cb = engine.compile_system(base), engine.compile_system(more)
    assert ca.p.size + 2 == cb.p.size
    assert engine.structure_key(base) == engine.structure_key(more)
    batch = engine.simulate_batch([base, more], compiled=[ca, cb])
    singles = [engine.simulate(base, compiled=ca), engine.simulate(more, compiled=cb)]
    for b, r in zip(batch, singles):
        assert b.ok and r.ok
        for c in load_cells(base):
            np.testing.assert_allclose(b[c], r[c], rtol=1e-12, atol=0.0)
    for c in load_cells(base):   # a knot after the record changes nothing in it
        np.testing.assert_allclose(singles[0][c], singles[1][c], rtol=1e-12, atol=0.0)
