"""Numerical core of the diagnosis (diagnosis.estimate), on signals with known answers."""
import math

import numpy as np
import pytest

from webline.diagnosis import estimate as est

FS = 500.0


def _angle(t, f0=1.0, drift=0.002):
    """Angle of a shaft whose speed drifts (a shrinking roll): omega = 2 pi f0 (1 + drift t)."""
    return 2 * math.pi * f0 * (t + 0.5 * drift * t * t)


def test_harmonic_fit_recovers_complex_amplitudes_at_varying_speed():
    t = np.arange(0, 30, 1 / FS)
    th = _angle(t)
    Y = np.array([0.5, 0.3j, 0.2 - 0.1j])
    y = est.harmonic_signal(th, Y, [1, 2, 3]) + np.random.default_rng(0).normal(0, 0.2, len(t))
    Yh = est.fit_harmonics(y, th, [1, 2, 3])
    assert np.max(np.abs(Yh - Y)) < 0.02


def test_significance_separates_lines_from_noise():
    rng = np.random.default_rng(1)
    t = np.arange(0, 20, 1 / FS)
    th = _angle(t, 2.0)
    orders = list(range(1, 7))
    freqs = 2.0 * np.array(orders)
    noise = rng.normal(0, 0.5, len(t))
    z0 = est.harmonic_z(est.fit_harmonics(noise, th, orders), freqs, est.NoiseFloor(noise, FS), 20.0)
    assert est.gamma_log10_sf(z0.sum(), len(orders)) > -4          # noise: not significant
    y = noise + 0.1 * np.sin(th + 0.4)                                 # a line 5x below the noise rms
    z1 = est.harmonic_z(est.fit_harmonics(y, th, orders), freqs, est.NoiseFloor(y, FS), 20.0)
    assert est.gamma_log10_sf(z1.sum(), len(orders)) < -20
    assert est.gamma_log10_sf(1e5, 6) < -1000                          # no underflow to -inf
    assert math.isfinite(est.gamma_log10_sf(1e5, 6))


def test_refine_angle_finds_speed_scale():
    t = np.arange(0, 40, 1 / FS)
    th = _angle(t, 1.5)
    y = est.harmonic_signal(1.012 * th, [0.3, 0.1j], [1, 2]) + np.random.default_rng(2).normal(0, 0.1, len(t))
    kappa, _ = est.refine_angle(y, th, [1, 2], span=0.03)
    assert abs(kappa - 0.012) < 1e-3


def test_solve_fourier_from_gains_and_pattern_misfit():
    rng = np.random.default_rng(3)
    X = np.array([60e-6 * np.exp(0.3j), 20e-6 * np.exp(1.0j)])
    G = rng.normal(size=(3, 2)) * 3e3 + 1j * rng.normal(size=(3, 2)) * 3e3   # 3 sensors
    Xh, misfit = est.solve_fourier(G * X, G)
    assert np.allclose(Xh, X) and misfit < 1e-12
    G_other = rng.normal(size=(3, 2)) * 3e3 + 0j                              # another element's pattern
    _, misfit_other = est.solve_fourier(G * X, G_other)
    assert misfit_other > 0.05


def test_complex_gain_of_a_linear_response():
    t = np.arange(0, 10, 1 / FS)
    th = 2 * math.pi * 3.0 * t
    Xt = np.full(2, 50e-6, complex)
    G = np.array([2000 * np.exp(-0.5j), 800 * np.exp(1.2j)])
    delta = est.harmonic_signal(th, G * Xt, [1, 2])
    assert np.allclose(est.complex_gain(delta, th, [1, 2], Xt), G)


@pytest.mark.parametrize("fc", [0.3, 1.0])
def test_slow_periodic_split(fc):
    t = np.arange(0, 20, 1 / FS)
    slow = 0.5 * np.tanh(t - 10)
    per = 0.2 * np.sin(2 * math.pi * 5 * t)
    s, p = est.split_slow_periodic(slow + per, FS, fc)
    assert np.sqrt(np.mean((p - per) ** 2)) < 0.02 and np.allclose(s + p, slow + per)


