"""Fast engine: the monolithic ODE of a System, generated as straight-line code and compiled.

The monolithic reference (:mod:`orchestrator.reference`) calls every model's
Python ``outputs``/``derivatives`` through lists at each right-hand-side
evaluation. This module builds the same :class:`~orchestrator.reference.ReferenceSystem`
(every FMU class instantiated in-process: models, parameters, start values,
connections) and from it writes the source of one scalar function for the whole
line::

    rhs(t, x, p, dx)        # dx/dt of all states
    outputs(t, x, p, y)     # every output, in the order of ``columns``
    check(t, x, p) -> int   # 0, or 1 + index of a material roll that ran empty

which calls ``numba.njit`` versions of the plain physics functions of
:mod:`webline.physics` (so the formulas are the models' own, not rewritten); the
per-model glue below mirrors each model class's ``outputs``/``derivatives``.
An output is computed where an input first needs it (demand-driven, so no
feed-through declaration can be stale); an input no connection feeds is its start
value. Every number lives in the float64 vector ``p``: variants of one structure
(model types, states, connections, drive/filter/Fourier options) share the
compiled code, which is cached per generated source in this process (and by numba
on disk, keyed by that source's hash).

Integration: classical fixed-step RK4 inside numba, from one output time to the
next (the step divides each interval exactly, so no interpolation), restarting at
every Profile knot (a kink or step in an input; the last stage before a knot is
evaluated just before it, on the old side of a step, as a co-simulation master holds
an input over its step). The step is ``min(h_max, c / |lambda|)`` over the eigenvalues
of the Jacobian at the start (finite differences of the compiled rhs), c = 0.5 for
the modes that oscillate or grow: RK4's relative error per step on a mode of rate
lambda is about (lambda h)^5/120, 2.6e-4 at the stiffest such mode and far below for
the slow modes that carry the tension signal. A real decaying mode (a current-loop
lag, a fast filter) needs stability only, c = 2 (:func:`step_for`). Load-cell noise
(``LoadCellModel.noise``, deterministic in (seed, t)) is added to the recorded
outputs at the sample times exactly as the reference does; inside the dynamics
(where a load cell feeds a tension loop) it is held from one output time to the
next, as the co-simulation master holds it over a step.

API: :func:`compile_system` -> :class:`Compiled`; :func:`simulate` ->
:class:`~orchestrator.results.Result` (columns ``<component>.<variable>``, meta kind
``"engine"``); :func:`simulate_batch` for variants of one structure (one compiled
``integrate``, which releases the GIL, a variant per thread).
"""
import hashlib
import importlib.util
import math
import os
import sys
import time as _time
import types
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

H_MAX = 1.0e-3          # s: longest RK4 step
STEP_FACTOR = 0.5       # h <= STEP_FACTOR / |lambda| for a mode that oscillates or grows (RK4 accuracy)
STEP_FACTOR_DECAY = 2.0  # h <= this / |lambda| for a decaying real mode (RK4 stability; see the module docstring)
DECAY_SLOPE = 0.2       # a mode counts as decaying real when |Im lambda| <= this x -Re lambda
KNOT_SHIFT = 2.0e-9     # s: last stage before a Profile knot is evaluated this much early (> TIME_TOLERANCE)


class EngineError(ValueError):
    """The system cannot be compiled (an algebraic loop, a model the engine does not know)."""


# ---- numba versions of the physics functions ---------------------------------------------
_NB = None


def _jit(fn, **deps):
    """``numba.njit`` of a physics function; ``deps`` rebinds the plain functions it calls
    (numba must see their compiled versions) without touching the physics module."""
    import numba
    if deps:
        g = dict(fn.__globals__)
        g.update(deps)
        fn = types.FunctionType(fn.__code__, g, fn.__name__, fn.__defaults__, fn.__closure__)
    return numba.njit(cache=False)(fn)


def _bisect_right(a, x):
    """``bisect.bisect_right`` for the profile functions: numba has no ``bisect``."""
    return np.searchsorted(a, x, side="right")


def _splitmix64(z):
    z = z + np.uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


def _standard_normal(seed, t):
    """:func:`webline.physics.load_cell.standard_normal` in uint64 arithmetic (wraps mod 2^64
    as the Python version masks)."""
    k = np.int64(np.rint(t / NOISE_TIME_RESOLUTION))
    a = _splitmix64(_splitmix64(np.uint64(seed)) ^ np.uint64(k))
    b = _splitmix64(a)
    u1 = np.float64((a >> np.uint64(11)) + np.uint64(1)) * 2.0 ** -53
    u2 = np.float64(b >> np.uint64(11)) * 2.0 ** -53
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)


NOISE_TIME_RESOLUTION = None


def nb():
    """Namespace of the compiled physics functions (built once)."""
    global _NB, NOISE_TIME_RESOLUTION
    if _NB is not None:
        return _NB
    from webline.physics import (controllers, drive, eccentricity, load_cell, material_roll, profile,
                                 roller, span)
    NOISE_TIME_RESOLUTION = load_cell.NOISE_TIME_RESOLUTION
    f = {}
    f["tension_rate"] = _jit(span.tension_rate)
    f["kelvin_voigt_tension"] = _jit(span.kelvin_voigt_tension)
    f["length_terms"] = _jit(eccentricity.length_terms)
    f["roller_acceleration"] = _jit(roller.roller_acceleration)
    f["wound_inertia"] = _jit(material_roll.wound_inertia)
    f["inertia"] = _jit(material_roll.inertia, wound_inertia=f["wound_inertia"])
    f["radius_rate"] = _jit(material_roll.radius_rate)
    f["unwind_acceleration"] = _jit(material_roll.unwind_acceleration)
    f["rewind_acceleration"] = _jit(material_roll.rewind_acceleration)
    f["dead_zone"] = _jit(drive.dead_zone)
    f["shaft_torque"] = _jit(drive.shaft_torque, dead_zone=f["dead_zone"])
    f["motor_acceleration"] = _jit(drive.motor_acceleration)
    f["pi_output"] = _jit(controllers.pi_output)
    f["integral_rate"] = _jit(controllers.integral_rate)
    f["acceleration_feedforward"] = _jit(controllers.acceleration_feedforward)
    f["current_lag_rate"] = _jit(controllers.current_lag_rate)
    f["measured_tension"] = _jit(load_cell.measured_tension)
    f["first_order_filter_rate"] = _jit(load_cell.first_order_filter_rate)
    f["second_order_filter_rates"] = _jit(load_cell.second_order_filter_rates)
    bisect_right = _jit(_bisect_right)
    f["profile_value"] = _jit(profile.profile_value, bisect_right=bisect_right)
    f["profile_slope"] = _jit(profile.profile_slope, bisect_right=bisect_right)
    sm = _jit(_splitmix64)
    f["standard_normal"] = _jit(_standard_normal, _splitmix64=sm, NOISE_TIME_RESOLUTION=NOISE_TIME_RESOLUTION)
    _NB = f
    return f


