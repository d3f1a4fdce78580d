"""The compiled integration loop: Dormand-Prince 5(4) steps, events and recording in numba.

Python enters only to start the run, when a buffer is full (it grows the buffer and calls
again), every ``pause_steps`` steps (progress and Ctrl-C) and at the end: stepping, dense
output, guard evaluation, crossing location, event application, time events and recording
into preallocated buffers all run in machine code.

The loop is made of named parts, each a small compiled function (:mod:`.loop_body`; the
per-step ones are inlined by numba, so the split costs no calls):

======================  ======================================================================
part                    what it does
======================  ======================================================================
``run_loop_dp54``,      the entries, one per method: each passes its method to ``_run_loop``
``run_loop_ros34pw2``,  as a compile-time constant and is compiled (or loaded from numba's
``run_loop_ndf``        cache) on its own, with that method's code only (a DP54 run never
                        compiles the stiff solvers); :class:`CompiledLoop` calls the run's one
``_run_loop``           the loop: start, then until ``t_end``: hand back to Python when a
                        buffer is full or every ``pause_steps`` steps (``_pause_code``), the
                        time events due (``_time_events_now``), else one step
``_one_step``           a new segment's first step size (``_segment_start``), the step cap for
                        the rows (``_cap_for_rows``), one accepted step, the stall watch, the
                        step's events and rows, the step taken (``_accept_step``)
``_advance``            one accepted step of the method: trial steps of :mod:`.dp54`,
                        :mod:`.rosenbrock` or :mod:`.bdf` until the error norm is <= 1, never
                        past the end of the segment (the next time event or ``t_end``)
``_step_events``        guards at the step end (``_guards_at_step_end``), a guard that
                        returned unseen (``_unseen_return``: the step retried shorter),
                        crossings against the step start (:func:`.events.crossings`)
``_event_in_step``      the earliest crossing located and applied (``_state_events``: every
                        crossing located on the dense output by ``_locate``, chattering
                        watched), then the run resumed there (``_resume_after_event``)
``_fire_due``           apply the time events due now (sources switching, sampled blocks)
``_settle``             fire the crossings caused by a jump at an event instant
``_record_grid``        rows on the uniform output grid from the dense output (``_dense``)
======================  ======================================================================

The method-specific parts (``_advance``, ``_dense``, the first step of a segment) are
functions of the method: numba types them for the entry's constant method alone
(:func:`spidersim.solver._jit.for_method`), a method known only at run time would branch.

The state of the run lives in arrays (``ist`` integers, ``fst`` floats, ``x``, ``K``, ``G``,
the buffers), so that the loop can return to Python and resume exactly where it stopped.
The parts are compiled once for every diagram (:mod:`.loop_body`): they call the system only
through its system function (:mod:`spidersim.solver.sysfn`, one C-callable function per
diagram, passed by address), so a new diagram compiles its own function and nothing of the
loop; the loop is tested on hand-written system functions as well as on generated modules.

Semantics are those of the SciPy-stepper loop (:mod:`spidersim.solver.integrate`): the same
event rules (direction, re-arming, settling, chattering, at most ``MAX_EVENTS_AT_ONE_TIME``
rounds at one instant), the same recording (every accepted step, pre- and post-event rows at
events, or a uniform grid) and the same failure reports.
"""
from __future__ import annotations

import math
import time

import numpy as np

