"""A rigid line against a compliant shaft, each with the line's fast dynamics calibrated
to the ripple spectrum.

The shaft screen (:mod:`diagnosis.compliance`) fits the drives' ripple responses of the
refined layout, as written, to the residual's spectrum. Above a few hertz those responses
follow parameters the layout has only to a data sheet's tolerance and forms it may not
have (web EA, the drives' inertias, the load cells' filters, the speed loops' gains, a
current-loop lag), and what a wrong line leaves there a shaft absorbs as well as a real
mode, or hides a real one (docs/diagnose.md, "What limits a shaft's recall"). Here each
candidate, the rigid line and a shaft on one drive at each of :data:`MODES_HZ`, is fitted
over those parameters first (log scale factors, :data:`BOUNDS`, Nelder-Mead), over a band
fixed by the drives (:data:`BAND_HZ`), not by a hump. The responses come from the
linearised line (:func:`orchestrator.modes.torque_transfer`): one linearisation per layout
tried, no simulation, no probe's Welch noise.

The comparison is the ratio of the calibrated misfits, rigid line over the best shaft
(:func:`scan`). Measured on the kept cases of seeds 50-57 (docs/diagnose.md, "The ripple
spectrum with the line calibrated").
"""
import copy
import dataclasses
import math

import numpy as np
from scipy import optimize

from webline.diagnosis import compliance, layout_edit, others, ripple, tolerances
from webline.orchestrator import modes, units
from webline.orchestrator.layout_source import load_located, plain

BAND_HZ = (4.0, 24.0)          # above the line's slow tension modes, below the load cells' roll-off
MODES_HZ = (5.0, 7.0, 10.0, 14.0, 20.0)   # the shafts' torsional modes tried on each drive
MAXFEV = 60                    # Nelder-Mead evaluations per candidate and form
#: the best shaft's mode refined between its grid neighbours: first at 2^(+-1/4) of the grid
#: mode (the grid's half step), then at 2^(+-1/8) of the better of the three, each fit warm
#: from the best one's calibration with :data:`REFINE_MAXFEV` steps
REFINE_STEPS = (2.0 ** 0.25, 2.0 ** 0.125)
REFINE_MAXFEV = 30
LAG0_S = 3.0e-3                # the current-loop lag every drive is given, scaled by the fit
#: log bounds of the scale factors: web EA within a data sheet's +-30 %, the rest +-50 %, the
#: lag 0.3-6 ms
BOUNDS = {"EA": (-math.log(1.3), math.log(1.3)), "lag": (math.log(0.1), math.log(2.0))}
WIDE = (-math.log(1.5), math.log(1.5))
#: feed-forward forms tried: the layout's, and the set point's (at a steady speed 'none'
#: linearises to the same line: the set point's torque is a constant)
FORMS = (None, "reference")


def resolved(model, sets):
    """The model's layout with the dotted ``sets`` written in, as plain data."""
    return plain(load_located(model.path, sets))


def responses(model, run, doc, drives, sensors, f, speed, band=None):
    """{drive: {sensor: |T(f)|^2 on the fine view}}: the motor torque of each drive to each
    load cell, the layout ``doc`` linearised at the line speed ``speed`` (m/s) under
    ``run``'s conditions. Per unit torque density: the ripple fit's levels are free.

    ``band`` (Hz): the responses are solved only where a fit over ``band`` reads them (its
    bins and the fine view's neighbours), 0 elsewhere; the values read are the same."""
    run = _at_speed(run, speed)
    lin = modes.linearise_system(model.system(run, doc))
    lo, hi = in_reach(f, band)
    T = np.zeros((len(f), len(lin.outputs), len(drives)), complex)
    # not at 0 Hz: a shaft's twist is an integrator there; every drive in one solve
    T[lo:hi] = lin.transfer(np.maximum(f[lo:hi], f[1]), [f"{e}.tau" for e in drives])
    return {e: {s: ripple.fine(np.abs(T[:, lin.outputs.index(s), j]) ** 2, f) for s in sensors}
            for j, e in enumerate(drives)}


def in_reach(f, band):
    """(first, end) indices of the bins of ``f`` a fit over ``band`` reads through the fine
    view (:func:`ripple.fine`: each bin's neighbours too); all of ``f`` without a band. The
    Welch grid runs to the Nyquist frequency and a band holds a few per cent of it: solving
    the line only there made a calibrated fit's step 2-3 x cheaper (docs/diagnose.md)."""
    if band is None:
        return 0, len(f)
    idx = np.flatnonzero((f >= band[0]) & (f <= band[1]))
    if not len(idx):
        return 0, 0
    return max(int(idx[0]) - 2, 0), min(int(idx[-1]) + 3, len(f))


