"""Will a run's results fit in memory? Checked before anything runs.

The master records every output of every component at every output time into one
preallocated float64 table (:class:`~orchestrator.results.Recorder`) and copies it
into the :class:`~orchestrator.results.Result` at the end, so a run needs about

    2 x rows x (columns + 1) x 8 bytes    (rows: output times; +1: the time column)

A run whose table would not fit in a share of the memory available now is refused
with :class:`ResultTooLarge` (a :class:`~orchestrator.master.SetupError`: exit code 2)
naming the size and what to change, instead of dying in ``np.empty`` (MemoryError)
or swapping the machine to a halt.
"""
import math
import os

from webline.orchestrator.master import SetupError

BYTES = 8  # float64
COPIES = 2  # the recorder's buffer and the Result's copy of it
SHARE = 0.5  # of the memory available: the FMUs, Python and the HDF5 writer need the rest


class ResultTooLarge(SetupError):
    """The results of a run would not fit in memory. ``field``: the experiment field to
    name (``experiment.duration``); ``needed``/``limit`` in bytes."""

    def __init__(self, message, needed, limit, rows, columns):
        super().__init__(message)
        self.field, self.needed, self.limit, self.rows, self.columns = "experiment.duration", needed, limit, rows, columns


def available_memory():
    """Bytes of memory available to a new allocation: MemAvailable of /proc/meminfo
    (Linux: free plus reclaimable cache), else the free physical pages (sysconf);
    None when neither can be read (the check is then skipped)."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024  # kB
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, ValueError, OSError):
        return None


def output_rows(experiment, step=None):
    """Rows the master records for ``experiment``: a row at the start, then every
    ``output_interval`` (whole macro steps; 0: every step) - as in master.simulate."""
    h = float(experiment.step if step is None else step)
    n_steps = max(1, math.ceil((experiment.stop - experiment.start) / h - 1e-9))
    oi = experiment.output_interval
    every = max(1, round(oi / h)) if oi > 0 else 1
    return n_steps // every + 1, every * h


def result_columns(system):
    """Recorded columns of ``system`` without building its FMUs: every output of every
    component (the master's convention), counted from the FMU scripts; None if a
    component's model is unknown (the master then checks with its own plan)."""
    from webline.orchestrator.reference import fmu_classes
    classes = fmu_classes()
    try:
        return sum(len(classes[c.model].OUTPUTS) for c in system.components)
    except KeyError:
        return None


def human(n):
    """1234567 -> '1.18 MiB'."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024 or unit == "PiB":
            return f"{n:.4g} {unit}" if unit != "B" else f"{n:.0f} B"
        n /= 1024.0
    return f"{n:.3g} PiB"


def check_result_memory(system, columns=None, available=None):
    """Raise :class:`ResultTooLarge` if the results of ``system`` would not fit in
    ``SHARE`` of the ``available`` memory (default: :func:`available_memory`).
    ``columns``: recorded columns (default: :func:`result_columns`). Returns the bytes
    the results need (None when the columns or the memory are unknown)."""
    columns = result_columns(system) if columns is None else columns
    available = available_memory() if available is None else available
    if columns is None:
        return None
    e = system.experiment
    rows, interval = output_rows(e)
    needed = COPIES * rows * (columns + 1) * BYTES
    if available is None:
        return needed
    limit = SHARE * available
    if needed <= limit:
        return needed
    max_rows = max(2, int(limit // (COPIES * (columns + 1) * BYTES)))
    duration = e.stop - e.start
    raise ResultTooLarge(
        f"the results would need {human(needed)} of memory ({rows:.4g} output times x {columns + 1} columns "
        f"x {BYTES} bytes, x{COPIES}: recorder and result) but {human(limit)} can be used "
        f"({SHARE:g} of the {human(available)} available); shorten experiment.duration "
        f"(now {duration:.4g} s) to at most {(max_rows - 1) * interval:.4g} s or raise "
        f"experiment.output_interval (now {interval:.4g} s) to at least "
        f"{duration / (max_rows - 1):.4g} s", needed, limit, rows, columns)
