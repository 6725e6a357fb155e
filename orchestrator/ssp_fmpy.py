"""Run an SSP written by ``webline export-ssp`` with fmpy alone (fmpy, numpy, the standard library).

fmpy's own runner, ``fmpy.ssp.simulation.simulate_ssp`` (0.3.32),
cannot run a webline line; docs/fmus-in-other-tools.md shows why (it matches
parameters to components by bare name prefix, and it starts every connected
input at 0.0, so the speed loops' first step sees a roll radius and inertia of
0 and returns fmi2Discard). This module is the path that works with fmpy: a
fixed-step Jacobi master on fmpy's ``FMU2Slave`` that does what the SSD says.
It imports nothing from webline, so it can be copied next to an ``.ssp`` and run
wherever fmpy is installed::

    python ssp_fmpy.py line.ssp --stop 0.5 --step 1e-3 --csv line.csv

    from webline.orchestrator.ssp_fmpy import simulate
    r = simulate("line.ssp", stop_time=0.5, step_size=1e-3)   # r["lc9.T"], r["time"]

The calls per macro step are those of ``webline run`` with ``experiment.algorithm:
jacobi`` (orchestrator/master.py), so both give the same numbers:

1. per component: ``fmi2Instantiate``, ``fmi2SetupExperiment``, its
   ``ParameterBindings`` (inline values or ``.ssv`` files: parameters and the
   start values of inputs), ``fmi2EnterInitializationMode``,
   ``fmi2ExitInitializationMode``;
2. outputs at the start time: read every output, then resolve the
   feed-through outputs (those whose ``ModelStructure`` lists input
   dependencies): set their components' connected inputs from the sources,
   read the outputs again, until no value changes. An acyclic chain settles
   (a chain of n components in n + 1 passes); no settling after as many passes
   as there are components is an algebraic loop, reported as such;
3. every step: all connected inputs from the outputs at ``t``, ``fmi2DoStep``
   of every component from ``t`` to ``t + h``, read the outputs, resolve (2).

Jacobi holds every input over the step, so the step must be short enough for
the fastest coupled mode: the EWL needs 1 ms (docs/performance.md).
"""
import argparse
import sys
import zipfile
from xml.etree import ElementTree as ET

import numpy as np

SSD_NS = {"ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
          "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
          "osp": "http://opensimulationplatform.com/SSP/OSPAnnotations"}


class _Component:
    """One FMU instance of the SSD, with its connected inputs and its outputs as value-reference arrays."""

    def __init__(self, element, ssp_dir):
        import os
        from fmpy import extract, read_model_description
        from fmpy.fmi2 import FMU2Slave

        self.name = element.name
        fmu_file = os.path.join(ssp_dir, element.source)
        self.md = read_model_description(fmu_file, validate=False)
        self.var = {v.name: v for v in self.md.modelVariables}
        self.unzipdir = extract(fmu_file)
        self.fmu = FMU2Slave(guid=self.md.guid, unzipDirectory=self.unzipdir,
                             modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName=self.name)
        self.bindings = [p for b in element.parameterBindings for s in b.parameterValues for p in s.parameters]
        self.outputs = [c.name for c in element.connectors if c.kind == "output"]
        self.out_vr = [self.var[n].valueReference for n in self.outputs]
        # outputs that depend on inputs within the step (FMI ModelStructure)
        self.feedthrough = any(o.dependencies for o in self.md.outputs if o.variable.name in self.outputs)
        self.inputs, self.in_vr = [], []  # connected inputs, filled by simulate
        self.state = "loaded"  # -> "instantiated"; "failed" after fmi2Error/fmi2Fatal: never called again

    def set_value(self, name, text):
        v = self.var[name]
        vr = [v.valueReference]
        if v.type == "Real":
            self.fmu.setReal(vr, [float(text)])
        elif v.type in ("Integer", "Enumeration"):
            self.fmu.setInteger(vr, [int(text)])
        elif v.type == "Boolean":
            self.fmu.setBoolean(vr, [str(text).lower() in ("true", "1")])
        else:
            self.fmu.setString(vr, [str(text)])

    def close(self):
        import shutil
        try:
            if self.state == "instantiated":  # pythonfmu crashes in terminate/free after an error
                self.fmu.terminate()
                self.fmu.freeInstance()
        finally:
            shutil.rmtree(self.unzipdir, ignore_errors=True)


def default_experiment(ssp):
    """(start, stop, step) of the SSD's ``DefaultExperiment`` (the step from OSP's
    ``FixedStepAlgorithm baseStepSize``, None if absent)."""
    with zipfile.ZipFile(ssp) as z:
        root = ET.fromstring(z.read("SystemStructure.ssd"))
    de = root.find("ssd:DefaultExperiment", SSD_NS)
    if de is None:
        return 0.0, None, None
    fs = de.find(".//osp:FixedStepAlgorithm", SSD_NS)
    stop = de.get("stopTime")
    return (float(de.get("startTime", 0.0)), float(stop) if stop is not None else None,
            float(fs.get("baseStepSize")) if fs is not None else None)


