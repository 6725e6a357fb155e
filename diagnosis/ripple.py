"""Drive torque ripple: is a broadband hump of the residual the line's own mode?

Every drive's torque carries a ripple (current ripple, PWM, commutation) that
no layout states. It excites the line's lightly damped modes, and the residual
of a model without it shows their humps at fixed frequencies, which
:func:`diagnosis.claims.humps` would otherwise call unexplained resonances.

:func:`responses` simulates the refined model once per fit run and drive with
a white ripple of known density on that drive alone (the speed loop's
``torque_noise``) and takes the Welch PSD of its difference from the refined
model at each sensor: the line's ripple transfer, per unit density.
:func:`fit_levels` finds the ripple density of each drive that best explains
the residual's spectrum above its noise floor (non-negative least squares,
each bin weighted by its own level so that no band dominates), and
:func:`explained` says which share of a hump's excess energy that fit
reproduces. A hump the ripple explains is the line's own mode, reported as
such with the estimated densities; what it does not explain stays an
unexplained resonance.

Densities are one-sided, N.m/sqrt(Hz): a white ripple of rms sigma held over
steps dt has 2 sigma^2 dt, whatever the sample rate.
"""
import hashlib
import logging
import math

import numpy as np
from scipy import optimize, signal

from webline.diagnosis import estimate as est
from webline.diagnosis import layout_edit

log = logging.getLogger("webline.diagnose")

PROBE_DENSITY = 2.0e-3    # N.m/sqrt(Hz) simulated on each drive (the response is linear in it)
SEED = 4242
BAND_HZ = (0.2, 30.0)     # where the line's modes sit (the fit's bins)
EXPLAINED = 0.5           # a hump whose excess the ripple fit reproduces to this share is the line's own


def drives(sim):
    """Driven elements (with a speed loop) of a simulation's system."""
    return [el for el, m in sim.system.meta["elements"].items() if m.get("driven") and m.get("speed_pi")]


def _hold_step(system):
    """The step over which a simulation holds a source: its output interval."""
    from webline.orchestrator.reference import output_times
    return float(np.median(np.diff(np.asarray(output_times(system.experiment), float))))


def smooth(p, f):
    """Running median over 2 Hz (at least 5 bins): lines drop out, humps broader than
    about 1 Hz stay. The view :func:`diagnosis.claims.humps` takes of a residual."""
    return est._running_median(p, max(5, 2 * int(round(1.0 / (f[1] - f[0]))) + 1))


def fine(p, f):
    """A 3-bin mean of the Welch PSD (0.75 Hz): a mode with a damping ratio of a few per
    cent keeps its peak, which the 2 Hz running median of :func:`smooth` flattens."""
    del f  # the same signature as :func:`smooth`: both are a ``view`` of :func:`responses`
    return np.convolve(p, np.ones(3) / 3.0, mode="same")


