"""No phantom source at the same frequency (issue 9: 'several sources ... the
follower as a separate effect').

The benchmark line (diagnosis.benchmark.derive_line) has equal-radius rollers
in the unwind zone (lc9) and the rewind zone (lc19). The truth's speed loops
feed forward no tension torque (the layout's feed forward the measured
tension), and one roller in the unwind zone is eccentric. Without the
measured-tension feed forward the eccentricity's line passes through the
S-wrap to lc19 far more than the layout's model passes, so the per-sensor
same-frequency split explains lc19's line with a second, rewind-zone roller.
One source and a form explain the data about as well: exactly one source must
be reported, the rewind-zone roller goes to ``rejected`` with the numbers.

Built and scored by the independent benchmark's own code (truth: monolithic
fast engine, a 10 s record at 250 Hz; diagnosis run blind in a subprocess).
"""
import pytest
from records import DIAGNOSIS_TIMEOUT, REWIND_ZONE, assert_no_sensor_worse

from webline.diagnosis import benchmark as B
from webline.diagnosis import benchmark_independent as BI

MM = 1e-3


@pytest.fixture(scope="module")
def case_result(tmp_path_factory):
    root = tmp_path_factory.mktemp("phantom")
    line = B.derive_line()
    loops = list(line["drives"]["speed_loops"])
    # the form differs only in the feed forward (no current lag, no web damping,
    # load cells as the layout's); parameters as the layout's
    forms = {"feedforward": "none"}
    params = {"EA_scale": 1.0, "inertia_scale": {e["name"]: 1.0 for e in line["path"]},
              "friction_scale": {e["name"]: 1.0 for e in line["path"] if "friction" in e},
              "span_scale": {e["name"]: 1.0 for e in line["path"] if "span" in e}, "rewind_radius_scale": 1.0}
    case = BI.ICase(
        id="ph", category="eccentric",
        effects=[B.Effect("eccentricity", "roller9", C_m=[0.5 * MM], psi_rad=[0.3])],
        runs=[BI.IRunSpec("run1", speed_fpm=200.0, duration_s=10.0, fs_hz=250.0, noise_N=0.05, pink_N=0.0,
                          white_N=0.05, drift_sine_N=0.0, drift_walk_N=0.0, seed=5)],
        model=BI.TruthModel(forms=forms, params=params))
    def feedforward_only(model, line_doc):
        return {f"drives.speed_loops.{el}.feedforward": ["none", False] for el in loops}

    # the transmitting forms are the first two screened (feed forward none / reference)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(BI, "form_set", feedforward_only)
        return BI.evaluate_case(case, root, line, timeout=DIAGNOSIS_TIMEOUT,
                                extra=["--jobs", "1", "--no-other", "--max-structures", "2", "--harmonics", "3"])


def test_one_source_is_reported(case_result):
    rep = case_result["report"]
    assert rep is not None, case_result.get("stderr") or case_result.get("generation_error")
    periodic = [e for e in rep["effects"] if e["kind"] == "eccentricity"]
    assert len(periodic) == 1, [e["element"] for e in periodic]
    assert periodic[0]["element"] not in REWIND_ZONE
    score = case_result["score"]
    assert score["missed"] == [] and len(score["matches"]) == 1, score


def test_the_second_zone_line_is_the_form_not_a_source(case_result):
    rep = case_result["report"]
    st = rep["structure"]
    assert st["chosen"] not in (None, "as modelled"), st.get("parsimony")
    dropped = [r for r in rep["rejected"] if r["stage"] == "parsimony (structure screen)"]
    assert dropped and all(r["element"] in REWIND_ZONE for r in dropped), dropped
    assert "transmitting" in dropped[0]["reason"]
    # the form it chose explains at least RECOVER of what the dropped source explained, per sensor
    tried = st["parsimony"]["tried"][-1]
    assert tried["accepted"]
    assert_no_sensor_worse(rep["gap"])


# ------------------------------------------------------------ the rule on numbers ----
def test_parsimony_rule_on_numbers():
    from webline.diagnosis.structure import parsimony_rule
    # benchmark c01 (phantom): lc19 0.54 with both, 1.0 without in the layout's form, 0.584 in
    # 'feedforward none' without: recovers (1 - 0.341) / (1 - 0.292) = 93 %; lc9 within 5 %
    rows, why = parsimony_rule({"lc9.T": 0.263, "lc19.T": 0.540}, {"lc9.T": 0.265, "lc19.T": 0.999},
                               {"lc9.T": 0.266, "lc19.T": 0.584})
    assert why is None
    assert rows["lc19.T"]["recovered"] == pytest.approx((0.999 ** 2 - 0.584 ** 2) / (0.999 ** 2 - 0.540 ** 2))
    # own family c12 (two real sources): lc19 0.316 with both, 0.777 without in every form
    rows, why = parsimony_rule({"lc19.T": 0.316}, {"lc19.T": 0.777}, {"lc19.T": 0.777})
    assert why and rows["lc19.T"]["recovered"] == pytest.approx(0.0) and "lc19.T" in why
    # recovering 70 % and 9 % above the full set: not about as good
    f, w = 0.3, 0.8
    p = (w ** 2 - 0.7 * (w ** 2 - f ** 2)) ** 0.5
    assert parsimony_rule({"s": f}, {"s": w}, {"s": p})[1] is not None
    p = (w ** 2 - 0.85 * (w ** 2 - f ** 2)) ** 0.5
    assert parsimony_rule({"s": f}, {"s": w}, {"s": p})[1] is None


