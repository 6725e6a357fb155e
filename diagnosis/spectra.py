"""Amplitude spectra, significant peaks, and tagging peaks to shaft harmonic families.

The paper's Figs 6-13 method as functions: take the tension's amplitude
spectrum, keep the peaks that stand out of the noise, and label each as
harmonic j of a rotating element whose fundamental is known (v / (2 pi R),
{30}-{31}) - or as ambiguous when two elements' harmonics lie closer than the
record can resolve.

All spectra use a Hann window and are scaled so that a sinusoid of amplitude A
(on a bin) shows a peak of height A.

Public: :func:`amplitude_spectrum`, :func:`frequency_resolution`,
:func:`noise_floor`, :func:`significance_factor`, :func:`spectral_peaks`, :func:`interpolate_peak`,
:class:`Peaks`, :class:`Family`, :func:`family`, :class:`Tag`, :func:`tag_peaks`.
"""
from typing import NamedTuple

import numpy as np
import scipy.ndimage
import scipy.signal

MAIN_LOBE_BINS = 2.0
"""Half-width of the Hann window's main lobe in bins (1/T): two tones closer than
this merge into one peak."""


def amplitude_spectrum(x, fs, *, detrend="linear"):
    """One-sided amplitude spectrum of ``x`` sampled at ``fs`` (Hann window).

    Returns (f, amp): ``f`` in Hz (in cycles per unit of whatever ``fs`` counts
    per second - samples per revolution gives orders), ``amp`` in the unit of
    ``x``, scaled so that A sin(2 pi f0 t) with f0 on a bin gives amp = A at f0.
    ``detrend``: "linear" (default: a tension drifting with the roll radius would
    otherwise leak into the lowest bins), "constant" or False.
    """
    x = np.asarray(x, dtype=float)
    f, p = scipy.signal.periodogram(x, fs, window="hann", detrend=detrend, scaling="spectrum")
    return f, np.sqrt(2.0 * p)  # p is the mean square of the component: A^2 / 2


def frequency_resolution(n, fs):
    """Frequency resolution (Hz) of an ``n``-sample Hann-windowed record at ``fs``:
    the main-lobe half-width ``MAIN_LOBE_BINS * fs / n`` (twice the bin spacing 1/T).
    Harmonics of two shafts closer than this cannot be told apart."""
    return MAIN_LOBE_BINS * fs / n


