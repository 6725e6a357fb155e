"""Detectability of a hidden drive effect in the benchmark's family "independent"
(diagnosis.benchmark_independent.detectability): the truth simulated with
and without the effect, the difference against the measurement error the case
injected. Known answers: a difference of zero is never detectable, a strong one
where the effect acts always is, and one outside its band or without a torque
reversal does not count."""
import math

import numpy as np
import pytest

from webline.diagnosis import benchmark as B
from webline.diagnosis import benchmark_independent as BI


def _noise(n, fs, sigma, seed=1):
    return np.random.default_rng(seed).normal(0.0, sigma, n)


FS, T = 250.0, 60.0
t = np.arange(0.0, T, 1.0 / FS)


def test_whitened_snr_of_a_sine_in_white_noise_is_the_matched_filter_one():
    # known signal d in white noise of variance s^2: SNR^2 = sum(d^2) / s^2 = N A^2 / 2 / s^2
    s, A, f = 0.3, 0.02, 5.0
    d = A * np.sin(2 * math.pi * f * t)
    snr, d_rms, n_rms = BI.whitened_snr(d, _noise(len(t), FS, s), FS)
    expect = math.sqrt(len(t) * A * A / 2) / s
    # the noise power per bin is estimated from one realisation smoothed over 0.5 Hz (61 bins):
    # its relative error ~ 1/sqrt(61) = 13 % in power, half that in the SNR
    assert snr == pytest.approx(expect, rel=0.15)
    assert d_rms == pytest.approx(A / math.sqrt(2), rel=1e-3) and n_rms == pytest.approx(s, rel=0.02)


def test_compliance_visibility_counts_only_its_band():
    noise = _noise(len(t), FS, 0.3)
    y0 = np.full(len(t), 100.0)
    kw = dict(torsional_hz=5.0)
    # no difference: nothing to see
    v0 = BI.effect_visibility("compliance", t, y0, y0, noise, FS, **kw)
    assert v0["snr_where"] == 0.0 and v0["snr_all"] == 0.0 and not BI._combine([v0])["detectable"]
    # a 0.1 N ringing at the torsional mode in 0.3 N of noise over 60 s: SNR ~ 29
    v1 = BI.effect_visibility("compliance", t, y0 + 0.1 * np.sin(2 * math.pi * 5.0 * t), y0, noise, FS, **kw)
    assert v1["snr_where"] > 20 and BI._combine([v1])["detectable"]
    # as strong, but at 15 Hz (outside 5 Hz -+ 30 %): visible overall, not where the effect acts
    v2 = BI.effect_visibility("compliance", t, y0 + 0.1 * np.sin(2 * math.pi * 15.0 * t), y0, noise, FS, **kw)
    assert v2["snr_all"] > 20 and v2["snr_where"] < 2 and not BI._combine([v2])["detectable"]
    # SNRs of independent records add in quadrature: 4 records of SNR 3 make 6
    c = BI._combine([{"snr_where": 3.0, "snr_all": 3.0}] * 4)
    assert c["snr_where"] == pytest.approx(6.0) and c["detectable"]


def test_under_a_torque_ripple_detectable_asks_what_a_diagnosis_can_know():
    # a matched-filter SNR of 9 that needs the ripple's sequence does not count; the
    # deterministic part's SNR or the spectral deflection does, whichever is larger
    hidden = {"snr_where": 9.0, "snr_all": 10.0, "snr_where_without_ripple": 0.6, "deflection_where": 2.4}
    c = BI._combine([hidden])
    assert c["snr_where"] == 9.0 and not c["detectable"] and c["detect_value"] == 2.4
    assert BI._combine([dict(hidden, deflection_where=5.5)])["detectable"]
    assert BI._combine([{k: v for k, v in hidden.items() if k != "deflection_where"} |
                        {"snr_where_without_ripple": 6.0}])["detectable"]
    # two records of deflection 4 each add in quadrature to 5.7
    assert BI._combine([dict(hidden, deflection_where=4.0)] * 2)["detectable"]


