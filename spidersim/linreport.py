"""Linearization reports for the CLI: figures per SISO pair, Bode plot, matrices on disk."""
from __future__ import annotations

import json
import math
import os
import re

import numpy as np

from .errors import DiagramError
from .outputs import save_figure, write_atomic

ANALYSIS_KEYS = ("inputs", "outputs", "open", "at", "loop")
_ANALYSIS_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_-]{0,63}\Z")


def analysis_request(d, name):
    """``(inputs, outputs, open, at, loop)`` of the named entry of the ``analysis`` section."""
    section = d.spec.analysis
    if name not in section:
        import difflib
        near = difflib.get_close_matches(name, list(section), n=3)
        hint = f"; did you mean {', '.join(near)}?" if near else ""
        raise DiagramError(f"no analysis named '{name}'{hint} (analyses: "
                           f"{', '.join(section) or 'none'})", file=d.file)
    entry = section[name]
    line = getattr(d.spec.data.get("analysis"), "line_of", lambda k: None)(name)
    if not isinstance(name, str) or not _ANALYSIS_NAME.match(name):
        raise DiagramError(f"analysis {name!r}: an analysis name is an identifier (letters, "
                           f"digits, _ and -; it names a folder and titles the plots), e.g. "
                           f"current_loop", file=d.file, line=line)
    if not isinstance(entry, dict):
        raise DiagramError(f"analysis '{name}' must be a mapping with inputs/outputs or loop",
                           file=d.file, line=line)
    for k in entry:
        if k not in ANALYSIS_KEYS:
            raise DiagramError(f"analysis '{name}': unknown key '{k}' (keys: "
                               f"{', '.join(ANALYSIS_KEYS)})", file=d.file, line=line)

    def names(key):
        v = entry.get(key, [])
        v = [v] if isinstance(v, str) else v
        if not isinstance(v, list) or not all(isinstance(s, str) for s in v):
            raise DiagramError(f"analysis '{name}': '{key}' must be a list of signal names",
                               file=d.file, line=line)
        return list(v)

    loop = entry.get("loop")
    return names("inputs"), names("outputs"), names("open"), entry.get("at"), loop


def parse_at(text):
    """CLI ``--at``: a time, 'initial' or 'trim'."""
    if text is None or text == "initial":
        return None
    if text == "trim":
        return {"trim": {}}
    try:
        return float(text)
    except ValueError:
        raise DiagramError(f"--at expects a time [s], 'initial' or 'trim', got '{text}'")


#: a pole faster than this [rad/s] marks a badly scaled model (a parameter many orders of
#: magnitude off: ``motor.J = 1e-30`` put a pole at 5.5e62 rad/s and read "DC gain inf")
FAST_POLE = 1e12


def check_scaling(sys):
    """Refuse a linear model with non-finite matrices (an overflow in the linearization:
    the figures would be NaN) and warn (:class:`~spidersim.errors.LinearizationWarning`,
    printed as a note) when a pole is faster than :data:`FAST_POLE`: the frequency
    response and margins of such a model are not computed to any useful accuracy."""
    import warnings

    import control

    from .errors import LinearizationWarning, SpidersimError
    mats = [np.asarray(m, dtype=float) for m in (sys.A, sys.B, sys.C, sys.D)]
    if not all(np.isfinite(m).all() for m in mats):
        raise SpidersimError("the linear model has non-finite entries (an overflow: a "
                             "parameter many orders of magnitude off, such as a tiny "
                             "inertia or inductance, or an operating point far outside "
                             "the model's range)")
    if sys.nstates:
        fast = max(abs(p) for p in control.poles(sys))
        if not np.isfinite(fast) or fast > FAST_POLE:
            warnings.warn(LinearizationWarning(
                f"a pole at {fast:.3g} rad/s: the model is badly scaled (a parameter many "
                f"orders of magnitude off?); the frequency-domain figures below are not "
                f"reliable"))


