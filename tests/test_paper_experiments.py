"""The paper's experiments (a)-(f) run through the master, and show the physics the paper reports.

Issue #3, item 4 ("tests assert the physics"). Every layout under scenarios/ runs; then:

* (c) out-of-round unwind at 100/200/300 ft/min: the first peak of the unwind load cell (lc9)
  is the roll's rotation frequency, {30}-{31}, within 2 %;
* (d) 200 ft/min at unwind radii 6.75/5.75/4.75 in: the unwind peak moves as 1/R, the peaks of
  the eccentric idlers, web-guide rollers and S-wrap leader stay;
* (a) 20 lbf tension step at zero speed: the load cell follows the step response of the
  linearised unwind zone under the PI design {24}/{25};
* (f) acceleration/deceleration: the speed master follows the ramps as its speed loop {24}
  predicts, and the controlled tensions stay within the linear model's prediction and return
  to their reference.

The predictions are computed here from first principles (layout parameters, the paper's
equations), never fitted to the simulation. Each scenario is simulated once per module (the
``sim`` fixture), the spectral ones at shortened durations that still resolve the 2 %
checks, so the file stays within minutes on a shared machine even with a slow master (about
45 s with the 3 ms extrapolated coupling).
"""
import math
from pathlib import Path

import numpy as np
import pytest
import scipy.optimize
import scipy.signal
import yaml

from webline.diagnosis.orders import harmonic_fit, joint_harmonic_fit
from webline.diagnosis.spectra import amplitude_spectrum, frequency_resolution, interpolate_peak, spectral_peaks
from webline.orchestrator.layout import load_system
from webline.orchestrator.master import simulate

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS_DIR = ROOT / "scenarios"
LBF = 4.4482216152605  # N
FPM = 0.3048 / 60.0  # m/s
INCH = 0.0254  # m


def _is_layout(path):
    """Layout files (not sweep definitions, which name a ``layout`` to run)."""
    data = yaml.safe_load(path.read_text())
    return isinstance(data, dict) and "layout" not in data


SCENARIOS = sorted(p for p in SCENARIOS_DIR.rglob("*.yaml") if _is_layout(p))

# Durations of the runs the physics tests analyse (s). Spectral windows start at STEADY:
# every run starts in its operating point, but the eccentricities switch on at t = 0 and
# kick the unwind tension loop's lightly damped mode (0.9 Hz, see (a)), which sits next to
# the 1 Hz fundamentals; by 4 s it has decayed enough not to pull them.
STEADY = 4.0
C_DURATION = {100: 14.0, 200: 12.0, 300: 12.0}  # windows 10, 8, 8 s: 5, 8, 12 revolutions
D_DURATION = 14.0  # 10 s windows
A_DURATION = 12.0  # the step at 2 s; the linear model settles to 1 % in 9.5 s
F_DURATION = 30.0  # the scenario as written: the last ramp ends at 25 s
LONG_RUNS = {
    **{f"paper/c_out_of_round_{v}fpm.yaml": d for v, d in C_DURATION.items()},
    **{f"paper/d_unwind_radius_{r}in.yaml": D_DURATION for r in ("6_75", "5_75", "4_75")},
    "paper/a_tension_step_zero_speed.yaml": A_DURATION,
    "paper/f_accel_decel.yaml": F_DURATION,
}
SMOKE_DURATION = 1.0


def _key(path):
    return Path(path).relative_to(SCENARIOS_DIR).as_posix()


@pytest.fixture(scope="module")
def sim(fmus):
    """sim(name) -> (System, Result) of scenarios/<name>, run once per module at its duration
    (LONG_RUNS, else SMOKE_DURATION)."""
    cache = {}

    def run(name):
        if name not in cache:
            duration = LONG_RUNS.get(name, SMOKE_DURATION)
            system = load_system(SCENARIOS_DIR / name, {"experiment.duration": f"{duration} s"})
            cache[name] = system, simulate(system, fmus, progress=False)
        return cache[name]

    return run


