"""Co-simulation master: runs a :class:`~orchestrator.system.System` of FMI 2.0 co-simulation FMUs.

The master knows FMI, not physics. One screen per concept, as in libcosim:

* **loading** (:func:`load_model`): each FMU model is extracted once per process
  and its modelDescription read (variables, units, output dependencies);
* **slaves** (:class:`Slave`): one instance per component. Life-cycle calls
  (instantiate, set start values, initialise) go through fmpy's ``FMU2Slave``;
  the per-step calls go through raw ctypes functions with value-reference and
  value arrays allocated once, one ``fmi2SetReal`` for all connected inputs
  and one ``fmi2GetReal`` for all outputs of an instance;
* **coupling plan** (:func:`plan_coupling`): every output lives at a fixed
  index of one float vector ``y`` and every connected input at a fixed index of
  ``u``; a connection is the pair of indices, so applying all connections is one
  gather ``u[dst] = y[src]``. Outputs that depend directly on inputs
  (feed-through: ``SpeedPI.tau``, ``TensionPI.v_trim``, ``LoadCell.T``,
  ``Span.L``/``dL``) are resolved after every step in topological order of the
  dependencies declared in the modelDescription; a cycle among them is a real
  algebraic loop and is reported before anything runs;
* **algorithms** (:func:`jacobi_step`, :func:`gauss_seidel_step`): fixed macro step.
  Rate inputs (an input whose FMI ``derivative`` attribute names another input: the
  FMU extrapolates that input linearly with it inside a step) are fed with the values
  at the start of the step: Gauss-Seidel resolves the outputs feeding them once at the
  end of each round instead of before every slave, and anchors an extrapolated input
  whose source already stepped back to the step start (value - h * rate), so the FMU
  interpolates over the step instead of running a step ahead;
* **observer** (:class:`orchestrator.results.Recorder`): one row of ``y`` per
  output interval into a preallocated array.

Failures: a call that returns fmi2Discard, fmi2Error or fmi2Fatal stops the run.
The :class:`~orchestrator.results.Result` keeps every row recorded so far, with
``status = "failed"`` and a message naming the component, its element, the
FMI function, the time and the last messages the FMU logged. An instance that
returned fmi2Error or fmi2Fatal is never called again, not even to free it
(pythonfmu instances segfault in terminate/free after a fatal error).

FMU log messages are taken raw from each instance's logger callback, without
fmpy's printf proxy: pythonfmu passes its message as the format string, and a
``%`` in it (a traceback, "100 %") crashed the proxy in a test.

Ctrl-C stops the run the same way (``status = "interrupted"``). Structural
problems (unknown model or variable, input fed twice, algebraic loop) raise
:class:`SetupError` before any FMU is instantiated.
"""
import atexit
import ctypes
import math
import os
import shutil
import sys
import tempfile
import time as _time
from collections import deque
from ctypes import POINTER, c_double, c_int, c_size_t, c_uint, c_void_p, cast
from functools import partial
from pathlib import Path

import numpy as np

from webline.orchestrator.results import Recorder

ALGORITHMS = ("jacobi", "gauss-seidel")
STATUS = ("OK", "Warning", "Discard", "Error", "Fatal", "Pending")
LOG_KEEP = 20  # log messages kept per instance
LOG_SHOW = 6  # of which shown in a failure message
CHECK_EVERY = 256  # macro steps between progress updates and finiteness checks


class SetupError(ValueError):
    """The System cannot be run as given (nothing was instantiated)."""


class RunFailure(Exception):
    """The run stopped; the message says where and why."""


class FmiFailure(RunFailure):
    """An FMI call returned Discard, Error or Fatal (``status`` None: instantiation failed)."""

    def __init__(self, slave, function, status, t):
        self.slave, self.function, self.status, self.t = slave, function, status, t
        super().__init__(describe_failure(slave, function, status, t))


