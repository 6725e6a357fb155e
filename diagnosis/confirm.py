"""The co-simulation confirms: the refined layout run once through the FMU co-simulation.

The diagnosis simulates every model on the fast engine (:mod:`orchestrator.engine`,
the compiled monolithic ODE). The FMU co-simulation stays the engine of
``webline run`` and the reference users' FMI tools see, so at the end the refined
layout (``refined_layout.yaml``) is run once through it for every run, fit and
held out, and the refined NRMSE of each load cell is computed the same way
(:func:`metrics_ext.gap_metrics` on the whole record) as the fast engine's.

How far the two may differ
--------------------------
For measured y and two simulations a (fast engine) and b (co-simulation), the
triangle inequality bounds the NRMSE difference exactly:

    |NRMSE(y, b) - NRMSE(y, a)| <= rms(b - a) / std(y)          (``bound``)

The fast engine is the monolithic reference to about 1e-6 (relative RMS of the
tension); the co-simulation's error against it is the accuracy table's
(docs/reference-accuracy-ssp.md, docs/performance.md): Gauss-Seidel at 2 ms,
0.22 % relative RMS on the worst load cell of the out-of-round EWL
(``EPS_COSIM`` = 2.2e-3), about 1e-6 on round rollers. So the co-simulation's
step alone may move the NRMSE by up to EPS_COSIM rms(T) / std(y)
(``step_error_allows``): large when the measured tension fluctuates little
around a big mean (0.2 % of 60 N is 0.13 N, more than a load cell's noise).

Two numbers per sensor and run:

* ``exceeds_threshold``: |difference| > max(0.02, 0.05 NRMSE_fast). 0.02
  absolute and 5 % relative are about what a reader of the gap table (2-3
  digits) would notice; below that the fast engine's gap is the co-simulation's.
* ``within_step_error``: ``tension_rel_rms`` = rms(b - a) / rms(a) <= EPS_COSIM,
  the number the accuracy table measures. Within it, a difference over the
  threshold is the co-simulation's known step error made visible by a record
  that fluctuates little (a smaller ``experiment.step`` shrinks it); beyond it
  the engines disagree on the model itself.

Either way an exceeded threshold is a warning note; the report keeps both gaps.
"""
import logging
import math
import time as _time

import numpy as np

log = logging.getLogger("webline.diagnose")

EPS_COSIM = 2.2e-3     # co-simulation relative RMS tension error, GS at 2 ms, worst load cell (accuracy table)
ABS_NRMSE = 0.02       # NRMSE difference always tolerated
REL_NRMSE = 0.05       # relative NRMSE difference always tolerated


def threshold(nrmse_fast):
    """NRMSE difference (fast engine vs co-simulation) that draws a warning."""
    return max(ABS_NRMSE, REL_NRMSE * abs(nrmse_fast))


def _rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


