"""Fourier coefficients of periodic effects in the time domain: the data regressed
on simulated responses.

The harmonic estimate (:mod:`diagnosis.estimate`: measured harmonic / model
complex gain, one gain per order) assumes one operating point. Over a record
whose line speed changes (ramps, two steady speeds) an order's frequency moves,
and near a lightly damped line mode its gain changes by large factors: the
estimate fits an average gain and the refined model, which has the true
speed-dependent gain, can end farther from the data than the nominal one (an
eccentric idler in a ramped record, its 6th order crossing an idler mode: NRMSE
1 -> 2.2).

Here the model itself supplies the regressors. The span-length change of order
j is Re(X_j e^{i j theta}) ({27}-{32}); its effect on every sensor is, to first
order, Re(X_j) r_j(t) + Im(X_j) q_j(t), where r_j and q_j are the simulated
responses (of the whole line, transients, ramps and speed-dependent gains
included) to X_j = a and X_j = i a, divided by a. The coefficients of all
candidate elements follow from one weighted least-squares fit of the periodic
residual over the fit runs (weights: each sensor's noise floor). Large
eccentricities near a line mode respond nonlinearly (the element's angle itself
is modulated), so the fit is a Gauss-Newton iteration: responses at the current
estimate, a step, a line search on the simulated residual.

The same regression tells elements at the same frequency apart (each one's
residual energy) and decides whether two of them are eccentric: a second
element is added only if it removes at least ``PAIR_GAIN`` of what the first
leaves above the noise, with a well-conditioned joint fit (two elements in one
tension zone at the same speed load the sensors alike and their joint fit
diverges: they are one candidate list, not two sources).
"""
import logging

import numpy as np

from webline.diagnosis import estimate as est

log = logging.getLogger("webline.diagnose")

PAIR_GAIN = 0.5      # share of the excess residual (above noise) a second same-frequency source must remove
PAIR_BLOWUP = 3.0    # joint amplitudes beyond this multiple of the single fits: the pair is degenerate
MAX_RANKED = 4       # candidates of one effect regressed (best harmonic pattern fits first)
GAIN_MIN = 0.01      # a Gauss-Newton step that lowers the simulated residual by less ends the iteration
LINEAR = 0.1         # a whole step whose simulated residual lands within this share of the predicted
#                      fall of it keeps its responses for the next step


def _doc(d, base, cands, Xs):
    for k, X in zip(cands, Xs):
        base = d.with_effect(base, k, np.asarray(X, complex))
    return base


def _periodic(c, y):
    return est.split_slow_periodic(y, c.fs, c.fc)[1]


def _weights(c):
    """Per sensor, w with w^2 = 2 / (median S x fs): a sample's noise variance (S fs / 2
    for a white floor S) weighted to 1, so a run counts by its duration and noise, not
    by its sample rate (with w^2 = 1 / median S a 1 kHz run counted four times a 250 Hz
    run of the same floor: independent c20's 100 ft/min run at 1 kHz, whose order 1
    sits on a ripple-rung line mode, pulled the joint estimate to its own)."""
    return {s: 1.0 / np.sqrt(max(0.5 * c.fs * float(np.median(c.floors[s].S)), 1e-300)) for s in c.sensors}


def simulate(d, doc, ctxs, label):
    """{run: Sim} or None if any run fails."""
    sims = d.model.simulate_many([(c.run, doc, label) for c in ctxs])
    if any(isinstance(s, Exception) for s in sims):
        return None
    return {c.name: s for c, s in zip(ctxs, sims)}


def sse(d, ctxs, sims):
    """Weighted energy of the periodic residual (data - simulation) over the fit samples."""
    e = 0.0
    for c in ctxs:
        w = _weights(c)
        for s in c.sensors:
            r = _periodic(c, c.meas[s] - sims[c.name].columns[s])[c.mask]
            e += w[s] ** 2 * float(np.sum(r * r))
    return e


def noise_sse(d, ctxs):
    """What :func:`sse` would be with a perfect model: the noise floor (white at its median
    level) over the periodic band of every fit sample."""
    e = 0.0
    for c in ctxs:
        band = max(0.5 * c.fs - c.fc, 0.0)
        for s in c.sensors:
            e += float(c.mask.sum()) * band / (0.5 * c.fs)  # w^2 * median(S) * band per sample
    return e


