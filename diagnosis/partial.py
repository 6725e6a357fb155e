"""What a diagnosis that stopped had computed: ``report_partial.json``.

A diagnosis of a few runs takes minutes, most of them in the refinement and its
model-form screen. When it stops before the end (Ctrl-C, a simulation that
fails, an internal error) the user keeps what the stages before had measured:
where model and data differ (the nominal gap per sensor, slow and periodic
parts), the periodic families the screen found and their frequencies, the
notes. Nothing in the file was checked by simulation, so no candidate is an
effect: ``checked`` is false on each, and the file's ``statement`` says so. A
finished diagnosis writes report.json and removes a partial file left by an
earlier stop in the same folder (:func:`remove`).
"""
import datetime
import json
import logging
from pathlib import Path

log = logging.getLogger("webline.diagnose")

SCHEMA = "webline-diagnose-partial-1"
FILE = "report_partial.json"


def reason(exc):
    """One line naming why the diagnosis stopped."""
    if isinstance(exc, KeyboardInterrupt):
        # a terminate signal arrives as an interrupt (diagnose_cmd) that names it
        return f"interrupted ({exc.args[0]})" if exc.args else "interrupted"
    text = (str(exc).splitlines() or [""])[0]
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def candidates(d):
    """The periodic sources found before any check: after the estimate stage its ranked
    candidates (best first) and run-outs, else the periodic screen's families in its order."""
    fit = [c for c in getattr(d, "ctx", []) if c.fit]

    def freqs(k):
        return {c.name: float(c.freq[k.key]) for c in fit if c.freq.get(k.key, 0.0) > 0}

    out = []
    if "estimate" in d.timings:
        for fe in getattr(d, "final_effects", []) or []:
            b = fe["ranked"][0]
            k = b["cand"]
            out.append({"element": k.element, "kind": k.kind, "stage": "estimate",
                        "candidates": [r["cand"].element for r in fe["ranked"]],
                        "fundamental_hz": freqs(k),
                        "run_out_m": {j + 1: float(abs(x)) for j, x in enumerate(b.get("X", [])) if abs(x) > 0},
                        "checked": False})
        return out
    for eff in getattr(d, "effects", []) or []:
        group = eff.get("group") or []
        if not group:
            continue
        best = eff.get("best") or group[0]
        k = best["cand"]
        out.append({"element": k.element, "kind": k.kind, "stage": "which",
                    "candidates": [g["cand"].element for g in [best] + [g for g in group if g is not best]],
                    "share_of_periodic_residual": float(best.get("share", 0.0)),
                    "fundamental_hz": freqs(k), "checked": False})
    return out


def checked(d):
    """The effects the refinement kept (each passed its check on the fit runs), once it finished."""
    if "refine" not in d.timings:
        return None
    out = [{"element": fe["ranked"][0]["cand"].element, "kind": fe["ranked"][0]["cand"].kind}
           for fe in getattr(d, "final_effects", []) or []]
    return out + [{"element": o["element"], "kind": o["kind"]} for o in getattr(d, "other", []) or []]


def build(d, stage, exc):
    """The partial report (dict) of Diagnosis ``d`` stopped in ``stage`` by ``exc``."""
    from webline.diagnosis import report as rep_mod
    ctx = getattr(d, "ctx", []) or []
    kept = checked(d)
    if kept is None:
        what = ("nothing here was checked by simulation, so the candidates are what the periodic screen "
                "found, not effects")
    else:
        what = ("the refinement had finished: the effects in 'checked_effects' passed its check on the fit runs "
                "(refined_layout.yaml holds them), but the report that says what is left was not built")
    doc = {
        "schema": SCHEMA,
        "complete": False,
        "written": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "stopped": {"stage": stage, "reason": reason(exc)},
        "stages_done": [s for s in d.timings if s not in (stage, "total")],
        "statement": (f"The diagnosis stopped in its stage '{stage}' ({reason(exc)}). What follows is what the "
                      f"stages before it had measured; {what}. Run the diagnosis to its end for a report."),
        "checked_effects": kept,
        "layout": str(d.layout_path),
        "runs": [{"name": c.name, "file": str(c.run.path), "holdout": not c.fit, "fs_hz": c.fs,
                  "sensors": c.sensors} for c in ctx],
        "where": rep_mod._where(d) if getattr(d, "where_report", None) else None,
        "candidates": candidates(d),
        "notes": list(d.notes),
        "timings_s": dict(d.timings),
    }
    model = getattr(d, "model", None)
    if model is not None:
        doc["simulations"] = model.stats()
    return doc


def write(d, stage, exc):
    """Write ``report_partial.json`` into ``d.out`` (if set and a run was loaded); its path, or
    None. Never raises: the stop that called it is what the user must see."""
    if d.out is None or not getattr(d, "ctx", None):
        return None
    try:
        doc = build(d, stage, exc)
        out = Path(d.out)
        out.mkdir(parents=True, exist_ok=True)
        path = out / FILE
        from webline.diagnosis import report as rep_mod
        path.write_text(json.dumps(rep_mod._clean(doc), indent=1, allow_nan=False))
        return path
    except Exception as err:  # noqa: BLE001 - a failed partial report must not hide the stop itself
        log.warning("could not write %s: %s", FILE, err)
        return None


def remove(out):
    """Remove a partial report an earlier stop left in ``out``: report.json replaces it."""
    p = Path(out) / FILE
    if p.exists():
        p.unlink()
