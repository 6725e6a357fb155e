"""Mechanics of 'no claim without a check', what is left / possible, and the
speed-scale rule (docs/diagnose.md, issue 9 items 1-3), on synthetic signals
whose answers follow by hand."""
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from records import assert_no_sensor_worse, measured_run

from webline.diagnosis import claims
from webline.diagnosis import estimate as est
from webline.diagnosis import layout_edit
from webline.diagnosis.candidates import Candidate
from webline.diagnosis.line_model import Sim
from webline.diagnosis.pipeline import Diagnosis, Options, RunCtx

EWL = Path(__file__).resolve().parents[1] / "scenarios" / "ewl.yaml"


# ----------------------------------------------------------------- decide ----
def test_decide_rejects_a_sensor_made_worse_by_more_than_2_percent():
    before = {"lc9.T": 1.0, "lc15.T": 0.50}
    ok, why = claims.decide(before, {"lc9.T": 0.40, "lc15.T": 0.512}, 10.0, 1.0, 500.0)
    assert not ok and "lc15.T" in why and "2.4 %" in why
    ok, _ = claims.decide(before, {"lc9.T": 0.40, "lc15.T": 0.509}, 10.0, 1.0, 500.0)
    assert ok


def test_decide_rejects_an_effect_that_does_not_lower_its_own_residual():
    nb = {"lc9.T": 1.0}
    assert not claims.decide(nb, {"lc9.T": 0.99}, 10.0, 9.5, 500.0)[0]      # 5 % < 10 %
    assert not claims.decide(nb, {"lc9.T": 0.99}, 10.0, 5.0, 4.0)[0]        # a drop noise gives
    assert claims.decide(nb, {"lc9.T": 0.99}, 10.0, 5.0, 40.0)[0]


# ---------------------------------------------------- what was possible ----
def test_closed_share_and_achievable_arithmetic():
    # nominal 1.0, refined 0.5, noise allows 0.3: closed 0.5 / 0.7
    assert claims.closed_share(1.0, 0.5, 0.3) == pytest.approx(0.5 / 0.7)
    assert claims.closed_share(1.0, 0.3, 0.3) == pytest.approx(1.0)
    assert claims.closed_share(1.0, 1.1, 0.3) == pytest.approx(-0.1 / 0.7)
    assert claims.closed_share(0.301, 0.3, 0.3) is None                    # no room to close
    # two runs: variance 0.04 N^2 over 1000 samples and 0.09 over 3000; deviations 100 + 900
    ach = claims.achievable_nrmse([0.04, 0.09], [1000, 3000], [100.0, 900.0])
    assert ach == pytest.approx(math.sqrt((40.0 + 270.0) / 1000.0))
    assert claims.achievable_nrmse(0.05, 1000, 48.0) == 1.0   # noise estimate above the data's variance


def test_noise_floor_is_the_white_noise_under_lines_and_line_dynamics():
    fs, n = 500.0, 30000
    rng = np.random.default_rng(3)
    t = np.arange(n) / fs
    sigma = 0.3
    y = 2.0 * np.sin(2 * np.pi * 1.0 * t) + 0.5 * np.sin(2 * np.pi * 17 * t) + rng.normal(0, sigma, n)
    var, S, band = claims.noise_floor(y, fs, f_lo=40.0)
    # the Welch median over ~1400 bins: a few % scatter
    assert math.sqrt(var) == pytest.approx(sigma, rel=0.05)
    assert S == pytest.approx(sigma ** 2 / (fs / 2), rel=0.1)


def test_a_broadband_hump_is_a_finding_and_a_line_is_not():
    from scipy import signal
    fs, n = 250.0, 250 * 40
    rng = np.random.default_rng(1)
    t = np.arange(n) / fs
    noise = rng.normal(0, 0.2, n)
    # a lightly damped mode at 17 Hz driven by white noise: resonant 2nd-order filter
    w0, z = 2 * np.pi * 17.0, 0.04
    b, a = signal.bilinear([w0 ** 2], [1.0, 2 * z * w0, w0 ** 2], fs)
    hump = signal.lfilter(b, a, rng.normal(0, 0.3, n))
    line = 0.8 * np.sin(2 * np.pi * 9.0 * t)
    d = _fake_diagnosis({"lc15.T": noise + hump + line}, fs, t, models={"lc15.T": np.zeros(n)})
    d.steps = [{"sims": {"r": Sim(None, {"lc15.T": np.zeros(n)})}}]
    d.where_report = {}
    noise_est = claims.sensor_noise(d)
    found = claims.humps(d, noise_est)
    assert found, "the 17 Hz resonance is not reported"
    assert abs(found[0]["frequency_hz"] - 17.0) <= 0.5   # 2 bins of 0.25 Hz
    assert found[0]["text"].startswith(f"unexplained resonance near {found[0]['frequency_hz']:.3g} Hz on lc15")
    assert all(abs(h["frequency_hz"] - 9.0) > 1.0 for h in found)          # the line is not a hump
    # the line alone: nothing
    d2 = _fake_diagnosis({"lc15.T": noise + line}, fs, t, models={"lc15.T": np.zeros(n)})
    d2.steps = d.steps
    d2.where_report = {}
    assert claims.humps(d2, claims.sensor_noise(d2)) == []


# ---------------------------------------------------- speed-scale rule ----
def test_speed_governed_and_radius_set_elements_keep_kappa_zero():
    assert not Diagnosis.kappa_allowed(Candidate("eccentricity", "sw_leader", "sw_leader", "DrivenRoller", 0.15))
    assert not Diagnosis.kappa_allowed(Candidate("out_of_round", "unwind", "unwind", "UnwindRoll", 0.16))
    assert Diagnosis.kappa_allowed(Candidate("eccentricity", "idler_u1", "idler_u1", "IdleRoller", 0.0381))