def test_parsimony_weighs_a_secondary_source_against_the_noise_floor():
    from webline.diagnosis.structure import CLOSES, RECOVER_MIN, parsimony_rule
    # independent c07 (phantom roller9 beside an eccentric roller19; the truth feeds forward
    # nothing): lc9 recovers 97 %, lc19 only 78 % - but roller9 takes lc19 from 0.0836 to
    # 0.0728 where its noise allows 0.0514: 39 % of the gap, a transfer error absorbed
    full, wo, form = {"lc9.T": 0.1748, "lc19.T": 0.0728}, {"lc9.T": 1.0007, "lc19.T": 0.1135}, \
        {"lc9.T": 0.2348, "lc19.T": 0.0836}
    floor = {"lc9.T": 0.1089, "lc19.T": 0.0514}
    rows, why = parsimony_rule(full, wo, form)
    assert why and "lc19.T" in why and rows["lc19.T"]["recovered"] < 0.80
    rows, why = parsimony_rule(full, wo, form, floor=floor)
    assert why is None
    c = rows["lc19.T"]["secondary_closes"]
    assert c == pytest.approx((0.0836 ** 2 - 0.0728 ** 2) / (0.0836 ** 2 - 0.0514 ** 2)) and c < CLOSES
    # independent c05 (two real idlers): without idler_u1 lc9 stays at 0.587 (floor 0.0835), with it
    # 0.195 - 91 % of the gap closed - and lc19 88 %: kept
    rows, why = parsimony_rule({"lc9.T": 0.1953, "lc19.T": 0.1177}, {"lc9.T": 1.0032, "lc19.T": 0.1553},
                               {"lc9.T": 0.5873, "lc19.T": 0.2816}, floor={"lc9.T": 0.0835, "lc19.T": 0.0692})
    assert why and rows["lc9.T"]["secondary_closes"] > 0.9
    # seed-2 c05 (roller9 real, beside idler_r1's line): 'load-cell filter order 2' without it explains
    # none of lc9's line (recovered 0) though the source closes only 38 % of the gap there: kept
    rows, why = parsimony_rule({"lc9.T": 0.816, "lc19.T": 0.6266}, {"lc9.T": 1.0009, "lc19.T": 0.6270},
                               {"lc9.T": 1.0009, "lc19.T": 0.6271}, floor={"lc9.T": 0.347, "lc19.T": 0.274})
    assert rows["lc9.T"]["secondary_closes"] < CLOSES and rows["lc9.T"]["recovered"] < 0.01
    assert why and "lc9.T" in why
    # seed-23 c05 (roller9 real, 83 um beside idler_r1's 200 um at one frequency): it takes 43 % of
    # lc9's NRMSE^2, closes 22 % of the gap there, and 'feedforward none + load-cell filter order 2'
    # without it recovers 69 %: kept (dropped while RECOVER_MIN was 0.5)
    full, wo, form = {"lc9.T": 0.8388, "lc19.T": 0.4687}, {"lc9.T": 1.065, "lc19.T": 0.4724}, \
        {"lc9.T": 0.914, "lc19.T": 0.474}
    rows, why = parsimony_rule(full, wo, form, floor={"lc9.T": 0.4921, "lc19.T": 0.2894})
    assert rows["lc9.T"]["secondary_closes"] < CLOSES and 0.5 < rows["lc9.T"]["recovered"] < RECOVER_MIN
    assert why and "lc9.T" in why
    # the phantoms of the same benchmark seed with a secondary part as large recover 82-99 %
    # (c12: lc19 0.689 with roller19, 0.994 without, 0.722 in 'feedforward reference + load-cell
    # filter order 2' without it): dropped
    rows, why = parsimony_rule({"lc9.T": 0.5223, "lc19.T": 0.6891}, {"lc9.T": 0.5259, "lc19.T": 0.9935},
                               {"lc9.T": 0.5318, "lc19.T": 0.7218}, floor={"lc9.T": 0.2754, "lc19.T": 0.3327})
    assert why is None and rows["lc19.T"]["recovered"] > 0.9
    # seed-3 c04 (a phantom idler_r1 beside an eccentric idler_u1): it takes lc9's NRMSE^2 by 0.04
    # only, closes 22 % of the gap, and 'feedforward none' recovers 40 %: dropped
    rows, why = parsimony_rule({"lc9.T": 0.345}, {"lc9.T": 0.401}, {"lc9.T": 0.380}, floor={"lc9.T": 0.178})
    assert rows["lc9.T"]["recovered"] < 0.5 and why is None
    # a full set at or below the floor (the estimate's scatter): the secondary took the sensor to
    # its noise, never dropped on this ground
    rows, why = parsimony_rule({"s": 0.10}, {"s": 0.5}, {"s": 0.5}, floor={"s": 0.11})
    assert why and rows["s"]["secondary_closes"] > 1.0


def test_two_sources_at_one_frequency_are_fitted_jointly():
    """structure._joint_fit: two effects whose responses differ across the sensors are
    recovered exactly from their sum, order by order; an order one of them lacks
    stays zero for it; a single effect is the weighted scalar fit."""
    import numpy as np
    from webline.diagnosis import structure
    G1 = np.array([[1.0 + 0.5j, 0.3], [0.2 - 0.1j, 0.8j]])      # rows: sensors; columns: orders 1, 2
    G2 = np.array([[0.1 + 0.0j, 0.5], [0.9 + 0.2j, -0.4]])
    X1, X2 = np.array([2e-4 * np.exp(0.3j), 5e-5]), np.array([4e-5 * np.exp(-1.0j), 0.0])
    M = G1 * X1[None, :] + G2 * X2[None, :]
    W = np.array([1.0, 3.0])
    got = structure._joint_fit(M, [G1, G2], W, [np.array([True, True]), np.array([True, False])])
    assert got[0] == pytest.approx(X1, rel=1e-9, abs=1e-15)
    assert got[1] == pytest.approx(X2, rel=1e-9, abs=1e-15)
    # summed one by one, each alone would claim the whole line: what the joint fit prevents
    one = structure._joint_fit(M, [G2], W, [np.array([True, True])])[0]
    assert abs(one[0]) > 2 * abs(X2[0])


