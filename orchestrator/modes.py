"""The linearised line: Jacobian at the operating point, modes, transfer functions.

``linearise(ode, compiled=None)`` differentiates the ODE of a line
(``orchestrator.reference.ReferenceSystem``, or any object with the same interface: ``x0``,
``state_names``, ``columns``, ``models``, ``names``, ``offsets``, ``u``, ``schedule``,
``stateful``; with ``compiled``, the fast engine's compiled code of the same system for A and
C: ``linearise_system(system)`` does that by default) by central finite differences
at its operating point (the start of the experiment, where the layout puts the line in
equilibrium, ``orchestrator.operating_point``), giving

    dx/dt = A x + B u + B_rate du/dt,     y = C x + D u

with ``x`` the deviations of the modal states, ``y`` the load-cell readings and ``u``
the inputs: the length change of every span end (m; its rate enters through
``B_rate``) and the motor torque of every driven element (N.m).

States left out (frozen at their operating values), and why:

* the angles ``theta`` of rotating elements (and a non-ideal drive's motor angle): a
  pure integral of the speed that nothing else reads once the line is round (the
  eccentricity is the *input* here, so the linearised line is the round one). A state
  whose column of A is zero only adds an eigenvalue 0 and leaves the others unchanged
  (A is block triangular). An angle that something does read (a drive shaft's twist
  theta_motor - theta) is kept, and its zero eigenvalue is reported as an integrator;
* the roll radii ``R`` of the unwind and rewind: the radius changes by one web
  thickness per revolution ({5}), minutes against the seconds of the tension and speed
  dynamics, so the operating point is no true equilibrium with R in it. The linear
  model is the line at the frozen radius of the operating point (quasi-static).

Span-length inputs, from {20} (``webline.physics.span.tension_rate``):
``dT/dt = [v_out (EA - T) - v_in (EA - T_in) + (EA - T) dL_down/dt + (EA - T_in) dL_up/dt] / L``,
so a length change at the upstream end enters with ``d(dT/dt)/d(dL_up/dt) = (EA - T_in)/L``,
at the downstream end with ``(EA - T)/L``, and the length itself with
``d(dT/dt)/dL = -(dT/dt)/L`` (zero at equilibrium). These partials are analytic (exact).
A rotating element's eccentricity ``Delta L(theta)`` lengthens the span leaving it
(the layout's convention, docs/layout.md) and changes the span entering it by the
opposite, a wrap ``alpha`` later in angle: ``C_j sin(j theta + psi_j + pi + j alpha)``
(the rewind: as given). At frequency f with the element at speed Omega the entering
span's input is thus ``-exp(i 2 pi f alpha / Omega)`` times the leaving span's. The
transfer function from the element's length change to a load cell is
``G(s) = C (sI - A)^-1 sum_ends w_end(s) (B_L + s B_rate) + D``.

Torque inputs are finite differences of the element's motor-torque input (the speed
PI's output, plus a disturbance): ``d(domega/dt)/dtau = 1/J`` for an ideal drive.

Modes: eigenvalues of A, frequency |Im lambda|/(2 pi), damping ratio -Re lambda/|lambda|,
and which spans and rollers move: each mode's share of the modal energy
(span: L |dT|^2 / (2 EA), rotating element: J |domega|^2 / 2), top three.

Plain functions on numpy arrays.
"""
import copy
import math
from dataclasses import dataclass, field

import numpy as np

# Relative central-difference step: the line's equations are low-order polynomials in the
# states (products T v, T/L), so truncation error is tiny; 1e-6 keeps round-off at
# ~eps/h ~ 1e-10 of a term.
REL_STEP = 1.0e-6
TRANSFER_CHUNK = 256   # frequencies per batched solve in Linearisation.transfer (memory ~ chunk n^2)
ROTATING_MODELS = ("IdleRoller", "DrivenRoller", "UnwindRoll", "RewindRoll")
DRIVEN_MODELS = ("DrivenRoller", "UnwindRoll", "RewindRoll")