def _at_speed(run, speed):
    """``run`` at the steady line speed ``speed`` (m/s): a ramped run is linearised at its
    fit window's mean speed."""
    ov = {**dict(run.overrides), "experiment.line_speed": f"{speed:.12g} m/s"}
    if dataclasses.is_dataclass(run):
        return dataclasses.replace(run, overrides=ov)
    out = copy.copy(run)
    out.overrides = ov
    return out


def misfit(P, G, S0, f, band):
    """(misfit, levels, fit) of the responses ``G`` to the spectra ``P`` over ``band``: every
    drive's level and a white and a 1/f floor per sensor free, as the shaft screen fits
    (:func:`compliance.spectral_fit`)."""
    lo, hi = band
    Gx = compliance.with_floors(G, S0, f, lo)
    levels, R = ripple.fit_levels(P, Gx, {s: 0.0 for s in P}, f, band=band)
    return compliance.log_misfit(P, R, (f >= lo) & (f <= hi))[0], levels, (Gx, R)


class Calibration:
    """The layout ``sets`` (dotted entries over the model's layout) in feed-forward form
    ``form`` (None: as written), with a shaft ``shaft`` = (spec, mode Hz) or none, and log
    scale factors x on web EA, each drive's inertia, the load cells' filter time constant,
    the speed loops' K_ref and a current lag in every drive."""

    def __init__(self, model, run, sets, drives, sensors, speed, shaft=None, form=None):
        self.model, self.run, self.drives, self.sensors, self.speed = model, run, drives, sensors, speed
        self.shaft = shaft
        extra = {}
        if form:
            extra = {f"drives.speed_loops.{e}.feedforward": form for e in drives}
        self.sets = {**sets, **extra}
        self.base = resolved(model, self.sets)
        self.names = ["EA"] + [f"J:{e}" for e in drives] + ["filter", "K", "lag"]
        self.bounds = np.array([BOUNDS.get(n.split(":")[0], WIDE) for n in self.names])

    def doc(self, x):
        """The derived layout of the scale factors exp(x)."""
        sc = dict(zip(self.names, np.exp(np.clip(x, self.bounds[:, 0], self.bounds[:, 1]))))
        base = self.base
        inert = {e: sc[f"J:{e}"] for e in self.drives}
        sets = tolerances.scaled_set(base, EA=sc["EA"], inertia=inert)
        for s, v in base["sensors"].items():
            if s in self.sensors or f"{s}.T" in self.sensors:
                sets[f"sensors.{s}.filter"] = f"{float(units.quantity(v['filter'], 'time')) * sc['filter']:.9g} s"
        for e, v in base["drives"]["speed_loops"].items():
            sets[f"drives.speed_loops.{e}.K_ref"] = f"{float(units.quantity(v['K_ref'], 'rate')) * sc['K']:.9g} 1/s"
            sets[f"drives.speed_loops.{e}.current_lag"] = f"{LAG0_S * sc['lag']:.6g} s"
        doc = layout_edit.with_sets(self.model.doc, {**self.sets, **sets})
        if self.shaft is not None:
            (el, J, (key, own)), ft = self.shaft
            k = inert.get(el, 1.0)
            doc = others._drive_doc(doc, (el, J * k, (key, own * k)), ft, 0.0)
        return doc

    def fit(self, P, S0, f, band=BAND_HZ, maxfev=MAXFEV, start=None):
        """(misfit as written, calibrated misfit, {name: scale factor}, evaluations);
        ``start``: {name: scale factor} the search starts from (default: the layout's)."""
        def cost(x):
            try:
                G = responses(self.model, self.run, self.doc(x), self.drives, self.sensors, f, self.speed, band)
            except Exception:  # noqa: BLE001 - a layout the line cannot hold is no candidate
                return 1e3
            return misfit(P, G, S0, f, band)[0]

        c0 = cost(np.zeros(len(self.names)))
        x0 = np.zeros(len(self.names)) if start is None else np.log([start[n] for n in self.names])
        simplex = np.vstack([x0] + [x0 + 0.15 * np.eye(len(x0))[i] for i in range(len(x0))])
        r = optimize.minimize(cost, x0, method="Nelder-Mead",
                              options={"maxfev": maxfev, "xatol": 0.01, "fatol": 1e-4, "initial_simplex": simplex})
        x = np.clip(r.x, self.bounds[:, 0], self.bounds[:, 1])
        return c0, float(r.fun), dict(zip(self.names, np.exp(x))), int(r.nfev)


def _forms(model, sets, drives):
    """:data:`FORMS` less those that write the layout's own: a layout whose drives all feed
    forward the set point or nothing is tried once."""
    loops = resolved(model, sets)["drives"]["speed_loops"]
    own = {str((loops.get(e) or {}).get("feedforward", "measured")) for e in drives}
    if own <= {"reference", "False", "none"}:
        return ["reference"]
    return list(FORMS)