# ---- loading ------------------------------------------------------------------------
class FmuModel:
    """One FMU file, extracted once: modelDescription facts the master needs."""

    def __init__(self, path):
        from fmpy import extract, read_model_description

        self.path = Path(path)
        self.md = read_model_description(str(self.path))
        if self.md.fmiVersion != "2.0" or self.md.coSimulation is None:
            raise SetupError(f"{self.path}: not an FMI 2.0 co-simulation FMU")
        self.name = self.md.modelName
        self.identifier = self.md.coSimulation.modelIdentifier
        # everything but other platforms' binaries (the largest members: a third of the setup's writes)
        mine = f"binaries/{_platform()}/"
        self.unzipdir = extract(str(self.path), unzipdir=tempfile.mkdtemp(prefix=f"webline_{self.identifier}_"),
                                include=lambda n: not n.startswith("binaries/") or n.startswith(mine))
        _EXTRACTED.append(self.unzipdir)
        self.library = os.path.join(self.unzipdir, "binaries", _platform(),
                                    self.identifier + (".dll" if sys.platform == "win32" else ".so"))
        self.variables = {v.name: v for v in self.md.modelVariables}
        self.inputs = [v.name for v in self.md.modelVariables if v.causality == "input"]
        # output -> tuple of input names it depends on directly (None: unknown = all inputs)
        self.outputs = {}
        for unknown in self.md.outputs:
            deps = unknown.dependencies
            self.outputs[unknown.variable.name] = (tuple(self.inputs) if deps is None
                                                   else tuple(d.name for d in deps if d.causality == "input"))
        # input -> input that is its time derivative (FMI ``derivative`` attribute on an input):
        # the FMU advances the first linearly with the second inside a step
        self.rates = {v.derivative.name: v.name for v in self.md.modelVariables
                      if v.causality == "input" and v.derivative is not None
                      and v.derivative.causality == "input"}
        self._dll = None

    def dll(self):
        """The shared library with the raw functions the loop calls (restype int, no argtypes)."""
        if self._dll is None:
            self._dll = ctypes.CDLL(self.library)  # same handle fmpy's FMU2Slave loads
            for name in ("fmi2SetReal", "fmi2GetReal", "fmi2DoStep"):
                getattr(self._dll, name).restype = c_int
        return self._dll

    def unit(self, name):
        v = self.variables[name]
        return v.unit or (v.declaredType.unit if v.declaredType is not None else "") or ""

    def description(self, name):
        return self.variables[name].description or ""


_MODELS = {}
_EXTRACTED = []


def _platform():
    from fmpy import platform
    return platform


@atexit.register
def _remove_extracted():
    for d in _EXTRACTED:
        shutil.rmtree(d, ignore_errors=True)


def load_model(path):
    """The :class:`FmuModel` of an FMU file, extracted once per process (and again if the file changed)."""
    path = Path(path).resolve()
    key = (str(path), path.stat().st_mtime_ns)
    if key not in _MODELS:
        _MODELS[key] = FmuModel(path)
    return _MODELS[key]


# ---- slaves -------------------------------------------------------------------------
class Slave:
    """One FMU instance: fmpy for the life cycle, raw ctypes calls in the loop."""

    def __init__(self, component, model, index):
        self.component = component
        self.name = component.name
        self.element = component.element or component.name
        self.model = model
        self.index = index
        self.log = deque(maxlen=LOG_KEEP)
        self.warnings = 0
        self.fmu = None
        self.state = "new"  # new, instantiated, initialized, failed (never call again), freed
        # filled by plan_coupling
        self.outputs = []  # output names in y order: state outputs, then feed-through by level
        self.y0 = 0  # index of the first output in y
        self.n_state = 0  # leading outputs that feed connections and depend on no connected input
        self.n_rest = 0  # then outputs that depend on no connected input and only get recorded
        self.inputs = []  # connected input names, in u order
        self.u0 = 0
        # multi-rate: steps at every ``multiple``-th macro step over ``multiple`` macro steps
        self.multiple = int(getattr(component, "step_multiple", 1) or 1)

    def label(self):
        extra = f", element {self.element!r}" if self.element != self.name else ""
        return f"component {self.name!r} ({self.model.name}{extra})"

    def _logger(self, env, instance, status, category, message):
        text = message.decode("utf-8", "replace") if message else ""
        self.log.append((status, text))
        if status >= 1:
            self.warnings += 1

    def instantiate(self):
        from fmpy import calloc, free
        from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                               fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)

        md = self.model.md
        cb = fmi2CallbackFunctions()
        cb.logger = fmi2CallbackLoggerTYPE(self._logger)
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        self.callbacks = cb  # the C side keeps a pointer: keep it alive as long as the instance
        self.fmu = FMU2Slave(guid=md.guid, unzipDirectory=self.model.unzipdir,
                             modelIdentifier=self.model.identifier, instanceName=self.name)
        self.fmu.instantiate(callbacks=cb, loggingOn=True)
        self.c = c_void_p(self.fmu.component)
        self.state = "instantiated"

    def set_start_values(self):
        """Parameters and input start values of the component (fmpy calls, once)."""
        for values in (self.component.parameters, self.component.inputs):
            for name, value in values.items():
                v = self.model.variables[name]
                vr = [v.valueReference]
                if v.type == "Real":
                    self.fmu.setReal(vr, [float(value)])
                elif v.type in ("Integer", "Enumeration"):
                    self.fmu.setInteger(vr, [int(value)])
                elif v.type == "Boolean":
                    self.fmu.setBoolean(vr, [bool(value)])
                else:
                    self.fmu.setString(vr, [str(value)])

    def bind(self, y, u):
        """Raw calls bound to this instance's slices of ``y`` and ``u`` (after plan_coupling)."""
        dll = self.model.dll()
        vr = self.model.variables
        dptr = POINTER(c_double)
        out_vrs = (c_uint * len(self.outputs))(*(vr[n].valueReference for n in self.outputs))
        self._out_vrs = out_vrs

        def get_range(a, b):
            p = cast(y.ctypes.data + 8 * (self.y0 + a), dptr)
            v = cast(ctypes.addressof(out_vrs) + 4 * a, POINTER(c_uint))
            return partial(dll.fmi2GetReal, self.c, v, c_size_t(b - a), p)

        self.get_state = get_range(0, self.n_state) if self.n_state else None
        self.get_rest = get_range(self.n_state, self.n_state + self.n_rest) if self.n_rest else None
        # on a recording step the record-only state outputs are read with the coupled ones, in
        # the same fmi2GetReal right after the step (they depend on no connected input, so they
        # do not change until the next step)
        n_all = self.n_state + self.n_rest
        self.get_all = get_range(0, n_all) if n_all else None
        self.get_range = get_range
        in_vrs = (c_uint * len(self.inputs))(*(vr[n].valueReference for n in self.inputs))
        self._in_vrs = in_vrs
        self.set_inputs = (partial(dll.fmi2SetReal, self.c, in_vrs, c_size_t(len(self.inputs)),
                                   cast(u.ctypes.data + 8 * self.u0, dptr)) if self.inputs else None)
        self.do_step = partial(dll.fmi2DoStep, self.c)

    def close(self):
        """Terminate and free, unless the instance failed (then it is left alone)."""
        if self.state == "initialized":
            _raw_quiet(self.model, "fmi2Terminate", self.c)
        if self.state in ("initialized", "instantiated"):
            _raw_quiet(self.model, "fmi2FreeInstance", self.c)
            self.state = "freed"
        elif self.state == "failed":
            _ABANDONED.append(self)  # keep callbacks alive: the instance is never freed


