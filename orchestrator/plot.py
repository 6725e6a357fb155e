"""Figures of one run (matplotlib, Agg): tension and speed time series, tension spectra.

* ``timeseries.png``: load-cell tensions (span tensions when the line has no
  load cell) and web speeds of the rotating elements against time;
* ``spectra.png``: one-sided amplitude spectrum of each tension over a steady
  window (Hann window, linear trend removed, amplitude-corrected), as in the
  paper's Fig. 7, with a marker at the fundamental f = v/(2 pi R) of every
  rotating element. The marker is taken from the element's recorded speed,
  f = mean(omega)/(2 pi) over the window: for a roll whose radius shrinks this
  is the frequency it really turned at (v/(2 pi R0) would be off by the
  radius change and the strain of the web on the unwind).

Function-first: :func:`amplitude_spectrum` and :func:`harmonic_markers` take
arrays and a Result and return arrays and lists; :func:`plot_results` writes
the PNGs. Which columns are tensions and speeds comes from the component
models recorded in the result metadata (``LoadCell``, ``Span``, rolls and
rollers), optionally narrowed by ``System.meta`` keys ``sensors`` (load-cell
component names) and ``steady_window`` ([t0, t1] s).
"""
import math
from pathlib import Path

import numpy as np

ROTATING = ("UnwindRoll", "RewindRoll", "DrivenRoller", "IdleRoller")
MAX_LINES = 12  # series per panel before the legend is dropped
ENVELOPE_BINS = 1000  # columns a full-width time series is reduced to (a 10 in figure is 900-1200 px wide)


def envelope(x, y, bins=ENVELOPE_BINS):
    """The points of the line (x, y) that draw it at ``bins`` columns: in each of
    ``bins`` equal runs of samples its first, lowest, highest and last point, in their
    order (the M4 reduction of Jugel et al., VLDB 2014). A figure is a few hundred to a
    thousand pixels wide, and a line through each column's first, extreme and last
    points covers the same pixels as every sample would (60 000 a series for 60 s at
    1 kHz). It saves less than one might think: a diagnosis report's 12 figures of
    three 1 kHz runs took 6.4 s of CPU, 5.8 s so; most of a figure is fixed cost.
    Series of at most ``4 * bins`` samples are returned as given. NaN samples are kept
    where they fall (a gap stays a gap)."""
    x, y = np.asarray(x), np.asarray(y)
    n = y.size
    if n <= 4 * bins:
        return x, y
    m = n // bins
    body = y[:m * bins].reshape(bins, m)
    start = np.arange(bins) * m
    nan = np.isnan(y)
    gaps = nan[:m * bins].reshape(bins, m)
    keep = [start + np.argmin(np.where(gaps, np.inf, body), axis=1),
            start + np.argmax(np.where(gaps, -np.inf, body), axis=1),
            start, start + m - 1, np.flatnonzero(nan), np.arange(m * bins, n)]
    idx = np.unique(np.concatenate([np.asarray(k, dtype=np.intp) for k in keep]))
    return x[idx], y[idx]


def _models(result):
    return {n: c.get("model", "") for n, c in result.meta.get("components", {}).items()}


def _element(result, name):
    c = result.meta.get("components", {}).get(name, {})
    return c.get("element") or name


def _system_meta(result):
    m = result.meta.get("system_meta", {})
    return m if isinstance(m, dict) else {}


def tension_columns(result):
    """Load-cell readings ``<lc>.T`` (those named in ``System.meta['sensors']`` if given:
    a list of names or a {name: {component: ...}} mapping), else every span tension."""
    models = _models(result)
    sensors = _system_meta(result).get("sensors")
    cells = [n for n, m in models.items() if m == "LoadCell"]
    if isinstance(sensors, dict):
        sensors = [v if isinstance(v, dict) else k for k, v in sensors.items()]
    if isinstance(sensors, (list, tuple)) and sensors:
        wanted = [s if isinstance(s, str) else s.get("component", s.get("name", "")) for s in sensors]
        chosen = [n for n in wanted if f"{n}.T" in result]
        cells = chosen or cells
    cols = [f"{n}.T" for n in cells if f"{n}.T" in result]
    if not cols:
        cols = [f"{n}.T" for n, m in models.items() if m in ("Span", "DampedSpan") and f"{n}.T" in result]
    if not cols and not models:
        cols = [c for c in result.columns if c.endswith(".T")]
    return cols


