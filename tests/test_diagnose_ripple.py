"""The drives' torque ripple as the diagnosis fits it (diagnosis.ripple): the fit's
arithmetic on hand-made spectra, a hump it explains reported as the line's own mode,
and the density recovered from a simulated line whose unwind drive has a ripple."""
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from webline.diagnosis import claims, ripple
from webline.diagnosis.line_model import LineModel
from webline.diagnosis.pipeline import RunCtx

EWL = Path(__file__).resolve().parents[1] / "scenarios" / "ewl.yaml"


def test_fit_levels_recovers_the_densities_that_made_the_spectrum():
    f = np.linspace(0.0, 50.0, 201)
    bump = lambda f0, w: 1.0 / (1.0 + ((f - f0) / w) ** 2)  # noqa: E731
    G = {"a": {"s1": bump(1.0, 0.3), "s2": 0.5 * bump(1.0, 0.3)},
         "b": {"s1": 0.2 * bump(6.0, 1.0), "s2": bump(6.0, 1.0)}}
    S0 = {"s1": 1e-3, "s2": 2e-3}
    P = {s: S0[s] + 4.0 * G["a"][s] + 0.25 * G["b"][s] for s in S0}
    levels, R = ripple.fit_levels(P, G, S0, f)
    # noise-free spectra made of the responses: the weighted least squares is exact
    assert levels["a"] == pytest.approx(4.0, rel=1e-6) and levels["b"] == pytest.approx(0.25, rel=1e-6)
    np.testing.assert_allclose(R["s1"], P["s1"] - S0["s1"], rtol=1e-6, atol=1e-12)
    # a drive whose response is not in the data gets no ripple (the fit is non-negative)
    G["c"] = {"s1": bump(20.0, 1.0), "s2": bump(20.0, 1.0)}
    levels, _ = ripple.fit_levels(P, G, S0, f)
    assert levels["c"] == pytest.approx(0.0, abs=1e-9)
    # the share of a hump's excess the fit reproduces
    assert ripple.explained(f, P["s1"], S0["s1"], R["s1"], (0.5, 1.5)) == pytest.approx(1.0, rel=1e-6)
    assert ripple.explained(f, P["s1"], S0["s1"], 0.5 * R["s1"], (0.5, 1.5)) == pytest.approx(0.5, rel=1e-6)


def test_a_hump_the_ripple_explains_is_the_lines_own_mode():
    from scipy import signal
    from test_diagnose_claims import _fake_diagnosis
    from webline.diagnosis.line_model import Sim
    fs, n = 250.0, 250 * 40
    rng = np.random.default_rng(1)
    t = np.arange(n) / fs
    w0, z = 2 * np.pi * 17.0, 0.04
    b, a = signal.bilinear([w0 ** 2], [1.0, 2 * z * w0, w0 ** 2], fs)
    y = rng.normal(0, 0.2, n) + signal.lfilter(b, a, rng.normal(0, 0.3, n))
    d = _fake_diagnosis({"lc15.T": y}, fs, t, models={"lc15.T": np.zeros(n)})
    d.steps = [{"sims": {"r": Sim(None, {"lc15.T": np.zeros(n)})}}]
    d.where_report = {}
    noise = claims.sensor_noise(d)
    f, p = ripple.welch(y[d.ctx[0].mask], fs)
    ps = ripple.smooth(p, f)
    S0 = noise["r"]["lc15.T"]["psd_N2_per_hz"]
    # a fit that reproduces the hump: the line's own mode; one that reproduces nothing: unexplained
    full = {"r": {"psd": {"lc15.T": np.maximum(ps - S0, 0.0)}, "f": f,
                  "levels_Nm_per_rtHz": {"unwind": 2e-3, "rewind": 0.0}}}
    h = claims.humps(d, noise, ripple_fit=full)[0]
    assert h["kind"] == "line mode excited through the drives" and h["ripple_explains"] > 0.9
    assert "(2 on unwind mN*m/sqrt(Hz);" in h["text"] and "rewind" not in h["text"]
    none = {"r": dict(full["r"], psd={"lc15.T": np.zeros_like(ps)})}
    h = claims.humps(d, noise, ripple_fit=none)[0]
    assert h["kind"] == "unexplained resonance" and h["ripple_explains"] == 0.0
    assert h["text"].endswith("the drives' torque ripple explains 0 % of it")