_ABANDONED = []


def _raw_quiet(model, function, *args):
    try:
        getattr(model.dll(), function)(*args)
    except Exception:  # cleanup must not hide the run's own outcome
        pass


def describe_failure(slave, function, status, t):
    """Message for a failed FMI call, with the last messages the instance logged."""
    if status is None:
        text = f"{slave.label()}: {function} failed at t = {t:.6g} s"
    else:
        label = f"fmi2{STATUS[status]}" if 0 <= status < len(STATUS) else f"illegal status {status}"
        text = f"{slave.label()}: {function} returned {label} at t = {t:.6g} s"
    logged = list(slave.log)[-LOG_SHOW:]
    if logged:
        text += "\nFMU log (last messages):"
        for st, msg in logged:
            lvl = STATUS[st] if 0 <= st < len(STATUS) else str(st)
            msg = msg if len(msg) <= 3000 else msg[:3000] + " [...]"
            text += f"\n  [{lvl}] " + msg.replace("\n", "\n    ")
    else:
        text += " (the FMU logged nothing)"
    return text


# ---- coupling plan ------------------------------------------------------------------
class Group:
    """Feed-through outputs of one slave resolved together: gather and set the
    slave's connected inputs, then read outputs ``y[a:b]`` of that slave."""

    __slots__ = ("slave", "level", "a", "b", "get", "deps")

    def __init__(self, slave, level, a, b):
        self.slave, self.level, self.a, self.b = slave, level, a, b


class Plan:
    """Where every value lives and in which order feed-through is resolved."""

    def __init__(self, slaves, y, u, dst, src, groups, sinks, chains, columns, units, descriptions):
        self.slaves, self.y, self.u, self.dst, self.src = slaves, y, u, dst, src
        self.groups, self.sinks, self.chains = groups, sinks, chains
        self.gs_order = [(chains[s.name], s) for s in slaves]
        self.gauss_seidel = False  # set by simulate: complete() then resolves the groups
        self.rate_groups, self.other_groups = [], list(groups)  # set by plan_coupling
        self.rest_read = False  # complete(): the record-only state outputs were read after the step
        self.record_next = True  # the step about to run ends on a recording point (set by simulate)
        self.k, self.n_steps = 0, 1  # index of the step about to run, steps in the run (set by simulate)
        self.sink_set = [True] * len(sinks)  # set by plan_sinks: a sink's slave needs its inputs set
        self.columns, self.units, self.descriptions = columns, units, descriptions


def _a(word):
    return ("an " if word[0] in "aeiou" else "a ") + word


