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
from .events import crossed, crossings, locate  # noqa: F401 (part of this module's API)
from .result import Result

METHODS = {"LSODA": LSODA, "RK45": RK45, "RK23": RK23, "DOP853": DOP853, "Radau": Radau,
           "BDF": BDF, "DP54": RK45, "ROS34PW2": Radau}
#: methods integrated by the compiled loop (:mod:`spidersim.solver.loop`) when the system
#: has one (numba-compiled diagrams); interpreted diagrams run them through the SciPy
#: stepper of the same tableau and controller (DP54) or SciPy's Radau (ROS34PW2)
COMPILED = ("DP54", "ROS34PW2")
#: methods given the structural Jacobian pattern (ROS34PW2 runs SciPy's Radau here)
IMPLICIT = ("Radau", "BDF", "ROS34PW2")
MAX_EVENTS_AT_ONE_TIME = 1000
#: a run stalls when this many consecutive accepted steps are each shorter than
#: STALL_STEP * max(1, |t|): the solution is running into a singularity
STALL_COUNT = 500
STALL_STEP = 1e-10
#: chattering: this many events of one block inside the window below is an error
CHATTER_COUNT = 50


class _Clock:
    """A system without states seen through one dummy state ``c' = 1``, so that diagrams of
    sources and static blocks get the same stepping, events and dense output."""

    n_x = 1
    jac_sparsity = None

    def __init__(self, system):
        self._s = system
        self.x0 = np.zeros(1)

    def __getattr__(self, name):
        return getattr(self._s, name)

    def rhs(self, t, x):
        return np.ones(1)

    def outputs(self, t, x):
        self._s.outputs(t, x[:0])

    def record_row(self, t, x, buf, row):
        return self._s.record_row(t, x[:0], buf, row)

    def guards(self, t, x):
        return self._s.guards(t, x[:0])

    def apply_event(self, t, x, k, direction):
        self._s.apply_event(t, x[:0], k, direction)

    def initialize(self, t, x):
        self._s.initialize(t, x[:0])

    def time_events(self, t, x, tol):
        return self._s.time_events(t, x[:0], tol)

    def diagnose(self, t, x):
        return self._s.diagnose(t, x[:0])


_crossings = crossings      # the compiled helper under its historical name