def report(sys, title="", loop=False):
    """Text: poles of the whole model, then the figures of each input/output pair (margins
    and stability notes only when ``sys`` is a loop transfer)."""
    import control

    from .solver.linearize import format_figures, loop_notes, peak_gain, siso_figures

    lines = [f"linear model{(' ' + title) if title else ''}: {sys.nstates} states, "
             f"{sys.ninputs} inputs, {sys.noutputs} outputs"]
    check_scaling(sys)
    poles = control.poles(sys) if sys.nstates else []
    lines.append("  poles [rad/s]: " + (", ".join(
        f"{p.real:.6g}{p.imag:+.6g}j" if abs(p.imag) > 1e-12 * max(1, abs(p)) else
        f"{p.real:.6g}" for p in sorted(poles, key=lambda z: (z.real, z.imag))) or "none"))
    for j, u in enumerate(sys.input_labels):
        for i, y in enumerate(sys.output_labels):
            sub = control.ss(sys.A, sys.B[:, [j]], sys.C[[i], :], sys.D[[i], [j]])
            with np.errstate(all="ignore"):    # overflows of a badly scaled model: NaN
                fig = siso_figures(sub)
                if loop:
                    fig["notes"] = loop_notes(sub)
                else:
                    fig["peak"] = peak_gain(sub)
            lines.append(format_figures(fig, f"{u} -> {y}:", loop=loop))
    return "\n".join(lines)


def bode_png(sys, path, title=""):
    """Magnitude and phase of every input/output pair."""
    import control
    import matplotlib.pyplot as plt

    poles = [abs(p) for p in control.poles(sys) if abs(p) > 0] if sys.nstates else []
    lo = min(poles + [1.0]) / 100
    hi = max(poles + [1.0]) * 100
    w = np.logspace(np.log10(lo), np.log10(hi), 600)
    fig, (am, ap) = plt.subplots(2, 1, sharex=True, figsize=(8, 6))
    resp = sys(1j * w)
    resp = np.asarray(resp).reshape(sys.noutputs, sys.ninputs, len(w))
    for j, u in enumerate(sys.input_labels):
        for i, y in enumerate(sys.output_labels):
            g = resp[i, j]
            with np.errstate(divide="ignore"):
                am.semilogx(w / (2 * math.pi), 20 * np.log10(np.abs(g)), label=f"{u} -> {y}")
            ph = np.degrees(np.unwrap(np.angle(g)))
            # the usual range: shift by whole turns so that the low-frequency phase lies
            # in (-360, 0]
            ph -= 360.0 * np.ceil(ph[0] / 360.0)
            ap.semilogx(w / (2 * math.pi), ph)
    am.set_ylabel("magnitude [dB]")
    ap.set_ylabel("phase [deg]")
    ap.set_xlabel("frequency [Hz]")
    top = am.secondary_xaxis("top", functions=(lambda f: 2 * math.pi * f,
                                               lambda w_: w_ / (2 * math.pi)))
    top.set_xlabel("frequency [rad/s]")
    for a in (am, ap):
        a.grid(True, which="both", alpha=0.3)
    am.legend(fontsize="small")
    am.set_title(f"Bode: {title}" if title else "Bode")
    fig.tight_layout()
    return save_figure(fig, path)


def save_matrices(sys, folder, stem="linearization"):
    """``stem.npz`` and ``stem.json`` with A, B, C, D and the state/input/output names."""
    os.makedirs(folder, exist_ok=True)
    names = {"states": list(sys.state_labels), "inputs": list(sys.input_labels),
             "outputs": list(sys.output_labels)}
    write_atomic(os.path.join(folder, stem + ".npz"), lambda fh: np.savez(
        fh, A=sys.A, B=sys.B, C=sys.C, D=sys.D, **{k: np.array(v) for k, v in names.items()}),
        binary=True)
    write_atomic(os.path.join(folder, stem + ".json"), lambda fh: json.dump(
        dict(names, A=sys.A.tolist(), B=sys.B.tolist(), C=sys.C.tolist(),
             D=sys.D.tolist()), fh, indent=1))
    return folder
