"""A dead zone crossed by an eccentric roller's tension swing, found blind.

At steady speed the S-wrap leader (the speed master between two zones of like
tension) holds a few hundredths of a newton metre; an eccentric roller swings
the tensions it carries, and its torque, through zero at every turn. The
nominal model, without the eccentric roller, holds the torque steady, so the
other-effects screen cannot see a dead zone there; :mod:`diagnosis.backlash`
screens it in the refined model, which holds the roller's run-out and the
model form. Two cases of the independent benchmark, seed 8 (truth with other
forms and parameters, simulated by the fast engine, measured through coloured
noise; the diagnosis runs blind in a subprocess): c24, an eccentric idler_r1
beside a 2.8 deg backlash on the leader (found), and c13, an eccentric leader
without one, its torque swinging through zero too (nothing may be claimed).
c24 is the case the screen was built on; since the seventeenth session the
structure screen's dead-zone form ("feedforward none + dead zone on
sw_leader") claims it first. Seed 8's c05 and c17 (leaders with backlash
beside eccentric idlers) are not found, see docs/diagnose.md.
"""
import pytest

from records import assert_no_sensor_worse, independent_cases

SEED = 8
pytestmark = pytest.mark.slow  # whole blind diagnoses of several minutes each: `make test-all`


@pytest.fixture(scope="module")
def cases(tmp_path_factory):
    return independent_cases(tmp_path_factory.mktemp("backlash_crossed"), SEED, ("c24", "c13"))


def test_the_cases_are_the_ones_drawn(cases):
    kinds = {cid: sorted((e["element"], e["kind"]) for e in r["truth"]["effects"]) for cid, r in cases.items()}
    assert ("sw_leader", "backlash") in kinds["c24"], kinds
    assert kinds["c13"] == [("sw_leader", "eccentricity")], kinds
    # the leader's torque passes through zero in both truths
    for r in cases.values():
        tq = r["truth"]["runs"][0]["drive_torque"]["sw_leader"]
        assert tq["min_Nm"] < 0.0 < tq["max_Nm"], tq


def test_the_crossed_dead_zone_is_found_beside_the_runout(cases):
    rep = cases["c24"]["report"]
    eff = [e for e in rep["effects"] if e["kind"] == "backlash"]
    assert [e["element"] for e in eff] == ["sw_leader"], rep["verdict"]
    rec = next((r for r in rep["backlash"] if r["element"] == "sw_leader"), None)
    if rec is not None:
        # the backlash screen's claim: against the periodic effects re-estimated without it,
        # beyond noise block by block
        assert rec["claimed"] and rec["energy_fall"] >= 0.005 and min(rec["rise_t"].values()) <= -3.0, rec
    else:
        # or the structure screen's dead-zone form (the leader's drive is then no longer ideal,
        # and the backlash screen does not try it again)
        assert "dead zone on sw_leader" in rep["structure"]["chosen"], rep["structure"]["chosen"]
        assert eff[0]["check"]["accepted"], eff[0]["check"]
    assert_no_sensor_worse(rep["gap"])


def test_no_dead_zone_is_claimed_beside_an_eccentric_leader(cases):
    rep = cases["c13"]["report"]
    assert not [e for e in rep["effects"] if e["kind"] == "backlash"], rep["verdict"]
    rec = next(r for r in rep["backlash"] if r["element"] == "sw_leader")
    assert rec["reverses"] and not rec["claimed"], rec
