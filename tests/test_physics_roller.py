"""Rollers {22} and the non-ideal drive: speed decay, constant speed, shaft mode, backlash."""
import math

import pytest

from webline.physics.drive import Drive, dead_zone, shaft_torque
from webline.physics.integrate import integrate
from webline.physics.roller import DrivenRollerModel, IdleRollerModel


def simulate(model, u, t_end, h=1.0e-3, max_sub=None):
    x = model.initial_state()
    n = int(round(t_end / h))
    for k in range(n):
        sub = min(h, model.max_substep(x)) if max_sub is None else max_sub
        x = integrate(lambda t, y: model.derivatives(t, y, u), k * h, x, h, sub)
    return x


def test_idle_roller_equal_tensions_keeps_speed():
    m = IdleRollerModel(R=0.05, J=0.01, b=0.0, omega0=12.0, theta0=0.5)
    x = simulate(m, [150.0, 150.0], 2.0)
    assert x[0] == 12.0
    assert x[1] == pytest.approx(0.5 + 12.0 * 2.0, rel=1e-12)
    assert m.outputs(2.0, x, [150.0, 150.0]) == [12.0, x[1], pytest.approx(0.6), 0.0]  # a = 0


def test_idle_roller_friction_decays_exponentially():
    J, b, w0 = 0.01, 0.004, 12.0
    m = IdleRollerModel(R=0.05, J=J, b=b, omega0=w0)
    for t_end in (0.5, 2.0):
        x = simulate(m, [100.0, 100.0], t_end)
        assert x[0] == pytest.approx(w0 * math.exp(-b * t_end / J), rel=1e-9)
        # theta = w0 J/b (1 - exp(-b t/J))
        assert x[1] == pytest.approx(w0 * J / b * (1.0 - math.exp(-b * t_end / J)), rel=1e-9)


def test_tension_difference_accelerates_roller():
    # R (T_out - T_in)/J = 0.05 * 20 / 0.01 = 100 rad/s^2
    m = IdleRollerModel(R=0.05, J=0.01)
    assert simulate(m, [100.0, 120.0], 0.3)[0] == pytest.approx(30.0, rel=1e-12)


def test_driven_roller_holding_torque():
    # {22}: tau = b w - R (T_out - T_in) keeps w
    R, J, b, w = 0.1, 0.05, 0.02, 8.0
    m = DrivenRollerModel(R=R, J=J, b=b, omega0=w)
    tau = b * w - R * (130.0 - 100.0)
    x = simulate(m, [tau, 100.0, 130.0], 1.0)
    assert x[0] == pytest.approx(w, rel=1e-12)


def test_drive_shaft_mode_and_automatic_substep():
    # Two inertias on a spring, motor torque tau from rest: twist
    # phi = phi_ss (1 - cos wn t), phi_ss = tau/(J_m wn^2), wn^2 = k (1/J_m + 1/J).
    Jm, J, k, tau = 0.01, 0.03, 3.0e4, 2.0
    wn = math.sqrt(k * (1 / Jm + 1 / J))
    d = Drive(1, J_motor=Jm, stiffness=k, damping=0.0, backlash=0.0)
    m = DrivenRollerModel(R=0.1, J=J, drive=d)
    assert m.max_substep(m.initial_state()) == pytest.approx(0.1 / wn)
    assert DrivenRollerModel(R=0.1, J=J).max_substep([0.0, 0.0]) == math.inf
    t_end = 0.3
    x = simulate(m, [tau, 0.0, 0.0], t_end)
    phi = x[2] - x[1]
    phi_ss = tau / (Jm * wn * wn)
    assert phi == pytest.approx(phi_ss * (1 - math.cos(wn * t_end)), abs=1e-3 * phi_ss)
    # momentum: J_m w_m + J w = tau t
    assert Jm * x[3] + J * x[0] == pytest.approx(tau * t_end, rel=1e-9)
    # a 1 ms sub-step (h wn = 1.15) visibly damps the mode: the automatic choice matters
    x_coarse = simulate(m, [tau, 0.0, 0.0], t_end, max_sub=1.0e-3)
    assert abs((x_coarse[2] - x_coarse[1]) - phi) > 0.05 * phi_ss