def _window(r, t0, t1=None):
    return (r.time >= t0 - 1e-9) & (r.time <= (r.time[-1] if t1 is None else t1) + 1e-9)


def _fs(r):
    return 1.0 / float(np.median(np.diff(r.time)))


# ---- 1. every scenario validates and runs -----------------------------------------------------

def test_scenarios_found():
    keys = {_key(p) for p in SCENARIOS}
    assert set(LONG_RUNS) <= keys
    assert "sweep_unwind_radius_speed.yaml" not in keys  # a sweep definition, not a layout
    assert len(keys) >= 13


@pytest.mark.parametrize("path", SCENARIOS, ids=_key)
def test_scenario_runs_through_the_master(sim, path):
    """Validates, runs (1 s, or the longer run the physics tests below use), tensions finite and
    the web taut everywhere."""
    system, r = sim(_key(path))
    assert r.status == "ok", r.message
    duration = LONG_RUNS.get(_key(path), SMOKE_DURATION)
    assert duration <= r.time[-1] < duration + system.experiment.step + 1e-9  # the whole run
    tensions = [c for c in r.columns if c.endswith(".T")]
    spans = {s["component"] for s in system.meta["spans"]}
    assert {f"{s}.T" for s in spans} <= set(tensions)
    for c in tensions:
        assert np.all(np.isfinite(r[c])), c
        assert r[c].min() > 0.0, c  # never slack


# ---- spectral helpers ---------------------------------------------------------------------

def _peaks(x, fs, fmax=12.0):
    f, amp = amplitude_spectrum(x, fs)
    return spectral_peaks(f, amp, fmax=fmax), frequency_resolution(len(x), fs)


def first_peak(x, fs, min_share=0.02, fmax=12.0):
    """Lowest-frequency peak of ``x`` (Hann spectrum, local maximum, Gaussian-interpolated)
    among those with at least ``min_share`` of the strongest peak's amplitude, above the DC
    main lobe. The records are free of noise and dense with harmonics (a bin every 0.1 Hz,
    harmonics every 0.5 Hz at 100 ft/min), so a median noise floor would sit on the
    harmonics' skirts; the share is the criterion instead. It skips the residue of the start
    transient of the tension loop's 0.9 Hz mode and the fundamental's leakage (0.4 % of the
    strongest peak at 300 ft/min in an 8 s window, where it lies below the fundamental; 1.4 %
    in 5 s); the weakest fundamental here (100 ft/min, where 2f dominates) has 7 %.
    Returns (frequency, resolution)."""
    f, amp = amplitude_spectrum(x, fs)
    idx, _ = scipy.signal.find_peaks(amp)
    idx = idx[(f[idx] >= 2 * f[1]) & (f[idx] <= fmax)]
    idx = idx[amp[idx] >= min_share * amp[idx].max()]
    return interpolate_peak(f, amp, int(idx.min()))[0], frequency_resolution(len(x), fs)


def peak_near(peaks, f, tol):
    """(frequency, amplitude) of the strongest peak within ``tol`` of ``f``, or None."""
    near = np.abs(peaks.frequency - f) <= tol
    if not near.any():
        return None
    k = np.flatnonzero(near)[np.argmax(peaks.amplitude[near])]
    return float(peaks.frequency[k]), float(peaks.amplitude[k])


def test_peak_estimator_is_accurate_for_these_windows():
    """The estimator (Hann, Gaussian interpolation) on a synthetic load-cell signal like the
    100 ft/min one in a 10 s window: 5 revolutions, 2f dominant, a drift, the decaying 0.9 Hz
    loop mode and the 9.5 Hz idler mode. A bin is 0.1 Hz (20 % of f), the interpolated peak is
    good to far better than the 2 % asserted."""
    for fs in (1000.0, 1000.0 / 3.0):  # records at 1 ms and 3 ms macro steps
        t = np.arange(0.0, 10.0, 1.0 / fs)
        for f0 in (0.4962, 0.9965, 1.4977):
            x = 66.7 + 0.05 * t + 0.004 * np.exp(-0.6 * (t + 4)) * np.sin(2 * np.pi * 0.91 * t)
            x += 0.02 * np.sin(2 * np.pi * 9.46 * t)
            for j, a in enumerate((0.33, 4.3, 0.45, 0.43, 0.15, 0.19), start=1):
                x = x + a * np.sin(2 * np.pi * j * f0 * t + 0.7 * j)
            f1, _ = first_peak(x, fs)
            assert f1 == pytest.approx(f0, rel=3e-3), (fs, f0)