def check_system(system, models):
    """Structural problems of ``system`` against the FMUs (raises SetupError listing all)."""
    problems = list(system.check())
    by_name = {c.name: c for c in system.components}
    for c in system.components:
        if c.model not in models:
            problems.append(f"component {c.name!r}: no FMU for model {c.model!r} "
                            f"(have: {', '.join(sorted(models)) or 'none'})")
            continue
        m = models[c.model]
        for kind, values, causality in (("parameter", c.parameters, ("parameter",)),
                                        ("input", c.inputs, ("input",))):
            for name in values:
                v = m.variables.get(name)
                if v is None:
                    problems.append(f"component {c.name!r}: model {c.model} has no variable {name!r}")
                elif v.causality not in causality:
                    problems.append(f"component {c.name!r}: {name!r} is {_a(v.causality)}, not {_a(kind)}")
    for k in system.connections:
        for comp, var, want in ((k.src, k.src_var, "output"), (k.dst, k.dst_var, "input")):
            c = by_name.get(comp)
            if c is None or c.model not in models:
                continue
            v = models[c.model].variables.get(var)
            if v is None:
                problems.append(f"connection {k.src}.{k.src_var} -> {k.dst}.{k.dst_var}: "
                                f"model {c.model} has no variable {var!r}")
            elif v.causality != want or v.type != "Real":
                problems.append(f"connection {k.src}.{k.src_var} -> {k.dst}.{k.dst_var}: "
                                f"{comp}.{var} is {_a(v.type)} {v.causality}, expected a Real {want}")
    for c in system.components:
        m = getattr(c, "step_multiple", 1)
        if not (isinstance(m, int) and not isinstance(m, bool) and m >= 1):
            problems.append(f"component {c.name!r}: step_multiple must be an integer >= 1 (got {m!r})")
        elif m > 1 and any(k.dst == c.name for k in system.connections):
            problems.append(f"component {c.name!r}: step_multiple {m} needs an instance without connected "
                            "inputs (its inputs would be sampled at the slower rate)")
    e = system.experiment
    if e.algorithm not in ALGORITHMS:
        problems.append(f"experiment.algorithm {e.algorithm!r}: expected one of {', '.join(ALGORITHMS)}")
    if not (e.step > 0 and math.isfinite(e.step)):
        problems.append(f"experiment.step must be > 0 (got {e.step!r})")
    if not (e.stop > e.start):
        problems.append(f"experiment.stop ({e.stop!r}) must be after start ({e.start!r})")
    if problems:
        raise SetupError("system cannot be run:\n  " + "\n  ".join(problems))


