"""``webline orders``: which rotating element is in a measured signal.

    webline orders DATA --signal COL --tach NAME=COL [--tach NAME=COL ...]
                   [--kind [NAME=]KIND ...] [--orders N] [--max-harmonic N]
                   [--max-order N] [--alpha P] [--time COL] [--time-unit U] [--out DIR]

For each named shaft the tach channel gives its angle (KIND: pulse, angle,
speed, model - an angle from a simulation, refined from the signal - or
auto-detected). The signal's amplitude spectrum is searched for significant
peaks, each tagged as harmonic j of one shaft or as ambiguous when several
shafts' harmonics fall within the record's resolution. Each shaft's harmonics
are fitted against its angle (all shafts jointly) and its order spectrum taken.
Prints a table; with --out writes ``orders.json`` and ``orders.png``.
Columns are named as in the header, with or without the unit (``Force`` or
``"Force [N]"``). The time column is detected (time, t, Timestamp, time_s,
``Time [s]``, date-time strings) or named with --time; jittered stamps are
resampled and short gaps filled, each reported as a note.

Exit codes: 0 ok, 2 bad data or arguments.
"""
import argparse
import json
import re
import sys
from pathlib import Path

import numpy as np

from webline.diagnosis import orders as od
from webline.diagnosis import spectra as sp
from webline.diagnosis.data import DataError, load

KINDS = ("auto", "pulse", "angle", "speed", "model")
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


class UsageError(ValueError):
    """Bad command-line input (exit 2)."""


