"""Numerical core of the diagnosis: harmonic families locked to an element's
angle, their significance against the local noise floor, angle refinement,
complex gains from a sensitivity simulation, and the Fourier coefficients of
an eccentricity from measured harmonics.

Complex-amplitude convention (sine series as in the paper, {28}): a signal
``y = sum_j a_j sin(j theta) + b_j cos(j theta)`` has complex amplitude
``Y_j = a_j + i b_j`` and ``y = sum_j Im(Y_j exp(i j theta))``. A span-length
term ``C_j sin(j theta + psi_j)`` has ``X_j = C_j exp(i psi_j)``. For a small
eccentricity the tension answers linearly, harmonic by harmonic:
``Y_j(sensor) = G_j(sensor) X_j`` with ``G`` the complex gain (N/m).

Plain functions on numpy arrays, no hidden state.
"""
import math

import numpy as np
from scipy import signal, stats


# ---------------------------------------------------------------- filtering ----
def lowpass(y, fs, fc, order=4):
    """Zero-phase Butterworth low-pass of ``y`` (1-D) at ``fc`` Hz."""
    y = np.asarray(y, float)
    if fc <= 0.0 or fc >= 0.45 * fs or len(y) < 30:
        return np.full_like(y, np.mean(y)) if fc <= 0.0 else y.copy()
    sos = signal.butter(order, fc, btype="low", fs=fs, output="sos")
    # pad with the reflected signal so the ends do not ring
    pad = min(len(y) - 1, int(3 * fs / fc))
    return signal.sosfiltfilt(sos, y, padtype="even", padlen=pad)


def split_slow_periodic(y, fs, fc):
    """(slow, periodic): the low-pass of ``y`` at ``fc`` and what remains."""
    slow = lowpass(y, fs, fc)
    return slow, np.asarray(y, float) - slow


# ---------------------------------------------------------------- harmonics ----
def mean_frequency(t, theta, idx):
    """The mean rotation frequency (Hz) of the angle ``theta`` (rad) over the samples
    ``idx`` (at least two) of the time base ``t`` (s)."""
    return float(abs(theta[idx[-1]] - theta[idx[0]]) / (2 * math.pi) / max(t[idx[-1]] - t[idx[0]], 1e-9))


def harmonic_basis(theta, orders):
    """Columns sin(j theta), cos(j theta) for every order j (N x 2H).

    exp(i j theta) as powers of exp(i theta) (one complex exponential, then
    products): the speed-scale search builds this basis thousands of times on
    records of 10^4-10^5 samples, and the trigonometric functions dominated.
    Up to order 8 the products stay within a few ulp of sin/cos."""
    theta = np.asarray(theta, float)
    orders = [int(j) for j in orders]
    out = np.empty((theta.size, 2 * len(orders)))
    if not orders:
        return out
    z1 = np.exp(1j * theta)
    zj, jz = np.ones_like(z1), 0
    for i, j in enumerate(orders):
        if j < jz or j - jz > 8:   # out of order or far: start again from exp(i j theta)
            zj, jz = np.exp(1j * j * theta), j
        while jz < j:
            zj = zj * z1
            jz += 1
        out[:, 2 * i] = zj.imag
        out[:, 2 * i + 1] = zj.real
    return out


def projected_energy(A, Y):
    """||A coef||^2 of the least-squares fit of ``Y`` (N x m) on the columns of ``A`` (N x k):
    the energy of ``Y`` that the basis explains, b^T G^-1 b with G = A^T A, b = A^T Y.

    The normal equations instead of an SVD (``lstsq``): the speed-scale search calls this
    hundreds of times on records of thousands of samples, and a harmonic basis over three
    or more revolutions is well conditioned (near-orthogonal columns); a singular G (too
    few samples) falls back to ``lstsq``."""
    G = A.T @ A
    b = A.T @ Y
    try:
        coef = np.linalg.solve(G, b)
    except np.linalg.LinAlgError:
        coef, *_ = np.linalg.lstsq(A, Y, rcond=None)
        return float(np.sum((A @ coef) ** 2))
    return float(np.sum(b * coef))


def fit_harmonics(y, theta, orders, mask=None):
    """Least-squares complex amplitudes ``Y_j`` of ``y`` on the orders of ``theta``.

    ``mask`` (bool) restricts the samples used for the fit. Returns ``Y``
    (complex array, one per order)."""
    theta = np.asarray(theta, float)
    y = np.asarray(y, float)
    if mask is not None:
        theta, y = theta[mask], y[mask]
    A = harmonic_basis(theta, orders)
    if len(y) < A.shape[1] + 2:
        return np.zeros(len(orders), complex)
    coef = least_squares(A, y)[0]
    return coef[0::2] + 1j * coef[1::2]


