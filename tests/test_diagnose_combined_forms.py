"""A run-out in one tension zone whose line the model passes to the other zone only in two forms at once.

An eccentric roller19 (independent seed 10, c19: the rewind zone, 3.92 Hz) shows
on both load cells. The truth's speed loops feed forward the tension set point
and its web has 2.5 ms of Kelvin-Voigt damping, among other forms and
parameters (simulated by the fast engine, measured through coloured noise;
the diagnosis runs blind in a subprocess). In either form alone the model
passes roller19's line to lc9 too strongly or not at all, and a phantom
idler_u1 at the same frequency in the unwind zone made up the difference. The
structure screen now tries the feed-forward forms together with web damping
and load-cell filters, and judges the set without the second source in the
form the full set fits best. c19 is the case the rule was built on.
"""
import pytest

from records import independent_cases

SEED = 10


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    return independent_cases(tmp_path_factory.mktemp("combined_forms"), SEED, ("c19",))["c19"]


def test_the_case_is_the_one_drawn(case):
    kinds = [(e["element"], e["kind"]) for e in case["truth"]["effects"]]
    assert kinds == [("roller19", "eccentricity")], kinds


def test_combined_forms_are_screened(case):
    names = {r["name"] for r in case["report"]["structure"]["screened"]}
    for a in ("feedforward none", "feedforward reference"):
        for b in ("web damping 2 ms", "load-cell filter order 2"):
            assert f"{a} + {b}" in names, sorted(names)


def test_roller19_alone_in_a_combined_form(case):
    rep = case["report"]
    periodic = [e for e in rep["effects"] if e["kind"] in ("eccentricity", "out_of_round")]
    assert [e["element"] for e in periodic] == ["roller19"], rep["verdict"]
    st = rep["structure"]
    assert "+" in st["chosen"], st["chosen"]
    # with the phantom, in a single form, lc19 closed 0.60 of its gap to the noise floor (1.01 ->
    # 0.47, floor 0.12); the target is 0.7
    g = rep["gap"]["lc19.T"]
    assert g["closed_share"] >= 0.7, g