def _floor_width(n_bins, width=None):
    width = max(31, n_bins // 50) if width is None else int(width)
    return min(width | 1, (n_bins - 1) | 1)


def noise_floor(amp, *, width=None):
    """Running median of an amplitude spectrum: the typical noise amplitude per bin.

    The median ignores the peaks as long as they fill less than half of each
    window. ``width`` (bins, odd) defaults to max(31, len(amp) // 50).
    """
    amp = np.asarray(amp, dtype=float)
    return scipy.ndimage.median_filter(amp, size=_floor_width(len(amp), width), mode="mirror")


def significance_factor(n_bins, alpha=0.01):
    """Threshold over the median noise floor for a family-wise false-alarm
    probability ``alpha`` over ``n_bins`` bins.

    For Gaussian noise a bin's amplitude is Rayleigh distributed:
    P(amp > k * median) = 2**(-k**2). Requiring n_bins * 2**(-k**2) = alpha gives
    k = sqrt(log2(n_bins / alpha)) (about 4.4 for 6000 bins at 1 %). Neighbouring
    Hann bins are correlated, so the actual false-alarm rate is lower.
    """
    return float(np.sqrt(np.log2(max(n_bins, 1) / alpha)))


def _hann_leakage(delta):
    """Upper envelope of a Hann-windowed tone's relative amplitude ``delta`` bins
    away from it: 1 within the main lobe, 1/(pi d (d^2 - 1)) in the side lobes."""
    d = np.abs(delta)
    with np.errstate(divide="ignore"):
        return np.where(d < MAIN_LOBE_BINS, 1.0, 1.0 / (np.pi * d * (d * d - 1.0)))


class Peaks(NamedTuple):
    """Significant spectral peaks, strongest first. Arrays of equal length:
    ``frequency`` (interpolated between bins), ``amplitude`` (corrected for the
    window's scalloping), ``floor`` (noise floor there), ``snr`` (amplitude/floor),
    ``index`` (bin). ``threshold`` is the per-bin threshold array used."""
    frequency: np.ndarray
    amplitude: np.ndarray
    floor: np.ndarray
    snr: np.ndarray
    index: np.ndarray
    threshold: np.ndarray


def interpolate_peak(f, amp, k):
    """Frequency and amplitude of the peak at bin k by a parabola through the log
    amplitudes of bins k-1, k, k+1 (Gaussian interpolation; Hann scalloping
    loss of up to 15 % drops to about 1 %)."""
    if k <= 0 or k >= len(amp) - 1 or min(amp[k - 1], amp[k], amp[k + 1]) <= 0:
        return float(f[k]), float(amp[k])
    a, b, c = np.log(amp[k - 1:k + 2])
    den = a - 2 * b + c
    if den >= 0:
        return float(f[k]), float(amp[k])
    d = 0.5 * (a - c) / den
    return float(f[k] + d * (f[1] - f[0])), float(np.exp(b - 0.25 * (a - c) * d))


def spectral_peaks(f, amp, *, alpha=0.01, floor=None, fmin=None, fmax=None, leakage_margin=3.0):
    """Peaks of an amplitude spectrum that are significant above the noise floor.

    A bin is a candidate if it is a local maximum above ``significance_factor(n, alpha)
    * floor`` (n = bins searched). ``floor`` defaults to :func:`noise_floor`, whose
    median over w bins is itself uncertain (relative standard error 0.72/sqrt(w)
    for Rayleigh amplitudes): the threshold is raised by that factor, which
    brings the false-alarm rate of white noise to about ``alpha``. A
    candidate is dropped if it lies within the main lobe of a stronger peak, or
    below ``leakage_margin`` times the side-lobe leakage of the stronger peaks
    (a clean record has side lobes above a low noise floor). Bins below ``fmin``
    (default: the DC main lobe) or above ``fmax`` are not searched.
    Returns :class:`Peaks`, strongest first. Noise alone yields no peak with
    probability about 1 - alpha.
    """
    f = np.asarray(f, dtype=float)
    amp = np.asarray(amp, dtype=float)
    df = f[1] - f[0]
    if floor is None:
        floor = noise_floor(amp)
        margin = 1.0 + 0.72 / np.sqrt(_floor_width(len(amp)))
    else:
        floor, margin = np.broadcast_to(np.asarray(floor, float), amp.shape), 1.0
    lo = MAIN_LOBE_BINS * df if fmin is None else fmin
    hi = f[-1] if fmax is None else fmax
    search = (f >= lo) & (f <= hi)
    threshold = significance_factor(int(search.sum()), alpha) * margin * floor
    idx, _ = scipy.signal.find_peaks(amp)  # true local maxima: a leak falling off DC has none
    idx = idx[search[idx] & (amp[idx] > threshold[idx])]
    idx = idx[np.argsort(amp[idx])[::-1]]
    kept, freqs, amps = [], [], []
    for k in idx:
        fk, ak = interpolate_peak(f, amp, k)
        if kept:
            leak = np.sum(np.array(amps) * _hann_leakage((fk - np.array(freqs)) / df))
            if ak <= leakage_margin * leak or np.min(np.abs(fk - np.array(freqs))) < MAIN_LOBE_BINS * df:
                continue
        kept.append(k)
        freqs.append(fk)
        amps.append(ak)
    kept = np.array(kept, dtype=int)
    return Peaks(frequency=np.array(freqs, dtype=float), amplitude=np.array(amps, dtype=float),
                 floor=floor[kept], snr=np.array(amps, dtype=float) / floor[kept], index=kept,
                 threshold=threshold)


class Family(NamedTuple):
    """Fundamental frequency of a rotating element (Hz): ``mean`` and ``spread``
    (half of its range over the record; 0 for a constant speed)."""
    mean: float
    spread: float = 0.0


def family(f):
    """:class:`Family` from a fundamental frequency: a number (spread 0), a
    ``Family`` (returned as is) or an array of the frequency over the record
    (mean and half-range)."""
    if isinstance(f, Family):
        return f
    f = np.asarray(f, dtype=float)
    if f.ndim == 0:
        return Family(float(f), 0.0)
    return Family(float(np.mean(f)), float(0.5 * (np.max(f) - np.min(f))))


class Tag(NamedTuple):
    """What a spectral peak is attributed to. ``status`` is "tagged" (``family`` and
    ``harmonic`` set), "ambiguous" (two or more families match; see ``candidates``)
    or "untagged" (none). ``candidates``: every (family, harmonic) within reach,
    nearest first."""
    frequency: float
    status: str
    family: str | None
    harmonic: int | None
    candidates: tuple


def tag_peaks(frequencies, families, resolution, *, max_harmonic=10):
    """Tag each peak frequency with the shaft family and harmonic it belongs to.

    ``families``: name -> fundamental frequency (see :func:`family`: a number, a
    :class:`Family`, or the frequency over time). Harmonic j of a family matches
    a peak at f when |f - j mean| <= resolution + j spread (j = 1..max_harmonic);
    ``resolution`` is usually :func:`frequency_resolution`. One family matching:
    "tagged" with its nearest harmonic; several: "ambiguous"; none: "untagged".
    Returns a list of :class:`Tag`, one per frequency.
    """
    fams = {name: family(v) for name, v in families.items()}
    tags = []
    for fp in np.atleast_1d(np.asarray(frequencies, dtype=float)):
        cands = []
        for name, fam in fams.items():
            if fam.mean <= 0:
                continue
            j_lo = max(1, int(np.floor((fp - resolution) / (fam.mean + fam.spread))))
            j_hi = min(max_harmonic, int(np.ceil((fp + resolution) / max(fam.mean - fam.spread, 1e-12))))
            for j in range(j_lo, j_hi + 1):
                err = abs(fp - j * fam.mean)
                if err <= resolution + j * fam.spread:
                    cands.append((err, name, j))
        cands.sort()
        names = {name for _, name, _ in cands}
        candidates = tuple((name, j) for _, name, j in cands)
        if not cands:
            tags.append(Tag(float(fp), "untagged", None, None, ()))
        elif len(names) == 1:
            tags.append(Tag(float(fp), "tagged", cands[0][1], cands[0][2], candidates))
        else:
            tags.append(Tag(float(fp), "ambiguous", None, None, candidates))
    return tags
