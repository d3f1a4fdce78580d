"""PNG plots of results, as listed in a diagram's ``plots`` section.

A plot entry::

    - title: Speed            # also names the file (speed.png) unless ``file`` is given
      signals: [motor.w, ref.y]
      kind: time              # the default; time series with units on the axis labels
      file: speed.png
      t_min: 0.0              # optional time window
      t_max: 1.0

Signals with different units go to separate panels sharing the time axis, unless
``one_panel: true`` (e.g. a set point from a unit-less source against the force it sets).

``kind: spectrum`` draws the amplitude spectrum of each signal over ``[t_min, t_max]``: the
samples are resampled on a uniform grid (the run's ``output_interval`` makes this exact),
the mean removed, a Hann window applied, and the FFT scaled so that a sinusoid of amplitude
A shows a peak of height A. ``f_max`` limits the frequency axis; the ``peaks`` highest local
maxima are labelled with their frequency in Hz.

``kind: animation`` writes a GIF (default file ``<title>.gif``): a 3-D stick figure of an arm
from the joint angles of an Arm block; keys ``model``, ``frames``, ``fps``, ``trace`` (see
:mod:`spidersim.animation`).
"""
from __future__ import annotations

import math
import os
import re

import numpy as np

from .errors import DiagramError
from .outputs import atomic_path

def _pyplot():
    """``matplotlib.pyplot``, imported when a figure is drawn (about 0.3 s): checking plot
    entries, reading signals and ``run --no-plots`` never import it. The CLI selects the
    Agg backend (``MPLBACKEND``); notebooks keep theirs."""
    import matplotlib.pyplot as plt
    return plt


KINDS = ("time", "spectrum", "animation")
KEYS = ("title", "signals", "kind", "file", "t_min", "t_max", "ylabel", "f_max", "peaks",
        "model", "frames", "fps", "trace", "one_panel")


def _slug(text):
    return re.sub(r"[^A-Za-z0-9]+", "_", str(text)).strip("_").lower()[:80].strip("_") or "plot"


_ELEM = re.compile(r"^(.*?)\[\s*(\d+)\s*\]\Z")


def split_signal(s):
    """``"arm.q[2]"`` -> ``("arm.q", 2)``; ``"arm.q"`` -> ``("arm.q", None)``."""
    m = _ELEM.match(str(s).strip())
    return (m.group(1).strip(), int(m.group(2))) if m else (str(s).strip(), None)


def signal_values(result, s):
    """Samples of the plot entry ``s`` (a signal or one element ``name[i]``)."""
    name, idx = split_signal(s)
    y = result[name]
    if idx is None:
        return y
    return y if y.ndim == 1 else y[:, idx]


#: plot file names: a bare name inside the output folder, with a known extension
_PLOT_FILE = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]{0,120}\Z")
PLOT_EXTENSIONS = (".png", ".svg", ".pdf")


def check_plot_file(name, kind, what, file=None, line=None):
    """A plot's ``file:`` must be a bare file name (no folder, no ``..``) with an extension
    matplotlib writes (.png, .svg, .pdf; .gif for animations); raise DiagramError."""
    exts = (".gif",) if kind == "animation" else PLOT_EXTENSIONS
    if not isinstance(name, str) or not _PLOT_FILE.match(name) or ".." in name:
        raise DiagramError(f"{what}: 'file' must be a bare file name inside the output "
                           f"folder (letters, digits, _ - .; no folder separators, no '..'), "
                           f"got {name!r}", file=file, line=line)
    if not name.lower().endswith(exts):
        raise DiagramError(f"{what}: 'file' {name!r} must end with "
                           f"{', '.join(exts)}", file=file, line=line)


def _kind_of(v):
    """``a mapping``, ``a list`` or the value itself, for messages."""
    return ("a mapping" if isinstance(v, dict) else "a list" if isinstance(v, list)
            else repr(v))


def _entry_line(p, k, entry_lines):
    """Line of plot entry ``k``: its own (a LineDict's), else from ``entry_lines``."""
    line = getattr(p, "line", None)
    if line is None and entry_lines is not None and k < len(entry_lines):
        line = entry_lines[k]
    return line


def _key_line(p, key, line):
    """Line of ``key`` inside entry ``p`` when the YAML reader recorded it, else ``line``."""
    return p.line_of(key) if hasattr(p, "line_of") else line


