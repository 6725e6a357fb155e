"""A dead zone crossed by what the refined model already holds.

A drive's backlash shows only where its torque passes through zero. A speed
master between two zones of like tension carries little more than its
bearings' friction, and it is the periodic sources - an eccentric roller
swinging the S-wrap's tensions - that swing its torque through zero, cycle
after cycle: the dead zone then distorts every cycle the same way, a
deterministic effect the data can show well above noise. The other-effects
screen (:mod:`diagnosis.others`) runs on the nominal model, whose speed master
holds a steady torque, so there a backlash explains nothing (independent
seed 8: three S-wrap leaders with 1.2-2.8 deg of backlash beside eccentric
rollers, matched-filter SNR 30-159 without any ripple, screened at 0.0 %).

:func:`screen` runs after the periodic effects and the model form are in the
refined layout: for each ideal drive whose torque in that model reverses or
stays near zero (:func:`others.torque_reverses`), a stiff shaft (50 Hz, as the
deterministic screen) with a dead zone on its grid of widths is simulated on
every run; the width that leaves the least residual energy on the fit runs is
kept. The element's bearing friction is then scanned at that width
(:data:`FRICTION_FACTORS`): behind a rigid speed-controlled drive friction
leaves no trace (the loop supplies it), but behind a dead zone it decides how
long the element runs free before its drive catches it again, and a data
sheet's friction is rarely within a factor 2 (independent seed-44 c05: the
truth's own 0.78 deg dead zone at the sheet's friction left 1.9 x the rigid
model's residual energy, at the truth's 2.1 x friction 1.03 x). The best pair
is kept, the periodic effects re-estimated in the model with it, if it lowers the
residual, against the same re-estimate without the dead zone (what the polish
alone gains is no evidence), on some load cell block by block beyond noise
(:func:`compliance.rise_t` at most ``-FALL_T``) and passes the claim check
(:func:`claims.check`: lower residual, no sensor's NRMSE up by more than the
allowance, run by run). The rest goes to ``d.rejected`` with the numbers.
"""
import copy
import logging
import math

from webline.diagnosis import claims
from webline.diagnosis import layout_edit
from webline.diagnosis import others
from webline.diagnosis import regress

log = logging.getLogger("webline.diagnose")

GRID_DEG = others.BACKLASH_GRID_DEG    # total dead-zone widths tried, 0.4-4.9 deg in steps of 25 %
SHAFT_HZ = 50.0                         # a stiff shaft: the dead zone, not a compliance, is tested
FALL_T = 3.0                            # block-by-block fall of a sensor's squared error, in standard errors
MIN_FALL = 0.005                        # ... and of the fit runs' residual energy, relative
WIDTH_SPAN = 2.0                        # widths fitting within MIN_FALL of the best over more than this factor: not read
FRICTION_FACTORS = (0.5, 1.5, 2.0, 3.0)  # the element's bearing friction x its refined value (benchmark: x0.3-3)


def _energy(d, sims):
    """Residual energy over the fit runs' fit windows, all sensors, in N^2 s (a run counts
    by its duration, not its sample rate)."""
    return sum(c.energy(c.meas[s] - sims[c.name].columns[s]) for c in d.fit_ctx() for s in c.sensors)


def _friction(d, el):
    """``el``'s bearing friction in the refined layout, N*m*s/rad (0.0 where none is stated)."""
    v = (d.refined_doc.get("set") or {}).get(f"path.{el}.friction")
    if v is None:
        v = (layout_edit.element_entry(d.refined_doc, el) or {}).get("friction", 0.0)
    return float(others._q(v, "rot_damping"))


def width_read(widths):
    """What the grid's fits say of the width: the residual energies' spread (max - min) / min,
    the range of widths (deg) fitting within ``MIN_FALL`` of the best, and whether that range
    spans at most ``WIDTH_SPAN``. ``widths``: ``{"backlash_deg", "residual_energy_ratio"}`` rows,
    a ratio None where the engine could not run the width."""
    # a dead zone the swing never closes, or closes on one flank only, acts alike whatever its
    # width (seed-8 c24: 0.4 and 4.9 deg alike to 1e-12; seed-44 c05: all within 0.6 %, 3.9 deg
    # best for the truth's 0.78); the claim's own threshold says which fits are about as good
    ok = [(x["backlash_deg"], x["residual_energy_ratio"]) for x in widths if x["residual_energy_ratio"] is not None]
    if not ok:
        return None, None, False
    lo = min(e for _, e in ok)
    spread = (max(e for _, e in ok) - lo) / lo if lo > 0 else None
    near = [deg for deg, e in ok if e <= lo * (1.0 + MIN_FALL)]
    return spread, [min(near), max(near)], max(near) <= WIDTH_SPAN * min(near)