from ..errors import AlgebraicLoopError, IntegrationError
from . import bdf, record_budget, rosenbrock
from .result import EventLog, Result
from .sysfn import entry_point
from .events import zeno_message
from .dense_size import check_dense_size
from .loop_body import entry as loop_entry
from .loop_state import (  # noqa: F401 (the loop's constants, re-exported)
    METHOD_DP54, METHOD_ROS34PW2, METHODS, DONE, ROWS_FULL, EVENTS_FULL, PAUSE,
    FAIL_NONFINITE, FAIL_STALL, FAIL_SMALL_STEP, FAIL_CHATTER, FAIL_TIME_EVENTS,
    FAIL_SETTLE, FAIL_START, FAIL_ZENO, I_ROWS, I_EVENTS, I_GRID, I_TINY, I_STEPS, I_NFEV, I_STARTED,
    I_REJECTED, I_SEGMENTS, I_TIMED, I_BLOCK, I_FRESH, I_NG, I_OVERFLOW, I_NEW_STEPS,
    I_METHOD, I_NJAC, I_NLU, I_JAGE, N_IST, F_T, F_H, F_TEND, F_RTOL, F_ATOL, F_MAXSTEP,
    F_FIRST, F_DT, F_T0, F_CHATTER_WINDOW, F_TFAIL, F_HLU, F_JAC_MAX_AGE, F_JAC_REJECTIONS,
    F_HOLD_MAX, N_FST, G_OLD, G_NEW, G_TMP, G_ARMED, G_BEFORE, G_TIMES, G_NONE, N_G_ROWS,
    KIND_STATE, KIND_TIME, ROW_RESERVE, CHATTER_COUNT, MAX_EVENTS_AT_ONE_TIME, STALL_COUNT,
    STALL_STEP)


# ---------------------------------------------------------------------------------------
# Python side: buffers, resumption, the Result
# ---------------------------------------------------------------------------------------

#: accepted steps between two returns to Python (progress, Ctrl-C)
PAUSE_STEPS = 2000

_FAILURES = {
    FAIL_NONFINITE: "non-finite value",
    FAIL_STALL: (f"the integration stalls: {STALL_COUNT} consecutive steps shorter than "
                 f"{STALL_STEP:g} s (a singularity, e.g. a division by a signal crossing "
                 f"zero, or a discontinuity without an event)"),
    FAIL_SMALL_STEP: "required step size is less than spacing between numbers",
    FAIL_START: "non-finite value at the start",
}


def _event_arrays(event_table, timed):
    """``(g_dir, g_block, timed_block, n_blocks)``: each guard's direction, the index of
    each guard's and each timed entry's block among the ``n_blocks`` blocks with events
    (sorted by path), as :func:`~spidersim.solver.loop_body.run_loop` takes them."""
    names = sorted({blk for blk, _e, _d in event_table} | set(timed))
    bid = {b: k for k, b in enumerate(names)}
    g_dir = np.array([d for _b, _e, d in event_table], dtype=float)
    g_block = np.array([bid[b] for b, _e, _d in event_table], dtype=np.int64)
    timed_block = np.array([bid[b] for b in timed], dtype=np.int64)
    return g_dir, g_block, timed_block, len(names)


