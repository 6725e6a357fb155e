"""Load cell: wrap-geometry weights, first-order filter, deterministic seeded noise."""
import math
import statistics

import pytest

from webline.physics.integrate import integrate
from webline.physics.load_cell import LoadCellModel, standard_normal, wrap_weights


def test_wrap_weights():
    assert wrap_weights(0.3, 0.3) == (pytest.approx(0.5), pytest.approx(0.5))
    # cos 0 = 1, cos(pi/3) = 1/2 -> weights 2/3, 1/3
    assert wrap_weights(0.0, math.pi / 3) == (pytest.approx(2 / 3), pytest.approx(1 / 3))
    m = LoadCellModel(angle_in=0.0, angle_out=math.pi / 3)
    assert m.outputs(0.0, [], [90.0, 120.0]) == [pytest.approx(100.0)]


def test_filter_step_response():
    tau = 0.05
    m = LoadCellModel(tau_filter=tau, T0=10.0)
    x, u, h = m.initial_state(), [110.0, 110.0], 1e-3
    for k in range(100):
        x = integrate(lambda t, y: m.derivatives(t, y, u), k * h, x, h, h)
    assert m.outputs(0.1, x, u)[0] == pytest.approx(110.0 - 100.0 * math.exp(-0.1 / tau), rel=1e-9)


def test_noise_is_a_function_of_seed_and_time():
    a = [standard_normal(7, k * 1e-3) for k in range(2000)]
    assert a == [standard_normal(7, k * 1e-3) for k in range(2000)]
    assert a != [standard_normal(8, k * 1e-3) for k in range(2000)]
    # float rounding of the communication time does not change the sample
    assert standard_normal(7, 0.1 * 3) == standard_normal(7, 0.3)
    assert standard_normal(7, 0.3 + 2e-7) == standard_normal(7, 0.3)


def test_noise_statistics():
    # 20000 samples of N(0,1): standard error of the mean 0.007, of the std 0.005
    s = [standard_normal(3, k * 1e-4) for k in range(20000)]
    assert abs(statistics.fmean(s)) < 0.03
    assert statistics.pstdev(s) == pytest.approx(1.0, abs=0.03)
    # neighbouring samples uncorrelated
    r = sum(a * b for a, b in zip(s, s[1:])) / len(s)
    assert abs(r) < 0.03


def test_noise_scaled_and_added_to_the_reading():
    m = LoadCellModel(noise_std=2.5, seed=11)
    assert m.outputs(0.25, [], [100.0, 100.0])[0] == pytest.approx(100.0 + 2.5 * standard_normal(11, 0.25))


def test_load_cell_problems():
    assert [n for n, _ in LoadCellModel(tau_filter=-1.0).problems()] == ["tau_filter"]
    assert [n for n, _ in LoadCellModel(noise_std=-1.0, seed=1.5).problems()] == ["noise_std", "seed"]
    assert [n for n, _ in LoadCellModel(angle_in=3.0, angle_out=3.0).problems()] == ["angle_in/angle_out"]
