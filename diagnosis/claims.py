"""No claim without a check; what is left and what was possible.

* :func:`check` / :func:`decide`: an effect added to the model is kept only if,
  re-simulated on the fit runs, it lowers the residual where it acts and
  raises no sensor's NRMSE by more than a set share (default 2 %).
* :func:`noise_floor`: the sensor noise variance estimated from the data
  itself (Welch PSD level above the band the line's dynamics and rotating
  harmonics occupy), and :func:`achievable_nrmse`: the NRMSE a perfect
  model would reach with that noise; :func:`closed_share` = (nominal -
  refined) / (nominal - achievable).
* :func:`leftovers`: per sensor, the harmonics each reported effect leaves
  (share of what the nominal residual held), untagged peaks left, noise floor.
* :func:`humps`: fixed-frequency broadband residual humps (a resonance no
  rotating element's family explains) reported as findings, not as noise.
"""
import math

import numpy as np
from scipy import signal, stats

from webline.diagnosis import estimate as est
from webline.diagnosis import ripple

ORDER_LOG10_P = -5.0   # one order's harmonic left is more than noise below this log10 p


# ================================================================== the check ====
def nrmse_over(ctxs, sims, s):
    """NRMSE of sensor ``s`` over the joined records of ``ctxs`` (whole records)."""
    e2 = d2 = 0.0
    for c in ctxs:
        if s not in c.sensors:
            continue
        y = c.meas[s]
        e2 += float(np.sum((y - sims[c.name].columns[s]) ** 2))
        d2 += float(np.sum((y - np.mean(y)) ** 2))
    return math.sqrt(e2 / d2) if d2 > 0 else float("nan")


def decide(nrmse_before, nrmse_after, local_before, local_after, local_z_drop, max_worse=0.02,
           min_local_drop=0.10, min_z_drop=9.0):
    """(accepted, reason): the rule of the check, on numbers.

    Rejected when any sensor's NRMSE rises by more than ``max_worse``
    (relative), or when the residual where the effect acts does not fall by
    ``min_local_drop`` (relative) and by more than ``min_z_drop`` in units of
    the noise (chi-square: a drop of a few units is what fitting noise gives)."""
    worse = {s: (nrmse_after[s] - b) / b for s, b in nrmse_before.items()
             if b and b > 0 and s in nrmse_after and np.isfinite(nrmse_after[s])}
    bad = {s: w for s, w in worse.items() if w > max_worse}
    if bad:
        s, w = max(bad.items(), key=lambda kv: kv[1])
        return False, (f"raises {s} NRMSE by {100 * w:.1f} % ({nrmse_before[s]:.3g} -> {nrmse_after[s]:.3g}; "
                       f"limit {100 * max_worse:.0f} %)")
    if not local_before > 0:
        return False, "nothing to explain where the effect acts"
    drop = 1.0 - local_after / local_before
    if drop < min_local_drop:
        return False, (f"lowers the residual where it acts by {100 * drop:.1f} % only "
                       f"(needs {100 * min_local_drop:.0f} %)")
    if local_z_drop is not None and local_z_drop < min_z_drop:
        return False, f"the residual drop where it acts is {local_z_drop:.3g} noise units (needs {min_z_drop:g})"
    return True, (f"lowers the residual where it acts by {100 * drop:.0f} %; no sensor's NRMSE "
                  f"rises by more than {100 * max_worse:.0f} %")


def local_energy(d, sims, local):
    """(energy, z) of the residual where an effect acts, over the fit runs.

    ``("periodic", cand)``: the harmonics of (data - model) on the element's
    (refined) angle at its orders, z = sum |Y|^2 T / (2 S(f)) (each term is
    Exp(1) for noise); ``("all", None)``: the whole residual after start-up,
    z = energy / noise variance per sample."""
    kind, cand = local
    E = z = 0.0
    for c in d.fit_ctx():
        if kind == "periodic":
            orders = d.orders_for(c, cand.key)
            if not orders:
                continue
            th = d._theta_refined(c, cand)
            f = np.array(orders) * c.freq[cand.key] * (1.0 + c.kappa.get(cand.key, 0.0))
            for s in c.sensors:
                Y = est.fit_harmonics(c.left(s, sims[c.name]), th, orders, c.mask)
                E += float(np.sum(np.abs(Y) ** 2))
                z += float(np.sum(est.harmonic_z(Y, f, c.floors[s], c.T)))
        else:
            m = c.t >= c.t[0] + min(1.0, 0.1 * c.run.duration)
            for s in c.sensors:
                r = (c.meas[s] - sims[c.name].columns[s])[m]
                e = float(np.sum((r - np.mean(r)) ** 2))
                E += e
                var = float(np.median(c.floors[s].S)) * 0.5 * c.fs
                z += e / max(var, 1e-300)
    return E, z