NORMAL_COND = 1e6   # condition number of the scaled Gram matrix up to which the normal equations are solved


def least_squares(A, y):
    """Least-squares coefficients of ``y`` on the columns of ``A``, and the Gram matrix
    A^T A (None where ``lstsq`` solved it).

    The normal equations with the columns scaled to unit norm: a harmonic basis over
    a record is near-orthogonal, and an SVD (``lstsq``) of records of 10^4-10^5 samples
    was a tenth of a diagnosis's time. Their error is about cond x eps of the scaled
    Gram matrix; beyond :data:`NORMAL_COND` (a window of about one revolution, lines a
    fraction of 1/T apart) ``lstsq`` solves it."""
    G = A.T @ A
    b = A.T @ y
    d = np.sqrt(np.diag(G))
    if np.all(d > 0):
        Gn = G / np.outer(d, d)
        if np.linalg.cond(Gn) < NORMAL_COND:
            return np.linalg.solve(Gn, b / d) / d, G
    return np.linalg.lstsq(A, y, rcond=None)[0], None


def harmonic_signal(theta, Y, orders):
    """sum_j Im(Y_j exp(i j theta))."""
    theta = np.asarray(theta, float)
    out = np.zeros_like(theta)
    for Yj, j in zip(Y, orders):
        out += Yj.real * np.sin(j * theta) + Yj.imag * np.cos(j * theta)
    return out


def fourier_to_complex(C, psi):
    """X_j = C_j exp(i psi_j) of a length series C_j sin(j theta + psi_j)."""
    return np.asarray(C, float) * np.exp(1j * np.asarray(psi, float))


