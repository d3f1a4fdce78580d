"""Variable-step integration through our own loop over SciPy's step-by-step solvers.

The run is cut into *segments* at the time events of the system (a step source switching,
a table corner, later sampled blocks): each segment is integrated by a fresh SciPy solver
object whose ``t_bound`` is the next event time, so no step straddles a discontinuity; at
the segment end the due events are applied and the solver restarts from the new state.

Output is recorded at every accepted step (``output_interval=None``) or on a uniform grid
through the solver's dense output. A failure (solver failure or a non-finite state) stops
the run and raises :class:`~spidersim.errors.IntegrationError` whose ``partial`` holds the
samples computed so far.
"""
from __future__ import annotations

import math
import time

import numpy as np
from scipy.integrate import BDF, DOP853, LSODA, RK23, RK45, Radau
from scipy.sparse import csr_matrix

from ..errors import AlgebraicLoopError, IntegrationError, SpidersimError
from .result import Result

METHODS = {"LSODA": LSODA, "RK45": RK45, "RK23": RK23, "DOP853": DOP853, "Radau": Radau,
           "BDF": BDF}
IMPLICIT = ("Radau", "BDF")
MAX_EVENTS_AT_ONE_TIME = 1000


class _Recorder:
    """Logged rows in a preallocated buffer that doubles when full."""

    def __init__(self, system, capacity=1024):
        self.system = system
        self.buf = np.zeros((capacity, system.record_size))
        self.tbuf = np.zeros(capacity)
        self.n = 0

    def add(self, t, x):
        """Record outputs at (t, x); return False if something is not finite."""
        if self.n == len(self.tbuf):
            self.buf = np.concatenate((self.buf, np.zeros_like(self.buf)))
            self.tbuf = np.concatenate((self.tbuf, np.zeros_like(self.tbuf)))
        ok = self.system.record_row(t, x, self.buf, self.n)
        self.tbuf[self.n] = t
        self.n += 1
        return ok

    @property
    def t(self):
        return self.tbuf[:self.n]

    def result(self, events, stats, status="ok", message=""):
        s = self.system
        return Result(self.t.copy(), self.buf[:self.n].copy(), s.record_slices, s.units,
                      events, stats, status, message)


def integrate(system, t_end, **kw):
    """Integrate ``system`` to ``t_end`` (see :func:`_integrate`), floating-point warnings
    silenced: non-finite values are detected and reported by name instead."""
    with np.errstate(all="ignore"):
        return _integrate(system, t_end, **kw)


