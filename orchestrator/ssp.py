"""Export a System as a standard SSP 1.0 package (``webline export-ssp``), and read one back.

The package is a zip holding

* ``SystemStructure.ssd``: one ``ssd:Component`` per FMU instance, pointing at
  ``resources/<Model>.fmu``; connectors (Real, with units) for every output
  and every connected input; the components' parameter and input start values
  as parameter bindings (inline ``ssv:ParameterSet``, or one ``.ssv`` file per
  component with ``parameter_files=True``); the connections (no
  ``LinearTransformation``, no unit conversion: connected variables share
  their unit); ``ssd:DefaultExperiment`` with start and stop time, the macro
  step in the form libcosim reads (``osp:FixedStepAlgorithm baseStepSize``)
  and webline's own experiment (step, algorithm, output interval) in an
  ``org.webline.experiment`` annotation;
* the FMUs under ``resources/``.

Unconnected inputs get no connector, only a parameter binding of their start
value: a connector of kind input that nothing feeds is set to 0 by
``fmpy.ssp.simulation`` at every step. Checked with libcosim (libcosimpy 0.0.6,
``CosimExecution.from_ssp_file``) and with ``fmpy.ssp.ssd.read_ssd`` (schema
validation); the names of XML prefixes matter to libcosim (it matches
``ssd:``, ``ssc:``, ``ssv:``, ``osp:`` literally), so they are fixed here.
"""
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

from webline.orchestrator.system import Component, Connection, Experiment, System

NS = {
    "ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
    "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
    "ssv": "http://ssp-standard.org/SSP1/SystemStructureParameterValues",
    "osp": "http://opensimulationplatform.com/SSP/OSPAnnotations",
    "wl": "https://github.com/webline/ssp-annotations",
}
for _p, _u in NS.items():
    ET.register_namespace(_p, _u)

OSP_ANNOTATION = "com.opensimulationplatform"
WEBLINE_ANNOTATION = "org.webline.experiment"
FMU_MIME = "application/x-fmu-sharedlibrary"


def _q(prefix, tag):
    return f"{{{NS[prefix]}}}{tag}"


def _num(value):
    return repr(float(value))


def _interfaces(models, fmu_dir=None):
    """{model: {"parameters": [...], "inputs": [...], "outputs": [...], "unit": {name: unit}}}
    from the FMU classes' declarations (the same data their modelDescription.xml is written from)."""
    from webline.orchestrator.reference import fmu_classes
    classes = fmu_classes()
    out = {}
    for m in models:
        if m not in classes:
            raise KeyError(f"no FMU script for model {m!r} (known: {', '.join(sorted(classes))})")
        cls = classes[m]
        params = list(cls.parameters())
        out[m] = {"parameters": [v.name for v in params], "inputs": [v.name for v in cls.INPUTS],
                  "outputs": [v.name for v in cls.OUTPUTS],
                  "unit": {v.name: v.unit for v in (*params, *cls.INPUTS, *cls.OUTPUTS)}}
    return out


def _parameter_set(parent, name, values, units=None):
    ps = ET.SubElement(parent, _q("ssv", "ParameterSet"), {"version": "1.0", "name": name})
    params = ET.SubElement(ps, _q("ssv", "Parameters"))
    for pname, value in values.items():
        p = ET.SubElement(params, _q("ssv", "Parameter"), {"name": pname})
        ET.SubElement(p, _q("ssv", "Real"), {"value": _num(value)})
    return ps