def test_stochastic_deflection_of_a_random_difference_is_its_power_ratio_per_bin():
    # a random difference with a^2 the noise's power per bin: P_k/S_k ~ a^2 in every bin, so
    # sqrt(sum (P/S)^2) = a^2 sqrt(bins); both periodograms are smoothed over 0.5 Hz (31 bins
    # here), a relative error of about 1/sqrt(31) each: 25 % on the squared ratio covers it
    a, s = 0.7, 0.3
    noise = _noise(len(t), FS, s, seed=3)
    delta = _noise(len(t), FS, a * s, seed=4)
    band = (2.0, 8.0)
    bins = int(np.sum((np.fft.rfftfreq(len(t), 1 / FS) >= band[0]) & (np.fft.rfftfreq(len(t), 1 / FS) <= band[1])))
    d = BI.stochastic_deflection(delta, noise, FS, band)
    assert d == pytest.approx(a * a * math.sqrt(bins), rel=0.25)
    # it needs the difference's spectrum only: a random sequence of the same spectrum scores alike
    d2 = BI.stochastic_deflection(_noise(len(t), FS, a * s, seed=5), noise, FS, band)
    assert d2 == pytest.approx(d, rel=0.15)
    assert BI.stochastic_deflection(np.zeros(len(t)), noise, FS, band) == 0.0


def _mode(x, f0, zeta=0.05):
    """``x`` through a two-mass mode's resonance at ``f0`` (unit gain at DC)."""
    from scipy import signal
    w = 2 * math.pi * f0
    b, a = signal.bilinear([w * w], [1.0, 2 * zeta * w, w * w], FS)
    return signal.lfilter(b, a, x)


def test_profiled_deflection_counts_the_modes_shape_not_the_ripples_level():
    # the rigid line's ripple response at a level no diagnosis knows: any multiple of it
    # leaves no shape to detect, while the plain deflection counts the rise of power
    noise = _noise(len(t), FS, 0.3, seed=6)
    rigid = _noise(len(t), FS, 0.3, seed=7)
    band = (3.5, 6.5)
    assert BI.profiled_deflection(3.0 * rigid, [rigid], noise, FS, band) == pytest.approx(0.0, abs=1e-6)
    assert BI.stochastic_deflection(2.0 * rigid, noise, FS, band) > 10 * BI.DETECT_SNR
    # the same ripple through a mode at 5 Hz (10 % damping ratio): a peak whose shape no
    # scaling of the rigid response makes
    shaft = _mode(rigid, 5.0, zeta=0.1)
    d = BI.profiled_deflection(shaft, [rigid], noise, FS, band)
    assert d > 10 * BI.DETECT_SNR
    # the least deflection over the rigid alternatives: one of them with that shape is enough
    assert BI.profiled_deflection(shaft, [rigid, 0.5 * shaft], noise, FS, band) == pytest.approx(0.0, abs=1e-6)
    assert BI.profiled_deflection(shaft, [rigid, _mode(rigid, 5.3, zeta=0.1)], noise, FS, band) < 0.8 * d
    # a lower ripple makes the same shape less visible against the error: quadratic in the level
    assert BI.profiled_deflection(0.1 * shaft, [rigid], noise, FS, band) == pytest.approx(0.01 * d, rel=1e-6)


def test_a_shafts_detectable_value_is_the_profiled_deflection_where_recorded():
    rec = {"snr_where": 9.0, "snr_all": 10.0, "snr_where_without_ripple": 0.6, "deflection_where": 40.0,
           "deflection_profiled": 2.0}
    c = BI._combine([rec])
    assert c["detect_value"] == 2.0 and not c["detectable"] and c["deflection_where"] == 40.0
    assert "level" in c["detect_basis"] and "inertia" in c["detect_basis"]
    assert BI._combine([dict(rec, snr_where_without_ripple=6.0)])["detect_value"] == 6.0
    # a record without the profiled value (cases made before it) keeps the plain deflection
    assert BI._combine([{k: v for k, v in rec.items() if k != "deflection_profiled"}])["detect_value"] == 40.0


