"""webline.diagnosis.orders: shaft angles from tachs, and harmonics that stay sharp when a roll shrinks."""
import numpy as np
import pytest

from webline.diagnosis import orders as od
from webline.diagnosis.spectra import amplitude_spectrum
from webline.diagnosis.synthetic import FPM, INCH, ewl_like, harmonics, pulse_train, roll_angle


@pytest.fixture(scope="module")
def ewl():
    return ewl_like()  # 60 s at 100 Hz; unwind drifts 7 % (1.00 -> 1.07 Hz), idle at 4.55 Hz


def phase_diff(a, b):
    """a - b wrapped to (-pi, pi]."""
    return np.angle(np.exp(1j * (np.asarray(a) - np.asarray(b))))


def wrapped_error(theta, truth):
    """theta - truth, with the whole turns between them removed."""
    e = theta - truth
    return e - 2 * np.pi * np.round(np.median(e) / (2 * np.pi))


def test_pulse_to_angle(ewl):
    rec, truth = ewl
    theta = od.angle_from_pulses(rec.time, rec["unwind_pulse"])
    err = wrapped_error(theta, truth["unwind"]["theta"])
    assert np.max(np.abs(err)) < 0.03  # edges quantised to 10 ms = 0.065 rad; the spline averages it out
    exact = wrapped_error(od.angle_from_pulses(rec.time, rec["unwind_pulse"], smooth=False),
                          truth["unwind"]["theta"])
    assert np.max(np.abs(exact)) < 0.15


def test_pulse_edges_sub_sample():
    t = np.arange(1000) * 1e-3
    x = np.clip((t - 0.3004) / 0.002, 0, 1)  # ramp crossing 0.5 at 0.3014 s
    assert od.pulse_edges(t, x)[0] == pytest.approx(0.3014, abs=1e-6)


def test_missed_pulse_is_an_error():
    t = np.arange(3000) * 0.01
    theta = 2 * np.pi * 1.0 * t
    x = pulse_train(theta)
    x[(t > 9.95) & (t < 10.5)] = 0.0  # the pulse at t = 10 s is lost
    with pytest.raises(ValueError, match="missed or extra pulse"):
        od.angle_from_pulses(t, x)
    with pytest.raises(ValueError, match="need at least 4"):
        od.angle_from_pulses(t[:250], x[:250])


def test_encoder_and_speed_angles(ewl):
    rec, truth = ewl
    th = truth["unwind"]["theta"]
    assert od.angle_from_encoder(np.mod(th, 2 * np.pi)) == pytest.approx(th - th[0] + np.mod(th[0], 2 * np.pi))
    omega = np.gradient(th, rec.time)
    assert wrapped_error(od.angle_from_speed(rec.time, omega, th[0]), th) == pytest.approx(0, abs=2e-3)
    theta, kind = od.shaft_angle(rec.time, rec["idle_speed"] / (2 * np.pi), "auto", "Hz")  # Hz = rev/s
    assert kind == "speed" and theta[-1] - theta[0] == pytest.approx(truth["idle"]["theta"][-1] - truth["idle"]["theta"][0])


def test_detect_tach_kind(ewl):
    rec, truth = ewl
    th = truth["unwind"]["theta"]
    assert od.detect_tach_kind(rec["unwind_pulse"]) == "pulse"
    assert od.detect_tach_kind(np.degrees(np.mod(th, 2 * np.pi)) - 180) == "angle"  # wrapped, no unit
    assert od.detect_tach_kind(th) == "angle"
    assert od.detect_tach_kind(rec["idle_speed"] + np.random.default_rng(0).normal(0, 0.1, th.size)) == "speed"
    assert od.detect_tach_kind(rec["unwind_pulse"], "rad/s") == "speed"  # a unit decides


def test_web_speed_is_not_a_shaft_speed(ewl):
    rec, _ = ewl
    with pytest.raises(ValueError, match="needs the roll radius"):
        od.shaft_angle(rec.time, np.full(rec.time.size, 1.0), "speed", "m/s")
    with pytest.raises(ValueError, match="unknown tach kind"):
        od.shaft_angle(rec.time, rec["idle_speed"], "laser")


