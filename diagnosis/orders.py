"""Order tracking: a shaft's angle, and the signal seen in that angle.

A roll's out-of-roundness disturbs tension at harmonics of its *angle*, not of a
fixed frequency ({27}-{29} with 2 pi f t replaced by theta). When the roll's
speed or radius changes, a plain FFT smears those harmonics over many bins;
fitted against theta(t) they stay sharp. This module gets theta(t) from

- an encoder / angle channel (:func:`angle_from_encoder`, unwrapped),
- a once-per-revolution pulse (:func:`angle_from_pulses`, 2 pi per pulse,
  smoothly interpolated between edges),
- a speed channel (:func:`angle_from_speed`, omega integrated),
- a model-predicted angle refined from the data (:func:`refine_angle`: a 0.5 %
  radius error drifts the harmonics' phase by a quarter turn in a minute),

(:func:`shaft_angle` dispatches, :func:`detect_tach_kind` guesses the kind),
then resamples the signal to uniform angle (:func:`resample_to_angle`), takes
its order spectrum (:func:`order_spectrum`) or least-squares fits its
harmonics (:func:`harmonic_fit`, :func:`joint_harmonic_fit`).

Harmonic j of a shaft is ``A_j sin(j theta + psi_j)`` ({27}-{28},
``webline.physics.eccentricity``): ``amplitude`` = A_j, ``phase`` = psi_j.
"""
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import scipy.integrate
import scipy.interpolate
import scipy.ndimage
import scipy.optimize
from numpy.polynomial import legendre

from webline.diagnosis.data import two_levels
from webline.diagnosis.spectra import amplitude_spectrum

TACH_KINDS = ("angle", "pulse", "speed")
TWO_PI = 2.0 * np.pi


# ----------------------------------------------------------------------------- angle sources

def angle_from_encoder(angle, period=TWO_PI):
    """Continuous shaft angle (rad) from a wrapped angle channel (rad, wrapping
    every ``period``; an unwrapped channel passes through unchanged)."""
    return np.unwrap(np.asarray(angle, dtype=float), period=period)


def angle_from_speed(t, omega, theta0=0.0):
    """Shaft angle (rad) by trapezoidal integration of the angular speed ``omega`` (rad/s)."""
    return theta0 + scipy.integrate.cumulative_trapezoid(np.asarray(omega, dtype=float), t, initial=0.0)


def pulse_levels(x):
    """(threshold, span, active_high) of a pulse channel: the two levels of
    :func:`diagnosis.data.two_levels` when the signal has them (any offset, a
    pulse of any width), else the 1st-99th percentile range. The active level is
    the one the signal spends less time at: a pulse that idles near 0 V and drops
    to -6.5 V once a revolution is active-low. NaN samples are ignored."""
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return 0.0, 0.0, True
    levels = two_levels(x)
    if levels is not None:
        low, high, mid = levels
    else:
        low, high = np.percentile(x, [1, 99])
        mid = 0.5 * (low + high)
    return float(mid), float(high - low), bool(np.mean(x > mid) <= 0.5)