def test_claimable_asks_whether_the_effect_lowers_the_truths_own_error_on_every_sensor():
    """The no-worse target applied to the truth: the effect's deterministic part, added
    to the truth without it, must not raise any sensor's error against the data."""
    y = 100.0 + _noise(len(t), FS, 0.3, seed=3)
    d = 0.05 * np.sin(2 * math.pi * 3.0 * t)
    base = np.full(len(t), 100.0)
    # the data carry the effect: its error falls by what the effect explains
    r = BI.no_worse_record(y + d, base + d, base)
    assert r["error_with_N"] < r["error_without_N"] and r["error_rise"] < 0
    # the data do not: the rise is (|d|^2 - 2 <d, noise>) / (2 |noise|^2) to first order
    r = BI.no_worse_record(y, base + d, base)
    n = y - base
    expect = (np.sum(d ** 2) - 2 * np.dot(d, n)) / (2 * np.sum(n ** 2))
    assert r["error_rise"] == pytest.approx(expect, rel=0.05) and r["error_rise"] > 0
    rec = {"snr_where": 9.0, "snr_all": 10.0}
    better, worse = BI.no_worse_record(y + d, base + d, base), BI.no_worse_record(y, base + d, base)
    assert BI._combine([dict(rec, **better)] * 2)["claimable"] is True
    c = BI._combine([dict(rec, **better), dict(rec, **worse)])
    assert c["claimable"] is False and c["worst_error_rise"] == worse["error_rise"]
    # a rise within rounding is no rise (the target's own tolerance)
    assert BI._combine([dict(rec, error_rise=0.5 * BI.WORSE_RTOL)])["claimable"] is True
    # records made before it was measured: not known, not false
    assert "claimable" not in BI._combine([rec])


def test_backlash_visibility_needs_a_torque_reversal():
    noise = _noise(len(t), FS, 0.3, seed=2)
    y0 = np.full(len(t), 100.0)
    # a 1 N transient decaying in 50 ms after the torque crosses zero at 30 s: sum(d^2) =
    # FS * 0.05 / 2 = 6.25 samples' worth, SNR = sqrt(6.25) / 0.3 = 8.3 in white noise
    bump = np.where(t >= 30.0, np.exp(-(t - 30.0) / 0.05), 0.0)
    tau = np.where(t < 30.0, 0.5, -0.5)
    v = BI.effect_visibility("backlash", t, y0 + bump, y0, noise, FS, tau=tau)
    assert v["reversals"] == 1 and v["snr_where"] == pytest.approx(8.33, rel=0.15)
    assert BI._combine([v])["detectable"]
    # the same difference with a torque that never changes sign (a drive held by the web)
    v = BI.effect_visibility("backlash", t, y0 + bump, y0, noise, FS, tau=np.full(len(t), 0.5))
    assert v["reversals"] == 0 and v["snr_where"] == 0.0 and not BI._combine([v])["detectable"]
    # a torque that comes down to zero without changing sign opens the dead zone as well
    tau = np.where(np.abs(t - 30.0) < 0.1, 0.0, 0.5)
    v = BI.effect_visibility("backlash", t, y0 + bump, y0, noise, FS, tau=tau)
    assert v["reversals"] == 1 and v["snr_where"] == pytest.approx(8.33, rel=0.15)
    mask, k = BI.near_zero_windows(t, tau)
    assert k == 1 and mask.mean() == pytest.approx(1.2 / T, abs=2.0 / FS / T)   # 0.2 s + 2 x 0.5 s


