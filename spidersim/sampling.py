"""Uniform samples of a recorded window, for the analyses that need them (the microgravity
band levels, the amplitude spectra of ``kind: spectrum`` plots).

A discrete Fourier transform assumes samples ``y(t0 + j dt)``. A run with
``simulation.output_interval`` records exactly that (the dense output of every step at the
grid's points); a run without it records one row per solver step, whose spacing follows the
error control (in a smooth stretch steps of 0.2 s beside a 20 Hz tone that the step size
never saw). Interpolating such rows onto a grid invents the samples in between: a tone
faster than the steps is lost or aliased, and the levels computed from it can be wrong by
orders of magnitude. So a record that is not uniform is refused unless the caller asks for
the interpolation (``resample=True``: right only where the rows are dense compared with the
signal's content, e.g. a measured record with jitter).
"""
from __future__ import annotations

import numpy as np

#: steps equal to within this fraction of the step count as one grid (the grid's times are
#: ``t0 + k dt`` in floating point: 1e-12 relative at most)
GRID_TOL = 1e-6


class NonUniformRecord(ValueError):
    """The samples of a window are not on a uniform time grid."""


def uniform_window(t, y, t0=None, t1=None, resample=False):
    """``(dt, samples)`` of ``y(t)`` on a uniform grid over ``[t0, t1]`` [s].

    The recorded points inside the window are used as they are when their steps agree to
    :data:`GRID_TOL`; a last step shorter than the others (a run stopped, or ended, between
    two grid points) is dropped with its sample; of two rows at the same time (an event
    instant) the later one is kept. Otherwise, with ``resample=True``, the samples are
    interpolated linearly onto a grid of the median recorded step; without it
    :class:`NonUniformRecord` is raised, naming ``simulation.output_interval``.

    Parameters
    ----------
    t : (n,) array
        Times [s], non-decreasing.
    y : (n,) or (n, k) array
        Values, one row per time.
    t0, t1 : float, optional
        The window [s] (default: the whole record).
    resample : bool
        Interpolate a non-uniform record instead of refusing it.
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    t0 = t[0] if t0 is None else t0
    t1 = t[-1] if t1 is None else t1
    sel = (t >= t0) & (t <= t1)
    ts, ys = t[sel], y[sel]
    keep = np.append(np.diff(ts) > 0, True)          # of equal times, the later row
    ts, ys = ts[keep], ys[keep]
    if ts.size < 2:
        raise ValueError(f"the window {t0:g}..{t1:g} s holds fewer than two samples")
    steps = np.diff(ts)
    dt = float(np.median(steps))
    if np.all(np.abs(steps - dt) <= GRID_TOL * dt):
        return dt, ys
    if steps.size >= 2 and np.all(np.abs(steps[:-1] - dt) <= GRID_TOL * dt) \
            and steps[-1] < dt:
        return dt, ys[:-1]                         # ended between two grid points
    if not resample:
        raise NonUniformRecord(
            f"the record is not on a uniform time grid over {t0:g}..{t1:g} s (steps from "
            f"{steps.min():.3g} to {steps.max():.3g} s: the solver's own steps); spectra "
            f"and band levels need uniform samples: record on a grid with "
            f"simulation.output_interval")
    n = int(np.floor((ts[-1] - ts[0]) / dt * (1 + 1e-12))) + 1
    grid = ts[0] + dt * np.arange(n)
    if ys.ndim == 2:
        return dt, np.column_stack([np.interp(grid, ts, ys[:, k])
                                    for k in range(ys.shape[1])])
    return dt, np.interp(grid, ts, ys)