def pulse_edges(t, pulse, *, threshold=None, hysteresis=0.2, edge="auto"):
    """Times (s) of the leading edges of a pulse channel, to a fraction of a sample.

    ``edge``: "rising", "falling", or "auto" - the edge into the active level
    (:func:`pulse_levels`: rising for an active-high pulse, falling for an
    active-low one; rising when there are fewer than two active-low pulses).
    A Schmitt trigger at ``threshold`` +/- ``hysteresis`` * span (``threshold`` defaults to the midpoint between the two levels) finds each
    edge; its time is where the signal crosses ``threshold``, linearly
    interpolated between the two samples around it. Missing (NaN) samples are
    bridged by linear interpolation first.
    """
    t = np.asarray(t, dtype=float)
    x = np.asarray(pulse, dtype=float)
    good = np.isfinite(x)
    if not good.any():
        return np.empty(0)
    if not good.all():
        x = x.copy()
        x[~good] = np.interp(t[~good], t[good], x[good])
    mid, span, active_high = pulse_levels(x)
    if not span > 0:
        return np.empty(0)
    mid = mid if threshold is None else float(threshold)
    if edge not in ("auto", "rising", "falling"):
        raise ValueError(f"edge must be rising, falling or auto, not {edge!r}")
    if edge == "auto":
        falling = _rising_edges(t, -x, -mid, hysteresis * span) if not active_high else np.empty(0)
        # a single step has no polarity: rising unless the record shows active-low pulses
        return falling if len(falling) >= 2 else _rising_edges(t, x, mid, hysteresis * span)
    if edge == "falling":
        return _rising_edges(t, -x, -mid, hysteresis * span)  # falling edges of x are rising edges of -x
    return _rising_edges(t, x, mid, hysteresis * span)


def _rising_edges(t, x, mid, band):
    """Rising crossings of ``mid`` by ``x`` with a Schmitt band +/- ``band``, interpolated in ``t``."""
    state = np.where(x > mid + band, 1.0, np.where(x < mid - band, 0.0, np.nan))
    known = np.flatnonzero(np.isfinite(state))
    if known.size == 0:
        return np.empty(0)
    state = state[known][np.searchsorted(known, np.arange(len(x)), side="right").clip(1) - 1]  # hold last
    rises = np.flatnonzero((state[1:] == 1.0) & (state[:-1] == 0.0)) + 1
    times = np.empty(len(rises))
    for n, k in enumerate(rises):
        i = k - 1
        while i > 0 and x[i] > mid:  # walk back to the sample below the threshold
            i -= 1
        j = i + 1
        while j < k and x[j] <= mid:
            i, j = j, j + 1
        frac = (mid - x[i]) / (x[j] - x[i]) if x[j] != x[i] else 0.5
        times[n] = t[i] + frac * (t[j] - t[i])
    return times


def angle_from_pulses(t, pulse, *, threshold=None, smooth=True, max_period_jump=0.6):
    """Shaft angle (rad) from a once-per-revolution pulse channel.

    Leading edge k (:func:`pulse_edges`: rising for an active-high pulse,
    falling for an active-low one) is at angle 2 pi k (k = 0 at the first
    edge). Between edges the angle follows a smoothing spline of (edge time,
    2 pi k), whose smoothing (chosen by generalised cross-validation) averages
    out the sampling jitter of the edge times; ``smooth=False`` interpolates
    exactly (cubic). Before the first and after the last edge the angle is
    extrapolated at the end speed. Raises ``ValueError`` with fewer than 4 edges
    or when one period differs from its neighbours by more than
    ``max_period_jump`` (relative): a missed or doubled pulse would shift every
    later angle by 2 pi.
    """
    t = np.asarray(t, dtype=float)
    edges = pulse_edges(t, pulse, threshold=threshold)
    if len(edges) < 4:
        raise ValueError(f"found {len(edges)} pulse edges; need at least 4 (one pulse per revolution)")
    periods = np.diff(edges)
    if len(periods) >= 3:
        ref = scipy.ndimage.median_filter(periods, size=5, mode="nearest")
        jump = np.abs(periods / ref - 1.0)
        if jump.max() > max_period_jump:
            k = int(np.argmax(jump))
            raise ValueError(f"pulse period {periods[k]:.4g} s at t = {edges[k]:.4g} s vs about {ref[k]:.4g} s "
                             "around it: a missed or extra pulse")
    angles = TWO_PI * np.arange(len(edges))
    spline = None
    if smooth and len(edges) >= 5:
        try:
            spline = scipy.interpolate.make_smoothing_spline(edges, angles)
        except (ValueError, np.linalg.LinAlgError):
            spline = None
    if spline is None:
        spline = scipy.interpolate.CubicSpline(edges, angles)
    theta = spline(t)
    d = spline.derivative()
    before, after = t < edges[0], t > edges[-1]
    theta[before] = spline(edges[0]) + d(edges[0]) * (t[before] - edges[0])
    theta[after] = spline(edges[-1]) + d(edges[-1]) * (t[after] - edges[-1])
    return theta