def responses(d, base, cands, Xs, orders, ctxs, sims0, label="response"):
    """Finite-difference responses at the estimate ``Xs``: {run: {sensor: array (n_cols, N)}}
    with columns (cand, order, real/imag) in that order, periodic part, per metre;
    None if a simulation failed."""
    a = d.opt.test_amplitude
    jobs, cols = [], []
    for i, k in enumerate(cands):
        for j in orders[i]:
            for ph in (1.0, 1j):
                Xp = [np.array(X, complex) for X in Xs]
                Xp[i][j - 1] += a * ph
                doc = _doc(d, base, cands, Xp)
                cols.append((i, j, ph))
                jobs += [(c.run, doc, f"{label} {k.element} {j}{'i' if ph == 1j else ''}") for c in ctxs]
    sims = d.model.simulate_many(jobs)
    if any(isinstance(s, Exception) for s in sims):
        return None, cols
    n = len(ctxs)
    out = {}
    for ic, c in enumerate(ctxs):
        out[c.name] = {}
        for s in c.sensors:
            y0 = sims0[c.name].columns[s]
            out[c.name][s] = np.array([_periodic(c, (sims[m * n + ic].columns[s] - y0) / a)
                                       for m in range(len(cols))])
    return out, cols


def _normal_equations(ctxs, resp, idx, sims0=None):
    """A^T A of the weighted response columns ``idx`` over the fit samples and, with
    ``sims0``, A^T y and y^T y of the weighted periodic residual data - sims0."""
    AtA = np.zeros((len(idx), len(idx)))
    Aty = np.zeros(len(idx))
    e0 = 0.0
    for c in ctxs:
        w = _weights(c)
        for s in c.sensors:
            A = resp[c.name][s][idx][:, c.mask] * w[s]
            AtA += A @ A.T
            if sims0 is not None:
                y = _periodic(c, c.meas[s] - sims0[c.name].columns[s])[c.mask] * w[s]
                Aty += A @ y
                e0 += float(y @ y)
    return AtA, Aty, e0


def solve(d, ctxs, resp, cols, sims0, subset=None):
    """Weighted least squares of the periodic residual (data - sims0) on the response
    columns (``subset``: indices of the columns used). Returns (coef, sse_before, sse_after)
    with coef in metres per column (zero outside the subset)."""
    idx = list(range(len(cols))) if subset is None else list(subset)
    AtA, Aty, e0 = _normal_equations(ctxs, resp, idx, sims0)
    # an order a run cannot show (beyond its band) has a zero column: least squares, not solve
    x = np.linalg.lstsq(AtA, Aty, rcond=1e-12)[0]
    e1 = e0 - float(Aty @ x)
    coef = np.zeros(len(cols))
    coef[idx] = x
    return coef, e0, max(e1, 0.0)


def to_X(coef, cols, n_cands, H):
    Xs = [np.zeros(H, complex) for _ in range(n_cands)]
    for v, (i, j, ph) in zip(coef, cols):
        Xs[i][j - 1] += v * ph
    return Xs


def standard_errors(d, ctxs, resp, cols, cands, Xs, sims):
    """Per candidate, the standard error (m) of each fitted order's amplitude |X_j|:
    the least-squares covariance (A^T A)^-1 of the weighted regressors times the
    variance of what the fit leaves (``sims``: the refined simulation) at that
    order's frequency (local PSD level x fs / 2 per regressor, the largest over runs
    and sensors), projected on the direction of X_j. Orders not fitted get NaN.
    The floor before the fit would do on a steady record; over a ramp the effect's
    own lines smear into it."""
    H = d.opt.harmonics
    idx = [m for m, (i, j, _) in enumerate(cols) if abs(Xs[i][j - 1]) > 0]
    out = [np.full(H, np.nan) for _ in cands]
    if not idx:
        return out
    cov = np.linalg.pinv(_normal_equations(ctxs, resp, idx)[0])
    left = {}
    for c in ctxs:
        for s in c.sensors:
            r = _periodic(c, c.meas[s] - sims[c.name].columns[s])[c.mask]
            left[c.name, s] = est.NoiseFloor(r, c.fs, median_hz=4.0)

    pos = {cols[m]: a for a, m in enumerate(idx)}
    for (i, j, ph), a in pos.items():
        b = pos.get((i, j, 1j))
        if ph != 1.0 or b is None:
            continue
        u = Xs[i][j - 1] / abs(Xs[i][j - 1])          # |X| changes along X's own direction
        var = u.real ** 2 * cov[a, a] + u.imag ** 2 * cov[b, b] + 2 * u.real * u.imag * cov[a, b]
        out[i][j - 1] = float(np.sqrt(max(var, 0.0) * _local_variance(ctxs, cands[i], j,
                                                                       lambda c, s: left[c.name, s])))
    return out