def speed_columns(result, idlers=False):
    """Web speed ``<comp>.v`` of the driven elements (rolls, driven rollers) in system
    order, and of the idle rollers too with ``idlers``."""
    models = _models(result)
    if not models:
        return [c for c in result.columns if c.endswith(".v")]
    kinds = ("UnwindRoll", "DrivenRoller", "RewindRoll") + (("IdleRoller",) if idlers else ())
    return [f"{n}.v" for n, m in models.items() if m in kinds and f"{n}.v" in result]


def line_speed_column(result):
    """The line-speed reference column named by ``System.meta['line_speed']``, if recorded."""
    c = _system_meta(result).get("line_speed")
    return c if isinstance(c, str) and c in result else None


def display_unit(result, quantity, si_unit):
    """(unit, SI per unit) for plotting ``quantity`` ("tension", "speed"): the layout's
    display unit from ``System.meta['units']['display']``, else SI."""
    d = _system_meta(result).get("units", {})
    d = d.get("display", {}) if isinstance(d, dict) else {}
    u = d.get(quantity) if isinstance(d, dict) else None
    if isinstance(u, dict) and u.get("unit") and u.get("si_per_unit"):
        return str(u["unit"]), float(u["si_per_unit"])
    return si_unit, 1.0


def _label(result, column):
    """``lc9 (roller9).T``: component, its element when different, variable."""
    comp, var = column.split(".", 1)
    el = _element(result, comp)
    return f"{comp} ({el}).{var}" if el != comp else column


def steady_window(result):
    """[t0, t1] for spectra: ``System.meta['steady_window']`` if given, else the second half."""
    t = result.time
    if not len(t):
        return (0.0, 0.0)
    w = _system_meta(result).get("steady_window")
    if isinstance(w, (list, tuple)) and len(w) == 2:
        return (max(float(w[0]), t[0]), min(float(w[1]), t[-1]))
    return (t[0] + 0.5 * (t[-1] - t[0]), t[-1])


def amplitude_spectrum(t, x, window=None, pad=4):
    """One-sided amplitude spectrum (f in Hz, amplitude in the unit of ``x``) of ``x(t)``
    over ``window`` = (t0, t1): linear trend removed, Hann window, amplitude-corrected
    (a sine of amplitude a shows a peak of height a), zero-padded ``pad`` times."""
    from scipy import signal
    from scipy.fft import rfft, rfftfreq

    t, x = np.asarray(t, float), np.asarray(x, float)
    if window is not None:
        keep = (t >= window[0] - 1e-12) & (t <= window[1] + 1e-12)
        t, x = t[keep], x[keep]
    keep = np.isfinite(x)
    t, x = t[keep], x[keep]
    if len(t) < 16:
        return np.zeros(0), np.zeros(0)
    dt = float(np.median(np.diff(t)))
    n = len(x)
    w = signal.get_window("hann", n)
    xw = signal.detrend(x, type="linear") * w
    nfft = int(2 ** math.ceil(math.log2(n * max(1, pad))))
    amp = 2.0 * np.abs(rfft(xw, nfft)) / w.sum()
    return rfftfreq(nfft, dt), amp


def harmonic_markers(result, window=None):
    """[(label, f Hz)] fundamental of every rotating element over ``window``:
    f = mean(omega)/(2 pi) from its recorded speed."""
    window = window or steady_window(result)
    keep = (result.time >= window[0] - 1e-12) & (result.time <= window[1] + 1e-12)
    if not keep.any():
        return []
    models = _models(result)
    names = [n for n, m in models.items() if m in ROTATING] if models else \
        [c[:-6] for c in result.columns if c.endswith(".omega")]
    out = []
    for n in names:
        col = f"{n}.omega"
        if col not in result:
            continue
        w = result[col][keep]
        w = w[np.isfinite(w)]
        if len(w) and abs(w.mean()) > 0:
            out.append((_element(result, n), abs(float(w.mean())) / (2.0 * math.pi)))
    return out


