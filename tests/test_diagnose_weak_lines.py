"""A periodic family must hold a share of the whole periodic residual, not only of
what the families taken before left (pipeline.significant_families).

The numbers are the screen's own, read from the benchmark's reports: seed-29 c07's
false out-of-round unwind (0.023 % of the whole, 1.6 % of what the eccentric
roller19 left, log10 p -40, coherence 0.78) and seed-25 c12's true eccentric S-wrap
leader (0.128 % of the whole, 9.9 % of what was left, log10 p -163, coherence 0.96).
"""
from types import SimpleNamespace

from webline.diagnosis.pipeline import Options, significant_families
from webline.diagnosis.report import _rejected


def family(element, share, share_left, logp, coherence, kind="eccentricity"):
    return {"cand": SimpleNamespace(element=element, kind=kind), "share": share, "share_left": share_left,
            "logp": logp, "coherence": coherence}


PHANTOM = family("unwind", 0.00023, 0.0163, -40.1, 0.78, kind="out_of_round")
WEAK_TRUE = family("sw_leader", 0.00128, 0.0992, -163.0, 0.96)


def test_a_line_under_the_share_of_the_whole_is_not_claimed():
    opt = Options()
    assert significant_families([PHANTOM], opt) == []
    assert significant_families([WEAK_TRUE], opt) == [WEAK_TRUE]


def test_the_share_of_the_whole_sits_between_the_false_and_the_weakest_true():
    # the threshold is no single case's digit: a factor 2 either side of it keeps both verdicts
    for scale in (0.5, 2.0):
        opt = Options(min_share_all=scale * Options().min_share_all)
        assert significant_families([PHANTOM, WEAK_TRUE], opt) == [WEAK_TRUE]


def test_the_other_thresholds_still_hold():
    opt = Options()
    assert significant_families([family("a", 0.5, 0.5, -5.0, 0.9)], opt) == []       # not significant
    assert significant_families([family("b", 0.5, 0.005, -50.0, 0.9)], opt) == []    # little of what was left
    assert significant_families([family("c", 0.5, 0.5, -50.0, 0.5)], opt) == []      # not coherent


def test_the_report_says_why_the_weak_line_was_not_claimed():
    opt = Options()
    entry = {"element": "unwind", "kind": "out_of_round", "share": PHANTOM["share"],
             "share_left": PHANTOM["share_left"], "log10_p": PHANTOM["logp"], "coherence": PHANTOM["coherence"]}
    d = SimpleNamespace(rejected=[], opt=opt, screen_log=[[entry]], effects=[], other=[], other_log=[])
    rows = [r for r in _rejected(d) if r["element"] == "unwind"]
    assert len(rows) == 1
    assert "of the whole periodic residual" in rows[0]["reason"], rows[0]["reason"]
    assert "0.023 %" in rows[0]["reason"] and "0.05 %" in rows[0]["reason"], rows[0]["reason"]
