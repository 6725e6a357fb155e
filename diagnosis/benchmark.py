"""Benchmark of ``webline diagnose`` on lines with hidden effects (issue #4, "Proof").

Generator, blind by construction
--------------------------------
A smaller line is derived from the EWL layout (:func:`derive_line`: the unwind
zone with an idler, a web-guide roller and the load-cell roller 9, the S-wrap
leader as speed master, the rewind zone with an idler and the load-cell
roller 19). :func:`draw_cases` draws cases from a seed: hidden eccentric
rollers and out-of-round rolls (harmonics 1..6, amplitudes 0.05-1 mm),
backlash or a compliant shaft on a driven element, several effects at once,
nothing at all (noise only), with one to three runs at different unwind radii
and speeds, some held out.

:func:`make_case` writes each case in two folders that never meet:

* ``blind/`` - what the diagnosis gets: the nominal layout ``line.yaml`` and
  per run a run file (experiment conditions only, neutral names ``run1``...)
  with its CSV (load cells, some in lbf headers; sometimes ``line_speed`` and
  an ``unwind.pulse`` column, whatever the hidden effect);
* ``truth/`` - the truth layout (the nominal one plus a ``set`` block with the
  effects) and ``truth.json`` (effects, true fundamentals, noise, oracle gap).

The "measured" data are the truth layout run by the fast engine
(:func:`orchestrator.engine.simulate`, the monolithic ODE compiled; ``engine="cosim"``:
co-simulated by the master, :func:`orchestrator.master.simulate`) plus Gaussian sensor noise.
:func:`diagnose_argv` builds the command line of the diagnosis from the blind
folder alone; it runs in a subprocess whose working directory is that folder.

Scorer
------
:func:`score_case` matches reported effects to the truth one to one by
(element, kind): an exact element match, or - when the true element is
physically indistinguishable from the reported one (same kind, equal radius,
same tension zone: it turns at the same speed and loads the same sensors) and
the report lists it in its ``tie`` (the candidates whose pattern across the
sensors fits as well; ``candidates`` in reports without one) - an "ambiguous"
match, counted but reported separately. :func:`summarize` aggregates precision / recall per
kind, the error of the fundamental frequency, false effects on noise-only
cases, in-sample and held-out gap shrinkage (NRMSE refined / nominal) and run
time; :func:`markdown` renders the table.
"""
import copy
import json
import math
import os
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import yaml

REPO = Path(__file__).resolve().parent.parent  # the checkout's root (installed: the webline package folder)
EWL = REPO / "scenarios" / "ewl.yaml"           # source checkouts only: a wheel ships no scenarios/
KEEP = ("unwind", "idler_u1", "guide_in", "roller9", "sw_leader", "idler_r1", "roller19", "rewind")
PERIODIC = ("eccentricity", "out_of_round")
DRIVE_KINDS = ("backlash", "compliance")
KINDS = PERIODIC + DRIVE_KINDS + ("sensor", "parameter")
LBF = 4.4482216152605
FPM = 0.3048 / 60.0
INCH = 0.0254
MM = 1e-3

# simulation settings of the benchmark line (both truth and diagnosis use them: the layout says so)
STEP = "2 ms"              # macro step; the EWL's own jacobi / 1 ms diverges at ~0.7 s on this commit
ALGORITHM = "gauss-seidel"
FS = 250.0                 # Hz, sample rate of the "measured" CSV (2 macro steps)
SETTLE = 1.0               # s, start-up skipped when computing true fundamentals and oracle gaps

# targets the benchmark reports against (never used to tune anything)
TARGETS = {"precision": 0.90, "recall": 0.90, "false_effects_noise_only": 0, "holdout_nrmse_ratio": 0.5}


# ============================================================== the line ====
def derive_line(src=EWL, keep=KEEP, *, step=STEP, algorithm=ALGORITHM, duration="10 s"):
    """The layout document of a smaller line derived from ``src`` (plain dict):
    the elements in ``keep`` (path order kept, each with its own span to the
    next kept element), their speed loops, the tension loops and sensors whose
    elements remain, and the experiment with the benchmark's step/algorithm."""
    doc = yaml.safe_load(Path(src).read_text())
    keep = list(keep)
    path = [copy.deepcopy(e) for e in doc["path"] if e["name"] in keep]
    missing = set(keep) - {e["name"] for e in path}
    if missing:
        raise ValueError(f"{src}: no element(s) {', '.join(sorted(missing))} to keep")
    path[-1].pop("span", None)
    out = {k: copy.deepcopy(v) for k, v in doc.items() if k not in ("path", "drives", "sensors", "experiment")}
    out["name"] = f"{doc.get('name', 'line')}_bench"
    out["description"] = (f"benchmark line derived from {Path(src).name}: " + ", ".join(keep))
    out["path"] = path
    drives = copy.deepcopy(doc["drives"])
    drives["speed_loops"] = {k: v for k, v in drives["speed_loops"].items() if k in keep}
    sensors = {k: v for k, v in (doc.get("sensors") or {}).items() if v["roller"] in keep}
    drives["tension_loops"] = {k: v for k, v in (drives.get("tension_loops") or {}).items()
                               if v["element"] in keep and v["load_cell"] in sensors}
    if drives["master"] not in keep:
        raise ValueError(f"the speed master {drives['master']!r} must be kept")
    out["drives"] = drives
    out["sensors"] = sensors
    exp = copy.deepcopy(doc["experiment"])
    exp.update(step=step, algorithm=algorithm, duration=duration)
    exp["tension"] = {z: v for z, v in (exp.get("tension") or {}).items() if z in drives["tension_loops"]}
    exp["roll_radius"] = {k: v for k, v in (exp.get("roll_radius") or {}).items() if k in keep}
    if not exp["roll_radius"]:
        exp.pop("roll_radius")
    out["experiment"] = exp
    return out


def write_yaml(path, doc, header=""):
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(header + yaml.safe_dump(doc, sort_keys=False, allow_unicode=True, width=110))
    return path


def line_facts(layout_path):
    """Per element: type, candidate kind, radius (m, SI), driven, tension zone index.

    Zones are the runs between consecutive driven elements; an element in
    between belongs to the zone, a driven element to none (it bounds two)."""
    from webline.orchestrator.layout import load_layout
    L = load_layout(layout_path)
    facts, zone = {}, -1
    for e in L.path:
        driven = e.type in ("unwind", "rewind", "driven_roller")
        if driven:
            zone += 1
        facts[e.name] = {"type": e.type, "kind": "out_of_round" if e.type in ("unwind", "rewind") else "eccentricity",
                         "radius_m": float(e.radius), "driven": driven, "zone": None if driven else zone}
    facts["_sensors"] = {n: s.roller for n, s in L.sensors.items()}
    facts["_zones"] = {n: z.element for n, z in L.drives.tension_loops.items()}
    facts["_master"] = L.drives.master
    return facts