def test_a_stretched_speed_master_line_cannot_take_an_idlers_line():
    """Issue 9 (a): an idler's line at 4.244 Hz next to order 4 of the speed master
    (1.052 Hz -> 4.208 Hz). The master's family may not be stretched 0.8 % onto the
    idler's line; the idler's own family finds it with no stretch, and an idler's
    stretch (a radius error) is one value for all runs, carried as a radius."""
    fs, n = 100.0, 6000
    t = np.arange(n) / fs
    th_master = 2 * np.pi * 1.052 * t
    th_idler = 2 * np.pi * 4.244 * t
    y = 3.0 * np.sin(th_idler + 0.3) + np.random.default_rng(0).normal(0, 0.2, n)
    d = _fake_diagnosis({"lc9.T": y}, fs, t, models={"lc9.T": np.zeros(n)})
    master = Candidate("eccentricity", "sw_leader", "sw_leader", "DrivenRoller", 0.154, "sw_leader.theta")
    idler = Candidate("eccentricity", "idler_u1", "idler_u1", "IdleRoller", 0.0381, "idler_u1.theta")
    d.cands = [master, idler]
    c = d.ctx[0]
    c.theta = {master.key: th_master, idler.key: th_idler / 1.01}          # idler radius 1 % off
    c.theta_src = {master.key: "model", idler.key: "model"}
    c.freq = {master.key: 1.052, idler.key: 4.244 / 1.01}
    c.fc = 0.3
    c.periodic = {"lc9.T": y - np.mean(y)}
    kap_master = d._refine_kappa_joint([c], master)
    assert kap_master != 0.0     # unconstrained, the fit would stretch the master onto the idler's line ...
    d.opt.max_effects = 1
    d.which()                    # ... which() does not let it
    assert c.kappa[master.key] == 0.0
    assert c.kappa[idler.key] == pytest.approx(0.01, abs=0.002)
    assert d.effects[0]["best"]["cand"] is idler
    doc = d.with_effect(layout_edit.base_doc(EWL), idler, np.array([1e-4, 0, 0], complex))
    R = float(doc["set"]["path.idler_u1.radius"].split()[0])
    assert R == pytest.approx(0.0381 / (1 + c.kappa[idler.key]), rel=1e-6)
    doc = d.with_effect(layout_edit.base_doc(EWL), master, np.array([1e-4, 0, 0], complex))
    assert "path.sw_leader.radius" not in doc["set"]



def test_an_idlers_radius_error_may_not_carry_its_line_onto_another_elements_order():
    """Independent seed-2 c17: the S-wrap leader (1.1289 Hz) is eccentric with a strong
    order 4 (4.5154 Hz); an idler turns at 4.553 Hz. Scaled by -0.83 % the idler's
    family sits on the leader's order 4 and would take it; the layout's idler radius
    is not in question when another element turns at that line as the layout stands.
    The idler keeps the model's speed and the leader is found."""
    fs, n = 100.0, 6000
    t = np.arange(n) / fs
    f_lead, f_idl = 1.1289, 4.553
    th_lead = 2 * np.pi * f_lead * t
    y = 0.8 * np.sin(th_lead + 0.2) + 3.0 * np.sin(4 * th_lead + 0.3) + np.random.default_rng(1).normal(0, 0.2, n)
    d = _fake_diagnosis({"lc9.T": y}, fs, t, models={"lc9.T": np.zeros(n)})
    d.opt.harmonics = 4
    lead = Candidate("eccentricity", "sw_leader", "sw_leader", "DrivenRoller", 0.154, "sw_leader.theta")
    idler = Candidate("eccentricity", "roller9", "roller9", "IdleRoller", 0.0381, "roller9.theta")
    d.cands = [lead, idler]
    c = d.ctx[0]
    c.theta = {lead.key: th_lead, idler.key: 2 * np.pi * f_idl * t}
    c.theta_src = {lead.key: "model", idler.key: "model"}
    c.freq = {lead.key: f_lead, idler.key: f_idl}
    kap = d._refine_kappa_joint([c], idler)
    assert kap == pytest.approx(4 * f_lead / f_idl - 1.0, abs=1e-3)   # alone, the scale finds the line ...
    assert d._kappa_lands_on([c], idler, kap) == "sw_leader order 4"
    assert d._kappa_lands_on([c], idler, 0.01) is None                 # ... a scale onto no other line is free
    d.opt.max_effects = 1
    d.which()                                                          # ... which() keeps the model's speed
    assert c.kappa[idler.key] == 0.0
    assert d.effects[0]["best"]["cand"] is lead


def test_a_check_passes_pooled_runs_but_not_a_run_made_worse():
    """Independent seed-2 c07: pooled over two fit runs lc9 improved (1.039 -> 1.035),
    run by run it went 1.055 -> 1.090 and 1.007 -> 0.916. The run-by-run rule refuses
    what the pooled rule lets through; with one run it adds nothing."""
    n = 1000
    t = np.arange(n) / 100.0
    rng = np.random.default_rng(2)
    ys = {"a": np.sin(2 * np.pi * 0.5 * t) + rng.normal(0, 0.1, n), "b": 3 * np.sin(2 * np.pi * 0.7 * t)}
    ctxs = [SimpleNamespace(name=k, sensors=["lc9.T"], meas={"lc9.T": y}) for k, y in ys.items()]
    before = {k: Sim(None, {"lc9.T": np.zeros(n)}) for k in ys}
    # run a: a wrong prediction (worse); run b: most of the signal explained (much better)
    after = {"a": Sim(None, {"lc9.T": 0.4 * np.cos(2 * np.pi * 0.5 * t)}),
             "b": Sim(None, {"lc9.T": 2.0 * np.sin(2 * np.pi * 0.7 * t)})}
    pooled_b = claims.nrmse_over(ctxs, before, "lc9.T")
    pooled_a = claims.nrmse_over(ctxs, after, "lc9.T")
    assert pooled_a < pooled_b                                            # the pooled rule passes it
    w = claims.worse_by_run(ctxs, before, after, 0.02)
    assert [x[:2] for x in w] == [("a", "lc9.T")]
    # by hand: NRMSE^2 of run a goes from 1 to 1 + 0.08 / (0.5 + 0.01) (the cosine is orthogonal)
    assert w[0][3] / w[0][2] == pytest.approx(math.sqrt(1 + 0.08 / 0.51), rel=0.02)
    ok, why = claims.run_by_run(ctxs, before, after, 0.02, "fine")
    assert not ok and "run a" in why and "lc9.T" in why
    assert claims.run_by_run(ctxs[1:], before, after, 0.02, "fine") == (True, "fine")

