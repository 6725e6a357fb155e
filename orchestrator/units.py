"""Units of a line layout: a pint registry with web-handling units, and one parser.

Layouts may give any physical value as a string with a unit (``"200 ft/min"``,
``"6.375 in"``, ``"2 (ft/min)/lbf"``) or as a plain number, which is taken as
SI (m, s, N, kg, rad and their combinations). :func:`quantity` parses a value,
checks its dimension and returns the SI float the FMUs use.

Web-handling units added to pint's defaults:

* ``fpm`` / ``FPM``: feet per minute (``ft/min`` works as well);
* ``PLI`` / ``pli``: pounds-force per linear inch of web width. A PLI value is
  a tension *per width*; :func:`quantity` with dimension ``"tension"``
  multiplies it by the web width to give newtons;
* ``mil`` / ``mils``: a thousandth of an inch (pint's own ``mil`` is an angle;
  a web handler always means thickness, so it is rewritten to ``thou``);
* ``(ft/min)/lbf`` and the like for tension-loop gains (dimension
  ``"tension_gain"``, SI unit (m/s)/N = m/(s.N)).
"""
import functools
import math
import re
import warnings

import pint

ureg = pint.UnitRegistry()
with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    ureg.define("fpm = foot / minute = FPM")
    ureg.define("PLI = pound_force / inch = pli")
    ureg.define("mpm = meter / minute")
Q_ = ureg.Quantity

_MIL = re.compile(r"\bmils?\b")


class QuantityError(ValueError):
    """A value that is not a number or quantity of the expected dimension."""


# name -> (pint dimensionality, SI unit as written in FMUs/docs, example)
DIMENSIONS = {
    "length": ("[length]", "m", "1.5 in"),
    "thickness": ("[length]", "m", "0.19 mm"),
    "time": ("[time]", "s", "20 s"),
    "speed": ("[length]/[time]", "m/s", "200 ft/min"),
    "acceleration": ("[length]/[time]**2", "m/s2", "40 (ft/min)/s"),
    "force": ("[force]", "N", "20 lbf"),
    "tension": ("[force]", "N", "20 lbf' or '1.5 PLI"),
    "tension_per_width": ("[force]/[length]", "N/m", "1.5 PLI"),
    "tension_rate": ("[force]/[time]", "N/s", "5 lbf/s"),
    "tension_gain": ("[length]/[time]/[force]", "m/(s.N)", "2 (ft/min)/lbf"),
    "mass": ("[mass]", "kg", "1.2 kg"),
    "inertia": ("[mass]*[length]**2", "kg.m2", "3.5 lb*ft^2"),
    "density": ("[mass]/[length]**3", "kg/m3", "390 kg/m^3"),
    "modulus": ("[force]/[length]**2", "Pa", "200 MPa"),
    "stiffness_axial": ("[force]", "N", "5800 N"),  # E*A
    "rate": ("1/[time]", "1/s", "10 1/s"),
    "frequency": ("1/[time]", "Hz", "0.97 Hz"),
    "angle": ("", "rad", "30 deg"),
    "dimensionless": ("", "1", "0.5"),
    "torque": ("[force]*[length]", "N.m", "5 N*m"),
    "rot_damping": ("[force]*[length]*[time]", "N.m.s/rad", "1e-3 N*m*s/rad"),
    "rot_stiffness": ("[force]*[length]", "N.m/rad", "2000 N*m/rad"),
}


def parse(value):
    """A pint Quantity from a string such as ``"200 ft/min"`` or a number (dimensionless)."""
    if isinstance(value, bool):
        raise QuantityError(f"expected a number or a quantity with a unit, got {value!r}")
    if isinstance(value, pint.Quantity):
        return value
    if isinstance(value, (int, float)):
        return Q_(float(value))
    if not isinstance(value, str):
        raise QuantityError(f"expected a number or a quantity with a unit, got {value!r}")
    text = _MIL.sub("thou", value.strip())
    if not text:
        raise QuantityError("expected a number or a quantity with a unit, got an empty string")
    try:
        q = ureg.parse_expression(text)
    except Exception as exc:  # pint raises several error types (undefined unit, syntax)
        raise QuantityError(f"cannot read {value!r} as a quantity ({_short(exc)})") from None
    if not isinstance(q, pint.Quantity):  # a bare number in a string
        q = Q_(float(q))
    return q


