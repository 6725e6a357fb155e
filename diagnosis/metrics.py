"""How far a model is from a measurement, and where the gap sits.

Error measures of a simulated signal ``yhat`` against a measured ``y`` on the
same time grid: NRMSE and fit %, the paper's L1 / L2 / L-infinity norms of the
error (integrals over time), and the error of the dominant spectral peaks.
Tools to look inside a residual: split it into a slow part and a periodic part,
cut a record into speed windows (ramps vs steady running), and measure the
share of energy in frequency bands.

Public: :func:`nrmse`, :func:`fit_percent`, :func:`error_norms`,
:class:`ErrorNorms`, :func:`spectral_peak_error`, :class:`PeakError`,
:func:`split_residual`, :func:`speed_windows`, :class:`Window`,
:func:`band_energy`.
"""
from typing import NamedTuple

import numpy as np
import scipy.ndimage
import scipy.signal

from webline.diagnosis.spectra import (amplitude_spectrum, frequency_resolution, interpolate_peak,
                               spectral_peaks)


def _pair(y, yhat):
    y = np.asarray(y, dtype=float)
    yhat = np.asarray(yhat, dtype=float)
    if y.shape != yhat.shape:
        raise ValueError(f"measured and model signals differ in shape: {y.shape} vs {yhat.shape}")
    return y, yhat


def nrmse(y, yhat, *, normalization="std"):
    """Root-mean-square error of ``yhat`` against ``y``, divided by the standard
    deviation of ``y`` ("std", so that fit % = 100 (1 - nrmse)), its range
    ("range") or its absolute mean ("mean")."""
    y, yhat = _pair(y, yhat)
    rmse = np.sqrt(np.mean((y - yhat) ** 2))
    scale = {"std": lambda: np.std(y), "range": lambda: np.ptp(y), "mean": lambda: abs(np.mean(y))}
    if normalization not in scale:
        raise ValueError(f"normalization must be one of {', '.join(scale)}, not {normalization!r}")
    return float(rmse / scale[normalization]())


def fit_percent(y, yhat):
    """Fit % = 100 (1 - ||y - yhat|| / ||y - mean(y)||): 100 is perfect, 0 is no better
    than the mean, negative is worse."""
    y, yhat = _pair(y, yhat)
    return float(100.0 * (1.0 - np.linalg.norm(y - yhat) / np.linalg.norm(y - np.mean(y))))


class ErrorNorms(NamedTuple):
    """The paper's error norms of e = y - yhat: ``l1`` = integral of |e| dt (unit.s),
    ``l2`` = integral of e^2 dt (unit^2.s; not square-rooted, as the paper defines
    it), ``linf`` = max |e| (unit)."""
    l1: float
    l2: float
    linf: float


def error_norms(t, y, yhat):
    """L1, L2 and L-infinity norms of the error, as the paper defines them: integrals
    over time (trapezoidal rule on ``t``, s), not sums over samples, so records of
    different sample rates compare. See :class:`ErrorNorms`."""
    y, yhat = _pair(y, yhat)
    e = y - yhat
    t = np.asarray(t, dtype=float)
    return ErrorNorms(l1=float(np.trapezoid(np.abs(e), t)), l2=float(np.trapezoid(e * e, t)),
                      linf=float(np.max(np.abs(e))))


class PeakError(NamedTuple):
    """Dominant measured peaks and the model's spectrum there, strongest first.
    ``model_frequency`` is NaN where the model has no local maximum within the
    search band (``model_amplitude`` is then its spectrum at the measured
    frequency). Errors are model minus measurement."""
    frequency: np.ndarray
    amplitude: np.ndarray
    model_frequency: np.ndarray
    model_amplitude: np.ndarray
    frequency_error: np.ndarray
    amplitude_error: np.ndarray
    relative_amplitude_error: np.ndarray


def spectral_peak_error(y, yhat, fs, *, n_peaks=5, alpha=0.01, band=None):
    """Amplitude and frequency error of the model at the ``n_peaks`` strongest
    significant peaks of the measurement (:func:`spectra.spectral_peaks`).

    For each measured peak at f, the model's spectrum is searched within
    f +/- ``band`` (default: the frequency resolution); its largest local maximum
    there is the model's peak. Returns :class:`PeakError` (empty arrays if the
    measurement has no significant peak).
    """
    y, yhat = _pair(y, yhat)
    f, amp = amplitude_spectrum(y, fs)
    _, amp_model = amplitude_spectrum(yhat, fs)
    peaks = spectral_peaks(f, amp, alpha=alpha)
    band = frequency_resolution(len(y), fs) if band is None else band
    fm, am = [], []
    for fp in peaks.frequency[:n_peaks]:
        inside = np.flatnonzero(np.abs(f - fp) <= band)
        k = inside[np.argmax(amp_model[inside])]
        if 0 < k < len(f) - 1 and amp_model[k] >= amp_model[k - 1] and amp_model[k] >= amp_model[k + 1]:
            fk, ak = interpolate_peak(f, amp_model, k)
        else:
            fk, ak = np.nan, float(np.interp(fp, f, amp_model))
        fm.append(fk)
        am.append(ak)
    freq, a = peaks.frequency[:n_peaks], peaks.amplitude[:n_peaks]
    fm, am = np.array(fm, dtype=float), np.array(am, dtype=float)
    return PeakError(frequency=freq, amplitude=a, model_frequency=fm, model_amplitude=am,
                     frequency_error=fm - freq, amplitude_error=am - a, relative_amplitude_error=(am - a) / a)


