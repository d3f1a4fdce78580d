"""3-D stick-figure animation of an arm from a result, written as a GIF.

A plot entry of ``kind: animation``::

    - title: Arm motion       # also names the file (arm_motion.gif) unless ``file`` is given
      kind: animation
      signals: [arm.q]        # exactly one signal: the joint angles of an Arm block
      model: spider           # the Arm's ``model`` ('spider' or an arm data file)
      frames: 60              # number of frames, evenly spaced over [t_min, t_max]
      fps: 15                 # frames per second of the GIF
      t_min: 0.0              # optional time window
      t_max: 1.0
      trace: true             # draw the flange path travelled so far

Each frame is the stick figure :meth:`spidersim.multibody.chain.Chain.frames` of the joint
angles interpolated at the frame time: the joint origins joined by lines. The axes have an
equal aspect and fixed limits covering the whole motion, the title shows the time. The GIF
is written by matplotlib's ``PillowWriter`` (Pillow comes with matplotlib).
"""
from __future__ import annotations

import math
import os

import matplotlib.pyplot as plt  # the CLI selects Agg; notebooks keep their backend
import numpy as np
from matplotlib.animation import FuncAnimation, PillowWriter

from .errors import DiagramError

_CHAINS = {}


def _chain(model):
    """The (cached) :class:`Chain` of an Arm ``model`` ('spider' or a data file path)."""
    from .multibody.chain import Chain
    if not isinstance(model, str) or not model:
        raise DiagramError(f"model must be 'spider' or the path of an arm data file, "
                           f"got {model!r}")
    key = None if model == "spider" else model
    if key not in _CHAINS:
        if key is not None and not os.path.isfile(key):
            raise DiagramError(f"arm data file not found: {model} (use 'spider' for the "
                               f"shipped SPIDER-like arm)")
        _CHAINS[key] = Chain.from_yaml(key)
    return _CHAINS[key]


#: most frames of one animation (each is drawn: 10**30 frames would never finish)
MAX_FRAMES = 10000
#: highest frame rate [1/s] of an animation (inf or nan is no rate)
MAX_FPS = 100


def check_animation_spec(spec, size=None, where="animation", file=None, line=None):
    """Validate an animation entry; raise :class:`DiagramError` on the first problem.

    Parameters
    ----------
    spec : dict
        The plot entry (keys as in the module docstring).
    size : int, optional
        Number of values of the named signal, when known; it must equal the arm's number of
        joints.
    where : str
        Prefix of the messages (``plots[3]``).
    file, line : optional
        YAML location attached to the error.

    Returns
    -------
    Chain
        The arm the animation draws.
    """
    def fail(msg):
        raise DiagramError(f"{where}: {msg}", file=file, line=line)

    sigs = spec.get("signals")
    if not isinstance(sigs, list) or len(sigs) != 1:
        n = len(sigs) if isinstance(sigs, list) else 0
        fail(f"an animation needs exactly one signal, the joint angles of an Arm block "
             f"(signals: [arm.q]), got {n}")
    try:
        chain = _chain(spec.get("model", "spider"))
    except DiagramError as exc:
        fail(exc.message)
    if size is not None and size != chain.n:
        fail(f"signal '{sigs[0]}' has {size} value{'s' if size != 1 else ''} but the arm "
             f"'{spec.get('model', 'spider')}' has {chain.n} joints; name the joint angles "
             f"of an Arm block (e.g. arm.q)")
    frames = spec.get("frames", 60)
    if (isinstance(frames, bool) or not isinstance(frames, int)
            or not 1 <= frames <= MAX_FRAMES):
        fail(f"frames must be an integer 1..{MAX_FRAMES}, got {frames!r:.40}")
    fps = spec.get("fps", 15)
    if (isinstance(fps, bool) or not isinstance(fps, (int, float))
            or not 0 < fps <= MAX_FPS):
        fail(f"fps must be a number > 0 and <= {MAX_FPS}, got {fps!r:.40}")
    if not isinstance(spec.get("trace", False), bool):
        fail(f"trace must be true or false, got {spec.get('trace')!r}")
    lo, hi = spec.get("t_min"), spec.get("t_max")
    if lo is not None and hi is not None and not lo < hi:
        fail(f"t_min ({lo}) must be less than t_max ({hi})")
    name = spec.get("file")
    if name is not None and not str(name).lower().endswith(".gif"):
        fail(f"an animation is written as a GIF: file must end in .gif, got '{name}'")
    return chain


