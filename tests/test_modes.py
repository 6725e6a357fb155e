"""The linearised line (orchestrator.modes, ``webline modes``): poles against hand-derived ones,
the paper's experiment (a) tension loop, harmonic gains against a monolithic simulation, the CLI."""
import json
import math
from pathlib import Path

import numpy as np
import pytest

from webline.orchestrator import modes as M
from webline.orchestrator.layout import load_system

ROOT = Path(__file__).resolve().parents[1]
EWL = ROOT / "scenarios" / "ewl.yaml"
PAPER_A = ROOT / "scenarios" / "paper" / "a_tension_step_zero_speed.yaml"
UNWIND_ZONE_IDLERS = ("idler_u1", "guide_in", "guide_out", "idler_u2", "roller9")


@pytest.fixture(scope="module")
def ewl():
    system = load_system(EWL)
    lin = M.linearise_system(system)
    return system, lin, M.modes(lin)


def _span(system, name):
    return next(s for s in system.meta["spans"] if s["component"] == name)


def test_angles_and_roll_radii_are_frozen(ewl):
    """Round line, ideal drives: every angle is a pure integrator of its speed (dropped), the roll
    radii are frozen (quasi-static); speeds, tensions, controllers and filters stay."""
    system, lin, _ = ewl
    assert set(lin.dropped) == {f"{e}.theta" for e in system.meta["elements"]} | {"unwind.R", "rewind.R"}
    assert "span7.T" in lin.states and "sw_leader.omega" in lin.states and "lc9.T" in lin.states
    # the operating point is an equilibrium but for the rolls' slow speed change as R changes ({5})
    others = [r for n, r in zip(lin.states, lin.residual) if n not in ("unwind.omega", "rewind.omega")]
    assert max(others) < 1e-9


def test_single_span_between_speed_controlled_rollers(ewl):
    """Span 7 (S-wrap leader -> follower, L = 0.4 m) has speed-controlled rollers at both ends.
    {21} linearised: dT/dt = -(v_out/L) T + ((EA - T) dv_out - (EA - T_in) dv_in)/L. The speed
    PIs' tension feed-forward R (T_in - T_out) cancels the web's pull on the rollers, so a change
    of T moves no roller: -v_out/L is a pole of the line, the span's own. The finite differences
    are exact to round-off on these bilinear equations, hence 1e-6."""
    system, lin, modes = ewl
    s = _span(system, "span7")
    v_out = system.meta["elements"][s["down"]]["v0"]
    pole = -v_out / s["length"]
    assert pole == pytest.approx(-2.54, rel=1e-3)  # 200 ft/min over 0.4 m
    m = min(modes, key=lambda m: abs(m["eigenvalue"] - pole))
    assert m["eigenvalue"].real == pytest.approx(pole, rel=1e-6)
    assert m["kind"] == "real" and m["moves"][0][0] == "span7"
    # the A entry itself: d(dT/dt)/dT = -v_out/L
    k = lin.states.index("span7.T")
    assert lin.A[k, k] == pytest.approx(pole, rel=1e-6)


def test_pull_roll_zone_is_one_spring(ewl):
    """Pull-roll zone (S-wrap follower -> pull roll, spans 8-10, no tension loop, idlers between):
    with the idlers quasi-static the zone is one span of the summed length, pole -v/sum(L). The idler
    modes (16.6 and 31 Hz) lie two decades above it; their coupling shifts it by far less than 1e-3."""
    system, _, modes = ewl
    spans = [_span(system, f"span{k}") for k in (8, 9, 10)]
    v = system.meta["elements"][spans[-1]["down"]]["v0"]
    pole = -v / sum(s["length"] for s in spans)
    m = min(modes, key=lambda m: abs(m["eigenvalue"] - pole))
    assert m["eigenvalue"].real == pytest.approx(pole, rel=1e-3)
    assert {n for n, _ in m["moves"]} == {"span8", "span9", "span10"}


def test_non_ideal_drive_keeps_its_angles_and_shaft_mode(tmp_path):
    """A compliant drive's twist theta_motor - theta is read by the shaft torque, so both angles stay:
    one integrator (the common angle) is reported, and the shaft mode lies at the two-mass frequency
    sqrt(k (1/J_m + 1/J)) (k 3000 N.m/rad, J_m 0.02, J 1.2 lb.ft^2: 72.8 Hz), to the few per cent
    the web's stiffness R^2 EA/L (1 % of k/J) and the speed PI add."""
    system = load_system(EWL, {"drives.speed_loops.pull_roll":
                               "{K_ref: 40 1/s, zeta: 1.1, drive: {motor_inertia: 0.02 kg*m^2, "
                               "stiffness: 3000 N*m/rad, damping: 0.5 N*m*s/rad}}"})
    lin = M.linearise_system(system)
    assert "pull_roll.theta" in lin.states and "pull_roll.theta_motor" in lin.states
    modes = M.modes(lin)
    integ = [m for m in modes if m["kind"] == "integrator"]
    assert len(integ) == 1
    J = 1.2 * 0.45359237 * 0.3048 ** 2
    w = math.sqrt(3000.0 * (1 / 0.02 + 1 / J))
    shaft = max(modes, key=lambda m: dict(m["moves"]).get("pull_roll.motor", 0.0))
    assert abs(shaft["eigenvalue"]) == pytest.approx(w, rel=0.03)


