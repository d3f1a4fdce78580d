"""The SciPy-stepper integration loop, as small named parts.

This is the cross-check path of the integration loop (``method: LSODA, RK45, ...``); the
production path for ``DP54`` is the compiled loop of :mod:`spidersim.solver.loop_body`, made
of the same parts. A run is a sequence of *segments* between time events; each segment is
integrated by a fresh SciPy stepper whose ``t_bound`` is the next event time.

The parts, in the order one accepted step uses them
---------------------------------------------------
1. ``_step``: one accepted step of the stepper, with the stall check.
2. ``_detect``: the guards at the step's end (recorded with the outputs in one evaluation)
   and the armed guards that changed sign in the event's direction.
3. ``_locate``: the time of each crossing on the stepper's dense output, to 1e-13 relative.
4. ``_apply``: the earliest crossings applied at their common instant, chattering checked,
   then ``_settle`` (crossings the jump caused) and ``_disarm`` (a guard that has just fired
   must leave zero before firing again).
5. ``_fire_due``: time events and sampled blocks due at a segment's end, then ``_settle``.
6. ``_record`` / ``_record_grid``: a row at every accepted step, or on a uniform grid through
   the dense output (a grid point at an event instant is recorded after the event).

Every failure goes through ``_fail``, which raises with the samples recorded so far.
The system is anything that meets the contract of :mod:`spidersim.solver.system`.
"""
from __future__ import annotations

import os
import threading
import time
import warnings

import numpy as np

from ..errors import AlgebraicLoopError, IntegrationError
from .events import (ARMED, CHATTER_COUNT, MAX_EVENTS_AT_ONE_TIME, STALL_COUNT, STALL_STEP,
                     UNSEEN_PROBE, UNSEEN_STEP, crossed, crossings, left_zero_unseen, locate,
                     rearm_after, snap_band, snapped, zeno_message,
                     zero_start_candidates)
from . import record_budget
from .result import Result


def _tol(t):
    """Two times closer than this are the same instant."""
    return 1e-12 * max(1.0, abs(t))



class _Retry:
    """Go back to ``(t, x)`` and integrate with steps of at most ``h_cap`` (a guard
    returned unseen within the step just taken)."""

    def __init__(self, t, x, h_cap):
        self.t, self.x, self.h_cap = t, x, h_cap


class RecordBudgetFull(Exception):
    """The row buffer is at the recording budget (:mod:`.record_budget`); the run turns it
    into an :class:`IntegrationError` carrying the rows so far."""


class Recorder:
    """Logged rows in a preallocated buffer that doubles when full (sized for the whole
    run when the rows are known: an output grid), handed to the result without a copy when
    it is nearly full."""

    def __init__(self, system, capacity=1024):
        self.system = system
        self.buf = np.zeros((capacity, system.record_size))
        self.tbuf = np.zeros(capacity)
        self.n = 0
        #: bytes the run's event log takes (the rows and the log share one budget)
        self.other_bytes = 0.0

    def add(self, t, x, g=None):
        """Record outputs at (t, x); with ``g``, also the guards into it (one evaluation).
        Return False if something is not finite."""
        if self.n == len(self.tbuf):
            rows = record_budget.grown_rows(self.n, self.buf.shape[1], self.other_bytes)
            if rows is None:
                raise RecordBudgetFull(record_budget.budget_message(
                    self.n, self.buf.shape[1], float(self.tbuf[self.n - 1]),
                    other_bytes=self.other_bytes))
            record_budget.resize_rows(self.buf, rows)     # in place: no transient copy
            record_budget.resize_rows(self.tbuf, rows)
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
        if self.n < 0.9 * len(self.tbuf):         # trim a buffer much larger than its rows
            record_budget.resize_rows(self.tbuf, self.n)      # in place, no copy
            record_budget.resize_rows(self.buf, self.n)
        t, buf = self.t, self.buf[:self.n]
        return Result(t, buf, s.record_slices, dict(s.units), events, stats, status,
                      message)