def plan_coupling(slaves, connections):
    """Lay out ``y``/``u``, classify outputs, order feed-through, detect algebraic loops."""
    feeds = {}  # (dst, input) -> (src, output)
    for k in connections:
        feeds[(k.dst, k.dst_var)] = (k.src, k.src_var)
    # connected inputs per slave, in modelDescription order
    for s in slaves:
        s.inputs = [n for n in s.model.inputs if (s.name, n) in feeds]

    # feed-through outputs: depend on at least one connected input
    ft = {}
    for s in slaves:
        for out, deps in s.model.outputs.items():
            d = [i for i in deps if (s.name, i) in feeds]
            if d:
                ft[(s.name, out)] = d

    # levels by depth-first search; a cycle is an algebraic loop
    level, on_path = {}, []

    def visit(node):
        if node in level:
            return level[node]
        if node in on_path:
            loop = on_path[on_path.index(node):] + [node]
            raise SetupError("algebraic loop through feed-through outputs: "
                             + " -> ".join(f"{a}.{b}" for a, b in loop))
        if node not in ft:
            return 0
        on_path.append(node)
        lv = 1 + max(visit(feeds[(node[0], i)]) for i in ft[node])
        on_path.pop()
        level[node] = lv
        return lv

    for node in ft:
        visit(node)

    # y layout per slave: coupled state outputs | other state outputs | feed-through
    # groups, coupled ones by level, then the sinks (feed nothing: read only to record)
    coupled = set(feeds.values())
    # Outputs that feed only rate inputs (a span's dT) form their own groups: those are
    # resolved once per round (Plan.rate_groups), and re-reading them together with an output
    # a consumer needs now (a damped span's T, same inputs, same level) would feed the rate
    # inputs a step newer than the schedule intends.
    model_of = {s.name: s.model for s in slaves}
    to_rate, to_value = set(), set()
    for (dst, inp), node in feeds.items():
        (to_rate if inp in model_of[dst].rates.values() else to_value).add(node)
    rate_only = to_rate - to_value
    columns, units, descriptions = [], {}, {}
    n_y = 0
    groups, sinks = [], []
    for s in slaves:
        outs = list(s.model.outputs)
        state = [o for o in outs if (s.name, o) not in ft]
        s.n_state = sum((s.name, o) in coupled for o in state)
        s.n_rest = len(state) - s.n_state
        key = {o: ((s.name, o) not in coupled, level.get((s.name, o), 0), (s.name, o) in rate_only) for o in outs}
        s.outputs = sorted(state, key=lambda o: key[o][0]) + sorted(
            (o for o in outs if (s.name, o) in ft), key=lambda o: key[o])
        s.y0 = n_y
        n_y += len(s.outputs)
        a = len(state)
        while a < len(s.outputs):
            b = a
            while b < len(s.outputs) and key[s.outputs[b]] == key[s.outputs[a]]:
                b += 1
            g = Group(s, key[s.outputs[a]][1], a, b)
            g.deps = sorted({i for o in s.outputs[a:b] for i in ft[(s.name, o)]})
            (sinks if key[s.outputs[a]][0] else groups).append(g)
            a = b
        for o in s.outputs:
            col = f"{s.name}.{o}"
            columns.append(col)
            units[col] = s.model.unit(o)
            descriptions[col] = s.model.description(o)
    groups.sort(key=lambda g: g.level)  # stable: system order within a level
    # a generic output (unit "1", e.g. Profile.y) takes the unit of the inputs it feeds
    fed_units = {}
    for (dst, inp), node in feeds.items():
        fed_units.setdefault(node, set()).add(model_of[dst].unit(inp))
    for (src, out), us in fed_units.items():
        col = f"{src}.{out}"
        if units.get(col) in ("", "1") and len(us) == 1 and next(iter(us)) not in ("", "1"):
            units[col] = next(iter(us))

    # u layout
    n_u = 0
    for s in slaves:
        s.u0 = n_u
        n_u += len(s.inputs)
    y = np.zeros(n_y)
    u = np.zeros(n_u)
    for s in slaves:  # u starts at the FMU's start values (overwritten before any use)
        for i, n in enumerate(s.inputs):
            start = s.component.inputs.get(n, s.model.variables[n].start)
            u[s.u0 + i] = float(start) if start is not None else 0.0
    y_index = {(s.name, o): s.y0 + i for s in slaves for i, o in enumerate(s.outputs)}
    dst, src = [], []
    per_slave = {s.name: ([], []) for s in slaves}
    for s in slaves:
        for i, n in enumerate(s.inputs):
            j = y_index[feeds[(s.name, n)]]
            dst.append(s.u0 + i)
            src.append(j)
            per_slave[s.name][0].append(s.u0 + i)
            per_slave[s.name][1].append(j)
    order = {s.name: k for k, s in enumerate(slaves)}
    for s in slaves:
        s.dst = np.array(per_slave[s.name][0], dtype=np.intp)
        s.src = np.array(per_slave[s.name][1], dtype=np.intp)
        # Gauss-Seidel: an input the FMU extrapolates (with a connected rate input) whose source
        # stepped earlier in the round holds the value at t + h while the FMU is at t; it is
        # anchored back, value - h * rate, so the FMU interpolates instead of running ahead.
        back_v, back_r = [], []
        for n, rate in s.model.rates.items():
            if n in s.inputs and rate in s.inputs and order[feeds[(s.name, n)][0]] < order[s.name]:
                back_v.append(s.u0 + s.inputs.index(n))
                back_r.append(s.u0 + s.inputs.index(rate))
        s.back_v = np.array(back_v, dtype=np.intp) if back_v else None
        s.back_r = np.array(back_r, dtype=np.intp)

    # Gauss-Seidel schedule: before slave k steps, the feed-through groups its inputs
    # need (transitively, in topological order) that changed since they were last
    # resolved. A group changes when any slave it depends on steps (its own slave
    # included: a controller's integrator). Computed once for the fixed order, from
    # "nothing resolved" at the start of a round, which is never optimistic.
    group_of = {}
    for g in groups:
        for o in g.slave.outputs[g.a:g.b]:
            group_of[(g.slave.name, o)] = g
    sources = {}  # id(group) -> names of the slaves whose steps change it

    def sources_of(g):
        if id(g) not in sources:
            found = {g.slave.name}
            for i in g.deps:
                node = feeds[(g.slave.name, i)]
                found |= sources_of(group_of[node]) if node in group_of else {node[0]}
            sources[id(g)] = found
        return sources[id(g)]

    for g in groups:
        sources_of(g)
    #
    # Rate inputs (the FMI ``derivative`` of another input: only used to extrapolate it
    # inside a step) are left out of these chains: a rate one step old changes the
    # extrapolated value by O(h^2) only. The groups feeding them are resolved once per
    # round instead, after every slave stepped (``Plan.rate_groups``), from the values the
    # other groups hold then.
    def is_rate(s, n):
        return n in s.model.rates.values()

    chains, valid = {}, set()
    for s in slaves:
        need, stack = set(), [feeds[(s.name, n)] for n in s.inputs if not is_rate(s, n)]
        while stack:
            node = stack.pop()
            g = group_of.get(node)
            if g is None or id(g) in need:
                continue
            need.add(id(g))
            stack.extend(feeds[(g.slave.name, n)] for n in g.deps)
        chains[s.name] = [g for g in groups if id(g) in need and id(g) not in valid]
        valid |= {id(g) for g in chains[s.name]}
        valid -= {id(g) for g in groups if s.name in sources[id(g)]}
    need, stack = set(), [feeds[(s.name, n)] for s in slaves for n in s.inputs if is_rate(s, n)]
    while stack:
        node = stack.pop()
        g = group_of.get(node)
        if g is None or id(g) in need:
            continue
        need.add(id(g))
    # Only the groups that feed a rate input directly: their own feed-through inputs (a
    # driven roller's torque) keep the value the slave held over the step that just ended,
    # instead of being re-resolved for t + h here and again before the next step. Measured
    # on ewl_out_of_round at 2 ms: lc9 error 2.13e-3 instead of 2.17e-3, and 9 of the 36
    # end-of-round set/get pairs gone (docs/performance.md).
    rate_groups = [g for g in groups if id(g) in need]
    plan = Plan(slaves, y, u, np.array(dst, dtype=np.intp), np.array(src, dtype=np.intp),
                groups, sinks, chains, columns, units, descriptions)
    plan.rate_groups = rate_groups
    plan.other_groups = [g for g in groups if id(g) not in need]
    return plan