def _zone_pole(system):
    from test_paper_experiments import zone_model
    model, _ = zone_model(system, "unwind_zone")
    p = np.linalg.eigvals(model.A)
    return p[np.argmax(p.imag)]


@pytest.mark.parametrize("light_idlers", [False, True])
def test_paper_a_tension_loop_pair(light_idlers):
    """Experiment (a), unwind zone at zero speed: tests/test_paper_experiments derives the pair
    -0.48 +- 5.68j from the PI design with the zone as one spring and massless idlers. With the
    idlers made light (1 g) the linearisation is that model, up to its EA for EA - T (T/EA = 0.4 %
    at 5 lbf, entering through the weakly coupled far end): 1e-3. With the real idlers their
    inertia shifts the pair to 0.910 Hz decaying at 0.486 1/s, what the monolithic reference run
    rings at (test_a_tension_step_follows_the_pi_design): 1 % from the one-spring model."""
    ov = {f"{e}.mass": "1 g" for e in UNWIND_ZONE_IDLERS} if light_idlers else {}
    system = load_system(PAPER_A, ov)
    ref = _zone_pole(system)
    assert ref == pytest.approx(-0.48 + 5.68j, abs=0.01)
    modes = [m for m in M.modes(M.linearise_system(system)) if m["kind"] == "oscillatory"]
    m = min(modes, key=lambda m: abs(m["eigenvalue"] - ref))
    lam = m["eigenvalue"]
    if light_idlers:
        assert abs(lam - ref) / abs(ref) < 1e-3
    else:
        assert 1e-3 < abs(lam - ref) / abs(ref) < 0.01
        assert m["f"] == pytest.approx(0.910, abs=0.003)
        assert -lam.real == pytest.approx(0.486, abs=0.005)
    assert m["moves"][0][0].startswith("span")


@pytest.fixture(scope="module")
def ewl_round_run():
    from webline.orchestrator.reference import simulate_reference
    return simulate_reference(load_system(EWL, {"experiment.duration": "8 s"}))


@pytest.mark.parametrize("element, tolerances", [
    ("idler_u1", {"lc9.T": 0.01, "lc15.T": 0.05}),
    ("pull_roll", {"lc15.T": 0.02, "lc19.T": 0.02}),
])
def test_harmonic_gains_match_a_simulation(ewl_round_run, element, tolerances):
    """A 20 um first-harmonic eccentricity on an EWL roller, off resonance: idler_u1 (90 deg wrap,
    4.24 Hz at 200 ft/min, between the 0.91 Hz tension-loop and 9.46 Hz idler modes) and the
    driven pull roll (180 deg wrap, 2.12 Hz, above the 1.40 Hz rewind loop). The load cells'
    harmonic from the monolithic reference (eccentric minus round, least squares on the element's
    angle after 2 s of transient: diagnosis.estimate.complex_gain) against G(j omega) of the
    linearisation, in the diagnosis's convention (Y = G X, X = C exp(i psi)). The decaying start transient of the tension-loop
    modes leaks into the fit: measured 0.03 % on lc9 (|G| 2.1e3 N/m), 1.4 % on lc15 (2.95 N/m,
    behind the S-wrap) for idler_u1; 0.6 % for the pull roll (2.0e3 and 3.0e3 N/m)."""
    from webline.diagnosis.estimate import complex_gain
    from webline.orchestrator.reference import simulate_reference
    C, psi = 20e-6, 0.7
    rb = ewl_round_run
    ecc = load_system(EWL, {"experiment.duration": "8 s",
                            f"{element}.eccentricity": f"{{C: [{C * 1e6:g} um], psi: [{psi} rad]}}"})
    f0 = ecc.meta["elements"][element]["f0"]
    G = M.harmonic_gains(ecc, element, [f0])  # the eccentricity in the layout is ignored: it is the input
    assert set(G) == {"lc9.T", "lc15.T", "lc19.T"}
    re = simulate_reference(ecc)
    mask = rb.time >= 2.0
    X = C * np.exp(1j * psi)
    for lc, rel in tolerances.items():
        # the diagnosis's own gain from a sensitivity simulation
        g_sim = complex_gain(re[lc] - rb[lc], re[f"{element}.theta"], [1], [X], mask)[0]
        g_lin = G[lc][0]
        assert abs(g_lin) > 1.0
        assert abs(g_sim) == pytest.approx(abs(g_lin), rel=rel), lc
        assert abs(np.angle(g_sim / g_lin)) < rel, lc