# ---- code generation ---------------------------------------------------------------------
class _Body:
    """Lines of one generated function; which outputs and temporaries it has defined."""

    def __init__(self):
        self.lines = []
        self.defined = set()
        self.busy = set()

    def emit(self, line):
        self.lines.append("    " + line)

    def let(self, name, expr):
        if name not in self.defined:
            self.emit(f"{name} = {expr}")
            self.defined.add(name)
        return name


class _Builder:
    """Parameter vector, inputs and per-model generators of one ReferenceSystem."""

    def __init__(self, ref):
        self.ref = ref
        self.p = []
        self.pnames = []
        self.pindex = {}
        self.arrays = []   # (start slot, stop slot, names, values): placed after the scalars
        self.feeder = {(d, ref.models[d].INPUTS[i]): (s, ref.models[s].OUTPUTS[o]) for s, o, d, i in ref.routes}
        self.gens = []
        for ci, (comp, model) in enumerate(zip(ref.system.components, ref.models)):
            cls = GENERATORS.get(comp.model)
            if cls is None:
                raise EngineError(f"component {comp.name!r}: the fast engine has no code for model {comp.model!r} "
                                  f"(known: {', '.join(sorted(GENERATORS))})")
            self.gens.append(cls(self, ci, comp, model, ref.offsets[ci][0]))
        # held Gaussian sources (load-cell noise, drive torque ripple): (slot, seed, std)
        self.noise = [(g.noise_slot, int(g.m.seed), float(g.noise_std)) for g in self.gens
                      if getattr(g, "noise_slot", None) is not None and g.noise_std != 0.0]

    def param(self, ci, name, value):
        key = (ci, name)
        if key not in self.pindex:
            self.pindex[key] = len(self.p)
            self.p.append(float(value))
            self.pnames.append(f"{self.ref.names[ci]}.{name}")
        return self.pindex[key]

    def param_array(self, ci, name, values):
        """An array parameter: two scalar slots hold where it starts and stops in ``p``,
        and the values go after every scalar (:meth:`_place_arrays`). The source then
        holds no array's length: lines whose profiles have other knots, or whose roll
        carries other harmonics, share one compiled code (numba compiles a structure
        in about 4 s, and a diagnosis runs each of its forms on runs with ramps and
        without)."""
        a, b = self.param(ci, f"{name}:start", 0.0), self.param(ci, f"{name}:stop", 0.0)
        if not any(x[0] == a for x in self.arrays):
            self.arrays.append((a, b, [f"{self.ref.names[ci]}.{name}[{k + 1}]" for k in range(len(values))],
                                [float(v) for v in values]))
        return a, b

    def _place_arrays(self):
        for a, b, names, values in self.arrays:
            self.p[a] = float(len(self.p))
            self.p.extend(values)
            self.pnames.extend(names)
            self.p[b] = float(len(self.p))
        self.arrays = []

    def output(self, body, ci, name):
        """Variable holding output ``name`` of component ``ci`` (generated on demand)."""
        var = f"y{ci}_{name}"
        if var in body.defined:
            return var
        if (ci, name) in body.busy:
            raise EngineError(f"algebraic loop through {self.ref.names[ci]}.{name}")
        body.busy.add((ci, name))
        expr = self.gens[ci].output(body, name)
        body.busy.discard((ci, name))
        return body.let(var, expr)

    def input(self, body, ci, name):
        src = self.feeder.get((ci, name))
        if src is not None:
            return self.output(body, *src)
        model = self.ref.models[ci]
        return f"p[{self.param(ci, 'u:' + name, self.ref.u[ci][model.INPUTS.index(name)])}]"

    def source(self):
        """``evaluate(t, x, p, dx, y, want_y)``: dx/dt always, every output into ``y`` when
        ``want_y`` (one function, so the compiler optimises the line once); ``check``."""
        ref = self.ref
        nx = len(ref.x0)
        body = _Body()
        for g in self.gens:
            if g.nx:
                ds = g.derivatives(body)
                if len(ds) != g.nx:
                    raise EngineError(f"{g.name}: {len(ds)} derivatives for {g.nx} states")
                for i, d in enumerate(ds):
                    body.emit(f"dx[{g.off + i}] = {d}")
        n_rhs = len(body.lines)
        j = 0
        for ci, model in enumerate(ref.models):
            for o in model.OUTPUTS:
                body.emit(f"y[{j}] = {self.output(body, ci, o)}")
                j += 1
        outs = ["    " + line for line in body.lines[n_rhs:]]
        chk = _Body()
        for g in self.gens:
            cond = g.empty_condition()
            if cond:
                chk.emit(f"if {cond}:")
                chk.emit(f"    return {g.ci + 1}")
        head = "# generated by webline.orchestrator.engine: %d states, %d scalar parameters\n" % (nx, len(self.p))
        self._place_arrays()
        src = [head, "def evaluate(t, x, p, dx, y, want_y):", *body.lines[:n_rhs],
               "    if want_y:", *(outs or ["        pass"]), "",
               "def check(t, x, p):", *chk.lines, "    return 0", ""]
        return "\n".join(src)