# ---- algorithms ---------------------------------------------------------------------
def _fail(slave, function, status, t):
    if status == 1:  # warning: keep going, the message is in the slave's log
        return
    if status >= 3 or status < 0:
        slave.state = "failed"
    raise FmiFailure(slave, function, status, t)


def resolve(groups, y, u, t):
    """Feed-through outputs in topological order: set the slave's inputs, read the group."""
    for g in groups:
        s = g.slave
        u[s.dst] = y[s.src]
        st = s.set_inputs()
        if st:
            _fail(s, "fmi2SetReal", st, t)
        st = g.get()
        if st:
            _fail(s, "fmi2GetReal", st, t)


def plan_sinks(plan, before):
    """Which sinks need their slave's inputs set again when recorded after ``before`` (the
    groups resolved, in order, since the last step): none when the slave's inputs were last
    set while resolving one of its own groups in ``before`` and no input of it is read from a
    group resolved after that (its FMU already holds exactly these input values)."""
    pos = {}  # slave name -> index in before of its last group
    for k, g in enumerate(before):
        pos[g.slave.name] = k
    later_y = {}  # index in before -> set of y indices written by the groups after it
    flags = []
    for g in plan.sinks:
        s = g.slave
        k = pos.get(s.name)
        if k is None or s.src is None or not len(s.src):
            flags.append(True)
            continue
        if k not in later_y:
            later_y[k] = {g2.slave.y0 + i for g2 in before[k + 1:] for i in range(g2.a, g2.b)}
        flags.append(bool(later_y[k] & set(int(j) for j in s.src)))
    plan.sink_set = flags


def jacobi_step(plan, t, h):
    """All slaves step from the same input values at ``t``; then outputs at ``t + h``."""
    y, u = plan.y, plan.u
    u[plan.dst] = y[plan.src]
    ct, ch, one = c_double(t), c_double(h), c_int(1)
    for s in plan.slaves:
        if s.set_inputs is not None:
            st = s.set_inputs()
            if st:
                _fail(s, "fmi2SetReal", st, t)
    k = plan.k
    for s in plan.slaves:
        if s.multiple > 1:
            if k % s.multiple:
                continue
            st = s.do_step(ct, c_double(h * min(s.multiple, plan.n_steps - k)), one)
        else:
            st = s.do_step(ct, ch, one)
        if st:
            _fail(s, "fmi2DoStep", st, t)
    t1 = t + h
    for s in plan.slaves:
        if s.multiple > 1 and k % s.multiple:
            continue
        get = s.get_all if plan.record_next or s.multiple > 1 else s.get_state
        if get is not None:
            st = get()
            if st:
                _fail(s, "fmi2GetReal", st, t1)
    resolve(plan.groups, y, u, t1)


def gauss_seidel_step(plan, t, h):
    """Slaves step one after the other (system order), each from the latest values
    of the slaves stepped before it (the feed-through outputs it needs re-resolved
    first, as scheduled by plan_coupling). Feed-through outputs at ``t + h`` are
    resolved only when recorded (:func:`complete`): the next step re-resolves what
    it needs anyway."""
    y, u = plan.y, plan.u
    ct, ch, one = c_double(t), c_double(h), c_int(1)
    t1 = t + h
    k = plan.k
    for chain, s, set_inputs, dst, src, back_v, back_r, do_step, get, get_all, m in plan.gs_loop:
        if m > 1:  # multi-rate, no inputs: one step over m macro steps, then all outputs read
            if k % m == 0:
                st = do_step(ct, c_double(h * min(m, plan.n_steps - k)), one)
                if st:
                    _fail(s, "fmi2DoStep", st, t)
                if get_all is not None:
                    st = get_all()
                    if st:
                        _fail(s, "fmi2GetReal", st, t1)
            continue
        if chain:
            resolve(chain, y, u, t)
        if set_inputs is not None:
            u[dst] = y[src]
            if back_v is not None:
                u[back_v] -= h * u[back_r]
            st = set_inputs()
            if st:
                _fail(s, "fmi2SetReal", st, t)
        st = do_step(ct, ch, one)
        if st:
            _fail(s, "fmi2DoStep", st, t)
        if plan.record_next:
            get = get_all
        if get is not None:
            st = get()
            if st:
                _fail(s, "fmi2GetReal", st, t1)
    if plan.rate_groups:
        resolve(plan.rate_groups, y, u, t1)


