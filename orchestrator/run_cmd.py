"""``webline run LAYOUT``: co-simulate a line layout and save its results.

Exit codes: 0 ok; 1 the run failed (the results up to the failure are saved);
2 bad input (invalid layout, bad option, a system the master cannot run).
"""
import argparse
import sys
from pathlib import Path


def _overrides(items):
    """``["a.b=1.5", "c=20 s"]`` -> {"a.b": 1.5, "c": "20 s"} (values read as YAML scalars)."""
    import yaml

    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ValueError(f"--set {item!r}: expected KEY=VALUE (e.g. experiment.duration=20s)")
        try:
            out[key.strip()] = yaml.safe_load(value)
        except yaml.YAMLError:
            out[key.strip()] = value
    return out


def parser():
    ap = argparse.ArgumentParser(
        prog="webline run", description=__doc__.splitlines()[0].split(": ", 1)[1].capitalize(),
        epilog="Writes OUT/results.h5 (and OUT/results.csv with --csv). Exit codes: 0 ok, "
               "1 run failure (partial results saved), 2 bad input.")
    ap.add_argument("layout", type=Path, help="line layout (YAML)")
    ap.add_argument("--out", type=Path, default=None,
                    help="output folder (default: out/<layout name>)")
    ap.add_argument("--csv", action="store_true", help="also write results.csv (time + one column per "
                                                       "<component>.<variable>, SI)")
    ap.add_argument("--set", dest="set", action="append", default=[], metavar="KEY=VALUE",
                    help="override a layout value by dotted key, e.g. --set experiment.duration=20s "
                         "(repeatable; values may carry units)")
    ap.add_argument("--algorithm", choices=("jacobi", "gauss-seidel"), default=None,
                    help="master algorithm (default: the layout's)")
    ap.add_argument("--step", default=None, metavar="STEP",
                    help="macro step, e.g. 1e-3 or '0.5 ms' (default: the layout's)")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    return ap


def summary(result):
    """Short text: mean / peak-to-peak tension per load cell, wall time, real-time factor."""
    from webline.orchestrator.plot import display_unit, tension_columns

    lines = []
    m = result.meta
    unit, si = display_unit(result, "tension", "N")
    if len(result.time):
        for c in tension_columns(result):
            x = result[c]
            mean, p2p = float(x.mean()), float(x.max() - x.min())
            text = f"  {c:<20} mean {mean:9.2f} N   p2p {p2p:8.3f} N"
            if unit != "N":
                text += f"   ({mean / si:.3f} / {p2p / si:.4f} {unit})"
            lines.append(text)
    sim = m.get("simulated_time", 0.0)
    wall = m.get("wall_time", 0.0)
    rtf = m.get("real_time_factor", float("nan"))
    lines.append(f"  simulated {sim:.4g} s in {wall:.3g} s wall (+{m.get('setup_time', 0.0):.2g} s setup): "
                 f"{rtf:.3g} x real time; {m.get('n_components', '?')} FMUs, step {m.get('step', 0):g} s, "
                 f"{m.get('algorithm', '?')}")
    return "\n".join(lines)


def _too_large(layout, exc):
    """``file:line: experiment.duration: reason`` for a run whose results cannot fit in memory."""
    from webline.orchestrator.layout_source import Issue, Location, locate
    data = getattr(layout, "_data", None)
    where = locate(data, ["experiment", "duration"])[0] if data else Location(str(getattr(layout, "_file", "")))
    return str(Issue(where, exc.field, str(exc)))


def main(argv=None):
    args = parser().parse_args(argv)
    from webline.orchestrator.master import SetupError, simulate

    try:
        from webline.orchestrator.layout import LayoutError, build_system, load_layout
        from webline.orchestrator.memory import ResultTooLarge, check_result_memory
    except ImportError as exc:
        print(f"webline run: the layout module is not available ({exc})", file=sys.stderr)
        return 2
    try:
        layout = load_layout(args.layout, _overrides(args.set))
        system = build_system(layout)
        if args.algorithm:
            system.experiment.algorithm = args.algorithm
        if args.step is not None:
            from webline.orchestrator.units import QuantityError, quantity
            try:
                system.experiment.step = quantity(args.step, "time", "--step")
            except QuantityError as exc:
                raise ValueError(str(exc)) from None
            if not system.experiment.step > 0:
                raise ValueError(f"--step must be > 0 (got {args.step!r})")
        check_result_memory(system)  # before the FMUs are built or anything runs
    except ResultTooLarge as exc:
        print(f"webline run: {_too_large(layout, exc)}", file=sys.stderr)
        return 2
    except (LayoutError, ValueError) as exc:
        print(f"webline run: {exc}", file=sys.stderr)
        return 2
    system.meta.setdefault("layout", str(args.layout))
    out = args.out or Path("out") / args.layout.stem
    try:
        result = simulate(system, progress=not args.no_progress)
    except ResultTooLarge as exc:  # the master's own count of the columns
        print(f"webline run: {_too_large(layout, exc)}", file=sys.stderr)
        return 2
    except SetupError as exc:
        print(f"webline run: {args.layout}: {exc}", file=sys.stderr)
        return 2
    result.meta["layout"] = str(args.layout)
    result.meta["overrides"] = list(args.set)
    paths = result.save(out, csv=args.csv)
    if not result.ok:
        what = "was interrupted" if result.status == "interrupted" else "failed"
        print(f"webline run: run {what} after {result.meta.get('simulated_time', 0):.6g} s:\n"
              f"{result.message}", file=sys.stderr)
        print(f"partial results ({len(result.time)} rows): {', '.join(map(str, paths))}", file=sys.stderr)
        return 1
    print(f"results: {', '.join(map(str, paths))}")
    print(summary(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
