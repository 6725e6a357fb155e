"""Material rolls {3}-{8}: radius per revolution, inertia, paid-out length, momentum, problems."""
import math

import pytest

from webline.physics.drive import Drive
from webline.physics.integrate import integrate
from webline.physics.material_roll import (RewindRollModel, RollEmptyError, UnwindRollModel, inertia,
                                           web_length)

ROLL = dict(R0=0.15, R_core=0.05, thickness=2.0e-4, width=0.5, rho=1000.0, J_core=0.02)


def run(model, u, t_end, h=1.0e-3):
    """Samples (t, x) of the model with inputs held at ``u``."""
    x = model.initial_state()
    out = [(0.0, x)]
    n = int(round(t_end / h))
    for k in range(n):
        x = integrate(lambda t, y: model.derivatives(t, y, u), k * h, x, h, h)
        out.append(((k + 1) * h, x))
    return out


def crossings(samples, period=2.0 * math.pi):
    """(revolution number, R) each time theta passes a whole revolution (linear interpolation)."""
    found = []
    for (t0, a), (t1, b) in zip(samples, samples[1:]):
        k0, k1 = math.floor(abs(a[1]) / period), math.floor(abs(b[1]) / period)
        for k in range(k0 + 1, k1 + 1):
            f = (k * period - abs(a[1])) / (abs(b[1]) - abs(a[1]))
            found.append((k, a[2] + f * (b[2] - a[2])))
    return found


def test_inertia_by_hand():
    # J_w = pi/2 * 1000 * 0.5 * (0.1^4 - 0.05^4) = 785.398... * 9.375e-5
    assert inertia(0.1, 0.05, 1000.0, 0.5, 0.02) == pytest.approx(0.02 + 0.07363107781851078, rel=1e-12)
    m = UnwindRollModel(**ROLL)
    assert m.outputs(0.0, m.initial_state(), [0.0, 0.0])[4] == pytest.approx(
        0.02 + 0.5 * math.pi * 1000 * 0.5 * (0.15 ** 4 - 0.05 ** 4), rel=1e-12)


def test_unwind_radius_drops_one_thickness_per_revolution():
    # 20 rad/s with a torque that keeps it turning: about 6 revolutions in 2 s
    m = UnwindRollModel(**ROLL, omega0=20.0)
    samples = run(m, [0.0, 10.0], 2.0)
    revs = crossings(samples)
    assert len(revs) >= 5
    for k, R in revs:
        assert R == pytest.approx(ROLL["R0"] - k * ROLL["thickness"], abs=1e-9)


def test_rewind_radius_grows_one_thickness_per_revolution():
    m = RewindRollModel(**ROLL, omega0=20.0)
    samples = run(m, [10.0, 0.0], 2.0)
    revs = crossings(samples)
    assert len(revs) >= 5
    for k, R in revs:
        assert R == pytest.approx(ROLL["R0"] + k * ROLL["thickness"], abs=1e-9)


def test_paid_out_length_is_integral_of_speed():
    # With {5}: d(R^2)/dt = -t_w v/pi, so int v dt = pi (R0^2 - R^2)/t_w.
    m = UnwindRollModel(**ROLL, omega0=15.0)
    h = 1.0e-3
    samples = run(m, [-2.0, 40.0], 3.0, h)
    v = [m.outputs(t, x, [0.0, 0.0])[3] for t, x in samples]
    paid = sum(0.5 * h * (a + b) for a, b in zip(v, v[1:]))
    R_end = samples[-1][1][2]
    assert paid == pytest.approx(web_length(ROLL["R0"], R_end, ROLL["thickness"]), rel=1e-6)
    assert paid == pytest.approx(math.pi * (ROLL["R0"] ** 2 - R_end ** 2) / ROLL["thickness"], rel=1e-6)


@pytest.mark.parametrize("cls", [UnwindRollModel, RewindRollModel])
def test_free_roll_conserves_angular_momentum(cls):
    # {1}/{8} without torque, tension or friction: d(J omega)/dt = 0, so the
    # unwind speeds up as it loses inertia and the rewind slows down.
    m = cls(**ROLL, omega0=30.0)
    samples = run(m, [0.0, 0.0], 2.0)
    L0 = m.roll_inertia(ROLL["R0"]) * 30.0
    for t, x in samples[::100]:
        assert m.roll_inertia(x[2]) * x[0] == pytest.approx(L0, rel=1e-9)
    w_end = samples[-1][1][0]
    assert (w_end > 30.0) if cls is UnwindRollModel else (w_end < 30.0)


def test_unwind_holding_torque_keeps_speed():
    # {7} at constant speed: tau = b w - R T - rho w_w R^3 t_w w^2 (at the current R)
    p = dict(ROLL, b=0.05)
    m = UnwindRollModel(**p, omega0=10.0)
    x = m.initial_state()
    R, w, T = p["R0"], 10.0, 80.0
    tau = p["b"] * w - R * T - p["rho"] * p["width"] * R ** 3 * p["thickness"] * w * w
    assert m.derivatives(0.0, x, [tau, T])[0] == pytest.approx(0.0, abs=1e-12)
    assert m.derivatives(0.0, x, [tau + 1.0, T])[0] == pytest.approx(1.0 / m.roll_inertia(R), rel=1e-12)


def test_unwind_running_empty_raises_clear_error():
    m = UnwindRollModel(**dict(ROLL, R0=0.0502), omega0=50.0)
    with pytest.raises(RollEmptyError, match=r"R_core = 0.05 m"):
        run(m, [0.0, 0.0], 1.0)


def test_non_ideal_drive_adds_motor_states_and_inertia():
    d = Drive(1, J_motor=0.03, stiffness=5e3, damping=0.5)
    m = UnwindRollModel(**ROLL, omega0=4.0, theta0=1.0, drive=d)
    assert m.STATES == ("omega", "theta", "R", "theta_motor", "omega_motor")
    x = m.initial_state()
    assert x[3:] == [1.0, 4.0]
    y = m.outputs(0.0, x, [0.0, 0.0])
    assert y[4] == pytest.approx(m.roll_inertia(ROLL["R0"]) + 0.03, rel=1e-12)
    assert y[5] == 4.0
    # no twist: the motor torque accelerates only the motor
    dx = m.derivatives(0.0, x, [3.0, 0.0])
    assert dx[4] == pytest.approx(3.0 / 0.03)


@pytest.mark.parametrize("cls", [UnwindRollModel, RewindRollModel])
@pytest.mark.parametrize("field,value", [("thickness", 0.0), ("width", -1.0), ("rho", 0.0), ("R_core", 0.0),
                                         ("J_core", -0.1), ("b", -1.0)])
def test_problems_name_the_parameter(cls, field, value):
    names = [n for n, _ in cls(**dict(ROLL, **{field: value})).problems()]
    assert field in names


def test_radius_below_core_is_a_problem():
    assert [n for n, _ in UnwindRollModel(**dict(ROLL, R0=0.05)).problems()] == ["R0"]
    assert [n for n, _ in RewindRollModel(**dict(ROLL, R0=0.04)).problems()] == ["R0"]
    assert RewindRollModel(**dict(ROLL, R0=0.05)).problems() == []  # empty core is fine
    assert [n for n, _ in RewindRollModel(**dict(ROLL, R0=0.05, J_core=0.0)).problems()] == ["J_core"]
    assert UnwindRollModel(**ROLL).problems() == []
    assert [n for n, _ in UnwindRollModel(**ROLL, drive=Drive(1, J_motor=0.0)).problems()] == ["drive.J_motor"]