def round_system(system):
    """Copy of ``system`` with every span's eccentricity series zeroed (the round line,
    whose eccentricities the linear model takes as inputs) and no load-cell noise."""
    s = copy.deepcopy(system)
    for c in s.components:
        if c.model == "Span":
            for k in list(c.parameters):
                if k.startswith(("up.C[", "down.C[")):
                    c.parameters[k] = 0.0
            if c.parameters.get("length_mode", 0.0) == 2.0:
                c.parameters["length_mode"] = 0.0
        if c.model == "LoadCell":
            c.parameters["noise_std"] = 0.0
    return s


# ---- the ODE with input offsets --------------------------------------------------------
def _evaluate(ode, t, xl, du):
    """Route all outputs at (t, xl) with the inputs offset by ``du`` {comp index: {input index:
    delta}} (the offset input is what the component's model sees, on top of what its connection
    routes in). Returns ({comp: its input list}, {comp: its outputs})."""
    seen = {}

    def inputs(c):
        u = ode.u[c]
        if c in du:
            u = list(u)
            for i, d in du[c].items():
                u[i] += d
        return u

    ys = {}
    for c, model, _y, entries in ode.schedule:
        a, b = ode.offsets[c]
        u = inputs(c)
        values = model.outputs(t, xl[a:b], u)
        ys[c] = values
        for o, dests in entries:
            for ulist, i in dests:
                ulist[i] = values[o]
    for c in range(len(ode.models)):
        seen[c] = inputs(c)
    return seen, ys


def _rhs(ode, t, x, du):
    xl = list(map(float, x))
    us, _ = _evaluate(ode, t, xl, du)
    dx = np.zeros(len(xl))
    for ci, a, b in ode.stateful:
        dx[a:b] = ode.models[ci].derivatives(t, xl[a:b], us[ci])
    return dx


def _outputs(ode, t, x, du, columns):
    xl = list(map(float, x))
    _, ys = _evaluate(ode, t, xl, du)
    flat = {}
    for c, name in enumerate(ode.names):
        if c in ys:
            for o, oname in enumerate(ode.models[c].OUTPUTS):
                flat[f"{name}.{oname}"] = ys[c][o]
    return np.array([flat[k] for k in columns])


# ---- linearisation ----------------------------------------------------------------------
@dataclass
class Linearisation:
    """Linear model of a line at its operating point (SI).

    ``A`` (n x n) over ``states``; ``B``, ``B_rate`` (n x m) over ``inputs`` (span-end
    lengths in m, then motor torques in N.m); ``C``, ``D`` (p x n, p x m) over ``outputs``
    (load-cell columns, N). ``dropped``: frozen states; ``residual``: |dx/dt| at the
    operating point per kept state (0 for a true equilibrium); ``info``: per-state and
    per-input metadata used for the mode descriptions and element transfer functions.
    """
    A: np.ndarray
    B: np.ndarray
    B_rate: np.ndarray
    C: np.ndarray
    D: np.ndarray
    states: list
    inputs: list
    outputs: list
    dropped: list
    residual: np.ndarray
    t: float
    info: dict = field(default_factory=dict)

    def transfer(self, freqs, columns=None):
        """G(i 2 pi f) for every frequency (Hz): array (len(freqs), p, m) of the inputs
        ``columns`` (default all), outputs per load cell."""
        cols = range(len(self.inputs)) if columns is None else [self.inputs.index(c) for c in columns]
        cols = list(cols)
        B, Br, D = self.B[:, cols], self.B_rate[:, cols], self.D[:, cols]
        freqs = np.atleast_1d(np.asarray(freqs, float))
        n = self.A.shape[0]
        out = np.empty((len(freqs), self.C.shape[0], len(cols)), complex)
        eye = np.eye(n)
        # one batched solve per chunk of frequencies: a Python loop of small solves cost
        # 0.12 s for 1000 frequencies, most of a ripple calibration's time
        for a in range(0, len(freqs), TRANSFER_CHUNK):
            s = (2j * math.pi * freqs[a:a + TRANSFER_CHUNK])[:, None, None]
            X = np.linalg.solve(s * eye - self.A, B + s * Br)
            out[a:a + TRANSFER_CHUNK] = self.C @ X + D
        return out