def indistinguishable(facts, element, rtol=1e-3):
    """Elements the data cannot tell from ``element``: same kind, equal radius,
    same tension zone (always including ``element`` itself), sorted."""
    f = facts[element]
    out = {element}
    if f["zone"] is not None:
        for n, g in facts.items():
            if n.startswith("_") or n == element or g["zone"] != f["zone"] or g["kind"] != f["kind"]:
                continue
            if abs(g["radius_m"] - f["radius_m"]) <= rtol * f["radius_m"]:
                out.add(n)
    return sorted(out)


# ============================================================ case specs ====
@dataclass
class Effect:
    kind: str                    # eccentricity / out_of_round / backlash / compliance
    element: str
    C_m: list = field(default_factory=list)     # periodic: amplitudes of harmonics 1..n (m)
    psi_rad: list = field(default_factory=list)
    drive: dict = field(default_factory=dict)   # drive kinds: motor_inertia, stiffness, damping, backlash (SI)
    inertia_shift: float = 0.0   # kg.m2 moved from the element to the motor (total inertia unchanged)


@dataclass
class RunSpec:
    name: str
    speed_fpm: float = 200.0
    unwind_radius_in: float = 6.375
    duration_s: float = 10.0
    holdout: bool = False
    profile: str = "constant"    # constant / tension_step / speed_ramp
    noise_N: float = 0.05
    lbf: bool = False            # load-cell headers in lbf
    extra: list = field(default_factory=list)   # "line_speed", "unwind.pulse"
    seed: int = 0


@dataclass
class Case:
    id: str
    category: str                # eccentric / out_of_round / noise_only / backlash / compliance / multi
    effects: list
    runs: list
    seed: int = 0


def _rotating(facts):
    return [n for n, f in facts.items() if not n.startswith("_")]


def draw_periodic(rng, facts, element, amp_range=(0.05 * MM, 1.0 * MM)):
    """Harmonics 1..6 of an eccentric roller / out-of-round roll: a dominant order
    (1 for a roller, 1 or 2 for a roll) with an amplitude log-uniform in
    ``amp_range``, up to 3 more orders of 1..6, each log-uniform between the
    bottom of the range and the dominant amplitude; phases uniform."""
    kind = facts[element]["kind"]
    lo, hi = amp_range
    dom = 1 if kind == "eccentricity" else int(rng.choice([1, 2]))
    n_more = int(rng.integers(0, 4))
    others = [int(j) for j in rng.choice([j for j in range(1, 7) if j != dom], size=n_more, replace=False)]
    a_dom = float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
    C = [0.0] * max([dom] + others)
    C[dom - 1] = a_dom
    for j in others:
        C[j - 1] = float(math.exp(rng.uniform(math.log(lo), math.log(max(a_dom, lo * 1.0001)))))
    psi = [float(rng.uniform(-math.pi, math.pi)) if c > 0 else 0.0 for c in C]
    return Effect(kind, element, C_m=C, psi_rad=psi)


def _element_inertia(layout_doc, element):
    from webline.orchestrator.units import quantity
    e = next(x for x in layout_doc["path"] if x["name"] == element)
    if "core_inertia" in e:
        return quantity(e["core_inertia"], "inertia"), "core_inertia"
    if "inertia" in e:
        return quantity(e["inertia"], "inertia"), "inertia"
    m, R, ri = (quantity(e[k], d) for k, d in (("mass", "mass"), ("radius", "length"), ("inner_radius", "length")))
    return m * (R * R + ri * ri) / 2.0, None


def _material_inertia(layout_doc, element):
    """Inertia of the material wound on ``element`` at the layout's radius (0 for an
    element without a core: rollers)."""
    from webline.orchestrator.units import quantity
    e = next(x for x in layout_doc["path"] if x["name"] == element)
    if "core_radius" not in e or "radius" not in e:
        return 0.0
    web = layout_doc["web"]
    rho, w = quantity(web["density"], "[mass]/[length]**3"), quantity(web["width"], "length")
    R, rc = quantity(e["radius"], "length"), quantity(e["core_radius"], "length")
    return math.pi / 2.0 * rho * w * (R ** 4 - rc ** 4)


def draw_drive(rng, kind, element, layout_doc):
    """A non-ideal drive on ``element``: a quarter to a third of its inertia moved
    to the motor side (total unchanged) behind a shaft. Backlash: 0.5-3 deg
    total, stiff shaft (torsional mode 40-60 Hz). Compliance: no backlash,
    torsional mode 4-15 Hz, damping ratio 2-10 %."""
    J, _ = _element_inertia(layout_doc, element)
    Jm = float(J * rng.uniform(0.25, 0.33))
    Je = J - Jm
    Jr = Jm * Je / J                              # reduced inertia of the two-mass mode
    if kind == "backlash":
        f = rng.uniform(40.0, 60.0)
        zeta = 0.1
        backlash = math.radians(float(rng.uniform(0.5, 3.0)))
    else:
        f = rng.uniform(4.0, 15.0)
        zeta = rng.uniform(0.02, 0.10)
        backlash = 0.0
    w = 2 * math.pi * f
    k = Jr * w * w
    c = 2 * zeta * math.sqrt(k * Jr)
    # the drawn f counts the element's own inertia only; a roll's material sits on the load
    # side too, so its two-mass mode at the start radius is lower: the yardstick for a found shaft
    mode = math.sqrt(k * (1.0 / Jm + 1.0 / (Je + _material_inertia(layout_doc, element)))) / (2 * math.pi)
    return Effect(kind, element, drive={"motor_inertia": Jm, "stiffness": float(k), "damping": float(c),
                                        "backlash": float(backlash), "torsional_hz": float(f),
                                        "mode_hz": float(mode)},
                  inertia_shift=Jm)


CATEGORY_CYCLE = ("eccentric", "out_of_round", "noise_only", "eccentric", "multi", "backlash",
                  "eccentric", "out_of_round", "compliance", "eccentric", "noise_only", "multi")


