"""The master's macro-step loop in compiled code: a list of operations run by a small C routine.

:mod:`orchestrator.master` plans what one macro step does (which inputs to gather from
which outputs, which FMU to set, step and read, in which order) and then only replays
that plan. Replaying it in Python costs a ctypes call, a numpy gather and some
interpreter work around every FMI call, about a quarter of the loop on the EWL; here
the same plan is a flat array of operations that ``webline_run`` executes for a number
of macro steps, calling the FMUs' ``fmi2SetReal``/``fmi2DoStep``/``fmi2GetReal``
through their function pointers, the way a C co-simulation host calls them.

The routine is compiled once with the system C compiler (``cc``, ``gcc``) into a cache
folder; without a compiler the master keeps its Python loop (``available()`` is False),
and ``WEBLINE_MASTER_LOOP=python`` forces the Python loop. The operations are the ones
the Python loop performs, in the same order, on the same ``y``/``u`` arrays, with the
same floating-point expressions (``t = t0 + k h``, ``u -= h rate``; compiled with
``-ffp-contract=off``), so both loops give bit-identical results.

It is loaded with :class:`ctypes.CDLL`: the Python lock is released for the whole block and
every Python FMU (pythonfmu) takes it back in each call, exactly as in the Python loop's
ctypes calls and in a C host. (Keeping the lock held with ``PyDLL`` was no faster, and three
runs in about sixty ended with a heap-corruption abort at exit that was not reproduced
since; with ``CDLL`` the FMUs see the same lock state as in every other host.)
"""
import ctypes
import hashlib
import math
import os
import shutil
import subprocess
import tempfile
from ctypes import POINTER, Structure, c_double, c_int, c_long, c_size_t, c_uint, c_void_p
from pathlib import Path

SOURCE = r"""
#include <stddef.h>

typedef int (*set_fn)(void *, const unsigned *, size_t, const double *);
typedef int (*get_fn)(void *, const unsigned *, size_t, double *);
typedef int (*step_fn)(void *, double, double, int);

typedef struct {
    long code;            /* 0 gather, 1 anchor back, 2 set, 3 step, 4 get */
    void *c;              /* FMU instance */
    void *fn;             /* FMI function */
    const unsigned *vr;   /* value references (set, get) */
    size_t n;             /* how many */
    double *p;            /* values (set: into u, get: into y) */
    const long *a;        /* gather: u indices; anchor: u indices of the values */
    const long *b;        /* gather: y indices; anchor: u indices of the rates */
    long m;               /* gather, anchor: how many */
} op_t;

/* Run n_steps macro steps k0, k0 + 1, ... (time t0 + k h) of a run of n_total steps; step k
   runs program progs[k % period] (multi-rate instances step in some phases only). Returns 0,
   or the first status other than OK and Warning; then where[0] = the op, where[1] = the
   steps completed before the failing one. */
int webline_run(const op_t *const *progs, const long *n_ops, long period, double *y, double *u,
                double t0, double h, long k0, long n_steps, long n_total, long *where)
{
    for (long i = 0; i < n_steps; i++) {
        long ks = k0 + i;
        double t = t0 + (double)ks * h;
        const op_t *ops = progs[ks % period];
        long n = n_ops[ks % period];
        for (long k = 0; k < n; k++) {
            const op_t *o = &ops[k];
            int st = 0;
            switch (o->code) {
            case 0:
                for (long j = 0; j < o->m; j++) u[o->a[j]] = y[o->b[j]];
                break;
            case 1:
                for (long j = 0; j < o->m; j++) u[o->a[j]] -= h * u[o->b[j]];
                break;
            case 2:
                st = ((set_fn)o->fn)(o->c, o->vr, o->n, o->p);
                break;
            case 3:
                if (o->m > 1) {  /* multi-rate: over m macro steps (fewer at the end of the run) */
                    long m = o->m < n_total - ks ? o->m : n_total - ks;
                    st = ((step_fn)o->fn)(o->c, t, h * (double)m, 1);
                } else {
                    st = ((step_fn)o->fn)(o->c, t, h, 1);
                }
                break;
            case 4:
                st = ((get_fn)o->fn)(o->c, o->vr, o->n, o->p);
                break;
            default:
                st = -1;
            }
            if (st != 0 && st != 1) {
                where[0] = k;
                where[1] = i;
                return st;
            }
        }
    }
    return 0;
}
"""

GATHER, ANCHOR, SET, STEP, GET = range(5)
FUNCTION = {SET: "fmi2SetReal", STEP: "fmi2DoStep", GET: "fmi2GetReal"}