class CompiledLoop:
    """The arrays of one run of the compiled loop and the calls that resume it.

    Parameters
    ----------
    entry : int
        The system function's address (:mod:`spidersim.solver.sysfn`), handed to the
        compiled :func:`spidersim.solver.loop_body.run_loop` with the arrays of the run.
    system : CompiledSystem or compatible
        Supplies ``x0``, ``sig``, ``p``, ``modes``, ``event_table``, ``timed``,
        ``record_size``, the record index arrays ``_s_idx``, ``_x_idx`` and optionally
        ``jac_sparsity`` (the structural pattern; dense without it).
    method : str
        ``DP54``, ``ROS34PW2`` or ``NDF``.
    """

    def __init__(self, entry, system, t0, t_end, rtol, atol, max_step, first_step,
                 output_interval, capacity=1024, method="DP54", jacobian="auto"):
        s = system
        check_dense_size(s.n_x, method)       # before the n x n work arrays
        #: the system assembles df/dx itself (:mod:`spidersim.diagram.jacobian`)
        self.analytic = method in ("NDF", "ROS34PW2") and _use_analytic(s, jacobian)
        self.entry, self.system = entry, s
        #: the compiled loop's entry of the method (:data:`.loop_body.ENTRIES`)
        self.run_loop = loop_entry(method)
        n = s.n_x
        self.x = np.array(s.x0, dtype=float)
        self.K = rosenbrock.work_array(n)      # rows enough for either method
        # the NDF method's history and state (V, iw, fw) and the Jacobian's work and
        # pattern; the other methods get the shared placeholders (never read nor written
        # by their entries)
        self.B, self.JW, self.jpat = _PLACEHOLDERS
        shared = getattr(s, "shared", None)
        if shared is None:
            shared = {}
        self._shared = shared
        if method == "NDF":
            V, self.JW, iw, fw = bdf.work(n)
            self.B = (V, iw, fw)
            self.jpat = _pattern(s, shared, n, self.analytic)
        elif method == "ROS34PW2":
            self.JW = rosenbrock.jacobian_work(n)
            self.jpat = _pattern(s, shared, n, self.analytic)
        self.x1 = np.zeros(n)
        self.xs = np.zeros(n)
        ng = s.n_g
        # the event tables as arrays (read only in run_loop): once per compiled structure
        tab = shared.get("loop_events")
        if tab is None:
            tab = shared["loop_events"] = _event_arrays(s.event_table, s.timed)
        self.g_dir, self.g_block, self.timed_block, n_blocks = tab
        self.G = np.zeros((N_G_ROWS, max(1, ng)))
        self.G[G_ARMED] = 1.0
        self.fired = np.zeros(max(1, len(s.timed)))
        self.bmask = np.zeros(max(1, n_blocks), dtype=np.int64)
        self.hit = np.zeros(max(1, ng), dtype=np.int64)
        self.chat = np.zeros((max(1, n_blocks), CHATTER_COUNT + 1))
        rows = capacity
        if output_interval:        # the grid's rows are known: no growth, no copy at the end
            rows = max(capacity, int((t_end - t0) / output_interval) + 2 + 2 * ROW_RESERVE)
        else:                      # as many as the last run of this structure needed
            rows = _rows_hint(shared, t_end - t0, capacity, s.record_size)
        self.tbuf = np.zeros(rows)
        self.buf = np.zeros((rows, s.record_size))
        self.ev_t = np.zeros(capacity)
        self.ev_i = np.zeros((capacity, 3), dtype=np.int64)
        self._log = None                # the event log once made (:meth:`events`)
        # the integer and float state of the run, built as lists (one array call each)
        ist = [0] * N_IST
        ist[I_NG], ist[I_METHOD], ist[I_JAGE] = ng, METHODS[method], -1
        self.ist = np.array(ist, dtype=np.int64)
        f = [0.0] * N_FST
        f[F_T], f[F_T0], f[F_TEND] = t0, t0, t_end
        f[F_RTOL], f[F_ATOL], f[F_MAXSTEP] = rtol, atol, max_step
        f[F_FIRST] = first_step or 0.0
        f[F_DT] = output_interval or 0.0
        f[F_CHATTER_WINDOW] = max(1e-9, 1e-6 * (t_end - t0))
        f[F_JAC_MAX_AGE] = rosenbrock.JAC_MAX_AGE
        f[F_JAC_REJECTIONS] = rosenbrock.JAC_REJECTIONS
        f[F_HOLD_MAX] = rosenbrock.HOLD_MAX
        self.fst = np.array(f, dtype=float)

    def arguments(self, pause_steps=PAUSE_STEPS):
        """The arguments of :func:`~spidersim.solver.loop_body.run_loop` after the system
        function, in order."""
        s = self.system
        return (self.ist, self.fst, self.x, self.K, self.x1, self.xs, self.JW, self.jpat,
                self.B, self.G, self.g_dir,
                self.g_block, self.timed_block, self.fired, self.bmask, self.hit, self.chat,
                self.tbuf, self.buf, self.ev_t, self.ev_i, s._s_idx, s._x_idx, s.sig, s.p,
                s.modes, pause_steps)

    def call(self, pause_steps=PAUSE_STEPS):
        args = (self.entry,) + self.arguments(pause_steps)
        e = entry_point(self.run_loop, args)
        return int((e or self.run_loop)(*args))

    def grow_rows(self):
        """Enlarge the row buffers (doubling, within :mod:`.record_budget`); False when
        they are already at the budget."""
        rows = record_budget.grown_rows(len(self.tbuf), self.buf.shape[1],
                                        self.ev_t.nbytes + self.ev_i.nbytes)
        if rows is None:
            return False
        record_budget.resize_rows(self.tbuf, rows)       # in place: no transient copy
        record_budget.resize_rows(self.buf, rows)
        return True

    def grow_events(self):
        """Enlarge the event log (doubling, within :mod:`.record_budget`: an entry is
        four 8-byte numbers); False when it is already at the budget."""
        n = record_budget.grown_rows(len(self.ev_t), EVENT_VALUES,
                                     self.tbuf.nbytes + self.buf.nbytes)
        if n is None:
            return False
        record_budget.resize_rows(self.ev_t, n)
        record_budget.resize_rows(self.ev_i, n)
        return True

    @property
    def t(self):
        return float(self.fst[F_T])

    def events(self):
        """The event log as an :class:`~spidersim.solver.result.EventLog` over the log's
        arrays, trimmed in place to its entries (no copy, no Python object per event: as a
        list of tuples the log of a sampler took 5 times the memory the budget counts).
        Made once: each entry's code (its guard's index, or its timed block's after the
        guards) is written over the guard index, in place and in blocks."""
        if self._log is not None:
            return self._log
        n = int(self.ist[I_EVENTS])
        names = self._shared.get("event_names")
        if names is None:               # block and event names: state events, then timed
            names = self._shared["event_names"] = (
                [e[0] for e in self.system.event_table] + list(self.system.timed),
                [e[1] for e in self.system.event_table] + ["time"] * len(self.system.timed),
                len(self.system.event_table))
        blocks, kinds, n_state = names
        record_budget.resize_rows(self.ev_t, n)
        record_budget.resize_rows(self.ev_i, n)
        code = self.ev_i[:, 0]
        for lo in range(0, n, 1 << 16):
            kind = self.ev_i[lo:lo + (1 << 16), 1]
            code[lo:lo + (1 << 16)] += (kind == KIND_TIME) * n_state
        self._log = EventLog(self.ev_t, code, blocks, kinds)
        return self._log

    def add_row(self, t, x):
        """One more row at ``(t, x)`` from Python (the end of an interrupted grid run)."""
        n = int(self.ist[I_ROWS])
        if n == len(self.tbuf) and not self.grow_rows():
            return
        self.system.record_row(t, x, self.buf, n)
        self.tbuf[n] = t
        self.ist[I_ROWS] = n + 1

    def result(self, stats, status="ok", message=""):
        s = self.system
        n = int(self.ist[I_ROWS])
        if status == "ok" and not self.fst[F_DT]:
            self._shared["rows_hint"] = (n, self.fst[F_TEND] - self.fst[F_T0])
        if n < 0.9 * len(self.tbuf):         # trim a buffer much larger than its rows
            record_budget.resize_rows(self.tbuf, n)  # in place: a copy doubled the rows
            record_budget.resize_rows(self.buf, n)
        t, buf = self.tbuf[:n], self.buf[:n]
        return Result(t, buf, s.record_slices, dict(s.units), self.events(), stats, status, message)

    def stats(self):
        i = self.ist.tolist()
        return dict(steps=i[I_STEPS], rhs_calls=i[I_NFEV],
                    jacobian_calls=i[I_NJAC], lu_decompositions=i[I_NLU],
                    jacobian_groups=int(self.jpat[0]) if self.jpat.size else 0,
                    jacobian="analytic" if self.analytic else (
                        "finite differences" if self.jpat.size else "none"),
                    segments=i[I_SEGMENTS],
                    time_events=i[I_TIMED], rejected_steps=i[I_REJECTED])