class _Gen:
    """Code of one component: ``output(body, name)`` -> expression, ``derivatives(body)`` ->
    expressions in STATES order, ``empty_condition()`` -> a failure test or ''."""

    def __init__(self, b, ci, comp, model, off):
        self.b, self.ci, self.comp, self.m, self.off = b, ci, comp, model, off
        self.name = comp.name
        self.nx = len(model.STATES)
        self.setup()

    def setup(self):
        pass

    def P(self, name, value):
        return f"p[{self.b.param(self.ci, name, value)}]"

    def Parray(self, name, values):
        a, b = self.b.param_array(self.ci, name, values)
        return f"p[int(p[{a}]):int(p[{b}])]"

    def u(self, body, name):
        return self.b.input(body, self.ci, name)

    def x(self, i):
        return f"x[{self.off + i}]"

    def tmp(self, body, name, expr_fn):
        var = f"c{self.ci}_{name}"
        if var not in body.defined:
            body.let(var, expr_fn())
        return var

    def derivatives(self, body):
        return []

    def empty_condition(self):
        return ""

    def output(self, body, name):
        raise EngineError(f"{self.name}: no output {name!r}")


class _Profile(_Gen):
    def setup(self):
        m = self.m
        self.knots = [float(t) for t in m.t]
        self.ts = self.Parray("t", m.t)
        self.ys = self.Parray("y", m.y)

    def output(self, body, name):
        if name == "y":
            return f"profile_value({self.ts}, {self.ys}, t)"
        if name == "dy":
            return f"profile_slope({self.ts}, {self.ys}, t)"
        return super().output(body, name)


class _LoadCell(_Gen):
    def setup(self):
        m = self.m
        self.w_in, self.w_out = self.P("w_in", m.w_in), self.P("w_out", m.w_out)
        if self.nx == 1:
            self.tau = self.P("tau_filter", m.tau_filter)
        elif self.nx == 2:
            self.w_c = self.P("w_c", getattr(m, "w_c", 1.0 / m.tau_filter))
            self.zeta = self.P("filter_damping", getattr(m, "filter_damping", 0.707))
        self.noise_std = m.noise_std
        self.noise_slot = self.b.param(self.ci, "noise", 0.0) if m.noise_std != 0.0 else None

    def reading(self, body):
        return self.tmp(body, "reading", lambda: f"measured_tension({self.u(body, 'T_in')}, "
                                                 f"{self.u(body, 'T_out')}, {self.w_in}, {self.w_out})")

    def output(self, body, name):
        if name != "T":
            return super().output(body, name)
        y = self.x(0) if self.nx else self.reading(body)
        return f"{y} + p[{self.noise_slot}]" if self.noise_slot is not None else y

    def derivatives(self, body):
        r = self.reading(body)
        if self.nx == 1:
            return [f"first_order_filter_rate({self.x(0)}, {r}, {self.tau})"]
        rates = self.tmp(body, "rates", lambda: f"second_order_filter_rates({self.x(0)}, {self.x(1)}, {r}, "
                                                f"{self.w_c}, {self.zeta})")
        return [f"{rates}[0]", f"{rates}[1]"]


class _TensionPI(_Gen):
    def setup(self):
        m = self.m
        self.K, self.w_i, self.sign = self.P("K", m.K), self.P("w_i", m.w_i), self.P("sign", m.sign)
        self.lo, self.hi = self.P("trim_min", m.trim_min), self.P("trim_max", m.trim_max)

    def law(self, body):
        e = self.tmp(body, "e", lambda: f"{self.u(body, 'T_ref')} - {self.u(body, 'T_meas')}")
        return e, self.tmp(body, "pi", lambda: f"pi_output({self.sign} * {self.K}, {self.w_i}, {e}, {self.x(0)}, "
                                               f"0.0, {self.lo}, {self.hi})")

    def output(self, body, name):
        if name == "v_trim":
            return f"{self.law(body)[1]}[0]"
        return super().output(body, name)

    def derivatives(self, body):
        e, pi = self.law(body)
        return [f"integral_rate({e}, {pi}[1], {self.lo}, {self.hi}, {self.sign})"]


class _SpeedPI(_Gen):
    def setup(self):
        m = self.m
        self.K_ref, self.w_ld = self.P("K_ref", m.K_ref), self.P("w_ld", m.w_ld)
        self.lo, self.hi = self.P("tau_min", m.tau_min), self.P("tau_max", m.tau_max)
        self.ff = bool(m.feedforward)
        if self.ff:
            self.b_ff = self.P("b_ff", m.b_ff)
        self.acc_ff = bool(getattr(m, "acc_ff", False))
        self.lag = bool(getattr(m, "lag", False))
        if self.lag:
            self.tau_current = self.P("tau_current", m.tau_current)
        # the slot is there with or without ripple: a line with ripple on a drive has the same
        # structure as without (one compiled code; the diagnosis probes each drive in turn)
        self.noise_std = getattr(m, "torque_noise", 0.0)
        self.noise_slot = self.b.param(self.ci, "noise", 0.0)

    def omega_ref(self, body):
        return self.tmp(body, "omega_ref", lambda: f"({self.u(body, 'v_ref')} + {self.u(body, 'v_trim')}) / "
                                                   f"{self.u(body, 'R')}")

    def law(self, body):
        """(error, pi tuple (tau command, unsaturated))."""
        w_ref = self.omega_ref(body)
        omega = self.u(body, "omega")
        e = self.tmp(body, "e", lambda: f"{w_ref} - {omega}")
        R, J = self.u(body, "R"), self.u(body, "J")
        terms = []
        if self.ff:
            terms.append(f"{R} * ({self.u(body, 'T_in')} - {self.u(body, 'T_out')}) + {self.b_ff} * {omega}")
        if self.acc_ff:
            terms.append(f"acceleration_feedforward({J}, {self.u(body, 'a_ref')}, {R})")
        ff = " + ".join(f"({t})" for t in terms) if terms else "0.0"
        pi = self.tmp(body, "pi", lambda: f"pi_output({J} * {self.K_ref}, {self.w_ld}, {e}, {self.x(0)}, {ff}, "
                                          f"{self.lo}, {self.hi})")
        return e, pi

    def output(self, body, name):
        if name == "omega_ref":
            return self.omega_ref(body)
        if name == "tau":
            tau = self.x(1) if self.lag else f"{self.law(body)[1]}[0]"
            return f"{tau} + p[{self.noise_slot}]"
        return super().output(body, name)

    def derivatives(self, body):
        e, pi = self.law(body)
        d = [f"integral_rate({e}, {pi}[1], {self.lo}, {self.hi})"]
        if self.lag:
            d.append(f"current_lag_rate({self.x(1)}, {pi}[0], {self.tau_current})")
        return d