class Op(Structure):
    _fields_ = [("code", c_long), ("c", c_void_p), ("fn", c_void_p), ("vr", POINTER(c_uint)),
                ("n", c_size_t), ("p", POINTER(c_double)), ("a", POINTER(c_long)), ("b", POINTER(c_long)),
                ("m", c_long)]


_LIB = None
_TRIED = False


def _cache_dir():
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    d = Path(base) / "webline"
    try:
        d.mkdir(parents=True, exist_ok=True)
        return d
    except OSError:
        return Path(tempfile.gettempdir())


def _compile():
    cc = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    if not cc:
        return None
    tag = hashlib.sha256(SOURCE.encode()).hexdigest()[:16]
    lib = _cache_dir() / f"webline_master_loop_{tag}.so"
    if not lib.exists():
        with tempfile.TemporaryDirectory() as tmp:
            src = Path(tmp, "loop.c")
            src.write_text(SOURCE)
            out = Path(tmp, "loop.so")
            p = subprocess.run([cc, "-O2", "-ffp-contract=off", "-fPIC", "-shared", "-o", str(out), str(src)],
                               capture_output=True, text=True, timeout=120)
            if p.returncode != 0 or not out.exists():
                return None
            part = lib.with_suffix(f".{os.getpid()}.part")
            shutil.copyfile(out, part)
            os.replace(part, lib)  # atomic: another process may be compiling the same file
    return lib


def library():
    """The compiled routine (ctypes function), or None when it cannot be built or is disabled."""
    global _LIB, _TRIED
    if os.environ.get("WEBLINE_MASTER_LOOP", "").lower() == "python":
        return None
    if not _TRIED:
        _TRIED = True
        try:
            path = _compile()
            if path is not None:
                fn = ctypes.CDLL(str(path)).webline_run
                fn.restype = c_int
                fn.argtypes = [POINTER(POINTER(Op)), POINTER(c_long), c_long, POINTER(c_double),
                               POINTER(c_double), c_double, c_double, c_long, c_long, c_long, POINTER(c_long)]
                _LIB = fn
        except (OSError, subprocess.SubprocessError, AttributeError):
            _LIB = None
    return _LIB


def available():
    return library() is not None


_INDEX_CACHE = {}  # id(index array) -> (array, its c_long copy, pointer); cleared per Runner


class Program:
    """A macro step as operations; ``info[k]`` = (slave, at_end) of operation k (for failures)."""

    def __init__(self, y, u):
        self.y, self.u = y, u
        # base addresses once: numpy's .ctypes builds an object per access
        self.base = {id(y): y.__array_interface__["data"][0], id(u): u.__array_interface__["data"][0]}
        self.ops, self.info, self.keep = [], [], []

    def _ptr(self, arr, index, ctype):
        return ctypes.cast(self.base[id(arr)] + arr.itemsize * index, POINTER(ctype))

    def _indices(self, a):
        hit = _INDEX_CACHE.get(id(a))
        if hit is None or hit[0] is not a:  # the same index arrays recur in every program
            import numpy as np
            c = np.array(a, dtype=np.int64 if ctypes.sizeof(c_long) == 8 else np.int32)  # a copy we own
            hit = _INDEX_CACHE[id(a)] = (a, c, ctypes.cast(c.__array_interface__["data"][0], POINTER(c_long)))
        self.keep.append(hit)
        return hit[2], len(hit[1])

    def gather(self, s):
        if len(s.dst):
            a, m = self._indices(s.dst)
            b, _ = self._indices(s.src)
            self.ops.append(Op(GATHER, None, None, None, 0, None, a, b, m))
            self.info.append((s, False))

    def gather_all(self, dst, src):
        if len(dst):
            a, m = self._indices(dst)
            b, _ = self._indices(src)
            self.ops.append(Op(GATHER, None, None, None, 0, None, a, b, m))
            self.info.append((None, False))

    def anchor(self, s):
        a, m = self._indices(s.back_v)
        b, _ = self._indices(s.back_r)
        self.ops.append(Op(ANCHOR, None, None, None, 0, None, a, b, m))
        self.info.append((s, False))

    def set(self, s, at_end=False):
        dll = s.model.dll()
        self.ops.append(Op(SET, s.c, ctypes.cast(dll.fmi2SetReal, c_void_p), s._in_vrs, len(s.inputs),
                           self._ptr(self.u, s.u0, c_double), None, None, 0))
        self.info.append((s, at_end))

    def step(self, s):
        dll = s.model.dll()
        self.ops.append(Op(STEP, s.c, ctypes.cast(dll.fmi2DoStep, c_void_p), None, 0, None, None, None,
                           s.multiple))
        self.info.append((s, False))

    def get(self, s, a, b, at_end):
        if b <= a:
            return
        dll = s.model.dll()
        vr = ctypes.cast(ctypes.addressof(s._out_vrs) + 4 * a, POINTER(c_uint))
        self.ops.append(Op(GET, s.c, ctypes.cast(dll.fmi2GetReal, c_void_p), vr, b - a,
                           self._ptr(self.y, s.y0 + a, c_double), None, None, 0))
        self.info.append((s, at_end))

    def resolve(self, groups, at_end):
        for g in groups:
            self.gather(g.slave)
            self.set(g.slave, at_end)
            self.get(g.slave, g.a, g.b, at_end)

    def done(self):
        self.array = (Op * max(1, len(self.ops)))(*self.ops)
        return self