def complete(plan, t):
    """Make every output consistent at ``t`` before it is recorded: the feed-through
    groups (Gauss-Seidel leaves them to the next step) and the outputs nothing
    depends on (read only here)."""
    y, u = plan.y, plan.u
    if plan.gauss_seidel:  # the rate groups were resolved at the end of the step
        resolve(plan.other_groups, y, u, t)
    if not plan.rest_read:  # else read with the state outputs right after the step
        for s in plan.slaves:
            if s.get_rest is not None:
                st = s.get_rest()
                if st:
                    _fail(s, "fmi2GetReal", st, t)
    for g, needs_set in zip(plan.sinks, plan.sink_set):
        s = g.slave
        if needs_set:
            u[s.dst] = y[s.src]
            st = s.set_inputs()
            if st:
                _fail(s, "fmi2SetReal", st, t)
        st = g.get()
        if st:
            _fail(s, "fmi2GetReal", st, t)


STEP = {"jacobi": jacobi_step, "gauss-seidel": gauss_seidel_step}


# ---- the run ------------------------------------------------------------------------
def _initialize(slaves, start, stop):
    from fmpy.fmi1 import FMICallException

    for s in slaves:
        try:
            s.instantiate()
        except Exception as exc:
            s.log.append((4, f"{type(exc).__name__}: {exc}"))
            raise FmiFailure(s, "fmi2Instantiate", None, start) from exc
    for s in slaves:
        try:
            s.fmu.setupExperiment(startTime=start, stopTime=stop)
            s.set_start_values()
            s.fmu.enterInitializationMode()
            s.fmu.exitInitializationMode()
        except FMICallException as exc:
            if exc.status >= 3:
                s.state = "failed"
            raise FmiFailure(s, exc.function, exc.status, start) from exc
        s.state = "initialized"


def _first_non_finite(rec, first, columns, slaves):
    """Message naming the first non-finite recorded value from row ``first`` on, or None."""
    data = rec.data[first:rec.n]
    bad = np.argwhere(~np.isfinite(data))
    if not len(bad):
        return None
    r, c = bad[0]
    col = columns[c]
    s = next(s for s in slaves if col.startswith(s.name + "."))
    return (f"{s.label()}: output {col} became {data[r, c]} at t = {rec.time[first + r]:.6g} s "
            "(diverged)")


