"""Parsimony on independent seed 20 (issue 9): a leader shaft in a second source's
place is not a simpler account; a weak real second source is judged against the
periodic part of the gap.

c16 (simulated by the fast engine, measured through coloured
noise; the diagnosis runs blind in a subprocess): roller9 eccentric (0.89 mm,
equal radius with idler_u1 in the unwind zone and with idler_r1 and roller19 in the
rewind zone); the truth's speed loops feed forward nothing, with 3.2 ms of web
damping and second-order load cells. The layout's form passes too little of the
line through the S-wrap, so a rewind-zone roller19 is fitted beside it. Parsimony
then took a leader shaft tuned to 7.51 Hz in roller19's place (sum of NRMSE^2 0.158
against 0.121 with both sources, 1.31 x) and claimed it as a compliance, the
truth having none. A shaft in a source's place holds as many effects as the full
set, so it may fit worse by no more than SHAFT_MARGIN; the rigid form without
roller19 is taken instead (since the thirty-ninth session: a line within the data
sheet's tolerances in that form, without roller19).

c24: idler_u1 (0.098 mm; on lc9 0.20 N rms against the truth's 0.52 N of mostly
1/f noise) and roller19 (0.099 mm, orders 1, 3-5) eccentric, all four rollers at
one frequency. 'acceleration feedforward' without the unwind-zone source is 2.4 %
worse on lc9, inside what parsimony allows; the source's own lines it leaves
carried 3.5 % of lc9's whole gap (5 % keeps a source) and it was dropped. Against
the gap's periodic part, the part a rotating source can explain, they carry 7.0 %.
"""
import pytest

from records import REWIND_ZONE, UNWIND_ZONE, assert_no_sensor_worse, independent_cases

SEED = 20
pytestmark = pytest.mark.slow  # whole blind diagnoses of several minutes each: `make test-all`


@pytest.fixture(scope="module")
def cases(tmp_path_factory):
    return independent_cases(tmp_path_factory.mktemp("parsimony20"), SEED, ("c16", "c24"))


def test_the_cases_are_the_ones_drawn(cases):
    kinds = {cid: [(e["element"], e["kind"]) for e in c["truth"]["effects"]] for cid, c in cases.items()}
    assert kinds == {"c16": [("roller9", "eccentricity")],
                     "c24": [("idler_u1", "eccentricity"), ("roller19", "eccentricity")]}, kinds


def test_one_source_and_no_shaft(cases):
    rep = cases["c16"]["report"]
    found = [(e["element"], e["kind"]) for e in rep["effects"]]
    assert len(found) == 1 and found[0][0] in UNWIND_ZONE and found[0][1] == "eccentricity", rep["verdict"]
    # no shaft took the phantom's place: the set taken without it is a rigid form (since the
    # thirty-ninth session a line within the data sheet's tolerances wins before the shaft
    # is tried; the shaft's refusal by the numbers is tests/test_diagnose_phantom.py's)
    tried = rep["structure"]["parsimony"]["tried"]
    taken = [t for t in tried if t["accepted"]]
    assert len(taken) == 1 and " shaft " not in taken[0]["name"], [(t["name"], t["reason"]) for t in tried]
    assert not [e for e in rep["effects"] if e["kind"] == "compliance"], rep["verdict"]
    assert_no_sensor_worse(rep["gap"])


def test_the_weak_second_source_stays(cases):
    rep = cases["c24"]["report"]
    found = sorted((e["element"], e["kind"]) for e in rep["effects"])
    zones = sorted("unwind" if el in UNWIND_ZONE else "rewind" if el in REWIND_ZONE else el for el, _ in found)
    assert zones == ["rewind", "unwind"] and all(k == "eccentricity" for _, k in found), rep["verdict"]
    assert_no_sensor_worse(rep["gap"])