def test_a_primary_source_is_tried_as_each_member_of_its_tie():
    """structure._swaps / _take_swap (independent seed-2 c07: roller19 reported as
    idler_r1 plus a phantom idler_u1). The set without the secondary source is also
    screened with the primary replaced by each member of its tie that turns at its
    frequency, the secondary's own element included, each estimated alone on the
    primary's measured harmonics; a chosen swap makes that member the effect."""
    from types import SimpleNamespace

    import numpy as np
    from webline.diagnosis import structure
    from webline.diagnosis.candidates import Candidate

    def cand(el):
        return Candidate("eccentricity", el, el, "IdleRoller", 0.0381, f"{el}.theta")
    r1, r19, r9, u1 = (cand(e) for e in ("idler_r1", "roller19", "roller9", "idler_u1"))
    G19 = np.array([[0.2 + 0.1j, 0.05], [1.0 - 0.3j, 0.4j]])
    X19 = np.array([3e-4 * np.exp(0.7j), 4e-5])
    M = G19 * X19[None, :]
    W = np.array([1.0, 2.0])
    rec = {c.element: {"cand": c, "G": G19 if c is r19 else np.ones((2, 2), complex), "M": M, "W": W,
                       "X": np.array([1e-4, 0.0], complex)} for c in (r1, r19, r9, u1)}
    fe_p = {"ranked": [rec[e] for e in ("idler_r1", "roller19", "roller9", "idler_u1")]}
    fe_s = {"ranked": [rec["idler_u1"]], "same_frequency_as": "idler_r1"}
    ctx = SimpleNamespace(T=60.0, freq={r1.key: 4.553, r19.key: 4.553, u1.key: 4.5531, r9.key: 4.60})
    d = SimpleNamespace(fit_ctx=lambda: [ctx], final_effects=[fe_p, fe_s], rejected=[], notes=[])
    X0 = np.array([2e-4, 3e-5], complex)
    sw = structure._swaps(d, [(r1, X0, fe_p)], [(fe_s, "idler_r1")])
    # roller9 turns 1 % faster: not a member of this tie; the secondary's element is
    assert [(old, new) for old, new, _ in sw] == [("idler_r1", "roller19"), ("idler_r1", "idler_u1")]
    (c19, X, fe), = sw[0][2]
    assert c19 is r19 and fe is fe_p
    assert X == pytest.approx(X19, rel=1e-9)
    # an order the primary does not carry stays out
    sw0 = structure._swaps(d, [(r1, np.array([2e-4, 0.0], complex), fe_p)], [(fe_s, "idler_r1")])
    assert sw0[0][2][0][1][1] == 0
    chosen = {"swap": {"replaced": "idler_r1", "by": "roller19"}, "X": {"roller19": X19},
              "name": "feedforward reference, roller19 in the place of idler_r1, without idler_u1",
              "form": "feedforward reference", "check": {"reason": "one source fewer"}, "nrmse": {"lc9.T": 0.9}}
    structure._take_swap(d, chosen)
    assert fe_p["ranked"][0]["cand"] is r19 and fe_p["ranked"][1]["cand"] is r1
    assert fe_p["ranked"][0]["X"] is X19 and fe_p["structure"] == "feedforward reference"
    assert d.rejected[0]["element"] == "idler_r1" and "roller19" in d.rejected[0]["reason"]


def test_a_shaft_form_chosen_with_a_source_fewer_is_measured_against_that_set():
    from webline.diagnosis import structure
    shafts = {"shaft on sw_leader at 6.37 Hz": ("sw_leader", "compliance", 6.37)}
    full = {"name": "feedforward none", "form": "feedforward none", "score": 0.276}
    without = {"name": "without idler_u1", "form": "as modelled", "without": ["idler_u1"], "score": 1.113}
    chosen = {"name": "shaft on sw_leader at 6.37 Hz, without idler_u1", "form": "shaft on sw_leader at 6.37 Hz",
              "without": ["idler_u1"], "score": 0.383}
    rigid = {"name": "feedforward none, without idler_u1", "form": "feedforward none", "without": ["idler_u1"],
             "score": 0.45}
    # the layout's form with both sources: 0.30 (a shaft that fits worse than that with one source
    # fewer read "explains -27 %")
    eff = structure._drive_effect(chosen, shafts, [full, without, chosen, rigid], 0.30)
    assert eff["explained_share"] == pytest.approx(1 - 0.383 / 1.113, rel=1e-12)
    assert "without idler_u1" in eff["explains_what"]
    assert eff["confidence"] == pytest.approx(1 - 0.383 / 0.45, rel=1e-12)
    # with every source: against the layout's form as before
    eff = structure._drive_effect(dict(chosen, without=None), shafts, [full, chosen], 0.30)
    assert eff["explained_share"] == pytest.approx(1 - 0.383 / 0.30, rel=1e-12)
    assert eff["kind"] == "compliance" and eff["fundamental_hz"] == 6.37