def test_drive_detectability_of_a_made_case_and_the_scorer(tmp_path):
    """A compliance case made by the generator: the truth engine run with and without
    the shaft, the measurement error regenerated from the case's seed (its rms is the
    one the case recorded), the layout without it has the inertia back on the element."""
    doc = B.derive_line()
    facts = B.line_facts(B.write_yaml(tmp_path / "l.yaml", doc))
    cases = BI.draw_cases(9, seed=0, layout_doc=doc, facts=facts)
    case = next(c for c in cases if c.category == "compliance")
    for r in case.runs:
        r.duration_s = 3.0
    folder = tmp_path / "independent" / "cases" / case.id
    truth = BI.make_case(case, folder, doc)
    i = next(k for k, e in enumerate(truth["effects"]) if e["kind"] == "compliance")
    det = truth["effects"][i]["detectable"]
    assert det["threshold"] == BI.DETECT_SNR and isinstance(det["detectable"], bool)
    fit = [r for r in truth["runs"] if not r["holdout"]]
    assert [r["run"] for r in det["runs"]] == [r["name"] for r in fit]
    for rr, r in zip(det["runs"], fit):
        assert r["ripple_set"]  # every truth drive has its torque ripple
        for lc, v in rr["sensors"].items():
            assert v["noise_rms_N"] == pytest.approx(r["sensors"][lc]["noise_rms_N"], rel=1e-9)
            assert v["delta_rms_N"] > 0 and math.isfinite(v["snr_where"])
            assert v["deflection_where"] >= 0 and math.isfinite(v["snr_where_without_ripple"])
    assert "deflection_where" in det and "snr_where_without_ripple" in det
    # each record says whether the shaft lowers the truth's own error there; the effect is
    # claimable where it does on every one
    rises = [v["error_rise"] for rr in det["runs"] for v in rr["sensors"].values()]
    assert det["worst_error_rise"] == max(rises) and det["claimable"] == (max(rises) <= BI.WORSE_RTOL)
    assert not any(r["holdout"] for r in truth["runs"]) and "held_out" not in det   # one run, no held-out
    # the shaft's detectable value profiles out the ripple's level and the element's inertia
    assert 0 <= det["deflection_profiled"] and det["detect_value"] == max(det["deflection_profiled"],
                                                                          det["snr_where_without_ripple"])
    el = truth["effects"][i]["element"]
    wo = BI._layout_without(truth, doc, folder / "blind" / "line.yaml", i)["set"]
    pset, _ = BI.param_set(BI.TruthModel(**truth["model"]), doc)
    assert f"drives.speed_loops.{el}.drive" in truth["set"] and f"drives.speed_loops.{el}.drive" not in wo
    tset = B.truth_set(case, BI.param_set(case.model, doc)[1])
    moved = [k for k in pset if k.startswith(f"path.{el}.") and k in tset]
    assert moved and all(wo[k] == pset[k] != truth["set"][k] for k in moved)
    # the scorer: recall over all drive effects and over the detectable ones
    t2 = {"id": "x", "effects": [dict(truth["effects"][i], detectable={"detectable": True}),
                                 {"kind": "backlash", "element": "rewind", "detectable": {"detectable": False}}],
          "runs": truth["runs"]}
    rep = {"effects": [{"element": el, "kind": "compliance", "candidates": [el]}]}
    s = BI.target_scores([{"truth": t2, "report": rep}])
    assert {k: s["drive"][k] for k in ("true", "matched", "detectable", "matched_detectable")} == \
        {"true": 2, "matched": 1, "detectable": 1, "matched_detectable": 1}
    assert s["drive"]["recall"] == 0.5 and s["drive"]["recall_detectable"] == 1.0
    assert s["recall"] == 0.5  # the headline stays over all effects
    row = next(r for r in BI.target_rows(s) if r[3] == "drive_recall")
    assert "all: 50 % (1/2); detectable only: 100 % (1/1)" in row[1] and "named possible" not in row[1]
    assert "claimable" not in row[1] and s["drive"]["claim_measured"] == 0
    # where measured: of the detectable, those the truth's own model takes in with no sensor worse
    t2c = dict(t2, effects=[dict(t2["effects"][0], detectable={"detectable": True, "claimable": False}),
                            t2["effects"][1]])
    sc = BI.target_scores([{"truth": t2c, "report": rep}])
    assert {k: sc["drive"][k] for k in ("claim_measured", "claimable", "matched_claimable")} == \
        {"claim_measured": 1, "claimable": 0, "matched_claimable": 0}
    row = next(r for r in BI.target_rows(sc) if r[3] == "drive_recall")
    assert "; of those, 0 the truth's own model takes in with no sensor worse: - (0/0)" in row[1]
    # a shaft named possible but not claimed is no find; counted beside, with those on a drive
    # without a hidden shaft
    other = next(e for e in ("unwind", "rewind", "sw_leader") if e != el)
    # ... and those whose layout lowers every sensor's NRMSE on the held-out runs (one sensor up: not)
    lower = {"nrmse_before": {"lc9.T": 1.0, "lc19.T": 0.9}, "nrmse_after": {"lc9.T": 0.99, "lc19.T": 0.89}}
    mixed = {"nrmse_before": {"lc9.T": 1.0, "lc19.T": 0.9}, "nrmse_after": {"lc9.T": 0.99, "lc19.T": 0.91}}
    rep_p = {"effects": [], "findings": [{"kind": "possible drive shaft", "element": el, "holdout": lower},
                                         {"kind": "possible drive shaft", "element": other, "holdout": mixed},
                                         {"kind": "unexplained resonance", "element": None}]}
    sp = BI.target_scores([{"truth": t2, "report": rep_p}])
    assert sp["drive"]["matched"] == 0 and sp["drive"]["possible_shafts"] == {"named": 2, "on_a_hidden_shaft": 1,
                                                                               "held_out_lower": 1}
    row = next(r for r in BI.target_rows(sp) if r[3] == "drive_recall")
    assert row[1].endswith("; 2 shaft(s) named possible, not claimed (1 on a hidden shaft; 1 lowering every "
                           "sensor's NRMSE on the held-out runs)")
    # every kind: a periodic effect found as an element it cannot be told from counts, one
    # the data cannot show leaves the recall over the detectable ones alone
    ecc = {"kind": "eccentricity", "element": "idler_r1", "indistinguishable": ["idler_r1", "roller19"],
           "C_m": [1e-4], "psi_rad": [0.0], "detectable": {"detectable": True, "detect_value": 22.0}}
    t3 = dict(t2, effects=t2["effects"] + [ecc, dict(ecc, element="unwind", kind="out_of_round",
                                                     indistinguishable=["unwind"],
                                                     detectable={"detectable": False})])
    f_true = float(np.mean([r["fundamental_hz"]["idler_r1"] for r in truth["runs"] if not r["holdout"]]))
    rep3 = {"effects": rep["effects"] + [{"element": "roller19", "kind": "eccentricity", "fundamental_hz": f_true,
                                          "candidates": [{"element": "roller19"}, {"element": "idler_r1"}]}]}
    s3 = BI.target_scores([{"truth": t3, "report": rep3}])
    assert {k: s3["detectable"][k] for k in ("true", "matched", "detectable", "matched_detectable")} == \
        {"true": 4, "matched": 2, "detectable": 2, "matched_detectable": 2}
    assert s3["drive"]["true"] == 2 and s3["recall"] == 0.5
    row = next(r for r in BI.target_rows(s3) if r[3] == "detectable_recall")
    assert "all: 50 % (2/4); detectable only: 100 % (2/2)" in row[1]