# ---- 2. (c) out-of-round unwind at 100, 200, 300 ft/min ---------------------------------------

@pytest.mark.parametrize("speed", [100, 200, 300])
def test_c_first_peak_is_the_unwind_rotation(sim, speed):
    """{30}-{31}: f = v/(2 pi R). The unwind turns with the *unstretched* web (mass conservation
    {21} through the zone: v_unwind = v (1 - T/EA), paper-notes), so the roll's rotation is
    f_rot = v (1 - T_ref/EA)/(2 pi R), 1.15 % below the nominal v/(2 pi R) at 15 lbf.

    Asserted within 2 %: the first lc9 peak against (1) f_rot from first principles, (2) the
    simulated mean(unwind.omega)/(2 pi), and (3) the nominal {30} v/(2 pi R). All three hold; (3)
    only because the strain (1.15 %) is below 2 %: it carries that systematic offset, (1) and (2)
    agree with the peak to a few 0.1 % and with each other to 0.1 %.
    v: the run's line speed; R: the mean unwind radius over the analysis window (the roll
    shrinks by t_w per revolution, {5})."""
    system, r = sim(f"paper/c_out_of_round_{speed}fpm.yaml")
    assert r.ok, r.message
    m = _window(r, STEADY)
    f1, res = first_peak(r["lc9.T"][m], _fs(r))
    v = speed * FPM
    assert r["line_speed.y"][m] == pytest.approx(v)
    R = float(np.mean(r["unwind.R"][m]))
    EA = system.meta["web"]["EA"]
    T_ref = 15.0 * LBF
    assert r["unwind_zone_T_ref.y"][m] == pytest.approx(T_ref)
    f_nominal = v / (2 * math.pi * R)
    f_rot = v * (1.0 - T_ref / EA) / (2 * math.pi * R)
    f_omega = float(np.mean(r["unwind.omega"][m])) / (2 * math.pi)
    assert f_omega == pytest.approx(f_rot, rel=2e-3)  # the roll does turn with the unstretched web
    assert f1 == pytest.approx(f_rot, rel=0.02), (f1, f_rot, res)
    assert f1 == pytest.approx(f_omega, rel=0.02), (f1, f_omega, res)
    assert f1 == pytest.approx(f_nominal, rel=0.02), (f1, f_nominal, res)
    assert R == pytest.approx(6.375 * INCH, rel=0.02)  # the scenario's roll, a little unwound


# ---- 3. (d) unwind radius 6.75, 5.75, 4.75 in at 200 ft/min -----------------------------------

RADII = ("6_75", "5_75", "4_75")


@pytest.fixture(scope="module")
def d_runs(sim):
    """Per radius: the lc9 window, the unwind's angle, radius and speed over it, and the peaks."""
    out = {}
    for rad in RADII:
        system, r = sim(f"paper/d_unwind_radius_{rad}in.yaml")
        assert r.ok, r.message
        m = _window(r, STEADY)
        x, fs = r["lc9.T"][m], _fs(r)
        v = float(np.mean(r["line_speed.y"][m]))
        R = float(np.mean(r["unwind.R"][m]))
        EA = system.meta["web"]["EA"]
        T_ref = float(np.mean(r["unwind_zone_T_ref.y"][m]))
        raw, res = _peaks(x, fs)
        # the unwind's own harmonics removed: least squares against its angle (order tracking)
        fit = harmonic_fit(x, r["unwind.theta"][m], 12, trend=2)
        residual, _ = _peaks(fit.residual, fs)
        joint = joint_harmonic_fit(x, {"unwind": r["unwind.theta"][m], "sw": r["sw_leader.theta"][m]},
                                   {"unwind": 12, "sw": 1}, trend=2)
        out[rad] = dict(system=system, v=v, R=R, res=res, raw=raw, residual=residual, joint=joint, x=x, fs=fs,
                        f_rot=v * (1.0 - T_ref / EA) / (2 * math.pi * R),
                        f_omega=float(np.mean(r["unwind.omega"][m])) / (2 * math.pi))
    return out


