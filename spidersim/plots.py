"""PNG plots of results, as listed in a diagram's ``plots`` section.

A plot entry::

    - title: Speed            # also names the file (speed.png) unless ``file`` is given
      signals: [motor.w, ref.y]
      kind: time              # the default; time series with units on the axis labels
      file: speed.png
      t_min: 0.0              # optional time window
      t_max: 1.0

Signals with different units go to separate panels sharing the time axis.
"""
from __future__ import annotations

import os
import re

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from .errors import DiagramError  # noqa: E402

KINDS = ("time",)
KEYS = ("title", "signals", "kind", "file", "t_min", "t_max", "ylabel")


def _slug(text):
    return re.sub(r"[^A-Za-z0-9]+", "_", text).strip("_").lower() or "plot"


def check_plot_specs(plots, signals, file=None):
    """Validate plot entries against the logged ``signals``; raise DiagramError."""
    for k, p in enumerate(plots):
        line = getattr(p, "line", None)
        if not isinstance(p, dict):
            raise DiagramError(f"plots[{k}] must be a mapping with 'signals'", file=file,
                               line=line)
        for key in p:
            if key not in KEYS:
                raise DiagramError(f"plots[{k}]: unknown key '{key}' (keys: {', '.join(KEYS)})",
                                   file=file, line=p.line_of(key) if hasattr(p, "line_of")
                                   else line)
        kind = p.get("kind", "time")
        if kind not in KINDS:
            raise DiagramError(f"plots[{k}]: unknown kind '{kind}' (kinds: {', '.join(KINDS)})",
                               file=file, line=line)
        sigs = p.get("signals")
        if not isinstance(sigs, list) or not sigs:
            raise DiagramError(f"plots[{k}] needs a non-empty list 'signals'", file=file,
                               line=line)
        for s in sigs:
            if s not in signals:
                import difflib
                near = difflib.get_close_matches(str(s), list(signals), n=3)
                hint = f"; did you mean {', '.join(near)}?" if near else ""
                raise DiagramError(f"plots[{k}]: signal '{s}' is not logged{hint}", file=file,
                                   line=line)


def time_plot(result, spec, path):
    """Draw one time plot into ``path`` (PNG)."""
    sigs = spec["signals"]
    units = []
    for s in sigs:
        u = result.units.get(s, "1")
        if u not in units:
            units.append(u)
    fig, axes = plt.subplots(len(units), 1, sharex=True, squeeze=False,
                             figsize=(8, 2.2 + 2.0 * len(units)))
    t = result.t
    mask = (t >= spec.get("t_min", -float("inf"))) & (t <= spec.get("t_max", float("inf")))
    for ax, unit in zip(axes[:, 0], units):
        for s in sigs:
            if result.units.get(s, "1") != unit:
                continue
            y = result[s]
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


def make_plots(result, plots, folder):
    """Draw every plot of ``plots`` into ``folder``; return the written paths."""
    os.makedirs(folder, exist_ok=True)
    written = []
    used = set()
    for k, spec in enumerate(plots):
        name = spec.get("file") or _slug(spec.get("title", f"plot_{k + 1}")) + ".png"
        while name in used:
            name = name.replace(".png", f"_{k + 1}.png")
        used.add(name)
        written.append(time_plot(result, spec, os.path.join(folder, name)))
    return written