def test_a_shaft_form_carries_the_modes_of_the_shafts_on_its_drive_that_fit_about_as_well():
    """The torsional mode of a chosen shaft form is the grid's; the shafts on the same drive
    that fit about as well (within AS_WELL of the best improvement, in any form) give its
    range, a shaft on another drive or a dead zone does not."""
    from webline.diagnosis import structure
    forms = {"shaft on sw_leader at 6.37 Hz": ("sw_leader", "compliance", 6.37),
             "feedforward reference + shaft on sw_leader at 9.55 Hz": ("sw_leader", "compliance", 9.55),
             "shaft on sw_leader at 12.7 Hz": ("sw_leader", "compliance", 12.7),
             "shaft on sw_follower at 5.1 Hz": ("sw_follower", "compliance", 5.1),
             "feedforward none + dead zone on sw_leader": ("sw_leader", "backlash", 1.0)}
    rigid = {"name": "feedforward none", "form": "feedforward none", "score": 0.50}
    chosen = {"name": "shaft on sw_leader at 6.37 Hz", "form": "shaft on sw_leader at 6.37 Hz", "score": 0.20}
    # the layout's form 0.60: the best improvement 0.40, 'about as well' up to 0.24
    near = {"name": "ff ref 9.55", "form": "feedforward reference + shaft on sw_leader at 9.55 Hz", "score": 0.239}
    far = {"name": "12.7", "form": "shaft on sw_leader at 12.7 Hz", "score": 0.241}
    other = [{"name": "f", "form": "shaft on sw_follower at 5.1 Hz", "score": 0.21},
             {"name": "dz", "form": "feedforward none + dead zone on sw_leader", "score": 0.205}]
    eff = structure._drive_effect(chosen, forms, [rigid, chosen, near, far] + other, 0.60)
    tf = eff["parameters"]["torsional_frequency"]
    assert tf["estimated"] == 6.37 and tf["range"] == [6.37, 9.55]
    assert "6.37-9.55 Hz fit about as well" in eff["detail"]
    # alone on its drive: a range of one mode, and the detail says nothing of a spread
    eff = structure._drive_effect(chosen, forms, [rigid, chosen, far] + other, 0.60)
    assert eff["parameters"]["torsional_frequency"]["range"] == [6.37, 6.37]
    assert "fit about as well)" not in eff["detail"]


def test_a_dead_zone_form_is_reported_as_a_backlash_of_its_width():
    """A chosen dead-zone form claims a backlash (no fundamental), its width the form's,
    said not to be estimated, measured against the best rigid form as a shaft is."""
    import math
    from webline.diagnosis import structure
    name = "feedforward none + dead zone on sw_leader"
    forms = {name: ("sw_leader", "backlash", 1.0)}
    rigid = {"name": "feedforward reference", "form": "feedforward reference", "score": 0.306}
    chosen = {"name": name, "form": name, "score": 0.25}
    eff = structure._drive_effect(chosen, forms, [rigid, chosen], 0.567)
    assert eff["kind"] == "backlash" and eff["element"] == "sw_leader" and eff["fundamental_hz"] is None
    assert eff["parameters"]["backlash"]["estimated"] == pytest.approx(math.radians(1.0), rel=1e-12)
    assert eff["parameters"]["backlash"]["identifiable"] is False
    assert eff["confidence"] == pytest.approx(1 - 0.25 / 0.306, rel=1e-12)
    assert eff["explained_share"] == pytest.approx(1 - 0.25 / 0.567, rel=1e-12)
    # chosen with a source fewer and another member in the primary's place: no run of that set in
    # the layout's form, so against the best rigid form with the same set, not the full set
    sw = {"replaced": "idler_u1", "by": "idler_r1"}
    chosen = {"name": name + ", swapped", "form": name, "without": ["roller19"], "swap": sw, "score": 0.9493}
    rigid_sw = {"name": "feedforward none, swapped", "form": "feedforward none", "without": ["roller19"],
                "swap": sw, "score": 1.091}
    eff = structure._drive_effect(chosen, forms, [rigid, rigid_sw, chosen], 0.8319)
    assert eff["explained_share"] == pytest.approx(1 - 0.9493 / 1.091, rel=1e-12)