def test_order_tracking_recovers_drifting_harmonics_where_fft_smears(ewl):
    rec, truth = ewl
    x = rec["tension"]
    theta_u = od.angle_from_pulses(rec.time, rec["unwind_pulse"])
    theta_i, _ = od.shaft_angle(rec.time, rec["idle_speed"], "speed", "rad/s")
    amp_u, ph_u = truth["unwind"]["amplitude"], truth["unwind"]["phase"]

    # plain FFT: the 3rd unwind harmonic sweeps 3.0 -> 3.2 Hz over 12 bins
    f, amp = amplitude_spectrum(x, rec.fs)
    fft_3 = amp[(f > 2.9) & (f < 3.3)].max()
    assert fft_3 < 0.7 * amp_u[2]

    # noise 0.5 N on 6000 samples: amplitude standard error 0.5 * sqrt(2 / 6000) = 0.009 N,
    # phase standard error 0.009 / A rad
    fits = od.joint_harmonic_fit(x, {"unwind": theta_u, "idle": theta_i}, 6)
    u, i = fits["unwind"], fits["idle"]
    assert u.amplitude[:3] == pytest.approx(amp_u, abs=0.03)
    assert phase_diff(u.phase[:3], ph_u) == pytest.approx(0, abs=0.04)
    assert np.all(u.amplitude[3:] < 0.03)
    # the idle angle integrated from 0 is the true one minus 0.4 rad: phases move by j * 0.4
    assert i.amplitude[:2] == pytest.approx(truth["idle"]["amplitude"], abs=0.03)
    assert phase_diff(i.phase[:2], truth["idle"]["phase"] + 0.4 * np.arange(1, 3)) == pytest.approx(0, abs=0.08)
    assert u.explained + i.explained == pytest.approx(1 - np.var(u.residual) / np.var(x - u.trend), abs=0.01)
    assert u.explained_per_order.sum() == pytest.approx(u.explained, rel=0.02)

    orders, oamp = od.order_spectrum(theta_u, x, max_order=8)
    at = [oamp[np.argmin(np.abs(orders - j))] for j in (1, 2, 3)]
    assert at == pytest.approx(amp_u, rel=0.03)


def test_harmonic_fit_single_shaft_with_trend():
    t = np.arange(4000) * 0.01
    theta = roll_angle(t, 1.0, 0.15, -2e-4)
    x = 50 + 0.2 * t + harmonics(theta, [1.0, 0.0, 0.5], [0.3, 0.0, -2.0])
    fit = od.harmonic_fit(x, theta, 4, trend=1)
    assert fit.amplitude == pytest.approx([1.0, 0.0, 0.5, 0.0], abs=1e-9)
    assert fit.phase[[0, 2]] == pytest.approx([0.3, -2.0])
    assert fit.trend == pytest.approx(50 + 0.2 * t) and fit.explained == pytest.approx(1.0)
    assert od.harmonic_energy(x, theta, 4, trend=1) == pytest.approx(1.0)


def test_refine_model_angle_with_radius_error(ewl):
    rec, truth = ewl
    x, t = rec["tension"], rec.time
    amp_u = truth["unwind"]["amplitude"]
    # the model's roll: radius 0.5 % too large, shrink rate 20 % too small - 4.7 rad behind after a minute
    theta_m = roll_angle(t, 200 * FPM, 6.375 * INCH * 1.005, -0.18e-3 * 0.8, theta0=-1.0)
    assert np.ptp(theta_m - truth["unwind"]["theta"]) > 4
    assert od.harmonic_fit(x, theta_m).amplitude[0] < 0.5 * amp_u[0]

    ref = od.refine_angle(x, theta_m)
    err = ref.theta - truth["unwind"]["theta"]
    assert np.ptp(err) < 0.15  # a constant offset is unobservable; the drift is gone
    assert ref.correction == pytest.approx(ref.theta - theta_m)
    assert 1.0 < ref.scale < 1.03
    fit = od.harmonic_fit(x, ref.theta)
    assert fit.amplitude[:3] == pytest.approx(amp_u, abs=0.03)
    # theta_ref = theta_true + err: psi_j = fitted phase + j err
    psi = fit.phase[:3] + np.arange(1, 4) * np.median(err)
    assert phase_diff(psi, truth["unwind"]["phase"]) == pytest.approx(0, abs=0.06)


def test_resample_to_angle_and_errors():
    t = np.arange(2000) * 0.005
    theta = -2 * np.pi * 1.3 * t  # turning backwards
    grid, xu = od.resample_to_angle(theta, np.sin(3 * theta), samples_per_rev=32)
    assert grid[1] - grid[0] == pytest.approx(-2 * np.pi / 32)
    assert xu == pytest.approx(np.sin(3 * grid), abs=1e-5)
    with pytest.raises(ValueError, match="not strictly monotonic"):
        od.resample_to_angle(np.r_[theta, theta[-1]], np.zeros(2001))


def test_shaft_frequency(ewl):
    rec, truth = ewl
    tm, f = od.shaft_frequency(rec.time, truth["unwind"]["theta"])
    R = 6.375 * INCH - 0.18e-3 * tm
    assert f == pytest.approx(200 * FPM / (2 * np.pi * R), rel=1e-3)