def _state_kind(ode):
    """(component index, model name, state name) per state."""
    out = []
    for ci, (a, b) in enumerate(ode.offsets):
        model = ode.models[ci]
        for s in list(model.STATES)[: b - a]:
            out.append((ci, type(model).__name__.replace("Model", ""), s))
    return out


def _model_name(model):
    return type(model).__name__.replace("Model", "")


def linearise(ode, t=None, rel_step=REL_STEP, compiled=None):
    """Central-difference linearisation of ``ode`` at its initial state ``ode.x0`` and time
    ``t`` (default the experiment start). Returns a :class:`Linearisation`.

    ``compiled``: the fast engine's :class:`~orchestrator.engine.Compiled` of the same system
    (``compiled.ref`` is then ``ode``): A and C are differenced on its generated code
    (``rhs_numpy``/``outputs_numpy``, the right-hand side every fast-engine run integrates)
    instead of the reference's Python models; the torque inputs (a connected input, no entry
    of the engine's parameter vector) are differenced on ``ode`` either way.
    Span-length inputs are analytic partials of {20}; everything else is differenced.
    """
    t = float(ode.system.experiment.start if t is None else t)
    x0 = np.asarray(ode.x0, float)
    if compiled is not None:
        if list(compiled.state_names) != list(ode.state_names):
            raise ValueError("linearise: the compiled system's states differ from the ODE's")
        rhs = lambda x: compiled.rhs_numpy(t, x)  # noqa: E731
        col_index = {c: i for i, c in enumerate(compiled.columns)}
    else:
        rhs = lambda x: _rhs(ode, t, x, {})  # noqa: E731
    kinds = _state_kind(ode)
    names = list(ode.state_names)
    # states frozen a priori: roll radii (quasi-static); angle candidates tested below
    frozen = {i for i, (_, m, s) in enumerate(kinds) if m in ("UnwindRoll", "RewindRoll") and s == "R"}
    angles = {i for i, (_, m, s) in enumerate(kinds) if s in ("theta", "theta_motor") and m in ROTATING_MODELS}
    cand = [i for i in range(len(x0)) if i not in frozen]
    h = rel_step * np.maximum(1.0, np.abs(x0))
    cols = {}
    for j in cand:
        xp, xm = x0.copy(), x0.copy()
        xp[j] += h[j]
        xm[j] -= h[j]
        cols[j] = (rhs(xp) - rhs(xm)) / (2 * h[j])
    # an angle is dropped when no other state's rate depends on it
    f0 = rhs(x0)
    scale = np.maximum(1e-300, np.abs(np.column_stack([cols[j] for j in cand])).max())
    drop = set(frozen)
    for j in angles:
        col = cols[j].copy()
        col[j] = 0.0
        if np.max(np.abs(col[[i for i in cand if i != j]])) <= 1e-9 * scale:
            drop.add(j)
    keep = [i for i in range(len(x0)) if i not in drop]
    A = np.array([[cols[j][i] for j in keep] for i in keep]) if keep else np.zeros((0, 0))

    # outputs: load-cell readings
    loadcells = [c for c, m in zip(ode.names, ode.models) if _model_name(m) == "LoadCell"]
    outputs = [f"{n}.T" for n in loadcells]
    if compiled is not None:
        idx = [col_index[o] for o in outputs]
        out = lambda x: compiled.outputs_numpy(t, x)[idx]  # noqa: E731
    else:
        out = lambda x: _outputs(ode, t, x, {}, outputs)  # noqa: E731
    C = np.zeros((len(outputs), len(keep)))
    for k, j in enumerate(keep):
        xp, xm = x0.copy(), x0.copy()
        xp[j] += h[j]
        xm[j] -= h[j]
        C[:, k] = (out(xp) - out(xm)) / (2 * h[j])

    # the operating point's inputs (for the span partials)
    us, _ = _evaluate(ode, t, list(x0), {})
    row = {j: k for k, j in enumerate(keep)}
    inputs, Bcols, Brcols, Dcols, input_info = [], [], [], [], []
    for ci, (name, model) in enumerate(zip(ode.names, ode.models)):
        if _model_name(model) != "Span":
            continue
        a, _ = ode.offsets[ci]
        u = us[ci]
        T, T_in, L, EA = x0[a], u[2], model.L0, model.EA
        f = f0[a]
        for end, factor in (("up", EA - T_in), ("down", EA - T)):
            b, br = np.zeros(len(keep)), np.zeros(len(keep))
            if a in row:
                b[row[a]] = -f / L
                br[row[a]] = factor / L
            inputs.append(f"{name}.{end}")
            Bcols.append(b)
            Brcols.append(br)
            Dcols.append(np.zeros(len(outputs)))
            input_info.append({"kind": "span_end", "span": name, "end": end, "unit": "m"})
    for ci, (name, model) in enumerate(zip(ode.names, ode.models)):
        if _model_name(model) not in DRIVEN_MODELS:
            continue
        i = model.INPUTS.index("tau")
        tau0 = us[ci][i]
        d = rel_step * max(1.0, abs(tau0))
        fp, fm = _rhs(ode, t, x0, {ci: {i: d}}), _rhs(ode, t, x0, {ci: {i: -d}})
        yp, ym = _outputs(ode, t, x0, {ci: {i: d}}, outputs), _outputs(ode, t, x0, {ci: {i: -d}}, outputs)
        inputs.append(f"{name}.tau")
        Bcols.append(((fp - fm) / (2 * d))[keep])
        Brcols.append(np.zeros(len(keep)))
        Dcols.append((yp - ym) / (2 * d))
        input_info.append({"kind": "torque", "element": name, "unit": "N.m"})
    stack = lambda cs, n: np.column_stack(cs) if cs else np.zeros((n, 0))  # noqa: E731
    info = {"state_kinds": [kinds[j] for j in keep], "inputs": input_info,
            "span_weights": {}, "inertia": {}, "jacobian": "engine" if compiled is not None else "reference"}
    # energy weights: span L/EA, rotating J (the roll's J at the operating radius)
    _, ys = _evaluate(ode, t, list(x0), {})
    for ci, (name, model) in enumerate(zip(ode.names, ode.models)):
        m = _model_name(model)
        if m == "Span":
            info["span_weights"][name] = model.L0 / model.EA
        elif m in ROTATING_MODELS:
            J = ys[ci][model.OUTPUTS.index("J")] if "J" in model.OUTPUTS else model.J
            drive = getattr(model, "drive", None)
            if drive is not None and drive.enabled and "J" in model.OUTPUTS:
                J -= drive.J_motor
            info["inertia"][name] = (J, drive.J_motor if drive is not None and drive.enabled else 0.0)
    return Linearisation(A=A, B=stack(Bcols, len(keep)), B_rate=stack(Brcols, len(keep)), C=C,
                         D=stack(Dcols, len(outputs)), states=[names[j] for j in keep], inputs=inputs,
                         outputs=outputs, dropped=[names[j] for j in sorted(drop)],
                         residual=np.abs(f0[keep]), t=t, info=info)