# ------------------------------------------------------ check in refine ----
def test_refine_drops_an_effect_that_makes_a_sensor_worse(tmp_path):
    """Two effects at one element's frequency: the first explains lc9, the second
    also puts a line on lc15 that the data does not have (its NRMSE rises far
    beyond 2 %). The refine stage keeps the first, takes the second out of the
    layout and lists it in ``rejected`` with the NRMSE numbers."""
    fs, n = 100.0, 3000
    rng = np.random.default_rng(2)
    t = np.arange(n) / fs
    th = 2 * np.pi * 1.3 * t
    th2 = 2 * np.pi * 3.1 * t
    meas = {"lc9.T": 4.0 * np.sin(th) + rng.normal(0, 0.3, n), "lc15.T": 1.0 + rng.normal(0, 0.3, n)}
    d = _fake_diagnosis(meas, fs, t, models={s: np.zeros(n) for s in meas})
    good = Candidate("eccentricity", "idler_u1", "idler_u1", "IdleRoller", 0.0381, "idler_u1.theta")
    bad = Candidate("eccentricity", "idler_p1", "idler_p1", "IdleRoller", 0.0381, "idler_p1.theta")
    c = d.ctx[0]
    c.theta = {good.key: th, bad.key: th2}
    c.theta_src = {good.key: "model", bad.key: "model"}
    c.freq = {good.key: 1.3, bad.key: 3.1}
    c.kappa = {good.key: 0.0, bad.key: 0.0}
    c.fc = 0.3

    def simulate(doc):
        s = doc.get("set", {})
        y9, y15 = np.zeros(n), np.zeros(n)
        if "path.idler_u1.eccentricity.C" in s:
            y9 = y9 + 4.0 * np.sin(th)
        if "path.idler_p1.eccentricity.C" in s:
            y9 = y9 + 0.5 * np.sin(th2)               # a small line on lc9 (its "own" residual) ...
            y15 = y15 + 1.5 * np.sin(th2)             # ... and a large one on lc15
        return Sim(None, {"lc9.T": y9, "lc15.T": y15})

    d.model = SimpleNamespace(copy_doc=lambda: layout_edit.base_doc(EWL),
                              simulate_many=lambda jobs: [simulate(doc) for _, doc, _ in jobs])
    d.final_effects = [{"ranked": [{"cand": good, "X": np.array([1e-4, 0, 0], complex)}]},
                       {"ranked": [{"cand": bad, "X": np.array([2e-5, 0, 0], complex)}]}]
    d.opt.polish = False
    d.opt.structure = False
    d.opt.ripple = False     # nor the shaft screen that reads the residual's spectrum
    d.opt.other_effects = False   # nor the backlash screen of the refined model's drives
    # the "bad" effect's own harmonics on lc9 are 0.5 N that the data lacks: make them
    # present so the local criterion passes and only the NRMSE rule can drop it
    d.ctx[0].meas["lc9.T"] = d.ctx[0].meas["lc9.T"] + 0.5 * np.sin(th2)
    d.refine()
    assert [fe["ranked"][0]["cand"].element for fe in d.final_effects] == ["idler_u1"]
    assert [st["added"] for st in d.steps] == [None, "idler_u1"]
    rej = [r for r in d.rejected if r["stage"] == "refine check"]
    assert len(rej) == 1 and rej[0]["element"] == "idler_p1"
    assert "lc15.T" in rej[0]["reason"]
    assert rej[0]["nrmse_after"]["lc15.T"] > 1.02 * rej[0]["nrmse_before"]["lc15.T"]
    assert rej[0]["nrmse_after"]["lc9.T"] < rej[0]["nrmse_before"]["lc9.T"]   # it did help lc9
    assert "path.idler_p1.eccentricity.C" not in d.refined_doc["set"]


# ------------------------------------------------------------- helpers ----
def _fake_diagnosis(meas, fs, t, models):
    d = Diagnosis(EWL, [], options=Options(harmonics=3, kappa_span=0.02))
    run = SimpleNamespace(name="r", t=t, duration=float(t[-1] - t[0]), columns={}, overrides={})
    c = RunCtx(run, True)
    c.fs = fs
    c.sensors = list(meas)
    c.meas = dict(meas)
    c.nominal = Sim(None, dict(models))
    c.mask = t >= t[0] + 1.0
    c.steady = np.ones_like(t, bool)
    c.speed = np.ones_like(t)
    c.fc = 0.3
    for s in c.sensors:
        c.resid[s] = c.meas[s] - models[s]
        c.periodic[s] = est.split_slow_periodic(c.resid[s], fs, c.fc)[1]
        c.floors[s] = est.NoiseFloor(c.periodic[s][c.mask], fs, median_hz=4.0)
    d.ctx = [c]
    d.cands = []
    return d


# ------------------------------------------------------- model form, end to end ----
def test_form_feedforward_none_found_and_run_out_recovered(tmp_path, monkeypatch):
    """Issue 9 (b), short: the line's speed loops feed forward no tension torque
    (the layout's feed forward the measured tension) and the unwind is out of
    round. In the layout's form the run-out estimate is far off and the pull and
    rewind load cells keep the unwind's orders; the model-form screen must find
    'feedforward none', recover the dominant order within 20 %, and leave no
    sensor worse than the nominal model.

    Model and 'line' are simulated by the monolithic reference solver (the
    co-simulation's own accuracy is tested against it elsewhere): this test is
    about the diagnosis, and keeps to a 20 s record at 250 Hz."""
    import yaml
    import webline.orchestrator.master as master
    from webline.orchestrator.reference import simulate_reference
    from webline.diagnosis.pipeline import diagnose

    C = [0.30e-3, 0.65e-3, 0.12e-3]
    psi = [0.4, -1.0, 2.0]
    loops = ("unwind", "sw_leader", "sw_follower", "pull_roll", "rewind")
    tset = {f"drives.speed_loops.{e}.feedforward": False for e in loops}
    tset["path.unwind.eccentricity"] = {"C": [f"{c * 1e3} mm" for c in C], "psi": [f"{p} rad" for p in psi]}
    (tmp_path / "truth.yaml").write_text(yaml.safe_dump({"base": str(EWL), "set": tset}))
    for name, speed, dur, seed in (("r1", "200 ft/min", "20 s", 11), ("h1", "170 ft/min", "12 s", 12)):
        measured_run(tmp_path, name, tmp_path / "truth.yaml", {"duration": dur, "line_speed": speed}, seed=seed,
                     simulate=simulate_reference)

    monkeypatch.setattr(master, "simulate", lambda system, fmu_paths=None, progress=False, **kw:
                        simulate_reference(system))
    rep = diagnose(EWL, [tmp_path / "r1.yaml"], holdout=[tmp_path / "h1.yaml"], out=tmp_path / "out",
                   options=Options(fmu_paths={}, jobs=1, max_structures=2, harmonics=3))
    eff = rep["effects"][0]
    assert (eff["element"], eff["kind"]) == ("unwind", "out_of_round")
    st = rep["structure"]
    assert st["triggers"] and st["chosen"] == "feedforward none"
    assert eff["model_form"] == "feedforward none"
    amp2 = next(h["amplitude"] for h in eff["harmonics"] if h["order"] == 2)
    unc = eff["amplitude_uncertainty"]
    assert abs(amp2 - C[1]) < 0.2 * C[1] or not unc["identifiable"]
    assert_no_sensor_worse(rep["gap"])
    for g in rep["gap"].values():
        assert 0.0 < g["achievable"] < 1.0 and g["closed_share"] is not None
    # held out (another speed, never fitted): the form and estimate carry over
    assert_no_sensor_worse(rep["holdout"]["out_of_sample"])
    g9 = rep["holdout"]["out_of_sample"]["lc9.T"]
    assert g9["closed_share"] > 0.5
    # ... and so does the dominant order's line: the held-out run keeps little of it
    from webline.diagnosis.report import HELD_OUT_LEFT
    h = rep["left"]["lc9.T"]["effects"][0]["held_out"]
    assert h["runs"] == ["h1"]
    assert next(o for o in h["by_order"] if o["order"] == 2)["share_left"] < HELD_OUT_LEFT
    # the noise floor comes from the data: 0.3 N was added
    for s, v in rep["noise_floor"]["r1"].items():
        assert v["rms_N"] == pytest.approx(0.3, rel=0.1), s
    assert "Model form: feedforward none" in rep["verdict"]
    assert (tmp_path / "out" / "report.html").exists()
    refined = yaml.safe_load((tmp_path / "out" / "refined_layout.yaml").read_text())
    assert refined["set"]["drives.speed_loops.unwind.feedforward"] is False


