"""A stand-in for one simulation run, for testing the sweep machinery without a line.

Imported by spawned pool workers and Dask workers by name ("sweep_fakes:fake_run"):
the tests folder is on their sys.path (inherited from the pytest process).
"""
import os
import time
from pathlib import Path


def fake_run(task):
    """Behaves as the override ``fake.mode`` says: ok, fail (raises) or crash (kills the process)."""
    mode = task["overrides"].get("fake.mode", "ok")
    counter = Path(task["run_dir"]) / "executions"
    counter.write_text(str(int(counter.read_text()) + 1 if counter.exists() else 1))
    time.sleep(float(task["overrides"].get("fake.sleep", "0")))
    if mode == "fail":
        raise RuntimeError("diverged on purpose")
    if mode == "crash":
        os._exit(3)  # like an FMU segfault: no Python error, the process is gone
    x = float(task["overrides"].get("fake.x", "1").split()[0])  # mode "ok", "ok2", ... all succeed
    return {"status": "ok", "sim_time": 1.0, "lc.T.mean": 10.0 * x, "pid_seen": os.getpid()}