#: values of one event-log entry after its time (``ev_i``: index, kind, direction)
EVENT_VALUES = 3


#: what DP54 passes for the NDF history (V, iw, fw), the Jacobian work and its pattern:
#: arrays of the right types that its entry never touches, made once
_PLACEHOLDERS = ((np.zeros((1, 1)), np.zeros(1, dtype=np.int64), np.zeros(1)),
                 np.zeros((2, 0, 0)), np.zeros(0, dtype=np.int64))


def _rows_hint(shared, span, capacity, record_size):
    """Rows to allocate for a run of ``span`` seconds recording every step: the last
    successful run of the same structure's rows, scaled by the spans and with 5 % to
    spare (no growth, and no trimming copy at the end, when the same run is made again: a
    sweep, a benchmark); a longer run starts with at most 2^16 rows and grows as usual
    (within the recording budget); ``capacity`` without a last run."""
    hint = shared.get("rows_hint")
    if hint is None or not hint[1] > 0:
        return capacity
    rows = int(hint[0] * min(1.0, span / hint[1]) * 1.05) + 4 * ROW_RESERVE
    if span > hint[1]:              # a longer run: scaled, but at most 2^16 rows at first
        rows = max(rows, min(int(rows * span / hint[1]), 1 << 16))
    return max(64, rows)


