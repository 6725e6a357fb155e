"""Small fmpy helpers for the element-FMU tests: one FMU instance with a captured
log, and a fixed-step loop that orders calls the way libcosim's fixed-step
algorithm does (so the two masters can be compared call for call)."""
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                       fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)
from fmpy import calloc, free

_UNZIPPED = {}


def unzipped(path):
    """(model description, extraction folder) of an FMU, extracted once per process."""
    key = str(path)
    if key not in _UNZIPPED:
        _UNZIPPED[key] = (read_model_description(key), extract(key))
    return _UNZIPPED[key]


class Instance:
    """One FMU instance. ``messages``: (status, text) of everything the FMU logged."""

    def __init__(self, path, name="x", parameters=None, inputs=None):
        self.md, unzipdir = unzipped(path)
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}
        self.variables = {v.name: v for v in self.md.modelVariables}
        self.messages = []

        def logger(env, instance, status, category, message):
            self.messages.append((status, message.decode() if message else ""))

        # The callbacks must outlive the instance: keep references.
        self._callbacks = fmi2CallbackFunctions()
        self._callbacks.logger = fmi2CallbackLoggerTYPE(logger)
        self._callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        self._callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        self.fmu = FMU2Slave(guid=self.md.guid, unzipDirectory=unzipdir,
                             modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName=name)
        self.fmu.instantiate(callbacks=self._callbacks, loggingOn=True)
        self.start_values = {**(parameters or {}), **(inputs or {})}
        self.alive = True

    def log_text(self):
        return "\n".join(m for _, m in self.messages)

    def set(self, values):
        if values:
            names = list(values)
            self.fmu.setReal([self.vr[n] for n in names], [float(values[n]) for n in names])

    def get(self, names):
        return self.fmu.getReal([self.vr[n] for n in names])

    def setup(self, t0=0.0):
        self.fmu.setupExperiment(startTime=t0)
        self.fmu.enterInitializationMode()
        self.set(self.start_values)

    def init(self, t0=0.0):
        """Setup, start values, exit initialisation (raises FMICallException on failure)."""
        self.setup(t0)
        self.fmu.exitInitializationMode()
        return self

    def step(self, t, h):
        self.fmu.doStep(currentCommunicationPoint=t, communicationStepSize=h)

    def free(self):
        if self.alive:
            self.alive = False
            try:
                self.fmu.terminate()
            except FMICallException:
                pass
            self.fmu.freeInstance()


def run_libcosim_order(instances, connections, h, n, record):
    """Fixed-step co-simulation in libcosim's order of calls.

    ``instances``: {name: Instance} (start values set by ``setup``);
    ``connections``: [(src, src_var, dst, dst_var)]; ``record``: {name: [vars]}.
    libcosim reads every output right after a simulator's step (or
    initialisation call) and sets the connected inputs just before that
    simulator's next call; initialisation runs one pass per simulator to
    propagate start values. Returns ([t_1..t_n], {"comp.var": [values]}).
    """
    names = list(instances)
    outs = {s: sorted({sv for src, sv, _, _ in connections if src == s} | set(record.get(s, ())))
            for s in names}
    cache = {s: {} for s in names}
    pending = {s: {} for s in names}

    def read(s):
        cache[s] = dict(zip(outs[s], instances[s].get(outs[s]))) if outs[s] else {}

    def transfer():
        for src, sv, dst, dv in connections:
            pending[dst][dv] = cache[src][sv]

    def apply(s):
        instances[s].set(pending[s])
        pending[s] = {}

    for s in names:
        instances[s].setup(0.0)
        read(s)
    for _ in range(len(names)):
        for s in names:
            apply(s)
            read(s)
        transfer()
    for s in names:
        apply(s)
        instances[s].fmu.exitInitializationMode()
        read(s)
    transfer()
    times, data = [], {f"{s}.{v}": [] for s, vs in record.items() for v in vs}
    for k in range(n):
        t = k * h
        for s in names:
            apply(s)
            instances[s].step(t, h)
            read(s)
        transfer()
        times.append((k + 1) * h)
        for s, vs in record.items():
            for v in vs:
                data[f"{s}.{v}"].append(cache[s][v])
    return times, data
