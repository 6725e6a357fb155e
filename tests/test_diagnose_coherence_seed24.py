"""A roll whose line crosses a taken family's line is judged on the orders it can be told by.

Independent seed 24, c17 (simulated by the fast engine, measured through coloured
noise; the diagnosis runs blind in a subprocess): roller9 eccentric (0.18 mm at
order 1, 0.10 mm at order 5) and the rewind out of round (0.078 mm at order 2,
0.059 mm at order 6), one fit run ramped 245 -> 196 -> 245 ft/min and one held out.
The rewind starts at 3 in, twice roller9's radius, so in the first steady window its
order 2 sits on roller9's order 1 and slides off as the roll grows. roller9 is taken
first; the rewind's coherence, with roller9 fitted beside it segment by segment,
read 0.71 (0.75 asked) because its order 2 read 0.12-0.33 in that window and
0.9-1.1 in the two others. Orders within a quarter of a segment resolution of a
taken family's line are now set aside (``pipeline._apart``): 0.94, and the rewind is
taken.
"""
import pytest

from records import assert_no_sensor_worse, independent_cases

SEED = 24
pytestmark = pytest.mark.slow  # whole blind diagnoses of several minutes each: `make test-all`


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    return independent_cases(tmp_path_factory.mktemp("coherence24"), SEED, ("c17",))["c17"]


def test_the_case_is_the_one_drawn(case):
    kinds = sorted((e["element"], e["kind"]) for e in case["truth"]["effects"])
    assert kinds == [("rewind", "out_of_round"), ("roller9", "eccentricity")], kinds


def test_both_sources_are_found(case):
    rep = case["report"]
    found = [(e["element"], e["kind"]) for e in rep["effects"]]
    assert ("rewind", "out_of_round") in found, rep["verdict"]
    ecc = [e for e in rep["effects"] if e["kind"] == "eccentricity"]
    assert ecc and any("roller9" in [c.get("element") for c in (e.get("candidates") or [])] + [e["element"]]
                       for e in ecc), rep["verdict"]
    assert_no_sensor_worse(rep["gap"])
