"""``webline validate LAYOUT``: check a line layout without running it.

Exit 0 when the layout is valid (a one-line summary on stdout, or the
operating point with ``--show``), 2 when it is not: one line per problem on
stderr, ``file:line: field: reason``. ``--schema`` prints the layout's JSON
schema (the one committed as docs/layout.schema.json).
"""
import argparse
import json
import sys
from pathlib import Path


def parse_overrides(items, prog="webline validate"):
    """``["a.b=1 in", ...]`` -> ``{"a.b": "1 in"}`` (values kept as written; the layout reads them)."""
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ValueError(f"--set {item!r}: expected KEY=VALUE, e.g. experiment.duration=20s")
        out[key.strip()] = value
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(prog="webline validate", description=__doc__.splitlines()[0].split(": ", 1)[-1])
    ap.add_argument("layout", type=Path, nargs="?", help="line layout (YAML)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="override a dotted key before validation (repeatable), e.g. --set unwind.radius='5.75 in'")
    ap.add_argument("--show", action="store_true", help="print the components and the operating point")
    ap.add_argument("--schema", action="store_true", help="print the layout JSON schema and exit")
    args = ap.parse_args(argv)

    from webline.orchestrator.layout import LayoutError, build_system, json_schema, load_layout
    if args.schema:
        print(json.dumps(json_schema(), indent=2, sort_keys=False))
        return 0
    if args.layout is None:
        ap.print_usage(sys.stderr)
        print("webline validate: error: the LAYOUT file is required", file=sys.stderr)
        return 2
    try:
        overrides = parse_overrides(args.set)
        system = build_system(load_layout(args.layout, overrides))
    except LayoutError as exc:
        print(str(exc), file=sys.stderr)
        return 2
    except ValueError as exc:
        print(f"{args.layout}: {exc}", file=sys.stderr)
        return 2
    m = system.meta
    zones = [z for z in m["zones"] if z["tension_loop"]]
    print(f"{args.layout}: ok: {len(m['elements'])} elements, {len(m['spans'])} spans, "
          f"{len(zones)} tension zones, {len(m['sensors'])} load cells; "
          f"{len(system.components)} components, {len(system.connections)} connections")
    if args.show:
        _show(system)
    return 0


def _show(system):
    m = system.meta
    disp = m["units"]["display"]
    sp, te = disp["speed"], disp["tension"]
    op = m["operating_point"]
    print(f"\noperating point (speeds in {sp['unit']}, tensions in {te['unit']}):")
    for name, e in m["elements"].items():
        v = e["v0"] / sp["si_per_unit"]
        print(f"  {name:<16} {e['kind']:<17} v = {v:10.4f}   f = {e['f0']:8.4f} Hz")
    for s in m["spans"]:
        print(f"  {s['component']:<16} {s['up']} -> {s['down']}: T = {s['T0'] / te['si_per_unit']:.4f}")
    for name, tau in op["torque"].items():
        print(f"  {name:<16} holding torque {tau:.4g} N.m")
    x = system.experiment
    print(f"\nexperiment: {x.start:g} .. {x.stop:g} s, step {x.step:g} s, {x.algorithm}")


if __name__ == "__main__":
    sys.exit(main())