def test_harmonic_gains_follow_the_layout_convention(ewl):
    """The element's input is +1 on the span leaving it and -exp(i j alpha) on the span entering it
    (docs/layout.md), j alpha = 2 pi f alpha/Omega; the rewind has no leaving span and its entering
    span takes the series as given; the unwind has no entering span."""
    system, lin, _ = ewl
    el = system.meta["elements"]["idler_u1"]
    f = np.array([el["f0"], 2 * el["f0"]])
    G = M.harmonic_gains(system, "idler_u1", f, lin=lin)["lc9.T"]
    up, down = lin.transfer(f, ["span2.up", "span1.down"])[:, 0, :].T
    w = -np.exp(1j * np.array([1, 2]) * el["wrap"])
    assert G == pytest.approx(up + w * down, rel=1e-12)
    assert [n for n, _ in M.element_ends(system, "unwind")] == ["span1.up"]
    ends = M.element_ends(system, "rewind")
    assert [n for n, _ in ends] == ["span13.down"] and ends[0][1](1.0) == 1.0
    with pytest.raises(KeyError, match="no element"):
        M.element_ends(system, "nope")


def test_transfer_is_the_resolvent_at_every_frequency_across_chunks(ewl):
    """G(s) = C (sI - A)^-1 (B + s B_rate) + D, solved in batches of TRANSFER_CHUNK
    frequencies: each frequency of a sweep longer than a chunk gives what it gives alone,
    and that is the resolvent written out (a complex solve at double precision)."""
    _, lin, _ = ewl
    f = np.linspace(0.05, 40.0, M.TRANSFER_CHUNK + 37)
    cols = ["sw_leader.tau", "span2.up"]
    G = lin.transfer(f, cols)
    i = [lin.inputs.index(c) for c in cols]
    for k in (0, M.TRANSFER_CHUNK - 1, M.TRANSFER_CHUNK, len(f) - 1):
        s = 2j * np.pi * f[k]
        X = np.linalg.inv(s * np.eye(lin.A.shape[0]) - lin.A) @ (lin.B[:, i] + s * lin.B_rate[:, i])
        assert G[k] == pytest.approx(lin.C @ X + lin.D[:, i], rel=1e-9, abs=1e-12)
        assert lin.transfer([f[k]], cols)[0] == pytest.approx(G[k], rel=1e-12, abs=1e-15)


