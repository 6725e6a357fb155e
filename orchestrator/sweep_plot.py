"""Plots of a finished sweep (``webline plot-sweep OUT``), from ``OUT/sweep.csv``.

The sweep file's ``plot`` section chooses the plot::

    plot:
      type: frequency_vs_rotation   # dominant tension frequency against roll rotation frequency
      y: lc_unwind.T.f_dom          # a sweep.csv column (Hz)
      roll: unwind                  # roll component: x = <roll>.f_rot = mean(omega)/2pi
      speed: experiment.line_speed  # swept keys for the nominal x = v/(2 pi R)
      radius: unwind.radius

    plot:
      type: scatter                 # any two columns, optional colour column
      x: experiment.line_speed.si
      y: lc_unwind.T.p2p
      color: unwind.radius.si

For ``frequency_vs_rotation`` the primary x is the roll's recorded rotation
frequency (mean omega over the steady window / 2 pi) when the runs recorded
it: the roll turns with the unstretched web and its radius shrinks, so
v/(2 pi R) from the nominal values is a few percent off. The nominal x is
drawn as well (open markers); the title says which x the statistics use.
"""
import argparse
import json
import math
import sys
from pathlib import Path

from webline.orchestrator.sweep import TABLE, read_table


def _num(v):
    try:
        v = float(v)
    except (TypeError, ValueError):
        return math.nan
    return v


def frequency_points(rows, spec):
    """[(run_id, x_measured, x_nominal, y)] of the ok runs, x in Hz."""
    roll, y = spec.get("roll"), spec["y"]
    speed, radius = spec.get("speed"), spec.get("radius")
    pts = []
    for r in rows:
        if r.get("status") != "ok":
            continue
        xm = _num(r.get(f"{roll}.f_rot")) if roll else math.nan
        v, R = _num(r.get(f"{speed}.si")), _num(r.get(f"{radius}.si"))
        xn = v / (2 * math.pi * R) if speed and radius and R > 0 else math.nan
        pts.append((r["run_id"], xm, xn, _num(r.get(y))))
    return pts


def plot_sweep(out, spec=None):
    """Draw the plot(s) of the sweep in folder ``out``; returns the written paths."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out)
    meta = json.loads((out / "sweep.json").read_text())
    spec = spec or meta.get("plot")
    if not spec:
        raise ValueError(f"{out / 'sweep.json'}: the sweep has no plot section")
    rows = read_table(out / TABLE)
    kind = spec.get("type", "frequency_vs_rotation")
    written = []
    if kind == "frequency_vs_rotation":
        pts = frequency_points(rows, spec)
        have_m = bool(pts) and all(math.isfinite(p[1]) for p in pts)
        xi = 1 if have_m else 2
        which = (f"x = recorded {spec.get('roll')} mean(omega)/2pi" if have_m
                 else "x = nominal v/(2 pi R) (no recorded roll speed)")
        fig, (ax, ax2) = plt.subplots(2, 1, figsize=(6.4, 7.2), height_ratios=[3, 1.3], sharex=True)
        xs_m = [p[1] for p in pts]
        xs_n = [p[2] for p in pts]
        ys = [p[3] for p in pts]
        finite = [v for v in xs_m + xs_n + ys if math.isfinite(v)]
        lo, hi = (min(finite), max(finite)) if finite else (0.0, 1.0)
        pad = 0.08 * (hi - lo or 1.0)
        ax.plot([lo - pad, hi + pad], [lo - pad, hi + pad], "k--", lw=0.8, label="y = x")
        for order in (2, 3):  # a harmonic of the rotation that won the spectrum lies here
            ax.plot([lo - pad, (hi + pad) / order], [order * (lo - pad), hi + pad], ":", color="0.6", lw=0.8,
                    label="y = 2x, 3x (harmonics)" if order == 2 else None)
        if have_m:
            ax.plot(xs_m, ys, "o", color="C0", label=f"x = {spec.get('roll')} mean(omega)/2pi (recorded)")
        ax.plot(xs_n, ys, "o", mfc="none", color="C1", label="x = v/(2 pi R) (nominal)")
        ax.set_ylabel(f"dominant frequency of {spec['y'].rsplit('.', 2)[0]} tension (Hz)")
        ax.legend(loc="upper left", fontsize=8)
        ax.grid(alpha=0.3)
        err = [100 * (p[3] / p[xi] - 1) for p in pts if math.isfinite(p[3]) and p[xi] > 0]
        stat = (f"y/x - 1: mean {sum(err) / len(err):+.2f} %, max |.| {max(map(abs, err)):.2f} % "
                f"({len(err)} runs)") if err else "no finite points"
        ax.set_title(f"{meta.get('name', out.name)}\n{which}; {stat}", fontsize=9)
        if have_m:
            ax2.plot(xs_m, [100 * (y / x - 1) for x, y in zip(xs_m, ys)], "o", color="C0")
        ax2.plot(xs_n, [100 * (y / x - 1) if x > 0 else math.nan for x, y in zip(xs_n, ys)],
                 "o", mfc="none", color="C1")
        ax2.axhline(0, color="k", lw=0.8, ls="--")
        ax2.set_ylabel("y/x - 1 (%)")
        ax2.set_xlabel("roll rotation frequency (Hz)")
        ax2.grid(alpha=0.3)
        fig.tight_layout()
        path = out / "frequency_vs_rotation.png"
        fig.savefig(path, dpi=120)
        plt.close(fig)
        written.append(path)
        table = out / "frequency_vs_rotation.csv"
        with open(table, "w") as f:
            f.write("run_id,x_recorded_hz,x_nominal_hz,y_hz\n")
            for p in pts:
                f.write(",".join([p[0], *(repr(v) for v in p[1:])]) + "\n")
        written.append(table)
    elif kind == "scatter":
        x, y, c = spec["x"], spec["y"], spec.get("color")
        ok = [r for r in rows if r.get("status") == "ok"]
        fig, ax = plt.subplots(figsize=(6.4, 4.8))
        sc = ax.scatter([_num(r.get(x)) for r in ok], [_num(r.get(y)) for r in ok],
                        c=[_num(r.get(c)) for r in ok] if c else None)
        if c:
            fig.colorbar(sc, ax=ax, label=c)
        ax.set_xlabel(x)
        ax.set_ylabel(y)
        ax.grid(alpha=0.3)
        ax.set_title(meta.get("name", out.name))
        fig.tight_layout()
        path = out / f"scatter_{y}_vs_{x}.png".replace("/", "_")
        fig.savefig(path, dpi=120)
        plt.close(fig)
        written.append(path)
    else:
        raise ValueError(f"plot type {kind!r} unknown (frequency_vs_rotation, scatter)")
    return written


def main(argv=None):
    ap = argparse.ArgumentParser(prog="webline plot-sweep", description="Redraw the plot of a finished sweep (its sweep file's plot section) from OUT/sweep.csv.")
    ap.add_argument("out", type=Path, help="sweep output folder (holds sweep.csv and sweep.json)")
    args = ap.parse_args(argv)
    for name in ("sweep.json", TABLE):
        if not (args.out / name).is_file():
            print(f"webline plot-sweep: {args.out / name}: not found (run 'webline sweep' first)", file=sys.stderr)
            return 2
    try:
        paths = plot_sweep(args.out)
    except (ValueError, KeyError) as exc:
        print(f"webline plot-sweep: {exc}", file=sys.stderr)
        return 2
    for p in paths:
        print(f"plot -> {p}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