JACOBIANS = ("engine", "reference")


def linearise_system(system, t=None, rel_step=REL_STEP, jacobian="engine"):
    """:func:`linearise` of the round ``system`` (eccentricities removed: they are inputs).

    ``jacobian="engine"``: A and C from the fast engine's compiled right-hand side
    (:func:`orchestrator.engine.compile_system`); a layout the engine cannot compile
    (:class:`~orchestrator.engine.EngineError`) or a missing numba falls back to the
    reference. ``"reference"``: the monolithic reference ODE's Python models (the
    cross-check). ``lin.info["jacobian"]`` says which was used."""
    from webline.orchestrator.reference import ReferenceSystem
    if jacobian not in JACOBIANS:
        raise ValueError(f"jacobian must be one of {', '.join(JACOBIANS)} (got {jacobian!r})")
    rs = round_system(system)
    if jacobian == "engine":
        try:
            from webline.orchestrator.engine import EngineError, compile_system
        except ImportError:  # no numba
            compile_system = None
        if compile_system is not None:
            try:
                c = compile_system(rs)
            except EngineError:
                c = None
            if c is not None:
                return linearise(c.ref, t=t, rel_step=rel_step, compiled=c)
    return linearise(ReferenceSystem(rs), t=t, rel_step=rel_step)