def test_runs_agree_in_the_chosen_form(tmp_path):
    """Two fit runs at 100 and 200 ft/min of issue 9 (b)'s line (no feed-forward
    in the speed loops, an out-of-round unwind). In the layout's form the model's
    response at the two speeds differs from the line's, so the run-by-run
    estimates disagree; once the screen has chosen 'feedforward none' the
    run-by-run estimates are made in that form (the model the refined layout
    runs) and must agree with each other and with the truth: the amplitude is
    not flagged for a disagreement of the form that was replaced."""
    import yaml
    from webline.diagnosis.pipeline import diagnose

    C = [0.30e-3, 0.65e-3]
    loops = ("unwind", "sw_leader", "sw_follower", "pull_roll", "rewind")
    tset = {f"drives.speed_loops.{e}.feedforward": False for e in loops}
    tset["path.unwind.eccentricity"] = {"C": [f"{c * 1e3} mm" for c in C], "psi": ["0.4 rad", "-1.0 rad"]}
    (tmp_path / "truth.yaml").write_text(yaml.safe_dump({"base": str(EWL), "set": tset}))
    runs = [measured_run(tmp_path, name, tmp_path / "truth.yaml", {"duration": "24 s", "line_speed": speed},
                         seed=seed)
            for name, speed, seed in (("r100", "100 ft/min", 21), ("r200", "200 ft/min", 22))]
    rep = diagnose(EWL, runs, out=tmp_path / "out",
                   options=Options(fmu_paths={}, jobs=1, max_structures=2, harmonics=2, confirm=False))
    eff = rep["effects"][0]
    assert (eff["element"], eff["kind"]) == ("unwind", "out_of_round")
    assert rep["structure"]["chosen"] == "feedforward none"
    unc = eff["amplitude_uncertainty"]
    assert unc["by_run_form"] == "feedforward none"
    # 24 s at 0.3 N noise: the order's standard error is a few um; the runs agree to 20 %
    for run, x in unc["by_run"].items():
        assert x == pytest.approx(C[1], rel=0.2), (run, unc["by_run"])
    assert unc["identifiable"] and unc.get("within_precision", True)


def test_orders_left_out_below_the_noise_are_reported_not_identifiable():
    """An order the first estimate left out as below the noise is listed with that
    estimate, sigma = C / sqrt(z), not identifiable when z < 9 (sigma > C / 3), never
    in the refined layout; an order a later fit put back is listed once, from the model."""
    from webline.diagnosis.report import _harmonics
    X = np.array([0.0, 0.0, 5e-5, 0.0, 6e-5, 0.0], complex)
    b = {"X": X, "below_noise": {1: (2e-5 * np.exp(0.3j), 4.0), 2: (1e-5, 16.0), 3: (4e-5, 3.0)}}
    h = {x["order"]: x for x in _harmonics(b, X)}
    assert sorted(h) == [1, 2, 3, 5]
    assert h[1]["below_noise"] and not h[1]["in_refined_layout"] and not h[1]["identifiable"]
    assert h[1]["amplitude"] == pytest.approx(2e-5) and h[1]["phase"] == pytest.approx(0.3)
    assert h[1]["sigma"] == pytest.approx(2e-5 / math.sqrt(4.0))
    assert h[2]["identifiable"]                 # z 16: sigma = C / 4
    assert "below_noise" not in h[3] and h[3]["amplitude"] == pytest.approx(5e-5)   # back in the model


def test_an_order_the_data_show_but_the_fit_left_out_is_listed_not_identifiable():
    """Independent seed-2 c08: the unwind's dominant order 1 was clearly on its angle in
    the family screen and the time-domain fit left it at zero; the report listed orders
    2-6 only. Such an order is listed with the per-order gain estimate (M = G X), not
    identifiable, not in the refined layout; a weak order left at zero is not."""
    from webline.diagnosis.report import _harmonics
    G = np.array([[1.0 + 0.2j, 0.5, 0.3j], [0.4, 0.2 - 0.1j, 0.1]])
    Xt = np.array([5e-5 * np.exp(1.1j), 1e-6, 4e-5])
    X = np.array([0.0, 0.0, 4e-5], complex)
    b = {"X": X, "G": G, "M": G * Xt[None, :], "W": np.ones(2),
         "score": {"fits": {"run1": {}, "run2": {}}, "z_order": {1: 22.0, 2: 12.0, 3: 900.0}}}
    h = {x["order"]: x for x in _harmonics(b, X)}
    assert sorted(h) == [1, 3]                   # order 2: z 12 over 2 runs, below the first estimate's rule
    assert h[1]["left_out"] and h[1]["identifiable"] is False and h[1]["in_refined_layout"] is False
    assert h[1]["amplitude"] == pytest.approx(5e-5, rel=1e-9) and h[1]["phase"] == pytest.approx(1.1)
    assert "left_out" not in h[3]