def test_periodic_visibility_is_the_matched_filter_over_every_frequency():
    # a run-out's lines are locked to an angle a diagnosis knows: the whole difference counts
    s, A = 0.3, 0.02
    noise = _noise(len(t), FS, s, seed=7)
    y0 = np.full(len(t), 100.0)
    d = A * np.sin(2 * math.pi * 1.1 * t) + A * np.sin(2 * math.pi * 4.4 * t)
    v = BI.effect_visibility("eccentricity", t, y0 + d, y0, noise, FS)
    assert v["snr_where"] == v["snr_all"] == pytest.approx(BI.whitened_snr(d, noise, FS)[0])
    # two lines of SNR sqrt(N A^2 / 2) / s each add in quadrature; smoothed-PSD error as above
    assert v["snr_where"] == pytest.approx(math.sqrt(len(t) * A * A) / s, rel=0.15)
    with pytest.raises(ValueError, match="not a hidden effect kind"):
        BI.effect_visibility("sensor", t, y0, y0, noise, FS)


def test_periodic_detectability_of_a_made_case_counts_the_ripple_as_noise(tmp_path):
    """An eccentric roller made by the generator: its visibility is the truth with and
    without its run-out, both without the drives' ripple, against the error the case
    injected plus the ripple-rung response (which no model of the run-out reproduces)."""
    doc = B.derive_line()
    facts = B.line_facts(B.write_yaml(tmp_path / "l.yaml", doc))
    case = next(c for c in BI.draw_cases(4, seed=0, layout_doc=doc, facts=facts) if c.category == "eccentric")
    for r in case.runs:
        r.duration_s = 3.0
    truth = BI.make_case(case, tmp_path / case.id, doc)
    det = truth["effects"][0]["detectable"]
    assert det["threshold"] == BI.DETECT_SNR and det["detect_value"] == det["snr_where"] == det["snr_all"]
    fit = [r for r in truth["runs"] if not r["holdout"]]
    for rr, r in zip(det["runs"], fit):
        for lc, v in rr["sensors"].items():
            assert v["delta_rms_N"] > 0 and v["where"] == "the element's harmonics"
            # the error the case injected plus the ripple-rung part (0.2-1 % of the drives'
            # torque: tenths of the error at most): not the error alone, close to it
            assert v["noise_rms_N"] != pytest.approx(r["sensors"][lc]["noise_rms_N"], rel=1e-9)
            assert v["noise_rms_N"] == pytest.approx(r["sensors"][lc]["noise_rms_N"], rel=0.5)
    # a run-out the data show lowers the truth's own error everywhere, on the held-out run too
    # (which the target counts as well)
    assert det["claimable"] is True and det["worst_error_rise"] < 0
    held = [r["name"] for r in truth["runs"] if r["holdout"]]
    assert held and [h["run"] for h in det["held_out"]] == held
    rises = [v["error_rise"] for h in det["held_out"] for v in h["sensors"].values()]
    assert det["held_out_worst_error_rise"] == max(rises)
    assert det["held_out_claimable"] == (max(rises) <= BI.WORSE_RTOL)
    # against the error the case injected there (regenerated from the run's seed)
    for h in det["held_out"]:
        r = next(r for r in truth["runs"] if r["name"] == h["run"])
        for lc, v in h["sensors"].items():
            assert v["noise_rms_N"] == pytest.approx(r["sensors"][lc]["noise_rms_N"], rel=1e-9)
    wo = BI._layout_without(truth, doc, tmp_path / case.id / "blind" / "line.yaml", 0)["set"]
    el = case.effects[0].element
    assert any(k.startswith(f"path.{el}.") and k not in wo for k in truth["set"])