class _Span(_Gen):
    def setup(self):
        m = self.m
        self.EA, self.L0 = self.P("EA", m.EA), self.P("L0", m.L0)
        self.mode = m.length_mode
        self.ecc_up = self.mode != 1 and not m.round_up
        self.ecc_dn = self.mode != 1 and not m.round_down
        # the series in sine-cosine form (eccentricity.length_terms): no trigonometry of the phases per step
        if self.ecc_up:
            self.a_up, self.b_up = (self.Parray(n, v) for n, v in zip(("a_up", "b_up"), m.ab_up))
        if self.ecc_dn:
            self.a_dn, self.b_dn = (self.Parray(n, v) for n, v in zip(("a_down", "b_down"), m.ab_down))
        if self.mode == 2:
            self.f_fixed = self.P("f_fixed", m.f_fixed)
        self.damping = getattr(m, "damping_time", 0.0) != 0.0
        if self.damping:
            self.d = self.P("damping_time", m.damping_time)

    def length(self, body):
        """(L, dL_up/dt, dL_down/dt) variables, as SpanModel.length."""
        if self.mode == 1:
            return self.u(body, "L_ext"), "0.0", self.u(body, "dL_ext")
        L, up, dn = [self.L0], "0.0", "0.0"
        if self.ecc_up:
            if self.mode == 2:
                w = self.tmp(body, "w_up", lambda: f"2.0 * math.pi * {self.f_fixed}")
                th = self.tmp(body, "th_up", lambda: f"{w} * t")
            else:
                th, w = self.u(body, "theta_up"), self.u(body, "omega_up")
            ecc = self.tmp(body, "ecc_up", lambda: f"length_terms({th}, {w}, {self.a_up}, {self.b_up})")
            L.append(self.tmp(body, "L_up", lambda: f"{ecc}[0]"))
            up = self.tmp(body, "dL_up", lambda: f"{ecc}[1]")
        if self.ecc_dn:
            th, w = self.u(body, "theta_down"), self.u(body, "omega_down")
            ecc = self.tmp(body, "ecc_dn", lambda: f"length_terms({th}, {w}, {self.a_dn}, {self.b_dn})")
            L.append(self.tmp(body, "L_dn", lambda: f"{ecc}[0]"))
            dn = self.tmp(body, "dL_dn", lambda: f"{ecc}[1]")
        return self.tmp(body, "L", lambda: " + ".join(L)), up, dn

    def rate(self, body):
        def expr():
            L, up, dn = self.length(body)
            return (f"tension_rate({self.x(0)}, {self.u(body, 'T_in')}, {self.u(body, 'v_in')}, "
                    f"{self.u(body, 'v_out')}, {self.EA}, {L}, {up}, {dn})")
        return self.tmp(body, "rate", expr)

    def output(self, body, name):
        if name == "T":
            if self.damping:
                return f"kelvin_voigt_tension({self.x(0)}, {self.rate(body)}, {self.d})"
            return self.x(0)
        if name == "L":
            return self.length(body)[0]
        if name == "dL":
            _, up, dn = self.length(body)
            return f"{up} + {dn}"
        if name == "dT":
            return self.rate(body)
        return super().output(body, name)

    def derivatives(self, body):
        return [self.rate(body)]


class _DriveMixin:
    """The optional non-ideal drive (webline.physics.drive.Drive) of a roller or roll."""

    def drive_setup(self, n_element_states):
        d = self.m.drive
        self.drive = d.enabled
        self.nd = n_element_states  # index of theta_motor among the states
        if self.drive:
            self.J_motor, self.k = self.P("J_motor", d.J_motor), self.P("stiffness", d.stiffness)
            self.c, self.backlash = self.P("damping", d.damping), self.P("backlash", d.backlash)

    def element_torque(self, body, theta, omega):
        tau = self.u(body, "tau")
        if not self.drive:
            return tau
        th_m, w_m = self.x(self.nd), self.x(self.nd + 1)
        return self.tmp(body, "ts", lambda: f"shaft_torque({th_m} - {theta}, {w_m} - {omega}, {self.k}, "
                                            f"{self.c}, {self.backlash})")

    def drive_derivatives(self, body, theta, omega):
        if not self.drive:
            return []
        ts = self.element_torque(body, theta, omega)
        return [self.x(self.nd + 1), f"motor_acceleration({self.u(body, 'tau')}, {ts}, {self.J_motor})"]


