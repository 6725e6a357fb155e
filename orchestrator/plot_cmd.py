"""``webline plot RESULTS``: tension/speed time series and tension spectra of a run.

RESULTS is a results folder (with results.h5) or a results.h5 / results.csv file.
Exit codes: 0 ok, 2 no readable results.
"""
import argparse
import sys
from pathlib import Path


def parser():
    ap = argparse.ArgumentParser(
        prog="webline plot", description=__doc__.splitlines()[0].split(": ", 1)[1].capitalize(),
        epilog="Writes timeseries.png and spectra.png (Hann window over a steady window, with a "
               "marker at each rotating element's fundamental mean(omega)/(2 pi)).")
    ap.add_argument("results", type=Path, help="results folder, results.h5 or results.csv")
    ap.add_argument("--out", type=Path, default=None, help="folder for the PNGs (default: the results folder)")
    ap.add_argument("--window", nargs=2, type=float, metavar=("T0", "T1"), default=None,
                    help="steady window for the spectra, s (default: the layout's, else the second half)")
    ap.add_argument("--fmax", type=float, default=None, help="highest frequency shown, Hz")
    return ap


def main(argv=None):
    args = parser().parse_args(argv)
    from webline.orchestrator.plot import plot_results
    from webline.orchestrator.results import load_results

    try:
        result = load_results(args.results)
    except (OSError, ValueError, KeyError) as exc:
        print(f"webline plot: cannot read results from {args.results}: {exc}", file=sys.stderr)
        return 2
    out = args.out or (args.results if args.results.is_dir() else args.results.parent)
    paths = plot_results(result, out, window=tuple(args.window) if args.window else None, fmax=args.fmax)
    print("plots: " + ", ".join(map(str, paths)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