def test_d_unwind_peak_moves_as_one_over_R(d_runs):
    """Fig. 9-10(a): the unwind fundamental (lc9 peak next to its rotation frequency, within the
    resolution) is the rotation frequency within 2 %, and the ratios of the three peaks are the
    ratios of 1/R within 2 % (R: mean radius over each window; it shrinks about 2 mm during the
    4.75 in run, so the nominal radii would be off by up to 2 %)."""
    f = {}
    for rad, d in d_runs.items():
        hit = peak_near(d["raw"], d["f_rot"], d["res"])
        assert hit is not None, (rad, d["f_rot"], d["raw"].frequency)
        f[rad] = hit[0]
        assert f[rad] == pytest.approx(d["f_rot"], rel=0.02), rad
        assert f[rad] == pytest.approx(d["f_omega"], rel=0.02), rad
        assert d["R"] == pytest.approx(float(rad.replace("_", ".")) * INCH, rel=0.02)
    for a, b in (("6_75", "5_75"), ("5_75", "4_75"), ("6_75", "4_75")):
        assert f[b] / f[a] == pytest.approx(d_runs[a]["R"] / d_runs[b]["R"], rel=0.02), (a, b)


@pytest.mark.parametrize("element", ["idler_u1", "guide_in"])
def test_d_roller_peaks_stay(d_runs, element):
    """Fig. 10(c)-(d): the eccentric 1.5 in idlers (4.24 Hz at 200 ft/min) and 1.1 in web-guide
    rollers (5.79 Hz) give peaks at v/(2 pi R_roller) that do not move with the unwind radius.
    Found in the lc9 spectrum once the unwind's own harmonics (orders 1-12, locked to its angle)
    are removed: its 4th/5th harmonics pass within 0.2 Hz of the idler frequency. Amplitudes
    ~0.06 N (idlers, C = 0.02 mm) and ~0.08 N (guide, 0.03 mm), significant above the noise
    floor (diagnosis.spectra.spectral_peaks). The unwind's peak moves by 0.17-0.24 Hz from one
    radius to the next; these stay within a quarter of the resolution."""
    found = []
    for rad, d in d_runs.items():
        R_el = d["system"].meta["elements"][element]["radius"]
        f_el = d["v"] / (2 * math.pi * R_el)
        hit = peak_near(d["residual"], f_el, d["res"])
        assert hit is not None, (rad, f_el, d["residual"].frequency)
        found.append(hit[0])
        assert hit[0] == pytest.approx(f_el, abs=d["res"] / 2)
    assert max(found) - min(found) < d_runs["6_75"]["res"] / 4, found  # same peak in all three


