"""Monolithic reference of a System: the same physics models in one ODE, no co-simulation.

Every component's model is built exactly as its FMU builds it, without FMI:
the FMU script of the component's model (``fmus/webline_*.py``) is imported
in-process, its class is instantiated, parameters and input start values are
set through its registered variables (the FMI variable names), and the FMI
initialisation calls run (``exit_initialization_mode`` checks the parameters
and calls ``make_model()``). The models are then assembled into one ODE:

* the state vector is the concatenation of all models' states, in component order;
* at each right-hand-side evaluation the outputs are computed in topological
  order of feed-through (an output that depends on inputs, per the FMU's
  declared ``depends``, is computed once the outputs feeding those inputs are
  known), routed through the connections into the inputs, and then every
  model's ``derivatives`` is called with the current inputs.

Inputs that no connection feeds keep their start values. Angles are exact
states of the rotating elements, so no input extrapolation is needed; the
rate inputs that only drive the FMUs' extrapolation (``RATE_INPUTS``: a span's
``a_in``/``a_out``/``dT_in``, a roller's ``dT_in``/``dT_out``) are left unconnected.

``simulate_reference(system)`` solves it with ``scipy.integrate.solve_ivp``
(LSODA, rtol 1e-8 by default) and samples every output at the master's output
times; columns are named ``<component>.<variable>`` as in the master's result.
"""
import importlib
import math
import time as _time
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp



class AlgebraicLoop(ValueError):
    """The connections close a loop of feed-through outputs (no state breaks it)."""


# ---- FMU classes, in-process -----------------------------------------------------------
_CLASSES = None


def fmu_classes():
    """{model name: FMU slave class} of every script ``fmus/webline_*.py``.

    Scripts are imported as ``fmus.webline_<x>``, a module name distinct from
    the top-level ``webline_<x>`` that pythonfmu uses when an FMU is loaded in
    the same process, so the two never shadow each other.
    """
    global _CLASSES
    from webline.fmus.build import model_name, scripts
    found = {model_name(s): s for s in scripts()}
    if _CLASSES is None or set(_CLASSES) != set(found):
        classes = {}
        for model, script in found.items():
            module = importlib.import_module(f"webline.fmus.{Path(script).stem}")
            classes[model] = getattr(module, model)
        _CLASSES = classes
    return _CLASSES


def _slave_class(component, classes):
    """The FMU slave class of ``component`` (``classes``: :func:`fmu_classes` or None)."""
    classes = classes or fmu_classes()
    if component.model not in classes:
        raise KeyError(f"component {component.name!r}: no FMU script for model {component.model!r} "
                       f"(known: {', '.join(sorted(classes))})")
    return classes[component.model]


def _no_variable(component, name):
    return KeyError(f"component {component.name!r} ({component.model}) has no variable {name!r}")


def _bad_parameters(component, exc):
    return ValueError(f"component {component.name!r} ({component.model}): {exc}")


def instantiate(component, start_time=0.0, stop_time=None, classes=None):
    """FMU slave object of ``component`` with its parameters and input starts set and
    initialised (its ``model`` attribute built by ``make_model()``), as an FMU host would.
    ``classes``: :func:`fmu_classes`, if the caller already has them."""
    slave = _slave_class(component, classes)(instance_name=component.name)
    variables = {v.name: v for v in slave.vars.values()}
    for group in (component.parameters, component.inputs):
        for name, value in group.items():
            if name not in variables:
                raise _no_variable(component, name)
            setter = variables[name].setter
            if setter is None:
                raise KeyError(f"variable {component.name}.{name} cannot be set")
            setter(float(value))
    slave.setup_experiment(start_time, stop_time, None)
    slave.enter_initialization_mode()
    try:
        slave.exit_initialization_mode()  # checks parameters (ValueError naming them), builds the model
    except ValueError as exc:
        raise _bad_parameters(component, exc) from None
    if slave.model is None:
        raise RuntimeError(f"component {component.name!r}: the FMU built no model")
    return slave


class ModelOnly:
    """What a reader of the models alone takes from an FMU slave: the model its class
    builds (``model``), the inputs' start values (``input_starts``, model order) and the
    class (``cls``: the variables' declarations)."""

    __slots__ = ("cls", "model", "input_starts")

    def __init__(self, cls, model, input_starts):
        self.cls, self.model, self.input_starts = cls, model, input_starts


def model_only(component, classes=None):
    """:class:`ModelOnly` of ``component``: the model :func:`instantiate`'s slave builds,
    without instantiating the FMU (``ElementSlave.model_of``); the same errors."""
    cls = _slave_class(component, classes)
    try:
        model, starts = cls.model_of({**component.parameters, **component.inputs})
    except KeyError as exc:
        raise _no_variable(component, exc.args[0]) from None
    except ValueError as exc:
        raise _bad_parameters(component, exc) from None
    return ModelOnly(cls, model, [float(starts[n]) for n in model.INPUTS])


