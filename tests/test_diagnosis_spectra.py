"""webline.diagnosis.spectra: calibrated spectra, significant peaks only, and tags to shaft families."""
import numpy as np
import pytest

from webline.diagnosis import spectra as sp
from webline.diagnosis.orders import shaft_frequency
from webline.diagnosis.synthetic import ewl_like


def tone(t, f, a, p=0.0):
    return a * np.sin(2 * np.pi * f * t + p)


def test_amplitude_is_calibrated_on_and_between_bins():
    fs, n = 100.0, 6000
    t = np.arange(n) / fs
    f, amp = sp.amplitude_spectrum(tone(t, 5.0, 3.0) + tone(t, 12.3456, 1.0) + 40.0, fs)
    assert amp[np.argmin(np.abs(f - 5.0))] == pytest.approx(3.0, rel=1e-6)
    peaks = sp.spectral_peaks(f, amp)
    assert peaks.frequency == pytest.approx([5.0, 12.3456], abs=2e-3)
    assert peaks.amplitude == pytest.approx([3.0, 1.0], rel=0.02)  # off-bin: scalloping corrected
    assert sp.frequency_resolution(n, fs) == pytest.approx(2 / 60)


def test_noise_alone_gives_no_significant_peak():
    for seed in range(10):
        for n in (1000, 6000):
            x = np.random.default_rng(seed).normal(0.0, 1.0, n) + 5.0
            f, amp = sp.amplitude_spectrum(x, 100.0)
            assert len(sp.spectral_peaks(f, amp, alpha=0.01).frequency) == 0, (seed, n)


def test_weak_tone_in_noise_is_found_and_floor_is_median_based():
    fs, n = 100.0, 6000
    t = np.arange(n) / fs
    x = np.random.default_rng(3).normal(0.0, 1.0, n) + tone(t, 7.0, 0.25)
    f, amp = sp.amplitude_spectrum(x, fs)
    peaks = sp.spectral_peaks(f, amp)
    assert peaks.frequency == pytest.approx([7.0], abs=0.02) and peaks.snr[0] > 5
    # Hann-windowed white noise of std 1: Rayleigh median sqrt(2 ln 2) * sqrt(2 * 1.5 / n) per bin
    assert np.median(sp.noise_floor(amp)) == pytest.approx(np.sqrt(2 * np.log(2)) * np.sqrt(3.0 / n), rel=0.1)
    assert sp.significance_factor(3000, 0.01) == pytest.approx(np.sqrt(np.log2(3e5)))


def test_clean_signal_side_lobes_are_not_peaks():
    fs, n = 100.0, 6000
    t = np.arange(n) / fs
    x = tone(t, 3.1234, 5.0) + tone(t, 20.0, 0.01) + np.random.default_rng(0).normal(0.0, 1e-6, n)
    f, amp = sp.amplitude_spectrum(x, fs)
    peaks = sp.spectral_peaks(f, amp)
    assert peaks.frequency == pytest.approx([3.1234, 20.0], abs=2e-3)


def test_ewl_peaks_tagged_to_shafts():
    rec, truth = ewl_like()
    f, amp = sp.amplitude_spectrum(rec["tension"], rec.fs)
    peaks = sp.spectral_peaks(f, amp)
    fams = {name: shaft_frequency(rec.time, truth[name]["theta"])[1] for name in ("unwind", "idle")}
    tags = sp.tag_peaks(peaks.frequency, fams, sp.frequency_resolution(len(f) * 2 - 2, rec.fs), max_harmonic=6)
    got = {(tg.family, tg.harmonic) for tg in tags if tg.status == "tagged"}
    assert got == {("unwind", 1), ("unwind", 2), ("unwind", 3), ("idle", 1), ("idle", 2)}
    assert all(tg.status == "tagged" for tg in tags)
    unwind = sp.family(fams["unwind"])
    assert unwind.mean == pytest.approx(1.034, abs=2e-3) and unwind.spread == pytest.approx(0.034, abs=3e-3)


def test_two_shafts_within_resolution_are_ambiguous_and_separate_in_a_longer_record():
    fs = 20.0
    fams = {"s_wrap": 1.050, "lead": 1.060}
    for duration, expect in ((60.0, "ambiguous"), (600.0, "tagged")):
        t = np.arange(int(duration * fs)) / fs
        x = tone(t, 1.050, 1.0) + tone(t, 1.060, 0.8, 1.0) + np.random.default_rng(1).normal(0, 0.05, t.size)
        f, amp = sp.amplitude_spectrum(x, fs)
        peaks = sp.spectral_peaks(f, amp)
        res = sp.frequency_resolution(t.size, fs)
        tags = sp.tag_peaks(peaks.frequency, fams, res)
        near = [tg for tg in tags if abs(tg.frequency - 1.055) < 0.02]
        if expect == "ambiguous":  # 0.010 Hz apart, resolution 0.033 Hz
            assert len(near) == 1 and near[0].status == "ambiguous" and near[0].family is None
            assert {c[0] for c in near[0].candidates} == {"s_wrap", "lead"}
        else:  # resolution 0.0033 Hz
            assert sorted((tg.family, tg.status) for tg in near) == [("lead", "tagged"), ("s_wrap", "tagged")]


def test_tag_rules():
    fams = {"a": 1.0, "b": sp.Family(3.51, 0.1)}  # b's speed varies: harmonic j spreads by j * 0.1
    tags = sp.tag_peaks([2.0, 3.45, 7.005, 9.5], fams, 0.01, max_harmonic=8)
    assert [tg.status for tg in tags] == ["tagged", "tagged", "ambiguous", "untagged"]
    assert (tags[0].family, tags[0].harmonic) == ("a", 2)
    assert (tags[1].family, tags[1].harmonic) == ("b", 1)  # 0.06 off, within 0.01 + 0.1
    assert tags[2].candidates == (("a", 7), ("b", 2))  # nearest first
    assert tags[3].candidates == ()  # a x9 is above max_harmonic


def test_family_from_array():
    assert sp.family(np.linspace(1.0, 1.1, 50)) == pytest.approx((1.05, 0.05))
    assert sp.family(2.0) == (2.0, 0.0)
