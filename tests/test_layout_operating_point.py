"""The operating point written into the start values: hand-derived equalities, and a true equilibrium
of the element models (the monolithic reference's right-hand side vanishes at t = 0)."""
import math
from pathlib import Path

import pytest

from webline.orchestrator.layout import load_system, span_ends, load_layout
from webline.physics.controllers import speed_gains
from webline.physics.material_roll import radius_rate

ROOT = Path(__file__).resolve().parents[1]
EWL = ROOT / "scenarios" / "ewl.yaml"
LBF = 4.4482216152605


def by_model(system, model):
    return [c for c in system.components if c.model == model]


def spans(system):
    return [system.component(s["component"]) for s in system.meta["spans"]]


def elements(system):
    return [system.component(n) for n in system.meta["elements"]]


def frictionless(**extra):
    """The EWL-like line with frictionless rollers (all span tensions then equal their zone's)."""
    ov = {f"path.{n}.friction": 0 for n in ("unwind", "idler_u1", "guide_in", "guide_out", "idler_u2", "roller9",
                                            "sw_leader", "sw_follower", "idler_p1", "roller15", "pull_roll",
                                            "idler_r1", "roller19", "rewind")}
    ov.update(extra)
    return load_system(EWL, ov)


def test_span_tensions_equal_their_zone_reference():
    s = frictionless(**{"experiment.tension.rewind_zone": "18 lbf"})
    T = [c.parameters["T0"] for c in spans(s)]
    # unwind zone (span1..6) and the speed-only zones after it (draw 1: the tension carries through)
    assert T[:10] == pytest.approx([15 * LBF] * 10, rel=1e-12)
    assert T[10:] == pytest.approx([18 * LBF] * 3, rel=1e-12)  # rewind zone


def test_speed_ratio_across_every_span_is_mass_conservation():
    for s in (load_system(EWL), frictionless()):
        EA = s.meta["web"]["EA"]
        v = [e["v0"] for e in s.meta["elements"].values()]
        T = [c.parameters["T0"] for c in spans(s)]
        for k, c in enumerate(spans(s)):
            T_in = T[k - 1] if k else 0.0
            assert v[k + 1] / v[k] == pytest.approx((EA - T_in) / (EA - T[k]), rel=1e-12)
            assert c.inputs["v_in"] == v[k] and c.inputs["v_out"] == v[k + 1] and c.inputs["T_in"] == T_in
        assert v[list(s.meta["elements"]).index("sw_leader")] == pytest.approx(1.016, rel=1e-15)
        # the unwind turns with the unstretched web: v0 = v1 (1 - T1/EA)
        assert v[0] == pytest.approx(v[1] * (1 - T[0] / EA), rel=1e-12)


def test_friction_raises_tension_across_idlers_and_load_cell_reads_the_reference():
    s = load_system(EWL)
    T = [c.parameters["T0"] for c in spans(s)]
    for i, (name, e) in enumerate(s.meta["elements"].items()):
        if e["kind"] in ("idle_roller", "load_cell_roller"):
            c = s.component(name)
            b, R, omega = c.parameters["b"], c.parameters["R"], c.parameters["omega0"]
            assert T[i] - T[i - 1] == pytest.approx(b * omega / R, rel=1e-9)  # {22} with tau = 0
    for name in ("lc9", "lc19"):
        lc = s.component(name)
        assert lc.parameters["T0"] == pytest.approx(15 * LBF, rel=1e-12)
        w = 0.5  # equal angles: the plain mean
        assert lc.parameters["T0"] == pytest.approx(w * lc.inputs["T_in"] + w * lc.inputs["T_out"], rel=1e-12)


def test_element_speeds_and_inputs():
    s = load_system(EWL)
    for name, e in s.meta["elements"].items():
        c = s.component(name)
        R = c.parameters.get("R", c.parameters.get("R0"))
        assert c.parameters["omega0"] == pytest.approx(e["v0"] / R, rel=1e-15)
        assert e["f0"] == pytest.approx(e["v0"] / (2 * math.pi * R), rel=1e-12)


def test_speed_pi_holds_the_torque_with_zero_error():
    s = frictionless()
    for pi in by_model(s, "SpeedPI"):
        el = s.component(pi.element)
        p, u = pi.parameters, pi.inputs
        assert (u["v_ref"] + u["v_trim"]) / u["R"] == pytest.approx(u["omega"], rel=1e-12)  # zero speed error
        K_p, w_ld = speed_gains(u["J"], p["K_ref"], p["zeta"])
        assert p["w_ld"] == pytest.approx(w_ld)
        ff = u["R"] * (u["T_in"] - u["T_out"]) + p["b_ff"] * u["omega"]
        tau = ff + K_p * p["w_ld"] * p["I0"]
        assert el.inputs["tau"] == pytest.approx(tau, rel=1e-12, abs=1e-12)
        if el.model == "DrivenRoller":
            # torque balance of {22}: tau = R (T_in - T_out) (no friction), integrator exactly 0
            assert tau == pytest.approx(el.parameters["R"] * (el.inputs["T_in"] - el.inputs["T_out"]), abs=1e-12)
            assert p["I0"] == 0.0
        else:
            # only the small {6} and radius-change terms escape the feed-forward
            assert abs(K_p * p["w_ld"] * p["I0"]) < 1e-2 * abs(tau)