def gauss_newton(d, base, cands, Xs, orders, ctxs, steps=3, sims=None, label="time-domain fit", drop_rounds=3,
                 last=None):
    """Polish the coefficients ``Xs`` of ``cands`` (same order as ``orders``) in the
    layout ``base`` on the fit runs ``ctxs``: first the orders that make the simulated
    residual larger are dropped (``drop_rounds``), then per step the responses at the
    current estimate, a least-squares step, quartered (up to twice) until the simulated
    residual falls. A whole step whose simulated residual fell as its responses predicted
    (within :data:`LINEAR`) keeps them for the next step: the line was linear over it, and
    the next step then costs one simulation per run, or none when those responses promise
    less than :data:`GAIN_MIN` (a reused step that fails gets fresh responses and is tried
    again). ``last``: a dict that receives the latest responses (``resp``, ``cols``).

    Returns (Xs, sims, sse, history); the input estimate if no step helps."""
    H = d.opt.harmonics
    Xs = [np.array(X, complex) for X in Xs]
    if sims is None:
        sims = simulate(d, _doc(d, base, cands, Xs), ctxs, f"{label} start")
        if sims is None:
            return Xs, None, np.inf, []
    e = sse(d, ctxs, sims)
    hist = [e]
    Xs, sims, e = drop_harmful_orders(d, base, cands, Xs, ctxs, sims, e, label, rounds=drop_rounds)
    resp = None
    for it in range(steps):
        for _ in range(2):
            fresh = resp is None
            if fresh:
                resp, cols = responses(d, base, cands, Xs, orders, ctxs, sims, label=f"{label} {it + 1}")
                if resp is None:
                    return Xs, sims, e, hist
                if last is not None:   # the latest regressors: the estimate's standard errors
                    last["resp"], last["cols"] = resp, cols
            coef, _, e_pred = solve(d, ctxs, resp, cols, sims)
            if not fresh and e - e_pred < GAIN_MIN * e:
                # responses the last step proved linear promise less than a step must bring
                return Xs, sims, e, hist
            dX = to_X(coef, cols, len(cands), H)
            lam, accepted = 1.0, False
            for _ in range(3):
                Xn = [X + lam * dx for X, dx in zip(Xs, dX)]
                sn = simulate(d, _doc(d, base, cands, Xn), ctxs, f"{label} {it + 1} step {lam:g}")
                if sn is not None:
                    en = sse(d, ctxs, sn)
                    if en < e:
                        accepted = True
                        break
                lam *= 0.25
            if accepted or fresh:
                break
            resp = None   # reused responses misled the step: fresh ones at this estimate
        if not accepted:
            break
        log.info("  %s %d: periodic residual %.4g -> %.4g (predicted %.4g, step %g%s)", label, it + 1,
                 e, en, e_pred, lam, "" if fresh else ", responses reused")
        # a whole step that fell as the responses predicted: the line is linear over it and
        # the same responses serve the next step (each costs 2 x orders x runs simulations)
        if not (lam == 1.0 and abs(en - e_pred) <= LINEAR * (e - e_pred)):
            resp = None
        gain = (e - en) / e if e > 0 else 0.0
        Xs, sims, e = Xn, sn, en
        hist.append(e)
        if gain < GAIN_MIN:
            break
    return Xs, sims, e, hist