def _pattern(system, shared, n, analytic):
    """The Jacobian pattern array (:func:`.rosenbrock.pattern_array`: a graph colouring),
    once per compiled structure."""
    key = ("jpat", analytic)
    jpat = shared.get(key)
    if jpat is None:
        jpat = shared[key] = rosenbrock.pattern_array(
            getattr(system, "jac_sparsity", None), n, analytic)
    return jpat


def _use_analytic(system, jacobian):
    """Whether the loop asks ``system`` for its analytic Jacobian (``jacobian``: ``auto``,
    ``fd``, ``analytic``; the last raises when the system has none)."""
    has = bool(getattr(system, "analytic_jacobian", False))
    if jacobian == "analytic" and not has:
        from ..errors import SpidersimError
        why = getattr(system, "jacobian_reason", "") or "not generated"
        raise SpidersimError(f"jacobian='analytic': the diagram has no analytic Jacobian "
                             f"({why}); use 'auto' or 'fd'")
    return has and jacobian != "fd"


def integrate_dp54(system, entry, t_end, t0=0.0, rtol=1e-6, atol=1e-8, max_step=math.inf,
                   first_step=None, output_interval=None, progress=None, stats=None,
                   should_stop=None, method="DP54", jacobian="auto"):
    """Integrate ``system`` with the compiled loop (Dormand-Prince 5(4); ROS34PW2 or the
    variable-order NDF with ``method="ROS34PW2"`` or ``"NDF"``); return a ``Result``.

    Arguments as :func:`spidersim.solver.integrate.integrate` (already validated there);
    ``entry`` is the system function's address (``system.compiled_entry``). Failures raise
    :class:`~spidersim.errors.IntegrationError` (or ``AlgebraicLoopError``) with the partial
    result, exactly as the SciPy-stepper loop does.
    """
    wall0 = time.perf_counter()
    if system.n_x == 0 and max_step == math.inf:
        max_step = (t_end - t0) / 200
    run = CompiledLoop(entry, system, t0, t_end, rtol, atol, max_step, first_step,
                       output_interval, method=method, jacobian=jacobian)
    st = dict(stats or {})
    st.update(method=method, rtol=rtol, atol=atol, max_step=max_step, t_end=t_end)
    status, message = "ok", ""
    while True:
        code = run.call()
        if code == ROWS_FULL:
            if not run.grow_rows():
                st.update(run.stats())
                msg = record_budget.budget_message(
                    int(run.ist[I_ROWS]), run.buf.shape[1], run.t,
                    other_bytes=run.ev_t.nbytes + run.ev_i.nbytes)
                raise IntegrationError(msg, partial=run.result(st, "failed", msg))
        elif code == EVENTS_FULL:
            if not run.grow_events():
                st.update(run.stats())
                msg = record_budget.budget_message(
                    int(run.ist[I_EVENTS]), EVENT_VALUES, run.t, what="event log",
                    other_bytes=run.tbuf.nbytes + run.buf.nbytes)
                raise IntegrationError(msg, partial=run.result(st, "failed", msg))
        elif code == PAUSE or code == DONE:
            if progress is not None:
                progress(run.t)
            if code == DONE:
                break
            if should_stop is not None and should_stop():
                status, message = "interrupted", f"interrupted at t = {run.t:.9g} s"
                if output_interval is not None and (
                        not run.ist[I_ROWS] or run.tbuf[run.ist[I_ROWS] - 1] < run.t):
                    run.add_row(run.t, run.x)
                break
        else:
            st.update(run.stats())
            _fail(system, run, code, st, wall0, IntegrationError)
        if run.ist[I_OVERFLOW]:
            st.update(run.stats())
            raise IntegrationError(f"events keep firing at t = {run.t:.9g} s",
                                   partial=run.result(st, "failed"))
    st.update(run.stats())
    st["t_reached"] = run.t
    st["events"] = int(run.ist[I_EVENTS])
    st["newton_iterations"] = system.newton_iterations()
    st["samples"] = int(run.ist[I_ROWS])
    st["wall_time"] = time.perf_counter() - wall0
    result = run.result(st, status, message)
    result.final = (run.t, run.x.copy(), system.modes.copy())
    return result