def test_backlash_delays_torque():
    # Motor starts in the middle of a dead zone of width 2 mrad: the roller
    # feels nothing until the motor has turned half of it:
    # 1e-3 = 1/2 (tau/J_m) t^2 -> t = sqrt(2e-3 J_m / tau).
    Jm, tau, backlash = 0.01, 0.5, 2.0e-3
    t_contact = math.sqrt(2 * 0.5 * backlash * Jm / tau)
    d = Drive(1, J_motor=Jm, stiffness=1.0e4, damping=0.5, backlash=backlash)
    m = DrivenRollerModel(R=0.1, J=0.02, drive=d)
    h = t_contact / 100
    before = simulate(m, [tau, 0.0, 0.0], 0.9 * t_contact, h=h)
    assert before[0] == 0.0 and before[1] == 0.0
    assert before[3] == pytest.approx(tau / Jm * 0.9 * t_contact, rel=1e-9)
    after = simulate(m, [tau, 0.0, 0.0], 1.5 * t_contact, h=h)
    assert after[0] > 0.0


def test_dead_zone_and_shaft_torque():
    assert dead_zone(0.004, 0.002) == pytest.approx(0.003)
    assert dead_zone(-0.004, 0.002) == pytest.approx(-0.003)
    assert dead_zone(0.0009, 0.002) == 0.0
    assert shaft_torque(0.004, 0.0, 100.0, 1.0, 0.002) == pytest.approx(0.3)
    # separating teeth do not pull: spring pushes, fast opening damping would pull
    assert shaft_torque(0.0011, -10.0, 100.0, 1.0, 0.002) == 0.0
    assert shaft_torque(0.004, -1.0, 100.0, 1.0, 0.0) == pytest.approx(-0.6)


def test_roller_problems():
    assert [n for n, _ in IdleRollerModel(R=0.0, J=0.01).problems()] == ["R"]
    assert [n for n, _ in IdleRollerModel(R=0.1, J=-1.0, b=-0.1).problems()] == ["J", "b"]
    bad = DrivenRollerModel(R=0.1, J=0.1, drive=Drive(1, J_motor=0.01, stiffness=0.0, backlash=-1e-3))
    assert [n for n, _ in bad.problems()] == ["drive.stiffness", "drive.backlash"]
    assert [n for n, _ in DrivenRollerModel(R=0.1, J=0.1, drive=Drive(0.5)).problems()] == ["drive.enabled"]
    # disabled drive: its parameters are not used, so not checked
    assert DrivenRollerModel(R=0.1, J=0.1, drive=Drive(0, J_motor=0.0)).problems() == []


@pytest.mark.parametrize("backlash", [0.0, 2.0e-3])
def test_drive_starts_in_equilibrium_with_the_initial_torque(backlash):
    # holding torque of {22}: tau = b w - R (T_out - T_in) = 0.16 - 3 = -2.84 N.m;
    # the shaft starts twisted by tau/k (+ half the backlash, on the loaded side)
    R, J, b, w, T_in, T_out = 0.1, 0.05, 0.02, 8.0, 100.0, 130.0
    tau = b * w - R * (T_out - T_in)
    d = Drive(1, J_motor=0.02, stiffness=5e3, damping=0.3, backlash=backlash)
    m = DrivenRollerModel(R=R, J=J, b=b, omega0=w, drive=d, tau0=tau)
    x0 = m.initial_state()
    assert x0[2] - x0[1] == pytest.approx(-2.84 / 5e3 - backlash / 2, rel=1e-12)
    assert m.derivatives(0.0, x0, [tau, T_in, T_out]) == [pytest.approx(0.0, abs=1e-12), w, w,
                                                         pytest.approx(0.0, abs=1e-12)]
    x = simulate(m, [tau, T_in, T_out], 0.5)
    assert x[0] == pytest.approx(w, rel=1e-10) and x[3] == pytest.approx(w, rel=1e-10)