def test_an_order_the_first_estimate_kept_for_its_energy_is_listed_when_the_fit_left_it_out():
    """Independent seed-37 c08: the unwind's dominant order 1 (0.064 mm) had z 12 over two
    fit runs, below the z rule, and was kept by the first estimate for its share of the
    line's measured energy; the time-domain fit left it at zero and the report listed
    orders 3-6 only. What the first estimate kept is listed when the fit leaves it out,
    whatever its z; a weak order it did not keep is not."""
    from webline.diagnosis.report import _harmonics
    G = np.array([[1.0 + 0.2j, 0.5, 0.3j], [0.4, 0.2 - 0.1j, 0.1]])
    Xt = np.array([5e-5 * np.exp(1.1j), 1e-6, 4e-5])
    X = np.array([0.0, 0.0, 4e-5], complex)
    b = {"X": X, "G": G, "M": G * Xt[None, :], "W": np.ones(2), "kept": [1, 3],
         "score": {"fits": {"run1": {}, "run2": {}}, "z_order": {1: 12.0, 2: 12.0, 3: 900.0}}}
    h = {x["order"]: x for x in _harmonics(b, X)}
    assert sorted(h) == [1, 3]
    assert h[1]["left_out"] and h[1]["identifiable"] is False and h[1]["in_refined_layout"] is False
    assert h[1]["amplitude"] == pytest.approx(5e-5, rel=1e-9)
    assert "z = 12 over 2 fit run(s)" in h[1]["why"]


def test_the_structure_screen_asks_every_form_for_the_orders_the_layouts_form_left_out():
    """Independent seed-48 c14: an out-of-round unwind (order 1 117 um, order 5 68 um) in a
    line without tension feed-forward; the fit in the layout's measured-tension form left
    order 1 (z 25 over two fit runs) at zero, and the report gave it as 9 um, left out.
    structure.readmit_orders puts the orders the report would list as left out back at
    their per-order gain estimate, so that each rigid form re-estimates them from its own
    response; an effect with none left out, and a rejected one, stay as they are."""
    from types import SimpleNamespace

    from webline.diagnosis import structure
    from webline.diagnosis.report import _harmonics

    G = np.array([[1.0 + 0.2j, 0.5, 0.3j], [0.4, 0.2 - 0.1j, 0.1]])
    Xt = np.array([5e-5 * np.exp(1.1j), 1e-6, 4e-5])
    X = np.array([0.0, 0.0, 4e-5], complex)
    b = {"X": X, "G": G, "M": G * Xt[None, :], "W": np.ones(2), "cand": SimpleNamespace(element="unwind"),
         "score": {"fits": {"run1": {}, "run2": {}}, "z_order": {1: 22.0, 2: 12.0, 3: 900.0}}}
    whole = np.array([1e-5, 0.0, 2e-5], complex)
    b2 = dict(b, X=whole, cand=SimpleNamespace(element="idler_u1"))
    effs = [(b["cand"], X, {"ranked": [b]}), (b2["cand"], whole, {"ranked": [b2]}),
            (SimpleNamespace(element="roller9"), X.copy(), None)]
    shown, effs_r = structure.readmit_orders(effs)
    assert shown == {"unwind": [1]}              # order 2: z 12 over 2 runs is not shown
    X_r = effs_r[0][1]
    assert X_r[0] == pytest.approx(Xt[0], rel=1e-9) and X_r[1] == 0 and X_r[2] == X[2]
    assert X[0] == 0                             # the layout's estimate is not touched
    assert effs_r[1][1] is whole and effs_r[2][1] is effs[2][1]
    # the order taken back is the one the report would list as left out, at the same value
    h = {x["order"]: x for x in _harmonics(b, X)}
    assert h[1]["left_out"] and h[1]["amplitude"] == pytest.approx(abs(X_r[0]))


def test_a_screened_set_is_named_by_its_form_orders_taken_back_swap_and_sources_left_out():
    """The set labels the report's structure table shows. A line within the data sheet's
    tolerances is tried with the orders taken back *and* without the secondary sources
    (independent seed-47 c17: 'feedforward reference + line 11 within the data sheet +
    sw_leader order 1, without roller9' was chosen), so both parts must be in its name."""
    from webline.diagnosis import structure

    assert structure.set_label("feedforward none", "no ff") == ("feedforward none", "no ff")
    name, desc = structure.set_label("line 11", "a line", {"roller19": [4, 6], "sw_leader": [1]}, ["roller9"])
    assert name == "line 11 + roller19 orders 4, 6; sw_leader order 1, without roller9"
    assert desc == "a line; with the orders the data show back in (roller19 orders 4, 6; sw_leader order 1), without roller9"
    name, _ = structure.set_label("feedforward reference", "", None, ["roller9"], ("roller19", "idler_r1"))
    assert name == "feedforward reference, idler_r1 in the place of roller19, without roller9"
    # a swap onto the only secondary source leaves none out
    assert structure.set_label("f", "", None, [], ("roller19", "roller9"))[0] == "f, roller9 in the place of roller19"


def test_a_form_that_gives_up_anything_must_gain_one_percent():
    """Seed-4 c08 of the independent family: "feedforward reference" against the
    layout's own form lowered lc19 from 1.0046 to 0.9989 and raised lc9 from 1.0098
    to 1.0112: the sum of NRMSE^2 0.42 % lower (the truth's form, none, fitted
    about as well). A trade that small is not the data's choice; a form that raises
    nothing, or one that gains 1 %, is not refused by this rule."""
    from webline.diagnosis import structure

    cur = {"lc9.T": 1.0098, "lc19.T": 1.0046}
    new = {"lc9.T": 1.0112, "lc19.T": 0.9989}

    def score(nr):
        return sum(v ** 2 for v in nr.values())
    why = structure._small_trade(cur, score(cur), new, score(new))
    assert why is not None and "lc9.T 1.01 -> 1.011" in why
    # no sensor raised: not this rule's business
    down = {"lc9.T": 1.0098, "lc19.T": 0.9989}
    assert structure._small_trade(cur, score(cur), down, score(down)) is None
    # a trade that lowers the sum by more than 1 %
    big = {"lc9.T": 1.0112, "lc19.T": 0.98}
    assert (score(cur) - score(big)) / score(cur) > 0.01
    assert structure._small_trade(cur, score(cur), big, score(big)) is None


