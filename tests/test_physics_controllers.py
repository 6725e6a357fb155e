"""PI controllers {24}, {25}: gains, open-loop step response, feed-forward, limits, anti-windup."""
import math

import pytest

from webline.physics.controllers import SpeedPIModel, TensionPIModel, pi_step_response, speed_gains
from webline.physics.integrate import integrate


def run(model, u, t_end, h=1.0e-3):
    """Output history [(t, y)] with inputs held at ``u``."""
    x = model.initial_state()
    hist = [(0.0, model.outputs(0.0, x, u))]
    for k in range(int(round(t_end / h))):
        x = integrate(lambda t, y: model.derivatives(t, y, u), k * h, x, h, h)
        hist.append(((k + 1) * h, model.outputs((k + 1) * h, x, u)))
    return hist


def test_speed_gains_of_24():
    # EWL unwind: K_ref = 15, zeta = 1.1 -> w_ld = 15/4.84
    assert speed_gains(2.0, 15.0, 1.1) == (30.0, pytest.approx(3.0991735537190084))
    assert SpeedPIModel(K_ref=15.0, zeta=1.1).w_ld == pytest.approx(15.0 / 4.84)
    assert SpeedPIModel(K_ref=15.0, zeta=1.1, w_ld=2.5).w_ld == 2.5


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_tension_pi_open_loop_step(sign):
    # {25}: K (s + w_i)/s on a constant error e0 -> sign K e0 (1 + w_i t)
    K, w_i, e0 = 2.0e-3, 10.0, 20.0
    m = TensionPIModel(K=K, w_i=w_i, sign=sign)
    for t, y in run(m, [120.0, 100.0], 0.5)[::50]:
        assert y[0] == pytest.approx(sign * pi_step_response(K, w_i, e0, t), rel=1e-12, abs=1e-15)
    assert pi_step_response(K, w_i, e0, 0.3) == pytest.approx(K * e0 * 4.0)


def test_speed_pi_open_loop_step_with_feedforward():
    # e0 = v_ref/R - omega = 1.0/0.2 - 4 = 1 rad/s; K_p = J K_ref = 0.5*20 = 10;
    # w_ld = 20/(4*0.25) = 20; ff = R (T_in - T_out) + b_ff omega = 0.2*(50 - 80) + 0.1*4 = -5.6
    m = SpeedPIModel(K_ref=20.0, zeta=0.5, feedforward=1, b_ff=0.1)
    u = [0.9, 0.1, 0.2, 4.0, 0.5, 50.0, 80.0]
    for t, y in run(m, u, 0.4)[::40]:
        assert y[0] == pytest.approx(-5.6 + 10.0 * 1.0 * (1.0 + 20.0 * t), rel=1e-12)
        assert y[1] == pytest.approx(5.0)
    # no feed-forward
    m0 = SpeedPIModel(K_ref=20.0, zeta=0.5, feedforward=0, b_ff=0.1)
    assert m0.outputs(0.0, [0.0], u)[0] == pytest.approx(10.0)


def test_anti_windup_stops_integrator_at_the_limit():
    # saturated at tau_max = 3 from the start (K_p e0 = 10): the integral must
    # not grow, so the output leaves the limit as soon as the error reverses.
    m = SpeedPIModel(K_ref=20.0, zeta=0.5, tau_min=-3.0, tau_max=3.0)
    u = [0.9, 0.1, 0.2, 4.0, 0.5, 0.0, 0.0]
    x = m.initial_state()
    for k in range(500):
        x = integrate(lambda t, y: m.derivatives(t, y, u), k * 1e-3, x, 1e-3, 1e-3)
    assert m.outputs(0.5, x, u)[0] == 3.0
    assert x[0] == 0.0
    u_rev = [0.9, 0.1, 0.2, 5.1, 0.5, 0.0, 0.0]  # e = -0.1 -> K_p e = -1
    assert m.outputs(0.5, x, u_rev)[0] == pytest.approx(-1.0)
    # integrating toward the inside of the limits continues while saturated
    assert m.derivatives(0.0, [0.0], u_rev) == [pytest.approx(-0.1)]


def test_tension_pi_anti_windup_with_negative_sign():
    # sign -1, error +10 N: output -K(e + w I) falls to trim_min and must stop there
    m = TensionPIModel(K=1.0e-2, w_i=10.0, sign=-1.0, trim_min=-0.05, trim_max=0.05)
    x = [0.0]
    assert m.outputs(0.0, x, [110.0, 100.0]) == [-0.05]
    assert m.derivatives(0.0, x, [110.0, 100.0]) == [0.0]
    # at the upper limit an error pushing down keeps integrating
    assert m.derivatives(0.0, [-100.0], [110.0, 100.0]) == [10.0]


def test_controller_problems():
    assert [n for n, _ in SpeedPIModel(K_ref=0.0, zeta=1.1).problems()] == ["K_ref"]
    assert [n for n, _ in SpeedPIModel(K_ref=1.0, zeta=1.1, tau_min=1.0, tau_max=0.0).problems()] == ["tau_max"]
    assert [n for n, _ in SpeedPIModel(K_ref=1.0, feedforward=2).problems()] == ["feedforward"]
    assert [n for n, _ in TensionPIModel(K=1e-3, sign=0.0).problems()] == ["sign"]
    assert [n for n, _ in TensionPIModel(K=-1e-3, w_i=-1.0).problems()] == ["K", "w_i"]


def test_speed_pi_rejects_bad_radius_input():
    with pytest.raises(ValueError, match="input R"):
        SpeedPIModel(K_ref=15.0).outputs(0.0, [0.0], [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0])