def _merge_markers(markers, rel=2e-3):
    """Markers sorted by frequency; elements turning at the same frequency (within
    ``rel``) share one marker: [("a, b", f), ...]."""
    out = []
    for label, f in sorted(markers, key=lambda m: m[1]):
        if out and abs(f - out[-1][2]) <= rel * max(abs(f), 1e-12):
            out[-1][0].append(label)
        else:
            out.append([[label], f, f])
    return [(", ".join(labels), f) for labels, f, _ in out]


def plot_results(result, out_dir, window=None, fmax=None):
    """Write ``timeseries.png`` and ``spectra.png`` into ``out_dir``; returns their paths."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    tens, speeds = tension_columns(result), speed_columns(result)
    title = Path(str(result.meta.get("layout") or "")).stem or "webline run"
    if result.status != "ok":
        title += f" ({result.status})"

    # time series
    t_unit, t_si = display_unit(result, "tension", "N")
    v_unit, v_si = display_unit(result, "speed", "m/s")
    fig, axes = plt.subplots(2, 1, figsize=(10, 7), sharex=True)
    panels = ((axes[0], tens, f"tension [{t_unit}]", t_si, None),
              (axes[1], speeds, f"web speed [{v_unit}]", v_si, line_speed_column(result)))
    for ax, cols, label, si, ref in panels:
        for c in cols:
            ax.plot(*envelope(result.time, result[c] / si), lw=0.8, label=_label(result, c))
        if ref is not None:
            ax.plot(*envelope(result.time, result[ref] / si), "k--", lw=0.8, label=f"reference ({ref})")
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
        if cols and len(cols) <= MAX_LINES:
            ax.legend(fontsize=8, loc="best")
        if not cols:
            ax.text(0.5, 0.5, "no such columns", transform=ax.transAxes, ha="center")
    axes[-1].set_xlabel("time [s]")
    axes[0].set_title(title)
    fig.tight_layout()
    p = out / "timeseries.png"
    fig.savefig(p, dpi=120)
    plt.close(fig)
    paths.append(p)

    # spectra
    window = window or steady_window(result)
    markers = harmonic_markers(result, window)
    n = max(1, len(tens))
    fig, axes = plt.subplots(n, 1, figsize=(10, 2.6 * n + 0.8), squeeze=False)
    axes = axes[:, 0]
    nyquist = 0.5 / float(np.median(np.diff(result.time))) if len(result.time) > 1 else 1.0
    if fmax is None:
        fmax = _system_meta(result).get("spectrum_fmax")
    if fmax is None:
        top = max((f for _, f in markers), default=1.0)
        fmax = max(1.3 * top, 2.0)
    fmax = min(float(fmax), nyquist)
    for ax, c in zip(axes, tens or [None]):
        if c is not None:
            f, a = amplitude_spectrum(result.time, result[c] / t_si, window)
            band = f <= fmax
            if band.any():
                ax.plot(f[band], a[band], lw=0.9, color="k")
                ax.set_ylim(bottom=0.0, top=1.15 * float(a[band].max()) or 1.0)
            ax.set_ylabel(f"{_label(result, c)}\namplitude [{t_unit}]")
        else:
            ax.text(0.5, 0.5, "no tension columns", transform=ax.transAxes, ha="center")
        ymax = ax.get_ylim()[1]
        for i, (label, fm) in enumerate(_merge_markers(markers)):
            if fm <= fmax:
                ax.axvline(fm, color=f"C{i % 10}", ls="--", lw=0.8)
                ax.text(fm, ymax * (0.95 - 0.1 * (i % 4)), f" {label} {fm:.3g} Hz", color=f"C{i % 10}",
                        fontsize=7, va="top", ha="left")
        ax.set_xlim(0, fmax)
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel("frequency [Hz]")
    axes[0].set_title(f"{title}: tension spectra, t = {window[0]:.3g}..{window[1]:.3g} s (Hann)")
    fig.tight_layout()
    p = out / "spectra.png"
    fig.savefig(p, dpi=120)
    plt.close(fig)
    paths.append(p)
    return paths