def detect_tach_kind(x, unit=None):
    """Guess what a tachometer channel holds: "angle", "pulse" or "speed".

    A unit decides when it can (SI strings as :mod:`diagnosis.data` gives them):
    rad -> angle, rad/s or Hz -> speed. Otherwise the shape decides, on the
    finite samples: a signal at two levels (:func:`diagnosis.data.two_levels`:
    either polarity, any offset, pulses as narrow as one sample) with at least
    four leading edges, a few samples or more apart on average, is a pulse
    train; one that moves one way (with wrap-arounds) is an angle; anything
    else a speed.
    """
    if unit == "rad":
        return "angle"
    if unit in ("rad/s", "Hz"):
        return "speed"
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    if x.size < 8:
        return "speed"
    if two_levels(x) is not None:
        edges = pulse_edges(np.arange(len(x), dtype=float), x)
        if len(edges) >= 4 and len(x) / len(edges) >= 4:  # transitions rare: not a fast square wave
            return "pulse"
    lo, hi = np.percentile(x, [1, 99])
    span = hi - lo
    if not span > 0:
        return "speed"
    steps = np.diff(x)
    wraps = np.abs(steps) > 0.5 * span
    small = steps[~wraps]
    one_way = small.size and max(np.mean(small > 0), np.mean(small < 0)) > 0.9
    if one_way and (wraps.sum() > 0 or span > TWO_PI):
        return "angle"
    return "speed"


def shaft_angle(t, x, kind="auto", unit=None):
    """Shaft angle (rad) from a tachometer channel ``x`` of the given ``kind``
    ("angle", "pulse", "speed" or "auto": :func:`detect_tach_kind`).

    ``unit`` is the channel's SI unit (None: as recorded, taken as rad or rad/s).
    A speed in Hz is read as revolutions per second. Raises ``ValueError`` for a
    unit that does not fit the kind (e.g. a web speed in m/s, which needs a radius).
    Returns (theta, kind).
    """
    if kind == "auto":
        kind = detect_tach_kind(x, unit)
    if kind == "angle":
        if unit not in (None, "rad"):
            raise ValueError(f"an angle channel must be in rad or deg, not {unit!r}")
        return angle_from_encoder(x), kind
    if kind == "pulse":
        return angle_from_pulses(t, x), kind
    if kind == "speed":
        if unit == "Hz":
            return angle_from_speed(t, TWO_PI * np.asarray(x, dtype=float)), kind
        if unit not in (None, "rad/s"):
            raise ValueError(f"a speed channel must be a shaft speed (rad/s, rpm, Hz), not {unit!r}"
                             + (" (a web speed needs the roll radius: omega = v / R)" if unit == "m/s" else ""))
        return angle_from_speed(t, x), kind
    raise ValueError(f"unknown tach kind {kind!r} (expected one of {', '.join(TACH_KINDS)} or auto)")


