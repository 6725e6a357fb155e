"""``webline diagnose LAYOUT RUN [RUN ...] --out DIR [--holdout RUN ...]``.

Where model and measured tension differ, which unmodelled effect causes it,
and how far the gap shrinks once the effect is in the model (docs/diagnose.md).
Exit codes: 0 done (with or without an effect found), 1 a simulation failed,
2 bad input (layout, run file, data).
"""
import argparse
import logging
import os
import signal
import sys
from pathlib import Path


def parser():
    ap = argparse.ArgumentParser(
        prog="webline diagnose",
        description="Find the unmodelled effect behind the gap between a line model and measured tension.")
    ap.add_argument("layout", type=Path, help="line layout (YAML)")
    ap.add_argument("runs", type=Path, nargs="+", help="run files (YAML: data + conditions) to fit on")
    ap.add_argument("--out", type=Path, required=True, help="output folder (report.json, report.html, refined_layout.yaml)")
    ap.add_argument("--holdout", type=Path, nargs="+", default=[], metavar="RUN",
                    help="runs not used for fitting: the refined model is checked on them")
    ap.add_argument("--harmonics", type=int, default=6, help="Fourier terms per element (default 6, as {32})")
    ap.add_argument("--max-effects", type=int, default=5, help="most effects to add (default 5)")
    ap.add_argument("--significance", type=float, default=-8.0,
                    help="log10 false-alarm probability an effect must beat (default -8)")
    ap.add_argument("--no-polish", action="store_true", help="skip the Gauss-Newton polish simulation")
    ap.add_argument("--no-other", action="store_true",
                    help="do not screen backlash, compliance, sensor and parameter effects")
    ap.add_argument("--no-structure", action="store_true",
                    help="do not screen model-form alternatives (feed forward, loop gains, ...)")
    ap.add_argument("--max-structures", type=int, default=None,
                    help="model-form alternatives screened at most (default: every one)")
    ap.add_argument("--jobs", type=int, default=None,
                    help="simulations run in parallel worker processes (default: 2 if the machine has 2+ cores)")
    ap.add_argument("--time", metavar="COL", default=None,
                    help="time column of the data, for runs whose file has no 'time:' (default: detected)")
    ap.add_argument("--time-unit", metavar="UNIT", default=None,
                    help="unit of the time column when the header gives none (e.g. ms); 'time_unit:' in a run file wins")
    ap.add_argument("--engine", choices=("fast", "cosim"), default="fast",
                    help="model runs: the compiled monolithic ODE (fast, default) or the FMU co-simulation")
    ap.add_argument("--no-confirm", action="store_true",
                    help="skip the final check of the refined layout by the FMU co-simulation (fast engine)")
    ap.add_argument("--no-ripple", action="store_true",
                    help="do not fit the drives' torque ripple to the residual's humps (each hump stays "
                         "an unexplained resonance)")
    ap.add_argument("--calibrated-shafts", action="store_true",
                    help="fit the ripple spectrum with the line's fast dynamics calibrated: a band's shaft "
                         "claim on one drive is vetoed where that puts the shaft on another, and with no shaft "
                         "claimed one is sought (minutes more; docs/diagnose.md, 'The calibrated shaft screen')")
    ap.add_argument("--no-transfer", action="store_true",
                    help="keep every estimated order in the refined layout, also those whose held-out "
                         "prediction does not carry over lines within the data sheet's tolerances")
    ap.add_argument("--gains", choices=("simulation", "modes"), default="modes",
                    help="per-harmonic gains of a candidate: the linearised line (default; webline modes, "
                         "docs/modes.md) or a sensitivity simulation each")
    ap.add_argument("--quiet", action="store_true", help="only warnings")
    return ap


def main(argv=None):
    args = parser().parse_args(argv)
    from webline.diagnosis.pipeline import DiagnoseError, Options, diagnose
    from webline.diagnosis.line_model import SimulationFailed

    logging.basicConfig(level=logging.WARNING if args.quiet else logging.INFO,
                        format="%(asctime)s %(message)s", datefmt="%H:%M:%S", stream=sys.stderr)
    if args.harmonics < 1 or args.harmonics > 8:
        print("webline diagnose: --harmonics must be 1..8 (the span model has 8 Fourier terms)", file=sys.stderr)
        return 2
    opt = Options(harmonics=args.harmonics, max_effects=args.max_effects, significance=args.significance,
                  polish=not args.no_polish, other_effects=not args.no_other,
                  structure=not args.no_structure, max_structures=args.max_structures,
                  progress=not args.quiet and sys.stderr.isatty(),
                  jobs=args.jobs if args.jobs is not None else min(2, os.cpu_count() or 1),
                  time_column=args.time, time_unit=args.time_unit, engine=args.engine,
                  confirm=not args.no_confirm, gains=args.gains, transfer=not args.no_transfer,
                  ripple=not args.no_ripple, calibrated_shafts=args.calibrated_shafts)
    previous = _terminate_as_interrupt()
    try:
        rep = diagnose(args.layout, args.runs, args.holdout, args.out, opt)
    except DiagnoseError as exc:
        print(f"webline diagnose: {exc}", file=sys.stderr)
        return 2
    except SimulationFailed as exc:
        print(f"webline diagnose: {exc}{_kept(exc)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as exc:
        print(f"webline diagnose: interrupted in stage '{getattr(exc, 'stage', None)}'{_kept(exc)}", file=sys.stderr)
        return 130
    except Exception as exc:
        # the command line's last line of defence names the error; say first what was kept
        kept = _kept(exc)
        if kept:
            print(f"webline diagnose: stopped in stage '{getattr(exc, 'stage', None)}'{kept}", file=sys.stderr)
        raise
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    print(rep["verdict"])
    print(f"report: {args.out / 'report.html'}")
    return 0


def _terminate_as_interrupt():
    """SIGTERM (a job scheduler's or the benchmark's time limit, ``kill``) stops the diagnosis
    as Ctrl-C does, so it keeps what it had measured (report_partial.json); the default would
    end the process with nothing written. Returns the handler it replaced (None off the main
    thread, where Python cannot set one)."""
    def interrupt(signum, frame):
        raise KeyboardInterrupt("terminated by SIGTERM")
    try:
        return signal.signal(signal.SIGTERM, interrupt)
    except ValueError:
        return None


def _kept(exc):
    """"; what the stages before it had measured: <path>" when the stop left a partial report."""
    path = getattr(exc, "partial_report", None)
    return f"; what the stages before it had measured: {path}" if path else ""


if __name__ == "__main__":
    sys.exit(main())