def test_steady_mask_excludes_ramps():
    t = np.arange(0, 20, 1 / FS)
    v = np.clip(t / 5.0, 0, 1) * 1.0            # ramp 0..5 s, then steady
    m = est.steady_mask(v, FS)
    assert not m[t < 4.5].any() and m[t > 6].all()
    assert est.windows_of(m, t)[0][0] == pytest.approx(5.0, abs=0.6)


def test_projected_energy_equals_the_least_squares_fit():
    import numpy as np
    from webline.diagnosis import estimate as est
    rng = np.random.default_rng(3)
    th = np.linspace(0.0, 2 * np.pi * 7.3, 900)
    A = est.harmonic_basis(th, [1, 2, 3])
    inside = A @ rng.normal(size=(6, 2))
    Y = inside + rng.normal(size=(900, 2))
    coef, *_ = np.linalg.lstsq(A, Y, rcond=None)
    assert est.projected_energy(A, Y) == pytest.approx(float(np.sum((A @ coef) ** 2)), rel=1e-10)
    # a signal in the span of the basis is explained entirely
    assert est.projected_energy(A, inside) == pytest.approx(float(np.sum(inside ** 2)), rel=1e-10)


def test_a_tie_is_the_candidates_the_sensors_cannot_tell_apart_not_every_candidate():
    """Seed-3 c07 of the independent family: four idlers of one radius, two per
    tension zone. The pattern across the two load cells excludes the other zone
    (misfit 0.92 against 0.08); inside the zone it cannot choose (0.078 vs 0.083).
    The report names the two, and its confidence is one in two, not one in four."""
    from types import SimpleNamespace

    from webline.diagnosis import report

    def cand(el, misfit, td):
        return {"cand": SimpleNamespace(element=el), "misfit": misfit, "td_sse": td,
                "score": {"logp": -8341.0}}

    ranked = [cand("idler_u1", 0.0781, 0.5125), cand("roller9", 0.0829, 0.5186),
              cand("idler_r1", 0.9180, 0.9585), cand("roller19", 0.9181, 0.9586)]
    assert [r["cand"].element for r in est.tied(ranked)] == ["idler_u1", "roller9"]
    d = SimpleNamespace(opt=SimpleNamespace(significance=-6.0))
    conf, why = report._confidence(d, ranked)
    # 1/2 raised by the 1.2 % less residual the first leaves: (1 - 0.5125/0.5186) / 0.5 * 1/2,
    # times what the pattern's exclusion of the other zone leaves: 1 - 0.0781/0.9180
    gain = 1.0 - 0.5125 / 0.5186
    assert conf == pytest.approx((0.5 + 0.5 * gain / 0.5) * (1.0 - 0.0781 / 0.9180), rel=1e-9)
    assert "(idler_u1, roller9)" in why and "idler_r1, roller19 excluded by the pattern" in why
    # seed-15 c17: the other zone excluded at 0.545 against 0.439, the truth among it. Inside
    # the tie roller19 leaves 26 % less than idler_r1 (0.76 before); the exclusion is a
    # 19 % gap, under the 1/4 of four candidates, so the tie keeps a quarter
    ranked3 = [cand("roller19", 0.439, 0.74), cand("idler_r1", 0.440, 1.0),
               cand("idler_u1", 0.545, 1.1), cand("roller9", 0.546, 1.1)]
    assert [r["cand"].element for r in est.tied(ranked3)] == ["roller19", "idler_r1"]
    conf3, why3 = report._confidence(d, ranked3)
    assert conf3 == pytest.approx((0.5 + 0.5 * 0.26 / 0.5) * 0.25, rel=1e-9)
    assert "leaves 25 % of the confidence" in why3
    # one candidate clearly ahead: no tie, the misfit gap sets the uniqueness
    ranked2 = [cand("idler_u1", 0.078, None), cand("idler_r1", 0.918, None)]
    assert len(est.tied(ranked2)) == 1
    conf2, _ = report._confidence(d, ranked2)
    assert conf2 == pytest.approx(1.0 - 0.078 / 0.918, rel=1e-9)