def test_d_s_wrap_disturbance_stays(d_runs):
    """Fig. 10(b): the eccentric S-wrap leader (6.05 in, the speed master: f = v/(2 pi R) =
    1.052 Hz exactly) disturbs lc9 at a frequency that does not depend on the unwind radius.

    In these records its peak cannot be told from the unwind fundamental by a plain spectrum:
    at 5.75 in the unwind turns at 1.107 Hz, 0.055 Hz away, and two tones that close need a
    Hann window of >= 2/0.055 = 36 s (the scenario itself runs 20 s; at 6.75 in, 0.11 Hz away,
    18 s; at 4.75 in, 0.3 Hz, 10 s is on the edge). Removing the unwind's harmonics alone (as
    for the rollers) takes part of the S-wrap tone with them and leaves the start transient of
    the 0.9 Hz tension-loop mode, which a round S-wrap also shows there (0.025 N at 1.0 Hz,
    checked once with path.sw_leader.eccentricity = null).
    So the unwind's harmonics are fitted *jointly* with the component locked to the leader's
    angle (diagnosis.orders.joint_harmonic_fit: neither takes the other's share) and removed;
    asserted:

    * the S-wrap component is there at every radius with the same amplitude (same disturbance,
      same closed loop, same frequency), 0.16-0.18 N; a round S-wrap gives 0.006 N in the same
      fit;
    * lc9 without the unwind's harmonics has a peak there (0.17 N; 0.026 N with a round
      S-wrap), the same in all three runs.
    """
    amp, found = {}, []
    for rad, d in d_runs.items():
        el = d["system"].meta["elements"]["sw_leader"]
        assert el["eccentric"]
        f_sw = d["v"] / (2 * math.pi * el["radius"])
        assert f_sw == pytest.approx(200 * FPM / (2 * math.pi * 6.05 * INCH), rel=1e-6)
        amp[rad] = float(d["joint"]["sw"].amplitude[0])
        x = d["x"] - d["joint"]["unwind"].component
        peaks, _ = _peaks(x, d["fs"])
        hit = peak_near(peaks, f_sw, d["res"] / 2)
        assert hit is not None, (rad, f_sw, peaks.frequency)
        assert hit[1] > 0.08, (rad, hit)  # round S-wrap: 0.026 N (the loop's start transient)
        found.append(hit[0])
    assert min(amp.values()) > 0.08, amp
    mean = np.mean(list(amp.values()))
    for a in amp.values():
        assert a == pytest.approx(mean, rel=0.25), amp
    assert max(found) - min(found) < d_runs["6_75"]["res"] / 4, found


# ---- 4. (a) tension step at zero speed: the PI design --------------------------------------------

def zone_model(system, loop):
    """Linear model of a tension zone at zero speed, inputs [T_ref (N), line speed (m/s)], output
    the load-cell reading (N). States [v_c, I_c, v_o, I_o, T, I_t, T_f].

    * Speed loops {24} with feed-forward: the feed-forward R (T_in - T_out) + b omega cancels the
      web and friction torques, and K_p = J K_ref, so each driven end follows its reference
      r + trim as v' = K_ref (r + trim - v + w_ld I), I' = r + trim - v (surface speeds; closed
      loop K_ref (s + w_ld)/(s^2 + K_ref s + K_ref w_ld), damping ratio zeta). ``c``: the end with
      the tension loop; ``o``: the other end (speed only); r = ratio * line speed.
    * Tension PI {25}: trim = sign K (e + w_i I_t), e = T_ref - T_f (K in m/(s N): 2 (ft/min)/lbf).
    * The zone as one spring: with light idle rollers all its spans carry one tension T, and
      {21} summed over its spans is L_zone T' = v_down (EA - T) - v_up (EA - T_in) with T_in = 0
      at the unwind: T' = (EA/L_zone)(v_down - v_up) at zero speed (to 2 % at 25 lbf).
    * Load cell: first-order filter tau_f.
    """
    c = {x.name: x for x in system.components}
    meta = system.meta
    z = next(z for z in meta["zones"] if z["tension_loop"] == loop)
    L = sum(s["length"] for s in meta["spans"] if s["component"] in z["spans"])
    EA = meta["web"]["EA"]
    tp = c[z["tension_pi"]].parameters
    ctrl = z["controlled_by"]
    other = z["down"] if ctrl == z["up"] else z["up"]
    ratio = meta["operating_point"]["ratio"]
    ends = {}
    for role, e in (("c", ctrl), ("o", other)):
        p = c[meta["elements"][e]["speed_pi"]].parameters
        assert p["feedforward"] == 1.0
        ends[role] = (p["K_ref"], p["w_ld"], ratio[meta["elements"][e]["index"]])
    tau_f = c[z["load_cell"]].parameters["tau_filter"]
    (Kc, wc, rc), (Ko, wo, ro) = ends["c"], ends["o"]
    sK, wi = tp["sign"] * tp["K"], tp["w_i"]
    A, B = np.zeros((7, 7)), np.zeros((7, 2))
    for row, g in ((0, Kc), (1, 1.0)):  # the trim enters the controlled end's reference
        A[row, 6] -= g * sK
        A[row, 5] += g * sK * wi
        B[row, 0] += g * sK
    A[0, 0], A[0, 1], B[0, 1] = -Kc, Kc * wc, Kc * rc
    A[1, 0], B[1, 1] = -1.0, rc
    A[2, 2], A[2, 3], B[2, 1] = -Ko, Ko * wo, Ko * ro
    A[3, 2], B[3, 1] = -1.0, ro
    up, down = (0, 2) if ctrl == z["up"] else (2, 0)
    A[4, down] += EA / L
    A[4, up] -= EA / L
    A[5, 6], B[5, 0] = -1.0, 1.0
    A[6, 4], A[6, 6] = 1.0 / tau_f, -1.0 / tau_f
    C = np.zeros((1, 7))
    C[0, 6] = 1.0
    return scipy.signal.StateSpace(A, B, C, np.zeros((1, 2))), dict(L=L, EA=EA, K=tp["K"], w_i=wi, Kc=Kc, wc=wc)


