"""Parameter tolerances of a line layout: the model as a data sheet knows it.

A layout written from a data sheet has its web stiffness, span lengths and
inertias to within a tolerance, not exactly. Two users of one rule:

* the independent benchmark draws a truth whose parameters differ from the
  nominal layout by such scale factors;
* the transfer screen (:mod:`diagnosis.transfer`) draws an ensemble of lines
  within :data:`DATA_SHEET` to ask whether what the fit runs taught carries
  to a run at another speed.

Both turn scale factors into the dotted ``set`` entries of a derived layout
(:func:`scaled_set`), in units, so that the derived layout reads as exactly
what was changed.
"""
import copy
import math

#: relative half-widths: web EA, rotating inertias (roller inertia, roll core inertia),
#: span lengths. Wide enough for a layout read off a data sheet.
DATA_SHEET = {"EA": 0.15, "inertia": 0.30, "span": 0.05}


def _q(value, dim):
    from webline.orchestrator.units import quantity
    return float(quantity(value, dim))


def _el(doc, name):
    return next(x for x in doc["path"] if x["name"] == name)


def scaled_set(line_doc, EA=1.0, inertia=None, friction=None, span=None, rewind_radius=1.0):
    """Dotted ``set`` entries (unit strings) that scale the layout ``line_doc``'s
    web EA (or E), each element's inertia (``core_inertia``, ``inertia`` or
    ``mass``), bearing friction and span length, and the rewind's radius, by the
    given factors ({element: factor}; an element left out keeps its value)."""
    inertia, friction, span = inertia or {}, friction or {}, span or {}
    s = {}
    web = line_doc["web"]
    if EA != 1.0:
        if "EA" in web:
            s["web.EA"] = f"{_q(web['EA'], 'force') * EA:.6g} N"
        else:
            s["web.E"] = f"{_q(web['E'], 'modulus') * EA:.6g} Pa"
    for e in line_doc["path"]:
        n = e["name"]
        k = inertia.get(n)
        if k is not None:
            if "core_inertia" in e:
                s[f"path.{n}.core_inertia"] = f"{_q(e['core_inertia'], 'inertia') * k:.6g} kg*m^2"
            elif "inertia" in e:
                s[f"path.{n}.inertia"] = f"{_q(e['inertia'], 'inertia') * k:.6g} kg*m^2"
            elif "mass" in e:
                s[f"path.{n}.mass"] = f"{_q(e['mass'], 'mass') * k:.6g} kg"
        if n in friction and "friction" in e:
            s[f"path.{n}.friction"] = f"{_q(e['friction'], 'rot_damping') * friction[n]:.6g} N*m*s/rad"
        if n in span and "span" in e:
            sp = e["span"]
            L = _q(sp["length"] if isinstance(sp, dict) else sp, "length") * span[n]
            s[f"path.{n}.span.length" if isinstance(sp, dict) else f"path.{n}.span"] = f"{L:.6g} m"
        if e["type"] == "rewind" and rewind_radius != 1.0:
            s[f"path.{n}.radius"] = f"{_q(e['radius'], 'length') * rewind_radius:.6g} m"
    return s


def applied(line_doc, s):
    """``line_doc`` with the dotted entries ``s`` of :func:`scaled_set` written in."""
    doc = copy.deepcopy(line_doc)
    for key, v in s.items():
        parts = key.split(".")
        if parts[0] == "path":
            el = _el(doc, parts[1])
            if len(parts) == 4:
                el[parts[2]][parts[3]] = v
            else:
                el[parts[2]] = v
        else:
            doc[parts[0]][parts[1]] = v
    return doc


def draw(rng, line_doc, tol=None):
    """One line within the tolerances ``tol`` (default :data:`DATA_SHEET`): scale
    factors drawn uniformly in 1 +- tol, each element's independently. Returns
    the keyword arguments of :func:`scaled_set`."""
    tol = DATA_SHEET if tol is None else tol
    path = line_doc["path"]

    def u(w):
        return float(rng.uniform(1.0 - w, 1.0 + w))
    return {"EA": u(tol.get("EA", 0.0)),
            "inertia": {e["name"]: u(tol.get("inertia", 0.0)) for e in path},
            "span": {e["name"]: u(tol.get("span", 0.0)) for e in path if "span" in e}}


#: what a data sheet leaves open about a line's fast dynamics: the load cells'
#: amplifier filter (its time constant x0.5-2, first or second order), the
#: drives' current loops (a lag of 0-5 ms) and the web's internal damping
#: (Kelvin-Voigt, 0.3-5 ms, or none). Above ~10 Hz these move an order's
#: response as much as the parameters do.
DYNAMICS = {"filter_scale": (0.5, 2.0), "filter_damping": (0.5, 0.9), "current_lag_s": (0.0, 5e-3),
            "web_damping_s": (0.3e-3, 5e-3)}


def draw_dynamics(rng, line_doc, ranges=None):
    """Dotted ``set`` entries of one draw of the fast dynamics within ``ranges``
    (default :data:`DYNAMICS`): each load cell's filter (time constant scaled,
    order 1 or 2), each speed loop's current lag, the web's damping (or none)."""
    r = DYNAMICS if ranges is None else ranges
    s = {}
    for lc, spec in (line_doc.get("sensors") or {}).items():
        tau = _q((spec or {}).get("filter", "5 ms"), "time") * log_uniform(rng, *r["filter_scale"])
        s[f"sensors.{lc}.filter"] = f"{1e3 * tau:.4g} ms"
        if rng.uniform() < 0.5:
            s[f"sensors.{lc}.filter_order"] = 2
            s[f"sensors.{lc}.filter_damping"] = f"{rng.uniform(*r['filter_damping']):.3g}"
    for el in ((line_doc.get("drives") or {}).get("speed_loops") or {}):
        s[f"drives.speed_loops.{el}.current_lag"] = f"{1e3 * rng.uniform(*r['current_lag_s']):.4g} ms"
    if rng.uniform() < 0.5:
        s["web.damping"] = f"{1e3 * log_uniform(rng, *r['web_damping_s']):.4g} ms"
    return s


def log_uniform(rng, lo, hi):
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