REUSE_MAX = 2048  # models kept for reuse (a few kB each)
_REUSE = {}


def _reused(component, start_time, stop_time, classes):
    """:func:`model_only`, or the one made before for an equal component (model, name,
    parameters, input starts). Only for readers that never step a slave or call its
    model (the fast engine generates code from them): a diagnosis simulates hundreds of
    variants of one line that differ in one or two components. The times are not part
    of what a model is built from (``make_model`` reads the parameters alone)."""
    del start_time, stop_time
    key = (component.model, component.name, tuple(sorted(component.parameters.items())),
           tuple(sorted(component.inputs.items())))
    slave = _REUSE.get(key)
    if slave is None:
        slave = model_only(component, classes)
        if len(_REUSE) >= REUSE_MAX:
            _REUSE.pop(next(iter(_REUSE)))
        _REUSE[key] = slave
    return slave


# ---- the assembled ODE -----------------------------------------------------------------
class ReferenceSystem:
    """A System compiled into one ODE ``dx/dt = rhs(t, x)`` over all models' states.

    Attributes: ``names`` (component names), ``models``, ``slaves`` (the FMU slaves; with
    ``reuse``, :class:`ModelOnly` records shared between systems), ``x0``
    (initial state, numpy), ``state_names`` (``<component>.<state>``),
    ``columns`` (``<component>.<output>`` for every output, in ``outputs()`` order).
    """

    def __init__(self, system, reuse=False):
        problems = system.check()
        if problems:
            raise ValueError("system is not well formed:\n  " + "\n  ".join(problems))
        exp = system.experiment
        self.system = system
        classes = fmu_classes()
        make = _reused if reuse else instantiate
        self.slaves = [make(c, exp.start, exp.stop, classes) for c in system.components]
        self.names = [c.name for c in system.components]
        self.models = [s.model for s in self.slaves]
        index = {n: i for i, n in enumerate(self.names)}

        # inputs (persistent lists, updated in place) and state slices
        self.u = []
        self.offsets = []
        x0, self.state_names = [], []
        for c, slave, model in zip(system.components, self.slaves, self.models):
            if isinstance(slave, ModelOnly):
                self.u.append(list(slave.input_starts))
            else:
                variables = {v.name: v for v in slave.vars.values()}
                self.u.append([float(variables[n].getter()) for n in model.INPUTS])
            xs = list(model.initial_state())
            if len(xs) != len(model.STATES):
                raise ValueError(f"{c.name}: initial_state() has {len(xs)} values for STATES {model.STATES}")
            self.offsets.append((len(x0), len(x0) + len(xs)))
            x0 += xs
            self.state_names += [f"{c.name}.{s}" for s in model.STATES]
        self.x0 = np.array(x0, dtype=float)
        self.columns = [f"{n}.{o}" for n, m in zip(self.names, self.models) for o in m.OUTPUTS]
        self.units, self.descriptions = {}, {}
        declared = [s.cls if isinstance(s, ModelOnly) else type(s) for s in self.slaves]
        for n, cls in zip(self.names, declared):
            for v in cls.OUTPUTS:
                self.units[f"{n}.{v.name}"] = v.unit
                self.descriptions[f"{n}.{v.name}"] = f"{v.description} [{v.unit}]"
        self.y = [[0.0] * len(m.OUTPUTS) for m in self.models]

        # which output feeds each input
        feeder = {}  # (comp, input idx) -> (comp, output idx)
        self.routes = []  # (src comp, src out idx, dst comp, dst in idx)
        for k in system.connections:
            s, d = index[k.src], index[k.dst]
            ms, md = self.models[s], self.models[d]
            if k.src_var not in ms.OUTPUTS:
                raise KeyError(f"connection {k}: {k.src}.{k.src_var} is not an output of {system.components[s].model} "
                               f"(outputs: {', '.join(ms.OUTPUTS)})")
            if k.dst_var not in md.INPUTS:
                raise KeyError(f"connection {k}: {k.dst}.{k.dst_var} is not an input of {system.components[d].model} "
                               f"(inputs: {', '.join(md.INPUTS)})")
            if k.dst_var in getattr(md, "RATE_INPUTS", ()):
                continue  # only extrapolates an input inside a macro step: no meaning in one ODE
            o, i = ms.OUTPUTS.index(k.src_var), md.INPUTS.index(k.dst_var)
            feeder[(d, i)] = (s, o)
            self.routes.append((s, o, d, i))

        # feed-through dependencies (from the FMU declarations) -> levels of calls
        deps = {}  # (comp, out idx) -> set of (comp, out idx) it needs first
        for ci, (cls, model) in enumerate(zip(declared, self.models)):
            depends = {v.name: v.depends for v in cls.OUTPUTS}
            for o, name in enumerate(model.OUTPUTS):
                needs = set()
                for inp in depends.get(name, ()):
                    if inp in model.INPUTS:
                        f = feeder.get((ci, model.INPUTS.index(inp)))
                        if f is not None:
                            needs.add(f)
                deps[(ci, o)] = needs
        self.schedule = self._schedule(deps)
        # inside the RHS only outputs that feed an input matter
        self.rhs_schedule = []
        for c, model, y, entries in self.schedule:
            used = [(o, dests) for o, dests in entries if dests]
            if used:
                a, b = self.offsets[c]
                self.rhs_schedule.append((model.outputs, a, b, self.u[c], used))

        # state-carrying components, for derivatives
        self.stateful = [(ci, a, b) for ci, (a, b) in enumerate(self.offsets) if b > a]
        self.derivative_calls = [(self.models[ci].derivatives, a, b, self.u[ci]) for ci, a, b in self.stateful]

    def _schedule(self, deps):
        """Kahn levels of output nodes, each level grouped by component:
        list of (comp, [(out idx, [(dst input list, dst idx), ...]), ...])."""
        remaining = {n: set(d) for n, d in deps.items()}
        done = set()
        calls = []
        while remaining:
            ready = sorted(n for n, d in remaining.items() if d <= done)
            if not ready:
                loop = ", ".join(f"{self.names[c]}.{self.models[c].OUTPUTS[o]}" for c, o in sorted(remaining))
                raise AlgebraicLoop(f"algebraic loop among feed-through outputs: {loop}")
            by_comp = {}
            for c, o in ready:
                by_comp.setdefault(c, []).append(o)
            for c, outs in sorted(by_comp.items()):
                entries = []
                for o in outs:
                    dests = [(self.u[d], i) for (s, so, d, i) in self.routes if s == c and so == o]
                    entries.append((o, dests))
                calls.append((c, self.models[c], self.y[c], entries))
            for n in ready:
                del remaining[n]
                done.add(n)
        return calls

    def _evaluate(self, t, xl):
        """Compute all outputs at (t, xl) and route them into the inputs."""
        offsets, u = self.offsets, self.u
        for c, model, y, entries in self.schedule:
            a, b = offsets[c]
            values = model.outputs(t, xl[a:b], u[c])
            for o, dests in entries:
                v = values[o]
                y[o] = v
                for ulist, i in dests:
                    ulist[i] = v

    def rhs(self, t, x):
        xl = x.tolist()
        for outputs, a, b, u, used in self.rhs_schedule:
            values = outputs(t, xl[a:b], u)
            for o, dests in used:
                v = values[o]
                for ulist, i in dests:
                    ulist[i] = v
        dx = [0.0] * len(xl)
        for derivatives, a, b, u in self.derivative_calls:
            dx[a:b] = derivatives(t, xl[a:b], u)
        return np.array(dx)

    def outputs(self, t, x):
        """All outputs (in ``columns`` order) at time t and state x."""
        self._evaluate(t, list(x) if not isinstance(x, np.ndarray) else x.tolist())
        return [v for y in self.y for v in y]

    def breakpoints(self):
        """Times where an input signal has a kink or a step (Profile points), inside the experiment."""
        exp = self.system.experiment
        pts = set()
        for c, model in zip(self.system.components, self.models):
            if c.model == "Profile":
                pts.update(float(t) for t in getattr(model, "t", ()) if exp.start < t < exp.stop)
        return sorted(pts)