def _short(exc):
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


def _dim(q):
    d = str(q.dimensionality)
    return "dimensionless" if d == "dimensionless" else d


def quantity(value, dimension, where=None, *, width=None):
    """SI float of ``value`` (number = SI, or a string with a unit) of ``dimension``.

    ``dimension`` is a name of :data:`DIMENSIONS` (``"speed"``, ``"length"``,
    ``"tension_gain"``...) or a pint dimensionality string (``"[length]/[time]"``).
    For ``"tension"`` a tension per width (``"1.5 PLI"``, ``"250 N/m"``) is
    accepted and multiplied by ``width`` (m). Errors are :class:`QuantityError`
    whose message starts with ``where`` when given.
    """
    try:
        return _quantity(value, dimension, width)
    except QuantityError as exc:
        if where:
            raise QuantityError(f"{where}: {exc}") from None
        raise


def _quantity(value, dimension, width):
    if isinstance(value, str):
        # a layout is read again for every variant a diagnosis simulates: the same few
        # hundred strings each time, and pint's parser is most of a system's build time
        return _quantity_of_text(value, dimension, width)
    return _quantity_uncached(value, dimension, width)


@functools.lru_cache(maxsize=8192)
def _quantity_of_text(value, dimension, width):
    return _quantity_uncached(value, dimension, width)


def _quantity_uncached(value, dimension, width):
    if dimension in DIMENSIONS:
        dims, si_unit, example = DIMENSIONS[dimension]
    else:
        dims, si_unit, example = dimension, None, None
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return _finite(float(value), value)
    q = parse(value)
    if q.unitless:  # "1e-3" (a YAML 1.1 string, not a float) or "200": a number, SI
        return _finite(float(q.magnitude), value)
    target = ureg.get_dimensionality(dims) if dims else ureg.get_dimensionality("")
    if q.dimensionality == target:
        x = float(q.to_base_units().magnitude)
    elif dimension == "tension" and q.dimensionality == ureg.get_dimensionality("[force]/[length]"):
        if width is None:
            raise QuantityError(f"{value!r} is a tension per width; it needs a valid web width")
        x = float(q.to_base_units().magnitude) * width
    else:
        what = dimension if dimension in DIMENSIONS else f"a quantity of dimension {dims}"
        hint = f" (e.g. '{example}', or a number in {si_unit})" if example else ""
        raise QuantityError(f"expected a {what}{hint}, got {value!r} ({_dim(q)})")
    return _finite(x, value)


def _finite(x, value):
    if not math.isfinite(x):
        raise QuantityError(f"must be finite (got {value!r})")
    return x


def convert(value_si, unit):
    """An SI value expressed in ``unit`` (e.g. ``convert(1.016, "ft/min") == 200``).

    The SI unit is taken as the base units of ``unit``'s dimension."""
    u = parse(f"1 {unit}")
    return value_si / float(u.to_base_units().magnitude)


@functools.lru_cache(maxsize=1024)   # unit strings repeat in every layout a diagnosis builds
def si_factor(unit):
    """SI value of one ``unit`` (``si_factor("lbf") == 4.448...``)."""
    return float(parse(f"1 {unit}").to_base_units().magnitude)


@functools.lru_cache(maxsize=1024)
def dimension_of(unit):
    """Name in :data:`DIMENSIONS` of the first dimension ``unit`` matches, or None."""
    d = parse(f"1 {unit}").dimensionality
    for name, (dims, _, _) in DIMENSIONS.items():
        if d == ureg.get_dimensionality(dims or ""):
            return name
    return None