class _IdleRoller(_Gen):
    def setup(self):
        m = self.m
        self.R, self.J, self.bf = self.P("R", m.R), self.P("J", m.J), self.P("b", m.b)

    def acc(self, body):
        return self.tmp(body, "acc", lambda: f"roller_acceleration({self.x(0)}, {self.R}, {self.u(body, 'T_in')}, "
                                             f"{self.u(body, 'T_out')}, 0.0, {self.J}, {self.bf})")

    def output(self, body, name):
        if name == "omega":
            return self.x(0)
        if name == "theta":
            return self.x(1)
        if name == "v":
            return f"{self.R} * {self.x(0)}"
        if name == "a":
            return f"{self.R} * {self.acc(body)}"
        return super().output(body, name)

    def derivatives(self, body):
        return [self.acc(body), self.x(0)]


class _DrivenRoller(_DriveMixin, _IdleRoller):
    def setup(self):
        super().setup()
        self.drive_setup(2)

    def acc(self, body):
        def expr():
            tau = self.element_torque(body, self.x(1), self.x(0))
            return (f"roller_acceleration({self.x(0)}, {self.R}, {self.u(body, 'T_in')}, {self.u(body, 'T_out')}, "
                    f"{tau}, {self.J}, {self.bf})")
        return self.tmp(body, "acc", expr)

    def output(self, body, name):
        if name == "omega_motor":
            return self.x(3) if self.drive else self.x(0)
        return super().output(body, name)

    def derivatives(self, body):
        return super().derivatives(body) + self.drive_derivatives(body, self.x(1), self.x(0))


class _MaterialRoll(_DriveMixin, _Gen):
    WINDING = 0
    TENSION = ""
    ACCELERATION = ""

    def setup(self):
        m = self.m
        self.R_core, self.tw = self.P("R_core", m.R_core), self.P("thickness", m.thickness)
        self.width, self.rho = self.P("width", m.width), self.P("rho", m.rho)
        self.J_core, self.bf = self.P("J_core", m.J_core), self.P("b", m.b)
        self.drive_setup(3)

    def J_roll(self, body):
        return self.tmp(body, "J", lambda: f"inertia({self.x(2)}, {self.R_core}, {self.rho}, {self.width}, "
                                           f"{self.J_core})")

    def dR(self, body):
        return self.tmp(body, "dR", lambda: f"radius_rate({self.x(0)}, {self.tw}, {float(self.WINDING)})")

    def acc(self, body):
        def expr():
            tau = self.element_torque(body, self.x(1), self.x(0))
            return (f"{self.ACCELERATION}({self.x(0)}, {self.x(2)}, {self.u(body, self.TENSION)}, {tau}, "
                    f"{self.J_roll(body)}, {self.bf}, {self.rho}, {self.width}, {self.tw})")
        return self.tmp(body, "acc", expr)

    def output(self, body, name):
        w, R = self.x(0), self.x(2)
        if name == "omega":
            return w
        if name == "theta":
            return self.x(1)
        if name == "R":
            return R
        if name == "v":
            return f"{R} * {w}"
        if name == "J":
            return f"{self.J_roll(body)} + {self.J_motor}" if self.drive else self.J_roll(body)
        if name == "omega_motor":
            return self.x(4) if self.drive else w
        if name == "a":
            return f"{R} * {self.acc(body)} + {w} * {self.dR(body)}"
        return super().output(body, name)

    def derivatives(self, body):
        return [self.acc(body), self.x(0), self.dR(body)] + self.drive_derivatives(body, self.x(1), self.x(0))


class _UnwindRoll(_MaterialRoll):
    WINDING, TENSION, ACCELERATION = -1, "T_out", "unwind_acceleration"

    def empty_condition(self):
        return f"not {self.x(2)} > {self.R_core}"


class _RewindRoll(_MaterialRoll):
    WINDING, TENSION, ACCELERATION = 1, "T_in", "rewind_acceleration"

    def empty_condition(self):
        return f"{self.x(2)} < {self.R_core}"


GENERATORS = {"Profile": _Profile, "LoadCell": _LoadCell, "TensionPI": _TensionPI, "SpeedPI": _SpeedPI,
              "Span": _Span, "IdleRoller": _IdleRoller, "DrivenRoller": _DrivenRoller,
              "UnwindRoll": _UnwindRoll, "RewindRoll": _RewindRoll,
              "DampedSpan": _Span}  # the Kelvin-Voigt span of the model forms (SpanModel with damping_time)


# ---- the integrator (compiled with each generated module) --------------------------------
_INTEGRATOR = '''
def integrate(x0, p, events, rows, shifts, h_target, nz_slot, nz_seed, nz_std, Y, X):
    """RK4 from events[0] through every event; at event e set the held noise and record
    row rows[e] (if >= 0) from the first stage of the following step. Returns (status,
    event index): 0 ok, -1 non-finite state, k > 0 component k-1 failed its check.
    ``evaluate`` is called from one place only (the compiler inlines it once)."""
    n = x0.size
    x = x0.copy()
    K = np.empty((4, n))
    xt = np.empty(n)
    ydummy = np.empty(Y.shape[1])
    ne = events.size
    for e in range(ne):
        t = events[e]
        for j in range(nz_slot.size):
            p[nz_slot[j]] = nz_std[j] * standard_normal(nz_seed[j], t)
        r = rows[e]
        if r >= 0:
            for j in range(n):  # a loop: slice assignment costs seconds of compile time
                X[r, j] = x[j]
        last = e == ne - 1
        m = 1
        h = 0.0
        b = t
        if not last:
            b = events[e + 1]
            m = int(math.ceil((b - t) / h_target - 1e-9))
            if m < 1:
                m = 1
            h = (b - t) / m
        for i in range(m):
            ti = t + i * h
            for s in range(4):
                if s == 0:
                    ts = ti
                    for j in range(n):
                        xt[j] = x[j]
                elif s < 3:
                    ts = ti + 0.5 * h
                    for j in range(n):
                        xt[j] = x[j] + 0.5 * h * K[s - 1, j]
                else:
                    ts = b + shifts[e + 1] if i == m - 1 else ti + h
                    for j in range(n):
                        xt[j] = x[j] + h * K[2, j]
                want = s == 0 and i == 0 and r >= 0
                evaluate(ts, xt, p, K[s], Y[r] if want else ydummy, want)
                if last:
                    break
            if last:
                break
            for j in range(n):
                x[j] += h / 6.0 * (K[0, j] + 2.0 * (K[1, j] + K[2, j]) + K[3, j])
        if last:
            break
        for j in range(n):
            if not math.isfinite(x[j]):
                return -1, e + 1
        c = check(b, x, p)
        if c != 0:
            return c, e + 1
    return 0, ne - 1
'''

