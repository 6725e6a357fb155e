"""Base class that turns a physics element into a well-formed pythonfmu slave.

Bundled into every FMU together with ``webline.physics``. What it adds to
pythonfmu 0.7's ``Fmi2Slave``:

* declarations as data (:class:`Var`): name, unit, start, description, and for
  outputs the inputs they really depend on;
* a ``modelDescription.xml`` that passes ``fmpy validate`` and that foreign
  importers can trust: UnitDefinitions, a unit on every Real, outputs
  ``initial="exact"``, ``ModelStructure/Outputs`` with true dependencies (a
  state output depends on no input, so OMSimulator sees no false algebraic
  loop);
* one generic integrator around an element model (``webline.physics.element``),
  so the FMU script is declarations plus ``make_model()``;
* parameter checks at initialisation that name the variable. pythonfmu can
  only return OK or fmi2Fatal from ``fmi2ExitInitializationMode``, so an
  invalid parameter is logged (status error, naming the variable) and then
  raised, which the host sees as fmi2Fatal;
* ``do_step`` that never lets an exception escape (pythonfmu would turn it
  into fmi2Fatal with "unknown error"): the traceback is logged and the step
  returns fmi2Discard; a state that stops being finite does the same.
"""
import math
import traceback
from xml.etree.ElementTree import Element, SubElement

from pythonfmu import Fmi2Slave, Real
from pythonfmu.enums import Fmi2Causality, Fmi2Initial, Fmi2Status, Fmi2Variability

from webline import __version__
from webline.physics.drive import Drive
from webline.physics.integrate import integrate, rk4_1, rk4_2, rk4_3, rk4_step

# SI base-unit exponents of every unit an FMU may declare (FMI 2.0 BaseUnit).
UNITS = {
    "1": {},
    "m": {"m": 1},
    "s": {"s": 1},
    "kg": {"kg": 1},
    "rad": {"rad": 1},
    "N": {"kg": 1, "m": 1, "s": -2},
    "Pa": {"kg": 1, "m": -1, "s": -2},
    "N.m": {"kg": 1, "m": 2, "s": -2},
    "N.m.s": {"kg": 1, "m": 2, "s": -1},
    "N.m/rad": {"kg": 1, "m": 2, "s": -2, "rad": -1},
    "N.m.s/rad": {"kg": 1, "m": 2, "s": -1, "rad": -1},
    "kg.m2": {"kg": 1, "m": 2},
    "kg/m3": {"kg": 1, "m": -3},
    "m/s": {"m": 1, "s": -1},
    "m/s2": {"m": 1, "s": -2},
    "rad/s": {"rad": 1, "s": -1},
    "1/s": {"s": -1},
    "Hz": {"s": -1},
    "m/(s.N)": {"s": 1, "kg": -1},
    "N.s": {"kg": 1, "m": 1, "s": -1},
    "N/s": {"kg": 1, "m": 1, "s": -3},
    "N.m/(rad/s)": {"kg": 1, "m": 2, "s": -1, "rad": -1},
}

N_HARMONICS = 8  # Fourier terms per eccentric end; the paper uses 6 ({32}).


class Var:
    """Declaration of one Real variable.

    ``depends`` (outputs only): names of the inputs this output depends on
    directly (feed-through). Empty for outputs that are functions of states.
    ``check``: a callable value -> error string or None, run at initialisation.
    ``rate_of`` (inputs only): the input this one is the time derivative of (the model's
    ``EXTRAPOLATE``); written as the FMI ``derivative`` attribute so that a master can tell
    which inputs move inside a step and at what rate.
    """

    __slots__ = ("name", "unit", "start", "description", "depends", "check", "attr", "rate_of")

    def __init__(self, name, unit, start, description, depends=(), check=None, attr=None, rate_of=None):
        if unit not in UNITS:
            raise KeyError(f"unit {unit!r} of {name!r} is not in webline.fmi_slave.UNITS")
        self.name = name
        self.unit = unit
        self.start = float(start)
        self.description = description
        self.depends = tuple(depends)
        self.check = check
        self.attr = attr or name.replace(".", "_").replace("[", "_").replace("]", "")
        self.rate_of = rate_of


def positive(value):
    return None if value > 0.0 and math.isfinite(value) else f"must be > 0 (got {value!r})"