def split_residual(r, fs, cutoff, *, method="butter", order=4):
    """Split a residual into a slow part and a periodic part: r = slow + periodic.

    ``method="butter"``: slow = zero-phase Butterworth low-pass (``order``,
    ``cutoff`` Hz; filtfilt, so no delay). ``method="moving_average"``: slow =
    centred moving average over 1/``cutoff`` s, which removes the frequency
    ``cutoff`` and all its harmonics exactly - give a shaft's rotation frequency
    to take every harmonic of that shaft out of the slow part.
    Returns (slow, periodic).
    """
    r = np.asarray(r, dtype=float)
    if not 0 < cutoff < fs / 2:
        raise ValueError(f"cutoff {cutoff} Hz must lie between 0 and fs/2 = {fs / 2} Hz")
    if method == "butter":
        sos = scipy.signal.butter(order, cutoff, fs=fs, output="sos")
        # pad by a few periods of the cutoff: the default (a few samples) leaves a
        # start-up transient of the slow part over seconds
        slow = scipy.signal.sosfiltfilt(sos, r, padlen=min(len(r) - 1, int(3 * fs / cutoff)))
    elif method == "moving_average":
        slow = scipy.ndimage.uniform_filter1d(r, max(1, int(round(fs / cutoff))), mode="nearest")
    else:
        raise ValueError(f"method must be 'butter' or 'moving_average', not {method!r}")
    return slow, r - slow


class Window(NamedTuple):
    """A stretch of a record at one kind of running: ``kind`` "steady", "ramp" or
    "stopped"; ``start``/``stop`` times (s, first and last sample); ``index`` a
    slice into the record's arrays."""
    kind: str
    start: float
    stop: float
    index: slice


def speed_windows(t, speed, *, accel_tol=None, stop_tol=None, smooth=1.0, min_duration=2.0):
    """Cut a record into windows of steady running, speed ramps and standstill.

    The speed is smoothed by a centred moving average over ``smooth`` s and
    differentiated. A sample is "stopped" when |speed| < ``stop_tol`` (default 2 %
    of the largest |speed|), "ramp" when |d speed/dt| > ``accel_tol`` (default 1 %
    of the largest |speed| per second), "steady" otherwise. Runs shorter than
    ``min_duration`` s are merged into the run before them (the first into the
    one after). Returns a list of :class:`Window` covering the record in order.
    """
    t = np.asarray(t, dtype=float)
    v = np.asarray(speed, dtype=float)
    dt = (t[-1] - t[0]) / (len(t) - 1)
    vs = scipy.ndimage.uniform_filter1d(v, max(1, int(round(smooth / dt))), mode="nearest")
    acc = np.gradient(vs, t)
    vmax = float(np.max(np.abs(vs))) or 1.0
    accel_tol = 0.01 * vmax if accel_tol is None else accel_tol
    stop_tol = 0.02 * vmax if stop_tol is None else stop_tol
    kinds = np.where(np.abs(vs) < stop_tol, 2, np.where(np.abs(acc) > accel_tol, 1, 0))
    names = ("steady", "ramp", "stopped")
    change = np.flatnonzero(np.diff(kinds)) + 1
    runs = [[int(kinds[a]), a, b] for a, b in zip(np.r_[0, change], np.r_[change, len(t)])]
    merged = []
    for run in runs:
        if merged and (run[0] == merged[-1][0] or t[run[2] - 1] - t[run[1]] < min_duration):
            merged[-1][2] = run[2]
        else:
            merged.append(run)
    if len(merged) > 1 and t[merged[0][2] - 1] - t[merged[0][1]] < min_duration:
        merged[1][1] = merged[0][1]
        merged.pop(0)
    out = []
    for kind, a, b in merged:  # merging may have joined runs of one kind
        if out and out[-1][0] == kind:
            out[-1][2] = b
        else:
            out.append([kind, a, b])
    return [Window(names[k], float(t[a]), float(t[b - 1]), slice(a, b)) for k, a, b in out]


def band_energy(x, fs, bands):
    """Share of the variance of ``x`` (mean removed) in each frequency band.

    ``bands``: name -> (f_lo, f_hi) in Hz, edges included. The key "other" in the
    result holds what no band covers (overlapping bands count twice). Computed
    from the Hann-windowed power spectrum, so a band edge cuts a peak's main
    lobe where it falls.
    """
    f, amp = amplitude_spectrum(x, fs, detrend="constant")
    power = 0.5 * amp ** 2
    total = float(np.sum(power)) or 1.0
    shares, covered = {}, np.zeros(len(f), dtype=bool)
    for name, (lo, hi) in bands.items():
        inside = (f >= lo) & (f <= hi)
        covered |= inside
        shares[name] = float(np.sum(power[inside]) / total)
    shares["other"] = float(np.sum(power[~covered]) / total)
    return shares