def _integrate(system, t_end, t0=0.0, method="LSODA", rtol=1e-6, atol=1e-8, max_step=math.inf,
              first_step=None, output_interval=None, progress=None, stats=None):
    """Integrate ``system`` from ``t0`` to ``t_end``; return a :class:`Result`.

    Parameters
    ----------
    system : CompiledSystem
        See :mod:`spidersim.solver.system` for the contract.
    method : str
        ``LSODA`` (default), ``RK45``, ``RK23``, ``DOP853``, ``Radau`` or ``BDF``.
    rtol, atol, max_step, first_step : float
        Passed to the SciPy solver.
    output_interval : float, optional
        Record on a uniform grid of this spacing instead of at every step.
    progress : callable, optional
        ``progress(t)`` after every accepted step.
    stats : dict, optional
        Extra entries for ``Result.stats``.
    """
    if method not in METHODS:
        import difflib
        near = difflib.get_close_matches(str(method), METHODS, n=1)
        raise SpidersimError(f"unknown method '{method}'"
                             + (f" (did you mean {near[0]}?)" if near else "")
                             + f"; methods: {', '.join(METHODS)}")
    if not (t_end > t0):
        raise SpidersimError(f"t_end must be > {t0}, got {t_end}")
    for name, v in (("rtol", rtol), ("atol", atol), ("max_step", max_step)):
        if not (v > 0):
            raise SpidersimError(f"{name} must be > 0, got {v}")
    if output_interval is not None and not (0 < output_interval <= t_end - t0):
        raise SpidersimError(f"output_interval must be in (0, {t_end - t0}], "
                             f"got {output_interval}")
    wall0 = time.perf_counter()
    cls = METHODS[method]
    kw = dict(rtol=rtol, atol=atol, max_step=max_step)
    if first_step is not None:
        kw["first_step"] = first_step
    if method in IMPLICIT and system.jac_sparsity is not None and system.n_x > 1:
        kw["jac_sparsity"] = csr_matrix(system.jac_sparsity)
    st = dict(stats or {})
    st.update(method=method, rtol=rtol, atol=atol, max_step=max_step, t_end=t_end, steps=0,
              rhs_calls=0, jacobian_calls=0, lu_decompositions=0, segments=0, time_events=0)
    rec = _Recorder(system)
    events = []
    grid_k = 0

    def grid_time(k):
        return t0 + k * output_interval

    def fire_due(t, x):
        n = 0
        while system.next_time(t) <= t + 1e-12 * max(1.0, abs(t)):
            fired = system.time_events(t, x, 1e-12 * max(1.0, abs(t)))
            events.extend((t, name, "time") for name in fired)
            st["time_events"] += len(fired)
            n += 1
            if n > MAX_EVENTS_AT_ONE_TIME or not fired:
                raise IntegrationError(
                    f"time events keep firing at t = {t:.9g} s without time advancing "
                    f"(blocks: {', '.join(fired) or 'none'})",
                    partial=rec.result(events, st, "failed"))

    def fail(msg, t, x):
        st["t_reached"] = t
        st["wall_time"] = time.perf_counter() - wall0
        st["newton_iterations"] = system.newton_iterations()
        loop = system.loop_failure(t, x)
        if loop:
            err = AlgebraicLoopError(loop)
            err.partial = rec.result(events, st, "failed", loop)
            raise err
        why = system.diagnose(t, x) if x is not None else ""
        full = f"integration failed at t = {t:.9g} s: {msg}" + (f"; {why}" if why else "")
        raise IntegrationError(full, partial=rec.result(events, st, "failed", full))

    t = float(t0)
    x = system.x0.copy()
    fire_due(t, x)
    rec.add(t, x)
    grid_k = 1
    while t < t_end:
        t_seg = min(system.next_time(t), t_end)
        if t_seg <= t:
            t_seg = t_end
        st["segments"] += 1
        if system.n_x == 0:
            solver = None
            t_new = t_seg
            if output_interval is not None:
                while grid_k < 1e15 and grid_time(grid_k) < t_seg - 1e-12 * abs(t_seg):
                    rec.add(grid_time(grid_k), x)
                    grid_k += 1
            else:
                for tt in np.linspace(t, t_seg, 51)[1:-1]:
                    rec.add(tt, x)
            t = t_new
        else:
            try:
                solver = cls(system.rhs, t, x, t_seg, **kw)
            except ValueError as exc:
                fail(str(exc), t, x)
            while solver.status == "running":
                t_old = solver.t
                msg = solver.step()
                if solver.status == "failed":
                    fail(msg or "solver failure", solver.t, solver.y)
                st["steps"] += 1
                if output_interval is None:
                    if not rec.add(solver.t, solver.y):
                        fail("non-finite value", solver.t, solver.y)
                else:
                    if not np.all(np.isfinite(solver.y)):
                        fail("non-finite state", solver.t, solver.y)
                    tk = grid_time(grid_k)
                    if tk <= solver.t:
                        dense = solver.dense_output()
                        while tk <= solver.t and tk <= t_end * (1 + 1e-12):
                            rec.add(tk, dense(tk) if tk < solver.t else solver.y)
                            grid_k += 1
                            tk = grid_time(grid_k)
                if progress is not None:
                    progress(solver.t)
            st["rhs_calls"] += int(solver.nfev)
            st["jacobian_calls"] += int(getattr(solver, "njev", 0))
            st["lu_decompositions"] += int(getattr(solver, "nlu", 0))
            t = solver.t
            x = solver.y.copy()
        if t >= t_end:
            break
        fire_due(t, x)
        if output_interval is None:
            rec.add(t, x)
    if output_interval is not None and (not rec.n or rec.t[-1] < t_end * (1 - 1e-12)):
        rec.add(t_end, x)
    st["t_reached"] = t
    st["newton_iterations"] = system.newton_iterations()
    st["samples"] = rec.n
    st["wall_time"] = time.perf_counter() - wall0
    return rec.result(events, st)