def test_speed_pi_without_feedforward_starts_its_integrator():
    s = load_system(EWL, {"drives.speed_loops.pull_roll.feedforward": "false"})
    pi, el = s.component("pull_roll_speed_pi"), s.component("pull_roll")
    K_p, w_ld = speed_gains(pi.inputs["J"], pi.parameters["K_ref"], pi.parameters["zeta"])
    hold = el.parameters["b"] * el.parameters["omega0"] + el.parameters["R"] * (el.inputs["T_in"] - el.inputs["T_out"])
    assert pi.parameters["feedforward"] == 0.0
    assert K_p * w_ld * pi.parameters["I0"] == pytest.approx(hold, rel=1e-12)
    assert not any(k.dst == pi.name and k.dst_var in ("T_in", "T_out") for k in s.connections)


def test_tension_loops_start_at_rest():
    s = load_system(EWL)
    for t in by_model(s, "TensionPI"):
        assert t.parameters["I0"] == 0.0
        assert t.inputs["T_ref"] == t.inputs["T_meas"]
    # each speed reference is the line speed times the element's speed ratio to the master
    for name, e in s.meta["elements"].items():
        if e["driven"]:
            ref = "line_speed" if name == s.meta["master"] else f"{name}_v_ref"
            assert s.component(ref).parameters["y[1]"] == pytest.approx(e["v0"], rel=1e-15)


def test_non_ideal_drive_parameters_and_inertia():
    s = load_system(EWL, {"drives.speed_loops.sw_follower.drive":
                          "{motor_inertia: 0.02 kg*m^2, stiffness: 3000 N*m/rad, backlash: 0.2 deg}"})
    p = s.component("sw_follower").parameters
    assert p["drive.enabled"] == 1.0 and p["drive.J_motor"] == 0.02 and p["drive.stiffness"] == 3000
    assert p["drive.backlash"] == pytest.approx(math.radians(0.2)) and p["drive.damping"] == 0.0
    assert s.component("sw_follower_speed_pi").inputs["J"] == pytest.approx(p["J"] + 0.02)
    assert s.component("sw_leader").parameters["drive.enabled"] == 0.0


def test_eccentricity_sign_convention_from_wrap():
    ov = {"path.idler_u1.eccentricity": "{C: [1 mm, 0.5 mm], psi: [0.1, 0.2]}", "path.idler_u1.wrap": "90 deg"}
    layout = load_layout(EWL, ov)
    C_up, psi_up, _, _ = span_ends(layout.path, 1)  # span leaving idler_u1: as given
    assert C_up == [1e-3, 0.5e-3] and psi_up == [0.1, 0.2]
    _, _, C_down, psi_down = span_ends(layout.path, 0)  # span entering idler_u1: psi_j + pi + j * wrap
    assert C_down == [1e-3, 0.5e-3]
    for j, (got, psi) in enumerate(zip(psi_down, [0.1, 0.2]), start=1):
        assert math.cos(got) == pytest.approx(math.cos(psi + math.pi + j * math.pi / 2))
        assert math.sin(got) == pytest.approx(math.sin(psi + math.pi + j * math.pi / 2))
    # a span end given explicitly replaces the derived one
    layout = load_layout(EWL, {**ov, "path.unwind.span": "{length: 1.2 m, down: {C: [0.2 mm]}}"})
    assert span_ends(layout.path, 0)[2:] == ([0.2e-3], [0.0])
    # with a tiny wrap the entering span changes opposite to the leaving one
    layout = load_layout(EWL, {**ov, "path.idler_u1.wrap": 0})
    C_up, psi_up, _, _ = span_ends(layout.path, 1)
    _, _, C_down, psi_down = span_ends(layout.path, 0)
    for th in (0.0, 0.7, 2.0):
        up = sum(c * math.sin((j + 1) * th + p) for j, (c, p) in enumerate(zip(C_up, psi_up)))
        down = sum(c * math.sin((j + 1) * th + p) for j, (c, p) in enumerate(zip(C_down, psi_down)))
        assert down == pytest.approx(-up)


def test_start_is_an_equilibrium_of_the_element_models():
    """dx/dt = 0 at t = 0 for every state but angles and roll radii; a roll's speed changes only as
    much as keeps its surface speed while its radius changes ({5})."""
    reference = pytest.importorskip("webline.orchestrator.reference")
    for ov in ({}, {"experiment.line_speed": 0},
               {"drives.master": "unwind", "drives.tension_loops.unwind_zone.element": "sw_leader"},
               {"drives.speed_loops.pull_roll.feedforward": "false", "sensors.lc9.angle_in": "30 deg"}):
        s = load_system(EWL, ov)
        ref = reference.ReferenceSystem(s)
        dx = ref.rhs(0.0, ref.x0)
        x0 = dict(zip(ref.state_names, ref.x0))
        for name, d in zip(ref.state_names, dx):
            if name.endswith((".theta", ".R")):
                continue
            if name in ("unwind.omega", "rewind.omega"):
                roll = name.split(".")[0]
                c = s.component(roll)
                omega, R = x0[name], x0[f"{roll}.R"]
                expect = -omega * radius_rate(omega, c.parameters["thickness"], -1 if roll == "unwind" else 1) / R
                assert d == pytest.approx(expect, rel=1e-6, abs=1e-12), (ov, name)
            else:
                assert abs(d) < 1e-9, (ov, name, d)