def draw_cases(n, seed=0, *, quick=False, layout_doc=None, facts=None):
    """``n`` case specs drawn from ``seed``. Categories follow CATEGORY_CYCLE
    (eccentric ~1/3, out-of-round, noise-only, multi ~1/6 each, backlash and
    compliance ~1/12 each); ``quick``: short single-run cases, cycle
    eccentric / noise_only / out_of_round."""
    if layout_doc is None:
        layout_doc = derive_line()
    if facts is None:
        import tempfile
        with tempfile.TemporaryDirectory() as d:
            facts = line_facts(write_yaml(Path(d) / "line.yaml", layout_doc))
    rng = np.random.default_rng(seed)
    rot = _rotating(facts)
    rollers = [n for n in rot if facts[n]["kind"] == "eccentricity"]
    rolls = [n for n in rot if facts[n]["kind"] == "out_of_round"]
    driven = [n for n in rot if facts[n]["driven"]]
    master = facts["_master"]
    cycle = ("eccentric", "noise_only", "out_of_round") if quick else CATEGORY_CYCLE
    cases = []
    for i in range(n):
        cat = cycle[i % len(cycle)]
        cseed = int(rng.integers(0, 2 ** 31 - 1))
        r = np.random.default_rng(cseed)
        effects = []
        if cat == "eccentric":
            effects.append(draw_periodic(r, facts, str(r.choice(rollers))))
        elif cat == "out_of_round":
            # the unwind is where out-of-round rolls come from; the rewind now and then
            effects.append(draw_periodic(r, facts, "unwind" if r.random() < 0.75 or "rewind" not in rolls
                                         else "rewind"))
        elif cat in DRIVE_KINDS:
            el = master if r.random() < 0.6 else str(r.choice([d for d in driven if d != master]))
            effects.append(draw_drive(r, "backlash" if cat == "backlash" else "compliance", el, layout_doc))
        elif cat == "multi":
            a = str(r.choice(rollers))
            b = str(r.choice([x for x in rot if x != a and
                              (facts[x]["zone"] is None or facts[x]["zone"] != facts[a]["zone"]
                               or abs(facts[x]["radius_m"] - facts[a]["radius_m"]) > 1e-3 * facts[a]["radius_m"])]))
            effects += [draw_periodic(r, facts, a), draw_periodic(r, facts, b)]
            if r.random() < 0.3:
                effects.append(draw_drive(r, str(r.choice(DRIVE_KINDS)), master, layout_doc))
        cases.append(Case(id=f"c{i + 1:02d}", category=cat, effects=effects,
                          runs=_draw_runs(r, cat, quick), seed=cseed))
    return cases


def _draw_runs(r, cat, quick):
    """One to three runs: a fit run at 150-250 ft/min and a full-ish roll;
    in about half the cases a held-out run at another speed and a smaller
    unwind radius; now and then a second fit run. Conditions are drawn the
    same way whatever the hidden effect (drive effects need a torque
    reversal or a speed change to show, so they never get a constant run)."""
    if quick:
        return [RunSpec("run1", speed_fpm=float(r.choice([180.0, 200.0, 220.0])), unwind_radius_in=6.375,
                        duration_s=4.0, noise_N=float(r.uniform(0.02, 0.08)), lbf=bool(r.random() < 0.5),
                        seed=int(r.integers(0, 2 ** 31 - 1)))]

    def one(name, holdout):
        prof = str(r.choice(["constant", "constant", "tension_step", "speed_ramp"]))
        if cat in DRIVE_KINDS and prof == "constant":
            prof = str(r.choice(["tension_step", "speed_ramp"]))
        extra = []
        if r.random() < 0.4:
            extra.append("line_speed")
        if r.random() < 0.3:
            extra.append("unwind.pulse")
        return RunSpec(name, speed_fpm=float(np.round(r.uniform(150.0, 250.0), 0)),
                       unwind_radius_in=float(np.round(r.uniform(5.25, 6.375), 3)),
                       duration_s=10.0 if not holdout else 8.0, holdout=holdout, profile=prof,
                       noise_N=float(np.round(math.exp(r.uniform(math.log(0.02), math.log(0.2))), 4)),
                       lbf=bool(r.random() < 0.5), extra=extra, seed=int(r.integers(0, 2 ** 31 - 1)))

    runs = [one("run1", False)]
    runs[0].unwind_radius_in = 6.375
    if r.random() < 0.2:
        runs.append(one(f"run{len(runs) + 1}", False))
    if r.random() < 0.55:
        h = one(f"run{len(runs) + 1}", True)
        # another speed and a smaller roll than every fit run: a real extrapolation
        h.speed_fpm = float(np.clip(runs[0].speed_fpm + r.choice([-1, 1]) * r.uniform(30, 60), 140, 260).round())
        h.unwind_radius_in = float(np.round(r.uniform(5.0, 5.75), 3))
        runs.append(h)
    return runs


# ============================================================== making ====
def fmt_len(x):
    return f"{x / MM:.6g} mm"


def truth_set(case, layout_doc):
    """The layout ``set`` block that adds the case's effects to the nominal line."""
    from webline.orchestrator.units import quantity
    s = {}
    for e in case.effects:
        if e.kind in PERIODIC:
            s[f"path.{e.element}.eccentricity"] = {"C": [fmt_len(c) for c in e.C_m],
                                                   "psi": [f"{p:.6g} rad" for p in e.psi_rad]}
        elif e.kind in DRIVE_KINDS:
            d = e.drive
            s[f"drives.speed_loops.{e.element}.drive"] = {
                "motor_inertia": f"{d['motor_inertia']:.6g} kg*m^2", "stiffness": f"{d['stiffness']:.6g} N*m/rad",
                "damping": f"{d['damping']:.6g} N*m*s/rad", "backlash": f"{math.degrees(d['backlash']):.6g} deg"}
            J, key = _element_inertia(layout_doc, e.element)
            el = next(x for x in layout_doc["path"] if x["name"] == e.element)
            if key is None:  # mass-given roller: the motor takes part of the mass
                s[f"path.{e.element}.mass"] = f"{quantity(el['mass'], 'mass') * (J - e.inertia_shift) / J:.6g} kg"
            else:
                s[f"path.{e.element}.{key}"] = f"{J - e.inertia_shift:.6g} kg*m^2"
        else:
            raise ValueError(f"cannot add an effect of kind {e.kind!r}")
    return s


def run_conditions(run):
    """The experiment block of a run file (also the truth simulation's overrides)."""
    exp = {"duration": f"{run.duration_s:g} s", "line_speed": f"{run.speed_fpm:g} ft/min",
           "roll_radius": {"unwind": f"{run.unwind_radius_in:g} in"}}
    if run.profile == "tension_step":
        exp["tension"] = {"unwind_zone": {"initial": "15 lbf", "segments": [
            {"hold": f"{0.45 * run.duration_s:.3g} s"}, {"step_to": "18 lbf"}]}}
    elif run.profile == "speed_ramp":
        v0 = run.speed_fpm
        exp["line_speed"] = {"initial": f"{v0:g} ft/min", "segments": [
            {"hold": f"{0.3 * run.duration_s:.3g} s"},
            {"ramp_to": f"{v0 * 0.8:.4g} ft/min", "duration": "1.5 s"}]}
    return exp


def _overrides(exp):
    """Run-file experiment block -> dotted overrides, as ``diagnosis.runs`` reads them."""
    from webline.diagnosis.runs import _experiment_overrides
    return _experiment_overrides(exp, "<run>", {})