def test_an_order_the_forms_disagree_on_is_flagged_not_identifiable():
    """Seed-4 c05: the S-wrap leader's order 1 needs 0.026 mm with a shaft on its drive
    and 0.215 mm in the rigid forms that fit about as well (0.213 mm true); the lines
    around the chosen form alone said 0.017-0.031 mm. Each order is flagged by the
    forms' range, not only the dominant one; an order they agree on is left alone."""
    from webline.diagnosis import report

    eff = {"harmonics": [{"order": 1, "amplitude": 2.6e-5, "identifiable": True},
                         {"order": 3, "amplitude": 1.79e-4, "identifiable": True},
                         {"order": 4, "amplitude": 6.2e-5, "left_out": True, "identifiable": False}],
           "amplitude_uncertainty": {"range_by_order": [[1.4e-5, 2.15e-4], [0.0, 0.0],
                                                        [9.85e-5, 1.83e-4], [2.4e-5, 2.2e-4]]}}
    report._forms_flag(eff)
    h1, h3, h4 = eff["harmonics"]
    assert h1["identifiable"] is False and "14-215 um" in h1["identifiable_basis"]
    assert h3["identifiable"] is True          # 1.86 x: within a factor 2
    assert "identifiable_basis" not in h4      # already flagged by its own rule


def test_fit_runs_that_disagree_beyond_20_percent_and_their_noise_flag_the_dominant_amplitude():
    """Independent seed-53 c08: the unwind's order 2, 84 and 120 um in the two fit runs
    (standard errors about 2 um), 109 um reported for 157 true. A run-out is the same at
    every speed, so the runs say the model's response is off by 1.43 x between them: the
    dominant order is flagged as not known to 20 %, the other orders are left alone. Runs
    1.1 x apart, or 1.43 x apart within 3 standard errors, are not flagged."""
    from webline.diagnosis import report
    from webline.diagnosis.structure import runs_apart

    assert runs_apart({"run1": (84e-6, 2e-6), "run3": (120e-6, 2e-6)}) == (pytest.approx(120 / 84), True)
    assert runs_apart({"run1": (84e-6, 9e-6), "run3": (120e-6, 9e-6)})[1] is False   # 36 < 3 x 12.7 um
    assert runs_apart({"run1": (100e-6, 1e-7), "run3": (110e-6, 1e-7)})[1] is False  # within 20 %
    assert runs_apart({"run1": (100e-6, 1e-7)}) == (1.0, False)
    eff = {"harmonics": [{"order": 1, "amplitude": 3.1e-5, "identifiable": True},
                         {"order": 2, "amplitude": 1.09e-4, "identifiable": True}],
           "amplitude_uncertainty": {"dominant_order": 2, "within_precision": False, "note": "runs apart",
                                     "range_by_order": [[3e-5, 3.2e-5], [1.08e-4, 1.12e-4]]}}
    report._forms_flag(eff)
    h1, h2 = eff["harmonics"]
    assert h2["within_precision"] is False and h2["precision_basis"] == "runs apart"
    assert h2["identifiable"] is True and "within_precision" not in h1


