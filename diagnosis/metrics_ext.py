"""Gap metrics between a measured and a simulated tension, as reported by ``webline diagnose``.

``gap_metrics`` returns, for measured y and model yhat (error e = y - yhat):

* ``nrmse`` = ||e|| / ||y - mean(y)|| (0 = perfect; 1 = no better than the mean)
* ``fit_percent`` = 100 (1 - nrmse)
* ``l1`` = integral |e| dt (N.s), ``l2`` = sqrt(integral e^2 dt) (N.s^0.5),
  ``linf`` = max |e| (N) - the paper's three norms
* ``rms`` (N), ``mean_error`` (N)
* ``spectral_peak_error``: the largest significant peaks of the measured
  spectrum (fit window, Hann window); relative RMS error of the model's
  amplitude at those frequencies, sqrt(sum (A_model - A_meas)^2 / sum A_meas^2)
  (0 = every peak reproduced, 1 = none); ``None`` if the data has no peak.

Where :mod:`diagnosis.metrics` provides a measure, its definition is used.
"""
import numpy as np


def _metrics_module():
    try:
        from diagnosis import metrics
        return metrics
    except ImportError:
        return None


def gap_metrics(t, y, yhat, fs, mask=None, n_peaks=8):
    y, yhat = np.asarray(y, float), np.asarray(yhat, float)
    e = y - yhat
    dt = 1.0 / fs
    den = float(np.linalg.norm(y - np.mean(y)))
    nrmse = float(np.linalg.norm(e) / den) if den > 0 else float("inf")
    out = {
        "nrmse": nrmse,
        "fit_percent": 100.0 * (1.0 - nrmse),
        "l1": float(np.sum(np.abs(e)) * dt),
        "l2": float(np.sqrt(np.sum(e ** 2) * dt)),
        "linf": float(np.max(np.abs(e))),
        "rms": float(np.sqrt(np.mean(e ** 2))),
        "mean_error": float(np.mean(e)),
    }
    m = mask if mask is not None and mask.sum() > 64 else np.ones_like(y, bool)
    out["spectral_peak_error"] = spectral_peak_error(y[m], yhat[m], fs, n_peaks)
    mod = _metrics_module()
    if mod is not None:
        for name in ("nrmse", "fit_percent"):
            fn = getattr(mod, name, None)
            if callable(fn):
                try:
                    out[name] = float(fn(y, yhat))
                except Exception:
                    pass
    return out


def spectral_peak_error(y, yhat, fs, n_peaks=8):
    from diagnosis import spectra
    f, A = spectra.amplitude_spectrum(y, fs)
    _, B = spectra.amplitude_spectrum(yhat, fs)
    pk = spectra.spectral_peaks(f, A)
    if len(pk.index) == 0:
        return None
    idx = pk.index[:n_peaks]
    a, b = A[idx], B[idx]
    return float(np.sqrt(np.sum((b - a) ** 2) / np.sum(a ** 2)))