def _check_plot_keys(p, k, file, line):
    """Entry ``k`` is a mapping of known keys (:data:`KEYS`) with a known ``kind``; return
    the kind (default ``time``)."""
    if not isinstance(p, dict):
        raise DiagramError(f"plots[{k}] must be a mapping with 'signals', got "
                           f"{_kind_of(p)}", file=file, line=line)
    for key in p:
        if key not in KEYS:
            raise DiagramError(f"plots[{k}]: unknown key '{key}' (keys: {', '.join(KEYS)})",
                               file=file, line=_key_line(p, key, line))
    kind = p.get("kind", "time")
    if kind not in KINDS:
        raise DiagramError(f"plots[{k}]: unknown kind '{kind}' (kinds: {', '.join(KINDS)})",
                           file=file, line=line)
    return kind


def _check_plot_values(p, k, file, line):
    """The optional values of entry ``k``: ``t_min``, ``t_max`` [s] and ``f_max`` [Hz]
    finite numbers, ``peaks`` an integer 0..20, ``title`` and ``ylabel`` texts,
    ``one_panel`` true or false (the text ``"no"`` would count as true)."""
    _check_plot_numbers(p, k, file, line)
    _check_plot_texts(p, k, file, line)
    if "one_panel" in p and not isinstance(p["one_panel"], bool):
        raise DiagramError(f"plots[{k}]: 'one_panel' must be true or false, got "
                           f"{_kind_of(p['one_panel'])}", file=file,
                           line=_key_line(p, "one_panel", line))


def _check_plot_numbers(p, k, file, line):
    """``t_min``, ``t_max`` [s], ``f_max`` [Hz]: finite numbers; ``peaks``: 0..20."""
    for key in ("t_min", "t_max", "f_max"):
        v = p.get(key)
        if key in p and (isinstance(v, bool) or not isinstance(v, (int, float))
                         or not math.isfinite(v)):
            raise DiagramError(f"plots[{k}]: '{key}' must be a finite number of seconds"
                               f"{' (Hz)' if key == 'f_max' else ''}, got {v!r}",
                               file=file, line=_key_line(p, key, line))
    if "f_max" in p and not p["f_max"] > 0:
        raise DiagramError(f"plots[{k}]: 'f_max' must be a frequency > 0 Hz, got "
                           f"{p['f_max']!r}", file=file, line=_key_line(p, "f_max", line))
    if "t_min" in p and "t_max" in p and not p["t_min"] < p["t_max"]:
        raise DiagramError(f"plots[{k}]: 't_min' ({p['t_min']!r} s) must be before 't_max' "
                           f"({p['t_max']!r} s)", file=file, line=_key_line(p, "t_max", line))
    _check_peaks(p, k, file, line)


def _check_peaks(p, k, file, line):
    """``peaks``: how many spectrum peaks to label, an integer 0..20."""
    if "peaks" in p and (isinstance(p["peaks"], bool) or not isinstance(p["peaks"], int)
                         or not 0 <= p["peaks"] <= 20):
        raise DiagramError(f"plots[{k}]: 'peaks' must be an integer 0..20, got "
                           f"{p['peaks']!r}", file=file, line=_key_line(p, "peaks", line))


def _check_plot_texts(p, k, file, line):
    """``title`` and ``ylabel``: texts (a number is accepted as its text; a boolean, YAML's
    yes/no/true/false, is not)."""
    for key in ("title", "ylabel"):
        if key in p and (isinstance(p[key], bool) or not isinstance(p[key], (str, int, float))):
            raise DiagramError(f"plots[{k}]: '{key}' must be a text, got "
                               f"{_kind_of(p[key])}", file=file, line=_key_line(p, key, line))
        problem = math_text_problem(str(p.get(key, "")))
        if problem:
            raise DiagramError(f"plots[{k}]: '{key}' holds math text ($...$) that matplotlib "
                               f"cannot draw: {problem}; write a literal dollar as \\$",
                               file=file, line=_key_line(p, key, line))


def math_text_problem(text):
    """What matplotlib's math-text parser says about ``text`` (None when it draws it, or
    when it is not math text: no pair of unescaped ``$``). Checked before the run, so that a
    title cannot fail the plots after the data is written."""
    if "$" not in text:
        return None
    from matplotlib import cbook, mathtext
    if not cbook.is_math_text(text):
        return None
    try:
        mathtext.MathTextParser("path").parse(text)
    except (ValueError, RuntimeError) as exc:
        return " ".join(str(exc).split())[:200] or type(exc).__name__
    return None


