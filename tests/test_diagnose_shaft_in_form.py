"""A leader shaft that shows only in the rigid form the line has.

Independent seed 18, c05: an eccentric guide_in (5.29 Hz), an eccentric S-wrap
leader and a compliant shaft in the leader's drive (two-mass mode 7.6 Hz). The
truth's speed loops feed the tension set point forward and its web carries
2.4 ms of damping, among other forms and parameters (simulated by the fast
engine, measured through coloured noise; the diagnosis runs blind in a
subprocess). The shaft forms were screened in the layout's form only, where the
best (5.29 Hz) fitted 0.570 against 0.456 for the rigid 'feedforward reference
+ web damping 2 ms', and the shaft was missed. The structure screen now
simulates the shaft forms in the rigid form that fits best: 0.364 at 7.94 Hz.

c17 is the other side: an eccentric leader, an out-of-round rewind and a 1.4 deg
dead zone in the leader's drive, in a line without feed-forward and with 1.9 ms
of web damping. With the shafts alone in the best rigid form ('feedforward none +
web damping 2 ms') a leader shaft at 2.67 Hz (0.722) took the dead zone's place;
the dead zone is now tried in that form too (0.676) and holds.
"""
import pytest

from records import assert_no_sensor_worse, independent_cases

SEED = 18
pytestmark = pytest.mark.slow  # whole blind diagnoses of several minutes each: `make test-all`


@pytest.fixture(scope="module")
def cases(tmp_path_factory):
    return independent_cases(tmp_path_factory.mktemp("shaft_in_form"), SEED, ("c05", "c17"))


@pytest.fixture(scope="module")
def case(cases):
    return cases["c05"]


def test_the_case_is_the_one_drawn(case):
    kinds = [(e["element"], e["kind"]) for e in case["truth"]["effects"]]
    assert kinds == [("guide_in", "eccentricity"), ("sw_leader", "eccentricity"), ("sw_leader", "compliance")], kinds


def test_the_leader_shaft_is_reported_in_the_best_rigid_form(case):
    rep = case["report"]
    found = {(e["element"], e["kind"]) for e in rep["effects"]}
    assert ("sw_leader", "compliance") in found, rep["verdict"]
    chosen = rep["structure"]["chosen"]
    assert "shaft on sw_leader" in chosen and chosen.startswith("feedforward"), chosen
    shaft = next(e for e in rep["effects"] if e["kind"] == "compliance")
    truth = next(e for e in case["truth"]["effects"] if e["kind"] == "compliance")["drive"]["mode_hz"]
    # the form's grid: SHAFT_RATIOS x the first effect's fundamental, 20 % steps near the truth
    assert abs(shaft["fundamental_hz"] / truth - 1.0) <= 0.2, (shaft["fundamental_hz"], truth)


def test_the_periodic_sources_stay_and_no_sensor_is_worse(case):
    rep = case["report"]
    found = {(e["element"], e["kind"]) for e in rep["effects"]}
    assert {("guide_in", "eccentricity"), ("sw_leader", "eccentricity")} <= found, rep["verdict"]
    assert_no_sensor_worse(rep["gap"])
    # without the shaft lc9 closed 0.82 of its gap to the noise floor; the target is 0.7
    assert rep["gap"]["lc9.T"]["closed_share"] >= 0.7, rep["gap"]["lc9.T"]["closed_share"]


def test_a_leader_dead_zone_keeps_its_place_against_the_shaft_in_that_form(cases):
    case = cases["c17"]
    kinds = [(e["element"], e["kind"]) for e in case["truth"]["effects"]]
    assert kinds == [("sw_leader", "eccentricity"), ("rewind", "out_of_round"), ("sw_leader", "backlash")], kinds
    rep = case["report"]
    found = {(e["element"], e["kind"]) for e in rep["effects"]}
    assert ("sw_leader", "backlash") in found, rep["verdict"]
    assert not any(k == "compliance" for _, k in found), rep["verdict"]
    assert {("sw_leader", "eccentricity"), ("rewind", "out_of_round")} <= found, rep["verdict"]
    assert_no_sensor_worse(rep["gap"])
