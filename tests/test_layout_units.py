"""webline.orchestrator.units: web-handling units, dimension checks, errors naming where."""
import math

import pytest

from webline.orchestrator.units import QuantityError, convert, quantity, si_factor


@pytest.mark.parametrize("text, dimension, si", [
    ("200 ft/min", "speed", 1.016),
    ("200 fpm", "speed", 1.016),
    ("200 FPM", "speed", 1.016),
    ("20 lbf", "force", 88.9644323),
    ("20 lbf", "tension", 88.9644323),
    ("6.375 in", "length", 0.161925),
    ("7.5 mil", "thickness", 7.5 * 25.4e-6),
    ("2 mils", "length", 50.8e-6),
    ("0.19 mm", "thickness", 0.19e-3),
    ("2 (ft/min)/lbf", "tension_gain", 2 * 0.00508 / 4.4482216152605),
    ("10 1/s", "rate", 10.0),
    ("30 deg", "angle", math.pi / 6),
    ("3.5 lb*ft^2", "inertia", 3.5 * 0.45359237 * 0.3048 ** 2),
    ("200 MPa", "modulus", 2.0e8),
    ("30 (ft/min)/s", "acceleration", 30 * 0.00508),
    ("5 ms", "time", 5.0e-3),
    ("1e-3", "time", 1.0e-3),  # YAML 1.1 reads 1e-3 as a string: still a number, SI
])
def test_conversions_to_si(text, dimension, si):
    assert quantity(text, dimension) == pytest.approx(si, rel=1e-9)


def test_numbers_are_si():
    assert quantity(1.016, "speed") == 1.016
    assert quantity(20, "force") == 20.0


def test_pli_is_tension_per_width():
    width = quantity("6 in", "length")
    assert quantity("1.5 PLI", "tension", width=width) == pytest.approx(40.03399, abs=1e-4)
    assert quantity("1.5 pli", "tension", width=width) == pytest.approx(9 * 4.4482216152605)
    assert quantity("262.69 N/m", "tension", width=1.0) == pytest.approx(262.69)
    with pytest.raises(QuantityError, match="tension per width"):
        quantity("1.5 PLI", "tension")  # no width known
    with pytest.raises(QuantityError, match="expected a force"):
        quantity("1.5 PLI", "force", width=width)  # a plain force field takes no per-width value


def test_wrong_dimension_names_where_and_what():
    with pytest.raises(QuantityError) as e:
        quantity("200 kg", "speed", "experiment.line_speed")
    msg = str(e.value)
    assert msg.startswith("experiment.line_speed: expected a speed")
    assert "200 kg" in msg and "[mass]" in msg and "ft/min" in msg


@pytest.mark.parametrize("bad", ["3 blargs", "", "m/", True, None, [1], "nan m", float("inf")])
def test_unreadable_values_are_errors(bad):
    with pytest.raises(QuantityError):
        quantity(bad, "length", "x")


def test_display_conversion():
    assert convert(1.016, "ft/min") == pytest.approx(200.0)
    assert si_factor("lbf") == pytest.approx(4.4482216152605)
