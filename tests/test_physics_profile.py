"""Piecewise-linear profile: interpolation, steps, holds, problems."""
import pytest

from webline.physics.profile import ProfileModel, profile_value


def y_at(model, t):
    return model.outputs(t, [], [])[0]


def test_ramp_then_hold():
    m = ProfileModel(3, [1.0, 3.0, 4.0], [0.0, 2.0, 2.0])
    assert y_at(m, 0.0) == 0.0          # before the first point: y[1]
    assert y_at(m, 2.0) == pytest.approx(1.0)
    assert y_at(m, 2.5) == pytest.approx(1.5)
    assert y_at(m, 3.5) == pytest.approx(2.0)
    assert y_at(m, 100.0) == 2.0        # after the last point: y[n]


def test_step_is_right_continuous_and_tolerant_of_rounding():
    m = ProfileModel(4, [0.0, 0.3, 0.3, 1.0], [10.0, 10.0, 20.0, 20.0])
    assert y_at(m, 0.29) == 10.0
    assert y_at(m, 0.3) == 20.0
    assert y_at(m, 0.1 * 3) == 20.0     # 0.30000000000000004
    assert y_at(m, 0.3 - 1e-12) == 20.0  # a master's k*h a hair early
    assert y_at(m, 0.31) == 20.0


def test_only_first_n_points_are_used():
    m = ProfileModel(2, [0.0, 1.0, 2.0], [0.0, 1.0, 50.0])
    assert y_at(m, 5.0) == 1.0
    assert profile_value([0.0], [7.0], 3.0) == 7.0


def test_profile_problems():
    assert [n for n, _ in ProfileModel(0, [0.0], [0.0]).problems()] == ["n"]
    assert [n for n, _ in ProfileModel(2.5, [0.0, 1.0, 2.0], [0.0] * 3).problems()] == ["n"]
    assert [n for n, _ in ProfileModel(33, [0.0] * 40, [0.0] * 40).problems()] == ["n"]
    assert [n for n, _ in ProfileModel(3, [0.0, 2.0, 1.0], [0.0] * 3).problems()] == ["t[3]"]
    assert ProfileModel(3, [0.0, 1.0, 1.0], [0.0, 0.0, 1.0]).problems() == []