# ---- modes -------------------------------------------------------------------------------
def modes(lin, zero_tol=1e-6):
    """Modes of ``lin``: one per real eigenvalue and per complex pair (Im > 0), sorted by
    frequency. Each: ``eigenvalue``, ``f`` (Hz, 0 for a real one), ``zeta`` (damping ratio;
    1 for a real stable one), ``tau`` (s, 1/|Re| or None), ``kind`` (oscillatory, real,
    integrator), ``moves`` [(name, share of modal energy), ...] top 3 (a mode that moves no
    span or roller: [(its largest state, 1.0)]), ``mechanical`` (share of the unit
    eigenvector's squared norm on span tensions and roller speeds)."""
    if lin.A.size == 0:
        return []
    lam, V = np.linalg.eig(lin.A)
    big = max(1.0, float(np.max(np.abs(lam))))
    weights, labels = _energy_weights(lin)
    kinds = lin.info["state_kinds"]
    spans = [i for i, (_, m, s) in enumerate(kinds) if m == "Span"]
    filters = [i for i, (_, m, s) in enumerate(kinds) if m == "LoadCell"]
    out = []
    for k, l in enumerate(lam):
        if l.imag < -1e-9 * big:
            continue
        v = V[:, k]
        e = {}
        for i, (w, lab) in enumerate(zip(weights, labels)):
            if w > 0:
                e[lab] = e.get(lab, 0.0) + w * abs(v[i]) ** 2
        tot = sum(e.values())
        moves = sorted(((n, x / tot) for n, x in e.items()), key=lambda p: -p[1])[:3] if tot > 0 else []
        # share of the eigenvector (unit 2-norm, states in SI) on spans and rollers: a mode
        # of a controller or a load-cell filter barely moves the web
        mech = float(np.sum(np.abs(v[weights > 0]) ** 2) / max(1e-300, np.sum(np.abs(v) ** 2)))
        # a load-cell filter mode: the filter state (N) far above every span tension (N)
        span_v = max((abs(v[i]) for i in spans), default=0.0)
        lc_v = [(abs(v[i]), i) for i in filters]
        if mech < 1e-6 or (lc_v and max(lc_v)[0] > 3.0 * span_v):
            i = max(lc_v)[1] if lc_v and max(lc_v)[0] > 3.0 * span_v else int(np.argmax(np.abs(v)))
            moves = [(lin.states[i], 1.0)]
        a = abs(l)
        if a <= zero_tol * big:
            kind, zeta = "integrator", None
        elif abs(l.imag) <= 1e-9 * big:
            kind, zeta = "real", 1.0 if l.real < 0 else -1.0
        else:
            kind, zeta = "oscillatory", -l.real / a
        out.append({"eigenvalue": complex(l), "f": abs(l.imag) / (2 * math.pi), "zeta": zeta,
                    "tau": (1.0 / abs(l.real)) if l.real != 0 else None, "kind": kind,
                    "moves": [(n, float(s)) for n, s in moves], "mechanical": mech})
    out.sort(key=lambda m: (m["f"], -m["eigenvalue"].real))
    return out