def test_summary_counts_detectable_drive_effects_and_says_so():
    """The own family's summary and table: a recorded measurement decides, else a
    backlash counts as detectable where its drive torque reverses, a compliance
    without a measurement is not known (and gets no note)."""
    def truth(i, effects, torque=None):
        return {"id": f"c{i}", "category": "x", "effects": effects,
                "runs": [{"name": "run1", "holdout": False, "fundamental_hz": {},
                          "drive_torque": torque or {}, "sensors": {}}]}

    bl = {"kind": "backlash", "element": "sw_leader", "indistinguishable": ["sw_leader"]}
    co = {"kind": "compliance", "element": "sw_leader", "indistinguishable": ["sw_leader"]}
    found = {"effects": [{"element": "sw_leader", "kind": "compliance", "candidates": ["sw_leader"]}]}
    cases = [
        (truth(1, [dict(co, detectable={"detectable": True})]), found),
        (truth(2, [dict(co, detectable={"detectable": False})]), {"effects": []}),
        (truth(3, [bl], {"sw_leader": {"min_Nm": -1.0, "max_Nm": 1.0}}), {"effects": []}),   # reverses
        (truth(4, [bl], {"sw_leader": {"min_Nm": 0.5, "max_Nm": 1.0}}), {"effects": []}),    # never
        (truth(5, [dict(bl, detectable={"detectable": False})], {"sw_leader": {"min_Nm": -1.0, "max_Nm": 1.0}}),
         {"effects": []}),  # the measurement wins over the reversal
    ]
    results = [{"truth": t, "report": r, "score": B.score_case(t, r), "gap": None, "wall_s": 1.0} for t, r in cases]
    s = B.summarize(results)
    assert s["drive_detectable"]["compliance"] == {"true": 1, "matched": 1, "unknown": 0}
    assert s["drive_detectable"]["backlash"] == {"true": 1, "matched": 0, "unknown": 0}
    assert s["backlash_with_torque_reversal"] == s["drive_detectable"]["backlash"]
    md = B.markdown(s)
    assert "| compliance: precision / recall | 100 % (1/1) / 50 % (1/2); 1 of the 2 hidden detectable" in md
    assert "| backlash: precision / recall | - (0/0) / 0 % (0/3); 1 of the 3 hidden detectable" in md
    # a compliance without a measurement: not known, no note
    t6 = truth(6, [co])
    s6 = B.summarize([{"truth": t6, "report": found, "score": B.score_case(t6, found), "gap": None, "wall_s": 1.0}])
    assert s6["drive_detectable"]["compliance"]["unknown"] == 1
    assert "hidden detectable" not in B.markdown(s6)


