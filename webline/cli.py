"""The ``webline`` command: one sub-command per module, dispatched by name.

Exit codes: 0 ok, 1 run failure, 2 bad input (argparse uses 2 as well).
"""
import importlib
import os
import sys

# sub-command -> (module with main(argv) -> int, one-line help)
COMMANDS = {
    "build-fmus": ("webline.fmus.build", "build every element FMU into one folder"),
    "orders": ("webline.diagnosis.orders_cmd", "order spectra and shaft-tagged tension peaks of measured data"),
    "run": ("webline.orchestrator.run_cmd", "co-simulate a line layout, save results.h5 (and .csv)"),
    "plot": ("webline.orchestrator.plot_cmd", "plot tensions, speeds and tension spectra of a run"),
    "sweep": ("webline.orchestrator.sweep_cmd", "run a parameter sweep (grid / Monte Carlo) of a layout"),
    "plot-sweep": ("webline.orchestrator.sweep_plot", "plot a finished sweep (sweep.csv)"),
    "accuracy": ("webline.orchestrator.accuracy_cmd", "co-simulation error vs the monolithic reference, per step/algorithm"),
    "export-ssp": ("webline.orchestrator.ssp_cmd", "write a layout as an SSP 1.0 package (.ssp) with its FMUs"),
    "modes": ("webline.orchestrator.modes_cmd", "linearised line: modes and transfer functions to the load cells"),
    "validate": ("webline.orchestrator.validate_cmd", "check a line layout (file:line: field: reason), print its operating point"),
    "diagnose": ("webline.diagnosis.diagnose_cmd", "find the unmodelled effect behind a model-vs-measured tension gap"),
    "diagnose-bench": ("webline.diagnosis.benchmark_cmd", "benchmark webline diagnose on lines with hidden effects"),
}


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "--version":
        from webline import __version__
        print(f"webline {__version__}")
        return 0
    if not argv or argv[0] in ("-h", "--help"):
        print("usage: webline COMMAND [--help] ...\n\ncommands:")
        for name, (_, text) in COMMANDS.items():
            print(f"  {name:<15} {text}")
        return 0 if argv else 2
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"webline: unknown command {name!r}; try 'webline --help'", file=sys.stderr)
        return 2
    try:
        module = importlib.import_module(COMMANDS[name][0])
        return module.main(rest)
    except KeyboardInterrupt:
        print(f"webline {name}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # the last line of defence: no bare traceback for users
        if os.environ.get("WEBLINE_DEBUG"):
            raise
        print(f"webline {name}: internal error: {type(exc).__name__}: {exc}\n"
              f"  (set WEBLINE_DEBUG=1 for the traceback, and please report it)", file=sys.stderr)
        return 1


def exit_now(code):
    """Flush and leave without interpreter teardown.

    pythonfmu FMUs run inside this process; tearing the interpreter down
    while their C++ slave objects still hold Python references has, on rare
    runs, aborted the process ("corrupted double-linked list", exit 134)
    after all work was done and saved. The result is decided by then, so
    report it and skip the teardown.
    """
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:
            pass
    os._exit(code)


def run():
    """Console-script entry point (``webline``)."""
    exit_now(main())


if __name__ == "__main__":
    run()