def predict(system, r, loop):
    """The zone model driven by the run's recorded references, from the operating point."""
    model, _ = zone_model(system, loop)
    z = next(z for z in system.meta["zones"] if z["tension_loop"] == loop)
    T0 = float(r[f"{z['T_ref']}.y"][0])
    u = np.column_stack([r[f"{z['T_ref']}.y"], r["line_speed.y"]])
    _, y, _ = scipy.signal.lsim(model, u, r.time, X0=[0, 0, 0, 0, T0, 0, T0])
    return y


def _lowpass(x, fs, fc=3.0):
    """Zero-phase low-pass: keeps the tension loop (< 1 Hz) and drops the lightly damped idler
    mode at 9.5 Hz that the step excites (damping ratio 0.002, spans have no material damping)."""
    b, a = scipy.signal.butter(4, fc, fs=fs)
    return scipy.signal.filtfilt(b, a, x)


def _ringing(t, e):
    """Decay rate (1/s) and frequency (Hz) of the dominant mode of an error signal e(t):
    least-squares fit of A exp(-s t) cos(w t + p) + B exp(-q t)."""
    def f(t, A, s, w, p, B, q):
        return A * np.exp(-s * t) * np.cos(w * t + p) + B * np.exp(-q * t)

    c, _ = scipy.optimize.curve_fit(f, t, e, p0=[e[0], 0.5, 5.7, 0.0, 0.0, 3.4], maxfev=20000)
    return c[1], c[2] / (2 * math.pi)


@pytest.fixture(scope="module")
def a_run(sim):
    system, r = sim("paper/a_tension_step_zero_speed.yaml")
    assert r.ok, r.message
    return system, r, predict(system, r, "unwind_zone")


def test_a_linear_model_is_the_pi_design(a_run):
    """The closed loop of the PI design at zero speed, from the layout: loop gain
    (EA/L_zone) K = 5791 N / 5.3 m * 2 (ft/min)/lbf = 2.50 1/s; crossover 0.90 Hz with 9 deg of
    phase margin; a pole pair at -0.48 +- 5.68j (0.90 Hz, damping ratio 0.084): an 85 % overshoot.
    The paper's gains on this line's (guessed) zone stiffness give a lightly damped loop."""
    system, _, _ = a_run
    model, p = zone_model(system, "unwind_zone")
    assert p["EA"] / p["L"] * p["K"] == pytest.approx(5791.2 / 5.3 * 2 * FPM / LBF, rel=1e-3)
    poles = np.linalg.eigvals(model.A)
    osc = poles[np.argmax(np.abs(poles.imag))]
    assert all(poles.real < 0)
    assert abs(osc.imag) / (2 * math.pi) == pytest.approx(0.90, abs=0.02)
    assert -osc.real / abs(osc) == pytest.approx(0.084, abs=0.005)