def simulate(system, fmu_paths=None, progress=True, compiled=True):
    """Run ``system`` and return a :class:`~orchestrator.results.Result`.

    ``compiled``: replay the planned macro step in compiled code
    (:mod:`orchestrator.cloop`) when a C compiler is available; False (or the
    environment variable ``WEBLINE_MASTER_LOOP=python``) keeps the Python loop. Both
    make the same FMI calls in the same order and give bit-identical results.

    ``fmu_paths``: {model name: .fmu path}; default: ``fmus.build.build_all()``
    (builds the FMUs if they are out of date). Raises :class:`SetupError` for a
    system that cannot run; an FMU failure gives a Result with
    ``status == "failed"`` and the rows recorded so far.
    """
    t_setup = _time.perf_counter()
    if fmu_paths is None:
        from webline.fmus.build import build_all
        fmu_paths = build_all(log=lambda m: print(m, file=sys.stderr))
    used = {c.model for c in system.components}
    models = {}
    for name, path in fmu_paths.items():
        if name in used:
            if not Path(path).exists():
                raise SetupError(f"FMU of model {name!r} not found: {path}")
            models[name] = load_model(path)
    check_system(system, models)
    slaves = [Slave(c, models[c.model], i) for i, c in enumerate(system.components)]
    plan = plan_coupling(slaves, system.connections)
    # refuse a run whose results cannot fit in memory before any FMU is instantiated
    from webline.orchestrator.memory import check_result_memory
    check_result_memory(system, columns=len(plan.columns))

    e = system.experiment
    h, t0 = float(e.step), float(e.start)
    n_steps = max(1, math.ceil((e.stop - e.start) / h - 1e-9))
    every = max(1, round(e.output_interval / h)) if e.output_interval > 0 else 1
    recorder = Recorder(plan.columns, plan.units, plan.descriptions, n_steps // every + 1)
    meta = {
        "layout": str(system.meta.get("layout", system.meta.get("layout_path", ""))),
        "start": t0, "stop": t0 + n_steps * h, "step": h, "algorithm": e.algorithm,
        "output_interval": every * h, "n_components": len(slaves),
        "components": {s.name: {"model": s.model.name, "element": s.component.element,
                                "kind": s.component.kind} for s in slaves},
        "system": _system_dict(system),
        "system_meta": system.meta,
    }
    step = STEP[e.algorithm]
    plan.gauss_seidel = e.algorithm == "gauss-seidel"
    status, message, k = "ok", "", 0
    t_loop, wall, setup_time, cpu = 0.0, 0.0, 0.0, float("nan")
    bar = None
    try:
        try:
            _initialize(slaves, t0, t0 + n_steps * h)
            for s in slaves:
                s.bind(plan.y, plan.u)
            for g in (*plan.groups, *plan.sinks):
                g.get = g.slave.get_range(g.a, g.b)
            plan.gs_loop = [(chain, s, s.set_inputs, s.dst, s.src, s.back_v, s.back_r, s.do_step,
                             s.get_state, s.get_all, s.multiple) for chain, s in plan.gs_order]
            plan.n_steps = n_steps
            # groups resolved between a step and complete(), in order
            plan_sinks(plan, plan.rate_groups + plan.other_groups if plan.gauss_seidel else plan.groups)
            setup_time = _time.perf_counter() - t_setup
            t_loop, cpu_loop = _time.perf_counter(), _time.process_time()
            y = plan.y
            for s in slaves:
                if s.get_state is not None:
                    st = s.get_state()
                    if st:
                        _fail(s, "fmi2GetReal", st, t0)
            resolve(plan.groups, y, plan.u, t0)
            plan.rest_read = False
            sink_set, plan.sink_set = plan.sink_set, [True] * len(plan.sinks)
            complete(plan, t0)
            plan.sink_set, plan.rest_read = sink_set, True
            record = recorder.record
            record(t0, y)
            bar = _progress_bar(n_steps, progress)
            checked = 0
            runner = None
            if compiled:
                from webline.orchestrator import cloop
                if cloop.available():
                    runner = cloop.Runner(plan, plan.gauss_seidel, n_steps)
            meta["master_loop"] = "compiled" if runner is not None else "python"
            while k < n_steps:
                stop_k = min(n_steps, k + CHECK_EVERY)
                while runner is None and k < stop_k:
                    plan.record_next = (k + 1) % every == 0
                    plan.k = k
                    step(plan, t0 + k * h, h)
                    k += 1
                    if k % every == 0:
                        complete(plan, t0 + k * h)
                        record(t0 + k * h, y)
                while runner is not None and k < stop_k:
                    # the same steps in compiled code: plain steps up to the next recording
                    # point, then one step that ends on it (reads what complete() reads)
                    nxt = min(stop_k, (k // every + 1) * every)
                    rec = nxt % every == 0
                    n_plain = nxt - k - rec
                    st, done, sl, fn, at_end = runner.run(runner.plain, t0, h, k, n_plain)
                    if not st and rec:
                        st, done, sl, fn, at_end = runner.run(runner.record, t0, h, k + n_plain, 1)
                        done += n_plain
                    if st:
                        k += done
                        _fail(sl, fn, st, t0 + k * h + (h if at_end else 0.0))
                    k = nxt
                    if rec:
                        record(t0 + k * h, y)
                bad = _first_non_finite(recorder, checked, plan.columns, slaves)
                if bad:
                    raise RunFailure(bad)
                checked = recorder.n
                if bar is not None:
                    bar.update(stop_k - bar.n)
            wall = _time.perf_counter() - t_loop
            cpu = _time.process_time() - cpu_loop
        except RunFailure as f:
            status, message = "failed", str(f)
            if isinstance(f, FmiFailure) and any("KeyboardInterrupt" in m for _, m in f.slave.log):
                # Ctrl-C landed in the FMU's Python code (same interpreter): pythonfmu made it fatal
                status, message = "interrupted", f"interrupted at t = {f.t:.6g} s (inside {f.slave.label()})"
            wall = _time.perf_counter() - t_loop if t_loop else 0.0
        except KeyboardInterrupt:
            status, message = "interrupted", f"interrupted at t = {t0 + k * h:.6g} s"
            wall = _time.perf_counter() - t_loop if t_loop else 0.0
    finally:
        if bar is not None:
            bar.close()
        for s in slaves:
            s.close()
    if not t_loop:
        setup_time = _time.perf_counter() - t_setup
    simulated = k * h
    meta.update(status=status, message=message, wall_time=wall, setup_time=setup_time,
                steps_done=k, simulated_time=simulated,
                real_time_factor=(simulated / wall) if wall > 0 else float("nan"),
                loop_cpu_time=cpu,
                fmu_warnings=sum(s.warnings for s in slaves))
    return recorder.result(meta)


def _progress_bar(total, wanted):
    if not wanted or not sys.stderr.isatty():
        return None
    try:
        from tqdm import tqdm
    except ImportError:
        return None
    return tqdm(total=total, unit="step", delay=2.0, file=sys.stderr, leave=False,
                dynamic_ncols=True, mininterval=0.5)


def _system_dict(system):
    """The System as plain data (stored with the results)."""
    e = system.experiment
    return {
        "components": [{"name": c.name, "model": c.model, "element": c.element, "kind": c.kind,
                        "parameters": dict(c.parameters), "inputs": dict(c.inputs)}
                       for c in system.components],
        "connections": [[k.src, k.src_var, k.dst, k.dst_var] for k in system.connections],
        "experiment": {"start": e.start, "stop": e.stop, "step": e.step, "algorithm": e.algorithm,
                       "output_interval": e.output_interval},
    }