def test_own_lines_on_measured_orders():
    """The secondary source's own orders, as parsimony records them (independent
    cases, measured), summed into the record ``own_lines``."""
    from webline.diagnosis.structure import OWN_LINES_KEEP, own_lines

    def row(el, j, s, left_w, left_f, share, run="run1"):
        return {"element": el, "order": j, "run": run, "sensor": s, "z": 100.0,
                "left_without": left_w, "left_full": left_f, "share_of_gap": share}
    # seed-8 c05 (idler_u1 real, reported as its twin roller9): 'feedforward none' without it
    # leaves orders 3, 4, 6 on lc9 - 1.05 + 1.69 + 0.65 = 3.4 % of lc9's gap
    real = [row("roller9", 3, "lc9.T", 0.64, 0.38, 0.0403), row("roller9", 4, "lc9.T", 0.53, 0.00, 0.0318),
            row("roller9", 6, "lc9.T", 0.96, 0.02, 0.0069), row("roller9", 5, "lc19.T", 0.31, 0.30, 0.0801)]
    got = own_lines(real)
    assert (got["element"], got["sensor"], got["orders"]) == ("roller9", "lc9.T", [4, 3, 6])
    assert got["share"] == pytest.approx(0.0403 * 0.26 + 0.0318 * 0.53 + 0.0069 * 0.94)
    # seed-3 c04 (phantom idler_r1): its large lines are mostly passed on by the form (38 %, 39 % left)
    phantom = [row("idler_r1", 3, "lc19.T", 0.38, 0.00, 0.0192), row("idler_r1", 5, "lc19.T", 0.92, 3.75, 0.0004),
               row("idler_r1", 6, "lc19.T", 3.61, 7.99, 0.0005), row("idler_r1", 6, "lc9.T", 0.39, 0.18, 0.0158)]
    assert own_lines(phantom)["share"] < 0
    # seed-0 c07 (phantom roller9 at roller19's frequency): its orders 1 and 2 are the primary's large
    # lines (89 % and 8 % of lc9's gap), 2 and 9 % of them left by the form's re-estimate: not counted
    got = own_lines([row("roller9", 1, "lc9.T", 0.020, 0.00, 0.889), row("roller9", 2, "lc9.T", 0.086, 0.00, 0.0793),
                     row("roller9", 6, "lc9.T", 0.537, 0.00, 0.0003)])
    assert got["orders"] == [6] and got["share"] == pytest.approx(0.0003 * 0.537)
    # seed-19 c24 (roller9 real, 0.10 mm beside idler_r1's 0.53 mm at one frequency): 'feedforward none
    # + web damping 2 ms' without it leaves 46 % of its order 1 on lc9, a line of 43 % of lc9's gap
    real = [row("roller9", 1, "lc9.T", 0.457, 0.001, 0.430), row("roller9", 3, "lc9.T", 1.566, 0.004, 0.003),
            row("roller9", 6, "lc9.T", 0.697, 0.014, 0.002), row("roller9", 1, "lc19.T", 0.006, 0.0, 0.853)]
    got = own_lines(real)
    assert (got["sensor"], got["orders"][0]) == ("lc9.T", 1)
    assert got["share"] >= OWN_LINES_KEEP
    # seed-21 c07 (phantom idler_u1 beside idler_r1, one frequency): 'feedforward reference + web
    # damping 2 ms' without it fits lc9 better than the full set and leaves 1.42 of order 5 there;
    # beyond the line the excess is the primary's transfer: counted up to the line, under the rule
    c07 = [row("idler_u1", 1, "lc9.T", 0.00534, 0.000148, 0.902), row("idler_u1", 4, "lc9.T", 0.345, 0.0053, 0.00117),
           row("idler_u1", 5, "lc9.T", 1.4155, 0.315, 0.0557), row("idler_u1", 6, "lc9.T", 2.467, 0.337, 0.000256)]
    assert own_lines(c07)["share"] >= OWN_LINES_KEEP
    got = own_lines(c07, better={"lc9.T", "lc19.T"})
    assert got["orders"] == [5, 6] and got["share"] < OWN_LINES_KEEP
    assert got["share"] == pytest.approx(0.0557 * (1 - 0.315) + 0.000256 * (1 - 0.337))
    # seed-20 c24 (roller9 real): the same form without it fits lc9 worse (1.024 against 0.980) and
    # leaves 11.8 x its order 1 there: not capped, kept
    c24 = [row("roller9", 1, "lc9.T", 11.78, 0.0098, 0.01443), row("roller9", 3, "lc9.T", 1.672, 0.0268, 0.00217),
           row("roller9", 4, "lc9.T", 0.313, 0.180, 0.01186), row("roller9", 5, "lc9.T", 0.170, 0.0030, 0.0440),
           row("roller9", 1, "lc19.T", 0.039, 0.00036, 0.5005)]
    got = own_lines(c24, better={"lc19.T"})
    assert (got["sensor"], got["orders"]) == ("lc9.T", [1, 3]) and got["share"] >= OWN_LINES_KEEP
    assert own_lines(c24, better={"lc9.T", "lc19.T"})["share"] < OWN_LINES_KEEP
    # summed per run and sensor; nothing recorded, nothing to sum
    split = [row("x", 4, "lc9.T", 1.0, 0.0, 0.01, run=r) for r in ("run1", "run2")]
    assert own_lines(split)["share"] == pytest.approx(0.01)
    assert own_lines([]) is None and own_lines([row("x", 4, "lc9.T", 1.0, 0.0, None)]) is None


def test_a_shaft_in_a_sources_place_is_held_to_the_full_sets_fit():
    """structure.shaft_swap_refused, on the measured sums of NRMSE^2: a shaft form in a
    secondary source's place claims a compliance, as many effects as the full set, so it
    may fit worse than the full set by no more than SHAFT_MARGIN; a dead zone is left free."""
    from webline.diagnosis.structure import SHAFT_MARGIN, shaft_swap_refused
    forms = {"shaft on sw_leader at 2.37 Hz": ("sw_leader", "compliance", 2.37),
             "feedforward reference + dead zone on sw_leader": ("sw_leader", "backlash", 1.0)}

    def swap(form, score):
        return {"form": form, "score": score, "without": ["idler_u1"]}
    # seed-20 c17: the shaft tuned to roller19's fundamental in the real idler_u1's place, 1.19 x
    why = shaft_swap_refused(swap("shaft on sw_leader at 2.37 Hz", 0.5632), {"score": 0.4729}, forms)
    assert why and "0.5632" in why and "0.4729" in why
    # seed-4 c05: the true shaft in a phantom roller19's place, 1.02 x: may replace the full set
    assert shaft_swap_refused(swap("shaft on sw_leader at 2.37 Hz", 0.349), {"score": 0.341}, forms) is None
    # the bound is the margin a shaft must beat the rigid forms by
    edge = (1.0 + SHAFT_MARGIN) * 0.4729
    assert shaft_swap_refused(swap("shaft on sw_leader at 2.37 Hz", edge), {"score": 0.4729}, forms) is None
    assert shaft_swap_refused(swap("shaft on sw_leader at 2.37 Hz", 1.001 * edge), {"score": 0.4729}, forms)
    # seed-8 c24: the true dead zone in a phantom's place at 0.699 against 0.584 stays free
    assert shaft_swap_refused(swap("feedforward reference + dead zone on sw_leader", 0.699),
                              {"score": 0.584}, forms) is None
    # a rigid form is parsimony's own business
    assert shaft_swap_refused(swap("feedforward none", 9.0), {"score": 0.1}, forms) is None