def make_case(case, folder, line_doc, fmu_paths=None, engine="fast"):
    """Write the case (blind/ and truth/ folders), simulating the truth layout for
    every run (``engine`` "fast": :mod:`orchestrator.engine`; "cosim": the FMU master).
    Returns the truth record (also in truth/truth.json)."""
    from webline.orchestrator.layout import load_system
    if engine == "fast":
        from webline.orchestrator.engine import simulate as _fast

        def simulate(system, fmu_paths=None, progress=False):
            return _fast(system)
    elif engine == "cosim":
        from webline.orchestrator.master import simulate
    else:
        raise ValueError(f"engine must be 'fast' or 'cosim' (got {engine!r})")
    from webline.diagnosis.synthetic import pulse_train
    folder = Path(folder)
    blind, truth_dir = folder / "blind", folder / "truth"
    line = write_yaml(blind / "line.yaml", line_doc, "# nominal line of the diagnosis benchmark\n")
    facts = line_facts(line)
    tset = truth_set(case, line_doc)
    truth_layout = write_yaml(truth_dir / "truth_layout.yaml",
                              {"base": os.path.relpath(line, truth_dir), "set": tset},
                              "# the nominal line plus the hidden effects\n")
    t_gen = time.perf_counter()
    runs_out = []
    hidden = range(len(case.effects))
    # the truth without each hidden effect (detectability: :func:`effect_record`)
    without = {i: write_yaml(truth_dir / f"without_{i}.yaml", {
        "base": os.path.relpath(line, truth_dir),
        "set": truth_set(replace(case, effects=[e for j, e in enumerate(case.effects) if j != i]),
                         line_doc)}) for i in hidden}
    seen = {i: [] for i in hidden}
    for run in case.runs:
        exp = run_conditions(run)
        system = load_system(truth_layout, _overrides(exp))
        system.experiment.output_interval = 1.0 / FS
        res = simulate(system, fmu_paths=fmu_paths, progress=False)
        if not res.ok:
            raise RuntimeError(f"case {case.id} {run.name}: truth simulation failed: {res.message[:400]}")
        t = np.asarray(res.time)
        rng = np.random.default_rng(run.seed)
        cols, clean, noise = {}, {}, {}
        for lc in sorted(facts["_sensors"]):
            y = np.asarray(res[f"{lc}.T"], float)
            n = rng.normal(0.0, run.noise_N, len(t))
            clean[lc], noise[lc] = y, n
            if run.lbf:
                cols[f"{lc} [lbf]"] = (y + n) / LBF
            else:
                cols[f"{lc} [N]"] = y + n
        for i in ([] if run.holdout else hidden):
            s0 = load_system(without[i], _overrides(exp))
            s0.experiment.output_interval = 1.0 / FS
            res0 = simulate(s0, fmu_paths=fmu_paths, progress=False)
            if res0.ok:
                seen[i].append(effect_record(case.effects[i], run, t, res, res0, clean, noise))
        master = facts["_master"]
        if "line_speed" in run.extra:
            cols["line_speed [ft/min]"] = np.asarray(res[f"{master}.v"]) / FPM
        if "unwind.pulse" in run.extra:
            cols["unwind.pulse"] = pulse_train(np.asarray(res["unwind.theta"]))
        csv = blind / f"{run.name}.csv"
        _write_csv(csv, t, cols)
        write_yaml(blind / f"{run.name}.yaml", {"data": csv.name, "experiment": exp})
        settle = t >= t[0] + SETTLE
        fund = {}
        for el in _rotating(facts):
            th = np.asarray(res[f"{el}.theta"], float)[settle]
            tt = t[settle]
            fund[el] = float(abs(th[-1] - th[0]) / (2 * math.pi) / (tt[-1] - tt[0]))
        torque = {}  # motor torque range of each driven element: backlash shows only if it reverses
        for el in _rotating(facts):
            col = f"{el}_speed_pi.tau"
            if facts[el]["driven"] and col in res:
                tau = np.asarray(res[col], float)[settle]
                torque[el] = {"min_Nm": float(tau.min()), "max_Nm": float(tau.max())}
        runs_out.append({
            "name": run.name, "holdout": run.holdout, "spec": asdict(run), "conditions": exp,
            "fundamental_hz": fund, "drive_torque": torque,
            "sensors": {lc: {"noise_rms_N": float(np.sqrt(np.mean(noise[lc] ** 2))),
                             "std_measured_N": float(np.std(clean[lc] + noise[lc])),
                             "n": int(len(t))} for lc in clean},
        })
    effects = [_effect_truth(e, facts) for e in case.effects]
    for i, per in seen.items():
        if per:
            from webline.diagnosis.benchmark_independent import _combine
            effects[i]["detectable"] = {**_combine([v for r in per for v in r["sensors"].values()]), "runs": per}
    truth = {"id": case.id, "category": case.category, "seed": case.seed,
             "effects": effects,
             "runs": runs_out, "generation_s": time.perf_counter() - t_gen, "truth_engine": engine,
             "blind_folder": str(blind), "truth_layout": str(truth_layout)}
    (truth_dir / "truth.json").write_text(json.dumps(truth, indent=1))
    return truth


def effect_record(effect, run, t, res, res0, clean, noise):
    """One fit run's record of how visible a hidden effect is at each load cell:
    ``res`` / ``res0`` the truth with / without it, ``clean`` / ``noise`` the
    tensions and the noise added (see
    :func:`diagnosis.benchmark_independent.effect_visibility`)."""
    from webline.diagnosis.benchmark_independent import effect_visibility
    t = np.asarray(t, float)
    m = t >= t[0] + min(1.0, 0.1 * run.duration_s)  # the diagnosis's settled window
    col = f"{effect.element}_speed_pi.tau"
    tau = np.asarray(res[col], float)[m] if col in res else None
    out = {"run": run.name, "sensors": {}}
    for lc, y in clean.items():
        y0 = np.asarray(res0[f"{lc}.T"], float)
        out["sensors"][lc] = effect_visibility(effect.kind, t[m], y[m], y0[m], noise[lc][m], FS, tau=tau,
                                               torsional_hz=(effect.drive or {}).get("torsional_hz"))
    return out


def _effect_truth(e, facts):
    d = asdict(e)
    if e.kind in PERIODIC:
        d["indistinguishable"] = indistinguishable(facts, e.element)
        d["dominant_order"] = int(np.argmax(e.C_m)) + 1
    else:
        d["indistinguishable"] = [e.element]
    return d


def _write_csv(path, t, cols):
    names = list(cols)
    arr = np.column_stack([t] + [cols[n] for n in names])
    np.savetxt(path, arr, delimiter=",", header=",".join(["time [s]"] + names), comments="", fmt="%.9g")


def diagnose_argv(blind, out, holdout=(), python=None, extra=()):
    """Command line of the diagnosis: the nominal layout and the run files of the
    blind folder, nothing else (``holdout``: names of runs passed with
    ``--holdout``). Paths are relative to ``blind``, the subprocess's working
    directory, except ``out``. ``--no-confirm``: the benchmark measures the
    method, and its time target is for the fast engine alone."""
    blind = Path(blind)
    runs = sorted(p.name for p in blind.glob("*.yaml") if p.name != "line.yaml")
    fit = [r for r in runs if Path(r).stem not in holdout]
    hold = [r for r in runs if Path(r).stem in holdout]
    argv = [python or sys.executable, "-m", "webline.cli", "diagnose", "line.yaml", *fit,
            "--out", str(Path(out).resolve()), "--quiet", "--no-confirm", *extra]
    if hold:
        argv += ["--holdout", *hold]
    return argv


def holdout_names(truth):
    return [r["name"] for r in truth["runs"] if r["holdout"]]