def scan(model, run, sets, specs, sensors, speed, P, S0, f, band=BAND_HZ, modes_hz=MODES_HZ,
         maxfev=MAXFEV, forms=None, progress=None, refine_best=True):
    """The rigid line and a shaft on each drive of ``specs`` (``others.drive_candidates``'
    (element, J, (key, own inertia))) at each of ``modes_hz``, each calibrated in each form.
    Returns {"rigid": row, "shafts": [rows by drive, best first], "ratio": rigid misfit
    over the best shaft's, "refined": {"row", "tried"} (:func:`refine`, the best shaft's mode;
    None without shafts or with ``refine_best`` false)}; a row is {element, torsional_hz, form,
    misfit, misfit_as_written, scales}. The ratio compares the grid's fits only, each
    started from the layout: the refinement's warm starts would favour the shaft.
    ``forms``: the feed-forward forms tried (default :func:`_forms`). ``progress(text)``:
    told after each fit."""
    drives = [sp[0] for sp in specs]
    forms = list(forms) if forms is not None else _forms(model, sets, drives)
    fit = Fit(model, run, sets, drives, sensors, speed, P, S0, f, band)

    def best_of(shaft):
        row = None
        for form in forms:
            r = fit.row(maxfev, shaft, form, None, progress)
            if row is None or r["misfit"] < row["misfit"]:
                row = r
        return row

    rigid = best_of(None)
    shafts, by_drive = [], {}
    for spec in specs:
        by_drive[spec[0]] = [best_of((spec, ft)) for ft in modes_hz]
        shafts.append(min(by_drive[spec[0]], key=lambda r: r["misfit"]))
    shafts.sort(key=lambda r: r["misfit"])
    ratio = rigid["misfit"] / shafts[0]["misfit"] if shafts and shafts[0]["misfit"] > 0 else None
    refined = None
    if shafts and refine_best:
        b = shafts[0]
        spec = next(sp for sp in specs if sp[0] == b["element"])
        row, tried = refine(fit, spec, b, progress=progress)
        refined = {"row": row, "tried": sorted([r for r in by_drive[b["element"]] if r is not b] + tried,
                                               key=lambda r: r["torsional_hz"])}
    return {"band_hz": list(band), "forms": [f or "as written" for f in forms], "rigid": rigid,
            "shafts": shafts, "ratio": ratio, "refined": refined}


@dataclasses.dataclass(frozen=True)
class Fit:
    """What every calibrated fit of one scan shares: the line (``model``, its ``run`` at
    ``speed``, the layout entries ``sets``, the ``drives`` scaled and the ``sensors``) and the
    residual's spectrum it is fitted to (``P`` over ``f``, floor ``S0``, within ``band``)."""
    model: object
    run: object
    sets: dict
    drives: list
    sensors: list
    speed: float
    P: object
    S0: object
    f: object
    band: tuple = BAND_HZ

    def row(self, maxfev, shaft, form, start, progress):
        """One calibrated fit as a row of :func:`scan`."""
        cal = Calibration(self.model, self.run, self.sets, self.drives, self.sensors, self.speed,
                          shaft=shaft, form=form)
        c0, c1, sc, _ = cal.fit(self.P, self.S0, self.f, self.band, maxfev, start=start)
        if progress:
            progress(f"{'rigid line' if not shaft else f'{shaft[0][0]} shaft {shaft[1]:.3g} Hz'}"
                     f" ({form or 'as written'}): {c0:.4g} -> {c1:.4g}")
        return {"element": shaft[0][0] if shaft else None, "torsional_hz": shaft[1] if shaft else None,
                "form": form, "misfit": c1, "misfit_as_written": c0, "scales": sc}


def refine(fit, spec, row, steps=REFINE_STEPS, maxfev=REFINE_MAXFEV, progress=None):
    """The mode of the shaft ``row`` (on ``spec``'s drive, in its form) refined between the
    grid's neighbours: at ``row``'s mode times and over each of ``steps`` in turn, around the
    best so far, each fit (:class:`Fit`) started from the calibration of the one it steps from.
    Returns (best row, the rows tried). Seed-50 c09's leader shaft (7.6 Hz) was claimed at the
    grid's 5 Hz before (docs/diagnose.md, "The calibrated shaft screen")."""
    best, tried = row, []
    for k in steps:
        centre = best
        for m in (centre["torsional_hz"] / k, centre["torsional_hz"] * k):
            r = fit.row(maxfev, (spec, m), centre["form"], centre["scales"], progress)
            tried.append(r)
            if r["misfit"] < best["misfit"]:
                best = r
    return best, [row] + tried
