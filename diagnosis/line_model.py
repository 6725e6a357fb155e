"""The line model as the diagnosis uses it: a layout, run conditions, edits, a co-simulation.

:class:`LineModel` builds a :class:`~orchestrator.system.System` from the
layout under a run's conditions (``orchestrator.layout.load_system`` with the
run's overrides), applies edits (eccentricity on an element, a drive made
non-ideal, a parameter scaled), runs the fmpy master and returns the columns
sampled on the run's time grid.

Two engines run the model: ``engine="fast"`` (default) the compiled monolithic ODE
of :mod:`orchestrator.engine` (the same physics models, RK4 in numba; variants of
one structure run as one batch), ``engine="cosim"`` the FMU co-simulation
(:func:`orchestrator.master.simulate`). :meth:`LineModel.confirm` runs the
co-simulation once whatever the engine, for a final check of a result.

Edits come in two forms: ``doc`` edits change the layout document itself
(what ``refined_layout.yaml`` holds) and ``system`` edits are callables on the
built System (screening only).
"""
import collections
import copy
import logging
import tempfile
import time as _time
import weakref
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

log = logging.getLogger("webline.diagnose")


class SimulationFailed(RuntimeError):
    pass


class _Columns(Mapping):
    """A simulation's columns by name (``self._names``), each made when first read."""

    def __contains__(self, k):
        return k in self._names

    def __iter__(self):
        return iter(self._names)

    def __len__(self):
        return len(self._names)


class RunColumns(_Columns):
    """A simulation's columns on the run's time grid, interpolated when first read:
    a diagnosis reads a handful of a simulation's ~50 columns (the load cells, an
    angle, the line speed), and interpolating all of them cost more than the fast
    engine's integration."""

    def __init__(self, t_model, cols, t_run):
        self._t, self._raw, self._t_run, self._done = t_model, cols, t_run, {}
        self._names = cols

    def __getitem__(self, k):
        v = self._done.get(k)
        if v is None:
            v = self._done[k] = np.interp(self._t_run, self._t, self._raw[k])  # run time is model time
            v.flags.writeable = False   # one Sim may serve several callers (LineModel.simulate_many)
        return v

    @property
    def nbytes(self):
        """Bytes of the outputs as simulated (the columns read, interpolated, add a little)."""
        return int(self._t.nbytes + sum(v.nbytes for v in self._raw.values()))


class ReadColumns(_Columns):
    """The columns a simulation's callers had read (its :class:`RunColumns`' interpolated
    ones, the dict shared), after the simulation itself was dropped: a caller that asks
    for another column gets the run simulated again (``refill()``, once; the engines are
    deterministic) and every column from it."""

    def __init__(self, names, done, refill):
        self._names, self._done, self._refill, self._full = names, done, refill, None

    def __getitem__(self, k):
        v = self._done.get(k)
        if v is None:
            if k not in self._names:
                raise KeyError(k)
            if self._full is None:
                self._full = self._refill().columns
            v = self._done[k] = self._full[k]
        return v


@dataclass
class Sim:
    system: object
    columns: dict          # column -> array on the run's time grid
    wall: float = 0.0
    key: tuple = None      # LineModel's memo key: what the simulation depends on

    def __getitem__(self, k):
        return self.columns[k]

    def __contains__(self, k):
        return k in self.columns


