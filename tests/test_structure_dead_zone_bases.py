"""The forms a dead zone is screened in: every feed-forward form, and each with both the web's
and the load cells' second forms (diagnosis.structure.dead_zone_bases)."""
from webline.diagnosis import structure as S

FF_NONE = {"drives.speed_loops.a.feedforward": False}
FF_REF = {"drives.speed_loops.a.feedforward": "reference"}
LC2 = {"sensors.lc9.filter_order": 2}
WD = {"web.damping": "2 ms"}


def _alternatives():
    one = [("feedforward none", "no ff", FF_NONE), ("feedforward reference", "ref ff", FF_REF),
           ("speed_gain x2", "gains", {"drives.speed_loops.a.K_ref": "2 1/s"}),
           ("load-cell filter order 2", "lc2", LC2), ("web damping 2 ms", "wd", WD)]
    pairs = [(f"{a} + {b}", f"{da}; {db}", {**sa, **sb}) for a, da, sa in one[:2] for b, db, sb in one[3:]]
    return one + pairs


def test_every_feed_forward_form_and_each_with_the_web_and_the_load_cells_forms_at_once():
    got = {name: sets for name, _, sets in S.dead_zone_bases(_alternatives())}
    assert set(got) == {
        "feedforward none", "feedforward reference",
        "feedforward none + load-cell filter order 2", "feedforward none + web damping 2 ms",
        "feedforward reference + load-cell filter order 2", "feedforward reference + web damping 2 ms",
        "feedforward none + web damping 2 ms + load-cell filter order 2",
        "feedforward reference + web damping 2 ms + load-cell filter order 2"}
    assert got["feedforward reference + web damping 2 ms + load-cell filter order 2"] == {**FF_REF, **WD, **LC2}
    assert got["feedforward none + web damping 2 ms + load-cell filter order 2"] == {**FF_NONE, **WD, **LC2}


def test_no_triple_without_both_second_forms():
    alts = [x for x in _alternatives() if "web damping" not in x[0]]
    names = [name for name, _, _ in S.dead_zone_bases(alts)]
    assert names == ["feedforward none", "feedforward reference", "feedforward none + load-cell filter order 2",
                     "feedforward reference + load-cell filter order 2"], names