def non_negative(value):
    return None if value >= 0.0 and math.isfinite(value) else f"must be >= 0 (got {value!r})"


def finite(value):
    return None if math.isfinite(value) else f"must be finite (got {value!r})"


def choice(*allowed):
    """A check accepting only the listed values (flags and modes declared as Reals)."""
    def check(value):
        if value in allowed:
            return None
        return f"must be one of {', '.join(f'{a:g}' for a in allowed)} (got {value!r})"
    return check


def drive_vars():
    """Parameters of the non-ideal drive (``webline.physics.drive.Drive``); checked by the model
    only when ``drive.enabled`` is 1."""
    return (
        Var("drive.enabled", "1", 0, "Non-ideal drive: 0 ideal (tau acts on the element), 1 motor inertia + "
            "compliant shaft with backlash (tau acts on the motor; the shaft starts twisted to carry "
            "the initial tau)", check=choice(0.0, 1.0)),
        Var("drive.J_motor", "kg.m2", 0.01, "Motor-side inertia (non-ideal drive)", check=finite),
        Var("drive.stiffness", "N.m/rad", 1.0e4, "Torsional stiffness of the shaft/coupling (non-ideal drive)",
            check=finite),
        Var("drive.damping", "N.m.s/rad", 1.0, "Torsional damping of the shaft/coupling (non-ideal drive)",
            check=finite),
        Var("drive.backlash", "rad", 0.0, "Total backlash dead-zone width (non-ideal drive)", check=finite),
    )


def drive_from(slave):
    """The ``Drive`` of an FMU instance declaring ``drive_vars()``."""
    return Drive(slave.drive_enabled, slave.drive_J_motor, slave.drive_stiffness, slave.drive_damping,
                 slave.drive_backlash)


def material_roll_parameters():
    """Parameters shared by the UnwindRoll and RewindRoll FMUs ({3}-{8})."""
    return (
        Var("R0", "m", 0.16, "Initial outer radius of the roll", check=positive),
        Var("R_core", "m", 0.04, "Core radius R_c ({4})", check=positive),
        Var("thickness", "m", 1.9e-4, "Web thickness t_w ({5})", check=positive),
        Var("width", "m", 0.15, "Web width w_w ({4})", check=positive),
        Var("rho", "kg/m3", 400.0, "Web density rho_w ({4})", check=positive),
        Var("J_core", "kg.m2", 0.02,
            "Inertia of core, shaft and coupling J_0 ({3}); with the ideal drive it includes the motor",
            check=non_negative),
        Var("b", "N.m.s/rad", 0.0, "Viscous friction coefficient", check=non_negative),
        Var("omega0", "rad/s", 0.0, "Initial angular speed", check=finite),
        Var("theta0", "rad", 0.0, "Initial angle", check=finite),
        *drive_vars(),
    )


def material_roll_outputs(tension):
    """Outputs shared by the UnwindRoll and RewindRoll FMUs (functions of states, except ``a``,
    which also depends on the torque and the tension input named ``tension``)."""
    return (
        Var("omega", "rad/s", 0.0, "Angular speed of the roll"),
        Var("theta", "rad", 0.0, "Angle of the roll"),
        Var("R", "m", 0.16, "Outer radius of the roll ({5})"),
        Var("v", "m/s", 0.0, "Web speed at the roll surface, R*omega"),
        Var("J", "kg.m2", 1.0, "Inertia the motor accelerates: J_0 + J_w ({3},{4}), "
            "plus drive.J_motor when the drive is enabled (K_p = J K_ref of {24})"),
        Var("omega_motor", "rad/s", 0.0, "Motor speed (equals omega with the ideal drive)"),
        Var("a", "m/s2", 0.0, "Web acceleration at the roll surface d(R*omega)/dt (rate input for the "
            "adjacent span's extrapolation of v)", depends=("tau", tension)),
    )


def tension_rate_input(name, of):
    """Rate input ``name`` (N/s) that extrapolates the tension input ``of`` inside a step."""
    return Var(name, "N/s", 0.0, f"Rate of {of} (extrapolates {of} linearly inside a step; 0 holds it)",
               rate_of=of)