class _Recorder:
    """Logged rows in a preallocated buffer that doubles when full."""

    def __init__(self, system, capacity=1024):
        self.system = system
        self.buf = np.zeros((capacity, system.record_size))
        self.tbuf = np.zeros(capacity)
        self.n = 0

    def add(self, t, x, g=None):
        """Record outputs at (t, x); with ``g``, also the guards into it (one evaluation).
        Return False if something is not finite."""
        if self.n == len(self.tbuf):
            self.buf = np.concatenate((self.buf, np.zeros_like(self.buf)))
            self.tbuf = np.concatenate((self.tbuf, np.zeros_like(self.tbuf)))
        if g is None:
            ok = self.system.record_row(t, x, self.buf, self.n)
        else:
            ok = self.system.record_row_guards(t, x, self.buf, self.n, g)
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
              first_step=None, output_interval=None, progress=None, stats=None,
              should_stop=None):
    """Integrate ``system`` from ``t0`` to ``t_end``; return a :class:`Result`.

    Parameters
    ----------
    system : CompiledSystem
        See :mod:`spidersim.solver.system` for the contract.
    method : str
        ``LSODA`` (default), ``RK45``, ``RK23``, ``DOP853``, ``Radau`` or ``BDF`` (SciPy's
        steppers driven by this loop), or ``DP54``: Dormand-Prince 5(4) in the compiled loop
        of :mod:`spidersim.solver.loop` (stepping, events and recording in machine code), or
        ``ROS34PW2``: the stiff Rosenbrock-W method of :mod:`spidersim.solver.rosenbrock` in
        the same loop (finite-difference Jacobian over coloured column groups); interpreted
        diagrams run SciPy's Radau for it.
    rtol, atol, max_step, first_step : float
        Passed to the SciPy solver.
    output_interval : float, optional
        Record on a uniform grid of this spacing instead of at every step.
    progress : callable, optional
        ``progress(t)`` after every accepted step.
    should_stop : callable, optional
        ``should_stop() -> bool`` polled after every accepted step (keep it a flag check);
        when true the run stops at that step and the result up to it is returned with
        ``status == "interrupted"`` (the CLI sets it from SIGINT/SIGTERM).
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
    entry = getattr(system, "compiled_entry", None)
    if method in COMPILED and entry is not None:
        from .loop import integrate_dp54
        return integrate_dp54(system, entry, t_end, t0=t0, rtol=rtol, atol=atol,
                              max_step=max_step, first_step=first_step,
                              output_interval=output_interval, progress=progress,
                              stats=stats, should_stop=should_stop, method=method)
    wall0 = time.perf_counter()
    if system.n_x == 0:
        system = _Clock(system)
        if max_step == math.inf:
            max_step = (t_end - t0) / 200
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
        g_before = system.guards(t, x) if n_g else None
        timed_blocks = set()
        while system.next_time(t) <= t + 1e-12 * max(1.0, abs(t)):
            fired = system.time_events(t, x, 1e-12 * max(1.0, abs(t)))
            events.extend((t, name, "time") for name in fired)
            timed_blocks.update(fired)
            st["time_events"] += len(fired)
            system.initialize(t, x)
            n += 1
            if n > MAX_EVENTS_AT_ONE_TIME or not fired:
                raise IntegrationError(
                    f"time events keep firing at t = {t:.9g} s without time advancing "
                    f"(blocks: {', '.join(fired) or 'none'})",
                    partial=rec.result(events, st, "failed"))
        if n:
            settle(t, x, g_before, timed_blocks)

    def fail(msg, t, x):
        st["t_reached"] = t
        st["wall_time"] = time.perf_counter() - wall0
        st["newton_iterations"] = system.newton_iterations()
        loop, lp = system.loop_failure()
        if loop:
            err = AlgebraicLoopError(loop, file=lp.get("file"), line=lp.get("line"),
                                     block=lp.get("block"))
            err.partial = rec.result(events, st, "failed", loop)
            raise err
        why = system.diagnose(t, x) if x is not None else ""
        full = f"integration failed at t = {t:.9g} s: {msg}" + (f"; {why}" if why else "")
        raise IntegrationError(full, partial=rec.result(events, st, "failed", full))

    n_g = system.n_g
    directions = np.array([d for _, _, d in system.event_table], dtype=float)
    armed = np.ones(n_g, dtype=bool)
    armed_all = True
    hit_buf = np.empty(max(1, n_g), dtype=np.int64)
    g_new = np.zeros(n_g)
    recent = {}
    chatter_window = max(1e-9, 1e-6 * (t_end - t0))

    def handle_state_events(solver, t_old, g_old, g_new):
        """Locate and apply the earliest crossing of this step; return (t, x) or None."""
        n_hit = _crossings(g_old, g_new, directions, armed, hit_buf)
        if not n_hit:
            return None
        hits = hit_buf[:n_hit].copy()
        dense = solver.dense_output()
        xtol = 1e-13 * max(1.0, abs(solver.t))
        times = {}
        for i in hits:
            if g_old[i] == 0.0:           # left zero at the start of the step
                times[i] = t_old
                continue
            times[i] = locate(lambda s, i=i: system.guards(s, dense(s))[i], t_old, solver.t,
                              g_old[i], xtol)
        t_ev = min(times.values())
        now = [i for i in hits if times[i] <= t_ev + 2 * xtol]
        x_ev = dense(t_ev) if t_ev < solver.t else solver.y.copy()
        if output_interval is not None:
            record_grid(dense, t_old, t_ev)
        else:
            rec.add(t_ev, x_ev)
        g_before = system.guards(t_ev, x_ev)
        for i in sorted(now):
            block, name, _d = system.event_table[i]
            system.apply_event(t_ev, x_ev, int(i), np.sign(g_new[i] - g_old[i]) or 1.0)
            events.append((float(t_ev), block, name))
            q = recent.setdefault(block, [])
            q.append(t_ev)
            if len(q) > CHATTER_COUNT:
                q.pop(0)
            if len(q) == CHATTER_COUNT and q[-1] - q[0] <= chatter_window:
                msg = (f"chattering: block '{block}' fired {CHATTER_COUNT} events ('{name}') "
                       f"within {q[-1] - q[0]:.3g} s up to t = {t_ev:.9g} s (Zeno "
                       f"behaviour); give the block a rest mode or threshold, or stop "
                       f"the run earlier")
                st["t_reached"] = t_ev
                st["events"] = len(events)
                rec.add(t_ev, x_ev)
                raise IntegrationError(msg, partial=rec.result(events, st, "failed", msg),
                                       block=block)
        system.initialize(t_ev, x_ev)
        fired = {system.event_table[i][0] for i in now}
        settle(t_ev, x_ev, g_before, fired)
        disarm(fired)
        return t_ev, x_ev

    def disarm(blocks):
        """Guards of blocks that have just fired must leave zero before firing again."""
        nonlocal armed_all
        for i, (blk, _n, _d) in enumerate(system.event_table):
            if blk in blocks:
                armed[i] = False
                armed_all = False

    def settle(t, x, g_before, fired_blocks):
        """Fire the crossings caused by a jump at an event instant: a guard of another block
        that was on one side just before the event and is on the other just after it (a
        step input that jumps past a corner). Guards of blocks whose own event has just
        changed their mode are not compared (their guard functions changed with the mode).
        Repeats until nothing more fires."""
        if not n_g:
            return
        for _ in range(MAX_EVENTS_AT_ONE_TIME):
            g_after = system.guards(t, x)
            hits = [i for i in crossed(g_before, g_after, directions)
                    if system.event_table[i][0] not in fired_blocks]
            if not hits:
                return
            for i in hits:
                block, name, _d = system.event_table[i]
                system.apply_event(t, x, int(i), np.sign(g_after[i] - g_before[i]) or 1.0)
                events.append((float(t), block, name))
                fired_blocks.add(block)
            system.initialize(t, x)
            g_before = system.guards(t, x)
        raise IntegrationError(f"events keep firing at t = {t:.9g} s",
                               partial=rec.result(events, st, "failed"))

    def record_grid(dense, t_a, t_b):
        """Grid points in [t_a, t_b): a point at an event time is recorded after the event
        (signals are right-continuous)."""
        nonlocal grid_k
        tk = grid_time(grid_k)
        while tk < t_b - 1e-12 * max(1.0, abs(t_b)):
            rec.add(tk, dense(tk))
            grid_k += 1
            tk = grid_time(grid_k)

    t = float(t0)
    tiny = 0
    x = system.x0.copy()
    system.initialize(t, x)
    fire_due(t, x)
    if not rec.add(t, x):
        fail("non-finite value at the start", t, x)
    grid_k = 1
    interrupted = False
    while t < t_end:
        if system.next_time(t) <= t + 1e-12 * max(1.0, abs(t)):
            # a time event due here (a state event may have stopped exactly on it)
            fire_due(t, x)
            if output_interval is None:
                rec.add(t, x)
        t_seg = min(system.next_time(t), t_end)
        st["segments"] += 1
        try:
            solver = cls(system.rhs, t, x, t_seg, **kw)
        except ValueError as exc:
            fail(str(exc), t, x)
        g_old = system.guards(t, x) if n_g else None
        restarted = False
        while solver.status == "running":
            t_old = solver.t
            msg = solver.step()
            if solver.status == "failed":
                fail(msg or "solver failure", solver.t, solver.y)
            st["steps"] += 1
            if solver.t - t_old < STALL_STEP * max(1.0, abs(solver.t)):
                tiny += 1
                if tiny >= STALL_COUNT:
                    fail(f"the integration stalls: {STALL_COUNT} consecutive steps shorter "
                         f"than {STALL_STEP:g} s (a singularity, e.g. a division by a "
                         f"signal crossing zero, or a discontinuity without an event)",
                         solver.t, solver.y)
            else:
                tiny = 0
            recorded = False
            if n_g:
                if output_interval is None:
                    # record this step and its guards from one evaluation; the row is
                    # overwritten if an event is located inside the step
                    n_before = rec.n
                    ok = rec.add(solver.t, solver.y, g_new)
                    recorded = True
                else:
                    g_new[:] = system.guards(solver.t, solver.y)
                hit = None
                if _crossings(g_old, g_new, directions, armed, hit_buf):
                    if recorded:              # the step's end lies beyond the event
                        rec.n = n_before
                        recorded = False
                    hit = handle_state_events(solver, t_old, g_old, g_new.copy())
                if hit is None and recorded and not ok:
                    fail("non-finite value", solver.t, solver.y)
                if hit is not None:
                    st["rhs_calls"] += int(solver.nfev)
                    st["jacobian_calls"] += int(getattr(solver, "njev", 0))
                    st["lu_decompositions"] += int(getattr(solver, "nlu", 0))
                    t, x = hit
                    if output_interval is None and not rec.add(t, x):
                        fail("non-finite value after an event", t, x)
                    restarted = True
                    break
                g_old[:] = g_new
                if not armed_all:
                    armed |= g_new != 0.0      # re-armed once it has left zero
                    armed_all = bool(armed.all())
            if output_interval is None:
                if not recorded and not rec.add(solver.t, solver.y):
                    fail("non-finite value", solver.t, solver.y)
            else:
                if not np.all(np.isfinite(solver.y)):
                    fail("non-finite state", solver.t, solver.y)
                if grid_time(grid_k) <= solver.t:
                    record_grid(solver.dense_output(), t_old, solver.t)
            if progress is not None:
                progress(solver.t)
            if should_stop is not None and should_stop():
                interrupted = True
                break
        if interrupted:
            # stop at the step reached: what was recorded so far is the result
            st["rhs_calls"] += int(solver.nfev)
            t, x = solver.t, solver.y.copy()
            if output_interval is not None and (not rec.n or rec.t[-1] < t):
                rec.add(t, x)
            break
        if restarted:
            continue
        st["rhs_calls"] += int(solver.nfev)
        st["jacobian_calls"] += int(getattr(solver, "njev", 0))
        st["lu_decompositions"] += int(getattr(solver, "nlu", 0))
        t = solver.t
        x = solver.y.copy()
        if t >= t_end and system.next_time(t) > t + 1e-12 * max(1.0, abs(t)):
            break
        fire_due(t, x)
        if output_interval is None:
            rec.add(t, x)
        elif abs(grid_time(grid_k) - t) <= 1e-12 * max(1.0, abs(t)):
            rec.add(t, x)
            grid_k += 1
        if t >= t_end:
            break
    if not interrupted and output_interval is not None and (
            not rec.n or rec.t[-1] < t_end * (1 - 1e-12)):
        rec.add(t_end, x)
    st["t_reached"] = t
    st["events"] = len(events)
    st["newton_iterations"] = system.newton_iterations()
    st["samples"] = rec.n
    st["wall_time"] = time.perf_counter() - wall0
    result = (rec.result(events, st, "interrupted", f"interrupted at t = {t:.9g} s")
              if interrupted else rec.result(events, st))
    x_final = x if not isinstance(system, _Clock) else x[:0]
    result.final = (float(t), np.array(x_final, dtype=float), system.modes.copy())
    return result