_MODULES = {}


def _cache_dir():
    base = os.environ.get("WEBLINE_ENGINE_CACHE")
    if base:
        return Path(base)
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "webline" / "engine"


def _physics_hash():
    """Hash of the physics sources and this file: a change invalidates numba's disk cache."""
    import webline.physics as ph
    h = hashlib.sha256()
    for f in sorted(Path(ph.__file__).parent.glob("*.py")) + [Path(__file__)]:
        h.update(f.read_bytes())
    return h.hexdigest()[:16]


def _load(source):
    """Compiled functions of a generated source (module in this process, numba's cache on disk)."""
    mod = _MODULES.get(source)
    if mod is not None:
        return mod
    import numba
    full = source + _INTEGRATOR
    key = hashlib.sha256((full + _physics_hash()).encode()).hexdigest()[:24]
    name = f"webline_engine_{key}"
    folder = _cache_dir()
    path = None
    try:
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / f"{name}.py"
        if not path.exists():
            tmp = path.with_suffix(f".{os.getpid()}.tmp")
            tmp.write_text(full)
            os.replace(tmp, path)
    except OSError:
        path = None
    if path is not None:
        mod = types.ModuleType(name)
        mod.__file__ = str(path)
    else:
        mod = types.ModuleType(name)
    mod.__dict__.update(nb())
    mod.__dict__.update(math=math, np=np, numba=numba)
    code = compile(full, str(path) if path else f"<{name}>", "exec")
    exec(code, mod.__dict__)
    # numba's disk cache needs a file it can stat; without one, compile in memory
    cache = path is not None
    sys.modules[name] = mod
    for fname in ("evaluate", "check"):
        setattr(mod, fname, numba.njit(cache=cache)(getattr(mod, fname)))
    # nogil: a batch runs its variants on threads (_run_batch) instead of a parallel (parfor)
    # copy of ``integrate``, whose compile cost a third of a new structure's
    mod.integrate = numba.njit(cache=cache, nogil=True)(mod.integrate)
    _MODULES[source] = mod
    return mod


# ---- compiled system ---------------------------------------------------------------------
class Compiled:
    """A System compiled for the fast engine.

    ``x0``, ``state_names``, ``columns`` (as the reference), ``p`` (parameter vector of this
    system; ``pnames`` names its entries), ``source`` (the generated code),
    ``rhs_numpy(t, x)`` / ``outputs_numpy(t, x)`` call the compiled functions,
    ``breakpoints()`` the Profile knots. ``structure`` is the source: systems with equal
    structure share the compiled code (``simulate_batch``)."""

    def __init__(self, system):
        from webline.orchestrator.reference import ReferenceSystem
        t = _time.perf_counter()
        self.system = system
        self.ref = ReferenceSystem(system, reuse=True)  # read only: slaves of equal components are shared
        b = _Builder(self.ref)
        self.source = b.source()
        self.p = np.array(b.p, dtype=float)
        self.pnames = list(b.pnames)
        self.noise = b.noise
        self.knots = sorted({k for g in b.gens if isinstance(g, _Profile) for k in g.knots})
        self.x0 = self.ref.x0.copy()
        self.state_names = list(self.ref.state_names)
        self.columns = list(self.ref.columns)
        self._ydummy = np.zeros(len(self.columns))
        self.setup_s = _time.perf_counter() - t
        t = _time.perf_counter()
        self.module = _load(self.source)
        self.load_s = _time.perf_counter() - t

    @property
    def structure(self):
        return self.source

    def rhs_numpy(self, t, x, p=None):
        """dx/dt at (t, x) (``p``: default this system's parameters)."""
        dx = np.zeros(self.x0.size)
        self.module.evaluate(float(t), np.ascontiguousarray(x, dtype=float), self.p if p is None else p, dx,
                             self._ydummy, False)
        return dx

    def outputs_numpy(self, t, x, p=None):
        """Every output (``columns`` order) at (t, x); load-cell noise as held in ``p``."""
        y = np.zeros(len(self.columns))
        self.module.evaluate(float(t), np.ascontiguousarray(x, dtype=float), self.p if p is None else p,
                             np.zeros(self.x0.size), y, True)
        return y

    def jacobian(self, t=None, x=None, p=None):
        """d rhs/dx by central differences (step 1e-6 max(1, |x|))."""
        t = float(self.system.experiment.start if t is None else t)
        x = self.x0 if x is None else np.asarray(x, float)
        n = x.size
        J = np.zeros((n, n))
        for i in range(n):
            d = 1e-6 * max(1.0, abs(x[i]))
            xp, xm = x.copy(), x.copy()
            xp[i] += d
            xm[i] -= d
            J[:, i] = (self.rhs_numpy(t, xp, p) - self.rhs_numpy(t, xm, p)) / (2 * d)
        return J

    def step(self, p=None, h_max=H_MAX, factor=STEP_FACTOR, decay=STEP_FACTOR_DECAY):
        """RK4 step for this system from the eigenvalues of the Jacobian at x0:
        ``min(h_max, factor / |lambda|)`` over the modes that oscillate or grow, and
        ``decay / |lambda|`` over the real decaying ones (:func:`step_for`)."""
        if not self.x0.size:
            return h_max
        J = self.jacobian(p=p)
        if not np.all(np.isfinite(J)):
            raise ValueError("the right-hand side is not finite at the initial state")
        return step_for(np.linalg.eigvals(J), h_max, factor, decay)