def run(d):
    """Run ``d.refined_doc`` through the co-simulation for every run of diagnosis ``d``
    (after refine); sets ``d.confirm_result`` (the report's ``confirm`` section). A failure
    is noted, never raised: the fast-engine result stands."""
    from webline.diagnosis import metrics_ext as mx
    last = d.steps[-1]
    t0 = _time.perf_counter()
    per_run = {}
    try:
        for c in d.ctx:
            sim = d.model.confirm(c.run, d.refined_doc, label="confirm, co-simulation")
            fast = last["sims"][c.name]
            per_run[c.name] = {}
            for s in c.sensors:
                m_fast = last["metrics"][c.name][s]
                m_co = mx.gap_metrics(c.t, c.meas[s], sim.columns[s], c.fs, c.mask)
                a, b, y = fast.columns[s], sim.columns[s], c.meas[s]
                diff = m_co["nrmse"] - m_fast["nrmse"]
                y_std, a_rms = float(np.std(y)), _rms(a)
                rel = _rms(b - a) / a_rms if a_rms > 0 else math.inf
                per_run[c.name][s] = {
                    "holdout": not c.fit,
                    "refined_fast": m_fast["nrmse"], "refined_cosim": m_co["nrmse"],
                    "difference": diff,
                    "relative_difference": diff / m_fast["nrmse"] if m_fast["nrmse"] else None,
                    "bound": _rms(b - a) / y_std if y_std > 0 else None,
                    "step_error_allows": EPS_COSIM * a_rms / y_std if y_std > 0 else None,
                    "tension_rel_rms": rel,
                    "threshold": threshold(m_fast["nrmse"]),
                    "exceeds_threshold": bool(abs(diff) > threshold(m_fast["nrmse"])),
                    "within_step_error": bool(rel <= EPS_COSIM),
                    "_m_cosim": m_co,
                }
    except Exception as exc:  # noqa: BLE001 - any failure of the check must leave the report
        wall = _time.perf_counter() - t0
        msg = f"co-simulation check failed ({type(exc).__name__}: {exc}); the fast engine's result stands"
        log.warning("  %s", msg)
        d.notes.append(msg)
        d.confirm_result = {"status": "failed", "error": f"{type(exc).__name__}: {exc}", "wall_s": wall}
        return
    wall = _time.perf_counter() - t0
    fit = [c for c in d.ctx if c.fit]
    hold = [c for c in d.ctx if not c.fit]
    sensors = list(dict.fromkeys(s for c in d.ctx for s in c.sensors))
    co_step = {"metrics": {r: {s: v["_m_cosim"] for s, v in per.items()} for r, per in per_run.items()}}

    def agg(ctxs):
        from webline.diagnosis.report import _agg
        if not ctxs:
            return None
        out = {}
        for s in sensors:
            f, b = _agg(last, ctxs, s), _agg(co_step, ctxs, s)
            if f is None or b is None:
                continue
            diff = b["nrmse"] - f["nrmse"]
            worst = [per_run[c.name][s] for c in ctxs if s in per_run[c.name]]
            out[s] = {"refined_fast": f["nrmse"], "refined_cosim": b["nrmse"], "difference": diff,
                      "relative_difference": diff / f["nrmse"] if f["nrmse"] else None,
                      "tension_rel_rms": max(w["tension_rel_rms"] for w in worst)}
        return out

    flagged = [(r, s, v) for r, per in per_run.items() for s, v in per.items() if v["exceeds_threshold"]]
    ins = agg(fit)
    text = _text(ins, flagged)
    log.info("  %s (co-simulation %.1f s)", text, wall)
    if flagged:
        for r, s, v in flagged:
            why = (f"the tensions differ by {100 * v['tension_rel_rms']:.2g} % RMS, within the co-simulation's "
                   f"step error ({100 * EPS_COSIM:.2g} % at 2 ms, accuracy table), which this record's small "
                   f"fluctuation makes visible (a smaller experiment.step shrinks it)" if v["within_step_error"] else
                   f"the tensions differ by {100 * v['tension_rel_rms']:.2g} % RMS, more than the co-simulation's "
                   f"step error ({100 * EPS_COSIM:.2g} % at 2 ms): the engines disagree on this model")
            d.notes.append(f"warning: run {r}, {s}: refined NRMSE {v['refined_cosim']:.3g} in the co-simulation, "
                           f"{v['refined_fast']:.3g} on the fast engine (difference {v['difference']:+.3g}, over the "
                           f"{v['threshold']:.2g} threshold); {why}")
    d.confirm_result = {
        "status": "done",
        "agrees": not flagged,
        "text": text,
        "wall_s": wall,
        "eps_cosim": EPS_COSIM,
        "runs": per_run,
        "in_sample": ins,
        "out_of_sample": agg(hold),
    }


def _text(ins, flagged):
    parts = []
    for s, v in (ins or {}).items():
        rel = v["relative_difference"]
        parts.append(f"refined NRMSE {s.removesuffix('.T')} {v['refined_cosim']:#.3g} (fast engine "
                     f"{v['refined_fast']:#.3g}), difference "
                     + (_pct(rel) if rel is not None else f"{v['difference']:.2g}"))
    if not flagged:
        head = "co-simulation confirms"
    elif all(v["within_step_error"] for _, _, v in flagged):
        head = "co-simulation differs, within its own step error (see notes)"
    else:
        head = "co-simulation differs beyond its step error (see notes)"
    return head + ": " + "; ".join(parts)


def _pct(rel):
    p = 100 * abs(rel)
    return f"{p:.0f} %" if p >= 10 else f"{p:#.2g} %"