def gauss_seidel_program(plan, record, phase):
    """Operations of :func:`master.gauss_seidel_step` for a step ``k`` with
    ``k % period == phase`` (and, with ``record``, of the reads that step does on a
    recording step and of :func:`master.complete`)."""
    p = Program(plan.y, plan.u)
    for chain, s in plan.gs_order:
        if s.multiple > 1:
            if phase % s.multiple == 0:
                p.step(s)
                p.get(s, 0, s.n_state + s.n_rest, True)
            continue
        p.resolve(chain, False)
        if s.set_inputs is not None:
            p.gather(s)
            if s.back_v is not None:
                p.anchor(s)
            p.set(s)
        p.step(s)
        p.get(s, 0, s.n_state + (s.n_rest if record else 0), True)
    p.resolve(plan.rate_groups, True)
    if record:
        _complete(p, plan, plan.other_groups)
    return p.done()


def jacobi_program(plan, record, phase):
    """Operations of :func:`master.jacobi_step` (and :func:`master.complete` with ``record``)."""
    p = Program(plan.y, plan.u)
    p.gather_all(plan.dst, plan.src)
    for s in plan.slaves:
        if s.set_inputs is not None:
            p.set(s)
    now = [s for s in plan.slaves if s.multiple == 1 or phase % s.multiple == 0]
    for s in now:
        p.step(s)
    for s in now:
        p.get(s, 0, s.n_state + (s.n_rest if record or s.multiple > 1 else 0), True)
    p.resolve(plan.groups, True)
    if record:
        _complete(p, plan, [])
    return p.done()


def _complete(p, plan, groups):
    p.resolve(groups, True)
    for g, needs_set in zip(plan.sinks, plan.sink_set):
        if needs_set:
            p.gather(g.slave)
            p.set(g.slave, True)
        p.get(g.slave, g.a, g.b, True)


class Runner:
    """Runs a plan's macro steps in compiled code: ``plain`` for steps that end between
    recording points, ``record`` for one that ends on one."""

    def __init__(self, plan, gauss_seidel, n_total):
        make = gauss_seidel_program if gauss_seidel else jacobi_program
        _INDEX_CACHE.clear()
        self.fn = library()
        self.period = math.lcm(*(s.multiple for s in plan.slaves)) if plan.slaves else 1
        self.n_total = n_total
        multiples = sorted({s.multiple for s in plan.slaves if s.multiple > 1})
        for record in (False, True):
            made = {}  # phases that step the same instances share one program
            progs = []
            for ph in range(self.period):
                key = tuple(ph % m == 0 for m in multiples)
                if key not in made:
                    made[key] = make(plan, record, ph)
                progs.append(made[key])
            setattr(self, "record" if record else "plain", self._programs(progs))
        _INDEX_CACHE.clear()  # the programs keep what they use
        self.y = ctypes.cast(plan.y.ctypes.data, POINTER(c_double))
        self.u = ctypes.cast(plan.u.ctypes.data, POINTER(c_double))
        self.where = (c_long * 2)()

    @staticmethod
    def _programs(programs):
        ptrs = (POINTER(Op) * len(programs))(*(ctypes.cast(p.array, POINTER(Op)) for p in programs))
        lens = (c_long * len(programs))(*(len(p.ops) for p in programs))
        return programs, ptrs, lens

    def run(self, which, t0, h, k, n):
        """Run ``n`` steps from step ``k`` (``which``: self.plain or self.record). Returns
        (0, n, ...) or (status, steps done, slave, FMI function, whether the call was at the
        step's end)."""
        if n <= 0:
            return 0, 0, None, None, False
        programs, ptrs, lens = which
        st = self.fn(ptrs, lens, self.period, self.y, self.u, t0, h, k, n, self.n_total, self.where)
        if st == 0:
            return 0, n, None, None, False
        done = int(self.where[1])
        program = programs[(k + done) % self.period]
        slave, at_end = program.info[self.where[0]]
        return st, done, slave, FUNCTION.get(program.ops[self.where[0]].code, "?"), at_end