def test_coherence_debiased_reads_a_weak_steady_line_as_steady_and_noise_or_a_transient_as_not():
    """Segment SNR 1 at K = 4: the raw ratio reads about (K r + 1)/(K r + K) = 0.625
    (0.60 as a mean of single draws), below the screen's 0.75 for a perfectly steady
    line; with the noise's share taken out the ratio of the sums is 1 and single
    draws (clipped at 1) average about 0.76. Noise alone and a burst in one segment
    stay low (a burst: 1/K). Margins: 4000 draws put the means within 0.01."""
    rng = np.random.default_rng(3)
    K, n, v = 4, 4000, 1.0
    def noise(shape):
        return (rng.normal(size=shape) + 1j * rng.normal(size=shape)) * math.sqrt(v / 2)
    Y = np.exp(0.7j) * math.sqrt(v)                       # |Y|^2 = v: segment SNR 1
    steady = Y + noise((n, K, 1))
    raw = [np.abs(s.sum(0)) ** 2 / (K * np.sum(np.abs(s) ** 2, 0)) for s in steady]
    deb = [est.coherence_debiased(s, v) for s in steady]
    assert np.mean(raw) < 0.66
    # the debiased ratio of sums is unbiased; clipping at 1 pulls the mean of single draws down
    num = np.mean([np.abs(s.sum(0)) ** 2 - K * v for s in steady])
    den = np.mean([K * (np.sum(np.abs(s) ** 2, 0) - K * v) for s in steady])
    assert abs(num / den - 1.0) < 0.05
    assert np.mean(deb) > np.mean(raw) + 0.1
    pure = [est.coherence_debiased(noise((K, 1)), v) for _ in range(n)]
    assert np.mean(pure) < 0.3
    burst = np.zeros((K, 1), complex)
    burst[1, 0] = 30.0
    assert abs(float(est.coherence_debiased(burst + noise((K, 1)), v)[0]) - 1 / K) < 0.05


def test_coherence_held_to_a_window_around_0_and_1_averages_without_bias():
    """The screen averages each order's coherence over orders, runs and sensors. Clipped
    to [0, 1] a steady line at segment SNR 1 averages about 0.76 (the scatter above 1
    cut) and noise about 0.14 (below 0 cut); held to [-1, 2] and averaged, the steady
    line reads about 0.97 and noise about 0.09 (the screen clips the average once).
    Margins: 4000 draws put the means within 0.01."""
    rng = np.random.default_rng(5)
    K, n, v = 4, 4000, 1.0
    def noise(shape):
        return (rng.normal(size=shape) + 1j * rng.normal(size=shape)) * math.sqrt(v / 2)
    steady = np.exp(0.7j) * math.sqrt(v) + noise((n, K, 1))
    pure = noise((n, K, 1))
    for draws, lo, hi in ((steady, 0.9, 1.05), (pure, -0.05, 0.12)):
        held = np.mean([est.coherence_debiased(s, v, clip=(-1.0, 2.0)) for s in draws])
        assert lo < held < hi, held
    assert np.mean([est.coherence_debiased(s, v) for s in steady]) < 0.8
    assert np.mean([est.coherence_debiased(s, v) for s in pure]) > 0.12


def test_a_family_fitted_beside_a_near_line_takes_only_its_own_share():
    """Seven seconds of a 4.01 Hz line beside a 3.53 Hz one ten times stronger (seed-5
    c12's roller19 beside the rewind's order 2): alone the fit leaks, jointly it is exact."""
    fs, T = 250.0, 7.4
    t = np.arange(0.0, T, 1 / fs)
    th_a, th_b = 2 * math.pi * 4.01 * t + 0.3, 2 * math.pi * 1.765 * t
    y = 0.3 * np.cos(th_a - 0.4) + 3.0 * np.cos(2 * th_b + 1.0)
    Y_alone = est.fit_harmonics(y, th_a, [1])[0]
    Y_joint = est.fit_harmonics_joint(y, [(th_a, [1]), (th_b, [1, 2])])[0]
    Y_true = est.fit_harmonics(0.3 * np.cos(th_a - 0.4), th_a, [1])[0]   # the line alone
    assert abs(Y_alone - Y_true) > 0.01                       # the leak is real at this length
    assert abs(Y_joint - Y_true) < 1e-9 * 3.0                   # exact but for rounding
    assert est.fit_harmonics_joint(y, [(th_a, [1])])[0] == Y_alone