def test_a_shaft_form_must_fit_ten_percent_better_than_the_rigid_forms_with_its_sources():
    """Shaft forms (structure.shaft_forms) compete with the rigid forms that hold the
    same sources, simulated or only predicted. Seed-4 c05: with one idler and the
    S-wrap leader, the shaft at 3.8 Hz scored 0.349 where the best rigid form with
    the same sources was predicted at 0.5485: kept. Seed-4 c01: the best shaft
    2.262 against "feedforward none" 2.222: refused (and not chosen anyway)."""
    from webline.diagnosis import structure

    shafts = {"shaft on sw_leader at 3.8 Hz": ("sw_leader", 3.8)}
    grp = [{"form": "feedforward reference", "predicted_score": 0.5485},
           {"form": "as modelled", "score": 1.1125},
           {"form": "shaft on sw_leader at 3.8 Hz", "score": 0.349}]
    assert structure._shaft_clears(grp, shafts) == grp
    grp2 = [{"form": "feedforward none", "score": 2.222},
            {"form": "shaft on sw_leader at 3.8 Hz", "score": 2.10}]    # 5.5 % better: not enough
    assert structure._shaft_clears(grp2, shafts) == grp2[:1]
    # no rigid form in the group: a shaft stands alone
    assert structure._shaft_clears(grp[2:], shafts) == grp[2:]


def test_a_shaft_form_with_another_member_of_a_tie_competes_with_every_members_rigid_sets():
    """Independent seed-10 c17 (eccentric idler_u1 and guide_in, no shaft): without the
    phantom roller19, a leader shaft with roller9 (idler_u1's tie) in idler_u1's place
    scored 0.526, 11 % under that swap's best rigid set (0.592) but only 8 % under
    idler_u1's own (0.572). A swap names another member of the same family: the sets
    hold as many sources, and the shaft does not clear. The full sets (with roller19)
    are a group of their own."""
    from webline.diagnosis import structure

    shaft = "shaft on sw_leader at 6.21 Hz"
    shafts = {shaft: ("sw_leader", "compliance", 6.21)}
    w = ["roller19"]
    swap = {"replaced": "idler_u1", "by": "roller9"}
    entries = [{"form": "feedforward reference + web damping 2 ms", "score": 0.491},
               {"form": shaft, "score": 0.60},
               {"form": "feedforward reference + web damping 2 ms", "score": 0.572, "without": w},
               {"form": "feedforward reference + web damping 2 ms", "score": 0.592, "without": w, "swap": swap},
               {"form": shaft, "score": 0.526, "without": w, "swap": swap}]
    assert structure._shaft_clears(entries[3:], shafts) == entries[3:]          # the swap's group alone
    kept = structure.drive_forms_cleared(entries, shafts)
    assert entries[4] not in kept and entries[1] not in kept
    assert [e for e in entries if e["form"] != shaft] == kept
    # 10 % under every rigid set with as many sources: kept
    entries[4]["score"] = 0.50
    assert entries[4] in structure.drive_forms_cleared(entries, shafts)


def test_the_html_report_shows_the_checks_refusals_before_the_forms_only_predicted():
    """report.rejected_for_reading: independent seed-34 c04's 150 rejected rows began with
    102 model forms only predicted; the HTML table (40 rows) never reached the periodic
    screen. The checks' refusals come first, then the screens' in their order, the
    predicted-only forms are counted, not listed, and what the limit cuts is counted."""
    from webline.diagnosis.report import rejected_for_reading

    def row(stage, element, reason="x"):
        return {"element": element, "kind": "k", "stage": stage, "reason": reason}

    rej = ([{**row("structure screen", f"form {i}", "predicted sum of NRMSE^2 1.2, not simulated: ..."),
             "predicted_nrmse": {"lc9.T": 1.1}} for i in range(50)]
           + [row("structure screen", "feedforward none", "sum of NRMSE^2 0.6 vs 0.5 (chosen)"),
              row("other-effects screen", "EA"), row("periodic screen step 2", "roller9"),
              row("periodic screen step 1", "sw_leader"), row("backlash screen", "sw_leader"),
              row("refine check", "idler_u1"), row("a stage of its own", "z")])
    rows, unsimulated, more = rejected_for_reading(rej)
    assert unsimulated == 50 and more == 0
    assert [r["element"] for r in rows] == ["idler_u1", "sw_leader", "roller9", "sw_leader", "EA", "z",
                                            "feedforward none"]
    assert [r["stage"] for r in rows][1:4] == ["backlash screen", "periodic screen step 2",
                                               "periodic screen step 1"]
    rows, unsimulated, more = rejected_for_reading(rej, limit=3)
    assert len(rows) == 3 and more == 4 and rows[0]["stage"] == "refine check"


def test_a_held_out_sensor_fit_worse_is_named_in_the_verdict():
    """report.held_out_worse: a held-out sensor whose refined NRMSE is above the nominal
    one is named with both values (independent seed-34 c02's lc19); one fit better or
    equal, or a report without held-out runs, gives nothing."""
    from webline.diagnosis.report import held_out_worse

    def g(a, b):
        return {"nominal": {"nrmse": a}, "refined": {"nrmse": b}}

    rep = {"holdout": {"holdout_runs": ["run3"],
                       "out_of_sample": {"lc9.T": g(1.1723, 1.1711), "lc19.T": g(1.0114, 1.0128)}}}
    got = held_out_worse(rep)
    assert len(got) == 1 and got[0].startswith("Held out (run3)"), got
    assert "lc19.T" in got[0] and "1.011 -> 1.013" in got[0] and "+0.14 %" in got[0] and "lc9.T" not in got[0], got
    rep["holdout"]["out_of_sample"]["lc19.T"] = g(1.0114, 1.0114)
    assert held_out_worse(rep) == []
    assert held_out_worse({"holdout": {"fit_runs": ["run1"], "in_sample": {}, "out_of_sample": None}}) == []
    assert held_out_worse({}) == []