def test_a_tension_step_follows_the_pi_design(a_run):
    """Fig. 5(a), 5 -> 25 lbf at 2 s, line at rest: the load cell against the linear prediction.

    Prediction (zone_model): first peak 42.06 lbf 0.544 s after the step (85 % overshoot),
    ringing at 0.904 Hz decaying at 0.48 1/s, 2 % settling 8.3 s, 1 % 9.5 s after the step.
    Simulated at the scenario's step (2 ms, Gauss-Seidel, extrapolated coupling): 42.11 lbf at
    0.534 s (1 ms with held inputs gave the 41.7 lbf, ~1 Hz a colleague measured), ringing at
    0.911 Hz, but decaying at 0.54 1/s, 14 % faster. That is the co-simulation's coupling
    error, not physics: the monolithic reference (orchestrator.reference, LSODA) rings at
    0.910 Hz decaying at 0.486 1/s with a 42.55 lbf peak, like the linear model with the idlers'
    inertia kept (0.910 Hz, 0.486 1/s, 42.52 lbf); the co-simulation converges to it with the
    step (decay 0.58 / 0.51 / 0.50 1/s, largest gap 1.5 / 0.46 / 0.23 lbf at 3 / 1 / 0.5 ms
    extrapolated; 0.81 / 0.60 / 0.54 1/s, 4.8 / 1.75 / 0.92 lbf with held inputs). Hence the
    decay rate is asserted from 0.95 to 1.4 times the prediction (no slower than designed), the
    rest as the PI design predicts to 10 %."""
    system, r, pred = a_run
    t, fs = r.time, _fs(r)
    y = r["lc9.T"] / LBF
    yp = pred / LBF
    step_t, T0, T1 = 2.0, 5.0, 25.0
    assert y[t < step_t] == pytest.approx(T0, abs=1e-6)  # starts in equilibrium
    after = t >= step_t
    ta = t[after] - step_t

    def first_peak_of(x):
        k = np.argmax(np.where(ta < 1.5, x[after], -np.inf))
        return x[after][k], ta[k]

    peak, t_peak = first_peak_of(y)
    peak_p, t_peak_p = first_peak_of(yp)
    assert peak_p == pytest.approx(42.06, abs=0.05)  # the design's own number, documented above
    assert (peak - T1) == pytest.approx(peak_p - T1, rel=0.10)  # overshoot
    assert t_peak == pytest.approx(t_peak_p, rel=0.10)  # first-peak time

    # ringing: frequency and decay of the dominant mode (idler mode filtered out)
    e = _lowpass(y, fs)[after] - T1
    ep = yp[after] - T1
    fit = ta >= 0.3
    s, f = _ringing(ta[fit], e[fit])
    s_p, f_p = _ringing(ta[fit], ep[fit])
    assert f_p == pytest.approx(0.904, abs=0.005)
    assert f == pytest.approx(f_p, rel=0.05)
    assert s_p * 0.95 <= s <= s_p * 1.4, (s, s_p)

    # settling into +-2 % of the step within the predicted time; final value within 1 %
    def settling(x):
        out = np.abs(x - T1) > 0.02 * (T1 - T0)
        return ta[np.flatnonzero(out)[-1]] if out.any() else 0.0

    ts, ts_p = settling(_lowpass(y, fs)[after]), settling(yp[after])
    assert ts_p == pytest.approx(8.3, abs=0.2)
    assert ts <= ts_p * 1.05, (ts, ts_p)
    last = t >= t[-1] - 1.0
    assert np.mean(y[last]) == pytest.approx(T1, rel=0.01)
    assert np.mean(yp[last]) == pytest.approx(T1, rel=0.01)
    # the whole transient (both through the same low-pass): within 10 % of the step of the
    # prediction (the co-simulation's extra damping, see above: 1.2 lbf at 2 ms, 1.5 at 3 ms)
    assert np.max(np.abs(_lowpass(y, fs) - _lowpass(yp, fs))[after]) < 0.10 * (T1 - T0)


# ---- 5. (f) acceleration and deceleration ----------------------------------------------------------

