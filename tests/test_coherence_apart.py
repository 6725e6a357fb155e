"""A family's coherence sets aside the orders it cannot tell from a family already taken.

A family's line within a quarter of a segment resolution (1/T_seg) of a taken
family's line shares each segment's phasor with it (the two bases correlate above
0.9); as a roll's radius changes the two beat from
segment to segment and the order reads incoherent whatever the source is
(independent seed-24 c17: the out-of-round rewind, 3 in at the start, turns its
order 2 onto roller9's 1.5 in order 1). The arithmetic below is exact: frequencies
from angles, the resolution from the segment's length.
"""
import math
from types import SimpleNamespace

import numpy as np

from webline.diagnosis import pipeline as P

FS = 500.0


def _segments(t, k=4):
    return np.array_split(np.arange(len(t)), k)


def test_orders_on_a_taken_familys_lines_are_set_aside():
    t = np.arange(0.0, 15.0, 1 / FS)
    c = SimpleNamespace(t=t)
    th = 2 * math.pi * 2.6 * t            # a roll at 2.6 Hz ...
    tb = 2 * math.pi * 5.2 * t            # ... beside a roller at twice its speed
    segs = _segments(t)
    free = P._apart(c, th, [1, 2, 3, 4, 5, 6], [(tb, [1, 2, 3, 4, 5, 6])], segs, 15.0 / 4)
    # even orders sit on the roller's lines; odd ones 2.6 Hz away, ten resolutions
    assert free.tolist() == [True, False, True, False, True, False]


def test_lines_the_joint_fit_separates_are_kept():
    # seed-24 c05: roller9's order 1 at 4.033 x the S-wrap leader's speed beside the
    # leader's order 4: 0.65 resolutions apart over 15 s segments (correlation 0.44),
    # which a joint fit separates; a quarter of a resolution (correlation 0.90) is not
    t = np.arange(0.0, 60.0, 1 / FS)
    f_sw = 1.294
    segs = _segments(t)
    c = SimpleNamespace(t=t)
    roller = 2 * math.pi * 4.0333 * f_sw * t
    leader = 2 * math.pi * f_sw * t
    assert P._apart(c, roller, [1], [(leader, [1, 2, 3, 4, 5, 6])], segs, 15.0).tolist() == [True]
    near = 2 * math.pi * (4 * f_sw + 0.2 / 15.0) * t
    assert P._apart(c, near, [1], [(leader, [1, 2, 3, 4, 5, 6])], segs, 15.0).tolist() == [False]


def test_nothing_taken_nothing_set_aside():
    t = np.arange(0.0, 15.0, 1 / FS)
    free = P._apart(SimpleNamespace(t=t), 2 * math.pi * 2.6 * t, [1, 2, 3], [], _segments(t), 15.0 / 4)
    assert free.all()


def test_a_line_that_drifts_onto_another_in_one_segment_is_set_aside():
    # 5.0 Hz falling to 4.4 Hz over 15 s (a growing roll) beside a steady 4.5 Hz: the
    # lines are 0.5 Hz apart in the first segment (two resolutions of 3.75 s) and within
    # 0.1 Hz in the last
    t = np.arange(0.0, 15.0, 1 / FS)
    f0, f1 = 5.0, 4.4
    th = 2 * math.pi * (f0 * t + 0.5 * (f1 - f0) / 15.0 * t ** 2)
    tb = 2 * math.pi * 4.5 * t
    segs = _segments(t)
    assert P._apart(SimpleNamespace(t=t), th, [1], [(tb, [1])], segs[:1], 15.0 / 4).tolist() == [True]
    assert P._apart(SimpleNamespace(t=t), th, [1], [(tb, [1])], segs, 15.0 / 4).tolist() == [False]


def _one_sensor(resid, Y):
    """(self, run, residuals, fit) for Diagnosis._coherence: one run, one sensor, a white floor of zero."""
    t = np.arange(len(resid)) / FS
    c = SimpleNamespace(t=t, fs=FS, mask=np.ones(len(t), bool), sensors=["lc.T"], floors={})
    me = SimpleNamespace(_mask_pieces=P.Diagnosis._mask_pieces)
    return me, c, {"lc.T": resid}, {"Y": {"lc.T": np.asarray(Y, complex)}}


def test_coherence_counts_the_free_orders_and_never_gives_a_free_pass():
    t = np.arange(0.0, 15.0, 1 / FS)
    rng = np.random.default_rng(0)
    th = 2 * math.pi * 2.6 * t
    tb = 2 * math.pi * 5.2 * t
    # order 1 steady; order 2 a line whose phase jumps segment by segment (as two beating lines read)
    jumps = np.repeat(rng.uniform(0, 2 * math.pi, 4), len(t) // 4 + 1)[:len(t)]
    y = np.cos(th) + np.cos(2 * th + jumps)
    me, c, resid, fit = _one_sensor(y, [1.0, 1.0])
    with_beside = P.Diagnosis._coherence(me, c, "k", resid, th, [1, 2], fit, beside=[(tb, [1])])
    alone = P.Diagnosis._coherence(me, c, "k", resid, th, [1, 2], fit, beside=[])
    assert with_beside > 0.99                  # order 2 set aside: order 1's steady line
    assert alone < 0.8                          # nothing taken: the jumping order counts
    # every order on a taken line: all of them count, as before
    me, c, resid, fit = _one_sensor(np.cos(2 * th + jumps), [1.0])
    every = P.Diagnosis._coherence(me, c, "k", resid, th, [2], fit, beside=[(tb, [1])])
    assert every < 0.8