def test_a_drive_form_competes_with_the_rigid_forms_in_its_own_parameters():
    """Independent seed-8 c24 (eccentric idler_r1, 2.8 deg dead zone on the leader): without
    the phantom roller19, the dead-zone form with idler_r1 in idler_u1's place scored 0.699,
    21 % under the best rigid set in the layout's parameters (0.890). A line drawn within
    the data sheet's tolerances (the best of twelve draws, structure._tolerance_lines) scored
    0.649: it is a search the dead-zone form never had, so it does not unseat it."""
    from webline.diagnosis import structure

    dz = "feedforward reference + dead zone on sw_leader"
    forms = {dz: ("sw_leader", "backlash", 1.0)}
    w, swap = ["roller19"], {"replaced": "idler_u1", "by": "idler_r1"}
    entries = [{"form": "feedforward reference + web damping 2 ms", "score": 0.890, "without": w, "swap": swap},
               {"form": dz, "score": 0.699, "without": w, "swap": swap},
               {"form": "feedforward none + load-cell filter order 2 + line 9 within the data sheet",
                "score": 0.649, "without": w, "swap": swap, "tolerance_line": {"draw": 9, "of": 12, "set": {}}}]
    assert structure.drive_forms_cleared(entries, forms) == entries
    # what the report says of it is measured against the same rigid set: it explains 21 %
    # of that set's sum, not -8 % against the line
    chosen = {**entries[1], "name": f"{dz}, idler_r1 in the place of idler_u1, without roller19",
              "check": {"accepted": True}}
    eff = structure._drive_effect(chosen, forms, entries, 0.584)
    assert eff["element"] == "sw_leader" and eff["kind"] == "backlash"
    assert eff["explained_share"] == pytest.approx(1.0 - 0.699 / 0.890) and \
        eff["confidence"] == pytest.approx(1.0 - 0.699 / 0.890), eff
    # the same score as a form in the layout's parameters would unseat it
    entries[2].pop("tolerance_line")
    assert entries[1] not in structure.drive_forms_cleared(entries, forms)


def test_a_drive_form_standing_in_for_a_source_that_fits_better_is_named_as_the_alternative():
    """structure.stands_in, on independent seed-36 c17's measured sums of NRMSE^2 (idler_u1
    and roller19 eccentric at 3.61 Hz, one fit run): the leader shaft at 5.41 Hz without
    idler_r1 (roller19's tie) scored 0.5416, the full set in the rigid 'feedforward none + web
    damping 2 ms' 0.5293. The report keeps the shaft (the swap rule allows it) but names the
    second source as the other account, and the run that would tell them apart; a full set in
    a drive form of its own, or a drive form that fits better, is no such pair."""
    from webline.diagnosis import structure
    from webline.diagnosis.report import _verdict

    sh = "feedforward none + web damping 2 ms + shaft on sw_leader at 5.41 Hz"
    forms = {sh: ("sw_leader", "compliance", 5.41)}
    full = {"name": "feedforward none + web damping 2 ms", "form": "feedforward none + web damping 2 ms",
            "score": 0.5293}
    r = {"name": f"{sh}, without idler_r1", "form": sh, "score": 0.5416, "without": ["idler_r1"]}
    why = structure.stands_in(r, full, forms, [3.607, 3.6075])
    assert why and "idler_r1" in why and "0.5293 against 0.5416" in why and "shaft in sw_leader's drive" in why
    assert "one frequency" in why and "3.61 Hz" in why and "another line speed" in why, why
    # a ramped fit run: its steady windows at two speeds
    two = structure.stands_in(r, full, forms, [2.74, 3.607])
    assert "one frequency" not in two and "2.74, 3.61 Hz" in two and "more line speeds" in two, two
    assert structure.stands_in({**r, "score": 0.5200}, full, forms) is None          # the drive form fits better
    assert structure.stands_in(r, {**full, "form": sh}, forms) is None               # the full set holds the shaft
    assert structure.stands_in({**r, "without": []}, full, forms) is None            # no source dropped
    assert structure.stands_in({**r, "form": "feedforward none"}, full, forms) is None   # a rigid form within 10 %
    # seed-37 c17: the rigid one-source form 1.56 x the full set's sum (the real idler_u1 dropped)
    rig = structure.stands_in({**r, "form": "feedforward none", "score": 1.56 * 0.5293}, full, forms, [3.469])
    assert rig and "56 % more without it" in rig and "form 'feedforward none'" in rig and "another line speed" in rig, rig
    dz = {"feedforward none + dead zone on sw_leader": ("sw_leader", "backlash", 1.0)}
    got = structure.stands_in({**r, "form": "feedforward none + dead zone on sw_leader"}, full, dz)
    assert "dead zone in sw_leader's drive" in got and "torque's swing" in got, got
    # the verdict: "Or a second source" with the reason, not "Not a second source"
    row = {"element": "idler_r1", "kind": "eccentricity", "stage": "parsimony (structure screen)",
           "reason": f"explained by {sh} transmitting idler_u1's line: ...", "or_instead": why}
    rep = {"effects": [], "gap": {}, "rejected": [row], "structure": {"chosen": sh}}
    v = _verdict(rep)
    assert "Or a second source: eccentricity of idler_r1 (the set with idler_r1" in v and "Not a second" not in v, v
    row.pop("or_instead")
    assert "Not a second source: eccentricity of idler_r1 (explained by" in _verdict(rep)


def _weak_roll_beside_strong_idler(rescale=True):
    fs, n = 100.0, 6000
    t = np.arange(n) / fs
    f_i = 3.59
    f_u = 0.86 + 0.05 * t / t[-1]                       # the roll's model speed rises as it unwinds
    th_u = 2 * np.pi * np.cumsum(f_u) / fs
    ref = 0.5 * (th_u[100] + th_u[-1])
    th_true = (1 + 0.0195) * (th_u - ref) + ref         # its start radius 1.9 % smaller than written
    y = 3.0 * np.sin(2 * np.pi * f_i * t + 0.4) + 0.15 * np.sin(2 * th_true + 1.6) \
        + np.random.default_rng(4).normal(0, 0.3, n)
    d = _fake_diagnosis({"lc9.T": y}, fs, t, models={"lc9.T": np.zeros(n)})
    d.opt.harmonics, d.opt.max_effects = 6, 2
    idler = Candidate("eccentricity", "idler_u1", "idler_u1", "IdleRoller", 0.0381, "idler_u1.theta")
    unw = Candidate("out_of_round", "unwind", "unwind", "UnwindRoll", 0.162, "unwind.theta")
    d.cands = [idler, unw]
    c = d.ctx[0]
    c.theta = {idler.key: 2 * np.pi * f_i * t, unw.key: th_u}
    c.theta_src = {idler.key: "model", unw.key: "model"}
    c.freq = {idler.key: f_i, unw.key: float(np.mean(f_u))}
    if not rescale:
        d._rescale_rolls = lambda *a: None
    d.which()
    return d, c, unw