def roller_parameters(inertia_text):
    """R, J, b, omega0, theta0 of an idle or driven roller ({22})."""
    return (
        Var("R", "m", 0.05, "Roller radius", check=positive),
        Var("J", "kg.m2", 0.01, inertia_text, check=positive),
        Var("b", "N.m.s/rad", 0.0, "Viscous friction coefficient", check=non_negative),
        Var("omega0", "rad/s", 0.0, "Initial angular speed", check=finite),
        Var("theta0", "rad", 0.0, "Initial angle", check=finite),
    )


def roller_tension_inputs():
    """The tensions on both sides of a roller and their rates (for extrapolation)."""
    return (
        Var("T_in", "N", 0.0, "Tension of the span entering the roller (T_i)"),
        Var("T_out", "N", 0.0, "Tension of the span leaving the roller (T_{i+1})"),
        tension_rate_input("dT_in", "T_in"),
        tension_rate_input("dT_out", "T_out"),
    )


def roller_outputs():
    """omega, theta, v: the state outputs every roller has."""
    return (
        Var("omega", "rad/s", 0.0, "Angular speed of the roller"),
        Var("theta", "rad", 0.0, "Angle of the roller"),
        Var("v", "m/s", 0.0, "Web speed on the roller, R*omega"),
    )


def fourier_vars(prefix, where):
    """Parameters C[j] (m), psi[j] (rad), j = 1..N_HARMONICS, for one eccentric end."""
    out = []
    for j in range(1, N_HARMONICS + 1):
        out.append(Var(f"{prefix}.C[{j}]", "m", 0.0,
                       f"Fourier amplitude of harmonic {j} of the span-length change caused by the {where} element ({{28}})",
                       check=finite))
        out.append(Var(f"{prefix}.psi[{j}]", "rad", 0.0,
                       f"Phase of harmonic {j} of the span-length change caused by the {where} element ({{28}})",
                       check=finite))
    return out


SPAN_FEED_THROUGH = ("v_in", "v_out", "T_in", "theta_up", "omega_up", "theta_down", "omega_down", "L_ext",
                     "dL_ext")


def span_declarations(damped):
    """(PARAMETERS, INPUTS, OUTPUTS) of the Span FMU (``damped`` False) and the DampedSpan FMU
    (True: adds ``damping_time`` and declares ``T`` a feed-through of the same inputs as ``dT``)."""
    parameters = (
        Var("EA", "N", 2.0e4, "Web axial stiffness E*A", check=positive),
        Var("L0", "m", 1.0, "Nominal (mean) span length", check=positive),
        Var("T0", "N", 100.0, "Initial tension" + (" (elastic tension T_e)" if damped else ""), check=finite),
        Var("length_mode", "1", 0, "0 angle-locked Fourier, 1 external L/dL inputs, 2 fixed frequency {32}"),
        Var("f_fixed", "Hz", 0.0, "Fundamental frequency for length_mode 2", check=finite),
        *((Var("damping_time", "s", 0.0, "Kelvin-Voigt web: T = T_e + damping_time dT_e/dt (0: elastic web, "
               "{20})", check=non_negative),) if damped else ()),
        *fourier_vars("up", "upstream"),
        *fourier_vars("down", "downstream"),
    )
    inputs = (
        Var("v_in", "m/s", 1.0, "Web speed on the upstream element"),
        Var("v_out", "m/s", 1.0, "Web speed on the downstream element"),
        Var("T_in", "N", 0.0, "Tension of the web entering the span (upstream span; 0 after an unwind)"),
        Var("theta_up", "rad", 0.0, "Angle of the upstream element"),
        Var("omega_up", "rad/s", 0.0, "Angular speed of the upstream element", rate_of="theta_up"),
        Var("theta_down", "rad", 0.0, "Angle of the downstream element"),
        Var("omega_down", "rad/s", 0.0, "Angular speed of the downstream element", rate_of="theta_down"),
        Var("L_ext", "m", 1.0, "Span length (length_mode 1)"),
        Var("dL_ext", "m/s", 0.0, "Span length rate (length_mode 1)"),
        Var("a_in", "m/s2", 0.0, "Web acceleration on the upstream element (extrapolates v_in inside a step; "
            "0 holds it)", rate_of="v_in"),
        Var("a_out", "m/s2", 0.0, "Web acceleration on the downstream element (extrapolates v_out inside a "
            "step; 0 holds it)", rate_of="v_out"),
        Var("dT_in", "N/s", 0.0, "Rate of T_in (extrapolates T_in inside a step; 0 holds it)", rate_of="T_in"),
    )
    outputs = (
        Var("T", "N", 100.0, "Web tension in the span: T_e + damping_time dT_e/dt (Kelvin-Voigt)" if damped
            else "Web tension in the span", depends=SPAN_FEED_THROUGH if damped else ()),
        Var("L", "m", 1.0, "Span length", depends=("theta_up", "theta_down", "L_ext")),
        Var("dL", "m/s", 0.0, "Span length rate dL/dt",
            depends=("theta_up", "omega_up", "theta_down", "omega_down", "dL_ext")),
        Var("dT", "N/s", 0.0, ("Elastic tension rate dT_e/dt" if damped else "Tension rate dT/dt")
            + " ({20}; rate input for the extrapolation of T by its neighbours)", depends=SPAN_FEED_THROUGH),
    )
    return parameters, inputs, outputs