def ssd_tree(system, name="webline", parameter_files=False, fmu_source=lambda model: f"resources/{model}.fmu"):
    """(ElementTree root of SystemStructure.ssd, {archive path: ssv root}) for ``system``."""
    from webline.fmi_slave import UNITS
    problems = system.check()
    if problems:
        raise ValueError("system is not well formed:\n  " + "\n  ".join(problems))
    models = sorted({c.model for c in system.components})
    iface = _interfaces(models)
    connected = {(k.dst, k.dst_var) for k in system.connections}
    for k in system.connections:
        src_model = system.component(k.src).model
        dst_model = system.component(k.dst).model
        if k.src_var not in iface[src_model]["outputs"]:
            raise KeyError(f"connection {k}: {k.src_var!r} is not an output of {src_model}")
        if k.dst_var not in iface[dst_model]["inputs"]:
            raise KeyError(f"connection {k}: {k.dst_var!r} is not an input of {dst_model}")
        us, ud = iface[src_model]["unit"][k.src_var], iface[dst_model]["unit"][k.dst_var]
        if us != ud and "1" not in (us, ud):  # "1": a generic signal (Profile.y) takes any unit
            raise ValueError(f"connection {k}: units differ ({us} -> {ud}); SSP export does no unit conversion")

    root = ET.Element(_q("ssd", "SystemStructureDescription"),
                      {"version": "1.0", "name": name, "generationTool": "webline"})
    sys_el = ET.SubElement(root, _q("ssd", "System"), {"name": name})
    elements = ET.SubElement(sys_el, _q("ssd", "Elements"))
    ssv_files = {}
    used_units = set()
    for c in system.components:
        m = iface[c.model]
        comp = ET.SubElement(elements, _q("ssd", "Component"),
                             {"name": c.name, "type": FMU_MIME, "source": fmu_source(c.model),
                              "implementation": "CoSimulation"})
        conns = ET.SubElement(comp, _q("ssd", "Connectors"))
        kinds = [(v, "input") for v in m["inputs"] if (c.name, v) in connected]
        kinds += [(v, "output") for v in m["outputs"]]
        for var, kind in kinds:
            conn = ET.SubElement(conns, _q("ssd", "Connector"), {"name": var, "kind": kind})
            unit = m["unit"][var]
            if unit == "1":  # generic signal: no unit, so no importer sees a conversion to do
                ET.SubElement(conn, _q("ssc", "Real"))
            else:
                used_units.add(unit)
                ET.SubElement(conn, _q("ssc", "Real"), {"unit": unit})
        values = {}
        for group, allowed, what in ((c.parameters, m["parameters"], "parameter"),
                                     (c.inputs, m["inputs"], "input")):
            for var, value in group.items():
                if var not in allowed:
                    raise KeyError(f"component {c.name!r} ({c.model}) has no {what} {var!r}")
                values[var] = value
        if values:
            bindings = ET.SubElement(comp, _q("ssd", "ParameterBindings"))
            if parameter_files:
                path = f"parameters/{c.name}.ssv"
                ET.SubElement(bindings, _q("ssd", "ParameterBinding"),
                              {"type": "application/x-ssp-parameter-set", "source": path})
                holder = ET.Element("holder")
                ssv_files[path] = _parameter_set(holder, c.name, values)
            else:
                binding = ET.SubElement(bindings, _q("ssd", "ParameterBinding"),
                                        {"type": "application/x-ssp-parameter-set"})
                pv = ET.SubElement(binding, _q("ssd", "ParameterValues"))
                _parameter_set(pv, c.name, values)
    if system.connections:
        cons = ET.SubElement(sys_el, _q("ssd", "Connections"))
        for k in system.connections:
            ET.SubElement(cons, _q("ssd", "Connection"),
                          {"startElement": k.src, "startConnector": k.src_var,
                           "endElement": k.dst, "endConnector": k.dst_var})
    if used_units:
        units = ET.SubElement(root, _q("ssd", "Units"))
        for u in sorted(used_units):
            unit = ET.SubElement(units, _q("ssc", "Unit"), {"name": u})
            ET.SubElement(unit, _q("ssc", "BaseUnit"), {k: str(e) for k, e in UNITS[u].items()})
    exp = system.experiment
    de = ET.SubElement(root, _q("ssd", "DefaultExperiment"),
                       {"startTime": _num(exp.start), "stopTime": _num(exp.stop)})
    anns = ET.SubElement(de, _q("ssd", "Annotations"))
    a = ET.SubElement(anns, _q("ssc", "Annotation"), {"type": OSP_ANNOTATION})
    alg = ET.SubElement(a, _q("osp", "Algorithm"))
    ET.SubElement(alg, _q("osp", "FixedStepAlgorithm"), {"baseStepSize": _num(exp.step)})
    a = ET.SubElement(anns, _q("ssc", "Annotation"), {"type": WEBLINE_ANNOTATION})
    ET.SubElement(a, _q("wl", "Experiment"), {"step": _num(exp.step), "algorithm": exp.algorithm,
                                              "outputInterval": _num(exp.output_interval)})
    return root, ssv_files


def _xml_bytes(root):
    ET.indent(root, space="  ")
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True)


def export_ssp(system, out, fmu_dir=None, name=None, parameter_files=False, log=None):
    """Write ``system`` as an SSP 1.0 zip to ``out`` (the FMUs it uses under
    ``resources/``, built first if out of date). Returns the path."""
    from webline.fmus.build import DEFAULT_OUT, build_all
    out = Path(out)
    fmu_dir = Path(fmu_dir) if fmu_dir else DEFAULT_OUT
    fmus = build_all(fmu_dir, log=log or (lambda *a: None))
    name = name or system.meta.get("name") or out.stem
    root, ssv_files = ssd_tree(system, name=name, parameter_files=parameter_files)
    models = sorted({c.model for c in system.components})
    missing = [m for m in models if m not in fmus or not Path(fmus[m]).exists()]
    if missing:
        raise FileNotFoundError(f"no FMU for {', '.join(missing)} in {fmu_dir}")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".part")
    with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("SystemStructure.ssd", _xml_bytes(root))
        for path, ps in ssv_files.items():
            z.writestr(path, _xml_bytes(ps))
        for m in models:
            z.write(fmus[m], f"resources/{m}.fmu")
    tmp.replace(out)
    return out