def output_times(experiment, step=None):
    """The master's output times for ``experiment`` (at macro step ``step``, default
    the experiment's): ceil((stop - start)/step) steps, a row at start and then every
    ``output_interval`` (rounded to whole steps; 0: every step)."""
    h = float(experiment.step if step is None else step)
    n_steps = max(1, math.ceil((experiment.stop - experiment.start) / h - 1e-9))
    oi = experiment.output_interval
    every = max(1, round(oi / h)) if oi > 0 else 1
    return experiment.start + h * every * np.arange(n_steps // every + 1)


def ripple_components(system):
    """Names of the components that carry a drive torque ripple (``torque_noise`` != 0)."""
    return [c.name for c in system.components if float(c.parameters.get("torque_noise", 0.0) or 0.0) != 0.0]


def solve_reference(system, rtol=1e-8, atol=None, method="LSODA", max_step=np.inf):
    """Solve the monolithic ODE of ``system`` over its experiment; returns a
    :class:`ReferenceSolution` (dense: sample it at any times with ``.sample(t)``).

    ``atol``: absolute tolerance, scalar or per state (default ``rtol`` times
    max(1, |x0|) per state: tensions in N, angles in rad, integrators ~0).
    The integration restarts at every Profile knot (a kink in an input).
    """
    wall = _time.perf_counter()
    ripple = ripple_components(system)
    if ripple:
        # the ripple is held between communication points; a continuous-time solver would
        # draw a new sample at every evaluation (a rhs discontinuous every microsecond)
        raise ValueError(f"torque ripple ({', '.join(ripple)}: torque_noise) needs a stepping master: "
                         f"run it with the fast engine or the co-simulation")
    ref = ReferenceSystem(system)
    exp = system.experiment
    if atol is None:
        atol = rtol * np.maximum(1.0, np.abs(ref.x0)) if ref.x0.size else rtol
    # the master's last step may end after stop (a step that does not divide the interval)
    t0, t1 = float(exp.start), max(float(exp.stop), float(output_times(exp)[-1]))
    edges = [t0, *[b for b in ref.breakpoints() if t0 < b < t1], t1]
    segments = []
    x = ref.x0.copy()
    nfev = 0
    if ref.x0.size:
        for a, b in zip(edges[:-1], edges[1:]):
            sol = solve_ivp(ref.rhs, (a, b), x, method=method, rtol=rtol, atol=atol,
                            dense_output=True, max_step=max_step)
            if not sol.success:
                raise RuntimeError(f"reference solver failed at t={sol.t[-1]:.6g} s: {sol.message}")
            nfev += sol.nfev
            segments.append((a, b, sol.sol))
            x = sol.y[:, -1]
    info = {"method": method, "rtol": rtol, "nfev": nfev, "n_states": int(ref.x0.size),
            "solve_s": _time.perf_counter() - wall}
    return ReferenceSolution(ref, segments, info)


class ReferenceSolution:
    """Dense solution of a :class:`ReferenceSystem` over [start, stop]."""

    def __init__(self, ref, segments, info):
        self.ref = ref
        self.segments = segments
        self.info = info

    def states(self, t):
        """States at times ``t`` (array), shape (len(t), n_states)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        out = np.zeros((t.size, self.ref.x0.size))
        if not self.segments:
            return out
        lo, hi = self.segments[0][0], self.segments[-1][1]
        if t.size and (t.min() < lo - 1e-12 or t.max() > hi + 1e-9):
            raise ValueError(f"times outside the solved interval [{lo:g}, {hi:g}] s")
        done = np.zeros(t.size, dtype=bool)
        for k, (a, b, sol) in enumerate(self.segments):
            last = k == len(self.segments) - 1
            mask = ~done & (t < b) if not last else ~done
            if mask.any():
                out[mask] = sol(np.clip(t[mask], a, b)).T
                done |= mask
        return out

    def sample(self, t_eval=None):
        """:class:`~orchestrator.results.Result` at ``t_eval`` (default: the master's
        output times), every output of every component as a column ``<component>.<variable>``;
        extra attributes ``states`` (time x states), ``state_names``, ``info``."""
        from webline.orchestrator.results import Result
        ref = self.ref
        t_eval = output_times(ref.system.experiment) if t_eval is None else np.asarray(t_eval, dtype=float)
        t_eval = np.atleast_1d(t_eval)
        states = self.states(t_eval)
        ys = np.array([ref.outputs(t, s) for t, s in zip(t_eval, states)]).reshape(t_eval.size, len(ref.columns))
        exp = ref.system.experiment
        meta = {"kind": "reference", "status": "ok", "message": "", "start": exp.start, "stop": exp.stop,
                "algorithm": "monolithic", "solver": self.info,
                "components": {n: {"model": c.model, "element": c.element, "kind": c.kind}
                               for n, c in zip(ref.names, ref.system.components)},
                "system_meta": ref.system.meta}
        result = Result(t_eval, ys, ref.columns, ref.units, ref.descriptions, meta)
        result.states, result.state_names, result.info = states, ref.state_names, dict(self.info)
        return result


def simulate_reference(system, t_eval=None, rtol=1e-8, atol=None, method="LSODA", max_step=np.inf):
    """Monolithic reference of ``system``: :func:`solve_reference` sampled at ``t_eval``
    (default: the master's output times, :func:`output_times`). Returns a
    :class:`~orchestrator.results.Result` (``result["<component>.<variable>"]``,
    ``result.time``; extra ``states``, ``state_names``, ``info``)."""
    wall = _time.perf_counter()
    result = solve_reference(system, rtol=rtol, atol=atol, method=method, max_step=max_step).sample(t_eval)
    result.info["wall_s"] = _time.perf_counter() - wall
    return result