def run_diagnosis(truth, out, timeout=1800, python=None, extra=()):
    """Run ``webline diagnose`` on the blind folder of ``truth`` in a subprocess.
    Returns {"report": dict or None, "wall_s", "returncode", "stderr"}."""
    blind = Path(truth["blind_folder"])
    argv = diagnose_argv(blind, out, holdout_names(truth), python, extra)
    env = dict(os.environ)
    if (REPO / "pyproject.toml").is_file():  # a source checkout; never an installed package's own folder
        env["PYTHONPATH"] = str(REPO) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    t0 = time.perf_counter()
    cpu0 = _children_cpu()
    rc, err = _run_with_timeout(argv, blind, env, timeout)
    wall = time.perf_counter() - t0
    cpu = _children_cpu() - cpu0
    rep = None
    rp = Path(out) / "report.json"
    if rc == 0 and rp.exists():
        rep = json.loads(rp.read_text())
    out_ = {"report": rep, "wall_s": wall, "cpu_s": cpu, "returncode": rc, "stderr": (err or "")[-3000:],
            "argv": argv}
    partial = Path(out) / "report_partial.json"
    if rep is None and partial.exists():
        # what a stopped diagnosis had measured (diagnosis.partial): named, never scored
        try:
            doc = json.loads(partial.read_text())
            out_["partial"] = {"file": str(partial), "stage": doc.get("stopped", {}).get("stage"),
                               "stages_done": doc.get("stages_done")}
        except (OSError, ValueError):
            out_["partial"] = {"file": str(partial)}
    return out_


TIMEOUT_GRACE = 60.0   # s between the terminate signal at the time limit and the kill