Z_ORDER = 23.0      # chi-square (2 dof) an order's drop must pass against its local noise: p ~ 1e-5


def noise_drop(d, ctxs, cand, j):
    """Expected fall of :func:`sse` when an order-``j`` pair of regressors of ``cand``
    is fitted to noise alone: per regressor the noise variance at that order's
    frequency, sigma^2 = S(f_j) fs / 2, in the weighted units (w^2 = 2 / (median S fs));
    the largest over the fit runs and sensors (a stacked fit removes about one
    regressor's worth of the noisiest block)."""
    return 2.0 * _local_variance(ctxs, cand, j, lambda c, s: c.floors[s])


def _local_variance(ctxs, cand, j, floor_of):
    """Largest over the fit runs and sensors of the variance per regressor at order j's
    frequency, in the weighted units of :func:`sse`: S(f_j) fs / 2 x w^2 = S(f_j) /
    median S, with S from ``floor_of(ctx, sensor)`` (a NoiseFloor)."""
    out = 0.0
    for c in ctxs:
        f = np.array([j * c.freq.get(cand.key, 0.0)])
        for s in c.sensors:
            S_med = max(float(np.median(c.floors[s].S)), 1e-300)
            out = max(out, float(floor_of(c, s)(f)[0]) / S_med)
    return out


def prune(d, ctxs, resp, cols, sims0, subset, cands):
    """Columns of ``subset`` whose order is significant: refitting without an order
    must raise the residual by more than Z_ORDER/2 times its noise drop (an order a
    lightly damped mode hides gets a large coefficient from noise, and at another
    speed that coefficient is no longer hidden)."""
    subset = list(subset)
    _, _, e_full = solve(d, ctxs, resp, cols, sims0, subset)
    keep = list(subset)
    for (i, j) in sorted({cols[m][:2] for m in subset}):
        without = [m for m in subset if cols[m][:2] != (i, j)]
        _, _, e_wo = solve(d, ctxs, resp, cols, sims0, without)
        if e_wo - e_full < 0.5 * Z_ORDER * noise_drop(d, ctxs, cands[i], j):
            keep = [m for m in keep if cols[m][:2] != (i, j)]
    return keep


def drop_harmful_orders(d, base, cands, Xs, ctxs, sims, e, label="fit", rounds=3):
    """Greedy, by simulation: while setting one order's coefficient to zero lowers the
    simulated residual, drop the order that lowers it most. An order on the flank of
    a lightly damped line mode can need a large coefficient in the linear fit and then
    respond nonlinearly (the element's angle itself is modulated): such an order makes
    the refined model worse than none, and no Gauss-Newton step from there recovers
    (one record: linear prediction 7.5e6, simulated 3.3e8, nominal 2.5e8)."""
    for _ in range(rounds):
        trials = [(i, j) for i, X in enumerate(Xs) for j in np.flatnonzero(np.abs(X) > 0)]
        if len(trials) < 2:
            break
        docs = []
        for i, j in trials:
            Xt = [X.copy() for X in Xs]
            Xt[i][j] = 0.0
            docs.append(Xt)
        jobs = [(c.run, _doc(d, base, cands, Xt), f"{label} without {cands[i].element} {j + 1}")
                for (i, j), Xt in zip(trials, docs) for c in ctxs]
        out = d.model.simulate_many(jobs)
        best = None
        for m, Xt in enumerate(docs):
            part = out[m * len(ctxs):(m + 1) * len(ctxs)]
            if any(isinstance(x, Exception) for x in part):
                continue
            st = {c.name: x for c, x in zip(ctxs, part)}
            et = sse(d, ctxs, st)
            if et < 0.99 * e and (best is None or et < best[0]):
                best = (et, Xt, st, trials[m])
        if best is None:
            break
        log.info("  %s: order %d of %s dropped (periodic residual %.4g -> %.4g)", label, best[3][1] + 1,
                 cands[best[3][0]].element, e, best[0])
        e, Xs, sims = best[0], best[1], best[2]
    return Xs, sims, e