class LineModel:
    ENGINES = ("fast", "cosim")

    def __init__(self, layout_path, fmu_paths=None, progress=False, jobs=1, engine="fast"):
        from webline.diagnosis import layout_edit
        if engine not in self.ENGINES:
            raise ValueError(f"engine must be one of {', '.join(self.ENGINES)} (got {engine!r})")
        self.engine = engine
        self.path = Path(layout_path)
        if not self.path.is_file():
            raise FileNotFoundError(f"{self.path}: layout not found")
        self.doc = layout_edit.base_doc(self.path)
        self.progress = progress
        self._fmu_paths = fmu_paths
        self.n_sims = 0
        self.sim_wall = 0.0
        self._tmp = None
        self._written = {}   # derived layout text -> its temporary file
        # (run conditions, layout file) -> the Sim still held by some caller: the diagnosis's
        # stages ask again for simulations they or another stage made (the nominal under each
        # run, a form's estimate, the refined layout), about one in seven of them
        self._memo = weakref.WeakValueDictionary()
        self.n_reused = 0
        # ... and the last ones made, released or not (:meth:`_remember`): a stage asks again
        # for simulations an earlier stage had released (seed-62 c01: 85 of 1030 asked for
        # were made before, 12 of them still held; 50 asked for more than 64 requests later)
        self._recent = collections.OrderedDict()   # key -> (Sim, bytes, job), the last RECENT_BYTES
        self._read = collections.OrderedDict()     # key -> what ReadColumns needs, the last READ_BYTES
        self.n_refilled = 0
        # small results derived from simulations (a probe's PSDs), kept after the Sims are
        # released: a Sim is ~20 MB, what is derived from it a few kB (:meth:`derived`)
        self._derived = collections.OrderedDict()
        self.jobs = max(1, int(jobs))
        self._pool = None

    # ------------------------------------------------------------------ FMUs ----
    @property
    def fmu_paths(self):
        if self._fmu_paths is None:
            from webline.fmus.build import build_all
            self._fmu_paths = build_all(log=lambda m: log.info(m))
        return self._fmu_paths

    # ---------------------------------------------------------------- systems ----
    def system(self, run, doc=None, edits=(), written=None):
        """System of the layout (or of the derived layout ``doc``) under ``run``'s conditions;
        ``written``: the file :meth:`write_doc` already gave for ``doc``."""
        from webline.orchestrator.layout import load_system
        overrides = dict(run.overrides) if run is not None else {}
        if doc is None or not doc.get("set"):
            system = load_system(self.path, overrides or None)
        else:
            system = load_system(written or self.write_doc(doc), overrides or None)
        if run is not None:
            e = system.experiment
            if not any(k in overrides for k in ("experiment.duration", "experiment.stop")):
                e.stop = e.start + run.t[-1] + 1e-9
            elif e.stop < e.start + run.t[-1] - 1e-9:
                log.warning("run %s: the model stops at %.3g s, the data at %.3g s; "
                            "the model is extended to the data", run.name, e.stop, run.t[-1])
                e.stop = e.start + run.t[-1] + 1e-9
            dt = float(run.t[1] - run.t[0])
            k = max(1, int(round(dt / e.step)))
            e.output_interval = k * e.step
        for edit in edits:
            edit(system)
        return system

    def write_doc(self, doc, path=None):
        """Write a derived layout; to a temporary file unless ``path`` is given
        (then its ``base`` is made relative to the file's folder)."""
        from webline.diagnosis import layout_edit
        if path is not None:
            doc = layout_edit.relative_to(doc, Path(path).parent)
        text = ("# written by webline diagnose: the layout named in 'base' plus what the diagnosis added\n"
                + yaml.safe_dump(doc, sort_keys=False, allow_unicode=True))
        if path is None:
            # one file per distinct document: a variant is simulated once per run, and an
            # unchanged file is parsed once (orchestrator.layout_source's cache)
            written = self._written
            if text in written:
                return written[text]
            if self._tmp is None:
                self._tmp = tempfile.TemporaryDirectory(prefix="webline_diagnose_")
            path = written[text] = Path(self._tmp.name) / f"layout_{len(written) + 1}.yaml"
        Path(path).write_text(text)
        return Path(path)

    def cleanup(self):
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None
            self._written = {}
        # what was kept goes too (the keys name the derived layouts' files, gone with them)
        self._recent.clear()
        self._read.clear()
        if getattr(self, "_pool", None) is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def copy_doc(self):
        return copy.deepcopy(self.doc)

    # ------------------------------------------------------------- simulate ----
    def simulate(self, run, doc=None, edits=(), label=""):
        """Sim of the layout (or derived layout ``doc``) under ``run``, with this model's engine."""
        if self.engine == "fast":
            return self._simulate_fast(run, doc, edits, label)
        return self._simulate_cosim(run, doc, edits, label)

    def confirm(self, run, doc=None, edits=(), label="confirm"):
        """The same model run once by the FMU co-simulation (whatever ``self.engine``)."""
        return self._simulate_cosim(run, doc, edits, label)

    def _finish(self, run, system, result, wall, label, how):
        self.n_sims += 1
        self.sim_wall += wall
        log.info("  simulated %s%s: %.3g s of line in %.2f s (%s)", run.name, f" ({label})" if label else "",
                 run.t[-1], wall, how)
        ok = getattr(result, "ok", True)
        if not ok:
            raise SimulationFailed(f"simulation of run {run.name}{' (' + label + ')' if label else ''} "
                                   f"failed: {getattr(result, 'message', '')}")
        t, cols = _columns(result)
        return Sim(system, RunColumns(t, cols, np.asarray(run.t, float)), wall)

    def _simulate_fast(self, run, doc=None, edits=(), label=""):
        from webline.orchestrator import engine
        system = self.system(run, doc, edits)
        t0 = _time.perf_counter()
        result = engine.simulate(system)
        return self._finish(run, system, result, _time.perf_counter() - t0, label, "fast engine")

    def _simulate_cosim(self, run, doc=None, edits=(), label=""):
        from webline.orchestrator.master import simulate
        system = self.system(run, doc, edits)
        t0 = _time.perf_counter()
        result = simulate(system, fmu_paths=self.fmu_paths, progress=self.progress)
        return self._finish(run, system, result, _time.perf_counter() - t0, label, "co-simulation")

    def _simulate_many_fast(self, jobs, written=None):
        """Fast engine: jobs whose systems share structure and output times run as one batch;
        ``written``: per job, the derived layout's file if already written."""
        from webline.orchestrator import engine
        from webline.orchestrator.reference import output_times
        out = [None] * len(jobs)
        groups = {}
        systems = []
        for k, (run, doc, label) in enumerate(jobs):
            try:
                system = self.system(run, doc, written=written[k] if written else None)
                compiled = engine.compile_system(system)
                # a batch shares its held noise sources (load cells, drive ripple): they are in the key
                key = (compiled.structure, tuple(output_times(system.experiment)), float(system.experiment.start),
                       tuple(compiled.noise))
            except (SimulationFailed, ValueError) as exc:
                out[k] = exc
                systems.append(None)
                continue
            systems.append((system, compiled))
            groups.setdefault(key, []).append(k)
        for idx in groups.values():
            t0 = _time.perf_counter()
            try:
                if len(idx) == 1:
                    results = [engine.simulate(systems[idx[0]][0], compiled=systems[idx[0]][1])]
                else:
                    results = engine.simulate_batch([systems[k][0] for k in idx],
                                                    compiled=[systems[k][1] for k in idx])
            except ValueError as exc:
                for k in idx:
                    out[k] = exc
                continue
            wall = (_time.perf_counter() - t0) / len(idx)
            for k, result in zip(idx, results):
                run, doc, label = jobs[k]
                try:
                    out[k] = self._finish(run, systems[k][0], result, wall, label,
                                          f"fast engine, batch of {len(idx)}" if len(idx) > 1 else "fast engine")
                except SimulationFailed as exc:
                    out[k] = exc
        return out

    def memo_key(self, run, doc):
        """What a simulation depends on (its ``Sim.key``): the run's conditions and grid,
        and the layout file :meth:`system` would load (one file per distinct derived layout)."""
        layout = None if doc is None or not doc.get("set") else self.write_doc(doc)
        t = np.asarray(run.t, float)
        return (run.name, repr(sorted((run.overrides or {}).items())), float(t[-1]),
                float(t[1] - t[0]) if t.size > 1 else 0.0, layout)

    def simulate_many(self, jobs, keys=None):
        """Simulate ``jobs`` = [(run, doc, label)]; returns [Sim] in order (or the
        exception raised by a job in its place, for the caller to handle). ``keys``:
        the jobs' :meth:`memo_key`, when the caller has them already.

        A job whose run conditions and layout match a simulation some caller still
        holds, or one of the last made (:meth:`_remember`), gets that Sim (the engines are
        deterministic; its columns are read-only), as does a job repeated in one call.
        With ``self.jobs`` > 1 the simulations run in worker processes (spawned: every
        worker loads its own FMU instances; pythonfmu's module names are process-global),
        the pool kept for the whole diagnosis."""
        jobs = list(jobs)
        # computing a key dumps the document: a caller that has them passes them
        keys = list(keys) if keys is not None else [self.memo_key(run, doc) for run, doc, _ in jobs]
        out, first, todo = [None] * len(jobs), {}, []
        self._trim()
        for k, key in enumerate(keys):
            if key in first:
                continue
            hit = self._recalled(key)
            if hit is not None:
                out[k] = hit
                continue
            first[key] = k
            todo.append(k)
        # the key's layout file serves the simulation too (writing it dumps the document)
        for k, sim in zip(todo, self._simulate_many_uncached([jobs[k] for k in todo], [keys[k][-1] for k in todo])):
            out[k] = sim
            if isinstance(sim, Sim):
                sim.key = keys[k]
                self._memo[keys[k]] = sim
                self._remember(keys[k], sim, jobs[k])
        fresh = set(todo)
        for k, key in enumerate(keys):
            if out[k] is None:
                out[k] = out[first[key]]
            if k not in fresh:
                self.n_reused += 1
                log.debug("  reused a simulation of %s (%s)", jobs[k][0].name, jobs[k][2])
        return out

    def stats(self):
        """report.json's ``simulations``: made (``again``: of those, runs simulated again for
        a column not kept), their engine wall time, asked for again and handed back."""
        return {"count": self.n_sims, "wall_s": self.sim_wall, "reused": self.n_reused, "again": self.n_refilled}

    # seed-62 c01 and c08: 1018 -> 966 and 1216 -> 1175 simulations (19 and 10 of them a
    # column not kept), report.json unchanged, peak memory ~+250 MB;
    # budgets of 128 + 256 MB saved 1 and 10 more
    RECENT_BYTES = 32 * 2 ** 20   # simulations kept whole (outputs as simulated: ~10-20 MB a 60 s run)
    READ_BYTES = 128 * 2 ** 20    # ... then only the columns read (a few of ~50, on the run's grid)

    def _remember(self, key, sim, job):
        """Keep the new ``sim`` (of ``job``) whole among the last :data:`RECENT_BYTES`; one
        dropped from there keeps the columns its callers had read (:class:`ReadColumns`),
        among the last :data:`READ_BYTES` of such."""
        if not isinstance(sim.columns, RunColumns):
            return
        self._recent[key] = (sim, sim.columns.nbytes, job)
        self._trim()

    def _trim(self):
        while sum(v[1] for v in self._recent.values()) > self.RECENT_BYTES:
            old, (dropped, _, old_job) = self._recent.popitem(last=False)
            self._read[old] = (dropped.system, tuple(dropped.columns), dropped.columns._done, dropped.wall, old_job)
        # the columns read grow while a caller holds the Sim: counted anew each time
        while self._read and (self.READ_BYTES <= 0 or self.READ_BYTES < sum(
                sum(a.nbytes for a in v[2].values()) for v in self._read.values())):
            self._read.popitem(last=False)

    def _recalled(self, key):
        """The Sim of ``key`` if a caller holds it or :meth:`_remember` kept it, else None."""
        sim = self._memo.get(key)
        if key in self._recent:
            self._recent.move_to_end(key)
            return self._recent[key][0]
        if sim is not None or key not in self._read:
            return sim
        self._read.move_to_end(key)
        system, names, done, wall, old_job = self._read[key]

        def refill():
            self.n_refilled += 1
            log.debug("  simulating %s (%s) again for a column not kept", old_job[0].name, old_job[2])
            got = self._simulate_many_uncached([old_job], [key[-1]])[0]
            if isinstance(got, Exception):
                raise SimulationFailed(f"simulating run {old_job[0].name} ({old_job[2]}) again failed: {got}")
            return got

        sim = Sim(system, ReadColumns(names, done, refill), wall, key)
        self._memo[key] = sim
        return sim

    DERIVED_MAX = 512   # entries kept by :meth:`derived` (least recently used dropped)

    def derived(self, key):
        """What :meth:`keep` stored for ``key`` (None if nothing): results derived from
        deterministic simulations whose keys (``Sim.key``) are part of ``key``."""
        value = self._derived.get(key)
        if value is not None:
            self._derived.move_to_end(key)
        return value

    def keep(self, key, value):
        self._derived[key] = value
        self._derived.move_to_end(key)
        while len(self._derived) > self.DERIVED_MAX:
            self._derived.popitem(last=False)

    def _simulate_many_uncached(self, jobs, written=None):
        if self.engine == "fast":
            return self._simulate_many_fast(jobs, written)
        if self.jobs <= 1 or len(jobs) < 2:
            out = []
            for run, doc, label in jobs:
                try:
                    out.append(self.simulate(run, doc, label=label))
                except (SimulationFailed, ValueError) as exc:
                    out.append(exc)
            return out
        if self._pool is None:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor
            self._pool = ProcessPoolExecutor(max_workers=self.jobs, mp_context=multiprocessing.get_context("spawn"))
        paths = {k: str(v) for k, v in self.fmu_paths.items()}
        futures = [self._pool.submit(_worker_simulate, str(self.path), paths, run, doc, label)
                   for run, doc, label in jobs]
        from concurrent.futures.process import BrokenProcessPool
        out = []
        for (run, doc, label), fut in zip(jobs, futures):
            try:
                sim = fut.result()
            except (SimulationFailed, ValueError) as exc:
                out.append(exc)
                continue
            except BrokenProcessPool:
                # a worker died (e.g. the FMU files were rebuilt under it): finish in-process
                log.warning("  a simulation worker died; continuing without workers")
                self._pool.shutdown(wait=False, cancel_futures=True)
                self._pool = None
                self.jobs = 1
                done = len(out)
                return out + self._simulate_many_uncached(jobs[done:])
            self.n_sims += 1
            self.sim_wall += sim.wall
            log.info("  simulated %s%s: %.3g s of line in %.1f s (co-simulation worker)", run.name,
                     f" ({label})" if label else "", run.t[-1], sim.wall)
            out.append(sim)
        return out


def _worker_simulate(layout, fmu_paths, run, doc, label):
    model = LineModel(layout, {k: Path(v) for k, v in fmu_paths.items()}, engine="cosim")
    try:
        return model.simulate(run, doc, label=label)
    finally:
        model.cleanup()


def _columns(result):
    t = np.asarray(result.time, float)
    cols = getattr(result, "columns", None)
    if isinstance(cols, dict):
        return t, {k: np.asarray(v, float) for k, v in cols.items()}
    return t, {k: np.asarray(result[k], float) for k in cols}