def _logged_size(signals, name):
    """Number of values of logged signal ``name`` when ``signals`` maps names to sizes,
    else None."""
    return signals.get(name) if hasattr(signals, "get") else None


def _check_plot_signal(s, k, signals, file, line):
    """Plot signal ``s`` (``name`` or ``name[i]``) is logged, and ``i`` within its size
    when the size is known; an unknown name suggests the nearest logged ones."""
    name, idx = split_signal(s)
    if name not in signals:
        import difflib
        near = difflib.get_close_matches(name, list(signals), n=3)
        hint = f"; did you mean {', '.join(near)}?" if near else ""
        raise DiagramError(f"plots[{k}]: signal '{s}' is not logged{hint}", file=file,
                           line=line)
    size = _logged_size(signals, name)
    if idx is not None and size is not None and idx >= size:
        raise DiagramError(f"plots[{k}]: '{s}': index {idx} out of range, "
                           f"'{name}' has {size} element(s)", file=file, line=line)


def check_plot_entry(p, k, signals, file=None, line=None):
    """Validate plot entry ``p`` (number ``k``, at ``line``) against the logged
    ``signals`` (see :func:`check_plot_specs`); raise DiagramError."""
    kind = _check_plot_keys(p, k, file, line)
    if "file" in p:
        check_plot_file(p["file"], kind, f"plots[{k}]", file, _key_line(p, "file", line))
    _check_plot_values(p, k, file, line)
    sigs = p.get("signals")
    if not isinstance(sigs, list) or not sigs:
        raise DiagramError(f"plots[{k}] needs a non-empty list 'signals'", file=file,
                           line=line)
    for s in sigs:
        _check_plot_signal(s, k, signals, file, line)
    if kind == "animation":
        from .animation import check_animation_spec
        check_animation_spec(p, _logged_size(signals, sigs[0]), f"plots[{k}]", file, line)


def check_plot_specs(plots, signals, file=None, lines=None):
    """Validate plot entries against the logged ``signals``; raise DiagramError.

    ``signals`` holds the names of the logged signals, or maps them to their number of
    values (then an animation's signal is also checked against the arm's number of joints).
    ``lines`` gives the line of each entry (default: the YAML reader's, when it has them).
    """
    entry_lines = lines if lines is not None else getattr(plots, "lines", None)
    for k, p in enumerate(plots):
        check_plot_entry(p, k, signals, file, _entry_line(p, k, entry_lines))


def time_plot(result, spec, path):
    """Draw one time plot into ``path`` (PNG)."""
    sigs = spec["signals"]
    units = []
    for s in sigs:
        u = result.units.get(split_signal(s)[0], "1")
        if u not in units:
            units.append(u)
    if spec.get("one_panel"):
        units = [", ".join(units)]
    plt = _pyplot()
    fig, axes = plt.subplots(len(units), 1, sharex=True, squeeze=False,
                             figsize=(8, 2.2 + 2.0 * len(units)))
    t = result.t
    mask = (t >= spec.get("t_min", -float("inf"))) & (t <= spec.get("t_max", float("inf")))
    for ax, unit in zip(axes[:, 0], units):
        for s in sigs:
            if result.units.get(split_signal(s)[0], "1") != unit and len(units) > 1:
                continue
            y = signal_values(result, s)
            if y.ndim == 1:
                ax.plot(t[mask], y[mask], label=s)
            else:
                for i in range(y.shape[1]):
                    ax.plot(t[mask], y[mask, i], label=f"{s}[{i}]")
        ax.set_ylabel(spec.get("ylabel", "value") + f" [{unit}]")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize="small")
    axes[-1, 0].set_xlabel("time [s]")
    axes[0, 0].set_title(spec.get("title", ", ".join(sigs)))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def amplitude_spectrum(t, y, t_min=None, t_max=None):
    """``(f [Hz], amplitude)`` of ``y(t)`` over the window (see the module docstring)."""
    t = np.asarray(t)
    y = np.asarray(y, dtype=float)
    lo = t[0] if t_min is None else t_min
    hi = t[-1] if t_max is None else t_max
    sel = (t >= lo) & (t <= hi)
    if sel.sum() < 8:               # window outside a (short) run: use what there is
        sel = np.ones_like(t, bool)
    ts, ys = t[sel], y[sel]
    if len(ts) < 2:
        return np.zeros(1), np.zeros(1)
    # uniform grid at the median spacing of the samples in the window
    dt = float(np.median(np.diff(ts)))
    n = int(round((ts[-1] - ts[0]) / dt)) + 1
    grid = ts[0] + dt * np.arange(n)
    # drop duplicate times (two samples at an event instant): keep the later one
    keep = np.append(np.diff(ts) > 0, True)
    yu = np.interp(grid, ts[keep], ys[keep])
    yu = yu - yu.mean()
    w = np.hanning(n)
    amp = 2.0 * np.abs(np.fft.rfft(yu * w)) / w.sum()
    return np.fft.rfftfreq(n, dt), amp