def test_a_weak_roll_beside_a_strong_idler_is_screened_on_what_the_idler_left():
    """Independent seed-13 c12: an out-of-round unwind (order 2, 0.16 mm) beside an
    eccentric idler_u1 (0.81 mm). The roll's order 4 sweeps across the idler's line
    as its radius shrinks, so its start-radius scale fitted to the raw residual
    missed, the order-2 line drifted in phase (coherence about 0.4) and, at 0.25 %
    of the whole periodic residual, it was under the 1 % share. With the idler's
    family taken out, the scale is found again on what is left (within a tenth
    of the 1.95 %), the family is coherent, and it holds over 1 % of what the
    idler left."""
    d, c, unw = _weak_roll_beside_strong_idler(rescale=False)
    assert [e["best"]["cand"].element for e in d.effects] == ["idler_u1"]
    second = {x["element"]: x for x in d.screen_log[1]}["unwind"]
    assert second["coherence"] < 0.75 and second["share"] < 0.01
    d, c, unw = _weak_roll_beside_strong_idler()
    assert [e["best"]["cand"].element for e in d.effects] == ["idler_u1", "unwind"]
    assert c.kappa[unw.key] == pytest.approx(0.0195, abs=0.002)
    second = {x["element"]: x for x in d.screen_log[1]}["unwind"]
    assert second["coherence"] > 0.9 and second["share"] < 0.01 <= second["share_left"]


def test_held_out_lines_left_are_named():
    """report.held_out_left: a reported effect's order the refined model leaves on a
    held-out run (significant, at least HELD_OUT_LEFT of its line) is named, largest
    first; one below the share or within noise is not (constructed records in the
    report's ``left`` shape)."""
    from webline.diagnosis.report import HELD_OUT_LEFT, held_out_left

    def eff(el, orders):
        return {"element": el, "kind": "eccentricity", "held_out": {"runs": ["run2"], "by_order": [
            {"order": j, "share_left": sh, "significant": sig} for j, sh, sig in orders]}}
    rep = {"left": {
        "lc9.T": {"effects": [eff("roller9", [(1, 0.02, True), (2, 0.9, True), (3, 0.8, False)])]},
        "lc19.T": {"effects": [eff("roller9", [(1, HELD_OUT_LEFT, True)]),
                               {"element": "x", "kind": "eccentricity", "held_out": None}]}}}
    got = held_out_left(rep)
    assert len(got) == 2
    assert "order(s) 2," in got[0] and "90 %" in got[0] and "lc9.T" in got[0] and "run2" in got[0]
    assert "order(s) 1," in got[1] and "lc19.T" in got[1]
    # more than the nominal model left there: said as a multiple
    more = held_out_left({"left": {"lc9.T": {"effects": [eff("roller9", [(4, 12.0, True)])]}}})
    assert len(more) == 1 and "12 x the line the nominal model left" in more[0]
    below = {"left": {"lc9.T": {"effects": [eff("roller9", [(2, 0.99 * HELD_OUT_LEFT, True)])]}}}
    assert held_out_left(below) == [] and held_out_left({}) == []


def test_a_held_out_line_the_found_source_barely_reaches_names_a_second_source_at_its_frequency():
    """Independent seed-53 c05: roller9 and roller19 both eccentric at 4.22 Hz, one fit
    run. roller19 (tied with idler_r1) was found; lc9's order 1 was left whole in the fit
    run at z 8.0 (p 3e-4, short of the 1e-5 a second source needs) and whole in the
    held-out run. The held-out sentence names the other reading: another candidate at
    that frequency outside the tie. Not when the fit run's line there was noise (z 2) or
    the found source took most of it (50 % left)."""
    from webline.diagnosis.report import held_out_left

    def rep(z, share):
        left = {"element": "idler_r1", "kind": "eccentricity", "runs": ["run1"],
                "by_order": [{"order": 1, "share_left": share, "z_left": z, "significant": False}],
                "held_out": {"runs": ["run2"], "by_order": [{"order": 1, "share_left": 1.0, "significant": True}]}}
        return {"left": {"lc9.T": {"effects": [left]}},
                "effects": [{"element": "idler_r1", "kind": "eccentricity", "tie": ["idler_r1", "roller19"],
                             "candidates": [{"element": x} for x in ("idler_r1", "roller19", "roller9", "idler_u1")]}]}
    got = held_out_left(rep(8.0, 1.0))
    assert len(got) == 1 and "(roller9, idler_u1) is a source too and acts on lc9.T" in got[0]
    assert "z 8, p 0.0003" in got[0]
    assert "is a source too" not in held_out_left(rep(2.0, 1.0))[0]     # p 0.14: noise
    assert "is a source too" not in held_out_left(rep(8.0, 0.5))[0]     # the found source took half


def test_the_verdict_names_a_line_mode_seen_on_several_sensors_once():
    """Independent seed-61 c17: the line's own 0.75 Hz mode, excited through the drives, found on
    lc9 (run1) and lc19 (run1, run2); the verdict named it three times, about 300 characters
    each. It now says it once, with the ranges, where the first of them stood; the report's
    findings keep each. A lone finding and other kinds read as before."""
    from webline.diagnosis.report import LINE_MODE, _verdict, verdict_findings

    def mode(run, sensor, f, explains, share):
        return {"kind": LINE_MODE, "run": run, "sensor": sensor, "frequency_hz": f, "ripple_explains": explains,
                "share_of_residual": share, "text": f"mode {f} on {sensor} in {run}"}

    other = {"kind": "unexplained resonance", "frequency_hz": 6.25, "text": "unexplained resonance near 6.25 Hz"}
    finds = [mode("run1", "lc9.T", 0.75, 0.893, 0.169), other, mode("run2", "lc19.T", 0.75, 0.721, 0.164),
             mode("run1", "lc19.T", 0.75, 0.798, 0.162), mode("run1", "lc9.T", 2.5, 0.6, 0.05)]
    got = verdict_findings(finds)
    assert len(got) == 3, got
    assert got[0] == ("the line's own mode near 0.75 Hz on lc9 (run1) and lc19 (run1, run2), excited through the "
                      "drives' torque: a broadband torque ripple fitted to the residual reproduces 72-89 % of it "
                      "(16-17 % of the refined residual; the levels per drive in the findings)")
    assert got[1:] == ["unexplained resonance near 6.25 Hz", "mode 2.5 on lc9.T in run1"]
    rep = {"effects": [], "gap": {}, "rejected": [], "structure": {}, "findings": finds}
    v = _verdict(rep)
    assert v.count("0.75 Hz") == 1 and "mode 2.5 on lc9.T" in v and "6.25 Hz" in v, v
