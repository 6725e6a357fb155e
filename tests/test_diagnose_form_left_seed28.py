"""Model form on independent seed 28: a run-out's own lines left on every load cell
make the form suspect (c04); a phantom beside a shaft form is tried without (c24).

Independent seed 28, c04 (simulated by the fast engine, measured through coloured
noise; the diagnosis runs blind in a subprocess): the S-wrap leader eccentric
(0.40 mm at order 1, 0.096 mm at order 6), one fit run at 171 ft/min and one held
out at 208 ft/min; the line's speed loops feed forward no tension torque, the
layout's feed forward the measured one. Refined in the layout's form the leader's
lines kept 20 % of their energy on both load cells (z 1012 and 549), below the 25 %
that screened the forms, and its order 1 came out at 0.066 mm (17 % of the truth);
the held-out run's lc9 NRMSE rose 1.13 -> 1.34. At 15 % the forms are screened,
feed-forward 'none' is taken and the order 1 comes out within 20 %.

c24: roller19 (0.11 mm) and guide_in eccentric, the S-wrap leader on a shaft at
8.6 Hz, one ramped fit run, the line feeding the set point forward. The screen
took 'feedforward reference + web damping 2 ms + shaft on sw_leader at 9.35 Hz'
with roller9 (15 um, at roller19's 4.57 Hz) beside roller19: the set without
roller9 was tried only in the forms without that shaft. In it roller9 is not
needed (sum NRMSE^2 0.1426 against 0.1422), and it is dropped.
"""
import pytest

from records import assert_no_sensor_worse, independent_cases

SEED = 28
pytestmark = pytest.mark.slow  # whole blind diagnoses of several minutes each: `make test-all`


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    return independent_cases(tmp_path_factory.mktemp("formleft28"), SEED, ("c04",))["c04"]


@pytest.fixture(scope="module")
def case24(tmp_path_factory):
    return independent_cases(tmp_path_factory.mktemp("shaftpars28"), SEED, ("c24",))["c24"]


def test_the_case_is_the_one_drawn(case):
    effects = case["truth"]["effects"]
    assert [(e["element"], e["kind"]) for e in effects] == [("sw_leader", "eccentricity")]
    assert case["truth"]["model"]["forms"]["feedforward"] == "none"


def test_the_form_is_screened_and_the_run_out_comes_out_right(case):
    rep = case["report"]
    assert any("stay on" in t for t in rep["structure"]["triggers"]), rep["structure"]["triggers"]
    assert "feedforward none" in (rep["structure"].get("chosen") or ""), rep["structure"].get("chosen")
    eff = [e for e in rep["effects"] if e["element"] == "sw_leader" and e["kind"] == "eccentricity"]
    assert len(eff) == 1, rep["verdict"]
    true_c1 = case["truth"]["effects"][0]["C_m"][0]
    got_c1 = next(h["amplitude"] for h in eff[0]["harmonics"] if h["order"] == 1)
    # the benchmark's target: the dominant harmonic within 20 % of the truth
    assert abs(got_c1 / true_c1 - 1.0) < 0.2, (got_c1, true_c1)
    assert_no_sensor_worse(rep["gap"])
    assert_no_sensor_worse(rep["holdout"]["out_of_sample"])


def test_a_share_left_below_the_threshold_or_within_noise_is_no_trigger():
    """structure.triggers on constructed ``left`` records: significant and above
    LEFT_SHARE triggers; just below it, or not significant, does not."""
    from types import SimpleNamespace

    from webline.diagnosis.structure import LEFT_SHARE, triggers
    d = SimpleNamespace(rejected=[], final_effects=[], fit_ctx=lambda: [], steps=[{"sims": {}}])

    def left(share, significant):
        return {"lc9.T": {"effects": [{"element": "sw_leader", "kind": "eccentricity", "share_left": share,
                                       "significant": significant, "by_order": []}]}}
    assert triggers(d, left(1.05 * LEFT_SHARE, True))
    assert triggers(d, left(0.95 * LEFT_SHARE, True)) == []
    assert triggers(d, left(0.9, False)) == []


def test_a_phantom_beside_a_shaft_form_is_tried_without_it_and_dropped(case24):
    truth = sorted((e["element"], e["kind"]) for e in case24["truth"]["effects"])
    assert truth == [("guide_in", "eccentricity"), ("roller19", "eccentricity"), ("sw_leader", "compliance")]
    rep = case24["report"]
    found = [(e["element"], e["kind"]) for e in rep["effects"]]
    assert ("roller9", "eccentricity") not in found, rep["verdict"]
    assert ("guide_in", "eccentricity") in found and ("sw_leader", "compliance") in found, rep["verdict"]
    ecc = [e for e in rep["effects"] if e["kind"] == "eccentricity" and e["element"] != "guide_in"]
    assert len(ecc) == 1 and "roller19" in [ecc[0]["element"]] + [c["element"] for c in ecc[0]["candidates"]]
    # the full set's own shaft form was screened without the secondary source
    assert any("shaft on sw_leader" in x["name"] and "without roller9" in x["name"] and "+ shaft" in x["name"]
               for x in rep["structure"]["screened"]), [x["name"] for x in rep["structure"]["screened"]]
    assert_no_sensor_worse(rep["gap"])