def test_parsimony_keeps_a_part_the_form_leaves_whole():
    """A secondary source's part on a sensor that the one-source form does not recover at all
    (it fits the sensor worse than the set without the source as modelled) keeps the source,
    though the form is within PARSIMONY of the full set there; a phantom's unrecovered parts
    were 0.01 of NRMSE^2 or less."""
    from webline.diagnosis.structure import PARSIMONY, UNRECOVERED_PART, parsimony_rule
    # independent seed-30 c17 (roller9 real, 62 um, as its tie idler_u1, beside idler_r1's 138 um at
    # 3.39 Hz): lc9 0.752 with both, 0.779 with idler_u1 alone as modelled, 0.782 with idler_r1 alone
    # in 'feedforward reference + load-cell filter order 2' (4 % above the full set)
    full, wo, form = {"lc9.T": 0.7523, "lc19.T": 0.7706}, {"lc9.T": 0.7788, "lc19.T": 1.0087}, \
        {"lc9.T": 0.7822, "lc19.T": 0.7825}
    floor = {"lc9.T": 0.4570, "lc19.T": 0.4554}
    rows, why = parsimony_rule(full, wo, form, floor=floor)
    r = rows["lc9.T"]
    assert r["worse_than_full"] < PARSIMONY and r["recovered"] < 0
    assert wo["lc9.T"] ** 2 - full["lc9.T"] ** 2 > 2 * UNRECOVERED_PART
    assert r["unrecovered"] and why and "lc9.T" in why and "recovers none" in why
    assert not rows["lc19.T"]["unrecovered"]
    # the phantoms whose part the form did not recover took 0.002-0.01 of NRMSE^2: still dropped
    # (seed-25 c16's roller19 on lc9: 0.003, recovered -604 %; the set within PARSIMONY elsewhere)
    f, w = 0.50, (0.50 ** 2 + 0.003) ** 0.5
    p = (w ** 2 + 0.0005) ** 0.5
    rows, why = parsimony_rule({"s": f}, {"s": w}, {"s": p}, floor={"s": 0.3})
    assert rows["s"]["recovered"] < 0 and not rows["s"]["unrecovered"] and why is None
    # a part twice UNRECOVERED_PART, left whole by a form the other rules allow (it closes 20 % of
    # the gap to the floor, a small part): kept
    w = (0.50 ** 2 + 2 * UNRECOVERED_PART) ** 0.5
    p = (w ** 2 + 0.0005) ** 0.5
    assert parsimony_rule({"s": f}, {"s": w}, {"s": p}, floor={"s": 0.3})[1] is not None


def test_a_readmitted_effect_is_checked_alone_in_its_form(monkeypatch):
    """An effect the check rejected as modelled and a new form readmits must pass the check
    alone in that form (the chosen set without it, then with it). Of two at one frequency the
    weakest failing one leaves first and the other is checked again without it: a joint fit
    splits one line between them, so with the phantom beside it the real one's own drop looks
    small (independent seed-31 c12: roller9 real, idler_r1 a phantom at 3.23 Hz)."""
    from types import SimpleNamespace

    from webline.diagnosis import claims, structure

    # the local drop each element's check gives, keyed by the elements left beside it
    drops = {("roller9", ("idler_r1",)): 0.06,   # split with the phantom: under the 10 % asked
             ("idler_r1", ("roller9",)): 0.02,
             ("roller9", ()): 0.40}
    asked = []

    def fake_with_fourier(doc, cand, C, psi, add=False):
        return {"has": tuple(e for e in doc["has"] if e != cand.element)}

    def fake_check(d, before, after, local, max_worse=None):
        el, others = local[1].element, before["doc"]["has"]
        asked.append((el, others))
        drop = drops[(el, others)]
        ok = drop >= 0.10
        return {"accepted": ok, "reason": f"drop {drop}", "nrmse_before": {"s": 1.0}, "nrmse_after": {"s": 0.9},
                "local_before": 1.0, "local_after": 1.0 - drop, "local_z_drop": 100.0}

    monkeypatch.setattr(structure.layout_edit, "with_fourier", fake_with_fourier)
    monkeypatch.setattr(claims, "check", fake_check)
    rejected, notes = [], []
    d = SimpleNamespace(rejected=rejected, notes=notes,
                        _reject=lambda el, kind, stage, chk, **kw: rejected.append((el, stage, chk["reason"])))
    r9, r1 = SimpleNamespace(element="roller9", kind="eccentricity"), SimpleNamespace(element="idler_r1",
                                                                                      kind="eccentricity")
    chosen = {"name": "f", "form": "f", "doc": {"has": ("roller9", "idler_r1")}, "sims": {"doc": None},
              "X": {"roller9": [1e-4], "idler_r1": [3e-6]}}
    chosen["sims"] = {"doc": chosen["doc"]}
    unc = {"roller9": {}, "idler_r1": {}}
    structure._check_readmitted(d, chosen, [r9, r1], lambda doc, label: {"doc": doc}, unc)
    assert [r[0] for r in rejected] == ["idler_r1"] and rejected[0][1] == "structure readmission check"
    assert chosen["doc"]["has"] == ("roller9",) and set(chosen["X"]) == {"roller9"} and set(unc) == {"roller9"}
    # roller9 was asked again without the phantom, and passed there
    assert ("roller9", ()) in asked and len(notes) == 1 and "idler_r1" in notes[0]
    # an effect that passes alone stays, the set unchanged
    rejected.clear()
    chosen = {"name": "f", "doc": {"has": ("roller9",)}, "X": {"roller9": [1e-4]}}
    chosen["sims"] = {"doc": chosen["doc"]}
    structure._check_readmitted(d, chosen, [r9], lambda doc, label: {"doc": doc})
    assert rejected == [] and chosen["doc"]["has"] == ("roller9",)