# ------------------------------------------------------------- noise floor ----
class NoiseFloor:
    """Local noise level of a signal, one-sided PSD S(f) (unit^2/Hz).

    Welch PSD smoothed by a running median over frequency, so narrow lines
    (the harmonics themselves) do not raise the floor they are tested against.
    """

    def __init__(self, y, fs, seg_seconds=8.0, median_hz=1.0):
        y = np.asarray(y, float)
        n = len(y)
        nperseg = int(min(n, max(256, seg_seconds * fs)))
        f, p = signal.welch(y - np.mean(y), fs=fs, nperseg=nperseg, noverlap=nperseg // 2,
                            detrend="constant")
        df = f[1] - f[0] if len(f) > 1 else fs
        half = max(3, int(round(median_hz / df / 2)))
        k = 2 * half + 1
        med = _running_median(p, k)
        # median of a chi2 estimate lies below its mean; correct for the
        # number of averaged segments (about 1.8x the count at 50 % overlap)
        nseg = max(1, (n - nperseg) // (nperseg // 2) + 1)
        dof = 2.0 * max(1.0, 0.9 * nseg)
        corr = dof / stats.chi2.median(dof)
        self.f, self.S = f, np.maximum(med * corr, 1e-300)

    def __call__(self, freq):
        return np.interp(np.asarray(freq, float), self.f, self.S)


def _running_median(p, k):
    k = min(k, len(p) if len(p) % 2 else len(p) - 1)
    if k < 3:
        return p.copy()
    pad = k // 2
    q = np.pad(p, pad, mode="reflect")
    win = np.lib.stride_tricks.sliding_window_view(q, k)
    return np.median(win, axis=1)


ORDER_SHOWN_Z = 9.0   # an order's z (harmonic_z) per fit run above which the data show it
TIE_MISFIT = 0.02     # pattern misfits closer than this: the sensors do not tell the elements apart


def tied(ranked):
    """The candidates (dicts with ``misfit``, best first) whose pattern across the
    sensors fits as well as the first one's: the first one included."""
    m0 = ranked[0]["misfit"]
    return [r for r in ranked if abs(r["misfit"] - m0) < TIE_MISFIT]


def harmonic_z(Y, freqs, floor, duration):
    """Per-harmonic statistic z_j = |Y_j|^2 T / (2 S(f_j)).

    For noise alone, each quadrature coefficient of a least-squares sinusoid
    fit has variance S/T, so z_j is Exp(1) and the sum over H harmonics is
    Gamma(H, 1)."""
    S = floor(freqs)
    return np.abs(np.asarray(Y)) ** 2 * duration / (2.0 * S)


def fit_harmonics_joint(y, families):
    """Least-squares complex amplitudes of the first of ``families`` [(theta, orders),
    ...] fitted together with the others on ``y``: the others' lines take their own
    share where the bases are not orthogonal (a short segment, lines a fraction
    of a hertz apart)."""
    if len(families) == 1:
        return fit_harmonics(y, *families[0])
    return fit_harmonics_families(y, families)[0]


def fit_harmonics_families(y, families, inflation=False):
    """Least-squares complex amplitudes of every family of ``families`` [(theta,
    orders), ...] fitted together on ``y``: one array per family (zeros if ``y`` is
    too short for the basis).

    ``inflation``: also return, per order of the first family, the factor by which
    fitting the others beside it inflates its coefficients' noise variance (1 where
    the bases are orthogonal, 1 / (1 - rho^2) for one line beside another of
    correlation rho): a z of the first family's lines divided by it stays Exp(1)
    under noise."""
    A = np.hstack([harmonic_basis(th, o) for th, o in families])
    n0 = len(families[0][1])
    if len(y) < A.shape[1] + 2:
        out = [np.zeros(len(o), complex) for _, o in families]
        return (out, np.ones(n0)) if inflation else out
    coef, G = least_squares(A, np.asarray(y, float))
    out, i = [], 0
    for _, o in families:
        c = coef[i:i + 2 * len(o)]
        out.append(c[0::2] + 1j * c[1::2])
        i += 2 * len(o)
    if not inflation:
        return out
    G = A.T @ A if G is None else G
    try:
        f = np.diag(np.linalg.inv(G)) * np.diag(G)
    except np.linalg.LinAlgError:
        f = np.full(A.shape[1], np.inf)
    return out, np.maximum(0.5 * (f[0:2 * n0:2] + f[1:2 * n0:2]), 1.0)


def coherence_debiased(Ys, v, clip=(0.0, 1.0)):
    """Phase stability per order of phasors ``Ys`` (K segments x orders) fitted
    on consecutive segments, each carrying white noise of expected ``|Y|^2 = v``
    (per order; ``2 S / T_seg``, :func:`harmonic_z`).

    A steady line Y plus noise gives E|sum Y_k|^2 = K^2 |Y|^2 + K v and
    E sum |Y_k|^2 = K |Y|^2 + K v; the raw ratio |sum Y_k|^2 / (K sum |Y_k|^2)
    reads (K r + 1) / (K r + K) at segment SNR r = |Y|^2 / v, so a weak steady
    line looks half incoherent. Subtracting the noise's share from both sums
    gives 1 for a steady line at any SNR; noise alone and a transient that
    fills one segment stay low. Clipped to [0, 1]; an order whose segments
    carry no more than their noise reads 0.

    ``clip``: the range each order's value is held to. Averaged over orders, a
    window around both values the estimate scatters about (0 for noise, 1 for a
    steady line), such as (-1, 2), keeps the average unbiased: clipped to
    [0, 1], a weak steady line's scatter above 1 is cut and its average reads
    low, and noise's below 0 is cut and it reads high."""
    Ys = np.asarray(Ys, complex)
    K = Ys.shape[0]
    v = np.broadcast_to(np.asarray(v, float), Ys.shape[1:])
    num = np.abs(Ys.sum(axis=0)) ** 2 - K * v
    den = K * (np.sum(np.abs(Ys) ** 2, axis=0) - K * v)
    out = np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)
    return np.clip(out, *clip)


def gamma_log10_sf(z_sum, shape):
    """log10 of the probability that noise alone gives a summed z above ``z_sum``."""
    if shape <= 0:
        return 0.0
    v = float(stats.gamma.logsf(z_sum, shape) / math.log(10.0))
    if not math.isfinite(v):  # underflow far in the tail: bound by the leading term
        v = (-z_sum + (shape - 1) * math.log(max(z_sum, 1.0)) - math.lgamma(shape)) / math.log(10.0)
    return v