class SciPyLoop:
    """One run of ``system`` from ``t0`` to ``t_end`` with the SciPy stepper class ``cls``.

    Parameters
    ----------
    system : System
        See :mod:`spidersim.solver.system`.
    cls : type
        A :class:`scipy.integrate.OdeSolver` subclass; ``kw`` its keyword arguments.
    output_interval, progress, should_stop, stats
        As in :func:`spidersim.solver.integrate.integrate`.
    """

    def __init__(self, system, cls, kw, t0, t_end, output_interval=None, progress=None,
                 should_stop=None, stats=None):
        self.system = system
        self.cls, self.kw = cls, kw
        self.t0, self.t_end = float(t0), t_end
        self.output_interval = output_interval
        self.progress, self.should_stop = progress, should_stop
        self.st = dict(stats or {})
        self.st.update(steps=0, rhs_calls=0, jacobian_calls=0, lu_decompositions=0,
                       segments=0, time_events=0)
        rows = 1024
        if output_interval:           # the grid's rows (and a few at events) are known
            rows = max(rows, int((t_end - self.t0) / output_interval) + 10)
        self.rec = Recorder(system, rows)
        self.events = []               # (t, block, event name or "time")
        self._next_budget_check = 0    # event count of the next recording-budget check
        self.grid_k = 0                # next grid point index (output_interval)
        self.tiny = 0                  # consecutive stalled steps
        n_g = self.n_g = system.n_g
        self.directions = np.array([d for _, _, d in system.event_table], dtype=float)
        self.armed = np.full(n_g, ARMED)      # events.ARMED and its kin, per guard
        #: guards that have just fired -> their snap band (:func:`.events.snap_band`) for
        #: the next segment's start
        self.snap = {}
        self.h_cap = None                 # max_step of the next segment's first solver
        self.armed_all = True
        self.hit_buf = np.empty(max(1, n_g), dtype=np.int64)
        self.g_new = np.zeros(n_g)
        self.recent = {}               # block -> times of its latest events (chattering)
        self.chatter_window = max(1e-9, 1e-6 * (t_end - t0))
        self.wall0 = time.perf_counter()
        #: warnings caught during the run (see :meth:`run`), or None
        self._caught = None

    # -- failures -----------------------------------------------------------------------

    def _fail(self, msg, t, x):
        """Raise :class:`IntegrationError` (or the loop's :class:`AlgebraicLoopError`)
        carrying the samples recorded so far."""
        s, st = self.system, self.st
        st["t_reached"] = t
        st["wall_time"] = time.perf_counter() - self.wall0
        st["newton_iterations"] = s.newton_iterations()
        loop, lp = s.loop_failure()
        if loop:
            err = AlgebraicLoopError(loop, file=lp.get("file"), line=lp.get("line"),
                                     block=lp.get("block"))
            err.partial = self.rec.result(self.events, st, "failed", loop)
            raise err
        from .loop import non_finite_ahead
        ahead = non_finite_ahead(s, t, x) if x is not None and "step size" in msg else ""
        if ahead:           # every trial step beyond t met a NaN or inf: say so (as LSODA)
            msg, why = (f"non-finite value just after t (the step size shrank to "
                        f"round-off): {ahead}"), ""
        else:
            why = s.diagnose(t, x) if x is not None else ""
        said = self._scipy_said()
        msg = f"{msg} (SciPy: {said})" if said else msg
        full = f"integration failed at t = {t:.9g} s: {msg}" + (f"; {why}" if why else "")
        raise IntegrationError(full, partial=self.rec.result(self.events, st, "failed", full))

    def _log(self, entries):
        """Append ``entries`` to the event log, within the recording budget shared with
        the rows (:mod:`.record_budget`; checked every 1024 events, or more often near
        the budget, so that the log fills it before the run stops)."""
        n = len(self.events) + len(entries)
        if entries and n >= self._next_budget_check:
            rec = self.rec
            rows = rec.buf.nbytes + rec.tbuf.nbytes
            ahead = 1024              # events reserved ahead: fewer when fewer fit
            while ahead > 1 and not record_budget.events_fit(n + ahead, rows):
                ahead //= 2
            if not record_budget.events_fit(n + ahead - 1, rows):
                raise RecordBudgetFull(record_budget.budget_message(
                    len(self.events), 3, entries[0][0], what="event log",
                    entry_bytes=record_budget.PY_EVENT_BYTES, other_bytes=rows))
            rec.other_bytes = (n + ahead) * record_budget.PY_EVENT_BYTES
            self._next_budget_check = n + ahead
        self.events.extend(entries)

    def _partial(self, msg=""):
        return self.rec.result(self.events, self.st, "failed", msg)

    # -- time events --------------------------------------------------------------------

    def _fire_due(self, t, x):
        """Apply every time event due at ``t`` (repeatedly, while new ones fall due at the
        same instant), then settle the crossings the jumps caused."""
        s = self.system
        n = 0
        g_before = s.guards(t, x) if self.n_g else None
        timed_blocks = set()
        while s.next_time(t) <= t + _tol(t):
            fired = s.time_events(t, x, _tol(t))
            self._log([(t, name, "time") for name in fired])
            timed_blocks.update(fired)
            self.st["time_events"] += len(fired)
            s.initialize(t, x)
            n += 1
            if n > MAX_EVENTS_AT_ONE_TIME or not fired:
                raise IntegrationError(
                    f"time events keep firing at t = {t:.9g} s without time advancing "
                    f"(blocks: {', '.join(fired) or 'none'})", partial=self._partial())
        if n:
            self._settle(t, x, g_before, timed_blocks, {})

    # -- state events -------------------------------------------------------------------

    def _locate(self, hits, dense, t_old, t_new, g_old):
        """Crossing time of each guard in ``hits`` inside [t_old, t_new] on ``dense``."""
        s = self.system
        xtol = 1e-13 * max(1.0, abs(t_new))
        times = {}
        for i in hits:
            if g_old[i] == 0.0:           # left zero at the start of the step
                times[i] = t_old
                continue
            times[i] = locate(lambda u, i=i: s.guards(u, dense(u))[i], t_old, t_new,
                              g_old[i], xtol)
        return times, xtol

    def _chatter(self, block, name, t_ev, x_ev):
        """Raise when ``block`` has fired CHATTER_COUNT events within the window."""
        q = self.recent.setdefault(block, [])
        q.append(t_ev)
        if len(q) > CHATTER_COUNT:
            q.pop(0)
        if len(q) == CHATTER_COUNT and q[-1] - q[0] <= self.chatter_window:
            msg = (f"chattering: block '{block}' fired {CHATTER_COUNT} events ('{name}') "
                   f"within {q[-1] - q[0]:.3g} s up to t = {t_ev:.9g} s (Zeno "
                   f"behaviour); give the block a rest mode or threshold, or stop "
                   f"the run earlier")
            self.st["t_reached"] = t_ev
            self.st["events"] = len(self.events)
            self.rec.add(t_ev, x_ev)
            raise IntegrationError(msg, partial=self.rec.result(self.events, self.st,
                                                                "failed", msg), block=block)

    def _apply(self, now, t_ev, x_ev, g_old, g_new):
        """Apply the crossings ``now`` at ``t_ev`` (in place on ``x_ev``), then settle and
        disarm the blocks that fired."""
        s = self.system
        g_before = s.guards(t_ev, x_ev)
        directions = {}                # guard -> the direction it fired in
        for i in sorted(now):
            block, name, _d = s.event_table[i]
            directions[i] = np.sign(g_new[i] - g_old[i]) or 1.0
            self.snap[int(i)] = snap_band(g_old[i], g_new[i])
            s.apply_event(t_ev, x_ev, int(i), directions[i])
            self._log([(float(t_ev), block, name)])
            self._chatter(block, name, t_ev, x_ev)
        chosen = s.modes.copy()
        s.initialize(t_ev, x_ev)
        self._keep_event_modes(now, chosen, t_ev, x_ev)
        fired = {s.event_table[i][0] for i in now}
        self._settle(t_ev, x_ev, g_before, fired, directions)
        self._disarm(fired, directions)

    def _state_events(self, solver, t_old, g_old, g_new):
        """Locate and apply the earliest crossing of the last step; return the event's
        ``(t, x)`` or None when no armed guard crossed."""
        n_hit = crossings(g_old, g_new, self.directions, self.armed, self.hit_buf)
        if not n_hit:
            return None
        hits = self.hit_buf[:n_hit].copy()
        dense = solver.dense_output()
        times, xtol = self._locate(hits, dense, t_old, solver.t, g_old)
        # crossings within 2 xtol of the earliest, or of one already in the group (chained),
        # are one instant, applied at the latest of them, where each has crossed (at the
        # earliest, one located a hair later would still be on its old side and fire again;
        # without chaining, one just beyond the window could have crossed and never fire)
        t_ev = min(times.values())
        grow = True
        while grow:
            later = [times[i] for i in hits if t_ev < times[i] <= t_ev + 2 * xtol]
            grow = bool(later)
            if grow:
                t_ev = max(later)
        now = [i for i in hits if times[i] <= t_ev]
        x_ev = dense(t_ev) if t_ev < solver.t else solver.y.copy()
        if self.output_interval is not None:
            self._record_grid(dense, t_old, t_ev)
        else:
            self.rec.add(t_ev, x_ev)
        self._apply(now, t_ev, x_ev, g_old, g_new)
        return t_ev, x_ev

    def _keep_event_modes(self, now, chosen, t, x):
        """Give back the modes its event chose to a block whose ``initialize`` changed them
        only because its fired guard lies within its snap band of zero
        (:func:`.events.snap_band`, on the side it came from): an input an algebraic loop
        solves to its Newton tolerance sits a hair past the corner the event was located
        on (a Saturation left its limit, ``initialize`` put it back, and it held there with
        its input inside: wrong by 0.4 to 0.8 on the SciPy methods). A guard farther off
        means the input really jumped (a simultaneous step): ``initialize`` is kept."""
        slices = getattr(self.system, "mode_slices", None)
        if not slices or np.array_equal(chosen, self.system.modes):
            return
        s = self.system
        g = s.guards(t, x)
        for i in now:
            span = slices.get(s.event_table[i][0])
            if span is None:
                continue
            a, b = span
            if not np.array_equal(chosen[a:b], s.modes[a:b]) and abs(g[i]) > 1e-300 and \
                    snapped(g[i], self.snap.get(int(i), 0.0)) == 0.0:
                # (a guard exactly on zero, or a block's marker next to it such as the
                # Switch's, is on the corner: there initialize decides)
                s.modes[a:b] = chosen[a:b]

    def _disarm(self, blocks, directions):
        """Guards of blocks that have just fired must leave zero before firing again; a
        guard that fired (``directions``: guard -> the direction it fired in) may fire at
        once back the way it came (:func:`.events.rearm_after`)."""
        for i, (blk, _n, _d) in enumerate(self.system.event_table):
            if blk in blocks:
                self.armed[i] = rearm_after(directions.get(i, 0.0))
                self.armed_all = False

    def _rearm(self, g):
        """A disarmed guard is armed again once it has left zero."""
        if not self.armed_all:
            self.armed[g != 0.0] = ARMED
            self.armed_all = bool((self.armed == ARMED).all())

    def _settle(self, t, x, g_before, fired_blocks, directions):
        """Fire the crossings caused by a jump at an event instant: a guard of another block
        that was on one side just before the event and is on the other just after it (a
        step input that jumps past a corner). Guards of blocks whose own event has just
        changed their mode are not compared (their guard functions changed with the mode).
        Repeats until nothing more fires."""
        if not self.n_g:
            return
        s = self.system
        for _ in range(MAX_EVENTS_AT_ONE_TIME):
            g_after = s.guards(t, x)
            hits = [i for i in crossed(g_before, g_after, self.directions)
                    if s.event_table[i][0] not in fired_blocks]
            if not hits:
                return
            for i in hits:
                block, name, _d = s.event_table[i]
                directions[i] = np.sign(g_after[i] - g_before[i]) or 1.0
                s.apply_event(t, x, int(i), directions[i])
                self._log([(float(t), block, name)])
                fired_blocks.add(block)
            s.initialize(t, x)
            g_before = s.guards(t, x)
        raise IntegrationError(f"events keep firing at t = {t:.9g} s",
                               partial=self._partial())

    # -- recording ----------------------------------------------------------------------

    def _grid_time(self, k):
        return self.t0 + k * self.output_interval

    def _record_grid(self, dense, t_a, t_b):
        """Grid points in [t_a, t_b): a point at an event time is recorded after the event
        (signals are right-continuous)."""
        tk = self._grid_time(self.grid_k)
        while tk < t_b - _tol(t_b):
            self.rec.add(tk, dense(tk))
            self.grid_k += 1
            tk = self._grid_time(self.grid_k)

    def _record_step(self, solver, t_old, recorded):
        """Record the end of an accepted step (or the grid points it passed)."""
        if self.output_interval is None:
            if not recorded and not self.rec.add(solver.t, solver.y):
                self._fail("non-finite value", solver.t, solver.y)
        else:
            if not np.all(np.isfinite(solver.y)):
                self._fail("non-finite state", solver.t, solver.y)
            if self._grid_time(self.grid_k) <= solver.t:
                self._record_grid(solver.dense_output(), t_old, solver.t)

    def _record_at(self, t, x):
        """Record at a segment's end, after its time events."""
        if self.output_interval is None:
            self.rec.add(t, x)
        elif abs(self._grid_time(self.grid_k) - t) <= _tol(t):
            self.rec.add(t, x)
            self.grid_k += 1

    # -- stepping -----------------------------------------------------------------------

    def _count(self, solver):
        """Add the stepper's evaluation counts to the statistics."""
        self.st["rhs_calls"] += int(solver.nfev)
        self.st["jacobian_calls"] += int(getattr(solver, "njev", 0))
        self.st["lu_decompositions"] += int(getattr(solver, "nlu", 0))

    def _step(self, solver):
        """One accepted step; fail on a solver failure or a stall. The state at the step's
        start is kept (``y_old``): a retried step restarts from it exactly."""
        t_old = solver.t
        self.y_old = solver.y.copy()
        try:
            msg = solver.step()
        except ValueError as exc:
            # BDF and Radau factor their iteration matrix with LAPACK, which refuses inf and
            # NaN ("array must not contain infs or NaNs"): derivatives turned non-finite
            if "inf" not in str(exc) and "NaN" not in str(exc):
                raise
            self._fail("non-finite value (the step size shrank to round-off)", solver.t,
                       solver.y)
        if solver.status == "failed":
            self._fail(msg or "solver failure", solver.t, solver.y)
        self.st["steps"] += 1
        if solver.t - t_old < STALL_STEP * max(1.0, abs(solver.t)):
            self.tiny += 1
            if self.tiny >= STALL_COUNT:
                self._fail(f"the integration stalls: {STALL_COUNT} consecutive steps shorter "
                           f"than {STALL_STEP:g} s (a singularity, e.g. a division by a "
                           f"signal crossing zero, or a discontinuity without an event)",
                           solver.t, solver.y)
        else:
            self.tiny = 0
        return t_old

    def _detect(self, solver, t_old, g_old):
        """Guards at the end of the step (the row recorded in the same evaluation when
        recording every step); locate and apply any crossing. Returns ``(hit, recorded)``:
        the event's ``(t, x)`` or None, and whether the step's end has been recorded."""
        g_new = self.g_new
        recorded = False
        if self.output_interval is None:
            # the row is overwritten if an event is located inside the step
            n_before = self.rec.n
            ok = self.rec.add(solver.t, solver.y, g_new)
            recorded = True
        else:
            g_new[:] = self.system.guards(solver.t, solver.y)
        retry = self._unseen_return(solver, t_old, g_old, g_new)
        if retry is not None:
            if recorded:
                self.rec.n = n_before
            return retry, False
        hit = None
        if crossings(g_old, g_new, self.directions, self.armed, self.hit_buf):
            if recorded:                  # the step's end lies beyond the event
                self.rec.n = n_before
                recorded = False
            hit = self._state_events(solver, t_old, g_old, g_new.copy())
        if hit is None and recorded and not ok:
            self._fail("non-finite value", solver.t, solver.y)
        if hit is None:
            g_old[:] = g_new
            self._rearm(g_new)
        return hit, recorded

    def _unseen_return(self, solver, t_old, g_old, g_new):
        """A guard that left zero and returned unseen within the step just taken
        (:func:`.events.left_zero_unseen`, probed a short Euler step along ``f(t_old,
        x_old)``): a :class:`_Retry` from ``(t_old, x_old)`` with steps at most 1/8 of this
        one, or the Zeno failure when the step cannot be shortened; None otherwise."""
        if not zero_start_candidates(g_old, g_new, self.directions, self.armed):
            return None
        s = self.system
        h = solver.t - t_old
        # the state the step began from, exactly: the dense output at t_old is within the
        # tolerances only (LSODA's put a ball just out of an impact at x = -1e-21, on the
        # stop's firing side, where its next landing went unseen and it fell through)
        x_old = self.y_old
        f_old = s.rhs(t_old, x_old)
        dt = UNSEEN_PROBE * h
        g_probe = s.guards(t_old + dt, x_old + dt * f_old)
        self.st["rhs_calls"] += 1
        i = left_zero_unseen(g_old, g_new, self.directions, self.armed, g_probe)
        if i < 0:
            return None
        if h <= UNSEEN_STEP * max(1.0, abs(solver.t)):
            block, name, _d = s.event_table[i]
            msg = zeno_message(block, name, t_old)
            self.st["t_reached"] = t_old
            self.st["events"] = len(self.events)
            raise IntegrationError(msg, partial=self._partial(msg), block=block)
        self.st["rejected_steps"] = self.st.get("rejected_steps", 0) + 1
        return _Retry(t_old, x_old, 0.125 * h)

    def _segment(self, t, x):
        """Integrate from (t, x) to the next time event, the end, or the first state event.

        Returns ``(solver, outcome, t, x)`` with outcome ``"event"`` (a state event at
        (t, x)), ``"interrupted"`` or ``"bound"`` (the segment's end reached)."""
        s = self.system
        t_seg = min(s.next_time(t), self.t_end)
        if t_seg - t <= _tol(t):
            # the same instant (3 x 0.3 = 0.8999999999999999 against t_end = 0.9): SciPy's
            # steppers refuse a span of a few ulps (LSODA: "Unexpected istate"); the state
            # cannot change over it, so the segment's end is reached where it stands
            if self.output_interval is None:
                self.rec.add(t_seg, x)
            return None, "bound", t_seg, x
        self.st["segments"] += 1
        kw = self.kw
        if self.h_cap is not None:                 # retrying an unseen return: shorter
            kw = dict(kw, max_step=min(kw.get("max_step", np.inf), self.h_cap))
            self.h_cap = None
        if kw.get("first_step") is not None and kw["first_step"] > t_seg - t:
            kw = dict(kw, first_step=t_seg - t)    # SciPy refuses one beyond the segment
        try:
            solver = self.cls(s.rhs, t, x, t_seg, **kw)
        except ValueError as exc:
            self._fail(str(exc), t, x)
        g_old = s.guards(t, x) if self.n_g else None
        for i, band in self.snap.items():    # fired, a hair back on its old side: on zero
            g_old[i] = snapped(g_old[i], band)
        self.snap = {}
        while solver.status == "running":
            t_old = self._step(solver)
            recorded = False
            if self.n_g:
                hit, recorded = self._detect(solver, t_old, g_old)
                if isinstance(hit, _Retry):
                    self._count(solver)
                    self.h_cap = hit.h_cap
                    return solver, "retry", hit.t, hit.x
                if hit is not None:
                    self._count(solver)
                    t, x = hit
                    if self.output_interval is None and not self.rec.add(t, x):
                        self._fail("non-finite value after an event", t, x)
                    return solver, "event", t, x
            self._record_step(solver, t_old, recorded)
            if self.progress is not None:
                self.progress(solver.t)
            if self.should_stop is not None and self.should_stop():
                return solver, "interrupted", solver.t, solver.y.copy()
        self._count(solver)
        return solver, "bound", solver.t, solver.y.copy()

    def run(self):
        """Integrate from ``t0`` to ``t_end``; return the :class:`Result` (its ``final``
        holds the end time, state and modes). A run whose rows reach the recording budget
        (:mod:`.record_budget`) fails with the rows recorded so far.

        SciPy's steppers say why they fail in a warning of their own (LSODA: "Repeated
        convergence failures ...", then only "Unexpected istate"): the warnings of the run
        are caught and SciPy's go into the failure's message (:meth:`_scipy_said`) instead
        of raw lines before it; the others, and all of a run that does not fail, are
        issued again after it. Catching swaps process-wide state, so it is done in the
        main thread only (where the command line and notebooks run); in other threads the
        warnings pass as before."""
        if threading.current_thread() is not threading.main_thread():
            return self._run_bounded()
        caught = []
        try:
            with warnings.catch_warnings(record=True) as caught:
                self._caught = caught
                return self._run_bounded()
        finally:
            self._caught = None
            for w in caught:
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)

    def _scipy_said(self):
        """The messages of the SciPy warnings caught so far, taken out of the catch (they
        are in the failure's message, not issued again), or ''."""
        if not self._caught:
            return ""
        mine = [w for w in self._caught
                if f"{os.sep}scipy{os.sep}" in (w.filename or "")]
        self._caught[:] = [w for w in self._caught if w not in mine]
        return "; ".join(dict.fromkeys(str(w.message) for w in mine))

    def _run_bounded(self):
        """:meth:`_run`, a full recording budget turned into an IntegrationError."""
        try:
            return self._run()
        except RecordBudgetFull as exc:
            msg = str(exc)
            self.st["t_reached"] = float(self.rec.tbuf[self.rec.n - 1])
            self.st["wall_time"] = time.perf_counter() - self.wall0
            raise IntegrationError(msg, partial=self._partial(msg)) from None

    def _run(self):
        s, st = self.system, self.st
        t = self.t0
        x = s.x0.copy()
        s.initialize(t, x)
        self._fire_due(t, x)
        if not self.rec.add(t, x):
            self._fail("non-finite value at the start", t, x)
        self.grid_k = 1
        interrupted = False
        while t < self.t_end:
            if s.next_time(t) <= t + _tol(t):
                # a time event due here (a state event may have stopped exactly on it)
                self._fire_due(t, x)
                if self.output_interval is None:
                    self.rec.add(t, x)
            solver, outcome, t, x = self._segment(t, x)
            if outcome == "interrupted":
                # stop at the step reached: what was recorded so far is the result
                st["rhs_calls"] += int(solver.nfev)
                if self.output_interval is not None and (not self.rec.n or
                                                         self.rec.t[-1] < t):
                    self.rec.add(t, x)
                interrupted = True
                break
            if outcome in ("event", "retry"):
                if t >= self.t_end and s.next_time(t) <= t + _tol(t):
                    # a state event exactly at t_end: the time events due there still fire
                    self._fire_due(t, x)
                    self._record_at(t, x)
                continue
            if t >= self.t_end and s.next_time(t) > t + _tol(t):
                break
            self._fire_due(t, x)
            self._record_at(t, x)
            if t >= self.t_end:
                break
        return self._finish(t, x, interrupted)

    def _finish(self, t, x, interrupted):
        s, st = self.system, self.st
        if not interrupted and self.output_interval is not None and (
                not self.rec.n or self.rec.t[-1] < self.t_end * (1 - 1e-12)):
            self.rec.add(self.t_end, x)
        st["t_reached"] = t
        st["events"] = len(self.events)
        st["newton_iterations"] = s.newton_iterations()
        st["samples"] = self.rec.n
        st["wall_time"] = time.perf_counter() - self.wall0
        result = (self.rec.result(self.events, st, "interrupted", f"interrupted at t = {t:.9g} s")
                  if interrupted else self.rec.result(self.events, st))
        result.final = (float(t), np.array(x, dtype=float), s.modes.copy())
        return result
