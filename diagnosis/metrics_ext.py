"""Gap metrics between a measured and a simulated tension, as ``webline diagnose`` reports them.

Built on :mod:`diagnosis.metrics`. ``gap_metrics`` returns, for measured y
and model yhat (error e = y - yhat):

* ``nrmse`` = rms(e) / std(y) (0 = perfect; 1 = no better than the mean)
* ``fit_percent`` = 100 (1 - ||e|| / ||y - mean(y)||)
* ``l1`` = integral |e| dt (N.s), ``l2`` = integral e^2 dt (N^2.s, the paper's
  definition, not square-rooted), ``linf`` = max |e| (N)
* ``rms`` (N), ``mean_error`` (N)
* ``spectral_peak_error``: at the 5 strongest significant peaks of the measured
  spectrum (fit window), the relative RMS error of the model's peak amplitudes,
  sqrt(sum (A_model - A_meas)^2 / sum A_meas^2): 0 = every peak reproduced,
  1 = none; ``None`` when the measurement has no significant peak.
  ``spectral_peaks`` lists them (frequency, measured and model amplitude).
"""
import numpy as np

from webline.diagnosis import metrics


def gap_metrics(t, y, yhat, fs, mask=None, n_peaks=5):
    y, yhat = np.asarray(y, float), np.asarray(yhat, float)
    e = y - yhat
    norms = metrics.error_norms(t, y, yhat)
    out = {
        "nrmse": metrics.nrmse(y, yhat),
        "fit_percent": metrics.fit_percent(y, yhat),
        "l1": norms.l1, "l2": norms.l2, "linf": norms.linf,
        "rms": float(np.sqrt(np.mean(e ** 2))),
        "mean_error": float(np.mean(e)),
    }
    m = mask if mask is not None and mask.sum() > 64 else np.ones_like(y, bool)
    pe = metrics.spectral_peak_error(y[m] - np.mean(y[m]), yhat[m] - np.mean(yhat[m]), fs, n_peaks=n_peaks)
    if len(pe.amplitude):
        out["spectral_peak_error"] = float(np.sqrt(np.sum(pe.amplitude_error ** 2) / np.sum(pe.amplitude ** 2)))
        out["spectral_peaks"] = [{"frequency_hz": float(f), "measured": float(a), "model": float(b)}
                                 for f, a, b in zip(pe.frequency, pe.amplitude, pe.model_amplitude)]
    else:
        out["spectral_peak_error"] = None
        out["spectral_peaks"] = []
    return out