def _label_peaks(ax, peaks, min_rel=0.05):
    """Label peaks in Hz, largest first, in the colour of their trace; a peak below
    ``min_rel`` of the largest, or whose label would sit within 6 % of the axis width and
    8 % of its height of a label already placed, is left unlabelled (legible, not crowded)."""
    if not peaks:
        return
    peaks = sorted(peaks, reverse=True)
    top = peaks[0][0]
    x0, x1 = ax.get_xlim()
    placed = []
    for amp, fk, x, colour in peaks:
        if amp < min_rel * top:
            break
        if any(abs(x - px) < 0.06 * (x1 - x0) and abs(amp - pa) < 0.08 * top
               for px, pa in placed):
            continue
        placed.append((x, amp))
        ax.annotate(f"{fk:.1f} Hz", (x, amp), textcoords="offset points", xytext=(4, 4),
                    fontsize="small", color=colour)


def spectrum_plot(result, spec, path):
    """Draw the amplitude spectra of the plot's signals, peaks labelled in Hz."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 4.5))
    f_max = spec.get("f_max")
    n_peaks = int(spec.get("peaks", 3))
    traces = []
    for s in spec["signals"]:
        y = signal_values(result, s)
        if y.ndim == 1:
            traces.append((s, y))
        else:
            traces += [(f"{s}[{i}]", y[:, i]) for i in range(y.shape[1])]
    peaks = []            # (amplitude, frequency, x, colour) of every trace's local maxima
    for label, y in traces:
        f, a = amplitude_spectrum(result.t, y, spec.get("t_min"), spec.get("t_max"))
        sel = f <= f_max if f_max else np.ones_like(f, bool)
        f, a = f[sel], a[sel]
        line, = ax.plot(f, a, label=f"{label} [{result.units.get(label.split('[')[0], '1')}]")
        if n_peaks and len(a) > 3:
            loc = np.flatnonzero((a[1:-1] > a[:-2]) & (a[1:-1] >= a[2:])) + 1
            loc = loc[np.argsort(a[loc])[::-1][:n_peaks]]
            df = f[1] - f[0]
            for k in loc:
                # parabolic interpolation of the peak between bins
                al, be, ga = a[k - 1], a[k], a[k + 1]
                den = al - 2 * be + ga
                fk = f[k] + (0.5 * (al - ga) / den * df if den != 0 else 0.0)
                peaks.append((a[k], fk, f[k], line.get_color()))
    _label_peaks(ax, peaks)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("amplitude")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize="small")
    window = f"{spec.get('t_min', result.t[0]):g}-{spec.get('t_max', result.t[-1]):g} s"
    ax.set_title(f"{spec.get('title', 'Spectrum')} (Hann window, {window})")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def make_plots(result, plots, folder):
    """Draw every plot of ``plots`` into ``folder``; return the written paths."""
    os.makedirs(folder, exist_ok=True)
    written = []
    used = set()
    for k, spec in enumerate(plots):
        kind = spec.get("kind", "time")
        ext = ".gif" if kind == "animation" else ".png"
        name = spec.get("file") or _slug(spec.get("title", f"plot_{k + 1}")) + ext
        # the CLI checked the entries already; checked again for direct callers: a name
        # from a diagram never leaves ``folder``
        check_plot_file(name, kind, f"plots[{k}]")
        while name in used:
            root, ext = os.path.splitext(name)
            name = f"{root}_{k + 1}{ext}"
        used.add(name)
        if kind == "animation":
            from .animation import arm_animation as draw
        else:
            draw = spectrum_plot if kind == "spectrum" else time_plot
        # drawn under a temporary name (same extension: it picks the format), then renamed
        final = os.path.join(folder, name)
        with atomic_path(final) as tmp:
            draw(result, spec, tmp)
        written.append(final)
    return written