def test_cli_table_json_png(tmp_path, capsys):
    from webline.orchestrator.modes_cmd import main
    assert main([str(EWL), "--out", str(tmp_path), "--fmax", "60"]) == 0
    out = capsys.readouterr().out
    assert "oscillatory modes" in out and "peak gain" in out
    row = next(line for line in out.splitlines() if line.strip().startswith("0.911"))
    assert "span1" in row
    data = json.loads((tmp_path / "modes.json").read_text())
    fs = [m["f_Hz"] for m in data["modes"] if m["kind"] == "oscillatory"]
    assert any(abs(f - 0.911) < 0.002 for f in fs)
    tf = data["transfer_functions"]
    assert tf["f_Hz"][-1] == pytest.approx(60.0)
    assert tf["inputs"]["idler_u1.dL"]["unit"] == "N/m"
    assert tf["inputs"]["unwind.tau"]["unit"] == "N/(N.m)"
    lc9 = tf["inputs"]["idler_u1.dL"]["load_cells"]["lc9.T"]
    assert len(lc9["magnitude"]) == len(tf["f_Hz"]) and max(lc9["magnitude"]) > 1e4
    # nothing downstream of the speed-controlled S-wrap reaches the unwind zone
    assert tf["inputs"]["rewind.dL"]["load_cells"]["lc9.T"]["zero"] is True
    lm = data["linear_model"]
    assert np.array(lm["A"]).shape == (len(lm["states"]),) * 2
    assert np.array(lm["B"]).shape == (len(lm["states"]), len(lm["inputs"]))
    assert (tmp_path / "bode.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_cli_bad_layout_exits_2(tmp_path, capsys):
    from webline.cli import main
    assert main(["modes", str(EWL), "--set", "idler_u1.radius=-1 in"]) == 2
    err = capsys.readouterr().err
    assert "ewl.yaml" in err and "radius" in err
    assert main(["modes", str(tmp_path / "missing.yaml")]) == 2
    assert "missing.yaml" in capsys.readouterr().err
    assert main(["modes", str(EWL), "--fmin", "5", "--fmax", "1"]) == 2
    assert "fmin" in capsys.readouterr().err


def test_mode_free_response_in_the_reference_grows_at_its_eigenvalue():
    """At zero line speed the spans lose their -v/L damping and the linearisation finds the rewind
    zone's 14.4 Hz idler mode (roller19, spans 11 and 13) slightly unstable, Re lambda = +0.07 1/s.
    Started on that eigenvector (0.01 N: linear), the monolithic reference (LSODA, rtol 1e-10)
    grows at the same rate: amplitudes of the 14.4 Hz line in two 0.4 s windows 1.5 s apart.
    Other modes are not excited, so the window fits are clean to ~1e-3 of the growth rate."""
    from scipy.integrate import solve_ivp
    from webline.orchestrator.reference import ReferenceSystem
    system = load_system(PAPER_A, {"experiment.duration": "1.9 s"})  # before the T_ref step at 2 s
    ref = ReferenceSystem(M.round_system(system))
    lin = M.linearise(ref)
    lam, V = np.linalg.eig(lin.A)
    k = max(range(len(lam)), key=lambda i: lam[i].real if lam[i].imag > 1.0 else -np.inf)
    assert lam[k].imag / (2 * math.pi) == pytest.approx(14.39, abs=0.05)
    assert lam[k].real > 0.03
    v = V[:, k] / np.max(np.abs(V[:, k]))
    x = ref.x0.copy()
    x[[ref.state_names.index(n) for n in lin.states]] += 0.01 * v.real
    sol = solve_ivp(ref.rhs, (0.0, 1.9), x, method="LSODA", rtol=1e-10, atol=1e-10, dense_output=True)
    assert sol.success
    t = np.linspace(0.0, 1.9, 4000)
    j = ref.state_names.index("span11.T")
    y = sol.sol(t)[j] - ref.x0[j]
    basis = np.column_stack([np.cos(lam[k].imag * t), np.sin(lam[k].imag * t)])

    def amplitude(a, b):
        m = (t >= a) & (t < b)
        c, *_ = np.linalg.lstsq(basis[m], y[m], rcond=None)
        return np.hypot(*c)

    rate = math.log(amplitude(1.5, 1.9) / amplitude(0.0, 0.4)) / 1.5
    assert rate == pytest.approx(lam[k].real, rel=0.02)


def test_engine_jacobian_equals_the_reference(ewl):
    """The fast engine's generated code calls the same physics functions as the reference's
    models, so A, C and B (``linearise_system`` default, jacobian="engine") equal the reference's
    up to the central difference's round-off: each rhs may differ by a few ulps of its largest
    term (a fused multiply-add, another summation order), which the step h = 1e-6 max(1, |x|)
    turns into eps/h ~ 2e-10 of a term; 1e-8 of the largest entry allows for terms up to 50 times
    the entry. Eigenvalues then agree to that over the eigenvectors' condition; simple
    eigenvalues (not within 1e-3 of another) are compared at 1e-6 of |A|. Measured: bit-identical."""
    system, lin_e, modes_e = ewl
    assert lin_e.info["jacobian"] == "engine"
    lin_r = M.linearise_system(system, jacobian="reference")
    assert lin_r.info["jacobian"] == "reference"
    assert lin_r.states == lin_e.states and lin_r.inputs == lin_e.inputs and lin_r.outputs == lin_e.outputs
    scale = np.max(np.abs(lin_r.A))
    assert np.max(np.abs(lin_e.A - lin_r.A)) <= 1e-8 * scale
    assert np.max(np.abs(lin_e.C - lin_r.C)) <= 1e-8 * np.max(np.abs(lin_r.C))
    assert np.max(np.abs(lin_e.B - lin_r.B)) <= 1e-8 * np.max(np.abs(lin_r.B))
    lr, le = np.linalg.eigvals(lin_r.A), np.linalg.eigvals(lin_e.A)
    simple = [l for l in lr if np.sum(np.abs(lr - l) < 1e-3 * max(1.0, abs(l))) == 1]
    assert len(simple) > 20
    for l in simple:
        assert np.min(np.abs(le - l)) <= 1e-6 * scale
    # the modes the command reports are the same
    modes_r = M.modes(lin_r)
    assert [m["kind"] for m in modes_r] == [m["kind"] for m in modes_e]
    assert [m["f"] for m in modes_r] == pytest.approx([m["f"] for m in modes_e], rel=1e-6, abs=1e-9)
    with pytest.raises(ValueError, match="jacobian"):
        M.linearise_system(system, jacobian="nope")
