"""``webline modes LAYOUT``: the linearised line: modes and transfer functions to the load cells.

Linearises the line at its operating point (the start of the experiment: its line speed,
tensions and roll radii; change them with ``--set``), prints the modes (frequency,
damping ratio, which spans and rollers move) and, per input, the peak gain to each load
cell. Inputs: each rotating element's span-length change (its eccentricity, N/m) and
each drive's motor torque (N/(N.m)). With ``--out DIR``: modes.json (eigenvalues, modes,
transfer functions on a frequency grid) and bode.png. Exit 0 ok, 2 bad layout or options.
See docs/modes.md.
"""
import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np


def parser():
    ap = argparse.ArgumentParser(prog="webline modes", description=__doc__.splitlines()[0].split(": ", 1)[1])
    ap.add_argument("layout", type=Path, help="line layout (YAML)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="override a dotted key of the layout (repeatable), e.g. experiment.line_speed='100 ft/min'")
    ap.add_argument("--out", type=Path, default=None, help="folder for modes.json and bode.png")
    ap.add_argument("--fmin", type=float, default=None, help="lowest frequency of the transfer functions, Hz "
                    "(default: a tenth of the slowest oscillatory mode, at most 0.05)")
    ap.add_argument("--fmax", type=float, default=None,
                    help="highest frequency, Hz (default: twice the fastest oscillatory mode, at least 10)")
    ap.add_argument("--points", type=int, default=800, help="frequencies on the log grid (default 800)")
    ap.add_argument("--jacobian", choices=("engine", "reference"), default="engine",
                    help="differentiate the fast engine's compiled right-hand side (default) or the "
                         "monolithic reference's Python models (the cross-check); identical physics")
    return ap


def frequency_grid(mode_list, fmin=None, fmax=None, points=800):
    """Log-spaced grid with every oscillatory mode's frequency added (peaks are not missed)."""
    fs = [m["f"] for m in mode_list if m["kind"] == "oscillatory"]
    if fmin is None:
        fmin = min([0.05] + [0.1 * f for f in fs])
    if fmax is None:
        fmax = max([10.0] + [2.0 * f for f in fs])
    if not (0 < fmin < fmax) or not all(map(math.isfinite, (fmin, fmax))):
        raise ValueError(f"need 0 < fmin < fmax (got fmin={fmin!r}, fmax={fmax!r})")
    grid = np.geomspace(fmin, fmax, max(2, points))
    return np.unique(np.concatenate([grid, [f for f in fs if fmin <= f <= fmax]]))


# A transfer function whose peak stays below this share of the largest of its kind (span
# length or torque) is a structural zero left by round-off: e.g. nothing downstream of a
# speed-controlled S-wrap with tension feed-forward reaches the load cells upstream of it.
ZERO_SHARE = 1e-9


def structural_zeros(tfs):
    """{input: [bool per load cell]}: True where the transfer function is zero up to round-off."""
    peak = {n: np.max(np.abs(G), axis=1) for n, G in tfs.items()}
    top = {}
    for n, p in peak.items():
        kind = n.rsplit(".", 1)[1]
        top[kind] = max(top.get(kind, 0.0), float(np.max(p)) if p.size else 0.0)
    return {n: [bool(x <= ZERO_SHARE * top[n.rsplit(".", 1)[1]]) for x in p] for n, p in peak.items()}


def main(argv=None):
    args = parser().parse_args(argv)
    from webline.orchestrator.layout import LayoutError, load_system
    from webline.orchestrator.validate_cmd import parse_overrides
    from webline.orchestrator import modes as M

    try:
        system = load_system(args.layout, parse_overrides(args.set, prog="webline modes"))
    except LayoutError as exc:
        print(str(exc), file=sys.stderr)
        return 2
    except (ValueError, OSError) as exc:
        print(f"{args.layout}: {exc}", file=sys.stderr)
        return 2
    if args.points < 2:
        print("webline modes: --points must be at least 2", file=sys.stderr)
        return 2
    lin = M.linearise_system(system, jacobian=args.jacobian)
    mode_list = M.modes(lin)
    try:
        freqs = frequency_grid(mode_list, args.fmin, args.fmax, args.points)
    except ValueError as exc:
        print(f"webline modes: {exc}", file=sys.stderr)
        return 2
    tfs = M.transfer_functions(lin, system, freqs)
    print(report(args.layout, system, lin, mode_list, freqs, tfs))
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        path = args.out / "modes.json"
        path.write_text(json.dumps(to_json(args.layout, system, lin, mode_list, freqs, tfs), indent=1))
        if lin.outputs:
            png = bode_plot(lin, mode_list, freqs, tfs, args.out / "bode.png", title=system.meta.get("name", ""))
            print(f"\nwrote {path} and {png}")
        else:
            print(f"\nwrote {path} (no load cells: no Bode plot)")
    return 0


def _moves(m):
    return ", ".join(f"{n} {100 * s:.0f}%" for n, s in m["moves"])


def report(layout, system, lin, mode_list, freqs, tfs):
    """The text table: modes, then peak gains per input and load cell."""
    op = system.meta["operating_point"]
    master = system.meta.get("master")
    v = op["v"][system.meta["elements"][master]["index"]] if master in system.meta.get("elements", {}) else None
    lines = [f"{layout}: linearised at t = {lin.t:g} s"
             + (f", line speed {v:.4g} m/s" if v is not None else "")
             + f": {len(lin.states)} states ({len(lin.dropped)} frozen: angles and roll radii), "
             f"{len(lin.outputs)} load cells"]
    # a roll's speed changes slowly with its radius ({5}); anything else should be at rest
    rolls = [i for i, (_, m, s) in enumerate(lin.info["state_kinds"])
             if m in ("UnwindRoll", "RewindRoll") and s == "omega"]
    others = [i for i in range(len(lin.states)) if i not in rolls]
    if rolls and float(np.max(lin.residual[rolls])) > 0:
        k = max(rolls, key=lambda i: lin.residual[i])
        lines.append(f"  operating point: d omega/dt = {lin.residual[k]:.3g} rad/s^2 on {lin.states[k]} "
                     "(a roll's slow speed change as its radius changes)")
    if others and float(np.max(lin.residual[others])) > 1e-6:
        k = max(others, key=lambda i: lin.residual[i])
        lines.append(f"  WARNING: not an equilibrium: |dx/dt| = {lin.residual[k]:.3g} on {lin.states[k]}; "
                     "the modes describe the line near this state only")
    lines.append("")
    lines.append("oscillatory modes:")
    lines.append(f"  {'f [Hz]':>8} {'zeta':>8} {'Re [1/s]':>9}  what moves (share of modal energy)")
    for m in mode_list:
        if m["kind"] != "oscillatory":
            continue
        flag = "  UNSTABLE" if m["eigenvalue"].real > 0 else ""
        lines.append(f"  {m['f']:8.3f} {m['zeta']:8.4f} {m['eigenvalue'].real:9.3f}  {_moves(m)}{flag}")
    real = [m for m in mode_list if m["kind"] != "oscillatory"]
    if real:
        lines.append("real modes (slowest first):")
        lines.append(f"  {'tau [s]':>8} {'lambda':>10}  what moves")
        for m in sorted(real, key=lambda m: -abs(1.0 / m["eigenvalue"].real) if m["eigenvalue"].real else -math.inf):
            if m["kind"] == "integrator":
                lines.append(f"  {'inf':>8} {0.0:10.4g}  {_moves(m)} (integrator)")
            else:
                flag = "  UNSTABLE" if m["eigenvalue"].real > 0 else ""
                lines.append(f"  {m['tau']:8.4g} {m['eigenvalue'].real:10.4g}  {_moves(m)}{flag}")
    lines.append("")
    if not lin.outputs:
        lines.append("no load cells: no transfer functions")
        return "\n".join(lines)
    lines.append(f"peak gain |G| (at f in Hz) over {freqs[0]:.3g}-{freqs[-1]:.3g} Hz; "
                 "span-length change (.dL) in N/m, motor torque (.tau) in N/(N.m):")
    width = 20
    zeros = structural_zeros(tfs)
    lines.append(f"  {'input':<20}" + "".join(f"{c:>{width}}" for c in lin.outputs))
    for name, G in tfs.items():
        cells = []
        for g, z in zip(G, zeros[name]):
            k = int(np.argmax(np.abs(g)))
            cells.append("0" if z else f"{abs(g[k]):10.3g} @ {freqs[k]:6.3g}")
        lines.append(f"  {name:<20}" + "".join(f"{c:>{width}}" for c in cells))
    return "\n".join(lines)


def to_json(layout, system, lin, mode_list, freqs, tfs):
    def cx(z):
        return [float(z.real), float(z.imag)]

    inputs = {}
    zeros = structural_zeros(tfs)
    for name, G in tfs.items():
        unit = "N/m" if name.endswith(".dL") else "N/(N.m)"
        inputs[name] = {"unit": unit, "load_cells": {
            col: {"zero": zeros[name][k],
                  "magnitude": [0.0 if zeros[name][k] else float(x) for x in np.abs(G[k])],
                  "phase_deg": [0.0 if zeros[name][k] else float(x) for x in np.degrees(np.angle(G[k]))]}
            for k, col in enumerate(lin.outputs)}}
    lam = np.linalg.eigvals(lin.A) if lin.A.size else np.zeros(0)
    return {
        "layout": str(layout), "name": system.meta.get("name"), "t": lin.t, "jacobian": lin.info.get("jacobian"),
        "states": lin.states, "frozen_states": lin.dropped,
        "residual_max": float(np.max(lin.residual)) if lin.residual.size else 0.0,
        "eigenvalues": [cx(z) for z in sorted(lam, key=lambda z: (abs(z.imag), z.real))],
        "modes": [{"kind": m["kind"], "f_Hz": m["f"], "zeta": m["zeta"], "eigenvalue": cx(m["eigenvalue"]),
                   "tau_s": m["tau"], "moves": [{"name": n, "share": s} for n, s in m["moves"]]}
                  for m in mode_list],
        "load_cells": lin.outputs,
        "linear_model": {"about": "dx/dt = A x + B u + B_rate du/dt, y = C x + D u; deviations from the "
                                  "operating point, SI; u: span-end lengths (m), then motor torques (N.m)",
                         "states": lin.states, "inputs": lin.inputs, "outputs": lin.outputs,
                         "A": lin.A.tolist(), "B": lin.B.tolist(), "B_rate": lin.B_rate.tolist(),
                         "C": lin.C.tolist(), "D": lin.D.tolist()},
        "transfer_functions": {"f_Hz": [float(f) for f in freqs], "inputs": inputs,
                               "convention": "G = Y/X with x(t) = Im(X exp(i 2 pi f t)), y likewise; "
                                             ".dL: the element's span-length change (its eccentricity "
                                             "convention, docs/layout.md), .tau: its motor torque"},
    }


def bode_plot(lin, mode_list, freqs, tfs, path, title=""):
    """Bode plot: per load cell, magnitude and phase of every input (span-length changes
    left, motor torques right); dotted lines at the oscillatory modes."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = [("span-length change", "N/m", [n for n in tfs if n.endswith(".dL")]),
              ("motor torque", "N/(N.m)", [n for n in tfs if n.endswith(".tau")])]
    groups = [g for g in groups if g[2]]
    p = len(lin.outputs)
    fig, axes = plt.subplots(2 * p, len(groups), figsize=(7.5 * len(groups), 3.2 * 2 * p),
                             sharex=True, squeeze=False)
    fosc = [m["f"] for m in mode_list if m["kind"] == "oscillatory" and freqs[0] <= m["f"] <= freqs[-1]]
    cmap = plt.get_cmap("tab20")
    zeros = structural_zeros(tfs)
    for gi, (label, unit, names) in enumerate(groups):
        for k, col in enumerate(lin.outputs):
            am, ap = axes[2 * k, gi], axes[2 * k + 1, gi]
            for ni, n in enumerate(names):
                g = tfs[n][k]
                if zeros[n][k]:
                    continue
                c = cmap(ni % 20)
                am.loglog(freqs, np.abs(g), color=c, lw=1, label=n.rsplit(".", 1)[0])
                # wrapped: the wrap delay of an entering span adds a phase linear in f
                ap.semilogx(freqs, np.degrees(np.angle(g)), ".", color=c, ms=1.2)
            for f in fosc:
                am.axvline(f, color="0.7", ls=":", lw=0.8)
            am.set_ylabel(f"|G| {col} [{unit}]")
            ap.set_ylabel("phase [deg]")
            ap.set_ylim(-185, 185)
            ap.set_yticks([-180, -90, 0, 90, 180])
            am.set_title(f"{label} -> {col}", fontsize=9)
            am.grid(True, which="both", alpha=0.3)
            ap.grid(True, which="both", alpha=0.3)
            if any(line.get_label()[:1] != "_" for line in am.get_lines()):
                am.legend(fontsize=5, ncol=3, loc="lower left")
        axes[-1, gi].set_xlabel("frequency [Hz]")
    if title:
        fig.suptitle(f"{title}: transfer functions to the load cells (dotted: modes)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


if __name__ == "__main__":
    sys.exit(main())