def check(d, before, after, local, max_worse=None):
    """The check of one effect: simulations ``before`` (the model so far) and
    ``after`` (with the effect), {run: Sim}, judged on the fit runs."""
    fit = d.fit_ctx()
    max_worse = d.opt.max_worse if max_worse is None else max_worse
    sensors = list(dict.fromkeys(s for c in fit for s in c.sensors))
    nb = {s: nrmse_over(fit, before, s) for s in sensors}
    na = {s: nrmse_over(fit, after, s) for s in sensors}
    Eb, zb = local_energy(d, before, local)
    Ea, za = local_energy(d, after, local)
    ok, why = decide(nb, na, Eb, Ea, zb - za, max_worse)
    if ok:
        ok, why = run_by_run(fit, before, after, max_worse, why)
    return {"accepted": ok, "reason": why, "nrmse_before": nb, "nrmse_after": na,
            "local_before": Eb, "local_after": Ea, "local_z_drop": zb - za}


def worse_by_run(ctxs, before, after, max_worse):
    """[(run, sensor, NRMSE before, after)] where one run's NRMSE rises by more than
    ``max_worse`` (relative), worst first; [] with a single run (the pooled rule holds)."""
    if len(ctxs) < 2:
        return []
    out = []
    for c in ctxs:
        for s in c.sensors:
            b, a = nrmse_over([c], before, s), nrmse_over([c], after, s)
            if b > 0 and np.isfinite(a) and (a - b) / b > max_worse:
                out.append((c.name, s, b, a))
    return sorted(out, key=lambda x: -(x[3] - x[2]) / x[2])


def run_by_run(ctxs, before, after, max_worse, why_ok):
    """(accepted, reason): :func:`decide`'s NRMSE rule on each run alone. Pooled over
    runs, a gain on one run hides a loss on another, and a user's next record is one
    run: independent seed-2 c07 (an eccentric roller19 reported as idler_r1 in
    "feedforward reference") pooled lc9 1.039 -> 1.035, run by run 1.055 -> 1.090 and
    1.007 -> 0.916; the held-out run went 1.021 -> 1.042."""
    w = worse_by_run(ctxs, before, after, max_worse)
    if not w:
        return True, why_ok
    run, s, b, a = w[0]
    return False, (f"raises {s} NRMSE in run {run} by {100 * (a - b) / b:.1f} % ({b:.3g} -> {a:.3g}; limit "
                   f"{100 * max_worse:.0f} % on each run, though the runs pooled pass)")