# ---- running in libcosim ----------------------------------------------------------------
def simulate_libcosim(ssp, variables=None, stop=None, step=None, log_level="ERROR"):
    """Run an SSP in libcosim (libcosimpy, an optional dependency) and record
    ``variables`` (``<component>.<variable>``; default: every output of every
    component) after every macro step with a last-value observer.

    ``step``: macro step (s), default the SSP's ``FixedStepAlgorithm``;
    ``stop``: default the SSP's stop time. Returns (time array, {name: array})
    with rows at t = start + k*step, k = 1..n (after each step; libcosim
    initialises in its first step, so there is no row at t = start).
    """
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver
    import numpy as np

    log_output_level(getattr(CosimLogLevel, log_level))
    system = read_ssp(ssp)
    exp = system.experiment
    stop = exp.stop if stop is None else stop
    step = exp.step if step is None else step
    step_ns = int(round(step * 1e9))
    ex = CosimExecution.from_ssp_file(str(ssp), step_ns)
    observer = CosimObserver.create_last_value()
    ex.add_observer(observer)
    slaves = {}
    for info in ex.slave_infos():
        vs = {v.name.decode(): (v.reference, v.causality) for v in ex.slave_variables(info.index)}
        slaves[info.name.decode()] = (info.index, vs)
    if variables is None:
        variables = []
        for c in system.components:
            index, vs = slaves[c.name]
            variables += [f"{c.name}.{n}" for n, (_, causality) in vs.items() if causality == 2]  # output
    by_slave = {}
    for full in variables:
        comp, var = full.split(".", 1)
        index, vs = slaves[comp]
        by_slave.setdefault(index, []).append((full, vs[var][0]))
    n = int(round((stop - exp.start) / step))
    times = np.empty(n)
    data = {v: np.empty(n) for v in variables}
    for k in range(n):
        if not ex.step(1):
            raise RuntimeError(f"libcosim step {k + 1} failed at t={exp.start + k * step:.6g} s")
        times[k] = ex.status().current_time * 1e-9
        for index, items in by_slave.items():
            values = observer.last_real_values(index, [r for _, r in items])
            for (full, _), value in zip(items, values):
                data[full][k] = value
    return times, data


# ---- reading back ---------------------------------------------------------------------
def _read_parameter_set(ps):
    values = {}
    for p in ps.findall("ssv:Parameters/ssv:Parameter", NS):
        real = p.find("ssv:Real", NS)
        if real is None:
            raise ValueError(f"parameter {p.get('name')!r}: only Real values are supported")
        values[p.get("name")] = float(real.get("value"))
    return values


def read_ssp(path):
    """System of an SSP written by :func:`export_ssp` (components' models from their
    ``source`` file names; parameter bindings split into parameters and inputs by
    the FMU declarations; experiment from ``DefaultExperiment``)."""
    with zipfile.ZipFile(path) as z:
        root = ET.fromstring(z.read("SystemStructure.ssd"))

        def ssv(name):
            return ET.fromstring(z.read(name))

        comps = []
        for el in root.findall("ssd:System/ssd:Elements/ssd:Component", NS):
            model = Path(el.get("source")).stem
            values = {}
            for b in el.findall("ssd:ParameterBindings/ssd:ParameterBinding", NS):
                if b.get("source"):
                    values.update(_read_parameter_set(ssv(b.get("source"))))
                for ps in b.findall("ssd:ParameterValues/ssv:ParameterSet", NS):
                    values.update(_read_parameter_set(ps))
            comps.append((el.get("name"), model, values))
    iface = _interfaces(sorted({m for _, m, _ in comps}))
    components = []
    for name, model, values in comps:
        params = {k: v for k, v in values.items() if k in iface[model]["parameters"]}
        inputs = {k: v for k, v in values.items() if k not in params}
        components.append(Component(name=name, model=model, parameters=params, inputs=inputs))
    connections = [Connection(k.get("startElement"), k.get("startConnector"), k.get("endElement"), k.get("endConnector"))
                   for k in root.findall("ssd:System/ssd:Connections/ssd:Connection", NS)]
    exp = Experiment()
    de = root.find("ssd:DefaultExperiment", NS)
    if de is not None:
        exp.start = float(de.get("startTime", exp.start))
        exp.stop = float(de.get("stopTime", exp.stop))
        fs = de.find(f"ssd:Annotations/ssc:Annotation[@type='{OSP_ANNOTATION}']/osp:Algorithm/osp:FixedStepAlgorithm", NS)
        if fs is not None:
            exp.step = float(fs.get("baseStepSize"))
        wl = de.find(f"ssd:Annotations/ssc:Annotation[@type='{WEBLINE_ANNOTATION}']/wl:Experiment", NS)
        if wl is not None:
            exp.step = float(wl.get("step", exp.step))
            exp.algorithm = wl.get("algorithm", exp.algorithm)
            exp.output_interval = float(wl.get("outputInterval", exp.output_interval))
    return System(components, connections, exp, meta={"name": root.get("name")})
