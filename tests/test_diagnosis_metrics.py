"""webline.diagnosis.metrics: model-vs-measurement errors and residual decomposition, on known answers."""
import numpy as np
import pytest

from webline.diagnosis import metrics as mt


def sine(t, f, a=1.0, p=0.0):
    return a * np.sin(2 * np.pi * f * t + p)


def test_fit_percent_and_nrmse():
    t = np.arange(1000) * 0.01
    y = 100 + sine(t, 1.0, 2.0)
    assert mt.fit_percent(y, y) == pytest.approx(100.0) and mt.nrmse(y, y) == 0.0
    assert mt.fit_percent(y, np.full_like(y, y.mean())) == pytest.approx(0.0)
    yhat = 100 + sine(t, 1.0, 1.5)
    assert mt.nrmse(y, yhat) == pytest.approx(0.25)
    assert mt.fit_percent(y, yhat) == pytest.approx(75.0)
    assert mt.nrmse(y, yhat, normalization="range") == pytest.approx(0.5 / np.sqrt(2) / 4, rel=1e-3)
    assert mt.nrmse(y, yhat, normalization="mean") == pytest.approx(0.5 / np.sqrt(2) / 100)
    with pytest.raises(ValueError, match="differ in shape"):
        mt.fit_percent(y, yhat[:-1])


def test_error_norms_are_time_integrals():
    for fs in (10.0, 1000.0):  # independent of the sample rate
        t = np.arange(int(20 * fs) + 1) / fs
        norms = mt.error_norms(t, np.full(t.size, 5.0), np.full(t.size, 4.5))
        assert norms == pytest.approx((0.5 * 20, 0.25 * 20, 0.5))
    t = np.linspace(0, 10, 100001)
    norms = mt.error_norms(t, sine(t, 1.0, 2.0), np.zeros_like(t))
    assert norms.l1 == pytest.approx(10 * 2 * 2 / np.pi, rel=1e-6)  # mean |sin| = 2/pi
    assert norms.l2 == pytest.approx(10 * 4 / 2, rel=1e-6) and norms.linf == pytest.approx(2.0)


def test_spectral_peak_error():
    fs = 100.0
    t = np.arange(6000) / fs
    rng = np.random.default_rng(0)
    y = sine(t, 1.5, 2.0) + sine(t, 4.0, 1.0) + rng.normal(0, 0.2, t.size)
    yhat = sine(t, 1.52, 1.8)  # frequency 0.02 Hz high, amplitude 10 % low; no 4 Hz at all
    err = mt.spectral_peak_error(y, yhat, fs)
    assert err.frequency == pytest.approx([1.5, 4.0], abs=2e-3)
    assert err.frequency_error[0] == pytest.approx(0.02, abs=2e-3)
    assert err.relative_amplitude_error[0] == pytest.approx(-0.1, abs=0.02)
    assert np.isnan(err.model_frequency[1]) and err.relative_amplitude_error[1] == pytest.approx(-1.0, abs=1e-3)


def test_split_residual():
    fs = 100.0
    t = np.arange(6000) / fs
    slow_true = 0.05 * t + 0.5 * np.sin(2 * np.pi * 0.02 * t)
    r = slow_true + sine(t, 1.25, 1.0) + sine(t, 2.5, 0.5)
    slow, periodic = mt.split_residual(r, fs, 1.25, method="moving_average")  # one period of the shaft
    assert slow + periodic == pytest.approx(r)
    inner = slice(200, -200)
    assert slow[inner] == pytest.approx(slow_true[inner], abs=0.01)
    slow, periodic = mt.split_residual(r, fs, 0.3)
    assert slow[inner] == pytest.approx(slow_true[inner], abs=0.02)
    assert periodic[inner] == pytest.approx((sine(t, 1.25) + sine(t, 2.5, 0.5))[inner], abs=0.02)
    with pytest.raises(ValueError, match="cutoff"):
        mt.split_residual(r, fs, 60.0)


def test_speed_windows():
    fs = 50.0
    t = np.arange(int(60 * fs)) / fs
    v = np.interp(t, [0, 10, 30, 35, 50, 55, 60], [0, 1.0, 1.0, 0.5, 0.5, 0, 0])
    v = v + np.random.default_rng(0).normal(0, 0.002, t.size)
    wins = mt.speed_windows(t, v)
    assert [w.kind for w in wins] == ["ramp", "steady", "ramp", "steady", "ramp", "stopped"]
    bounds = [w.start for w in wins[1:]]
    assert bounds == pytest.approx([10, 30, 35, 50, 55], abs=0.7)
    assert wins[0].index.start == 0 and wins[-1].index.stop == t.size
    assert all(a.index.stop == b.index.start for a, b in zip(wins, wins[1:]))
    assert np.ptp(v[wins[1].index]) < 0.05


def test_band_energy():
    fs = 100.0
    t = np.arange(6000) / fs
    x = 3 + sine(t, 3.0, 2.0) + sine(t, 10.0, 1.0)  # variances 2 and 0.5
    shares = mt.band_energy(x, fs, {"shaft": (2.5, 3.5), "roller": (9.0, 11.0)})
    assert shares == pytest.approx({"shaft": 0.8, "roller": 0.2, "other": 0.0}, abs=1e-6)
