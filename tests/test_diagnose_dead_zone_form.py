"""Leader backlashes that show only in the forms that pass the run-outs' lines as the line does.

Independent seed 10, c24: an eccentric idler_u1 (0.61 mm, 4.26 Hz), an
out-of-round rewind and a 1.2 deg dead zone in the S-wrap leader's drive, which
the idler's line swings through zero all the time. The truth's speed loops feed
forward no tension torque, among other forms and parameters (simulated by the
fast engine, measured through coloured noise; the diagnosis runs blind in a
subprocess). In the layout's form a dead zone makes the fit worse at every
width, so the backlash screen never claimed it, and a phantom 5.3 Hz shaft form
on the leader took its place. The structure screen now tries a dead zone beside
each feed-forward form. c24 is the case the form was built on.

Independent seed 64, c12: an eccentric roller9, an out-of-round rewind and a 2.7 deg
leader dead zone; the truth feeds the set points forward, has 3.8 ms of web damping
and second-order load cells. At its first look (40c1287) the dead zone, tried beside
the feed-forward forms alone, fitted 0.3689 (sum of NRMSE^2) and a leader shaft at
1.03 Hz (0.3506) was claimed; the truth's run-outs in the data sheet's line fit 1.022
with the dead zone in 'feedforward reference' and 0.895 with web damping and
second-order filters beside it (the truth 0.890). The dead zone is now tried in those
forms too (structure.dead_zone_bases): 0.3422, the shaft the rival kind.
"""
import pytest

from records import assert_no_sensor_worse, independent_cases

pytestmark = pytest.mark.slow  # whole blind diagnoses of several minutes each: `make test-all`

# seed, case, the truth's effects, what the chosen form must name, the roller or its
# equal-radius neighbour
CASES = {
    "seed10-c24": (10, "c24", [("idler_u1", "eccentricity"), ("rewind", "out_of_round"), ("sw_leader", "backlash")],
                   ("dead zone on sw_leader",), {"idler_u1", "roller9"}),
    "seed64-c12": (64, "c12", [("roller9", "eccentricity"), ("rewind", "out_of_round"), ("sw_leader", "backlash")],
                   ("dead zone on sw_leader", "web damping"), {"roller9", "idler_u1"}),
}


@pytest.fixture(scope="module", params=sorted(CASES))
def case(request, tmp_path_factory):
    seed, cid, *_ = CASES[request.param]
    res = independent_cases(tmp_path_factory.mktemp("dead_zone_form"), seed, (cid,))[cid]
    return request.param, res


def test_the_case_is_the_one_drawn(case):
    name, res = case
    kinds = [(e["element"], e["kind"]) for e in res["truth"]["effects"]]
    assert kinds == CASES[name][2], kinds


def test_the_leader_backlash_is_reported_not_a_shaft(case):
    name, res = case
    rep = res["report"]
    found = {(e["element"], e["kind"]) for e in rep["effects"]}
    assert ("sw_leader", "backlash") in found, rep["verdict"]
    assert not any(k == "compliance" for _, k in found), rep["verdict"]
    chosen = rep["structure"]["chosen"]
    assert all(part in chosen for part in CASES[name][3]), chosen


def test_the_periodic_sources_stay_and_no_sensor_is_worse(case):
    name, res = case
    rep = res["report"]
    found = {(e["element"], e["kind"]) for e in rep["effects"]}
    assert ("rewind", "out_of_round") in found, rep["verdict"]
    assert found & {(el, "eccentricity") for el in CASES[name][4]}, rep["verdict"]
    assert_no_sensor_worse(rep["gap"])
    if name == "seed64-c12":   # its held-out run: lc9 1.01 -> 0.44, lc19 1.00 -> 0.49 measured
        assert_no_sensor_worse(rep["holdout"]["out_of_sample"])
    if name == "seed10-c24":
        # with the shaft form lc9 closed 0.59 of its gap to the noise floor (1 -> 0.53, floor 0.21),
        # with the dead zone 0.74; the target is 0.7
        assert rep["gap"]["lc9.T"]["closed_share"] >= 0.7, rep["gap"]["lc9.T"]["closed_share"]