def test_own_family_records_detectability_of_its_drive_effects(tmp_path):
    """The family "own" measures detectability the same way (truth with and without
    the effect, against the white noise it added): a backlash whose drive torque never
    reverses (on the unwind, held back by the web) changes next to nothing; one on the
    speed master, whose torque does reverse in the speed ramp, stands far out."""
    doc = B.derive_line()
    facts = B.line_facts(B.write_yaml(tmp_path / "l.yaml", doc))
    cases = {c.id: c for c in B.draw_cases(24, seed=0, layout_doc=doc, facts=facts)}
    got = {}
    for cid in ("c06", "c18"):  # rewind backlash / sw_leader backlash (the draw's, pinned by seed 0)
        case = cases[cid]
        assert [(e.kind, e.element) for e in case.effects] == [("backlash", "rewind" if cid == "c06" else "sw_leader")]
        truth = B.make_case(case, tmp_path / cid, doc)
        det = truth["effects"][0]["detectable"]
        fit = [r for r in truth["runs"] if not r["holdout"]]
        for rr, r in zip(det["runs"], fit):
            for lc, v in rr["sensors"].items():
                # the same noise draw: the case records it over the whole record, the visibility
                # over the settled window (1 s of 10 s less): equal within the rms's sampling error
                assert v["noise_rms_N"] == pytest.approx(r["sensors"][lc]["noise_rms_N"], rel=0.03)
        got[cid] = det
    assert not got["c06"]["detectable"] and got["c06"]["snr_where"] == 0.0
    assert got["c18"]["detectable"] and got["c18"]["snr_where"] > 10 * BI.DETECT_SNR


def test_own_family_records_detectability_of_its_periodic_effects(tmp_path):
    """A run-out in the family "own": its lines in white noise of the run's sigma, so the
    matched filter's SNR is rms(difference) sqrt(n) / sigma per load cell and run."""
    doc = B.derive_line()
    facts = B.line_facts(B.write_yaml(tmp_path / "l.yaml", doc))
    case = next(c for c in B.draw_cases(4, seed=0, layout_doc=doc, facts=facts) if c.category == "eccentric")
    truth = B.make_case(case, tmp_path / case.id, doc)
    det = truth["effects"][0]["detectable"]
    fit = {r["name"]: r for r in truth["runs"] if not r["holdout"]}
    assert [r["run"] for r in det["runs"]] == list(fit)
    for rr in det["runs"]:
        spec = fit[rr["run"]]["spec"]
        for v in rr["sensors"].values():
            n = spec["duration_s"] * B.FS - B.FS  # the settled window (the first second left out)
            expect = v["delta_rms_N"] * math.sqrt(n) / spec["noise_N"]
            # the noise power per bin from one realisation smoothed over 0.5 Hz: ~10 % in the SNR
            assert v["snr_where"] == pytest.approx(expect, rel=0.15)
    assert det["detectable"] == (det["detect_value"] >= BI.DETECT_SNR)



