"""A run-out's own lines left on every load cell make the model form suspect.

Independent seed 28, c04 (simulated by the fast engine, measured through coloured
noise; the diagnosis runs blind in a subprocess): the S-wrap leader eccentric
(0.40 mm at order 1, 0.096 mm at order 6), one fit run at 171 ft/min and one held
out at 208 ft/min; the line's speed loops feed forward no tension torque, the
layout's feed forward the measured one. Refined in the layout's form the leader's
lines kept 20 % of their energy on both load cells (z 1012 and 549), below the 25 %
that screened the forms, and its order 1 came out at 0.066 mm (17 % of the truth);
the held-out run's lc9 NRMSE rose 1.13 -> 1.34. At 15 % the forms are screened,
feed-forward 'none' is taken and the order 1 comes out within 20 %.
"""
import pytest

from records import assert_no_sensor_worse, independent_cases

SEED = 28


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    return independent_cases(tmp_path_factory.mktemp("formleft28"), SEED, ("c04",), timeout=900)["c04"]


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
