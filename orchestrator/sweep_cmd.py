"""``webline sweep SWEEP.yaml``: run a parameter sweep of a line (grid or Monte Carlo).

Each run is its own process: a local process pool (spawn) by default, or the
workers of a Dask distributed cluster with ``--scheduler ADDRESS`` (the
workers must see the same file system: every run writes ``OUT/runs/<key>/``).
Finished runs are skipped when the sweep is run again. Writes ``OUT/sweep.csv``
(one row per run) and, when the sweep file has a ``plot`` section, the plot.

Exit codes: 0 every run ok, 1 some run failed (recorded in sweep.csv),
2 bad sweep file or arguments, 130 interrupted (finished runs are kept).
"""
import argparse
import sys
from pathlib import Path


def main(argv=None):
    ap = argparse.ArgumentParser(prog="webline sweep", description="Run a parameter sweep of a line layout (grid or Monte Carlo), one process per run.", epilog="Exit codes: 0 all runs ok, 1 some run failed, 2 bad sweep file, 130 interrupted. Format: docs/sweep.md")
    ap.add_argument("sweep", type=Path, help="sweep YAML (layout + grid or monte_carlo)")
    ap.add_argument("--out", type=Path, help="output folder (default out/sweeps/<name>)")
    ap.add_argument("--scheduler", metavar="ADDRESS",
                    help="Dask scheduler address (tcp://host:8786); default: local process pool")
    ap.add_argument("--workers", type=int, metavar="N",
                    help="local worker processes (default: CPU count; ignored with --scheduler)")
    ap.add_argument("--force", action="store_true", help="re-run finished runs too")
    ap.add_argument("--retry-failed", action="store_true", help="re-run runs that failed before")
    ap.add_argument("--in-worker", action="store_true",
                    help="with --scheduler: run in the Dask worker process itself, not a subprocess")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    ap.add_argument("--no-plot", action="store_true", help="skip the plot of the sweep file's plot section")
    args = ap.parse_args(argv)
    if args.workers is not None and args.workers < 1:
        ap.error("--workers must be >= 1")

    from webline.orchestrator.sweep import SweepError, load_sweep, run_sweep, validate_overrides
    try:
        sweep = load_sweep(args.sweep)
        validate_overrides(sweep)
    except SweepError as exc:
        print(f"webline sweep: {exc}", file=sys.stderr)
        return 2
    out = args.out or Path("out") / "sweeps" / sweep.name
    if args.scheduler and args.workers:
        print("webline sweep: --workers ignored with --scheduler (the cluster decides)", file=sys.stderr)
    try:
        rows = run_sweep(sweep, out, scheduler=args.scheduler, workers=args.workers,
                         progress=not args.no_progress, force=args.force,
                         retry_failed=args.retry_failed, isolate=not args.in_worker)
    except KeyboardInterrupt:
        print(f"webline sweep: interrupted; finished runs are kept in {out} "
              "(run the same command again to continue)", file=sys.stderr)
        return 130
    ok = sum(r["status"] == "ok" for r in rows)
    print(f"{ok} of {len(rows)} runs ok -> {out / 'sweep.csv'}")
    for r in rows:
        if r["status"] != "ok":
            print(f"  {r['run_id']} {r['status']}: {r.get('error', '')[:300]}", file=sys.stderr)
    if sweep.plot and not args.no_plot:
        from webline.orchestrator.sweep_plot import plot_sweep
        try:
            for p in plot_sweep(out):
                print(f"plot -> {p}")
        except Exception as exc:  # a plot problem must not hide the finished sweep
            print(f"webline sweep: plot failed: {type(exc).__name__}: {exc}", file=sys.stderr)
            return 1
    return 0 if ok == len(rows) else 1


if __name__ == "__main__":
    sys.exit(main())
