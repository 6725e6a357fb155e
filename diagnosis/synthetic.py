"""Synthetic tension records with known answers, for tests and demonstrations.

A shaft's angle is built from first principles (web speed over radius), its
harmonics are ``A_j sin(j theta + psi_j)`` ({27}-{28}), and a measured tension
is their sum on a mean, plus white noise. :func:`ewl_like` assembles the
paper's situation: an unwind at 200 ft/min whose radius shrinks (its frequency
drifts several percent), an idle roller at a fixed frequency, a once-per-rev
pulse on the unwind and a speed signal on the idle roller.
"""
import numpy as np

from webline.diagnosis.data import Record

FPM = 0.00508  # m/s per ft/min
INCH = 0.0254  # m


def roll_angle(t, v, R0, dR_dt=0.0, theta0=0.0):
    """Angle (rad) of a roll turning with web speed ``v`` (m/s) at a radius
    R(t) = R0 + dR_dt * t (m): theta = theta0 + integral of v/R dt, closed form.
    An unwind has dR_dt < 0 (radius shrinking by one web thickness per turn)."""
    t = np.asarray(t, dtype=float)
    if dR_dt == 0.0:
        return theta0 + v * t / R0
    return theta0 + (v / dR_dt) * np.log((R0 + dR_dt * t) / R0)


def harmonics(theta, amplitudes, phases):
    """sum_j A_j sin(j theta + psi_j), j = 1..len(amplitudes)."""
    theta = np.asarray(theta, dtype=float)
    out = np.zeros_like(theta)
    for j, (a, p) in enumerate(zip(amplitudes, phases), start=1):
        out += a * np.sin(j * theta + p)
    return out


def pulse_train(theta, width=0.6, high=5.0):
    """Once-per-revolution pulse: ``high`` while (theta mod 2 pi) < width, else 0.
    Rising edges fall at theta = 2 pi k."""
    return np.where(np.mod(theta, 2 * np.pi) < width, high, 0.0)


def ewl_like(duration=60.0, fs=100.0, *, v=200 * FPM, R0=6.375 * INCH, dR_dt=-0.18e-3,
             R_idle=1.4 * INCH, T0=100.0, noise_std=0.5, seed=0,
             unwind=((3.0, 0.7), (1.5, -1.2), (1.0, 2.0)),
             idle=((1.2, 0.3), (0.4, 1.0))):
    """A measured-looking record and its truth.

    The unwind's radius shrinks by ``dR_dt`` (m/s; -0.18 mm/s, a 0.19 mm web at
    200 ft/min, takes 0.162 m to 0.151 m in a minute: its frequency rises 7 %)
    so its harmonics sweep; the idle
    roller turns at the fixed v/R_idle. ``unwind`` / ``idle`` are (amplitude N,
    phase rad) per harmonic. Columns: ``tension`` (N), ``unwind_pulse`` (V, one
    pulse per unwind revolution), ``idle_speed`` (rad/s), ``unwind_angle``
    (rad, true), ``idle_angle`` (rad, true).

    Returns (Record, truth) with truth = {shaft: {"theta", "amplitude", "phase"}}.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(int(round(duration * fs))) / fs
    th_u = roll_angle(t, v, R0, dR_dt, theta0=-1.0)
    th_i = roll_angle(t, v, R_idle, theta0=0.4)
    a_u, p_u = (np.array(c, dtype=float) for c in zip(*unwind))
    a_i, p_i = (np.array(c, dtype=float) for c in zip(*idle))
    tension = T0 + harmonics(th_u, a_u, p_u) + harmonics(th_i, a_i, p_i) + rng.normal(0, noise_std, t.size)
    columns = {"tension": tension, "unwind_pulse": pulse_train(th_u),
               "idle_speed": np.full_like(t, v / R_idle), "unwind_angle": th_u, "idle_angle": th_i}
    units = {"tension": "N", "unwind_pulse": "V", "idle_speed": "rad/s", "unwind_angle": "rad", "idle_angle": "rad"}
    truth = {"unwind": {"theta": th_u, "amplitude": a_u, "phase": p_u},
             "idle": {"theta": th_i, "amplitude": a_i, "phase": p_i}}
    return Record(time=t, columns=columns, units=units, source="<synthetic ewl_like>"), truth
