"""``webline accuracy LAYOUT``: relative RMS error of the load-cell tensions of the
co-simulation against the monolithic reference, per macro step and algorithm."""
import argparse
import json
import re
import sys
from pathlib import Path

from webline.orchestrator.accuracy import DEFAULT_ALGORITHMS, DEFAULT_STEPS, json_ready, markdown_table, measure

_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6}


def parse_step(text):
    """'0.5ms' / '500us' / '1e-3' / '0.002s' -> seconds."""
    m = re.fullmatch(r"\s*([0-9.eE+-]+)\s*(s|ms|us|µs)?\s*", text)
    if not m:
        raise ValueError(f"bad step {text!r} (examples: 0.5ms, 500us, 1e-3, 0.002s)")
    value = float(m.group(1)) * _UNITS[m.group(2) or "s"]
    if not value > 0:
        raise ValueError(f"step {text!r} must be > 0")
    return value


def main(argv=None):
    ap = argparse.ArgumentParser(prog="webline accuracy", description=__doc__.splitlines()[0])
    ap.add_argument("layout", type=Path, help="line layout (YAML)")
    ap.add_argument("--steps", default=",".join(f"{h * 1e3:g}ms" for h in DEFAULT_STEPS),
                    help="macro steps, comma-separated (default %(default)s)")
    ap.add_argument("--algorithms", default=",".join(DEFAULT_ALGORITHMS),
                    help="master algorithms, comma-separated (default %(default)s)")
    ap.add_argument("--stop", type=float, help="stop time (s); default the layout's")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="layout override (repeatable)")
    ap.add_argument("--rtol", type=float, default=1e-8, help="reference solver tolerance (default %(default)g)")
    ap.add_argument("--columns", help="compare these columns instead of the load cells (comma-separated)")
    ap.add_argument("--keep-noise", action="store_true", help="keep load-cell noise (default: noise_std = 0)")
    ap.add_argument("--no-engine", action="store_true", help="leave out the fast engine's row")
    ap.add_argument("--json", type=Path, help="report file (default out/accuracy/<layout>.json)")
    args = ap.parse_args(argv)
    try:
        steps = [parse_step(s) for s in args.steps.split(",") if s.strip()]
    except ValueError as e:
        ap.error(str(e))
    algorithms = [a.strip() for a in args.algorithms.split(",") if a.strip()]
    bad = [a for a in algorithms if a not in DEFAULT_ALGORITHMS]
    if bad:
        ap.error(f"unknown algorithm(s) {', '.join(bad)}; choose from {', '.join(DEFAULT_ALGORITHMS)}")
    try:
        from webline.orchestrator.layout import load_system
        from webline.orchestrator.ssp_cmd import _overrides
        system = load_system(args.layout, _overrides(args.set))
    except (OSError, ValueError, KeyError) as e:
        print(f"webline accuracy: {args.layout}: {e}", file=sys.stderr)
        return 2
    if args.stop is not None:
        system.experiment.stop = args.stop
    columns = [c.strip() for c in args.columns.split(",")] if args.columns else None
    try:
        report = measure(system, steps, algorithms, columns=columns, rtol=args.rtol,
                         keep_noise=args.keep_noise, log=lambda m: print(m, file=sys.stderr),
                         engine=not args.no_engine)
    except ValueError as e:
        print(f"webline accuracy: {e}", file=sys.stderr)
        return 2
    except RuntimeError as e:
        print(f"webline accuracy: {e}", file=sys.stderr)
        return 1
    report["layout"] = str(args.layout)
    print(f"Relative RMS error of the load-cell tensions vs the monolithic reference "
          f"({args.layout.name}, {system.experiment.start:g}-{system.experiment.stop:g} s, "
          f"reference LSODA rtol {args.rtol:g}):\n")
    print(markdown_table(report))
    out = args.json or Path("out") / "accuracy" / f"{args.layout.stem}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(json_ready(report), indent=1))
    print(f"\nreport: {out}")
    failed = [r for r in report["runs"] if r["status"] != "ok"]
    return 1 if failed and len(failed) == len(report["runs"]) else 0


if __name__ == "__main__":
    sys.exit(main())