def simulate(ssp, stop_time=None, step_size=None, start_time=None):
    """Run the SSP ``ssp`` (Jacobi, fixed step) and return a numpy structured array with
    ``time`` and one ``<component>.<output>`` field per output connector, one row at the
    start time and one after every step. Defaults: the SSD's ``DefaultExperiment``."""
    from fmpy import extract
    from fmpy.ssp.ssd import find_components, read_ssd
    import shutil

    t0_def, stop_def, step_def = default_experiment(ssp)
    t0 = t0_def if start_time is None else float(start_time)
    stop = stop_def if stop_time is None else float(stop_time)
    h = step_def if step_size is None else float(step_size)
    if stop is None or h is None:
        raise ValueError(f"{ssp}: no stop time or step in its DefaultExperiment: pass stop_time and step_size")
    ssd = read_ssd(str(ssp))
    elements = find_components(ssd.system)
    ssp_dir = extract(str(ssp))
    comps = []
    try:
        for el in elements:
            comps.append(_Component(el, ssp_dir))
        by_name = {c.name: c for c in comps}
        # output vector y: the outputs of every component, in SSD order
        offset, start = 0, {}
        for c in comps:
            start[c.name] = offset
            offset += len(c.outputs)
        y = np.zeros(offset)
        src_of = {}
        for k in ssd.system.connections:
            if getattr(k, "linearTransformation", None) is not None:
                raise ValueError(f"{ssp}: connection {k.startElement}.{k.startConnector} -> "
                                 f"{k.endElement}.{k.endConnector}: LinearTransformation is not supported")
            s = by_name[k.startElement]
            src_of[(k.endElement, k.endConnector)] = start[s.name] + s.outputs.index(k.startConnector)
        for c in comps:
            c.inputs = [n for (e, n) in src_of if e == c.name]
            c.in_vr = [c.var[n].valueReference for n in c.inputs]
            c.src = np.array([src_of[(c.name, n)] for n in c.inputs], dtype=int)
            c.sl = slice(start[c.name], start[c.name] + len(c.outputs))
        feedthrough = [c for c in comps if c.feedthrough and c.inputs]

        cur = [None]  # the component being called, named in errors

        def set_inputs(c):
            if c.inputs:
                c.fmu.setReal(c.in_vr, y[c.src].tolist())

        def get_outputs(c):
            if c.outputs:
                y[c.sl] = c.fmu.getReal(c.out_vr)

        def resolve(t):
            for _ in range(len(comps) + 1):
                before = y.copy()
                for c in feedthrough:
                    cur[0] = c
                    set_inputs(c)
                    get_outputs(c)
                if np.array_equal(y, before, equal_nan=True):
                    return
            raise RuntimeError(f"feed-through outputs do not settle at t = {t:.6g} s: algebraic loop")

        def run():
            for c in comps:
                cur[0] = c
                c.fmu.instantiate()
                c.state = "instantiated"
                c.fmu.setupExperiment(startTime=t0, stopTime=stop)
                for p in c.bindings:
                    c.set_value(p.name, p.value)
                c.fmu.enterInitializationMode()
                c.fmu.exitInitializationMode()
            for c in comps:
                cur[0] = c
                get_outputs(c)
            resolve(t0)
            rows[0] = y
            for k in range(n):
                t = t0 + k * h
                for c in comps:
                    cur[0] = c
                    set_inputs(c)
                for c in comps:
                    cur[0] = c
                    c.fmu.doStep(currentCommunicationPoint=t, communicationStepSize=h)
                for c in comps:
                    cur[0] = c
                    get_outputs(c)
                resolve(t + h)
                rows[k + 1] = y

        n = max(1, int(np.ceil((stop - t0) / h - 1e-9)))
        rows = np.empty((n + 1, len(y)))
        try:
            run()
        except Exception as exc:
            from fmpy.fmi1 import FMICallException
            c = cur[0]
            if isinstance(exc, FMICallException) and c is not None:
                if exc.status >= 3:
                    c.state = "failed"
                raise RuntimeError(f"component {c.name!r}: {exc}") from exc
            raise
    finally:
        for c in comps:
            try:
                c.close()
            except Exception:
                pass
        shutil.rmtree(ssp_dir, ignore_errors=True)
    names = [f"{c.name}.{o}" for c in comps for o in c.outputs]
    out = np.empty(n + 1, dtype=[("time", np.float64)] + [(nm, np.float64) for nm in names])
    out["time"] = t0 + h * np.arange(n + 1)
    for i, nm in enumerate(names):
        out[nm] = rows[:, i]
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description="Run a webline SSP with fmpy (Jacobi, fixed step).")
    ap.add_argument("ssp", help="the .ssp file (webline export-ssp)")
    ap.add_argument("--stop", type=float, help="stop time (s; default: the SSD's DefaultExperiment)")
    ap.add_argument("--step", type=float, help="macro step (s; default: the SSD's FixedStepAlgorithm)")
    ap.add_argument("--csv", help="write the outputs to this CSV file")
    args = ap.parse_args(argv)
    try:
        r = simulate(args.ssp, args.stop, args.step)
    except (OSError, ValueError, KeyError, zipfile.BadZipFile) as e:
        print(f"ssp_fmpy: {args.ssp}: {e}", file=sys.stderr)
        return 2
    if args.csv:
        np.savetxt(args.csv, np.column_stack([r[n] for n in r.dtype.names]), delimiter=",",
                   header=",".join(r.dtype.names), comments="", fmt="%.17g")
    print(f"{args.ssp}: {len(r)} rows, t = {r['time'][0]:g} .. {r['time'][-1]:g} s, "
          f"{len(r.dtype.names) - 1} outputs" + (f" -> {args.csv}" if args.csv else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