def select(d, ranked, orders, ctxs):
    """Which of an effect's candidates (same frequency family) is eccentric, and whether a
    second one is too: each candidate's responses at zero eccentricity (nominal layout),
    its own least-squares fit, then the best pair. ``ranked``: harmonic-pattern ranking
    (list of dicts with ``cand``); ``orders``: per candidate, the orders to fit (an
    order found insignificant in the time domain is dropped). Returns a dict: ``order`` (indices into ranked, best
    first), ``sse`` per index, ``X`` per index (single fits), ``pair`` (i, j, Xi, Xj, sse)
    or None, ``sse0`` and ``noise``; None if a simulation failed."""
    top = ranked[:MAX_RANKED]
    cands = [r["cand"] for r in top]
    H = d.opt.harmonics
    base = d.model.copy_doc()
    sims0 = {c.name: c.nominal for c in ctxs}
    zeros = [np.zeros(H, complex) for _ in cands]
    resp, cols = responses(d, base, cands, zeros, orders, ctxs, sims0, label="regressor")
    if resp is None:
        return None
    per = {i: [m for m, col in enumerate(cols) if col[0] == i] for i in range(len(cands))}
    per = {i: prune(d, ctxs, resp, cols, sims0, per[i], cands) or per[i] for i in per}
    single = {}
    e0 = None
    for i in per:
        coef, e0, e1 = solve(d, ctxs, resp, cols, sims0, per[i])
        single[i] = (e1, to_X(coef, cols, len(cands), H)[i])
    order = sorted(single, key=lambda i: single[i][0])
    noise = noise_sse(d, ctxs)
    out = {"order": order, "sse": {i: single[i][0] for i in single}, "X": {i: single[i][1] for i in single},
           "pair": None, "sse0": e0, "noise": noise, "resp": (resp, cols)}
    b = order[0]
    e_b = single[b][0]
    best_pair = None
    for i in order[1:]:
        coef, _, e2 = solve(d, ctxs, resp, cols, sims0, per[b] + per[i])
        Xp = to_X(coef, cols, len(cands), H)
        lim = PAIR_BLOWUP * max(np.max(np.abs(single[b][1])), np.max(np.abs(single[i][1])), 1e-12)
        if max(np.max(np.abs(Xp[b])), np.max(np.abs(Xp[i]))) > lim:
            continue   # degenerate: the two load the sensors alike
        if best_pair is None or e2 < best_pair[4]:
            best_pair = (b, i, Xp[b], Xp[i], e2)
    if best_pair is not None:
        excess = max(e_b - noise, 1e-12 * max(e_b, 1e-300))
        gain = (e_b - best_pair[4]) / excess
        log.info("  same frequency: %s alone leaves %.4g, with %s %.4g (noise %.4g: removes %.0f %% of the excess)",
                 cands[b].element, e_b, cands[best_pair[1]].element, best_pair[4], noise, 100 * gain)
        floor = 0.5 * Z_ORDER * sum(noise_drop(d, ctxs, cands[best_pair[1]], j)
                                    for j in {cols[m][1] for m in per[best_pair[1]]})
        # judged on the linear fit only against noise: what a large first source's nonlinear
        # response leaves can hide or fake a second one, so the share is judged once the
        # first is polished (_verify_pair)
        if e_b - best_pair[4] >= floor:
            out["pair"] = _verify_pair(d, cands, best_pair, per, resp, cols, ctxs, noise, single[b][1])
    return out


