"""Edits of a layout as derived layouts: ``base`` + a ``set`` block of dotted keys.

The diagnosis never rewrites the user's layout. Every model it simulates
(sensitivity, screening, refined) is a small derived layout::

    base: ../scenarios/ewl.yaml
    set:
      path.idler_u1.eccentricity.C: [42.1 um, 3.2 um, ...]
      path.idler_u1.eccentricity.psi: [0.52 rad, ...]

which ``orchestrator.layout`` merges onto the base (docs/layout.md), so the
refined layout reads as exactly what the diagnosis added.
"""
import copy
import math
from pathlib import Path

import numpy as np


def base_doc(layout_path):
    return {"base": str(Path(layout_path).resolve()), "set": {}}


def _plain_base(doc):
    from webline.orchestrator.layout_source import load_located, plain
    return plain(load_located(Path(doc["base"])))


def element_entry(doc, element):
    data = _plain_base(doc)
    for e in data.get("path", []):
        if isinstance(e, dict) and e.get("name") == element:
            return e
    return None


def current_fourier(doc, element, n):
    """Complex coefficients X_j = C_j exp(i psi_j) of ``element`` in ``doc`` (base + set), length n."""
    from webline.orchestrator.units import quantity
    s = doc.get("set", {})
    kC, kp = f"path.{element}.eccentricity.C", f"path.{element}.eccentricity.psi"
    if kC in s:
        C, psi = s[kC], s.get(kp, [])
    else:
        e = element_entry(doc, element) or {}
        ecc = e.get("eccentricity") or {}
        C, psi = ecc.get("C", []), ecc.get("psi", [])
    X = np.zeros(max(n, len(C)), complex)
    for j, c in enumerate(C):
        p = quantity(psi[j], "angle") if j < len(psi) else 0.0
        X[j] = quantity(c, "length") * np.exp(1j * p)
    return X


def with_fourier(doc, cand, C, psi, add=False):
    """``doc`` with the eccentricity of ``cand.element`` set to (or, ``add``, increased by)
    the series sum_j C_j sin(j theta + psi_j)."""
    doc = copy.deepcopy(doc)
    X = np.asarray(C, float) * np.exp(1j * np.asarray(psi, float))
    if add:
        old = current_fourier(doc, cand.element, len(X))
        old[:len(X)] += X
        X = old
    X = X[:8]
    doc.setdefault("set", {})
    doc["set"][f"path.{cand.element}.eccentricity.C"] = [f"{abs(x) * 1e6:.6g} um" for x in X]
    doc["set"][f"path.{cand.element}.eccentricity.psi"] = [f"{_wrap(np.angle(x)):.6g} rad" for x in X]
    return doc


def with_set(doc, key, value):
    doc = copy.deepcopy(doc)
    doc.setdefault("set", {})[key] = value
    return doc


def with_sets(doc, sets):
    """Copy of ``doc`` with every dotted entry of ``sets`` written, in order: :func:`with_set`
    for many entries with one copy of the document."""
    doc = copy.deepcopy(doc)
    doc.setdefault("set", {}).update(sets)
    return doc


def _wrap(x):
    return (x + math.pi) % (2 * math.pi) - math.pi


def relative_to(doc, folder):
    """Copy of ``doc`` whose ``base`` is relative to ``folder`` (where it will be written)."""
    import os
    doc = copy.deepcopy(doc)
    try:
        doc["base"] = os.path.relpath(doc["base"], Path(folder).resolve())
    except ValueError:
        pass
    return doc