def _run_with_timeout(argv, cwd, env, timeout, grace=None):
    """(returncode, stderr) of ``argv``; at ``timeout`` seconds it is terminated (SIGTERM, which
    a diagnosis takes as Ctrl-C and writes what its stages had measured, report_partial.json;
    not SIGINT, which a benchmark started in the background passes on ignored) and killed if
    it has not stopped ``grace`` seconds later. A timed-out run returns -9."""
    import signal
    grace = TIMEOUT_GRACE if grace is None else grace
    p = subprocess.Popen(argv, cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        _, err = p.communicate(timeout=timeout)
        return p.returncode, err
    except subprocess.TimeoutExpired:
        p.send_signal(signal.SIGTERM)
        try:
            _, err = p.communicate(timeout=grace)
        except subprocess.TimeoutExpired:
            p.kill()
            _, err = p.communicate()
        return -9, f"timeout after {timeout:g} s\n{err or ''}"


def _children_cpu():
    """CPU seconds (user + system) of the finished child processes of this process."""
    try:
        import resource
        r = resource.getrusage(resource.RUSAGE_CHILDREN)
        return r.ru_utime + r.ru_stime
    except (ImportError, OSError):
        return 0.0


# =============================================================== scoring ====
def _cands(eff):
    c = [x.get("element") for x in (eff.get("candidates") or []) if isinstance(x, dict)]
    return c or [eff.get("element")]


def score_case(truth, report):
    """Match the report's effects to the truth one to one by (element, kind).

    Exact: same element and kind. Ambiguous: same kind, the true element among
    the reported effect's candidates and physically indistinguishable from the
    reported element. Exact matches are made first. Returns
    {matches: [...], false: [...], missed: [...], ...} with per-match
    frequency and amplitude errors (periodic kinds)."""
    truths = list(truth["effects"])
    reported = list((report or {}).get("effects") or [])
    used_t, used_r, matches = set(), set(), []
    for mode in ("exact", "ambiguous"):
        for ri, r in enumerate(reported):
            if ri in used_r:
                continue
            for ti, t in enumerate(truths):
                if ti in used_t or r.get("kind") != t["kind"]:
                    continue
                if mode == "exact":
                    ok = r.get("element") == t["element"]
                else:
                    # the report's tie when it gives one (the candidates its pattern does not exclude)
                    ok = (t["element"] in (r.get("tie") or _cands(r))
                          and r.get("element") in t.get("indistinguishable", [t["element"]]))
                if ok:
                    used_t.add(ti)
                    used_r.add(ri)
                    matches.append(_match_detail(mode, t, r, truth))
                    break
    false = [{"element": r.get("element"), "kind": r.get("kind"), "candidates": _cands(r),
              "explained_share": r.get("explained_share"), "confidence": r.get("confidence")}
             for ri, r in enumerate(reported) if ri not in used_r]
    missed = [{"element": t["element"], "kind": t["kind"]} for ti, t in enumerate(truths) if ti not in used_t]
    return {"matches": matches, "false": false, "missed": missed, "n_true": len(truths),
            "n_reported": len(reported)}


def _match_detail(mode, t, r, truth):
    d = {"mode": mode, "kind": t["kind"], "element": t["element"], "reported_element": r.get("element"),
         "candidates": _cands(r), "confidence": r.get("confidence")}
    if t["kind"] == "compliance":   # a shaft is found on its element; how well its mode is placed is reported
        dr = t.get("drive") or {}
        f_true, f_rep = dr.get("mode_hz") or dr.get("torsional_hz"), r.get("fundamental_hz")
        d["torsional_true_hz"], d["torsional_reported_hz"] = f_true, f_rep
        d["torsional_rel_error"] = abs(f_rep - f_true) / f_true if f_rep and f_true else None
    if t["kind"] in PERIODIC:
        fit = [x for x in truth["runs"] if not x["holdout"]] or truth["runs"]
        f_true = float(np.mean([x["fundamental_hz"][t["element"]] for x in fit]))
        f_rep = r.get("fundamental_hz")
        d["f_true_hz"] = f_true
        d["f_reported_hz"] = f_rep
        d["f_rel_error"] = abs(f_rep - f_true) / f_true if f_rep and f_true > 0 else None
        j = int(t.get("dominant_order") or (int(np.argmax(t["C_m"])) + 1))
        h = {int(x["order"]): x for x in (r.get("harmonics") or [])}
        C_true = t["C_m"][j - 1]
        d["dominant_order"] = j
        if j in h and C_true > 0:
            d["amp_rel_error"] = abs(h[j]["amplitude"] - C_true) / C_true
            dp = (h[j]["phase"] - t["psi_rad"][j - 1] + math.pi) % (2 * math.pi) - math.pi
            d["phase_error_rad"] = abs(dp)
        else:
            d["amp_rel_error"] = None
            d["phase_error_rad"] = None
    return d


def most_affected(report):
    """(sensor, [(key, hold, {nominal, refined} NRMSE or None)]) at the sensor with the
    largest in-sample nominal RMS error, for the in-sample and held-out blocks of the
    report's ``holdout``; None if the report has no in-sample gap."""
    hs = (report or {}).get("holdout") or {}
    ins = hs.get("in_sample") or {}
    cand = [(v["nominal"].get("rms") or 0.0, s) for s, v in ins.items() if v and v.get("nominal")]
    if not cand:
        return None
    sensor = max(cand)[1]
    blocks = []
    for key, block, hold in (("in_sample", ins, False), ("held_out", hs.get("out_of_sample") or {}, True)):
        v = block.get(sensor)
        ok = v and v.get("nominal") and v.get("refined")
        blocks.append((key, hold, (v["nominal"]["nrmse"], v["refined"]["nrmse"]) if ok else None))
    return sensor, blocks


def gap_of(report, truth):
    """In-sample and held-out NRMSE (nominal, refined, ratio) at the most affected
    sensor (largest nominal RMS error in sample), plus the oracle ratio: what the
    true model would reach (the noise floor)."""
    found = most_affected(report)
    if found is None:
        return None
    sensor, blocks = found
    out = {"sensor": sensor}
    for key, hold, nr in blocks:
        if nr is None:
            out[key] = None
            continue
        n, r = nr
        out[key] = {"nominal": n, "refined": r, "ratio": r / n if n else None,
                    "oracle_ratio": _oracle(truth, sensor, hold, n)}
    return out


def _oracle(truth, sensor, hold, nominal_nrmse):
    """NRMSE of the true (noise-free) model over the runs, divided by the nominal NRMSE."""
    lc = sensor[:-2] if sensor.endswith(".T") else sensor
    e2 = d2 = 0.0
    for r in truth["runs"]:
        if r["holdout"] != hold or lc not in r["sensors"]:
            continue
        s = r["sensors"][lc]
        e2 += s["noise_rms_N"] ** 2 * s["n"]
        d2 += s["std_measured_N"] ** 2 * s["n"]
    if d2 <= 0 or not nominal_nrmse:
        return None
    return math.sqrt(e2 / d2) / nominal_nrmse


def _ratio(a, b):
    return a / b if b else None


def summarize(results):
    """Aggregate scores over cases. ``results``: list of {truth, report, score,
    gap, wall_s, returncode, ...} (as :func:`evaluate_case` returns)."""
    per_kind = {}
    for k in KINDS:
        per_kind[k] = {"true": 0, "reported": 0, "matched": 0, "exact": 0, "ambiguous": 0}
    f_err, amp_err, ph_err, ft_err = [], [], [], []
    noise_only = {"cases": 0, "false_effects": 0, "cases_with_false": 0}
    gaps_in, gaps_out, gaps_in_ecc, gaps_out_ecc, oracle_out_ecc = [], [], [], [], []
    failed = []
    walls, cpus = [], []
    detect = {k: {"true": 0, "matched": 0, "unknown": 0} for k in DRIVE_KINDS}
    for res in results:
        tr, sc = res["truth"], res["score"]
        walls.append(res.get("wall_s") or 0.0)
        for t in tr["effects"]:
            if t["kind"] in DRIVE_KINDS:
                det = effect_detectable(tr, t)
                dk = detect[t["kind"]]
                if det is None:
                    dk["unknown"] += 1
                elif det:
                    dk["true"] += 1
                    dk["matched"] += any(m["kind"] == t["kind"] and m["element"] == t["element"]
                                         for m in sc["matches"])
        if res.get("cpu_s"):
            cpus.append(res["cpu_s"])
        if res.get("report") is None:
            failed.append({"id": tr["id"], "returncode": res.get("returncode"),
                           "stderr_tail": (res.get("stderr") or "")[-400:],
                           **({"stopped_in": res["partial"].get("stage")} if res.get("partial") else {})})
        for t in tr["effects"]:
            per_kind.setdefault(t["kind"], {"true": 0, "reported": 0, "matched": 0, "exact": 0, "ambiguous": 0})
            per_kind[t["kind"]]["true"] += 1
        for m in sc["matches"]:
            pk = per_kind[m["kind"]]
            pk["matched"] += 1
            pk["reported"] += 1
            pk[m["mode"]] += 1
            if m.get("f_rel_error") is not None:
                f_err.append(m["f_rel_error"])
            if m.get("torsional_rel_error") is not None:
                ft_err.append(m["torsional_rel_error"])
            if m.get("amp_rel_error") is not None and m["mode"] == "exact":
                amp_err.append(m["amp_rel_error"])
                ph_err.append(m["phase_error_rad"])
        for f in sc["false"]:
            per_kind.setdefault(f["kind"], {"true": 0, "reported": 0, "matched": 0, "exact": 0, "ambiguous": 0})
            per_kind[f["kind"]]["reported"] += 1
        if not tr["effects"] and res.get("report") is not None:
            noise_only["cases"] += 1
            noise_only["false_effects"] += len(sc["false"])
            noise_only["cases_with_false"] += bool(sc["false"])
        g = res.get("gap")
        has_ecc = any(t["kind"] in PERIODIC for t in tr["effects"])
        if g:
            if g.get("in_sample") and g["in_sample"]["ratio"] is not None and tr["effects"]:
                gaps_in.append(g["in_sample"]["ratio"])
                if has_ecc:
                    gaps_in_ecc.append(g["in_sample"]["ratio"])
            if g.get("held_out") and g["held_out"]["ratio"] is not None and tr["effects"]:
                gaps_out.append(g["held_out"]["ratio"])
                if has_ecc:
                    gaps_out_ecc.append(g["held_out"]["ratio"])
                    if g["held_out"].get("oracle_ratio") is not None:
                        oracle_out_ecc.append(g["held_out"]["oracle_ratio"])
    for k, v in per_kind.items():
        v["precision"] = _ratio(v["matched"], v["reported"])
        v["recall"] = _ratio(v["matched"], v["true"])
    per = {k: v for k, v in per_kind.items() if v["true"] or v["reported"]}
    pm = {key: sum(per_kind[k][key] for k in PERIODIC) for key in ("true", "reported", "matched", "exact", "ambiguous")}
    pm["precision"] = _ratio(pm["matched"], pm["reported"])
    pm["recall"] = _ratio(pm["matched"], pm["true"])
    halved = [x <= TARGETS["holdout_nrmse_ratio"] for x in gaps_out_ecc]
    s = {
        "cases": len(results),
        "diagnose_failures": failed,
        "per_kind": per,
        "periodic": pm,
        "fundamental_rel_error": _stats(f_err),
        "torsional_rel_error": _stats(ft_err),
        "dominant_amplitude_rel_error": _stats(amp_err),
        "dominant_phase_error_rad": _stats(ph_err),
        "noise_only": noise_only,
        # hidden drive effects that can be seen at all (:func:`effect_detectable`), and how many were found
        "backlash_with_torque_reversal": detect["backlash"],
        "drive_detectable": detect,
        "gap": {
            "in_sample_ratio": _stats(gaps_in), "held_out_ratio": _stats(gaps_out),
            "in_sample_ratio_periodic": _stats(gaps_in_ecc), "held_out_ratio_periodic": _stats(gaps_out_ecc),
            "held_out_oracle_ratio_periodic": _stats(oracle_out_ecc),
            "held_out_halved_periodic": {"cases": len(halved), "halved": int(sum(halved))},
        },
        "runtime_s": _stats(walls),
        "cpu_s": _stats(cpus),
        "targets": TARGETS,
    }
    s["verdict"] = _verdicts(s)
    return s


def torque_reverses(truth, element, eps=0.01):
    """Whether the motor torque of ``element`` changes sign (beyond ``eps`` N.m) in
    a fit run of the truth simulation (None: not recorded)."""
    seen = None
    for r in truth["runs"]:
        if r["holdout"]:
            continue
        tq = (r.get("drive_torque") or {}).get(element)
        if tq is None:
            continue
        seen = bool(seen) or (tq["min_Nm"] < -eps and tq["max_Nm"] > eps)
    return seen


def effect_detectable(truth, effect):
    """Whether a hidden effect can be seen in the fit runs at all (None: not
    known). Measured where the case records it (``effect["detectable"]``: the
    truth simulated with and without the effect against what else the data
    hold, :func:`diagnosis.benchmark_independent.detectability`); else a
    backlash only where its drive torque reverses (:func:`torque_reverses`)."""
    d = effect.get("detectable")
    if isinstance(d, dict) and "detectable" in d:
        return bool(d["detectable"])
    if effect["kind"] == "backlash":
        return torque_reverses(truth, effect["element"])
    return None


def _stats(x):
    x = [float(v) for v in x if v is not None and math.isfinite(v)]
    if not x:
        return {"n": 0, "median": None, "mean": None, "max": None, "min": None}
    a = np.array(x)
    return {"n": len(x), "median": float(np.median(a)), "mean": float(a.mean()), "max": float(a.max()),
            "min": float(a.min()), "p90": float(np.percentile(a, 90))}


def _verdicts(s):
    v = {}
    for k in PERIODIC:
        pk = s["per_kind"].get(k)
        if pk:
            v[f"{k}_precision"] = _pass(pk["precision"], TARGETS["precision"])
            v[f"{k}_recall"] = _pass(pk["recall"], TARGETS["recall"])
    no = s["noise_only"]
    v["no_invented_effect"] = ("n/a" if not no["cases"] else
                               "pass" if no["false_effects"] <= TARGETS["false_effects_noise_only"] else "fail")
    h = s["gap"]["held_out_halved_periodic"]
    v["held_out_gap_halved"] = ("n/a" if not h["cases"] else "pass" if h["halved"] == h["cases"] else
                                f"fail ({h['halved']}/{h['cases']})")
    return v


def _pass(x, target):
    if x is None:
        return "n/a"
    return "pass" if x >= target else "fail"


def _pct(x):
    return "-" if x is None else f"{100 * x:.0f} %"


def _pct2(x):
    return "-" if x is None else f"{100 * x:.2g} %"


def _num(x, fmt="{:.3g}"):
    return "-" if x is None else fmt.format(x)


def markdown(summary, results=None, meta=None):
    """The README table (and a per-case table when ``results`` are given)."""
    s = summary
    L = []
    if meta:
        line = meta.get("line") or {}
        L.append(f"Benchmark of `webline diagnose` (`webline diagnose-bench`, diagnosis/benchmark.py): "
                 f"{s['cases']} cases, seed {meta.get('seed')}, {meta.get('mode', 'full')} mode, "
                 f"{meta.get('jobs', 1)} parallel jobs, total wall {meta.get('wall_s', 0) / 60:.1f} min on "
                 f"{meta.get('cpus', '?')} CPUs.")
        if results:
            cpu = sum(r.get("cpu_s") or 0.0 for r in results)
            gen = sum(r.get("generation_s") or 0.0 for r in results)
            la = meta.get("load_average_end")
            L.append(f"Diagnosis CPU time {cpu / 60:.1f} min in all, truth simulations {gen / 60:.1f} min (wall)"
                     + (f"; load average at the end {la[0]:.1f} (a shared machine: wall times are inflated, an "
                        f"idle machine needs about (CPU + truth) / jobs = {(cpu + gen) / 60 / max(1, meta.get('jobs', 1)):.1f} min)"
                        if la else "") + ".")
        code = meta.get("code") or {}
        if code.get("commit"):
            L.append(f"Code: commit {code['commit']}" + (f" plus uncommitted changes in "
                                                         f"{', '.join(code['uncommitted'])}"
                                                         if code.get("uncommitted") else "") + ".")
        L.append("")
        if line:
            L.append(f"Line: {', '.join(line.get('elements', []))} (derived from {line.get('derived_from')}; "
                     f"{line.get('algorithm')}, step {line.get('step')}), load cells lc9 and lc19 sampled at "
                     f"{line.get('sample_rate_hz', 0):g} Hz. Each case hides effects drawn from the seed "
                     "(eccentric rollers / out-of-round rolls with harmonics 1-6 of 0.05-1 mm, backlash or a "
                     "compliant shaft on a driven element, several at once, or nothing) in 1-3 runs of 8-10 s "
                     "at 150-260 ft/min and unwind radii 5-6.375 in (some held out); the measured data are the "
                     "truth layout run by the fast engine (the compiled monolithic ODE; within 1e-5 of the LSODA "
                     "reference) plus 0.02-0.2 N of sensor noise. The diagnosis runs "
                     "in a subprocess that sees only the nominal layout and the run files. A reported effect "
                     "counts when its (element, kind) is the truth's, or - counted as *ambiguous* - when the "
                     "true element is among its candidates and physically indistinguishable from it (equal "
                     "radius in one tension zone). NRMSE ratios are refined/nominal at the load cell with the "
                     "largest nominal error; the oracle is what the true model reaches (the noise floor).")
            L.append("")
    L.append("| measure | value | target | verdict |")
    L.append("|---|---|---|---|")
    for k in PERIODIC:
        pk = s["per_kind"].get(k)
        if not pk:
            continue
        amb = f" (of which {pk['ambiguous']} ambiguous)" if pk["ambiguous"] else ""
        L.append(f"| {k}: precision | {_pct(pk['precision'])} ({pk['matched']}/{pk['reported']}){amb} | "
                 f">= 90 % | {s['verdict'].get(k + '_precision', 'n/a')} |")
        L.append(f"| {k}: recall | {_pct(pk['recall'])} ({pk['matched']}/{pk['true']}) | >= 90 % | "
                 f"{s['verdict'].get(k + '_recall', 'n/a')} |")
    for k, pk in s["per_kind"].items():
        if k in PERIODIC:
            continue
        note = ""
        dd = s.get("drive_detectable") or {"backlash": s.get("backlash_with_torque_reversal") or {}}
        rv = dd.get(k) or {}
        if k in DRIVE_KINDS and pk["true"] and rv.get("unknown", 0) < pk["true"]:
            basis = ("measured, else a torque reversal in a fit run" if k == "backlash"
                     else "truth with and without it against the measurement error, the ripple's level and "
                     "the inertia profiled out")
            note = (f"; {rv.get('true', 0)} of the {pk['true']} hidden detectable ({basis}), "
                    f"{rv.get('matched', 0)} of those found")
            if rv.get("unknown"):
                note += f", {rv['unknown']} not known"
        L.append(f"| {k}: precision / recall | {_pct(pk['precision'])} ({pk['matched']}/{pk['reported']}) / "
                 f"{_pct(pk['recall'])} ({pk['matched']}/{pk['true']}){note} | - | - |")
    no = s["noise_only"]
    L.append(f"| invented effects on noise-only cases | {no['false_effects']} in {no['cases']} cases | 0 | "
             f"{s['verdict']['no_invented_effect']} |")
    fe = s["fundamental_rel_error"]
    L.append(f"| fundamental frequency error (matched periodic) | median {_pct2(fe['median'])}, max "
             f"{_pct2(fe['max'])} (n={fe['n']}) | - | - |")
    te = s.get("torsional_rel_error") or {"n": 0}
    if te["n"]:
        L.append(f"| torsional mode of a found shaft against the truth's two-mass mode (matched compliance; a roll's with its material) | median "
                 f"{_pct2(te['median'])}, max {_pct2(te['max'])} (n={te['n']}) | - | - |")
    ae = s["dominant_amplitude_rel_error"]
    pe = s["dominant_phase_error_rad"]
    L.append(f"| dominant harmonic amplitude / phase error (exact matches) | median {_pct2(ae['median'])}, max "
             f"{_pct2(ae['max'])} / median {_num(pe['median'], '{:.2g}')} rad (n={ae['n']}) | - | - |")
    g = s["gap"]
    L.append(f"| in-sample NRMSE refined/nominal, cases with an effect | median {_num(g['in_sample_ratio']['median'])}"
             f" (n={g['in_sample_ratio']['n']}) | - | - |")
    h = g["held_out_halved_periodic"]
    L.append(f"| held-out NRMSE refined/nominal, periodic effect present | median "
             f"{_num(g['held_out_ratio_periodic']['median'])}, max {_num(g['held_out_ratio_periodic']['max'])} "
             f"(n={g['held_out_ratio_periodic']['n']}; halved in {h['halved']}/{h['cases']}; noise-floor "
             f"oracle median {_num(g['held_out_oracle_ratio_periodic']['median'])}) | <= 0.5 | "
             f"{s['verdict']['held_out_gap_halved']} |")
    rt = s["runtime_s"]
    cp = s.get("cpu_s") or {"n": 0}
    cpu_txt = (f"; CPU median {_num(cp['median'], '{:.0f}')} s, max {_num(cp['max'], '{:.0f}')} s"
               if cp.get("n") else "")
    L.append(f"| diagnose run time per case | wall median {_num(rt['median'], '{:.0f}')} s, max "
             f"{_num(rt['max'], '{:.0f}')} s{cpu_txt} | - | - |")
    if s["diagnose_failures"]:
        L.append(f"| diagnose failures | {len(s['diagnose_failures'])}: "
                 f"{', '.join(f['id'] for f in s['diagnose_failures'])} | 0 | - |")
    if results:
        L += ["", "| case | category | hidden (element: kind) | reported (element: kind [candidates]) | "
              "f err | NRMSE ratio in / held out | wall / CPU s |", "|---|---|---|---|---|---|---|"]
        for res in results:
            tr, sc, gp = res["truth"], res["score"], res.get("gap") or {}
            hid = "; ".join(f"{t['element']}: {t['kind']}" for t in tr["effects"]) or "none"
            rep = res.get("report")
            if rep is None:
                got = f"diagnose failed (rc {res.get('returncode')})"
                if (res.get("partial") or {}).get("stage"):
                    got += f", stopped in stage '{res['partial']['stage']}' (report_partial.json kept)"
            else:
                got = "; ".join(f"{e.get('element')}: {e.get('kind')}"
                                + (f" [{', '.join(_cands(e))}]" if len(_cands(e)) > 1 else "")
                                for e in rep.get("effects") or []) or "none"
            fe = [m.get("f_rel_error") for m in sc["matches"] if m.get("f_rel_error") is not None]
            gi = (gp.get("in_sample") or {}).get("ratio")
            go = (gp.get("held_out") or {}).get("ratio")
            L.append(f"| {tr['id']} | {tr['category']} | {hid} | {got} | "
                     f"{', '.join(f'{100 * x:.2g} %' for x in fe) or '-'} | {_num(gi, '{:.2f}')} / "
                     f"{_num(go, '{:.2f}')} | {res.get('wall_s', 0):.0f} / {_num(res.get('cpu_s'), '{:.0f}')} |")
    return "\n".join(L) + "\n"


# ============================================================ one case ====
def evaluate_case(case, root, line_doc, fmu_paths=None, timeout=1800, extra=(), make=None):
    """Make a case (``make``, default :func:`make_case`), diagnose it blind, score
    it. Returns the result record."""
    make = make or make_case
    root = Path(root)
    folder = root / "cases" / case.id
    t0 = time.perf_counter()
    try:
        truth = make(case, folder, line_doc, fmu_paths)
    except Exception as exc:  # a truth simulation that failed: recorded, not scored
        return {"truth": {"id": case.id, "category": case.category, "effects": [asdict(e) for e in case.effects],
                          "runs": []}, "generation_error": str(exc)[:2000], "report": None,
                "score": {"matches": [], "false": [], "missed": [], "n_true": 0, "n_reported": 0}}
    gen = time.perf_counter() - t0
    d = run_diagnosis(truth, folder / "diagnosis", timeout=timeout, extra=extra)
    rep = d["report"]
    res = {"truth": truth, "report": rep, "wall_s": d["wall_s"], "cpu_s": d.get("cpu_s"), "generation_s": gen,
           "returncode": d["returncode"], "stderr": d["stderr"] if rep is None else "", "argv": d["argv"],
           "score": score_case(truth, rep), "gap": gap_of(rep, truth)}
    if d.get("partial"):
        res["partial"] = d["partial"]
    (folder / "result.json").write_text(json.dumps(
        {k: res[k] for k in ("wall_s", "cpu_s", "generation_s", "returncode", "stderr", "argv", "partial")
         if k in res}, indent=1))
    return res


def load_case(folder):
    """Re-read a finished case folder (truth, report, run time) and score it again."""
    folder = Path(folder)
    truth = json.loads((folder / "truth" / "truth.json").read_text())
    rp = folder / "diagnosis" / "report.json"
    rep = json.loads(rp.read_text()) if rp.exists() else None
    meta = json.loads((folder / "result.json").read_text()) if (folder / "result.json").exists() else {}
    if "wall_s" not in meta:
        meta["wall_s"] = ((rep or {}).get("timings_s") or {}).get("total", 0.0)
    res = {"truth": truth, "report": rep, **meta, "score": score_case(truth, rep), "gap": gap_of(rep, truth)}
    res.setdefault("returncode", 0 if rep is not None else None)
    return res


def compact(res):
    """A result record without the bulky report (effects and gap kept)."""
    rep = res.get("report")
    out = {k: v for k, v in res.items() if k != "report"}
    if rep is not None:
        out["reported_effects"] = [{k: e.get(k) for k in ("element", "kind", "candidates", "fundamental_hz",
                                                          "harmonics", "explained_share", "confidence")}
                                   for e in rep.get("effects") or []]
        out["reported_gap"] = rep.get("holdout")
        out["timings_s"] = rep.get("timings_s")
        out["simulations"] = rep.get("simulations")
    return out