def backlash_doc(doc, spec, deg, friction=None):
    """``doc`` with a stiff shaft and a ``deg`` dead zone on ``spec``'s drive
    (:func:`others._drive_doc`), and the element's bearing friction set to ``friction``
    (N*m*s/rad) unless None."""
    doc = others._drive_doc(copy.deepcopy(doc), spec, SHAFT_HZ, math.radians(deg))
    if friction is not None:
        doc = layout_edit.with_set(doc, f"path.{spec[0]}.friction", f"{friction:.6g} N*m*s/rad")
    return doc


def screen(d):
    """Try a backlash on every ideal drive whose torque the refined model swings
    through or near zero; a claimed one joins ``d.other``, the refined layout and
    ``d.steps``. Records what was tried in ``d.backlash``."""
    from webline.diagnosis.compliance import rise_t
    d.backlash = []
    taken = others.non_ideal_drives(d)
    fit = d.fit_ctx()
    ref = rec_ref = None
    for spec in others.drive_candidates(d):
        el = spec[0]
        if el in taken:
            continue
        base = d.steps[-1]["sims"]
        reverses, rng = others.torque_reverses(d, el, sims=base)
        rec = {"element": el, "torque": rng, "reverses": reverses, "tried": [], "claimed": False}
        d.backlash.append(rec)
        if not reverses:
            continue
        e0 = _energy(d, base)
        best = None

        def tryout(deg, friction, what):
            nonlocal best
            doc = backlash_doc(d.refined_doc, spec, deg, friction)
            try:
                sims = d._simulate_all(doc, f"refined +{el} backlash {what}")
            except Exception as exc:  # noqa: BLE001 - a width the engine cannot run is no candidate
                log.info("  backlash of %s at %s failed: %s", el, what, (str(exc).splitlines() or [""])[0][:200])
                return None
            e = _energy(d, sims)
            if best is None or e < best[1]:
                best = (deg, e, sims, doc, friction)
            return e / e0 if e0 > 0 else None

        for deg in GRID_DEG:
            rec["tried"].append({"backlash_deg": deg, "residual_energy_ratio": tryout(deg, None, f"{deg:g} deg")})
        if best is None:
            continue
        b0 = _friction(d, el)
        rec["friction_nominal"] = b0
        rec["friction_tried"] = []
        if b0 > 0:
            deg = best[0]
            for f in FRICTION_FACTORS:
                rec["friction_tried"].append({"factor": f, "residual_energy_ratio": tryout(
                    deg, b0 * f, f"{deg:g} deg, friction x{f:g}")})
        widths = rec["tried"]
        if best[4] is not None:
            # the widths again at the friction taken: how long the element runs free, and so
            # which width fits, follows the friction (seed-44 c05: 0.4 deg best at the sheet's)
            rec["tried_at_friction"] = widths = [
                {"backlash_deg": deg, "residual_energy_ratio": tryout(
                    deg, best[4], f"{deg:g} deg, friction {best[4]:.3g} N*m*s/rad")} for deg in GRID_DEG]
        rec["width_spread"], rec["width_range_deg"], rec["width_identifiable"] = width_read(widths)
        if ref is None:
            # the same re-estimate without a dead zone: what the polish alone gains is no evidence
            got0 = regress.reestimate(d, d.refined_doc, "no backlash")
            e_got0 = _energy(d, got0[1]) if got0 is not None else math.inf
            ref = (e_got0, got0[1]) if e_got0 < e0 else (e0, base)
            rec_ref = {"residual_energy_ratio": ref[0] / e0 if e0 > 0 else None}
        rec["reestimated_without"] = rec_ref
        deg, e, sims, doc, friction = best
        # the periodic sources' estimates were made without the dead zone, which changes how
        # their lines pass through the S-wrap: re-estimated in the model with it
        got = regress.reestimate(d, doc, f"{el} backlash {deg:g} deg")
        e_got = _energy(d, got[1]) if got is not None else math.inf
        if e_got < e:
            (doc, sims, new_X), e = got, e_got
            rec["reestimated"] = True
        else:
            new_X = None
        sensors = list(dict.fromkeys(s for c in fit for s in c.sensors))
        t = {s: rise_t(fit, ref[1], sims, s) for s in sensors}
        fall = 1.0 - e / ref[0] if ref[0] > 0 else 0.0
        rec.update(best_deg=deg, best_friction=friction, energy_fall=fall, rise_t=t)
        fr_text = f", friction {friction:.3g} N*m*s/rad" if friction is not None else ""
        log.info("  backlash of %s (torque %s): best %g deg%s, residual energy %+.2f %%, block-by-block t %s",
                 el, rng, deg, fr_text, -100 * fall, ", ".join(f"{s} {v:+.2g}" for s, v in t.items()))
        if fall < MIN_FALL or min(t.values()) > -FALL_T:
            rec["why"] = (f"the best dead zone ({deg:g} deg{fr_text}), the periodic effects re-estimated with it, changes "
                          f"the residual energy by {-100 * fall:+.2g} % against the same re-estimate without it "
                          f"(needs -{100 * MIN_FALL:g} %); the error falls block by block at most "
                          f"{-min(t.values()):.2g} standard errors (needs {FALL_T:g})")
            d._reject(el, "backlash", "backlash screen", None, reason=rec["why"], backlash_deg=deg,
                      energy_fall=fall)
            continue
        chk = claims.check(d, base, sims, local=("all", None))
        if not chk["accepted"]:
            rec["why"] = chk["reason"]
            d._reject(el, "backlash", "backlash check", chk, backlash_deg=deg)
            continue
        Jm = others.motor_inertia(spec)
        eff = {
            "element": el, "kind": "backlash",
            "candidates": [{"element": el, "kind": "backlash", "explained_share": fall}],
            "fundamental_hz": None, "harmonics": [], "explained_share": fall,
            "confidence": float(min(1.0, fall / (fall + MIN_FALL))),
            "confidence_basis": (f"a {deg:g} deg dead zone, crossed by the torque the refined model gives the "
                                 f"drive ({rng}), lowers the fit runs' residual energy by {100 * fall:.2g} %, "
                                 f"block by block {-min(t.values()):.2g} standard errors on "
                                 f"{min(t, key=t.get).split('.')[0]}"),
            "parameters": {"backlash": {"estimated": math.radians(deg), "unit": "rad",
                                        "grid_deg": list(GRID_DEG),
                                        "identifiable": rec["width_identifiable"],
                                        "range_deg": rec["width_range_deg"],
                                        "residual_energy_spread_over_widths": rec["width_spread"]},
                           "motor_inertia": {"estimated": Jm, "unit": "kg*m^2"}},
            "detail": (f"{el} backlash {deg:g} deg (crossed by the refined model's torque {rng}){fr_text}"
                       if rec["width_identifiable"] else
                       f"{el} backlash (the refined model's torque {rng}; widths "
                       f"{rec['width_range_deg'][0]:g}-{rec['width_range_deg'][1]:g} deg fit within "
                       f"{100 * MIN_FALL:g} % of one another: the teeth meet on one side only, or never, and "
                       f"between contacts {el} runs free of its drive, so the width is not identifiable from "
                       f"these runs; a run that loads the drive, a speed ramp, would measure it){fr_text}"),
            "check": chk,
            "apply_doc": (lambda doc_, spec=spec, deg=deg, friction=friction:
                          backlash_doc(doc_, spec, deg, friction)),
        }
        if friction is not None:
            # behind the dead zone the element's own friction sets how long it runs free
            eff["parameters"]["friction"] = {"estimated": friction, "unit": "N*m*s/rad",
                                             "nominal": rec["friction_nominal"],
                                             "factors_tried": list(FRICTION_FACTORS)}
        rec["claimed"] = True
        ref = None   # the next drive is judged against the model with this one's dead zone
        if new_X is not None:
            regress.adopt(d, new_X)
        d.other = list(getattr(d, "other", []) or []) + [eff]
        d.refined_doc = doc
        d.steps.append({"added": el, "kind": "backlash", "sims": sims, "check": chk})
        log.info("  claimed: %s", eff["detail"])