def step_for(eigenvalues, h_max=H_MAX, factor=STEP_FACTOR, decay=STEP_FACTOR_DECAY):
    """The RK4 step for modes of rates ``eigenvalues``. A mode that oscillates or grows
    carries the signal: its error per step, about (lambda h)^5/120, sets the step.
    A real mode that decays (|Im| <= :data:`DECAY_SLOPE` x -Re; a drive's current lag,
    a fast filter) is slaved to its inputs once its transient has gone: the step
    needs only keep it stable (RK4's real-axis limit is 2.785; at lambda h = -2 a
    step damps it to a third), and its forced response stays accurate, because a
    slowly varying input is followed to RK4's order in the input's rate, not the mode's
    (seed-43 c04's refined line, a 0.43 ms lag: h 0.86 ms instead of the 0.215 ms the
    spectral radius gave, lc19 within 1.5e-5 N RMS of h = 0.1 ms on a 3.2 N signal)."""
    lam = np.asarray(eigenvalues, dtype=complex)
    lam = lam[np.abs(lam) > 0]
    if not lam.size:
        return h_max
    real = (lam.real < 0) & (np.abs(lam.imag) <= DECAY_SLOPE * -lam.real)
    limits = np.where(real, decay, factor) / np.abs(lam)
    return float(min(h_max, np.min(limits)))


def compile_system(system):
    """:class:`Compiled` of ``system``: its generated code is compiled once per structure
    (in this process; numba's cache on disk, ``WEBLINE_ENGINE_CACHE`` or
    ``~/.cache/webline/engine``, keeps it across processes)."""
    return Compiled(system)


# ---- simulation --------------------------------------------------------------------------
def _events(compiled, t_eval, t0):
    t_eval = np.asarray(t_eval, dtype=float)
    if t_eval.ndim != 1 or t_eval.size == 0:
        raise ValueError("t_eval must be a non-empty 1-D array of times")
    if np.any(np.diff(t_eval) <= 0):
        raise ValueError("t_eval must be strictly increasing")
    if t_eval[0] < t0 - 1e-12:
        raise ValueError(f"t_eval starts at {t_eval[0]:g} s, before the experiment's start {t0:g} s")
    t_end = t_eval[-1]
    knots = np.array([k for k in compiled.knots if t0 < k < t_end], dtype=float)
    ev = np.union1d(np.concatenate(([t0], t_eval)), knots)
    # merge times closer than 1 ns (a knot on a sample time written differently)
    keep = np.concatenate(([True], np.diff(ev) > 1e-9))
    ev = ev[keep]
    rows = np.full(ev.size, -1, dtype=np.int64)
    idx = np.searchsorted(ev, t_eval - 1e-9)
    idx = np.minimum(idx, ev.size - 1)
    rows[idx] = np.arange(t_eval.size)
    shifts = np.zeros(ev.size)
    if knots.size:
        kidx = np.searchsorted(ev, knots - 1e-9)
        shifts[np.minimum(kidx, ev.size - 1)] = -KNOT_SHIFT
    return t_eval, ev, rows, shifts


def _noise_arrays(compiled):
    slot = np.array([s for s, _, _ in compiled.noise], dtype=np.int64)
    seed = np.array([sd for _, sd, _ in compiled.noise], dtype=np.int64)
    std = np.array([sd for _, _, sd in compiled.noise], dtype=float)
    return slot, seed, std


DIVERGED_X = 100.0   # speed-up over the last recorded speed past which a roll "ran empty" by diverging


def _roll_failure(ref, k, X, t_eval, n, t_fail):
    """The message for component ``k``'s failed radius check. A roll that reaches its
    core from a radius far above it within one recording interval did not run empty:
    its speed diverged (an unstable loop), and the message says so (a structure screen's
    'speed_gain x0.5' reported 'material roll empty' at R = 0.157 m, core 0.044 m)."""
    comp, m, a = ref.names[k], ref.models[k], ref.offsets[k][0]
    i = max(n - 1, 0)
    R, w = float(X[i, a + 2]), float(X[i, a])
    t_last = float(t_eval[i])
    # the radius change the last recorded speed gives up to the failure ({3}-{5}: one thickness a turn)
    drop = abs(w) * max(t_fail - t_last, 0.0) * m.thickness / (2.0 * math.pi)
    gap = abs(R - m.R_core)
    if n > 0 and gap > DIVERGED_X * max(drop, 1e-300):   # no row recorded: nothing to compare
        return (f"{comp}: the run diverged: the roll's radius went from R = {R:.6g} m at t = {t_last:.6g} s "
                f"to its core (R_core = {m.R_core:.6g} m) by t = {t_fail:.6g} s, which needs more than "
                f"{DIVERGED_X:g} x its speed at t = {t_last:.6g} s ({w:.4g} rad/s): the line is unstable "
                f"with these parameters")
    return (f"{comp}: material roll {'empty' if m.WINDING < 0 else 'unwound past its core'}: "
            f"radius R = {R:.6g} m vs R_core = {m.R_core:.6g} m (by t = {t_fail:.6g} s)")


def _result(compiled, t_eval, Y, X, status, where, ev, h, wall, compile_s):
    from webline.orchestrator.results import Result
    ref = compiled.ref
    exp = compiled.system.experiment
    message = ""
    n = t_eval.size
    if status != 0:
        t_fail = float(ev[where])
        n = int(np.searchsorted(t_eval, t_fail - 1e-9))  # rows recorded before the failure
        if status < 0:
            message = f"the state became non-finite before t = {t_fail:.6g} s"
        else:
            message = _roll_failure(ref, status - 1, X, t_eval, n, t_fail)
    meta = {"kind": "engine", "status": "ok" if status == 0 else "failed", "message": message,
            "start": exp.start, "stop": exp.stop, "algorithm": "monolithic RK4 (fast engine)",
            "solver": {"method": "RK4", "h": h, "wall_s": wall, "compile_s": compile_s,
                       "n_states": int(compiled.x0.size)},
            "components": {nm: {"model": c.model, "element": c.element, "kind": c.kind}
                           for nm, c in zip(ref.names, ref.system.components)},
            "system_meta": ref.system.meta}
    result = Result(t_eval[:n], Y[:n], compiled.columns, ref.units, ref.descriptions, meta)
    result.states, result.state_names = X[:n], compiled.state_names
    result.info = dict(meta["solver"])
    return result


