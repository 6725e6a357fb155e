"""Span-length variation {28}-{29}: the sine-cosine form the engine evaluates equals the
paper's sums order by order."""
import math

import numpy as np
import pytest

from webline.physics.eccentricity import length_offset, length_rate, length_terms, sine_cosine_form


@pytest.mark.parametrize("theta", [0.0, 0.7, -2.3, 377.0, 4.5e4])
def test_length_terms_equal_the_sums_of_28_and_29(theta):
    rng = np.random.default_rng(7)
    C = list(rng.uniform(0.0, 5e-4, 8) * (rng.uniform(size=8) > 0.3))
    psi = list(rng.uniform(-math.pi, math.pi, 8))
    omega = 12.3
    off, rate = length_terms(theta, omega, *sine_cosine_form(C, psi))
    # the recurrence loses about one rounding per order; the sums carry ~|j theta| eps each
    # (sin of a large argument), so the bound scales with the largest order's phase
    tol = 1e-15 * sum(C) * (len(C) + abs(theta) * len(C)) * 4
    assert off == pytest.approx(length_offset(theta, C, psi), abs=tol)
    assert rate == pytest.approx(length_rate(theta, omega, C, psi), abs=tol * omega * len(C))


def test_one_order_is_a_sine_of_its_phase():
    # Delta L = C sin(theta + psi) and its rate omega C cos(theta + psi), by hand
    C, psi, theta, omega = 2e-4, 0.4, 1.1, 3.0
    off, rate = length_terms(theta, omega, *sine_cosine_form([C], [psi]))
    assert off == pytest.approx(C * math.sin(theta + psi), rel=1e-14)
    assert rate == pytest.approx(omega * C * math.cos(theta + psi), rel=1e-14)


def test_rate_is_the_time_derivative_of_the_offset():
    C, psi = [1e-4, 0.0, 3e-5], [0.2, 0.0, -1.0]
    ab = sine_cosine_form(C, psi)
    omega, t, h = 9.0, 0.37, 1e-6
    d = (length_terms(omega * (t + h), omega, *ab)[0] - length_terms(omega * (t - h), omega, *ab)[0]) / (2 * h)
    assert length_terms(omega * t, omega, *ab)[1] == pytest.approx(d, rel=1e-6)