def shaft_frequency(t, theta, *, window=None):
    """Rotation frequency (Hz) of a shaft, averaged over windows of ``window``
    seconds (default: 1/20 of the record, at least one revolution).

    Returns (t_mid, f): window centres and the mean frequency in each,
    (theta_end - theta_start) / (2 pi window). Averaging keeps encoder
    quantisation out of the result; ``spectra.family(f)`` gives mean and spread.
    """
    t = np.asarray(t, dtype=float)
    theta = np.asarray(theta, dtype=float)
    duration = t[-1] - t[0]
    if window is None:
        rev_time = duration * TWO_PI / max(abs(theta[-1] - theta[0]), 1e-12)
        window = max(duration / 20.0, rev_time)
    n_win = max(1, int(duration // window))
    bounds = t[0] + np.arange(n_win + 1) * (duration / n_win)
    th = np.interp(bounds, t, theta)
    return 0.5 * (bounds[1:] + bounds[:-1]), np.abs(np.diff(th)) / (TWO_PI * np.diff(bounds))


# ----------------------------------------------------------------------------- angle domain

def resample_to_angle(theta, x, samples_per_rev=None):
    """Resample ``x(t)`` onto a uniform grid of the shaft angle ``theta(t)``.

    ``theta`` must be strictly monotonic (either direction). The grid starts at
    theta[0] and covers whole samples of 2 pi / samples_per_rev. The default
    ``samples_per_rev`` is the power of two at or above the mean number of time
    samples per revolution, so nothing is decimated (with fewer, orders above
    samples_per_rev / 2 alias: low-pass first). Cubic-spline interpolation.
    Returns (theta_grid, x_grid).
    """
    theta = np.asarray(theta, dtype=float)
    x = np.asarray(x, dtype=float)
    sign = 1.0 if theta[-1] >= theta[0] else -1.0
    s = sign * theta
    if np.any(np.diff(s) <= 0):
        raise ValueError("shaft angle is not strictly monotonic (shaft stopped or reversed)")
    revs = (s[-1] - s[0]) / TWO_PI
    if samples_per_rev is None:
        samples_per_rev = int(2 ** np.ceil(np.log2(max(len(s) / max(revs, 1e-12), 2.0))))
    step = TWO_PI / samples_per_rev
    grid = s[0] + step * np.arange(int(np.floor((s[-1] - s[0]) / step)) + 1)
    return sign * grid, scipy.interpolate.CubicSpline(s, x)(grid)


def order_spectrum(theta, x, *, samples_per_rev=None, max_order=None, detrend="linear"):
    """Amplitude per order of ``x`` against the shaft angle ``theta``.

    ``x`` is resampled to uniform angle (:func:`resample_to_angle`), cut to whole
    revolutions, and given the Hann-windowed amplitude spectrum with "sample
    rate" samples_per_rev: integer orders then fall on bins, and a component
    A sin(j theta + psi) shows amplitude A at order j whatever the speed did.
    Returns (orders, amp), orders up to ``max_order`` (default: all).
    """
    grid, xu = resample_to_angle(theta, x, samples_per_rev)
    spr = round(TWO_PI / abs(grid[1] - grid[0]))
    revs = len(xu) // spr
    if revs < 2:
        raise ValueError(f"order spectrum needs at least 2 whole revolutions, the record has {len(xu) / spr:.2f}")
    orders, amp = amplitude_spectrum(xu[:revs * spr], spr, detrend=detrend)
    if max_order is not None:
        keep = orders <= max_order
        orders, amp = orders[keep], amp[keep]
    return orders, amp


# ----------------------------------------------------------------------------- harmonic fits

@dataclass(frozen=True)
class HarmonicFit:
    """Least-squares harmonics of one shaft in a signal.

    ``orders`` (1..n); ``amplitude`` A_j and ``phase`` psi_j with the component
    A_j sin(j theta + psi_j); ``explained_per_order`` and ``explained``: share of the
    signal's variance about its trend that the orders carry (var(component) /
    var(x - trend)); ``component``: the fitted harmonic signal of this shaft;
    ``trend``: fitted slow trend (mean and polynomial); ``residual``:
    x - trend - all fitted components (of every shaft in a joint fit).
    """
    orders: np.ndarray
    amplitude: np.ndarray
    phase: np.ndarray
    explained_per_order: np.ndarray
    explained: float
    component: np.ndarray
    trend: np.ndarray
    residual: np.ndarray


def _least_squares(design, x):
    """Least-squares coefficients by the normal equations. The columns (Legendre
    trend, cos/sin of whole orders over many revolutions) are near orthogonal, so
    squaring the condition number costs nothing, and a 15 x 15 solve is 30x faster
    than an SVD of the n x 15 design (and does not fight over BLAS threads). The
    pseudo-inverse cut-off (1e-10 of the largest eigenvalue) gives a minimum-norm
    answer when two shafts turn at the same speed."""
    gram = design.T @ design
    return np.linalg.lstsq(gram, design.T @ x, rcond=1e-10)[0]


def _trend_basis(n, degree):
    """Legendre polynomials 0..degree over the samples (well conditioned)."""
    return legendre.legvander(np.linspace(-1.0, 1.0, n), degree)


def joint_harmonic_fit(x, thetas, orders=6, *, trend=2):
    """Fit the harmonics of several shafts and a slow trend to ``x`` in one least-squares
    problem: x ~ P_trend(t) + sum_shafts sum_j a_j cos(j theta) + b_j sin(j theta).

    ``thetas``: name -> angle array (rad), same length as ``x``; ``orders``: highest
    order, one int for all or name -> int; ``trend``: degree of the polynomial
    trend over the record (0: mean only). ``x`` is taken as uniformly sampled.
    Fitting jointly keeps two shafts with near frequencies from taking each
    other's share. Returns name -> :class:`HarmonicFit` (same trend and
    residual in each).
    """
    x = np.asarray(x, dtype=float)
    n = len(x)
    names = list(thetas)
    n_orders = {k: (orders[k] if isinstance(orders, dict) else int(orders)) for k in names}
    cols = [_trend_basis(n, trend)]
    for name in names:
        th = np.asarray(thetas[name], dtype=float)
        if th.shape != x.shape:
            raise ValueError(f"angle {name!r} has {th.size} samples, the signal {n}")
        j = np.arange(1, n_orders[name] + 1)
        cols += [np.cos(np.outer(th, j)), np.sin(np.outer(th, j))]
    design = np.hstack(cols)
    coef = _least_squares(design, x)
    n_trend = trend + 1
    trend_part = design[:, :n_trend] @ coef[:n_trend]
    fitted = design @ coef
    residual = x - fitted
    base = np.var(x - trend_part)
    base = base if base > 0 else 1.0
    out, pos, col = {}, n_trend, n_trend
    for name in names:
        m = n_orders[name]
        a, b = coef[pos:pos + m], coef[pos + m:pos + 2 * m]
        component = design[:, col:col + 2 * m] @ coef[col:col + 2 * m]
        pos, col = pos + 2 * m, col + 2 * m
        amp = np.hypot(a, b)
        out[name] = HarmonicFit(orders=np.arange(1, m + 1), amplitude=amp, phase=np.arctan2(a, b),
                                explained_per_order=0.5 * amp ** 2 / base,
                                explained=float(np.var(component) / base), component=component,
                                trend=trend_part, residual=residual)
    return out


def harmonic_fit(x, theta, orders=6, *, trend=2):
    """Least-squares fit of one shaft's harmonics 1..``orders`` and a slow
    polynomial trend of degree ``trend`` to ``x``:
    x ~ P_trend(t) + sum_j a_j cos(j theta) + b_j sin(j theta) = ... + A_j sin(j theta + psi_j).
    Returns :class:`HarmonicFit`."""
    return joint_harmonic_fit(x, {"shaft": theta}, orders, trend=trend)["shaft"]


def harmonic_energy(x, theta, orders=6, *, trend=2):
    """Share of the detrended variance of ``x`` carried by harmonics 1..orders of ``theta``
    (1 - var(residual) / var(x - trend)): large when ``theta`` is the right angle."""
    fit = harmonic_fit(x, theta, orders, trend=trend)
    base = np.var(fit.residual + fit.component)
    return float(1.0 - np.var(fit.residual) / base) if base > 0 else 0.0


def _demodulated_phase(x, theta, j, window_revs):
    """Slowly varying phase of order j of ``x`` against ``theta``, zero at mid-record:
    arg of x exp(-i j theta) averaged in the angle domain by two boxcars of whole
    revolutions (which null every integer order, the 2j image included)."""
    grid, xu = resample_to_angle(theta, x)
    spr = round(TWO_PI / abs(grid[1] - grid[0]))
    box = min(len(grid), spr * max(1, int(round(window_revs / 2))))
    z = xu * np.exp(-1j * j * grid)
    for _ in range(2):
        z = (scipy.ndimage.uniform_filter1d(z.real, box, mode="reflect")
             + 1j * scipy.ndimage.uniform_filter1d(z.imag, box, mode="reflect"))
    sign = 1.0 if grid[-1] > grid[0] else -1.0
    phi = np.interp(sign * theta, sign * grid, np.unwrap(np.angle(z)))
    return phi - phi[len(phi) // 2]


class AngleRefinement(NamedTuple):
    """Result of :func:`refine_angle`: the refined ``theta`` (rad), the speed ``scale``
    factor found by the grid search, and the slow phase ``correction`` theta - theta_model."""
    theta: np.ndarray
    scale: float
    correction: np.ndarray


def refine_angle(x, theta_model, *, orders=6, max_scale_error=0.03, window_revs=8.0, trend=2, iterations=2):
    """Refine a model-predicted shaft angle from the signal its harmonics are in.

    A model's roll angle drifts from the real one (a 0.5 % radius error is a
    quarter turn a minute at 1 Hz). Two steps:

    1. speed scale: theta_s = theta_m(mid) + s (theta_m - theta_m(mid)) for s on a
       grid over 1 +/- ``max_scale_error`` fine enough that the highest order
       moves by at most a quarter turn per grid step over the record; s maximises
       :func:`harmonic_energy` (then a bounded scalar search between grid points);
    2. slow phase: the dominant order j of the fit (the other orders and the trend
       removed) is demodulated, z = x_j exp(-i j theta_s), z averaged over about
       ``window_revs`` revolutions in the angle domain, and
       theta_s + (arg z - arg z(mid)) / j taken as the angle. ``iterations``
       repeats this with the other orders fitted on the refined angle.

    The angle is anchored to the model at mid-record: a constant offset cannot be
    seen in the data (it moves into the phases psi_j). Needs the dominant order
    well above the noise within ``window_revs`` revolutions, and no other
    component within 1 / (window duration) of it. Returns :class:`AngleRefinement`.
    """
    x = np.asarray(x, dtype=float)
    theta_model = np.asarray(theta_model, dtype=float)
    n = len(x)
    mid = n // 2
    d = theta_model - theta_model[mid]
    revs = abs(theta_model[-1] - theta_model[0]) / TWO_PI
    if revs < 3:
        raise ValueError(f"the record holds {revs:.1f} revolutions; refining the angle needs at least 3")

    def energy(s):
        return harmonic_energy(x, theta_model[mid] + s * d, orders, trend=trend)

    step = 0.25 / (orders * revs)
    grid = 1.0 + np.arange(-max_scale_error, max_scale_error + step / 2, step)
    e = np.array([energy(s) for s in grid])
    k = int(np.argmax(e))
    lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    best = scipy.optimize.minimize_scalar(lambda s: -energy(s), bounds=(lo, hi), method="bounded",
                                          options={"xatol": step * 1e-3})
    scale = float(best.x) if -best.fun >= e[k] else float(grid[k])
    theta = theta_model[mid] + scale * d

    scaled = theta
    for _ in range(iterations):
        fit = harmonic_fit(x, theta, orders, trend=trend)
        j = int(np.argmax(fit.amplitude)) + 1
        own = fit.amplitude[j - 1] * np.sin(j * theta + fit.phase[j - 1])
        xj = x - fit.trend - (fit.component - own)
        theta = scaled + _demodulated_phase(xj, scaled, j, window_revs) / j
    return AngleRefinement(theta=theta, scale=scale, correction=theta - theta_model)