def simulate(system, t_eval=None, params=None, h=None, h_max=H_MAX, compiled=None):
    """Run ``system`` with the fast engine; a :class:`~orchestrator.results.Result` like
    :func:`orchestrator.reference.simulate_reference` (default times: the master's output
    times). ``params``: a parameter vector replacing the system's (``Compiled.p`` layout);
    ``h``: fixed RK4 step (default :meth:`Compiled.step`, from the Jacobian's modes, at most ``h_max``).
    A material roll that runs empty or a non-finite state gives ``status == "failed"``
    with the rows up to there."""
    from webline.orchestrator.reference import output_times
    t_wall = _time.perf_counter()
    c = compiled or compile_system(system)
    compile_s = c.setup_s + c.load_s
    exp = system.experiment
    t_eval, ev, rows, shifts = _events(c, output_times(exp) if t_eval is None else t_eval, float(exp.start))
    p = (c.p if params is None else np.asarray(params, dtype=float)).copy()
    h = float(h) if h else c.step(p, h_max)
    Y = np.zeros((t_eval.size, len(c.columns)))
    X = np.zeros((t_eval.size, c.x0.size))
    slot, seed, std = _noise_arrays(c)
    t_run = _time.perf_counter()
    status, where = c.module.integrate(c.x0.copy(), p, ev, rows, shifts, h, slot, seed, std, Y, X)
    run_s = _time.perf_counter() - t_run
    res = _result(c, t_eval, Y, X, int(status), int(where), ev, h, _time.perf_counter() - t_wall, compile_s)
    res.info["run_s"] = run_s
    return res


def _run_batch(module, X0, P, ev, rows, shifts, hs, slot, seed, std, Ys, Xs, status, where):
    """``module.integrate`` for every variant, on up to one thread a core (numba's thread
    count): ``integrate`` releases the GIL, each variant writes its own rows."""
    def one(v):
        status[v], where[v] = module.integrate(X0[v], P[v], ev, rows, shifts, float(hs[v]), slot, seed, std,
                                               Ys[v], Xs[v])

    import numba
    workers = min(len(X0), max(1, int(numba.config.NUMBA_NUM_THREADS)))
    if workers == 1:
        for v in range(len(X0)):
            one(v)
        return
    with ThreadPoolExecutor(max_workers=workers) as pool:
        list(pool.map(one, range(len(X0))))


def simulate_batch(systems, t_eval=None, h_max=H_MAX, compiled=None):
    """Run variants of one structure (equal generated code: same models, states, connections
    and options; any parameter values) in one compiled call, a variant per thread.
    Returns [Result] in order. Systems of differing structure raise ValueError
    (run them with :func:`simulate`). ``compiled``: their :class:`Compiled`, if already built."""
    from webline.orchestrator.reference import output_times
    systems = list(systems)
    if not systems:
        return []
    t_wall = _time.perf_counter()
    comps = list(compiled) if compiled is not None else [compile_system(s) for s in systems]
    base = comps[0]
    for s, c in zip(systems, comps):
        if c.source != base.source:
            raise ValueError(f"simulate_batch: variants differ in structure ({s.meta.get('layout', '')}); "
                             "use simulate() per variant")
        if c.noise != base.noise:
            raise ValueError("simulate_batch: variants differ in noise (a load cell's or a drive's torque ripple: seed or std)")
    compile_s = sum(c.setup_s + c.load_s for c in comps)
    exp = systems[0].experiment
    t_eval = output_times(exp) if t_eval is None else t_eval
    starts = {float(s.experiment.start) for s in systems}
    if len(starts) != 1:
        raise ValueError("simulate_batch: variants start at different times")
    # knots of every variant: each one restarts exactly at its own kinks
    union = Compiled.__new__(Compiled)
    union.knots = sorted({k for c in comps for k in c.knots})
    t_eval, ev, rows, shifts = _events(union, t_eval, starts.pop())
    nv, nx, ny = len(comps), base.x0.size, len(base.columns)
    X0 = np.array([c.x0 for c in comps]).reshape(nv, nx)
    # arrays sit after the scalars, addressed from p itself: variants whose arrays differ in
    # length share the code, and zeros pad the shorter vectors
    P = np.zeros((nv, max(c.p.size for c in comps)))
    for k, c in enumerate(comps):
        P[k, :c.p.size] = c.p
    hs = np.array([c.step(c.p, h_max) for c in comps])
    Ys = np.zeros((nv, t_eval.size, ny))
    Xs = np.zeros((nv, t_eval.size, nx))
    status, where = np.zeros(nv, dtype=np.int64), np.zeros(nv, dtype=np.int64)
    slot, seed, std = _noise_arrays(base)
    t_run = _time.perf_counter()
    _run_batch(base.module, X0, P, ev, rows, shifts, hs, slot, seed, std, Ys, Xs, status, where)
    run_s = _time.perf_counter() - t_run
    wall = _time.perf_counter() - t_wall
    out = []
    for v, c in enumerate(comps):
        r = _result(c, t_eval, Ys[v], Xs[v], int(status[v]), int(where[v]), ev, float(hs[v]), wall, compile_s)
        r.info["run_s"] = run_s
        r.info["batch"] = nv
        out.append(r)
    return out


def structure_key(system):
    """The generated source of ``system`` (equal keys: one compiled code, batchable)."""
    from webline.orchestrator.reference import ReferenceSystem
    return _Builder(ReferenceSystem(system)).source()