def test_the_set_without_a_secondary_source_is_tried_in_lines_within_the_data_sheet():
    """structure._tolerance_lines: the set without the secondary sources, as it is, as
    its best swap and with the orders the layout's form left out taken back (independent
    seed-47 c17), is tried in TOLERANCE_LINES lines drawn within the data sheet's
    tolerances around the full set's best rigid form (the form's own keys kept, the draws
    repeatable), each predicted, per variant the best TOLERANCE_SIMULATED simulated and
    queued with the sets parsimony judges."""
    from pathlib import Path
    from types import SimpleNamespace
    from webline.diagnosis import layout_edit, structure, transfer
    from webline.diagnosis.line_model import LineModel
    ewl = Path(__file__).resolve().parents[1] / "scenarios" / "ewl.yaml"
    d = SimpleNamespace(model=LineModel(ewl))
    # keys a draw would set too (every speed loop's current lag, the web's damping)
    form_set = {"drives.speed_loops.unwind.feedforward": False, "drives.speed_loops.unwind.current_lag": "1 ms",
                "web.damping": "2 ms"}
    f_best = {"form": "feedforward none + web damping 2 ms", "description": "no feed forward; damped web",
              "set": form_set}
    zero = d.model.copy_doc()
    as_is, swapped, back = [("the primary source",)], [("another member of its tie",)], [("orders back",)]
    variants = [(as_is, None, None), (swapped, ("idler_r1", "roller19"), None), (back, None, {"sw_leader": [1]})]
    n = 4
    # predicted scores, draw by draw: the set as it is, its swap, with the orders taken back
    scores = iter([5.0, 0.5, 2.0, 3.0, 0.9, 0.3, 4.0, 0.1, 1.5, 1.0, 0.7, 0.2])
    calls, stage_a, simulated, to_b = [], [], [], [("already queued",)]

    def stage_a_one(name, desc, sets, use=None, swap=None, readmit=None):
        calls.append((name, sets, use, swap, readmit))
        label = f"{name} {swap}" + (f" {readmit}" if readmit else "")
        stage_a.append(({"name": label, "form": name, "set": sets, "predicted_score": next(scores)},
                        None, None, None))

    def stage_b(entry, alt0, X1s, Gs):
        simulated.append(entry["name"])

    structure._tolerance_lines(d, f_best, zero, variants, stage_a_one, stage_a, stage_b, to_b, n=n)
    drawn = transfer.members(layout_edit._plain_base(d.model.copy_doc()), structure._apply(zero, form_set), n=n)
    names = [structure.tolerance_line_name(f_best["form"], k) for k in range(1, n + 1)]
    assert [(c[0], c[2], c[3], c[4]) for c in calls] == [(nm, *v) for nm in names for v in variants]
    for (name, sets, use, swap, readmit), (entry, *_), i in zip(calls, stage_a, range(3 * n)):
        m = drawn[i // 3]
        # the form's keys are the form's: a draw leaves them to it
        assert sets == {**m, **form_set} and not set(m) & set(form_set)
        assert any("inertia" in key or "mass" in key for key in m)   # a line, not the form again
        assert entry["tolerance_line"] == {"draw": i // 3 + 1, "of": n, "set": m}
    # per variant the best predicted: as it is draws 4 and 2 (1.0, 3.0); swapped draws 3 and 1
    # (0.1, 0.5); with the orders back draws 4 and 2 (0.2, 0.3)
    best = [f"{names[3]} None", f"{names[1]} None", f"{names[2]} ('idler_r1', 'roller19')",
            f"{names[0]} ('idler_r1', 'roller19')", f"{names[3]} None {{'sw_leader': [1]}}",
            f"{names[1]} None {{'sw_leader': [1]}}"]
    assert structure.TOLERANCE_SIMULATED == 2
    assert simulated == best
    assert [x[0]["name"] for x in to_b[1:]] == best and to_b[0] == ("already queued",)


def test_a_line_within_the_data_sheet_must_fit_every_sensor_as_well_as_the_full_set():
    """structure.tolerance_line_refused, on seed-27 c05's and seed-33 c07's measured NRMSE:
    a set in a drawn line may replace the full set only within PARSIMONY on every sensor."""
    from webline.diagnosis.structure import PARSIMONY, tolerance_line_refused
    line = {"draw": 7, "of": 12, "set": {}}
    # seed-27 c05: roller9 and roller19 real; the line with idler_u1 alone trades lc19 for lc9
    r = {"form": "feedforward none + web damping 2 ms + line 7 within the data sheet", "tolerance_line": line,
         "nrmse": {"lc9.T": 0.3605, "lc19.T": 0.4763}}
    full = {"nrmse": {"lc9.T": 0.4756, "lc19.T": 0.2742}}
    why = tolerance_line_refused(r, full)
    assert why and "lc19.T 0.476 against 0.274" in why and "lc9.T" not in why
    # seed-33 c07: the phantom idler_u1 goes, lc19 0.5 % above the full set's
    assert tolerance_line_refused({**r, "nrmse": {"lc9.T": 0.8079, "lc19.T": 0.6967}},
                                  {"nrmse": {"lc9.T": 0.8106, "lc19.T": 0.6932}}) is None
    # the bound, and a form that is no drawn line is parsimony_rule's business
    edge = (1.0 + PARSIMONY) * 0.2742
    assert tolerance_line_refused({**r, "nrmse": {"lc9.T": 0.4, "lc19.T": edge}}, full) is None
    assert tolerance_line_refused({**r, "nrmse": {"lc9.T": 0.4, "lc19.T": 1.001 * edge}}, full)
    assert tolerance_line_refused({"form": "feedforward none", "nrmse": r["nrmse"]}, full) is None


def test_a_drive_form_says_when_a_form_of_another_kind_on_its_drive_fits_about_as_well():
    """A shaft and a dead zone on one drive can pass the lines between the zones alike
    (independent seed-47 c12: a true leader dead zone, the leader shaft claimed at 0.136,
    the dead zone 0.151): the claim then says its kind is not identifiable and names the
    rival; a rival on another drive, or beyond 'about as well', does not count."""
    from webline.diagnosis import structure
    forms = {"ff none + shaft on sw_leader at 4.45 Hz": ("sw_leader", "compliance", 4.45),
             "ff none + dead zone on sw_leader": ("sw_leader", "backlash", 1.0),
             "ff ref + dead zone on sw_leader": ("sw_leader", "backlash", 1.0),
             "ff none + dead zone on rewind": ("rewind", "backlash", 1.0)}
    rigid = {"name": "ff none", "form": "ff none", "score": 0.1676}
    chosen = {"name": "ff none + shaft on sw_leader at 4.45 Hz", "form": "ff none + shaft on sw_leader at 4.45 Hz",
              "score": 0.1355}
    # the layout's form 0.397: 'about as well' up to 0.1355 + 0.1 x 0.2615 = 0.1617
    dz = {"name": "ff none + dead zone on sw_leader", "form": "ff none + dead zone on sw_leader", "score": 0.1512}
    dz2 = {"name": "ff ref + dead zone on sw_leader", "form": "ff ref + dead zone on sw_leader", "score": 0.1590}
    far = {"name": "ff ref + dead zone on sw_leader, far", "form": "ff ref + dead zone on sw_leader", "score": 0.1620}
    rw = {"name": "ff none + dead zone on rewind", "form": "ff none + dead zone on rewind", "score": 0.1400}
    eff = structure._drive_effect(chosen, forms, [rigid, chosen, dz2, dz, far, rw], 0.397)
    assert eff["kind"] == "compliance" and eff["kind_identifiable"] is False
    # one rival a kind, its best form first
    assert eff["kind_rivals"] == [{"kind": "backlash", "form": "ff none + dead zone on sw_leader", "score": 0.1512}]
    assert "a dead zone ('ff none + dead zone on sw_leader', sum of NRMSE^2 0.1512 against 0.1355)" in eff["detail"]
    assert "not identifiable from these runs" in eff["detail"]
    # no rival within 'about as well' on this drive: identifiable, the detail as before
    eff = structure._drive_effect(chosen, forms, [rigid, chosen, far, rw], 0.397)
    assert eff["kind_identifiable"] is True and "kind_rivals" not in eff
    assert eff["detail"].endswith(")") and "identifiable" not in eff["detail"]
    # a chosen dead zone names a shaft that fits about as well the same way
    sh = dict(chosen, score=0.1500)
    eff = structure._drive_effect(dz, forms, [rigid, dz, sh], 0.397)
    assert eff["kind"] == "backlash" and eff["kind_rivals"][0]["kind"] == "compliance"
    assert "a compliant shaft (" in eff["detail"]


def test_a_shaft_whose_mode_sits_on_a_sources_line_is_placed_by_no_run_at_that_speed():
    """A mode on the line it carries between the zones only turns that line's gain and
    phase, as a dead zone the line's swing crosses once a turn does (independent seed-39
    c17: a true 1.24 deg leader dead zone claimed as a leader shaft at 5.61 Hz, 1.00 x
    guide_in's fundamental; the dead-zone form 0.4229 against the shaft's 0.1045). The
    claim says so; two fit runs at speeds that move the line off the mode do not."""
    from types import SimpleNamespace
    from webline.diagnosis import structure

    def diag(freqs):
        ctx = [SimpleNamespace(freq={"g": f}, kappa={"g": 0.0}) for f in freqs]
        return SimpleNamespace(fit_ctx=lambda: ctx, orders_for=lambda c, key: [1, 2])

    g = (SimpleNamespace(element="guide_in", key="g"), None, None)
    assert structure.line_under_mode(diag([5.6138]), [g], 5.6138) == ("guide_in", [5.6138])
    assert structure.line_under_mode(diag([5.6138]), [g], 1.02 * 5.6138 * 0.999)[0] == "guide_in"
    # the grid's next shaft, 1.25 x the line, and a second run at another speed: placed
    assert structure.line_under_mode(diag([5.6138]), [g], 7.0173) is None
    assert structure.line_under_mode(diag([5.6138, 4.21]), [g], 5.6138) is None
    forms = {"ff ref + lc2 + shaft on sw_leader at 5.61 Hz": ("sw_leader", "compliance", 5.6138),
             "ff ref + lc2 + dead zone on sw_leader": ("sw_leader", "backlash", 1.0)}
    chosen = {"name": "ff ref + lc2 + shaft on sw_leader at 5.61 Hz",
              "form": "ff ref + lc2 + shaft on sw_leader at 5.61 Hz", "score": 0.1045}
    dz = {"name": "ff ref + lc2 + dead zone on sw_leader", "form": "ff ref + lc2 + dead zone on sw_leader",
          "score": 0.4248}
    rigid = {"name": "ff ref + lc2", "form": "ff ref + lc2", "score": 0.4281}
    on = ("guide_in", [5.6138])
    eff = structure._drive_effect(chosen, forms, [rigid, chosen, dz], 1.0498, on_line=on)
    assert eff["kind"] == "compliance" and eff["kind_identifiable"] is False
    assert eff["mode_on_line"] == {"element": "guide_in", "line_hz": [5.6138]}
    assert eff["parameters"]["torsional_frequency"]["identifiable"] is False
    assert "sits on guide_in's line (5.61 Hz in the fit runs, 1.00 x)" in eff["detail"]
    assert "fitted 0.4248 against 0.1045" in eff["detail"] and "another line speed" in eff["detail"]
    # no dead zone screened on the drive (its torque never swings through zero): the mode alone
    eff = structure._drive_effect(chosen, {k: v for k, v in forms.items() if v[1] == "compliance"},
                                  [rigid, chosen], 1.0498, on_line=on)
    assert eff["kind_identifiable"] is True and "dead zone" not in eff["detail"]
    assert eff["parameters"]["torsional_frequency"]["identifiable"] is False
    # a dead zone that fits about as well is named once, as a rival
    near = dict(dz, score=0.1100)
    eff = structure._drive_effect(chosen, forms, [rigid, chosen, near], 1.0498, on_line=on)
    assert eff["kind_identifiable"] is False and eff["kind_rivals"][0]["score"] == 0.1100
    assert eff["detail"].count("is not identifiable from these runs") == 1 and "sits on guide_in's line" in eff["detail"]
    # off the line: as before
    eff = structure._drive_effect(chosen, forms, [rigid, chosen, dz], 1.0498)
    assert eff["kind_identifiable"] is True and "mode_on_line" not in eff
    assert eff["parameters"]["torsional_frequency"]["identifiable"] is True and "sits on" not in eff["detail"]
