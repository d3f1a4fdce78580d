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
samples must lie on a uniform grid (the run's ``simulation.output_interval``; a record of the
solver's own steps is refused, see :mod:`spidersim.sampling`), the mean is removed, a
periodic Hann window ``w_j = (1 - cos(2 pi j / n)) / 2`` applied, and the FFT scaled by
``2 / sum(w) = 4 / n``, so that a sinusoid of amplitude A whose frequency falls on a bin
(``f = k / T``, ``T = n dt``) shows a peak of height A on the curve. Between two bins, at
``f = (k + d) / T`` with ``|d| <= 1/2``, the curve's highest bin shows
``A sinc(d) / (1 - d^2)`` (``sinc(d) = sin(pi d) / (pi d)``: the Hann window's scalloping
loss, at most 15.1 % low at ``d = 1/2``). The labelled peaks are corrected: see
:func:`hann_peak`, which recovers ``d`` from the ratio of the two highest bins and the
amplitude from the formula above, exactly for a lone tone, and checks the third bin against
the same shape: a peak that is not one tone's (a drifting line, lines a few bins apart) keeps
the curve's height, labelled ``~``. ``f_max`` limits the frequency axis; the ``peaks`` highest
local maxima are labelled ``f Hz: A unit`` with that frequency and amplitude, marked at that
height.

``kind: animation`` writes a GIF (default file ``<title>.gif``): a 3-D stick figure of an arm
from the joint angles of an Arm block; keys ``model``, ``frames``, ``fps``, ``trace`` (see
:mod:`spidersim.animation`).
"""
from __future__ import annotations

import math
import os
import re

import numpy as np

from .errors import ASCII_RULE, DiagramError, non_ascii
from .outputs import BARE_NAME, atomic_path

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


#: one element ``name[i]``, ``i`` in ASCII digits (``\d`` read ``[١]`` as 1), negative
#: from the end (``[-1]`` is the last)
_ELEM = re.compile(r"^(.*?)\[\s*(-?[0-9]+)\s*\]\Z")
#: a connection's element range (``[1:]``, ``[:2]``, ``[0:3]``), which a plot does not read
_RANGE = re.compile(r"^[^\[]*\[[^\[\]]*:[^\[\]]*\]\Z")


def split_signal(s):
    """``"arm.q[2]"`` -> ``("arm.q", 2)``; ``"arm.q[-1]"`` -> ``("arm.q", -1)`` (from the
    end, as in Python and in connections); ``"arm.q"`` -> ``("arm.q", None)``."""
    m = _ELEM.match(str(s).strip())
    if not m or len(m.group(2)) > 100:       # int() of thousands of digits fails
        return str(s).strip(), None
    return m.group(1).strip(), int(m.group(2))


def element_problem(name, idx, size):
    """Why element ``idx`` of signal ``name`` of ``size`` values does not exist (``index 7
    out of range, 'arm.q' has 7 element(s) (0..6, or -7..-1 from the end)``), or None."""
    if -size <= idx < size:
        return None
    return (f"index {idx} out of range, '{name}' has {size} element(s) (0..{size - 1}, or "
            f"-{size}..-1 from the end)")


def signal_values(result, s):
    """Samples of the plot entry ``s`` (a signal or one element ``name[i]``)."""
    name, idx = split_signal(s)
    y = result[name]
    if idx is None:
        return y
    return y if y.ndim == 1 else y[:, idx]


#: plot file names: a bare name inside the output folder, with a known extension
PLOT_EXTENSIONS = (".png", ".svg", ".pdf")


#: plot file names a run writes itself (the microgravity assessment's plot): a plot's
#: ``file`` may not take them; a plot whose title gives one is renamed (``_<k>``)
RESERVED_PLOT_FILES = ("microgravity.png",)


def _check_reserved_file(name, what, file=None, line=None):
    """A plot's ``file`` is not one of :data:`RESERVED_PLOT_FILES` (the assessment's plot
    overwrote it, and the run listed one file twice); raise DiagramError."""
    if isinstance(name, str) and name.lower() in RESERVED_PLOT_FILES:
        raise DiagramError(f"{what}: 'file' {name!r} is reserved for the microgravity "
                           f"assessment's plot; choose another name", file=file, line=line)


def check_plot_file(name, kind, what, file=None, line=None):
    """A plot's ``file:`` must be a bare file name (no folder, no ``..``) with an extension
    matplotlib writes (.png, .svg, .pdf; .gif for animations); raise DiagramError."""
    exts = (".gif",) if kind == "animation" else PLOT_EXTENSIONS
    if not isinstance(name, str) or not BARE_NAME.match(name) or ".." in name:
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
    """Plot signal ``s`` (``name`` or ``name[i]``, ``i`` negative from the end) is ASCII and
    logged, and ``i`` within its size when the size is known; an unknown name suggests the
    nearest logged ones."""
    problem = non_ascii(s)
    if problem:
        raise DiagramError(f"plots[{k}]: signal '{s}': {problem}: {ASCII_RULE}", file=file,
                           line=line)
    name, idx = split_signal(s)
    if name not in signals and _RANGE.match(str(s).strip()):
        base = str(s).partition("[")[0].strip()
        raise DiagramError(f"plots[{k}]: signal '{s}': a plot takes a whole signal "
                           f"('{base}') or one element ('{base}[0]'), not an element range: "
                           f"list the elements", file=file, line=line)
    if name not in signals:
        import difflib
        near = difflib.get_close_matches(name, list(signals), n=3)
        hint = f"; did you mean {', '.join(near)}?" if near else ""
        raise DiagramError(f"plots[{k}]: signal '{s}' is not logged{hint}", file=file,
                           line=line)
    size = _logged_size(signals, name)
    problem = element_problem(name, idx, size) if None not in (idx, size) else None
    if problem:
        raise DiagramError(f"plots[{k}]: '{s}': {problem}", file=file, line=line)


#: most lines (and legend entries) one time or spectrum plot draws: one per element of
#: each signal (a 2000-element vector drew 2000 lines and legend entries in 16 s)
MAX_PLOT_LINES = 64


def _line_count(sigs, sizes):
    """Lines a plot of ``sigs`` draws when ``sizes`` maps logged names to their number of
    values: one per element (``name[i]`` is one); names of unknown size count as one."""
    n = 0
    for s in sigs:
        name, idx = split_signal(s)
        n += 1 if idx is not None else int(_logged_size(sizes, name) or 1)
    return n


def check_line_count(sigs, sizes, what, file=None, line=None):
    """A time or spectrum plot of ``sigs`` draws at most :data:`MAX_PLOT_LINES` lines;
    raise DiagramError naming the count and the largest signal otherwise."""
    n = _line_count(sigs, sizes)
    if n <= MAX_PLOT_LINES:
        return
    big = max(sigs, key=lambda s: _line_count([s], sizes))
    raise DiagramError(f"{what}: the plot would draw {n} lines, one per element ('{big}' "
                       f"has {_line_count([big], sizes)}); at most {MAX_PLOT_LINES}: plot "
                       f"single elements ('{split_signal(big)[0]}[0]') or split the plot",
                       file=file, line=line)


def check_plot_entry(p, k, signals, file=None, line=None):
    """Validate plot entry ``p`` (number ``k``, at ``line``) against the logged
    ``signals`` (see :func:`check_plot_specs`); raise DiagramError."""
    kind = _check_plot_keys(p, k, file, line)
    if "file" in p:
        check_plot_file(p["file"], kind, f"plots[{k}]", file, _key_line(p, "file", line))
        _check_reserved_file(p["file"], f"plots[{k}]", file, _key_line(p, "file", line))
    _check_plot_values(p, k, file, line)
    sigs = p.get("signals")
    if not isinstance(sigs, list) or not sigs:
        raise DiagramError(f"plots[{k}] needs a non-empty list 'signals'", file=file,
                           line=line)
    for s in sigs:
        _check_plot_signal(s, k, signals, file, line)
    if kind != "animation":
        check_line_count(sigs, signals, f"plots[{k}]", file, line)
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


#: line styles of a time plot, in turn (colours: matplotlib's ten, C0..C9)
LINE_STYLES = ("-", "--", ":", "-.")


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
        vectors = 0
        for s in sigs:
            if result.units.get(split_signal(s)[0], "1") != unit and len(units) > 1:
                continue
            y = signal_values(result, s)
            if y.ndim == 1:
                n = len(ax.lines)         # ten colours, then the next line style
                ax.plot(t[mask], y[mask], label=s, color=f"C{n % 10}",
                        linestyle=LINE_STYLES[n // 10 % len(LINE_STYLES)])
            else:
                # element i in colour i, each vector in its own style: the commanded and
                # delivered torques of one joint share a colour (14 lines in one style
                # reused four colours, commanded and delivered alike)
                style = LINE_STYLES[vectors % len(LINE_STYLES)]
                vectors += 1
                for i in range(y.shape[1]):
                    ax.plot(t[mask], y[mask, i], label=f"{s}[{i}]", color=f"C{i % 10}",
                            linestyle=style)
        ax.set_ylabel(spec.get("ylabel", "value") + f" [{unit}]")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize="small", ncol=-(-len(ax.lines) // 16))
    axes[-1, 0].set_xlabel("time [s]")
    axes[0, 0].set_title(spec.get("title", ", ".join(sigs)))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


#: the fewest samples a spectrum window may hold (fewer give a handful of bins, not a
#: spectrum)
MIN_SPECTRUM_SAMPLES = 8


def _too_few_samples(lo, hi, n, dt=None):
    """The message for a spectrum window ``[lo, hi]`` holding ``n`` samples (every ``dt``)."""
    every = f" (one every {dt:g} s)" if dt else ""
    return (f"the spectrum window [{lo:g}, {hi:g}] s holds {n} sample(s){every}; a spectrum "
            f"needs at least {MIN_SPECTRUM_SAMPLES}: widen t_min..t_max or shorten "
            f"simulation.output_interval")


def spectrum_window_problem(t_min, t_max, t_end, dt):
    """The :func:`_too_few_samples` message when the window ``[t_min, t_max]`` (None: the
    run's start or end ``t_end``) of a run sampled every ``dt`` from 0 holds fewer than
    :data:`MIN_SPECTRUM_SAMPLES` samples; None when it holds enough."""
    lo = 0.0 if t_min is None else max(float(t_min), 0.0)
    hi = float(t_end) if t_max is None else min(float(t_max), float(t_end))
    n = max(math.floor(hi / dt + 1e-9) - math.ceil(lo / dt - 1e-9) + 1, 0)
    return _too_few_samples(lo, hi, n, dt) if n < MIN_SPECTRUM_SAMPLES else None


def amplitude_spectrum(t, y, t_min=None, t_max=None, resample=False):
    """``(f [Hz], amplitude)`` of ``y(t)`` over the window (see the module docstring).

    The samples in the window must be uniform (a last row off the grid is dropped); a record
    that is not raises :class:`~spidersim.sampling.NonUniformRecord` unless ``resample=True``
    (linear interpolation at the median step: right only for dense points). A window holding
    fewer than :data:`MIN_SPECTRUM_SAMPLES` samples raises ValueError naming the window and
    the count (it used to fall back to the whole record silently)."""
    from .sampling import uniform_window
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    lo = t[0] if t_min is None else t_min
    hi = t[-1] if t_max is None else t_max
    n = int(((t >= lo) & (t <= hi)).sum())
    if n < MIN_SPECTRUM_SAMPLES:
        raise ValueError(_too_few_samples(lo, hi, n))
    dt, yu = uniform_window(t, y, lo, hi, resample=resample)
    n = len(yu)
    yu = yu - yu.mean()
    w = 0.5 - 0.5 * np.cos(2 * np.pi * np.arange(n) / n)     # periodic Hann: sum(w) = n / 2
    amp = 2.0 * np.abs(np.fft.rfft(yu * w)) / w.sum()
    return np.fft.rfftfreq(n, dt), amp


#: a peak is taken for a lone tone when its smaller neighbour is within this of the height
#: the Hann shape predicts (ratios to the peak bin, which lie in 0.2..0.5 for one tone)
LONE_TONE_TOL = 0.05


def hann_peak(f, a, k):
    """``(frequency [Hz], amplitude, lone)`` of the tone behind the local maximum ``a[k]``
    of a Hann amplitude spectrum (:func:`amplitude_spectrum`).

    For a lone tone of amplitude ``A`` at ``(k + d) df``, ``|d| <= 1/2``, the periodic Hann
    window gives (bins ``m`` at distance ``x = m - k - d``, ``n`` large)

        a_m = A |sinc(x)| / |1 - x^2|,    sinc(x) = sin(pi x) / (pi x),

    so the ratio of the larger neighbour to the maximum is
    ``r = a_{k+1} / a_k = (1 + d) / (2 - d)`` (for ``d >= 0``; mirrored for ``d < 0``),
    whence ``|d| = (2 r - 1) / (1 + r)`` (``r = 1/2`` on a bin, ``1`` halfway) and
    ``A = a_k (1 - d^2) / sinc(d)``, at ``f_k + d df``. Exact for a lone tone up to
    ``O((pi d / n)^2)`` and the leakage of other lines.

    The smaller neighbour checks the shape: one tone puts it at ``(1 - d) / (2 + d)`` of the
    peak. When it is off by more than :data:`LONE_TONE_TOL` (a line that drifts over the
    window, several lines within a few bins, noise, a line within a few bins of 0 Hz) the
    peak is no lone tone and has no single amplitude: the curve's height ``a_k`` is returned
    with the parabolic interpolation of the frequency, and ``lone`` is False. At the ends of
    the array the bin itself is returned.
    """
    df = f[1] - f[0] if len(f) > 1 else 0.0
    if k <= 0 or k >= len(a) - 1 or a[k] <= 0:
        return float(f[k]), float(a[k]), False
    right = a[k + 1] >= a[k - 1]
    big, small = (a[k + 1], a[k - 1]) if right else (a[k - 1], a[k + 1])
    r = min(big / a[k], 1.0)
    d = min(max((2 * r - 1) / (1 + r), 0.0), 0.5)
    if abs(small / a[k] - (1 - d) / (2 + d)) <= LONE_TONE_TOL:
        amp = a[k] * (1 - d * d) / np.sinc(d)
        return float(f[k] + (d if right else -d) * df), float(amp), True
    den = a[k - 1] - 2 * a[k] + a[k + 1]
    fk = f[k] + (0.5 * (a[k - 1] - a[k + 1]) / den * df if den != 0 else 0.0)
    return float(fk), float(a[k]), False


def _label_peaks(ax, peaks, min_rel=0.05):
    """Label peaks ``f Hz: A unit`` at their corrected frequency and amplitude
    (:func:`hann_peak`), largest first, in the colour of their trace, with a marker there; a
    peak below ``min_rel`` of the largest, or whose label would sit within 6 % of the axis
    width and 8 % of its height of a label already placed, is left unlabelled (legible, not
    crowded)."""
    if not peaks:
        return
    peaks = sorted(peaks, reverse=True)
    top = peaks[0][0]
    x0, x1 = ax.get_xlim()
    placed = []
    for amp, fk, colour, unit, lone in peaks:
        if amp < min_rel * top:
            break
        if any(abs(fk - px) < 0.06 * (x1 - x0) and abs(amp - pa) < 0.08 * top
               for px, pa in placed):
            continue
        placed.append((fk, amp))
        ax.plot([fk], [amp], marker="v", ms=4, color=colour, ls="none")
        ax.annotate(peak_label(fk, amp, unit, lone), (fk, amp), textcoords="offset points",
                    xytext=(4, 4), fontsize="small", color=colour)


def peak_label(f, amp, unit, lone=True):
    """The label of a spectrum peak: ``'111.4 Hz: 0.0123 N.m'`` (unit ``1`` or unknown
    ``?``: none shown); a peak
    that is not a lone tone gets ``~`` before its height (the curve's, see
    :func:`hann_peak`)."""
    return (f"{f:.1f} Hz: {'' if lone else '~'}{amp:.3g}"
            + ("" if unit in ("1", "?", "", None) else f" {unit}"))


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
        try:
            f, a = amplitude_spectrum(result.t, y, spec.get("t_min"), spec.get("t_max"))
        except ValueError as exc:         # a run cut short (--t-end) before the window
            ax.text(0.5, 0.5, f"no spectrum: {exc}", ha="center", va="center", wrap=True,
                    transform=ax.transAxes)
            break
        sel = f <= f_max if f_max else np.ones_like(f, bool)
        f, a = f[sel], a[sel]
        unit = result.units.get(label.split('[')[0], '1')
        line, = ax.plot(f, a, label=f"{label} [{unit}]")
        if n_peaks and len(a) > 3:
            loc = np.flatnonzero((a[1:-1] > a[:-2]) & (a[1:-1] >= a[2:])) + 1
            loc = loc[np.argsort(a[loc])[::-1][:n_peaks]]
            for k in loc:
                fk, ak, lone = hann_peak(f, a, k)    # corrected between bins
                peaks.append((ak, fk, line.get_color(), unit, lone))
    _label_peaks(ax, peaks)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("amplitude")
    ax.grid(True, alpha=0.3)
    if ax.lines:
        ax.legend(fontsize="small")
    window = f"{spec.get('t_min', result.t[0]):g}-{spec.get('t_max', result.t[-1]):g} s"
    ax.set_title(f"{spec.get('title', 'Spectrum')} (Hann window, {window})")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _values(result, name):
    """Number of values of logged signal ``name`` of ``result`` (per time)."""
    y = result[name]
    return 1 if np.ndim(y) == 1 else int(np.shape(y)[1])


def make_plots(result, plots, folder):
    """Draw every plot of ``plots`` into ``folder``; return the written paths."""
    os.makedirs(folder, exist_ok=True)
    written = []
    used = set(RESERVED_PLOT_FILES)     # a title 'Microgravity' is renamed microgravity_<k>
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
            names = {split_signal(n)[0] for n in spec["signals"]}
            check_line_count(spec["signals"], {n: _values(result, n) for n in names
                                               if n in result}, f"plots[{k}]")
        # drawn under a temporary name (same extension: it picks the format), then renamed
        final = os.path.join(folder, name)
        with atomic_path(final) as tmp:
            draw(result, spec, tmp)
        written.append(final)
    return written