# ============================================================ what was possible ====
def noise_floor(y, fs, f_lo, f_hi=None):
    """Variance (N^2) of white sensor noise in ``y``, from the data: the median
    of the Welch PSD between ``f_lo`` and ``f_hi`` (default 0.45 fs), corrected
    from median to mean of its chi-square distribution, times the bandwidth
    fs/2. Above the band of the line's dynamics the measured PSD is the
    noise's; the median ignores isolated lines. Returns (variance, S, band)."""
    y = np.asarray(y, float)
    n = len(y)
    f_hi = 0.45 * fs if f_hi is None else f_hi
    nperseg = int(min(n, max(64, 2.0 * fs)))
    f, p = signal.welch(y - np.mean(y), fs=fs, nperseg=nperseg, noverlap=nperseg // 2)
    band = (f >= f_lo) & (f <= f_hi)
    if band.sum() < 5:  # no band above the dynamics: the quietest 20 % of the spectrum
        band = f > 0
        p_b = np.sort(p[band])[: max(3, int(0.2 * band.sum()))]
    else:
        p_b = p[band]
    nseg = max(1, (n - nperseg) // (nperseg // 2) + 1)
    dof = 2.0 * max(1.0, 0.9 * nseg)
    S = float(np.median(p_b)) * dof / stats.chi2.median(dof)
    return S * 0.5 * fs, S, (float(f_lo), float(f_hi))


def achievable_nrmse(noise_var, n_samples, sum_sq_dev):
    """NRMSE a perfect model reaches when the data carries white noise of
    variance ``noise_var`` (per run): sqrt(sum var_k N_k / sum (y - mean)^2),
    at most 1 (the data's variance holds the noise's); lists over runs or scalars."""
    v = np.atleast_1d(np.asarray(noise_var, float))
    n = np.atleast_1d(np.asarray(n_samples, float))
    d2 = float(np.sum(np.atleast_1d(np.asarray(sum_sq_dev, float))))
    if not d2 > 0:
        return float("nan")
    # var(y) = var(signal) + var(noise) >= var(noise): above 1 is the estimate's scatter
    return min(1.0, math.sqrt(float(np.sum(v * n)) / d2))


def closed_share(nominal, refined, achievable, min_room=0.02):
    """(nominal - refined) / (nominal - achievable): the share of the gap the
    noise leaves room to close that the refinement closed (1 = down to the
    noise; < 0 = worse). None when the nominal model is already within
    ``min_room`` (relative) of the achievable."""
    if nominal is None or refined is None or achievable is None:
        return None
    if not all(np.isfinite([nominal, refined, achievable])):
        return None
    room = nominal - achievable
    if room <= min_room * max(nominal, 1e-12):
        return None
    return float((nominal - refined) / room)


def sensor_noise(d):
    """{run: {sensor: {variance_N2, rms_N, band_hz}}} from the measured data."""
    out = {}
    for c in d.ctx:
        w = d.where_report.get(c.name, {})
        f_hi = None
        for s in c.sensors:
            bands = w.get("sensors", {}).get(s, {}).get("bands", [])
            f_hi = next((b["f_lo_hz"] for b in bands if b["band"] == "high"), None)
            break
        f_lo = f_hi if f_hi is not None and f_hi < 0.4 * c.fs else c.fc
        out[c.name] = {}
        for s in c.sensors:
            var, S, band = noise_floor(c.meas[s][c.mask], c.fs, f_lo)
            out[c.name][s] = {"variance_N2": var, "rms_N": math.sqrt(var), "psd_N2_per_hz": S, "band_hz": band}
    return out


def achievable_for(d, noise, ctxs, s):
    ctxs = [c for c in ctxs if s in c.sensors]
    if not ctxs:
        return None
    return achievable_nrmse([noise[c.name][s]["variance_N2"] for c in ctxs], [len(c.meas[s]) for c in ctxs],
                            [float(np.sum((c.meas[s] - np.mean(c.meas[s])) ** 2)) for c in ctxs])


# ================================================================ what is left ====
def leftovers(d, noise, remaining_peaks):
    """Per sensor after refinement: each reported periodic effect's harmonics
    left (share of what the nominal residual held, fit runs; ``held_out`` the
    same on the held-out runs, where a transfer the fit absorbed into the
    estimate shows), the untagged peaks left, the noise floor."""
    last = d.steps[-1]["sims"]
    fit = d.fit_ctx()
    hold = [c for c in d.ctx if not c.fit]
    sensors = list(dict.fromkeys(s for c in d.ctx for s in c.sensors))
    out = {}
    for s in sensors:
        effs = []
        for fe in d.final_effects:
            k = fe["ranked"][0]["cand"]
            rec = _effect_left(d, k, fit, s, last)
            if rec is None:
                continue
            # independent seed-21 c05: roller9's order 2 fitted in the one fit run beside a leader
            # shaft's 11.4 Hz mode the model lacks; at the held-out run's speed the line (12.7 Hz)
            # passes that mode otherwise, and 0.83 N of it stays on lc9
            rec["held_out"] = _effect_left(d, k, hold, s, last) if hold else None
            effs.append(rec)
        untagged = []
        for rname, per in (remaining_peaks or {}).items():
            for p in per.get(s, []):
                if p.get("status") == "untagged":
                    untagged.append({"run": rname, "frequency_hz": p["frequency_hz"], "amplitude": p["amplitude"]})
        out[s] = {"effects": effs, "untagged_peaks_left": untagged,
                  "noise_floor_rms_N": {c.name: noise[c.name][s]["rms_N"] for c in d.ctx if s in c.sensors}}
    return out


def _effect_left(d, k, ctxs, s, last):
    """Effect ``k``'s harmonics on sensor ``s`` over runs ``ctxs``: measured minus
    nominal and measured minus refined (``last``), on the refined angle; None if
    no run carries them."""
    e_nom = e_ref = z_ref = 0.0
    amp_nom, amp_ref, n_terms = {}, {}, 0
    z_order, runs = {}, []
    for c in ctxs:
        orders = d.orders_for(c, k.key)
        if not orders or s not in c.sensors:
            continue
        runs.append(c.name)
        th = d._theta_refined(c, k)
        f = np.array(orders) * c.freq[k.key] * (1.0 + c.kappa.get(k.key, 0.0))
        Yn = est.fit_harmonics(c.periodic[s], th, orders, c.mask)   # measured minus nominal, split once per run
        Yr = est.fit_harmonics(c.left(s, last[c.name]), th, orders, c.mask)
        e_nom += float(np.sum(np.abs(Yn) ** 2))
        e_ref += float(np.sum(np.abs(Yr) ** 2))
        z = est.harmonic_z(Yr, f, c.floors[s], c.T)
        z_ref += float(np.sum(z))
        n_terms += len(orders)
        for j, a, b, zj in zip(orders, Yn, Yr, z):
            amp_nom.setdefault(j, []).append(abs(a))
            amp_ref.setdefault(j, []).append(abs(b))
            z_order.setdefault(j, []).append(float(zj))
    if not n_terms:
        return None
    return {"element": k.element, "kind": k.kind, "orders": sorted(amp_nom),
            "runs": runs,
            "amplitude_nominal_N": [float(np.mean(amp_nom[j])) for j in sorted(amp_nom)],
            "amplitude_left_N": [float(np.mean(amp_ref[j])) for j in sorted(amp_ref)],
            "share_left": e_ref / e_nom if e_nom > 0 else None,
            "z_left": z_ref, "n_terms": n_terms,
            # what is left is more than noise at these orders
            "significant": bool(z_ref > n_terms + 3.0 * math.sqrt(2.0 * n_terms) + 9.0),
            "by_order": [_order_left(j, amp_nom[j], amp_ref[j], z_order[j]) for j in sorted(amp_nom)]}


def _order_left(j, a_nom, a_ref, z):
    """One order's harmonic left on one sensor: share of the nominal energy and
    whether what is left is more than noise (summed z over the runs, fit or held out, is
    Gamma(runs, 1) for noise alone; significant below p = 1e-5)."""
    e_nom = float(np.sum(np.square(a_nom)))
    return {"order": int(j), "share_left": float(np.sum(np.square(a_ref))) / e_nom if e_nom > 0 else None,
            "z_left": float(np.sum(z)),
            "significant": bool(est.gamma_log10_sf(float(np.sum(z)), len(z)) < ORDER_LOG10_P)}


def humps(d, noise, min_share=0.05, min_width_hz=1.0, ratio=4.0, max_top3=0.7, ripple_fit=None):
    """Broadband humps of the refined residual: contiguous regions where the
    Welch PSD (0.25 Hz resolution, running median over 2 Hz so that lines
    drop out) stays above ``ratio`` x the noise floor for
    at least ``min_width_hz``, holding at least ``min_share`` of the residual
    energy, and not a line (the 3 strongest bins hold less than ``max_top3`` of
    the region's excess: a harmonic's energy sits in its window's main lobe).
    A lightly damped mode excited broadband looks like this and follows no
    element's speed. ``ripple_fit`` (:func:`diagnosis.ripple.screen`): a hump
    whose excess the drives' fitted torque ripple reproduces (share >=
    ``ripple.EXPLAINED``) is the line's own mode excited by it, reported so and
    not as unexplained. Returns findings, strongest first."""
    last = d.steps[-1]["sims"]
    found = []
    for c in d.ctx:
        for s in c.sensors:
            r = (c.meas[s] - last[c.name].columns[s])[c.mask]
            if min(len(r), 4.0 * c.fs) < 64:
                continue
            f, p = ripple.welch(r, c.fs)
            df = f[1] - f[0]
            S0 = noise[c.name][s]["psd_N2_per_hz"]
            total = float(np.sum(p) * df)
            # a running median over 2 Hz removes lines (a window's main lobe is 4 bins)
            # and keeps what is broader than about 1 Hz
            ps = ripple.smooth(p, f)
            above = (ps > ratio * S0) & (f >= max(c.fc, 2 * df))
            for a, b in _runs(above):
                width = (b - a) * df
                if width < min_width_hz:
                    continue
                ex = np.maximum(ps[a:b] - S0, 0.0)
                e = float(np.sum(ex) * df)
                share = e / total if total > 0 else 0.0
                top3 = float(np.sum(np.sort(ex)[-3:]) / max(np.sum(ex), 1e-300))
                if share < min_share or top3 >= max_top3:
                    continue
                # a mode's frequency: the hump's top (the median's top, refined within +-1 Hz
                # on the 3-bin mean, which a skewed resonance does not bias)
                i0 = a + int(np.argmax(ps[a:b]))
                w = int(round(1.0 / df))
                lo_i, hi_i = max(a, i0 - w), min(b, i0 + w + 1)
                pm = ripple.fine(p, f)
                fc = float(f[lo_i + int(np.argmax(pm[lo_i:hi_i]))])
                h = {"kind": "unexplained resonance", "run": c.name, "sensor": s,
                     "frequency_hz": fc, "band_hz": [float(f[a]), float(f[b - 1])],
                     "share_of_residual": share, "rms_N": math.sqrt(e),
                     "text": f"unexplained resonance near {fc:.3g} Hz on {s.split('.')[0]} "
                             f"({100 * share:.0f} % of the refined residual, run {c.name})"}
                rf = (ripple_fit or {}).get(c.name)
                if rf is not None and s in rf["psd"]:  # the same Welch grid (ripple.welch, same run)
                    x = ripple.explained(f, ps, S0, rf["psd"][s], (f[a], f[b - 1]))
                    h["ripple_explains"] = x
                    if x is not None and x >= ripple.EXPLAINED:
                        lv = rf["levels_Nm_per_rtHz"]
                        on = ", ".join(f"{1e3 * v:.2g} on {el}" for el, v in sorted(lv.items(), key=lambda x: -x[1])
                                       if v > 0)
                        h["kind"] = "line mode excited through the drives"
                        # the drives' responses overlap in shape: the split between them is a fit,
                        # not a measurement of each drive; and what excites the mode may be any
                        # broadband torque (ripple, a drive effect modelled imperfectly)
                        h["text"] = (f"the line's own mode near {fc:.3g} Hz on {s.split('.')[0]}, excited through "
                                     f"the drives' torque: a broadband torque ripple fitted to the residual "
                                     f"({on} mN*m/sqrt(Hz); these data do not fix the split between the drives) "
                                     f"reproduces {100 * x:.0f} % of it "
                                     f"({100 * share:.0f} % of the refined residual, run {c.name})")
                    else:
                        h["text"] += (f"; the drives' torque ripple explains {100 * (x or 0.0):.0f} % of it")
                found.append(h)
    # across runs: does it stay at one frequency whatever the speed?
    runs = {c.name for c in d.ctx}
    for h in found:
        others = [g for g in found if g["sensor"] == h["sensor"] and g["run"] != h["run"]]
        if len(runs) > 1:
            same = {g["run"] for g in others if abs(g["frequency_hz"] - h["frequency_hz"]) < 0.1 * h["frequency_hz"]}
            h["same_frequency_in_other_runs"] = len(same) == len(runs) - 1
        else:
            h["same_frequency_in_other_runs"] = None
    found.sort(key=lambda h: -h["share_of_residual"])
    return found


def _runs(mask):
    """[start, stop) index pairs of the True runs of ``mask``."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    d = np.diff(m.astype(int))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))