@pytest.fixture(scope="module")
def f_run(sim):
    system, r = sim("paper/f_accel_decel.yaml")
    assert r.ok, r.message
    return system, r


def test_f_line_speed_follows_the_ramps(f_run):
    """0 -> 300 ft/min at 30 (ft/min)/s, hold, -> 50 ft/min in 8 s (31.25 (ft/min)/s). The speed
    master's loop {24} is type 2 (PI on an integrator, feed-forward cancelling the web): no
    error on a steady ramp, a transient at each kink of a * h(t), h the impulse response of
    1/(s^2 + K_ref s + K_ref w_ld): at most 0.038 s * 31.25 (ft/min)/s = 1.19 ft/min."""
    system, r = f_run
    master = system.meta["master"]
    c = {x.name: x for x in system.components}[f"{master}_speed_pi"].parameters
    K, w = c["K_ref"], c["w_ld"]
    error_tf = scipy.signal.lti([1.0, 0.0, 0.0], [1.0, K, K * w])  # 1 - closed loop
    _, e_pred, _ = scipy.signal.lsim(error_tf, r["line_speed.y"], r.time)
    e = r[f"{master}.v"] - r["line_speed.y"]
    pred_max = np.max(np.abs(e_pred)) / FPM
    assert pred_max == pytest.approx(1.19, abs=0.02)
    assert np.max(np.abs(e)) / FPM == pytest.approx(pred_max, rel=0.15)
    ls = r["line_speed.y"] / FPM
    assert ls.max() == pytest.approx(300.0) and ls[-1] == pytest.approx(50.0)
    assert r[f"{master}.v"][-1] / FPM == pytest.approx(50.0, abs=0.05)


@pytest.mark.parametrize("loop,cell", [("unwind_zone", "lc9"), ("rewind_zone", "lc19")])
def test_f_tension_stays_within_the_linear_bound(f_run, loop, cell):
    """The ramps disturb each controlled zone through the speed loops' transient tracking errors
    (unwind K_ref 15, S-wrap 20; pull roll 40, rewind 15): their difference stretches the zone.
    The zone model (the one of (a), driven by the recorded line speed and references) predicts
    the deviation: 0.14 lbf (unwind zone) and 0.36 lbf (rewind zone, a 1.4 Hz loop with damping
    ratio 0.06). Asserted: the simulated deviation stays within 1.25 x that bound, reaches at
    least half of it (the effect is there), and after the last ramp (25 s) it decays like the
    prediction and is back at the reference (within 0.05 lbf) no later than predicted. The
    transport term v T/L (0.3 1/s at 300 ft/min) is not in the zero-speed model; it only adds
    damping."""
    system, r = f_run
    z = next(z for z in system.meta["zones"] if z["tension_loop"] == loop)
    T_ref = r[f"{z['T_ref']}.y"]
    assert T_ref == pytest.approx(15 * LBF)
    dev = (_lowpass(r[f"{cell}.T"], _fs(r), fc=5.0) - T_ref) / LBF
    dev_p = (predict(system, r, loop) - T_ref) / LBF
    bound = np.max(np.abs(dev_p))
    assert bound == pytest.approx({"lc9": 0.14, "lc19": 0.36}[cell], abs=0.02)
    assert np.max(np.abs(dev)) <= 1.25 * bound
    assert np.max(np.abs(dev)) >= 0.5 * bound
    # after the last ramp (25 s): decays like the prediction, second by second, and is back
    # within 0.05 lbf (0.3 % of the reference) no later than the prediction
    t = r.time
    for a in range(25, int(round(t[-1]))):
        m = (t >= a) & (t < a + 1)
        assert np.max(np.abs(dev[m])) <= 1.25 * np.max(np.abs(dev_p[m])) + 0.01, a

    def back(x, band=0.05):
        out = (t >= 25.0) & (np.abs(x) > band)
        return t[np.flatnonzero(out)[-1]] if out.any() else 25.0

    assert back(dev_p) < t[-1] - 0.5  # the prediction is back before the end of the run
    assert back(dev) <= back(dev_p) + 0.1