def test_least_squares_by_normal_equations_matches_the_svd_and_falls_back_when_ill_conditioned():
    """The normal equations solve a near-orthogonal harmonic basis to rounding (error about
    cond x eps of the scaled Gram matrix, here < 10); two lines 1/2500 of 1/T apart make the
    Gram matrix near singular, and the SVD (``lstsq``) solves it instead (Gram None)."""
    rng = np.random.default_rng(5)
    t = np.arange(0.0, 20.0, 1 / FS)
    A = np.hstack([est.harmonic_basis(_angle(t, 1.3), [1, 2, 3]), est.harmonic_basis(_angle(t, 2.9), [1, 2])])
    y = A @ rng.normal(size=A.shape[1]) + rng.normal(0, 0.5, len(t))
    coef, G = est.least_squares(A, y)
    ref = np.linalg.lstsq(A, y, rcond=None)[0]
    assert G is not None
    assert np.max(np.abs(coef - ref)) < 1e-10 * np.max(np.abs(ref))
    near = np.hstack([est.harmonic_basis(2 * math.pi * 1.0 * t, [1]),
                      est.harmonic_basis(2 * math.pi * (1.0 + 2e-5) * t, [1])])   # 1/T = 0.05 Hz
    coef, G = est.least_squares(near, y)
    assert G is None
    assert np.allclose(coef, np.linalg.lstsq(near, y, rcond=None)[0])


def test_a_line_searched_shafts_range_is_where_its_residual_is_within_a_tenth_of_the_best():
    """others.as_well_range: residual energy J(f) = 20 + 320 (f - 13.47)^2 near the mode.
    The best point tried, 13.5 Hz, leaves 20.288; 10 % more (22.317) is left where
    320 (f - 13.47)^2 = 2.317, f = 13.47 +- 0.0851 Hz. Points on a parabola give it
    exactly; the best at an end of the points, or a concave triple, give no range."""
    from webline.diagnosis.others import as_well_range

    def J(f):
        return 20.0 + 320.0 * (f - 13.47) ** 2
    lo, hi = as_well_range([(f, J(f)) for f in (10.8, 13.2, 13.5, 13.9)])
    half = math.sqrt((1.1 * J(13.5) - 20.0) / 320.0)
    assert half == pytest.approx(0.0851, abs=1e-4)
    assert (lo, hi) == (pytest.approx(13.47 - half, rel=1e-9), pytest.approx(13.47 + half, rel=1e-9))
    assert as_well_range([(13.0, J(13.0)), (13.2, J(13.2)), (13.4, J(13.4))]) is None
    assert as_well_range([(1.0, 5.0), (2.0, 1.0), (3.0, 5.0), (4.0, 0.5)]) is None


def test_a_line_searched_shafts_range_is_narrowed_by_bisection_to_a_sharp_resonances_well():
    """others._bisect_range on a resonance's well, J(f) = 100 (1 - 0.98 / (1 + ((f - 13.47)
    / 0.1)^2)), tried at 13.46, 10.77 and 16.15 Hz as own seed-0 c09's line search was:
    the parabola through them is far wider than the well. 10 % more than the best's
    residual (2.970) is left where 0.98 / (1 + u^2) = 1 - 1.1 x 0.0297, u = 0.114
    (f = 13.47 +- 0.0114 Hz). Three simulations a side (the parabola's end, then halves)
    keep the outer end of the bracket: never inside the crossing, narrower than the parabola."""
    from webline.diagnosis.others import _bisect_range, as_well_range

    def J(f):
        return 100.0 * (1.0 - 0.98 / (1.0 + ((f - 13.47) / 0.1) ** 2))
    pts = [(f, J(f)) for f in (13.46, 10.77, 16.15)]
    span = as_well_range(pts)
    calls = []
    lo, hi = _bisect_range(pts, span, lambda v: calls.append(v) or J(v))
    assert len(calls) == 6 and calls[0] == span[0] and calls[3] == span[1]
    u = 0.1 * math.sqrt(0.98 / (1.0 - 1.1 * J(13.46) / 100.0) - 1.0)
    assert u == pytest.approx(0.0114, abs=1e-4)
    assert 10.77 <= lo <= 13.47 - u and 13.47 + u <= hi <= 16.15
    assert span[0] <= lo and hi <= span[1] and hi - lo < span[1] - span[0]
