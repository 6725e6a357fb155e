"""``webline export-ssp LAYOUT OUT.ssp``: write a line as a standard SSP 1.0 package."""
import argparse
import sys
from pathlib import Path


def main(argv=None):
    ap = argparse.ArgumentParser(prog="webline export-ssp",
                                 description="Write a line layout as an SSP 1.0 package (SystemStructure.ssd + FMUs)")
    ap.add_argument("layout", type=Path, help="line layout (YAML)")
    ap.add_argument("out", type=Path, help="output .ssp file")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="layout override (repeatable), as for 'webline run'")
    ap.add_argument("--stop", type=float, help="stop time written to DefaultExperiment (s)")
    ap.add_argument("--step", type=float, help="macro step written to DefaultExperiment (s)")
    ap.add_argument("--ssv", action="store_true", help="one .ssv parameter file per component instead of inline values")
    ap.add_argument("--fmu-dir", type=Path, help="folder of built FMUs (default build/fmus; built if out of date)")
    args = ap.parse_args(argv)
    try:
        from webline.orchestrator.layout import load_system
        system = load_system(args.layout, _overrides(args.set))
    except (OSError, ValueError, KeyError) as e:
        print(f"webline export-ssp: {args.layout}: {e}", file=sys.stderr)
        return 2
    if args.stop is not None:
        system.experiment.stop = args.stop
    if args.step is not None:
        system.experiment.step = args.step
    from webline.orchestrator.ssp import export_ssp
    try:
        out = export_ssp(system, args.out, fmu_dir=args.fmu_dir, name=args.layout.stem,
                         parameter_files=args.ssv, log=lambda m: print(m, file=sys.stderr))
    except (KeyError, ValueError, FileNotFoundError) as e:
        print(f"webline export-ssp: {e}", file=sys.stderr)
        return 2
    n = len(system.components)
    print(f"{out}: {n} components, {len(system.connections)} connections, "
          f"{len({c.model for c in system.components})} FMUs")
    return 0


def _overrides(items):
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep:
            raise SystemExit(f"webline export-ssp: --set {item!r}: expected KEY=VALUE")
        try:
            import yaml
            out[key] = yaml.safe_load(value)
        except Exception:
            out[key] = value
    return out


if __name__ == "__main__":
    sys.exit(main())