def _energy_weights(lin):
    """Per kept state: (energy weight, label). Span tension L/EA, rotating speed J, motor J_m."""
    w, lab = [], []
    for (ci, model, s), name in zip(lin.info["state_kinds"], lin.states):
        comp = name.rsplit(".", 1)[0]
        if model == "Span" and s == "T":
            w.append(lin.info["span_weights"][comp])
            lab.append(comp)
        elif model in ROTATING_MODELS and s == "omega":
            w.append(lin.info["inertia"][comp][0])
            lab.append(comp)
        elif model in ROTATING_MODELS and s == "omega_motor":
            w.append(lin.info["inertia"][comp][1])
            lab.append(comp + ".motor")
        else:
            w.append(0.0)
            lab.append(name)
    return np.array(w), lab


# ---- element inputs ------------------------------------------------------------------------
def element_ends(system, element):
    """[(span-end input name, weight(f) callable)] for ``element``'s length change, per the
    layout's eccentricity convention: +1 on the up end of the span leaving it; on the down
    end of the span entering it -exp(i 2 pi f alpha/Omega) (the wrap alpha later in angle),
    or +1 for the rewind. At zero speed the wrap delay has no time equivalent: -1."""
    meta = system.meta
    el = meta["elements"].get(element)
    if el is None:
        raise KeyError(f"no element {element!r} (elements: {', '.join(meta['elements'])})")
    ends = []
    for s in meta["spans"]:
        if s["up"] == element:
            ends.append((f"{s['component']}.up", lambda f: np.ones_like(np.asarray(f, float), complex)))
        if s["down"] == element:
            if el["kind"] == "rewind":
                ends.append((f"{s['component']}.down", lambda f: np.ones_like(np.asarray(f, float), complex)))
            else:
                alpha, omega = float(el.get("wrap") or 0.0), float(el["omega0"])
                delay = alpha / omega if omega != 0.0 else 0.0
                ends.append((f"{s['component']}.down",
                             lambda f, d=delay: -np.exp(2j * math.pi * np.asarray(f, float) * d)))
    return ends


def element_transfer(lin, system, element, freqs):
    """Transfer function (p x len(freqs), complex, N/m) from ``element``'s span-length change
    (the series of its ``eccentricity``) to every load cell."""
    freqs = np.atleast_1d(np.asarray(freqs, float))
    ends = element_ends(system, element)
    G = lin.transfer(freqs, [n for n, _ in ends])  # (F, p, e)
    W = np.column_stack([w(freqs) for _, w in ends])  # (F, e)
    return np.einsum("fpe,fe->pf", G, W)


def harmonic_gains(system, element, freqs, lin=None):
    """{load-cell column: complex gain per frequency (N/m)} of ``element``'s eccentricity.

    In the diagnosis's convention (diagnosis/estimate.py): a length series
    ``C_j sin(j theta + psi_j)`` on ``element`` (X_j = C_j exp(i psi_j)) makes the load
    cell's harmonic ``Y_j = G_j X_j`` (y = sum Im(Y_j exp(i j theta))), with G_j this
    function's value at f_j = j Omega/(2 pi). ``lin``: a :func:`linearise_system` of
    ``system`` to reuse (else computed)."""
    lin = linearise_system(system) if lin is None else lin
    G = element_transfer(lin, system, element, freqs)
    return {col: G[k] for k, col in enumerate(lin.outputs)}


def torque_transfer(lin, element, freqs):
    """Transfer function (p x len(freqs), N/(N.m)) from ``element``'s motor torque to the load cells."""
    G = lin.transfer(np.atleast_1d(freqs), [f"{element}.tau"])
    return G[:, :, 0].T


def transfer_functions(lin, system, freqs):
    """{input name: (p x F) complex}: every rotating element's span-length change (N/m),
    then every drive torque (N/(N.m))."""
    out = {}
    for name, el in system.meta["elements"].items():
        out[f"{name}.dL"] = element_transfer(lin, system, name, freqs)
    for info in lin.info["inputs"]:
        if info["kind"] == "torque":
            out[f"{info['element']}.tau"] = torque_transfer(lin, info["element"], freqs)
    return out