def _fail(system, run, code, st, wall0, IntegrationError):
    """Raise the error of failure ``code`` (messages as the SciPy-stepper loop's)."""
    t = run.t
    st["t_reached"] = t
    st["wall_time"] = time.perf_counter() - wall0
    st["events"] = int(run.ist[I_EVENTS])
    st["newton_iterations"] = system.newton_iterations()
    if code == FAIL_CHATTER:
        i = int(run.ist[I_BLOCK])
        block, name, _d = system.event_table[i]
        span = float(run.fst[F_TFAIL])
        msg = (f"chattering: block '{block}' fired {CHATTER_COUNT} events ('{name}') "
               f"within {span:.3g} s up to t = {t:.9g} s (Zeno behaviour); give the block a "
               f"rest mode or threshold, or stop the run earlier")
        raise IntegrationError(msg, partial=run.result(st, "failed", msg), block=block)
    if code == FAIL_ZENO:
        block, name, _d = system.event_table[int(run.ist[I_BLOCK])]
        msg = zeno_message(block, name, t)
        raise IntegrationError(msg, partial=run.result(st, "failed", msg), block=block)
    if code == FAIL_TIME_EVENTS:
        msg = f"time events keep firing at t = {t:.9g} s without time advancing"
        raise IntegrationError(msg, partial=run.result(st, "failed", msg))
    if code == FAIL_SETTLE:
        msg = f"events keep firing at t = {t:.9g} s"
        raise IntegrationError(msg, partial=run.result(st, "failed", msg))
    loop, lp = system.loop_failure()
    if loop:
        err = AlgebraicLoopError(loop, file=lp.get("file"), line=lp.get("line"),
                                 block=lp.get("block"))
        err.partial = run.result(st, "failed", loop)
        raise err
    what = _FAILURES.get(code, 'solver failure')
    ahead = non_finite_ahead(system, t, run.xs) if code in (FAIL_SMALL_STEP,
                                                              FAIL_STALL) else ""
    if ahead:
        # the step shrank because every trial step beyond t met a NaN or inf (log or sqrt
        # of a negative, a division by zero): say so, as LSODA's 'non-finite value' does
        what = f"non-finite value just after t (the step size shrank to round-off): {ahead}"
        why = ""
    else:
        why = _failure_detail(system, t, run.xs)
    full = (f"integration failed at t = {t:.9g} s: {what}" + (f"; {why}" if why else ""))
    raise IntegrationError(full, partial=run.result(st, "failed", full))


def _failure_detail(system, t, x):
    diagnose = getattr(system, "diagnose", None)
    return diagnose(t, x) if diagnose is not None else ""


def non_finite_ahead(system, t, x):
    """When the derivatives are finite at ``(t, x)`` but not just beyond (an Euler
    prediction ``x + dt f`` at ``t + dt``, ``dt`` from ``1e-12 max(1, |t|)`` up to
    ``1e-3 max(1, |t|)``): the system's diagnosis there (the first non-finite signal or
    derivative, by name); else ''. Failure reporting only: the run has already stopped."""
    diagnose, rhs = getattr(system, "diagnose", None), getattr(system, "rhs", None)
    if diagnose is None or rhs is None:
        return ""
    x = np.asarray(x, dtype=float)
    with np.errstate(all="ignore"):
        f0 = np.array(rhs(t, x), dtype=float)
        if not np.all(np.isfinite(f0)):
            return diagnose(t, x)
        scale = max(1.0, abs(t))
        for k in range(12, 2, -1):
            dt = scale * 10.0 ** -k
            x1 = x + dt * f0
            if not np.all(np.isfinite(np.asarray(rhs(t + dt, x1), dtype=float))):
                return diagnose(t + dt, x1)
    return ""