def welch(x, fs):
    """Welch PSD of a residual, mean removed: 4 s segments (0.25 Hz), half overlap. The
    grid :func:`diagnosis.claims.humps` and the ripple fit share."""
    x = np.asarray(x, float) - np.mean(x)
    n = len(x)
    nperseg = int(min(n, 4.0 * fs))
    return signal.welch(x, fs=fs, nperseg=nperseg, noverlap=nperseg // 2)


def probe_doc(doc, element, dt):
    """``doc`` with a white ripple of PROBE_DENSITY on ``element``'s drive, held over ``dt``."""
    rms = PROBE_DENSITY / math.sqrt(2.0 * dt)
    doc = layout_edit.with_set(doc, f"drives.speed_loops.{element}.torque_noise", f"{rms:.6g} N*m")
    return layout_edit.with_set(doc, f"drives.speed_loops.{element}.noise_seed", SEED)


def _samples_digest(c):
    """Which samples of run ``c`` a probe's PSDs read (part of what they depend on)."""
    return hashlib.sha1(np.packbits(np.asarray(c.mask, bool)).tobytes()).hexdigest()


def responses(d, doc, sims, view=None):
    """{run: {drive: {sensor: PSD per unit density^2}}} of the refined model (``doc``,
    its simulations ``sims`` by run) on every run, and {run: frequency grid} (runs
    may differ in sample rate). ``view`` (p, f) -> PSD: how the Welch PSD is
    smoothed (default :func:`smooth`).

    The PSDs (read-only) are kept by the line model (:meth:`LineModel.derived`): the
    refined layout is probed by the ripple fit, the shaft screen's bands and its
    hump, each after the others' simulations were released."""
    view = view or smooth
    probes, jobs, job_keys = [], [], []
    for c in d.ctx:  # held-out runs too: the fit reads the residual's spectrum, no effect's estimate
        base = sims[c.name]
        dt = _hold_step(base.system)
        # the PSDs depend on the probe's and the base's simulations, the view, the samples read
        # (a base without a key, simulated outside simulate_many, is not kept)
        kept = None if base.key is None else (base.key, view.__name__, tuple(c.sensors), float(c.fs),
                                                _samples_digest(c))
        for el in drives(base):
            pdoc = probe_doc(doc, el, dt)
            sim_key = d.model.memo_key(c.run, pdoc)
            key = None if kept is None else ("ripple probe", sim_key) + kept
            hit = d.model.derived(key) if key is not None else None
            probes.append((c, el, key, hit))
            if hit is None:
                jobs.append((c.run, pdoc, f"ripple probe {el}"))
                job_keys.append(sim_key)
    fresh = iter(d.model.simulate_many(jobs, keys=job_keys))
    out, freqs = {}, {}
    for c, el, key, hit in probes:  # in the order of the drives: the fit's columns follow it
        if hit is None:
            sim = next(fresh)
            if isinstance(sim, Exception):
                log.info("  ripple probe of %s in %s failed: %s", el, c.name, (str(sim).splitlines() or [""])[0])
                continue
            per, f = {}, None
            for s in c.sensors:
                f, p = welch((sim.columns[s] - sims[c.name].columns[s])[c.mask], c.fs)
                per[s] = view(p, f) / PROBE_DENSITY ** 2
                per[s].setflags(write=False)
            if f is None:
                continue
            f.setflags(write=False)
            hit = (per, f)
            if key is not None:
                d.model.keep(key, hit)
        out.setdefault(c.name, {})[el], freqs[c.name] = hit
    return out, freqs


def fit_levels(P, G, S0, f, band=BAND_HZ):
    """Ripple density^2 per drive (>= 0) so that sum_e a_e G[e][s] fits P[s] - S0[s]
    over ``band``, each bin weighted by 1/P (relative error). ``P``, ``S0`` by sensor
    (``S0[s]`` a level or a PSD on ``f``: what is held fixed under the fit), ``G``
    {drive: {sensor: PSD per unit density^2}}. Returns ({drive: a_e}, explained PSD
    {sensor: sum_e a_e G})."""
    names = [e for e in G if all(s in G[e] for s in P)]
    if not names:
        return {}, {s: np.zeros_like(P[s]) for s in P}
    m = (f >= band[0]) & (f <= band[1])
    A, b = [], []
    for s in P:
        w = 1.0 / np.maximum(P[s][m], 1e-300)
        A.append(np.column_stack([G[e][s][m] * w for e in names]))
        s0 = np.asarray(S0[s], float)
        b.append((P[s][m] - (s0[m] if s0.ndim else s0)) * w)
    a, _ = optimize.nnls(np.vstack(A), np.concatenate(b))
    levels = dict(zip(names, (float(x) for x in a)))
    return levels, {s: sum(levels[e] * G[e][s] for e in names) for s in P}


def explained(f, p, S0, R, band):
    """Share of a hump's excess (running-median PSD ``p`` above ``S0`` over ``band``)
    that the ripple fit's PSD ``R`` reproduces (at most 1)."""
    m = (f >= band[0]) & (f <= band[1])
    excess = float(np.sum(np.maximum(p[m] - S0, 0.0)))
    if not excess > 0:
        return None
    return min(1.0, float(np.sum(np.minimum(R[m], np.maximum(p[m] - S0, 0.0)))) / excess)


def screen(d, noise, doc=None, sims=None):
    """The ripple fit of every run: {run: {"levels_Nm_per_rtHz": {drive: density},
    "psd": {sensor: explained PSD}, "f": grid}}; {} when no drive could be probed."""
    doc = d.refined_doc if doc is None else doc
    sims = d.steps[-1]["sims"] if sims is None else sims
    from webline.orchestrator.reference import ripple_components
    stated = sorted({name for sim in sims.values() for name in ripple_components(sim.system)})
    if stated:
        # the layout models a ripple already: its residual is not the model's response plus
        # a ripple to fit, and a probe would replace the stated one on its drive
        log.info("  ripple fit skipped: the layout states a torque ripple (%s)", ", ".join(stated))
        return {}
    G, freqs = responses(d, doc, sims)
    out = {}
    for c in d.ctx:
        if c.name not in G:
            continue
        f = freqs[c.name]
        P, S0 = {}, {}
        for s in c.sensors:
            _, p = welch((c.meas[s] - sims[c.name].columns[s])[c.mask], c.fs)
            P[s] = smooth(p, f)
            S0[s] = noise[c.name][s]["psd_N2_per_hz"]
        a, R = fit_levels(P, G[c.name], S0, f)
        out[c.name] = {"levels_Nm_per_rtHz": {e: math.sqrt(v) for e, v in a.items()}, "psd": R, "f": f}
    return out
