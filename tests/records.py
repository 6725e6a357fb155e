"""Measured records for the diagnosis tests: a truth layout simulated under a run's
conditions, its load cells with white noise, written as a data file and a run file
the way a user hands them to ``webline diagnose``."""
from pathlib import Path

import numpy as np
import yaml


def measured_run(folder, name, truth_layout, exp, *, exp_true=None, seed=0, noise_N=0.3, fs=250.0,
                 sensors=("lc9", "lc15", "lc19"), simulate=None, extra=None):
    """Write ``<name>.csv`` and ``<name>.yaml`` in ``folder``; return the run file's path.

    ``exp`` is the run file's experiment block, ``exp_true`` the one the truth ran
    under (default ``exp``: e.g. another start radius than the run sheet says);
    ``simulate`` (default the fast engine) runs the truth system; ``extra(res)``
    gives more data columns ({header: array})."""
    from webline.orchestrator import engine
    from webline.orchestrator.layout import load_system
    from webline.diagnosis.runs import _experiment_overrides

    folder = Path(folder)
    system = load_system(truth_layout, _experiment_overrides(exp_true or exp, "<run>", {}))
    system.experiment.output_interval = 1.0 / fs
    res = (simulate or engine.simulate)(system)
    assert getattr(res, "ok", True), res.message
    t = np.asarray(res.time)
    rng = np.random.default_rng(seed)
    cols = {f"{lc} [N]": np.asarray(res[f"{lc}.T"]) + rng.normal(0, noise_N, len(t)) for lc in sensors}
    cols.update(extra(res) if extra else {})
    np.savetxt(folder / f"{name}.csv", np.column_stack([t] + list(cols.values())), delimiter=",",
               header=",".join(["time [s]"] + list(cols)), comments="", fmt="%.9g")
    (folder / f"{name}.yaml").write_text(yaml.safe_dump({"data": f"{name}.csv", "experiment": exp}))
    return folder / f"{name}.yaml"


# the EWL layout's equal-radius idlers, one tie per zone: the sensors cannot tell a zone's
# two apart, and the benchmark counts either as found
UNWIND_ZONE = ("idler_u1", "roller9")
REWIND_ZONE = ("idler_r1", "roller19")


# A whole diagnosis in a subprocess is stopped after this long: a guard against a hung run,
# not a speed test. On a fresh machine the engine compiles every structure anew, and under
# `make test` two workers share the cores: test_diagnose_same_frequency's case took 762 s there,
# and was stopped at the former 900 s with a benchmark beside it (364 s of CPU by then).
DIAGNOSIS_TIMEOUT = 2700


def independent_cases(root, seed, ids, timeout=DIAGNOSIS_TIMEOUT):
    """Cases ``ids`` of the independent benchmark's draw for ``seed``, diagnosed blind
    in a subprocess (one job) in ``root``: {id: the benchmark's result dict}."""
    from webline.diagnosis import benchmark as B
    from webline.diagnosis import benchmark_independent as I
    line = B.derive_line()
    drawn = {c.id: c for c in I.draw_cases(24, seed, layout_doc=line)}
    out = {}
    for cid in ids:
        res = I.evaluate_case(drawn[cid], root, line, timeout=timeout, extra=["--jobs", "1"])
        assert res["report"] is not None, res.get("stderr") or res.get("generation_error")
        out[cid] = res
    return out


def assert_no_sensor_worse(gap):
    """Every load cell's refined NRMSE within the claim check's allowance (2 %) of the nominal one;
    ``gap`` is a report's ``gap`` (or ``holdout.out_of_sample``) mapping."""
    for s, g in gap.items():
        assert g["refined"]["nrmse"] <= 1.02 * g["nominal"]["nrmse"], (s, g["refined"], g["nominal"])