def test_ripple_density_of_a_simulated_line_is_recovered(tmp_path):
    """The EWL with a white ripple of 4 mN*m/sqrt(Hz) on the unwind drive alone, load
    cells with 0.05 N of white noise, two runs at other rates (40 s at 250 Hz, 20 s at
    500 Hz: the density, not the rms, is the same). The fit over 0.2-30 Hz and three
    sensors has thousands of Welch bins of ~20 degrees of freedom each: its statistical
    error is a few per cent. The unwind's response differs in shape from the other
    drives' (it carries its own zone's mode), so the density goes to the unwind:
    within 25 %, and the other drives get less than a third of it."""
    dens = 4e-3
    model = LineModel(EWL)
    base_doc = {"base": str(EWL), "set": {}}
    rng = np.random.default_rng(5)
    ctx, sims, noise = [], {}, {}
    for name, fs, T, seed in (("a", 250.0, 40.0, 77), ("b", 500.0, 20.0, 78)):
        exp = {"experiment.duration": f"{T} s", "experiment.output_interval": f"{1 / fs} s"}
        run = SimpleNamespace(name=name, overrides=exp, t=np.arange(0.0, T + 0.5 / fs, 1 / fs), holdout=False)
        truth = ripple.probe_doc(base_doc, "unwind", 1.0 / fs)
        truth["set"]["drives.speed_loops.unwind.torque_noise"] = f"{dens / math.sqrt(2.0 / fs):.6g} N*m"
        truth["set"]["drives.speed_loops.unwind.noise_seed"] = seed
        sim_true, sims[name] = model.simulate_many([(run, truth, "truth"), (run, base_doc, "model")])
        c = RunCtx(run, True)
        c.fs = fs
        c.sensors = [s for s in ("lc9.T", "lc15.T", "lc19.T") if s in sim_true.columns]
        c.meas = {s: sim_true.columns[s] + rng.normal(0, 0.05, len(run.t)) for s in c.sensors}
        c.mask = run.t >= 2.0
        ctx.append(c)
        noise[name] = {s: {"psd_N2_per_hz": 0.05 ** 2 * 2.0 / fs} for s in c.sensors}
    d = SimpleNamespace(ctx=ctx, model=model, refined_doc=base_doc, steps=[{"sims": sims}])
    fits = ripple.screen(d, noise)
    for name in ("a", "b"):
        fit = fits[name]["levels_Nm_per_rtHz"]
        assert fit["unwind"] == pytest.approx(dens, rel=0.25), (name, fit)
        assert all(v < dens / 3 for el, v in fit.items() if el != "unwind"), (name, fit)
        assert len(fits[name]["f"]) == len(fits[name]["psd"]["lc9.T"])


def test_a_layout_that_states_a_ripple_is_not_fitted_again():
    fs, T = 250.0, 4.0
    model = LineModel(EWL)
    exp = {"experiment.duration": f"{T} s", "experiment.output_interval": f"{1 / fs} s"}
    run = SimpleNamespace(name="a", overrides=exp, t=np.arange(0.0, T + 0.5 / fs, 1 / fs), holdout=False)
    doc = ripple.probe_doc({"base": str(EWL), "set": {}}, "rewind", 1.0 / fs)
    sim = model.simulate(run, doc=doc)
    c = RunCtx(run, True)
    c.fs, c.sensors, c.mask = fs, ["lc9.T"], run.t >= 1.0
    c.meas = {"lc9.T": sim.columns["lc9.T"]}
    d = SimpleNamespace(ctx=[c], model=model, refined_doc=doc, steps=[{"sims": {"a": sim}}])
    assert ripple.screen(d, {"a": {"lc9.T": {"psd_N2_per_hz": 1e-6}}}) == {}


def test_probe_responses_are_kept_after_their_simulations_are_released():
    """The shaft screen probes the refined layout again after the ripple fit released
    its probes: the second ask is answered from what the line model kept, identical,
    and another view or other samples read are probed afresh."""
    import gc
    fs, T = 250.0, 4.0
    model = LineModel(EWL)
    model.RECENT_BYTES = model.READ_BYTES = 0   # what is derived, not the released Sims (test_line_model_memo.py)
    exp = {"experiment.duration": f"{T} s", "experiment.output_interval": f"{1 / fs} s"}
    run = SimpleNamespace(name="a", overrides=exp, t=np.arange(0.0, T + 0.5 / fs, 1 / fs), holdout=False)
    doc = {"base": str(EWL), "set": {"web.E": "2.3e8 Pa"}}
    [sim] = model.simulate_many([(run, doc, "refined")])
    c = RunCtx(run, True)
    c.fs, c.sensors, c.mask = fs, ["lc9.T", "lc19.T"], run.t >= 1.0
    d = SimpleNamespace(ctx=[c], model=model)
    G1, f1 = ripple.responses(d, doc, {"a": sim}, view=ripple.fine)
    probes = model.n_sims - 1
    assert probes == len(ripple.drives(sim)) >= 3
    gc.collect()   # the probes' simulations are gone
    G2, f2 = ripple.responses(d, doc, {"a": sim}, view=ripple.fine)
    assert model.n_sims == 1 + probes
    assert list(G2["a"]) == list(G1["a"])   # the drives in the same order (the fit's columns)
    for el in G1["a"]:
        for s in c.sensors:
            np.testing.assert_array_equal(G2["a"][el][s], G1["a"][el][s])
    np.testing.assert_array_equal(f2["a"], f1["a"])
    with pytest.raises(ValueError):
        G2["a"]["unwind"]["lc9.T"][0] = 0.0     # kept arrays cannot be changed by a caller
    ripple.responses(d, doc, {"a": sim})          # another view
    assert model.n_sims == 1 + 2 * probes
    c.mask = run.t >= 2.0                         # other samples
    ripple.responses(d, doc, {"a": sim}, view=ripple.fine)
    assert model.n_sims == 1 + 3 * probes
    model.cleanup()