def test_rescore_measures_detectability_of_cases_made_before(tmp_path):
    """A case folder whose truth.json has no ``detectable`` (made before it was
    measured) gets it on a rescore, the same numbers as when the case is made."""
    import json
    from webline.diagnosis import benchmark_cmd
    doc = B.derive_line()
    facts = B.line_facts(B.write_yaml(tmp_path / "l.yaml", doc))
    case = next(c for c in BI.draw_cases(9, seed=0, layout_doc=doc, facts=facts) if c.category == "compliance")
    for r in case.runs:
        r.duration_s = 3.0
    folder = tmp_path / "independent" / "cases" / case.id
    made = BI.make_case(case, folder, doc)
    p = folder / "truth" / "truth.json"
    old = json.loads(p.read_text())
    for e in old["effects"]:
        e.pop("detectable", None)
    p.write_text(json.dumps(old))
    (folder / "diagnosis").mkdir()
    (folder / "diagnosis" / "report.json").write_text(json.dumps({"effects": []}))
    out = tmp_path / "res.json"
    assert benchmark_cmd.main(["--family", "independent", "--rescore", "--out", str(tmp_path),
                               "--results", str(out)]) == 0
    new = json.loads(p.read_text())
    i = next(k for k, e in enumerate(made["effects"]) if e["kind"] == "compliance")
    assert new["effects"][i]["detectable"]["snr_where"] == pytest.approx(made["effects"][i]["detectable"]["snr_where"],
                                                                           rel=1e-9)
    ts = json.loads(out.read_text())["families"]["independent"]["target_scores"]
    assert ts["drive"]["true"] == 1 and ts["drive"]["unknown"] == 0
    # a shaft recorded before its profiled deflection was measured gets it too
    prof = made["effects"][i]["detectable"]["deflection_profiled"]
    del new["effects"][i]["detectable"]["deflection_profiled"]
    p.write_text(json.dumps(new))
    assert benchmark_cmd.main(["--family", "independent", "--rescore", "--out", str(tmp_path),
                               "--results", str(out)]) == 0
    again = json.loads(p.read_text())["effects"][i]["detectable"]
    assert again["deflection_profiled"] == pytest.approx(prof, rel=1e-9)
    assert again["detect_value"] == pytest.approx(made["effects"][i]["detectable"]["detect_value"], rel=1e-9)


def test_a_found_shafts_mode_is_scored_against_the_truths_with_its_range():
    """A found compliance carries its torsional mode and the range of the shafts that fit
    about as well; the benchmark says how far the mode is from the truth's (the scorer's
    match) and whether the truth lies inside that range (a mode the reported range misses
    is said so, not hidden)."""
    t = {"kind": "compliance", "element": "sw_leader", "drive": {"torsional_hz": 13.56},
         "detectable": {"detectable": True, "detect_value": 122.0}}
    truth = {"id": "x", "effects": [t], "runs": [{"name": "run1", "holdout": False}]}

    def mode(tr, eff):
        m = B.score_case(tr, {"effects": [eff]})["matches"]
        return BI.shaft_mode(m[0], [eff]) if m else None

    within = {"element": "sw_leader", "kind": "compliance", "fundamental_hz": 10.9,
              "parameters": {"torsional_frequency": {"estimated": 10.9, "unit": "Hz", "range": [10.9, 14.75]}}}
    m = mode(truth, within)
    assert m["in_range"] and m["range_hz"] == [10.9, 14.75]
    assert m["rel_error"] == pytest.approx((13.56 - 10.9) / 13.56, rel=1e-12)
    # no range given: the estimate alone, which misses the truth
    alone = {"element": "sw_leader", "kind": "compliance", "fundamental_hz": 10.9,
             "parameters": {"torsional_frequency": {"estimated": 10.9, "unit": "Hz"}}}
    assert mode(truth, alone)["in_range"] is False
    assert mode(truth, dict(alone, element="rewind")) is None
    # a roll's material on the load side lowers its two-mass mode: that is the yardstick
    roll = dict(truth, effects=[dict(t, drive={"torsional_hz": 9.54, "mode_hz": 8.72})])
    assert mode(roll, within)["true_hz"] == 8.72 and mode(roll, within)["in_range"] is False
    s = BI.target_scores([{"truth": truth, "report": {"effects": [within]}},
                          {"truth": dict(truth, id="y"), "report": {"effects": [alone]}},
                          {"truth": dict(truth, id="z"), "report": {"effects": [dict(alone, element="rewind")]}}])
    sm = s["drive"]["shaft_modes"]
    assert sm["n"] == 2 and sm["in_range"] == 1 and [f["id"] for f in sm["found"]] == ["x", "y"]
    row = next(r for r in BI.target_rows(s) if r[3] == "drive_recall")
    assert row[1].endswith("; found shafts' torsional modes: the truth inside the reported range 1/2")