def _as_slice(idx):
    """``slice(a, b)`` when ``idx`` is ``a, a + 1, ..., b - 1`` (else None)."""
    if idx and idx == list(range(idx[0], idx[0] + len(idx))):
        return slice(idx[0], idx[0] + len(idx))
    return None


class ElementSlave(Fmi2Slave):
    """A primitive element model (see ``webline.physics.element``) as an FMI 2.0 slave.

    Subclasses declare ``PARAMETERS``, ``INPUTS`` and ``OUTPUTS`` (lists of
    :class:`Var`; inputs and outputs named as in the model's ``INPUTS`` and
    ``OUTPUTS``) and ``make_model()``, which builds the model from the
    parameter attributes. The wrapper integrates the model's states over each
    macro step with RK4 sub-steps no longer than ``max_step`` nor than the
    model's ``max_substep(x)`` (a stiff drive shaft picks its own), holding the
    inputs (or advancing the model's ``EXTRAPOLATE`` inputs linearly from the
    time each was set).
    Outputs that depend on inputs are recomputed whenever they are read, so a
    master can resolve feed-through chains at a communication point.
    """

    author = "webline"
    license = "MIT"
    version = __version__
    PARAMETERS = ()
    INPUTS = ()
    OUTPUTS = ()
    MAX_STEP = Var("max_step", "s", 1.0e-3, "Longest internal RK4 sub-step", check=positive)

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.failed = False
        self.model = None
        self.time = self.start_time = 0.0
        # Time at which each extrapolated input (an angle) was last set: it advances
        # from its own setting time, whichever other inputs a master sets.
        self.set_time = {}
        self.x = []
        self.dirty = True  # feed-through outputs need recomputing before they are read
        for v in self.parameters():
            self._declare(v, Fmi2Causality.parameter, Fmi2Variability.fixed, None)
        for v in self.INPUTS:
            self._declare(v, Fmi2Causality.input, Fmi2Variability.continuous, None, is_input=True)
        for v in self.OUTPUTS:
            self._declare(v, Fmi2Causality.output, Fmi2Variability.continuous, Fmi2Initial.exact,
                          refresh=bool(v.depends))

    @classmethod
    def parameters(cls):
        return (*cls.PARAMETERS, cls.MAX_STEP)

    def _declare(self, v, causality, variability, initial, is_input=False, refresh=False):
        setattr(self, v.attr, v.start)
        attr = v.attr

        def get():
            if refresh or self.model is None:
                self._refresh_if_dirty()
            if self.model is not None:  # inputs and outputs live in lists once initialised
                where = self._slot.get(attr)
                if where is not None:
                    return (self._u if where[0] else self._y)[where[1]]
            return getattr(self, attr)

        def set_(value):
            setattr(self, attr, value)
            if is_input:
                if self.model is not None:
                    i = self._slot[attr][1]
                    self._u[i] = value
                    self._t_set[i] = self.time
                self.set_time[attr] = self.time
                self.dirty = True

        self.register_variable(Real(
            v.name, causality=causality, variability=variability, initial=initial,
            description=f"{v.description} [{v.unit}]", getter=get, setter=set_))

    def values(self, prefix, n=N_HARMONICS, field="C"):
        """List of the array parameter ``prefix.field[1..n]`` (``field[1..n]`` when ``prefix`` is empty)."""
        base = f"{prefix}_{field}" if prefix else field
        return [getattr(self, f"{base}_{j}") for j in range(1, n + 1)]

    def make_model(self):
        raise NotImplementedError

    # ---- lifecycle -----------------------------------------------------------------
    def setup_experiment(self, start_time, stop_time=None, tolerance=None):
        # Outputs computed at initialisation (a profile's value) belong to the start time.
        self.time = self.start_time = float(start_time or 0.0)

    def _checked_model(self):
        """(model or None, [(variable, reason)]): the model ``make_model()`` builds from the
        parameter attributes, the parameters' checks and the model's own."""
        problems = []
        for v in self.parameters():
            if v.check is not None:
                reason = v.check(getattr(self, v.attr))
                if reason:
                    problems.append((v.name, reason))
        model = None
        try:
            model = self.make_model()
            if not problems:
                problems.extend(model.problems())
        except Exception:
            problems.append(("(model)", traceback.format_exc()))
        return model, problems

    @classmethod
    def model_of(cls, values):
        """(model, {input name: start}) that an instance with ``values`` ({variable name:
        value}, parameters and input starts) builds at initialisation, without an FMU's
        variable registration: for readers of the model alone (the fast engine sets up
        hundreds of variants of a line; a variant of the benchmark line in which 21 of 27
        components change took 15 ms to compile with the FMUs instantiated, 2 ms so).
        KeyError(name) for a variable it does not have, ValueError naming the problems as
        :meth:`exit_initialization_mode` finds them."""
        obj = cls.__new__(cls)
        declared = {v.name: v for v in (*cls.parameters(), *cls.INPUTS, *cls.OUTPUTS)}
        for v in declared.values():
            setattr(obj, v.attr, v.start)
        for name, value in values.items():   # any declared variable, as an instance's setters take
            if name not in declared:
                raise KeyError(name)
            setattr(obj, declared[name].attr, float(value))
        model, problems = obj._checked_model()
        if problems:
            raise ValueError("; ".join(f"{n} {r}" for n, r in problems))
        return model, {n: getattr(obj, obj._attr_of(n)) for n in model.INPUTS}

    def exit_initialization_mode(self):
        self.model, problems = self._checked_model()
        if problems:
            for name, reason in problems:
                self.log(f"{self.instance_name}: parameter '{name}' {reason}", Fmi2Status.error)
            self.failed = True
            # pythonfmu maps any exception here to fmi2Fatal: the only non-OK
            # status it can return from initialisation.
            raise ValueError("; ".join(f"{n} {r}" for n, r in problems))
        self._input_index = [(i, self.model.INPUTS.index(rate))
                             for i, rate in ((self.model.INPUTS.index(a), r)
                                             for a, r in self.model.EXTRAPOLATE.items())]
        self._input_attrs = [self._attr_of(n) for n in self.model.INPUTS]
        self._output_attrs = [self._attr_of(n) for n in self.model.OUTPUTS]
        # From here on inputs and outputs live in lists (model order): the per-step paths
        # index them instead of going through attributes.
        self._u = [getattr(self, a) for a in self._input_attrs]
        self._t_set = [self.set_time.get(a, self.start_time) for a in self._input_attrs]
        self._y = [getattr(self, a) for a in self._output_attrs]
        self._slot = {a: (True, i) for i, a in enumerate(self._input_attrs)}
        self._slot.update({a: (False, i) for i, a in enumerate(self._output_attrs)})
        self._vr = None
        self._get_fast, self._set_fast = {}, {}  # value-reference tuple -> indices (get_real, set_real)
        self._step = {1: rk4_1, 2: rk4_2, 3: rk4_3}.get(len(self.model.STATES), rk4_step)
        self.x = list(self.model.initial_state())
        try:
            self._refresh_outputs()
        except Exception:
            self.failed = True
            self.log(f"{self.instance_name}: computing the initial outputs failed\n"
                     f"{traceback.format_exc()}", Fmi2Status.error)
            raise
        return True

    def _attr_of(self, name):
        return next(v.attr for v in (*self.INPUTS, *self.OUTPUTS) if v.name == name)

    def _inputs(self, s):
        """Model inputs ``s`` seconds after the current time, extrapolated ones advanced
        linearly from the time they were set."""
        u = self._u[:]
        if self._input_index:
            t = self.time + s
            t_set = self._t_set
            for i, r in self._input_index:
                u[i] += u[r] * (t - t_set[i])
        return u

    def _refresh_outputs(self):
        y = self.model.outputs(self.time, self.x, self._inputs(0.0))
        self._y = y
        self.dirty = False
        return y

    def _refresh_if_dirty(self):
        if self.dirty and self.model is None and not self.failed:
            self._provisional_outputs()
        elif self.dirty and not self.failed:
            try:
                self._refresh_outputs()
            except Exception:
                # An exception in a getter would reach the host as fmi2Fatal
                # "unknown error"; log it, keep the last value, fail the next step.
                self.failed = True
                self.log(f"{self.instance_name}: computing outputs at t={self.time:.6g} s failed\n"
                         f"{traceback.format_exc()}", Fmi2Status.error)

    def _provisional_outputs(self):
        """Outputs read during initialisation mode, before the model exists.

        Some hosts (libcosim) read feed-through outputs while initialising to
        settle their start values; answer from a model built with the current
        parameters rather than the declared start values. Invalid parameters
        are reported by exit_initialization_mode, not here."""
        try:
            model = self.make_model()
            u = [getattr(self, self._attr_of(n)) for n in model.INPUTS]
            y = model.outputs(self.time, list(model.initial_state()), u)
        except Exception:
            return
        for name, value in zip(model.OUTPUTS, y):
            setattr(self, self._attr_of(name), value)

    # Fast paths for the FMI get/set calls: pythonfmu's generic versions call a
    # getter closure and an isinstance per scalar; a line of ~50 FMUs makes
    # hundreds of these calls per macro step.
    # After initialisation a table entry is (attr, feed-through, kind, index): kind 0 a
    # parameter (attribute), 1 an input (self._u[index]), 2 an output (self._y[index]).
    def _vr_tables(self):
        tables = {}
        feed = {v.attr for v in self.OUTPUTS if v.depends}
        slot = self.__dict__.get("_slot") if self.model is not None else None
        by_name = {v.name: v.attr for v in (*self.parameters(), *self.INPUTS, *self.OUTPUTS)}
        for vr, var in self.vars.items():
            attr = by_name[var.name]
            where = slot.get(attr) if slot else None
            kind = 0 if where is None else (1 if where[0] else 2)
            tables[vr] = (attr, attr in feed, kind, where[1] if where else -1)
        if slot is not None:  # tables made before initialisation are rebuilt once after it
            self._vr = tables
        return tables

    def get_real(self, vrs):
        # A master asks for the same value-reference lists every step: after initialisation
        # a list of outputs only is answered from a cache (indices into self._y).
        fast = self.__dict__.get("_get_fast")
        if fast is not None:
            key = tuple(vrs)
            hit = fast.get(key)
            if hit is not None:
                if hit[0] and self.dirty:
                    self._refresh_if_dirty()
                if hit[2] is not None:  # consecutive outputs: one slice (pythonfmu wants a list)
                    y = self._y[hit[2]]
                    return y if type(y) is list else list(y)
                y = self._y
                return [y[i] for i in hit[1]]
            table = self._vr or self._vr_tables()
            rows = [table[vr] for vr in key]
            if all(r[2] == 2 for r in rows):
                idx = [r[3] for r in rows]
                fast[key] = (any(r[1] for r in rows), idx, _as_slice(idx))
        table = self.__dict__.get("_vr") or self._vr_tables()
        out = []
        for vr in vrs:
            attr, feed, kind, i = table[vr]
            if self.dirty and (feed or self.model is None):
                self._refresh_if_dirty()
            if kind == 2:
                out.append(float(self._y[i]))
            elif kind == 1:
                out.append(float(self._u[i]))
            else:
                out.append(float(getattr(self, attr)))
        return out

    def set_real(self, vrs, values):
        fast = self.__dict__.get("_set_fast")  # inputs only, after initialisation: their indices
        if fast is not None:
            key = tuple(vrs)
            hit = fast.get(key)
            if hit is not None:
                idx, sl = hit
                if sl is not None:  # consecutive inputs: slice assignments
                    self._u[sl] = values
                    self._t_set[sl] = [self.time] * len(values)
                else:
                    u, t_set, now = self._u, self._t_set, self.time
                    for i, value in zip(idx, values):
                        u[i] = value
                        t_set[i] = now
                self.dirty = True
                return
            table = self._vr or self._vr_tables()
            rows = [table[vr] for vr in key]
            if all(r[2] == 1 for r in rows):
                idx = [r[3] for r in rows]
                fast[key] = (idx, _as_slice(idx))
        table = self.__dict__.get("_vr") or self._vr_tables()
        now = self.time
        u, t_set = self.__dict__.get("_u"), self.__dict__.get("_t_set")
        for vr, value in zip(vrs, values):
            attr, _, kind, i = table[vr]
            if kind == 1:
                u[i] = value
                t_set[i] = now
            elif kind == 2:
                self._y[i] = value
            else:
                setattr(self, attr, value)
                if attr in self.__dict__.get("_slot", ()) or any(v.attr == attr for v in self.INPUTS):
                    self.set_time[attr] = now
        self.dirty = True

    def do_step(self, current_time, step_size):
        if self.failed:
            return False
        try:
            if self.x:
                model = self.model
                u0 = self._inputs(0.0)
                if self._input_index:
                    # Extrapolated inputs move inside the step; the rest are held.
                    moving = [(i, u0[i], u0[r]) for i, r in self._input_index]

                    def f(t, x):
                        u = u0[:]
                        s = t - current_time
                        for i, base, rate in moving:
                            u[i] = base + rate * s
                        return model.derivatives(t, x, u)
                else:
                    def f(t, x):
                        return model.derivatives(t, x, u0)

                h_max = min(self.max_step, model.max_substep(self.x))
                self.x = integrate(f, current_time, self.x, step_size, h_max, self._step)
            self.time = current_time + step_size
            y = self._refresh_outputs()
        except Exception:
            self.failed = True
            self.log(f"{self.instance_name}: step at t={current_time:.6g} s failed\n"
                     f"{traceback.format_exc()}", Fmi2Status.error)
            return False
        if math.isfinite(sum(y)):
            return True
        for name, value in zip(self.model.OUTPUTS, y):
            if not math.isfinite(value):
                self.failed = True
                self.log(f"{self.instance_name}: output '{name}' became {value} at "
                         f"t={self.time:.6g} s (diverged)", Fmi2Status.error)
                return False
        return True

    # ---- modelDescription.xml ------------------------------------------------------
    def to_xml(self, model_options=dict()):
        root = super().to_xml(model_options)
        declared = {v.name: v for v in (*self.parameters(), *self.INPUTS, *self.OUTPUTS)}
        variables = root.find("ModelVariables")
        index = {}
        used = set()
        for i, sv in enumerate(variables.findall("ScalarVariable"), start=1):
            name = sv.get("name")
            index[name] = i
            v = declared[name]
            real = sv.find("Real")
            real.set("unit", v.unit)
            used.add(v.unit)
        for v in self.INPUTS:
            if v.rate_of:
                variables.findall("ScalarVariable")[index[v.name] - 1].find("Real").set(
                    "derivative", str(index[v.rate_of]))
        # UnitDefinitions must follow CoSimulation (FMI 2.0 schema order).
        units = Element("UnitDefinitions")
        for u in sorted(used):
            unit = SubElement(units, "Unit", name=u)
            SubElement(unit, "BaseUnit", {k: str(e) for k, e in UNITS[u].items()})
        cosim = root.find("CoSimulation")
        root.insert(list(root).index(cosim) + 1, units)

        structure = root.find("ModelStructure")
        outputs = structure.find("Outputs")
        if outputs is not None:
            for unknown in outputs.findall("Unknown"):
                i = int(unknown.get("index"))
                v = next(v for v in self.OUTPUTS if index[v.name] == i)
                deps = " ".join(str(index[d]) for d in v.depends)
                unknown.set("dependencies", deps)
                unknown.set("dependenciesKind", " ".join("dependent" for _ in v.depends))
        return root