# ---------------------------------------------------------- angle refinement ----
def refine_angle(y, theta, orders, mask=None, span=0.03, fs=None, duration=None):
    """Speed-scale refinement of an element angle.

    The element may turn slightly faster or slower than the model says (radius
    error, strain): theta_true = (1 + kappa) (theta - theta_ref) + theta_ref,
    the phase being absorbed by the complex amplitudes. Searches ``kappa`` in
    [-span, span] for the largest energy explained by the harmonic family
    (a coarse grid at a fraction of the resolution 1/(orders * revolutions),
    then a parabolic refinement). Returns (kappa, explained energy).
    """
    theta = np.asarray(theta, float)
    sel = slice(None) if mask is None else mask
    th = theta[sel]
    ref = 0.5 * (th[0] + th[-1]) if len(th) else 0.0
    revs = max(1e-9, abs(th[-1] - th[0]) / (2 * math.pi)) if len(th) > 1 else 1.0
    hmax = max(orders)
    step = 0.25 / (hmax * revs)  # quarter of the resolution of the top order
    n = int(min(400, math.ceil(span / step)))
    grid = np.linspace(-span, span, 2 * n + 1) if n > 0 else np.array([0.0])
    ysel = np.asarray(y, float)[sel]

    def energy(k):
        t = (1.0 + k) * (th - ref) + ref
        Y = fit_harmonics(ysel, t, orders)
        return float(np.sum(np.abs(Y) ** 2))

    e = np.array([energy(k) for k in grid])
    i = int(np.argmax(e))
    k = grid[i]
    if 0 < i < len(grid) - 1:
        a, b, c = e[i - 1], e[i], e[i + 1]
        den = a - 2 * b + c
        if den < 0:
            k = grid[i] + 0.5 * (a - c) / den * (grid[1] - grid[0])
    return float(k), energy(k)


def scaled_angle(theta, kappa, ref):
    return (1.0 + kappa) * (np.asarray(theta, float) - ref) + ref


# ------------------------------------------------------------ gains/solving ----
def complex_gain(delta, theta, orders, X_test, mask=None):
    """Complex gain per order of a sensor from a sensitivity simulation.

    ``delta``: sensitivity simulation minus nominal, at that sensor;
    ``X_test``: complex Fourier coefficients put on the element in that
    simulation (m). Returns G_j = Y_j / X_test_j (N/m)."""
    Y = fit_harmonics(delta, theta, orders, mask)
    X = np.asarray(X_test, complex)
    return np.where(np.abs(X) > 0, Y / np.where(np.abs(X) > 0, X, 1.0), 0.0)


def solve_fourier(M, G, weights=None):
    """Fourier coefficients X_j from measured harmonics M[k, j] and gains G[k, j].

    k runs over (run, sensor) pairs. Least squares per order:
    X_j = sum_k w_k conj(G_kj) M_kj / sum_k w_k |G_kj|^2. Returns (X, misfit)
    with ``misfit`` = unexplained share of the measured harmonic energy
    (0 = the element's pattern across sensors fits exactly)."""
    M = np.atleast_2d(np.asarray(M, complex))
    G = np.atleast_2d(np.asarray(G, complex))
    w = np.ones(M.shape[0]) if weights is None else np.asarray(weights, float)
    num = np.sum(w[:, None] * np.conj(G) * M, axis=0)
    den = np.sum(w[:, None] * np.abs(G) ** 2, axis=0)
    X = np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)
    resid = np.sum(w[:, None] * np.abs(M - G * X[None, :]) ** 2)
    total = np.sum(w[:, None] * np.abs(M) ** 2)
    return X, float(resid / total) if total > 0 else 0.0


# ------------------------------------------------------------------- misc ----
def steady_mask(speed, fs, rel_rate=0.01, min_seconds=1.0, speed_floor=0.05):
    """Samples at steady line speed: |dv/dt| below ``rel_rate`` * max|v| per
    second and speed above ``speed_floor`` * max|v|; runs shorter than
    ``min_seconds`` are dropped."""
    v = np.asarray(speed, float)
    vmax = max(float(np.max(np.abs(v))), 1e-12)
    vs = lowpass(v, fs, min(2.0, 0.2 * fs))
    dv = np.gradient(vs) * fs
    ok = (np.abs(dv) <= rel_rate * vmax) & (np.abs(vs) >= speed_floor * vmax)
    return _drop_short(ok, int(min_seconds * fs))


def _drop_short(mask, n):
    mask = mask.copy()
    i = 0
    N = len(mask)
    while i < N:
        if mask[i]:
            j = i
            while j < N and mask[j]:
                j += 1
            if j - i < n:
                mask[i:j] = False
            i = j
        else:
            i += 1
    return mask


def windows_of(mask, t):
    """[(start, stop)] times of the True runs of ``mask``."""
    out = []
    m = np.concatenate([[False], mask, [False]]).astype(int)
    d = np.diff(m)
    starts, stops = np.where(d == 1)[0], np.where(d == -1)[0]
    for a, b in zip(starts, stops):
        out.append((float(t[a]), float(t[b - 1])))
    return out
