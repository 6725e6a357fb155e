"""Parsimony on independent seed 23 (issue 9): a real second source at the first one's
frequency is kept when the form without it carries less than three quarters of its line.

c05 (simulated by the fast engine, measured through coloured noise; the diagnosis runs
blind in a subprocess): idler_r1 eccentric (0.20 mm at order 1, 0.14 and 0.06 mm at
orders 5 and 6) and roller9 (0.08 mm at order 1), equal radii, one frequency. With
both, lc9's NRMSE is 0.839 and lc19's 0.469 (nominal 1.065 and 1.017). Without
roller9, 'feedforward none + load-cell filter order 2' fits lc9 at 0.914: it recovers
69 % of what roller9 explained there, and roller9 closes 22 % of lc9's gap to its
noise. Under the rule's earlier recovery condition (half) roller9 went as a phantom
and the refined model was left at lc9 1.069, above the nominal; at three quarters
(``structure.RECOVER_MIN``) it stays. The phantoms of the same seed with a secondary
part as large were recovered 82-99 % (unit rows in test_diagnose_phantom).
"""
import pytest

from records import REWIND_ZONE, UNWIND_ZONE, assert_no_sensor_worse, independent_cases

SEED = 23
pytestmark = pytest.mark.slow  # whole blind diagnoses of several minutes each: `make test-all`


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    return independent_cases(tmp_path_factory.mktemp("parsimony23"), SEED, ("c05",))["c05"]


def test_the_case_is_the_one_drawn(case):
    kinds = sorted((e["element"], e["kind"]) for e in case["truth"]["effects"])
    assert kinds == [("idler_r1", "eccentricity"), ("roller9", "eccentricity")], kinds


def test_both_sources_are_kept(case):
    rep = case["report"]
    found = [(e["element"], e["kind"]) for e in rep["effects"]]
    assert len(found) == 2 and all(k == "eccentricity" for _, k in found), rep["verdict"]
    zones = sorted(el in REWIND_ZONE for el, _ in found)
    assert zones == [False, True] and all(el in UNWIND_ZONE + REWIND_ZONE for el, _ in found), found
    assert not [r for r in rep["rejected"] if r.get("stage") == "parsimony (structure screen)"]
    # the pair takes lc9 well below its nominal (1.065; 0.914 was the best without roller9)
    gap = rep["gap"]
    assert gap["lc9.T"]["refined"]["nrmse"] < 0.9 * gap["lc9.T"]["nominal"]["nrmse"], gap["lc9.T"]
    assert_no_sensor_worse(gap)