def reestimate(d, doc, label):
    """(doc, sims, [X per final effect]) with the periodic effects' coefficients polished
    in ``doc`` (two Gauss-Newton steps on the orders they have, from the coefficients
    ``doc`` holds), simulated on every run; None when there are none or no step helps.
    A drive effect (a dead zone, a shaft) changes how the periodic sources' lines pass
    through the line: their estimates, made without it, are polished in the model with
    it (:mod:`diagnosis.backlash`, :mod:`diagnosis.compliance`)."""
    from webline.diagnosis import layout_edit
    if not d.final_effects:
        return None
    H = d.opt.harmonics
    cands = [fe["ranked"][0]["cand"] for fe in d.final_effects]
    Xs0 = [layout_edit.current_fourier(doc, k.element, H)[:H] for k in cands]
    orders = [[j + 1 for j in np.flatnonzero(np.abs(X) > 0)] for X in Xs0]
    if not any(orders):
        return None
    try:
        Xs, sims_fit, _, _ = gauss_newton(d, doc, cands, Xs0, orders, d.fit_ctx(), steps=2, drop_rounds=0,
                                          label=f"{label}, re-estimate")
    except Exception as exc:  # noqa: BLE001 - no re-estimate, the screen goes on with the first one
        log.info("  %s: no re-estimate (%s)", label, (str(exc).splitlines() or [""])[0][:200])
        return None
    if sims_fit is None:
        return None
    doc2 = _doc(d, doc, cands, Xs)
    try:
        sims = d._simulate_all(doc2, f"refined +{label}, re-estimated")
    except Exception:  # noqa: BLE001
        return None
    return doc2, sims, Xs


def adopt(d, Xs):
    """The final effects take the coefficients ``Xs`` (one per effect, as :func:`reestimate`)."""
    for fe, X in zip(d.final_effects, Xs):
        fe["ranked"][0]["X"] = X


def lines_excess(d, ctxs, cand, orders, sims):
    """Weighted energy (units of :func:`sse`) of the periodic residual (data - ``sims``)
    at ``cand``'s orders, each run and sensor's lines fitted freely on its angle, less
    what fitting them to noise would take (:func:`noise_drop` per order and sensor)."""
    e = 0.0
    for c in ctxs:
        w = _weights(c)
        th = d._theta_refined(c, cand)
        by_noise = sum(noise_drop(d, [c], cand, j) for j in orders)   # per sensor of the run
        for s in c.sensors:
            r = _periodic(c, c.meas[s] - sims[c.name].columns[s])
            Y = est.fit_harmonics(r, th, orders, c.mask)
            e += w[s] ** 2 * 0.5 * float(np.sum(np.abs(Y) ** 2)) * float(c.mask.sum()) - by_noise
    return max(e, 1e-300)


def _verify_pair(d, cands, pair, per, resp, cols, ctxs, noise, Xb):
    """The pair as the linear fit at zero eccentricity proposes it, if it still holds
    once the first element's fit is polished (Gauss-Newton, simulated): what a large
    eccentricity's nonlinear response leaves is not a second source. The second
    element (linear from zero) must then remove PAIR_GAIN of the excess left and
    more than fitting noise with its coefficients would (Z_ORDER per order). None if not."""
    b, i, _, _, _ = pair
    H = d.opt.harmonics
    base = d.model.copy_doc()
    ords = [sorted({cols[m][1] for m in per[b]})]
    Xs, sims, e_b, _ = gauss_newton(d, base, [cands[b]], [Xb], ords, ctxs, steps=2, label="pair check",
                                    drop_rounds=1)
    if sims is None:
        return None
    coef, _, e2 = solve(d, ctxs, resp, cols, sims, per[i])
    drop = e_b - e2
    excess = max(e_b - noise, 1e-12 * max(e_b, 1e-300))
    ords_i = sorted({cols[m][1] for m in per[i]})
    floor = 0.5 * Z_ORDER * sum(noise_drop(d, ctxs, cands[i], j) for j in ords_i)
    lines = lines_excess(d, ctxs, cands[i], ords_i, sims)
    log.info("  pair check: %s polished leaves %.4g; %s removes %.4g more (%.0f %% of the excess, %.0f %% of "
             "what its lines hold above noise; noise would give %.3g)", cands[b].element, e_b, cands[i].element,
             drop, 100 * drop / excess, 100 * drop / lines, floor)
    # the excess over the whole periodic band holds what no source at this frequency can
    # remove (a line mode's ring, other families); what counts is the share of the second
    # element's own lines left (independent seed-9 c17: roller19 beside idler_u1 removed 28 %
    # of the excess, 11.6 x what noise would, while lc19 kept 99 % of the family's lines)
    if drop < PAIR_GAIN * min(excess, lines) or drop < floor:
        return None
    Xi = to_X(coef, cols, len(cands), H)[i]
    return (b, i, Xs[0], Xi, e2)
