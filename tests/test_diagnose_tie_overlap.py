"""The periodic screen's ties (diagnosis.pipeline.Diagnosis._lines_overlap): only families
whose lines can stand for each other are one effect's candidates. Independent seed-58 c17:
guide_in at 4.65 Hz and the equal idlers at 3.41 Hz were taken as a tie, and guide_in, a
second real source, was never screened again."""
import math
from types import SimpleNamespace

import numpy as np
import pytest

from webline.diagnosis.pipeline import Diagnosis, Options

FS, T = 250.0, 60.0


def _run(rates):
    t = np.arange(0.0, T, 1.0 / FS)
    return SimpleNamespace(fs=FS, t=t, mask=np.ones(len(t), bool),
                           theta={k: 2 * math.pi * f * t for k, f in rates.items()})


def _overlap(runs, a, b):
    d = SimpleNamespace(opt=Options(), _theta_refined=lambda c, k: c.theta[k.key])
    d._mean_freq = lambda c, th: Diagnosis._mean_freq(d, c, th)
    return Diagnosis._lines_overlap(d, runs, SimpleNamespace(key=a), SimpleNamespace(key=b))


@pytest.mark.parametrize("fa, fb, overlap", [
    (3.4098, 3.4097, True),     # equal radii: the same lines
    (4.3559, 2.17795, True),    # a sub-multiple: its order 2 is the other's order 1
    (4.6497, 3.4098, False),    # seed-58 c17: nearest lines 3 x 4.65 and 4 x 3.41 Hz, 0.31 Hz apart
    (4.0, 3.0, False),          # one common line (12 Hz) in six orders: two sources, not one
    (2.0, 12.0, True),          # the sixth order
])
def test_families_tie_only_where_their_lines_meet(fa, fb, overlap):
    assert _overlap([_run({"a": fa, "b": fb})], "a", "b") == overlap


def test_a_run_that_separates_two_families_makes_them_two():
    # the same pair meets at one speed and not at another: one run telling them apart is enough
    runs = [_run({"a": 3.0, "b": 3.0}), _run({"a": 3.0, "b": 3.2})]
    assert not _overlap(runs, "a", "b")
    assert _overlap(runs[:1], "a", "b")