def _parser():
    p = argparse.ArgumentParser(prog="webline orders", description=__doc__.split("\n\n", 1)[1],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("data", help="measured record (.csv with a time column, or .mat)")
    p.add_argument("--signal", required=True, help="column to analyse (e.g. a load cell)")
    p.add_argument("--tach", action="append", required=True, metavar="NAME=COL",
                   help="a shaft and the column that tracks it (repeat per shaft)")
    p.add_argument("--kind", action="append", default=[], metavar="[NAME=]KIND",
                   help=f"tach kind: {', '.join(KINDS)} (default auto); without NAME= for every shaft")
    p.add_argument("--orders", type=int, default=6, help="harmonics fitted per shaft (default 6)")
    p.add_argument("--max-harmonic", type=int, default=10, help="highest harmonic used to tag peaks (default 10)")
    p.add_argument("--max-order", type=float, default=12, help="order spectra up to this order (default 12)")
    p.add_argument("--alpha", type=float, default=0.01,
                   help="false-alarm probability of the peak search (default 0.01)")
    p.add_argument("--time", metavar="COL", help="the time column (default: detected by name or date-time values)")
    p.add_argument("--time-unit", metavar="UNIT", help="unit of the time column when its header gives none (e.g. ms)")
    p.add_argument("--out", type=Path, help="folder for orders.json and orders.png")
    return p


def _parse_pairs(items, what):
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not _NAME.match(name) or not value:
            raise UsageError(f"{what} {item!r}: expected NAME=VALUE with NAME like unwind or s_wrap")
        if name in out:
            raise UsageError(f"{what}: shaft {name!r} given twice")
        out[name] = value
    return out


def _kinds(items, names):
    kinds = dict.fromkeys(names, "auto")
    for item in items:
        name, sep, kind = item.rpartition("=")
        if kind not in KINDS:
            raise UsageError(f"--kind {item!r}: kind must be one of {', '.join(KINDS)}")
        if not sep:
            kinds = dict.fromkeys(names, kind)
        elif name not in kinds:
            raise UsageError(f"--kind {item!r}: no --tach named {name!r}")
        else:
            kinds[name] = kind
    return kinds


def analyse(record, signal, tachs, kinds, *, n_orders=6, max_harmonic=10, max_order=12, alpha=0.01):
    """The whole analysis as a JSON-ready dict (see module docstring). ``tachs``:
    shaft -> column; ``kinds``: shaft -> kind. Raises ``UsageError`` / ``ValueError``
    on data that cannot be analysed."""
    for col in [signal, *tachs.values()]:
        if record.resolve(col) is None:
            raise UsageError(f"no column {col!r} in {record.source} (have: {', '.join(record.columns)})")
    signal = record.resolve(signal)
    tachs = {name: record.resolve(col) for name, col in tachs.items()}
    t, x = record.time, record[signal]
    thetas, shafts = {}, {}
    for name, col in tachs.items():
        unit = record.units.get(col)
        try:
            if kinds[name] == "model":
                theta, kind = od.shaft_angle(t, record[col], "angle", unit)
                refined = od.refine_angle(x, theta, orders=n_orders)
                theta, extra = refined.theta, {"scale": refined.scale,
                                               "correction_range_rad": float(np.ptp(refined.correction))}
                kind = "model"
            else:
                theta, kind = od.shaft_angle(t, record[col], kinds[name], unit)
                extra = {}
            _, f_t = od.shaft_frequency(t, theta)
            orders, amp = od.order_spectrum(theta, x, max_order=max_order)
        except ValueError as exc:
            raise ValueError(f"shaft {name} (column {col!r}): {exc}") from None
        fam = sp.family(f_t)
        thetas[name] = theta
        shafts[name] = {"column": col, "kind": kind, "frequency_hz": {"mean": fam.mean, "spread": fam.spread},
                        **extra, "order_spectrum": {"orders": orders.tolist(), "amplitude": amp.tolist()}}

    fits = od.joint_harmonic_fit(x, thetas, n_orders)
    for name, fit in fits.items():
        shafts[name]["explained"] = fit.explained
        shafts[name]["harmonics"] = [
            {"order": int(j), "amplitude": float(a), "phase_rad": float(p), "explained": float(e)}
            for j, a, p, e in zip(fit.orders, fit.amplitude, fit.phase, fit.explained_per_order)]
    any_fit = next(iter(fits.values()))
    detrended = np.var(any_fit.residual + sum(f.component for f in fits.values()))

    f, amp = sp.amplitude_spectrum(x, record.fs)
    peaks = sp.spectral_peaks(f, amp, alpha=alpha)
    resolution = sp.frequency_resolution(len(x), record.fs)
    tags = sp.tag_peaks(peaks.frequency, {n: sp.Family(**s["frequency_hz"]) for n, s in shafts.items()},
                        resolution, max_harmonic=max_harmonic)
    return {
        "source": record.source,
        "signal": {"column": signal, "unit": record.units.get(signal)},
        "samples": len(x), "fs_hz": record.fs, "duration_s": record.duration,
        "resolution_hz": resolution, "alpha": alpha,
        "phase_convention": "component = amplitude * sin(order * theta + phase_rad)",
        "explained_total": float(1.0 - np.var(any_fit.residual) / detrended) if detrended > 0 else 0.0,
        "shafts": shafts,
        "notes": list(record.notes),
        "peaks": [{"frequency_hz": float(fr), "amplitude": float(a), "snr": float(s), "status": tag.status,
                   "family": tag.family, "harmonic": tag.harmonic,
                   "candidates": [{"family": n, "harmonic": j, "order_amplitude": _order_amplitude(shafts[n], j)}
                                  for n, j in tag.candidates]}
                  for fr, a, s, tag in zip(peaks.frequency, peaks.amplitude, peaks.snr, tags)],
        "spectrum": {"frequency_hz": f, "amplitude": amp, "threshold": peaks.threshold},  # for the plot only
    }


def _order_amplitude(shaft, j):
    """Amplitude of order j in a shaft's order spectrum (None beyond --max-order): the
    evidence for telling apart the candidates of an ambiguous peak."""
    osp = shaft["order_spectrum"]
    if not osp["orders"] or j > osp["orders"][-1]:
        return None
    return float(osp["amplitude"][int(np.argmin(np.abs(np.asarray(osp["orders"]) - j)))])


def _label(peak, evidence=True):
    if peak["status"] == "tagged":
        return f"{peak['family']} x{peak['harmonic']}"
    if peak["status"] == "ambiguous":
        def one(c):
            a = c["order_amplitude"]
            return f"{c['family']} x{c['harmonic']}" + (f" (order amplitude {a:.3g})" if evidence and a is not None else "")
        return "ambiguous: " + ", ".join(one(c) for c in peak["candidates"])
    return "-"


def format_table(result):
    """The printed report."""
    unit = result["signal"]["unit"] or ""
    lines = [f"{result['signal']['column']} in {result['source']}: {result['samples']} samples, "
             f"{result['fs_hz']:.6g} Hz, {result['duration_s']:.6g} s, resolution {result['resolution_hz']:.4g} Hz",
             "", f"{'shaft':<12} {'column':<16} {'kind':<7} {'f mean [Hz]':>11} {'spread':>8} {'explained':>9}"]
    for name, s in result["shafts"].items():
        fr = s["frequency_hz"]
        lines.append(f"{name:<12} {s['column']:<16} {s['kind']:<7} {fr['mean']:>11.4f} {fr['spread']:>8.4f} "
                     f"{s['explained']:>9.1%}")
    if result.get("notes"):
        lines += [""] + [f"note: {n}" for n in result["notes"]]
    lines += ["", f"peaks significant at alpha = {result['alpha']:g} ({len(result['peaks'])}):",
              f"{'f [Hz]':>9} {'amplitude':>10} {'SNR':>7}  tag"]
    for p in result["peaks"]:
        lines.append(f"{p['frequency_hz']:>9.4f} {p['amplitude']:>10.4g} {p['snr']:>7.1f}  {_label(p)}")
    lines += ["", f"harmonic fit, amplitude [{unit}] * sin(j theta + phase), all shafts jointly "
                  f"({result['explained_total']:.1%} of the detrended variance):",
              f"{'shaft':<12} {'j':>2} {'amplitude':>10} {'phase':>7} {'explained':>9}"]
    for name, s in result["shafts"].items():
        for h in s["harmonics"]:
            lines.append(f"{name:<12} {h['order']:>2} {h['amplitude']:>10.4g} {h['phase_rad']:>7.3f} "
                         f"{h['explained']:>9.1%}")
    return "\n".join(lines)


def plot(result, path):
    """Spectrum with tagged peaks, then one order spectrum per shaft, to a PNG."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shafts = result["shafts"]
    fig, axes = plt.subplots(1 + len(shafts), 1, figsize=(10, 3.2 * (1 + len(shafts))), squeeze=False)
    ax = axes[0, 0]
    spec = result["spectrum"]
    f, amp = spec["frequency_hz"], spec["amplitude"]
    fmax = max([p["frequency_hz"] for p in result["peaks"]] + [0.0]) * 1.15 or f[-1]
    keep = f <= fmax
    ax.plot(f[keep], amp[keep], lw=0.8, color="0.3")
    ax.plot(f[keep], spec["threshold"][keep], lw=0.8, ls="--", color="0.6", label="significance threshold")
    colours = dict(zip(shafts, plt.rcParams["axes.prop_cycle"].by_key()["color"]))
    for p in result["peaks"]:
        c = colours.get(p["family"], "k") if p["status"] == "tagged" else ("r" if p["status"] == "ambiguous" else "0.5")
        ax.plot(p["frequency_hz"], p["amplitude"], "o", ms=4, color=c)
        ax.annotate(_label(p, evidence=False).replace("ambiguous: ", "? "), (p["frequency_hz"], p["amplitude"]),
                    textcoords="offset points", xytext=(3, 4), fontsize=7, color=c)
    unit = result["signal"]["unit"] or ""
    ax.set(xlabel="frequency [Hz]", ylabel=f"amplitude [{unit}]",
           title=f"{result['signal']['column']}: amplitude spectrum (Hann), peaks tagged to shafts")
    ax.legend(loc="upper right", fontsize=8)
    for ax, (name, s) in zip(axes[1:, 0], shafts.items()):
        osp = s["order_spectrum"]
        ax.plot(osp["orders"], osp["amplitude"], lw=0.8, color=colours[name])
        h = s["harmonics"]
        ax.plot([x["order"] for x in h], [x["amplitude"] for x in h], "kx", ms=5, label="harmonic fit")
        ax.set(xlabel="order [per revolution]", ylabel=f"amplitude [{unit}]",
               title=f"{name}: order spectrum ({s['kind']} from {s['column']}, "
                     f"{s['frequency_hz']['mean']:.4g} Hz mean)")
        ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _jsonable(result):
    return {k: v for k, v in result.items() if k != "spectrum"}


def main(argv=None):
    args = _parser().parse_args(argv)
    try:
        tachs = _parse_pairs(args.tach, "--tach")
        kinds = _kinds(args.kind, list(tachs))
        if args.orders < 1 or args.max_harmonic < 1 or not 0 < args.alpha < 1:
            raise UsageError("--orders and --max-harmonic must be >= 1, --alpha in (0, 1)")
        record = load(args.data, time=args.time, time_unit=args.time_unit)
        result = analyse(record, args.signal, tachs, kinds, n_orders=args.orders,
                         max_harmonic=args.max_harmonic, max_order=args.max_order, alpha=args.alpha)
    except (DataError, ValueError) as exc:  # UsageError is a ValueError
        print(f"webline orders: error: {exc}", file=sys.stderr)
        return 2
    print(format_table(result))
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "orders.json").write_text(json.dumps(_jsonable(result), indent=1) + "\n")
        plot(result, args.out / "orders.png")
        print(f"\nwrote {args.out / 'orders.json'} and {args.out / 'orders.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