def _interp(t, y, times):
    """Linear interpolation of the rows of ``y(t)`` at ``times`` (the later of two samples
    at one instant, as after an event, wins)."""
    keep = np.append(np.diff(t) > 0, True)
    t, y = t[keep], y[keep]
    return np.column_stack([np.interp(times, t, y[:, i]) for i in range(y.shape[1])])


def arm_animation(result, spec, path):
    """Write a 3-D stick-figure animation of an arm to ``path`` (GIF).

    Parameters
    ----------
    result : Result
        A run that logged the joint angles of an Arm block.
    spec : dict
        The plot entry: ``signals`` (one signal, the joint angles, e.g. ``[arm.q]``),
        optional ``model`` (the Arm's model, default ``'spider'``), ``frames`` (default 60),
        ``fps`` (default 15), ``t_min``, ``t_max``, ``trace`` (draw the flange path,
        default false) and ``title``.
    path : str
        Output file, ``.gif``.

    Returns
    -------
    str
        ``path``.

    Raises
    ------
    DiagramError
        The entry is invalid: not exactly one signal, a signal whose size is not the arm's
        number of joints, a bad ``frames``/``fps``/``model``, an empty time window.
    """
    sig = spec.get("signals")
    size = None
    if isinstance(sig, list) and len(sig) == 1:
        if sig[0] not in result:
            raise DiagramError(f"animation: signal '{sig[0]}' is not logged")
        y = result[sig[0]]
        size = 1 if y.ndim == 1 else y.shape[1]
    chain = check_animation_spec(spec, size)
    q = np.asarray(result[sig[0]], dtype=float).reshape(len(result.t), -1)
    t = np.asarray(result.t, dtype=float)
    lo = max(float(spec.get("t_min", t[0])), float(t[0]))
    hi = min(float(spec.get("t_max", t[-1])), float(t[-1]))
    if not lo <= hi:
        raise DiagramError(f"animation: the time window {spec.get('t_min')}..."
                           f"{spec.get('t_max')} s holds none of the run "
                           f"({t[0]:g}...{t[-1]:g} s)")
    n_frames = int(spec.get("frames", 60))
    times = np.linspace(lo, hi, n_frames)
    figs = np.array([chain.frames(qk) for qk in _interp(t, q, times)])   # frames x (n+1) x 3
    # the flange path, denser than the frames (samples in the window + the frame times)
    inside = t[(t >= lo) & (t <= hi)]
    if len(inside) > 2000:
        inside = inside[np.linspace(0, len(inside) - 1, 2000).astype(int)]
    t_path = np.union1d(inside, times)
    flange = np.array([chain.frames(qk)[-1] for qk in _interp(t, q, t_path)])

    pts = np.vstack([figs.reshape(-1, 3), flange])
    mid = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    half = 0.55 * max(float(np.ptp(pts, axis=0).max()), 1e-6)

    title = spec.get("title", f"{sig[0]} ({chain.name})")
    dt = (hi - lo) / max(n_frames - 1, 1)
    digits = max(2, int(math.ceil(-math.log10(dt))) + 1) if dt > 0 else 2

    fig = plt.figure(figsize=(6, 6))
    ax = fig.add_subplot(projection="3d")
    for setlim, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), mid):
        setlim(c - half, c + half)
    ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.scatter([0], [0], [0], marker="s", color="k", s=30)          # base
    (links,) = ax.plot([], [], [], "-o", color="tab:blue", lw=3, ms=4)
    (tip,) = ax.plot([], [], [], "o", color="tab:red", ms=6)
    trace = spec.get("trace", False)
    if trace:
        (path_line,) = ax.plot([], [], [], "-", color="tab:red", lw=1, alpha=0.7)
    head = ax.set_title("")

    def draw(k):
        p = figs[k]
        links.set_data_3d(p[:, 0], p[:, 1], p[:, 2])
        tip.set_data_3d(p[-1:, 0], p[-1:, 1], p[-1:, 2])
        if trace:
            f = np.vstack([flange[t_path <= times[k]], p[-1:]])
            path_line.set_data_3d(f[:, 0], f[:, 1], f[:, 2])
        head.set_text(f"{title}  t = {times[k]:.{digits}f} s")
        return ()

    anim = FuncAnimation(fig, draw, frames=n_frames, blit=False)
    try:
        anim.save(path, writer=PillowWriter(fps=spec.get("fps", 15)), dpi=80)
    finally:
        plt.close(fig)
    return path
