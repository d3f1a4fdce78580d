"""The compiled integration loop's parts, compiled once for every diagram.

Each part is a small compiled function whose first argument ``fn`` is the system function of
the diagram being integrated (its address; see :mod:`spidersim.solver.sysfn`): the parts call
the system only through :mod:`.sysfn`'s task functions, so their machine code does not depend
on the diagram and is compiled once and cached with spidersim itself. The helpers of
:mod:`.dp54`, :mod:`.rosenbrock` and :mod:`.events` are pure functions on arrays.

The loop has one entry per method (``run_loop_dp54``, ``run_loop_ros34pw2``,
``run_loop_ndf``), each compiled on its own with its method a constant; the parts, their
order and their state arrays are described in :mod:`spidersim.solver.loop`.
"""
import math

import numpy as np

from ._jit import njit_borrowed, for_method, literal_method
from . import dp54 as _dp54
from .dense_lu import lu_solve as _lu_solve
from . import events as _events
from . import rosenbrock as _ros
from . import bdf as _bdf
from . import sysfn as _sf
from .loop_state import (  # noqa: F401
    CHATTER_COUNT, DONE, EVENTS_FULL, FAIL_CHATTER, FAIL_NONFINITE, FAIL_SETTLE,
    FAIL_SMALL_STEP, FAIL_STALL, FAIL_START, FAIL_TIME_EVENTS, FAIL_ZENO, F_ATOL, F_CHATTER_WINDOW,
    F_DT, F_FIRST, F_H, F_MAXSTEP, F_RTOL, F_T, F_T0, F_TEND, F_TFAIL, G_ARMED, G_BEFORE,
    G_FIRED,
    G_NEW, G_NONE, G_OLD, G_TIMES, G_TMP, I_BLOCK, I_EVENTS, I_FRESH, I_GRID, I_NEW_STEPS,
    I_NFEV, I_NG, I_OVERFLOW, I_REJECTED, I_ROWS, I_SEGMENTS, I_STARTED, I_STEPS, I_TIMED,
    I_TINY, I_METHOD, I_NJAC, I_NLU, I_JAGE, F_HLU, F_JAC_MAX_AGE, F_JAC_REJECTIONS,
    F_HOLD_MAX, F_HCAP, METHOD_DP54, METHOD_ROS34PW2, METHOD_NDF, METHODS, KIND_STATE,
    KIND_TIME,
    MAX_EVENTS_AT_ONE_TIME, PAUSE,
    ROW_RESERVE, ROWS_FULL, STALL_COUNT, STALL_STEP)


@njit_borrowed(inline="always")
def _copy(dst, src):
    """``dst[:] = src`` element by element (numba's slice assignment checks whether the
    arrays overlap and would copy through a new buffer if they did: an allocation that
    needs reference counting, and a test per copy)."""
    for i in range(dst.size):
        dst[i] = src[i]


@njit_borrowed(inline="always")
def _step(fn, t, x, h, K, x1, rtol, atol, sig, p, modes):
    """One Dormand-Prince trial step (see :mod:`spidersim.solver.dp54`); returns the error
    norm."""
    y = K[_dp54.ROW_TRIAL]
    for s in range(1, 6):
        _dp54.stage_state(s, x, K, h, y)
        _sf.derivatives(fn, t + _dp54.c_of(s) * h, y, sig, p, modes, K[s])
    _dp54.stage_state(6, x, K, h, x1)
    _sf.derivatives(fn, t + h, x1, sig, p, modes, K[6])
    return _dp54.error_norm(x, x1, K, h, rtol, atol)


@njit_borrowed
def _first_step(fn, t, x, f0, span, rtol, atol, K, sig, p, modes):
    """Initial step size at a segment start (see :func:`spidersim.solver.dp54.initial_h0`)."""
    y = K[_dp54.ROW_TRIAL]
    f1 = K[_dp54.ROW_SCRATCH]
    h0 = _dp54.initial_h0(x, f0, rtol, atol, span, y)
    if x.size == 0:
        return h0
    _sf.derivatives(fn, t + h0, y, sig, p, modes, f1)
    return _dp54.initial_step(x, f0, f1, h0, rtol, atol, span)


def _dense(meth, t, h, x, x1, K, B, s, out):
    """The dense output of the step ``(t, x) -> (t + h, x1)`` of method ``meth`` at ``s``
    (``B``: the NDF method's arrays ``(V, iw, fw)``). Compiled for the method alone when
    ``meth`` is a compile-time constant (:func:`spidersim.solver._jit.for_method`), and
    inlined: as a call it passed its five arrays and the tuple ``B`` field by field at every
    iteration of the event location (the ball's 100-impact run 0.27-0.29 -> 0.24-0.25
    ms)."""
    if meth == METHOD_NDF:
        _bdf.dense(t + h, B[0], B[1], B[2], s, out)
    elif meth == METHOD_ROS34PW2:
        _ros.dense(t, h, x, x1, K, s, out)
    else:
        _dp54.dense(t, h, x, x1, K, s, out)


def _dense_dp54(meth, t, h, x, x1, K, B, s, out):
    _dp54.dense(t, h, x, x1, K, s, out)


def _dense_ros34pw2(meth, t, h, x, x1, K, B, s, out):
    _ros.dense(t, h, x, x1, K, s, out)


def _dense_ndf(meth, t, h, x, x1, K, B, s, out):
    _bdf.dense(t + h, B[0], B[1], B[2], s, out)


@for_method(_dense)
def _dense_of(meth, t, h, x, x1, K, B, s, out):
    return literal_method(meth, (_dense_dp54, _dense_ros34pw2, _dense_ndf), _dense)


@njit_borrowed(inline="always")
def _locate(fn, meth, i, g_a, g_b, t, h, x, x1, K, B, xs, g, xtol, sig, p, modes):
    """Crossing time of guard ``i`` in ``(t, t + h]`` on the step's dense output, on the far
    side (see :func:`spidersim.solver.events.bracket_trial`). Inlined into its caller: as a
    call, the method's dense output reached through :func:`_dense` inside it made the
    ball's 100 impacts 25 % slower (0.147 against 0.122 ms, run only)."""
    a = t
    b = t + h
    fa = g_a
    fb = g_b
    side = 0
    for it in range(_events.LOCATE_MAX_ITER):
        if _events.bracket_done(a, b, xtol):
            break
        s = _events.bracket_trial(a, b, fa, fb, it, xtol)
        _dense(meth, t, h, x, x1, K, B, s, xs)
        _sf.guards(fn, s, xs, sig, p, modes, g)
        a, b, fa, fb, side = _events.bracket_update(a, b, fa, fb, side, s, g[i])
    return b


@njit_borrowed(inline="always")
def _tol(t):
    return 1e-12 * max(1.0, abs(t))


@njit_borrowed
def _log(ev_t, ev_i, ist, t, index, kind, direction):
    n = ist[I_EVENTS]
    if n < ev_t.size:
        ev_t[n] = t
        ev_i[n, 0] = index
        ev_i[n, 1] = kind
        ev_i[n, 2] = direction
        ist[I_EVENTS] = n + 1
    else:
        ist[I_OVERFLOW] += 1


@njit_borrowed
def _row(fn, t, x, tbuf, buf, ist, s_idx, x_idx, sig, p, modes):
    """Record the outputs at (t, x) as the next row; False if something is not finite."""
    r = ist[I_ROWS]
    ok = _sf.record(fn, t, x, sig, p, modes, s_idx, x_idx, buf, r)
    tbuf[r] = t
    ist[I_ROWS] = r + 1
    return ok


@njit_borrowed
def _record_grid(fn, meth, t_a, t_b, t, h, x, x1, K, B, xs, tbuf, buf, ist, fst, s_idx,
                 x_idx, sig, p, modes):
    """Rows at the grid times in ``[t_a, t_b)`` of the step ``(t, x) -> (t + h, x1)``; a
    grid point at an event time is recorded after the event (signals are right-continuous)."""
    dt = fst[F_DT]
    t0 = fst[F_T0]
    k = ist[I_GRID]
    tk = t0 + k * dt
    while tk < t_b - _tol(t_b) and ist[I_ROWS] < tbuf.size:
        _dense(meth, t, h, x, x1, K, B, tk, xs)
        _row(fn, tk, xs, tbuf, buf, ist, s_idx, x_idx, sig, p, modes)
        k += 1
        tk = t0 + k * dt
    ist[I_GRID] = k


@njit_borrowed
def _settle(fn, t, x, G, g_dir, g_block, bmask, ev_t, ev_i, ist,
           hit, sig, p, modes):
    """Fire the crossings caused by a jump at an event instant.

    ``G[G_BEFORE]`` holds the guards just before the instant; a guard of a block not in
    ``bmask`` (blocks whose own event changed their mode, and so their guard functions) that
    is on the other side now fires. Repeats until nothing more fires; returns 0 or
    ``FAIL_SETTLE``.
    """
    ng = ist[I_NG]
    if ng == 0:
        return 0
    for _ in range(MAX_EVENTS_AT_ONE_TIME):
        # the callers (and the end of each round) ran INITIALIZE: sig holds (t, x)'s outputs
        _sf.guards_at_sig(fn, t, x, sig, p, modes, G[G_TMP])
        nh = _events.crossings(G[G_BEFORE, :ng], G[G_TMP, :ng], g_dir, G[G_NONE, :ng], hit)
        m = 0
        for j in range(nh):
            if bmask[g_block[hit[j]]] == 0:
                hit[m] = hit[j]
                m += 1
        if m == 0:
            return 0
        for j in range(m):
            i = hit[j]
            d = math.copysign(1.0, G[G_TMP, i] - G[G_BEFORE, i]) \
                if G[G_TMP, i] != G[G_BEFORE, i] else 1.0
            _sf.apply_event(fn, t, x, sig, p, modes, i, d)
            _log(ev_t, ev_i, ist, t, i, KIND_STATE, int(d))
            G[G_FIRED, i] = d
        for j in range(m):
            bmask[g_block[hit[j]]] = 1
        _sf.initialize(fn, t, x, sig, p, modes)
        _sf.guards_at_sig(fn, t, x, sig, p, modes, G[G_BEFORE])
    return FAIL_SETTLE


@njit_borrowed
def _fire_due(fn, t, x, G,
             g_dir, g_block, timed_block, fired, bmask, ev_t, ev_i, ist, hit, sig, p, modes):
    """Apply every time event due at ``t`` (then settle); returns 0 or a failure code."""
    ng = ist[I_NG]
    tol = _tol(t)
    if ng:      # the guards before the instant; sig: the outputs of (t, x)
        _sf.guards(fn, t, x, sig, p, modes, G[G_BEFORE])
    else:
        _sf.outputs(fn, t, x, sig, p, modes)
    bmask[:] = 0
    rounds = 0
    while _sf.next_time(fn, t, p, modes) <= t + tol:
        fired[:] = 0
        # sig holds the outputs of (t, x): from above, then from INITIALIZE
        _sf.time_events(fn, t, x, sig, p, modes, tol, fired)
        n = 0
        for k in range(timed_block.size):
            if fired[k]:
                _log(ev_t, ev_i, ist, t, k, KIND_TIME, 0)
                bmask[timed_block[k]] = 1
                n += 1
        ist[I_TIMED] += n
        _sf.initialize(fn, t, x, sig, p, modes)
        rounds += 1
        if rounds > MAX_EVENTS_AT_ONE_TIME or n == 0:
            return FAIL_TIME_EVENTS
    if rounds:
        return _settle(fn, t, x, G, g_dir, g_block, bmask, ev_t,
                      ev_i, ist, hit, sig, p, modes)
    return 0


def _advance(meth, fn, t, t_seg, x, K, x1, JW, jpat, B, ist, fst, sig, p, modes):
    """One accepted step of the method ``meth`` from ``(t, x)``; see
    :func:`_advance_dp54`, :func:`_advance_ros34pw2` and :func:`_advance_ndf` (compiled for
    the method alone when ``meth`` is a compile-time constant, see :func:`_dense`)."""
    if meth == METHOD_NDF:
        return _advance_ndf(fn, t, t_seg, x, K, x1, JW, jpat, B, ist, fst, sig, p, modes)
    if meth == METHOD_ROS34PW2:
        return _advance_ros34pw2(fn, t, t_seg, x, K, x1, JW, jpat, ist, fst, sig, p, modes)
    return _advance_dp54(fn, t, t_seg, x, K, x1, ist, fst, sig, p, modes)


def _advance_by_dp54(meth, fn, t, t_seg, x, K, x1, JW, jpat, B, ist, fst, sig, p, modes):
    return _advance_dp54(fn, t, t_seg, x, K, x1, ist, fst, sig, p, modes)


def _advance_by_ros34pw2(meth, fn, t, t_seg, x, K, x1, JW, jpat, B, ist, fst, sig, p,
                         modes):
    return _advance_ros34pw2(fn, t, t_seg, x, K, x1, JW, jpat, ist, fst, sig, p, modes)


def _advance_by_ndf(meth, fn, t, t_seg, x, K, x1, JW, jpat, B, ist, fst, sig, p, modes):
    return _advance_ndf(fn, t, t_seg, x, K, x1, JW, jpat, B, ist, fst, sig, p, modes)


@for_method(_advance)
def _advance_of(meth, fn, t, t_seg, x, K, x1, JW, jpat, B, ist, fst, sig, p, modes):
    return literal_method(meth, (_advance_by_dp54, _advance_by_ros34pw2, _advance_by_ndf),
                          _advance)


@njit_borrowed
def _jacobian(fn, t, x, K, J, jpat, ist, sig, p, modes):
    """``J`` = the finite-difference Jacobian at ``(t, x)`` (``K[0] = f(t, x)``), one
    evaluation per column group (see :mod:`spidersim.solver.rosenbrock`); or, when
    ``jpat`` says so, the system's analytic one (one call, counted as one evaluation: it
    evaluates the outputs; :mod:`spidersim.diagram.jacobian`)."""
    if _ros.analytic(jpat) and _sf.jacobian(fn, t, x, sig, p, modes, J):
        ist[I_NFEV] += 1
        ist[I_NJAC] += 1
        ist[I_JAGE] = 0
        return
    y = K[_ros.ROW_TRIAL]
    fp = K[_ros.ROW_FPERT]
    d = K[_ros.ROW_SCRATCH]
    ng = _ros.n_groups(jpat)
    for g in range(ng):
        _ros.perturb_group(g, x, jpat, y, d)
        _sf.derivatives(fn, t, y, sig, p, modes, fp)
        _ros.store_group(g, K[0], fp, d, jpat, J)
    ist[I_NFEV] += ng
    ist[I_NJAC] += 1
    ist[I_JAGE] = 0


@njit_borrowed
def _step_ros34pw2(fn, t, x, h, K, x1, LU, rtol, atol, sig, p, modes):
    """One ROS34PW2 trial step (see :mod:`spidersim.solver.rosenbrock`) with ``LU`` the
    factors of ``I / (h gamma) - J``; returns the error norm."""
    piv = K[_ros.ROW_PIV]
    y = K[_ros.ROW_TRIAL]
    _copy(K[1], K[0])
    _lu_solve(LU, piv, K[1])
    for s in range(1, 4):
        _ros.stage_state(s, x, K, y)
        _sf.derivatives(fn, t + _ros.alpha_of(s) * h, y, sig, p, modes, K[s + 1])
        _ros.stage_rhs(s, K, h, K[s + 1])
        _lu_solve(LU, piv, K[s + 1])
    _ros.solution(x, K, x1)
    return _ros.error_norm(x, x1, K, rtol, atol)


@njit_borrowed
def _advance_ros34pw2(fn, t, t_seg, x, K, x1, JW, jpat, ist, fst, sig, p, modes):
    """One accepted ROS34PW2 step from ``(t, x)`` (``K[0] = f(t, x)``), never past
    ``t_seg``; returns ``(h, factor)`` as :func:`_advance_dp54` and leaves
    ``f(t + h, x1)`` in ``K[ROW_END]``.

    The Jacobian ``JW[0]`` is computed when it is marked stale (``ist[I_JAGE] < 0``: a new
    segment, i.e. the start or after an event), after ``fst[F_JAC_MAX_AGE]`` accepted
    steps, and after ``fst[F_JAC_REJECTIONS]`` consecutive rejections of this step unless it
    was computed at this step's start. The LU factors ``JW[1]`` of ``I / (h gamma) - J`` are
    reused while ``h`` (``fst[F_HLU]``) and ``J`` are unchanged; to make that happen, a
    step-size factor in ``[1, fst[F_HOLD_MAX]]`` is taken as 1.
    """
    rtol = fst[F_RTOL]
    atol = fst[F_ATOL]
    J = JW[0]
    LU = JW[1]
    h_min = 10.0 * (np.nextafter(t, math.inf) - t)
    h = min(fst[F_H], fst[F_MAXSTEP])
    if h < h_min:
        h = h_min
    if ist[I_JAGE] < 0 or ist[I_JAGE] >= fst[F_JAC_MAX_AGE]:
        _jacobian(fn, t, x, K, J, jpat, ist, sig, p, modes)
        fst[F_HLU] = 0.0
    rejected = False
    n_rej = 0
    while True:
        if h < h_min:
            return 0.0, 1.0
        if t + h > t_seg:
            h = t_seg - t
        ok = True
        if h != fst[F_HLU]:
            ok = _ros.factor_matrix(J, LU, K[_ros.ROW_PIV], h)
            ist[I_NLU] += 1
            fst[F_HLU] = h if ok else 0.0
        err = math.inf
        if ok:
            err = _step_ros34pw2(fn, t, x, h, K, x1, LU, rtol, atol, sig, p, modes)
            ist[I_NFEV] += 3
        if err <= 1.0:
            _sf.derivatives(fn, t + h, x1, sig, p, modes, K[_ros.ROW_END])
            ist[I_NFEV] += 1
            ist[I_JAGE] += 1
            fac = _ros.factor(err, rejected)
            if 1.0 <= fac <= fst[F_HOLD_MAX]:
                fac = 1.0
            return h, fac
        n_rej += 1
        if ist[I_JAGE] > 0 and n_rej >= fst[F_JAC_REJECTIONS]:   # an older Jacobian
            _jacobian(fn, t, x, K, J, jpat, ist, sig, p, modes)
            fst[F_HLU] = 0.0
        h *= _ros.factor(err, rejected)
        rejected = True
        ist[I_REJECTED] += 1


@njit_borrowed
def _advance_ndf(fn, t, t_seg, x, K, x1, JW, jpat, B, ist, fst, sig, p, modes):
    """One accepted step of the variable-order NDF method (:mod:`spidersim.solver.bdf`)
    from ``(t, x)`` (``K[0] = f(t, x)``), never past ``t_seg`` nor ``fst[F_HCAP]``; returns
    ``(h, 1.0)`` (the method keeps its own next step size) and leaves ``f(t + h, x1)`` in
    ``K[ROW_END]``.

    At a segment start (``ist[I_JAGE] == -1``: the start, after an event) the history is
    restarted at order 1 with the step ``fst[F_H]`` and the Jacobian marked stale (the
    event may have changed the equations); ``-2`` (a step retried shorter, see
    :func:`spidersim.solver.events.left_zero_unseen`) restarts the history only; otherwise the method's own Jacobian reuse
    applies (recomputed only when Newton fails with an old one).
    """
    V, iw, fw = B[0], B[1], B[2]
    if ist[I_JAGE] < 0:
        _bdf.restart(t, x, K[0], fst[F_H], V, JW, iw, fw)
        if ist[I_JAGE] == -1:          # -2: a retried step, the equations are the same
            _bdf.invalidate_jacobian(iw)
        ist[I_JAGE] = 0
    nfev, njac, nlu = iw[_bdf.I_NFEV], iw[_bdf.I_NJAC], iw[_bdf.I_NLU]
    nrej = iw[_bdf.I_NREJECT] + iw[_bdf.I_NNEWTON]
    h = _bdf.advance(fn, t, t_seg, x1, K[_ros.ROW_END], fst[F_RTOL], fst[F_ATOL],
                     fst[F_HCAP], V, JW, iw, fw, jpat, sig, p, modes)
    ist[I_NFEV] += iw[_bdf.I_NFEV] - nfev
    ist[I_NJAC] += iw[_bdf.I_NJAC] - njac
    ist[I_NLU] += iw[_bdf.I_NLU] - nlu
    ist[I_REJECTED] += iw[_bdf.I_NREJECT] + iw[_bdf.I_NNEWTON] - nrej
    return h, 1.0


@njit_borrowed(inline="always")
def _advance_dp54(fn, t, t_seg, x, K, x1, ist, fst, sig, p, modes):
    """One accepted step from ``(t, x)`` (``K[0] = f(t, x)``), never past ``t_seg``.

    Returns ``(h, factor)``: the step taken (``x1``, ``K`` hold its end state and stages)
    and the factor for the next one; ``h = 0`` when the step size fell below the spacing of
    floating-point numbers at ``t`` (``FAIL_SMALL_STEP``).
    """
    rtol = fst[F_RTOL]
    atol = fst[F_ATOL]
    h_min = 10.0 * (np.nextafter(t, math.inf) - t)
    h = min(fst[F_H], fst[F_MAXSTEP])
    if h < h_min:
        h = h_min
    rejected = False
    while True:
        if h < h_min:
            return 0.0, 1.0
        if t + h > t_seg:              # never past the segment end (as SciPy's t_bound)
            h = t_seg - t
        err = _step(fn, t, x, h, K, x1, rtol, atol, sig, p, modes)
        ist[I_NFEV] += 6
        if err <= 1.0:
            return h, _dp54.factor(err, rejected)
        h *= _dp54.factor(err, rejected)
        rejected = True
        ist[I_REJECTED] += 1


@njit_borrowed(inline="always")
def _state_events(fn, meth, t, h, x, x1, K, B, xs, G, g_dir,
                 g_block, bmask, chat, hit, nh, tbuf, buf, ev_t, ev_i, ist, fst, s_idx,
                 x_idx, sig, p, modes):
    """Locate the crossings ``hit[:nh]`` of the step ``(t, x) -> (t + h, x1)``, apply the
    earliest ones at ``t_ev`` (state into ``xs``); returns ``(t_ev, code)``. Inlined into
    :func:`_event_in_step`, its one caller."""
    ng = ist[I_NG]
    t_end_step = t + h
    xtol = 1e-13 * max(1.0, abs(t_end_step))
    t_ev = t_end_step
    for j in range(nh):
        i = hit[j]
        if G[G_OLD, i] == 0.0:           # left zero at the start of the step
            ti = t
        else:
            ti = _locate(fn, meth, i, G[G_OLD, i], G[G_NEW, i], t, h, x, x1, K, B, xs,
                         G[G_TMP], xtol, sig, p, modes)
        G[G_TIMES, j] = ti
        t_ev = min(t_ev, ti)
    # crossings located within 2 xtol of the earliest, or of one already in the group
    # (chained), are one instant: applied together at the latest of them, where every one
    # of them has crossed. Applied at the earliest, a guard located a hair later was still
    # on its old side and fired again; grouped without chaining, a guard just beyond the
    # window could have crossed by the latest time and was never fired
    for _ in range(nh - 1):              # at most nh - 1 extensions (none for one crossing)
        grow = False
        for j in range(nh):
            if t_ev < G[G_TIMES, j] <= t_ev + 2 * xtol:
                t_ev = G[G_TIMES, j]
                grow = True
        if not grow:
            break
    if t_ev < t_end_step:
        _dense(meth, t, h, x, x1, K, B, t_ev, xs)
    else:
        _copy(xs, x1)
    if fst[F_DT] > 0.0:
        _grid_to(fn, meth, t, t_ev, t, h, x, x1, K, B, tbuf, buf, ist, fst, s_idx, x_idx,
                 sig, p, modes)
    else:
        _row(fn, t_ev, xs, tbuf, buf, ist, s_idx, x_idx, sig, p, modes)
    _sf.guards(fn, t_ev, xs, sig, p, modes, G[G_BEFORE])
    bmask[:] = 0
    G[G_FIRED, :ng] = 0.0
    window = fst[F_CHATTER_WINDOW]
    for j in range(nh):
        if G[G_TIMES, j] > t_ev:
            continue
        i = hit[j]
        d = math.copysign(1.0, G[G_NEW, i] - G[G_OLD, i]) \
            if G[G_NEW, i] != G[G_OLD, i] else 1.0
        _sf.apply_event(fn, t_ev, xs, sig, p, modes, i, d)
        _log(ev_t, ev_i, ist, t_ev, i, KIND_STATE, int(d))
        G[G_FIRED, i] = d
        b = g_block[i]
        c = int(chat[b, CHATTER_COUNT])
        if c >= CHATTER_COUNT - 1:      # the 50th most recent event of this block
            oldest = chat[b, (c + 1) % CHATTER_COUNT]
            if t_ev - oldest <= window:
                ist[I_BLOCK] = i
                fst[F_TFAIL] = t_ev - oldest
                _row(fn, t_ev, xs, tbuf, buf, ist, s_idx, x_idx, sig, p, modes)
                return t_ev, FAIL_CHATTER
        chat[b, c % CHATTER_COUNT] = t_ev
        chat[b, CHATTER_COUNT] = c + 1
    for j in range(nh):
        if G[G_TIMES, j] <= t_ev:
            bmask[g_block[hit[j]]] = 1
    _sf.initialize(fn, t_ev, xs, sig, p, modes)
    code = _settle(fn, t_ev, xs, G, g_dir, g_block, bmask, ev_t,
                  ev_i, ist, hit, sig, p, modes)
    for i in range(ng):                  # blocks that fired: their guards must leave zero
        if bmask[g_block[i]]:            # (a guard that fired may turn back at once)
            G[G_ARMED, i] = _events.rearm_after(G[G_FIRED, i])
    return t_ev, code


@njit_borrowed
def _grid_to(fn, meth, t_a, t_b, t, h, x, x1, K, B, tbuf, buf, ist, fst, s_idx, x_idx, sig,
             p, modes):
    xs = K[_dp54.ROW_SCRATCH]
    _record_grid(fn, meth, t_a, t_b, t, h, x, x1, K, B, xs, tbuf, buf, ist, fst, s_idx,
                 x_idx, sig, p, modes)


@njit_borrowed
def _start(fn, t, x, K, xs, G, g_dir, g_block, timed_block, fired, bmask, hit, tbuf, buf,
           ev_t, ev_i, ist, s_idx, x_idx, sig, p, modes):
    """The start of a run: modes made consistent, time events due at ``t`` fired, the first
    row, ``K[0] = f(t, x)`` and the guards; returns 0 or a failure code."""
    ng = ist[I_NG]
    _sf.initialize(fn, t, x, sig, p, modes)
    if _sf.next_time(fn, t, p, modes) <= t + _tol(t):
        code = _fire_due(fn, t, x, G, g_dir, g_block, timed_block, fired, bmask,
                         ev_t, ev_i, ist, hit, sig, p, modes)
        if code:
            return code
    if not _row(fn, t, x, tbuf, buf, ist, s_idx, x_idx, sig, p, modes):
        _copy(xs, x)
        return FAIL_START
    ist[I_GRID] = 1
    _sf.derivatives(fn, t, x, sig, p, modes, K[0])
    ist[I_NFEV] += 1
    if ng:
        _sf.guards(fn, t, x, sig, p, modes, G[G_OLD])
    ist[I_STARTED] = 1
    ist[I_FRESH] = 1
    return 0


@njit_borrowed
def _segment_start(fn, meth, t, t_seg, x, K, B, ist, fst, sig, p, modes):
    """A new segment (the start, after an event or time event): the first step size
    (``fst[F_FIRST]``, or the method's rule from ``K[0] = f(t, x)``) and a stale Jacobian
    (modes may have changed the equations)."""
    ist[I_SEGMENTS] += 1
    if fst[F_FIRST] > 0.0:
        fst[F_H] = min(fst[F_FIRST], t_seg - t)
    else:
        fst[F_H] = _method_first_step(meth, fn, t, x, K, B, min(t_seg - t, fst[F_MAXSTEP]),
                                      fst[F_RTOL], fst[F_ATOL], sig, p, modes)
        ist[I_NFEV] += 1
    ist[I_FRESH] = 0
    ist[I_JAGE] = -1


def _method_first_step(meth, fn, t, x, K, B, span, rtol, atol, sig, p, modes):
    """The first step size of a segment by the method's rule (one evaluation of ``f``):
    the NDF method's own (order 1, :func:`.bdf.first_step`), else :func:`_first_step`."""
    if meth == METHOD_NDF:
        return _bdf.first_step(fn, t, x, K[0], span, rtol, atol, B[0], sig, p, modes)
    return _first_step(fn, t, x, K[0], span, rtol, atol, K, sig, p, modes)


def _first_step_runge_kutta(meth, fn, t, x, K, B, span, rtol, atol, sig, p, modes):
    return _first_step(fn, t, x, K[0], span, rtol, atol, K, sig, p, modes)


def _first_step_ndf(meth, fn, t, x, K, B, span, rtol, atol, sig, p, modes):
    return _bdf.first_step(fn, t, x, K[0], span, rtol, atol, B[0], sig, p, modes)


@for_method(_method_first_step)
def _method_first_step_of(meth, fn, t, x, K, B, span, rtol, atol, sig, p, modes):
    return literal_method(meth, (_first_step_runge_kutta, _first_step_runge_kutta,
                                 _first_step_ndf), _method_first_step)


@njit_borrowed
def _unseen_return(fn, t, h, t_new, x, x1, K, xs, G, g_dir, ng, sig, p, modes):
    """The guard that left zero and returned unseen in the step ``(t, x) -> (t_new, x1)``,
    or -1 (:func:`spidersim.solver.events.left_zero_unseen`). The probe is a short Euler
    step along ``f(t, x) = K[0]`` (the start's own direction, not the method's
    interpolant) into ``G[G_TMP]``; ``sig`` is left at the step end."""
    if not _events.zero_start_candidates(G[G_OLD, :ng], G[G_NEW, :ng], g_dir,
                                         G[G_ARMED, :ng]):
        return -1
    dt_probe = _events.UNSEEN_PROBE * h
    for j in range(x.size):
        xs[j] = x[j] + dt_probe * K[0, j]
    _sf.guards(fn, t + dt_probe, xs, sig, p, modes, G[G_TMP])
    _sf.outputs(fn, t_new, x1, sig, p, modes)
    return _events.left_zero_unseen(G[G_OLD, :ng], G[G_NEW, :ng], g_dir, G[G_ARMED, :ng],
                                    G[G_TMP, :ng])


@njit_borrowed
def _resume_after_event(fn, t, x, K, G, grid, tbuf, buf, ist, s_idx, x_idx, sig, p, modes):
    """Go on from the state ``x`` after the events at ``t``: its row (without a grid),
    ``K[0] = f(t, x)``, the guards, a new segment; False when the row is not finite."""
    if not grid:
        if not _row(fn, t, x, tbuf, buf, ist, s_idx, x_idx, sig, p, modes):
            return False
    _sf.derivatives(fn, t, x, sig, p, modes, K[0])
    ist[I_NFEV] += 1
    _sf.guards_at_sig(fn, t, x, sig, p, modes, G[G_OLD])     # sig: the outputs of (t, x)
    ist[I_FRESH] = 1
    return True


@njit_borrowed
def _time_events_now(fn, t, x, K, G, g_dir, g_block, timed_block, fired, bmask, hit, grid,
                     tbuf, buf, ev_t, ev_i, ist, fst, s_idx, x_idx, sig, p, modes):
    """Fire the time events due at ``t`` (:func:`_fire_due`), record the row after them
    (on a grid only at a grid time), ``K[0] = f(t, x)``, the guards, a new segment; returns
    0 or a failure code."""
    code = _fire_due(fn, t, x, G, g_dir, g_block, timed_block, fired, bmask,
                     ev_t, ev_i, ist, hit, sig, p, modes)
    if code:
        return code
    if grid:
        if abs(fst[F_T0] + ist[I_GRID] * fst[F_DT] - t) <= _tol(t):
            _row(fn, t, x, tbuf, buf, ist, s_idx, x_idx, sig, p, modes)
            ist[I_GRID] += 1
    else:
        _row(fn, t, x, tbuf, buf, ist, s_idx, x_idx, sig, p, modes)
    _sf.derivatives(fn, t, x, sig, p, modes, K[0])
    ist[I_NFEV] += 1
    if ist[I_NG]:
        _sf.guards_at_sig(fn, t, x, sig, p, modes, G[G_OLD])  # sig: the outputs of (t, x)
    ist[I_FRESH] = 1
    return 0


@njit_borrowed(inline="always")
def _pause_code(t, ev_reserve, pause_steps, tbuf, ev_t, ist, fst):
    """``ROWS_FULL``, ``EVENTS_FULL`` or ``PAUSE`` when the loop must hand back to the
    caller before the next step (``fst[F_T] = t``), else ``DONE`` (0: go on)."""
    code = DONE
    if ist[I_ROWS] + ROW_RESERVE > tbuf.size:
        code = ROWS_FULL
    elif ist[I_EVENTS] + ev_reserve > ev_t.size:
        code = EVENTS_FULL
    elif ist[I_NEW_STEPS] >= pause_steps:
        code = PAUSE
    if code != DONE:
        fst[F_T] = t
    return code


@njit_borrowed(inline="always")
def _cap_for_rows(grid, tbuf, ist, fst):
    """Step cap of this step: ``max_step``, and on an output grid the rows one step may
    write must fit in the buffer."""
    fst[F_HCAP] = fst[F_MAXSTEP]
    if grid:
        room = tbuf.size - ist[I_ROWS] - ROW_RESERVE
        fst[F_H] = min(fst[F_H], max(room, 1) * fst[F_DT])
        fst[F_HCAP] = min(fst[F_HCAP], max(room, 1) * fst[F_DT])


@njit_borrowed(inline="always")
def _stalled(h, t_new, ist):
    """True after ``STALL_COUNT`` steps in a row shorter than ``STALL_STEP`` (relative)."""
    if h < STALL_STEP * max(1.0, abs(t_new)):
        ist[I_TINY] += 1
        return ist[I_TINY] >= STALL_COUNT
    ist[I_TINY] = 0
    return False


@njit_borrowed(inline="always")
def _guards_at_step_end(fn, meth, t_new, x1, grid, tbuf, buf, ist, G, s_idx, x_idx, sig, p,
                        modes):
    """``G[G_NEW]`` = the guards at the step's end ``(t_new, x1)``; without an output grid
    the step's row is recorded from the same evaluation. Returns False when the row is not
    finite.

    DP54's last stage and NDF's ``f1`` were evaluated at ``(t_new, x1)``: ``sig`` holds
    its outputs, so the guards and the row are taken from it without evaluating the system
    again (one evaluation of seven per DP54 step); ROS34PW2's last evaluation was
    elsewhere, so it evaluates the outputs."""
    reuse = meth != METHOD_ROS34PW2
    if grid:
        if reuse:
            _sf.guards_at_sig(fn, t_new, x1, sig, p, modes, G[G_NEW])
        else:
            _sf.guards(fn, t_new, x1, sig, p, modes, G[G_NEW])
        return True
    row0 = ist[I_ROWS]
    if reuse:
        _sf.guards_at_sig(fn, t_new, x1, sig, p, modes, G[G_NEW])
        ok = _sf.copy_row(x1, sig, s_idx, x_idx, buf, row0)
    else:
        ok = _sf.record_guards(fn, t_new, x1, sig, p, modes, s_idx, x_idx, buf, row0,
                               G[G_NEW])
    tbuf[row0] = t_new
    ist[I_ROWS] = row0 + 1
    return ok


@njit_borrowed(inline="always")
def _retry_unseen(meth, i_unseen, h, t_new, row0, ist, fst):
    """After a step in which guard ``i_unseen`` left zero and returned unseen: ``FAIL_ZENO``
    when the step is already at the time resolution, else the step is undone (its row
    dropped, counted as rejected) to be retried eight times shorter from ``(t, x)``
    (``K[0]`` is intact; NDF restarts its history and keeps its Jacobian); returns 0."""
    ist[I_ROWS] = row0
    if h <= _events.UNSEEN_STEP * max(1.0, abs(t_new)):
        ist[I_BLOCK] = i_unseen             # events faster than the time resolution
        return FAIL_ZENO
    ist[I_STEPS] -= 1
    ist[I_NEW_STEPS] -= 1
    ist[I_REJECTED] += 1
    fst[F_H] = 0.125 * h
    if meth == METHOD_NDF:
        ist[I_JAGE] = -2
    return 0


@njit_borrowed(inline="always")
def _accept_guards(G, ng):
    """The step is accepted: its end's guards become the old ones; a guard is re-armed once
    it has left zero."""
    for i in range(ng):
        G[G_OLD, i] = G[G_NEW, i]
        if G[G_NEW, i] != 0.0:
            G[G_ARMED, i] = 1.0


@njit_borrowed(inline="always")
def _record_step(fn, meth, t, t_new, h, x, x1, K, B, tbuf, buf, ist, fst, s_idx, x_idx, sig,
                 p, modes):
    """On an output grid, the rows at the grid times the step passed (from its dense
    output); False when the step's end is not finite."""
    for i in range(x1.size):
        if not math.isfinite(x1[i]):
            return False
    _grid_to(fn, meth, t, t_new, t, h, x, x1, K, B, tbuf, buf, ist, fst, s_idx, x_idx, sig,
             p, modes)
    return True


#: what a step of :func:`_one_step` ended in (negative: not return codes of the loop)
STEP_ON, STEP_EVENT, STEP_RETRY = -1, -2, -3


@njit_borrowed(inline="always")
def _stop(code, t, y, xs, fst):
    """A failure at ``(t, y)``: ``fst[F_T] = t``, ``xs = y`` (the offending state); returns
    ``code``."""
    fst[F_T] = t
    _copy(xs, y)
    return code


@njit_borrowed(inline="always")
def _accept_step(h, fac, t_new, t_seg, x, x1, K, fst):
    """The step to ``(t_new, x1)`` is taken: the next step size (not shrunk by a segment
    end the step was cut to), ``x = x1``, ``K[0] = f(t_new, x1)`` (left in ``K[6]`` by every
    method), ``fst[F_T] = t_new``."""
    fst[F_H] = h * fac if t_new < t_seg else max(fst[F_H], h * fac)
    _copy(x, x1)
    _copy(K[0], K[6])
    fst[F_T] = t_new


@njit_borrowed(inline="always")
def _event_in_step(fn, meth, t, h, nh, x, x1, K, B, xs, G, g_dir, g_block, bmask, chat, hit,
                   grid, tbuf, buf, ev_t, ev_i, ist, fst, s_idx, x_idx, sig, p, modes):
    """The step ``(t, x) -> (t + h, x1)`` crossed ``nh`` guards: the run goes on from the
    earliest event (:func:`_state_events`, :func:`_resume_after_event`), ``fst[F_T] = t_ev``;
    returns ``STEP_EVENT`` or a failure code. Inlined into the step, with
    :func:`_state_events` and :func:`_locate` inlined into it: as a call taking the method,
    the machine code numba loads from its cache reached the method's dense output through
    the run-time branch (the ball's 100 impacts, run only: 0.145 ms loaded from the cache
    against 0.118 ms just compiled; inlined 0.111-0.115 ms loaded, 0.121 ms compiled)."""
    t_ev, code = _state_events(fn, meth, t, h, x, x1, K, B, xs, G, g_dir, g_block, bmask,
                               chat, hit, nh, tbuf, buf, ev_t, ev_i, ist, fst, s_idx, x_idx,
                               sig, p, modes)
    fst[F_T] = t_ev
    if code:
        return code
    _copy(x, xs)
    if not _resume_after_event(fn, t_ev, x, K, G, grid, tbuf, buf, ist, s_idx, x_idx, sig, p,
                               modes):
        return FAIL_NONFINITE
    return STEP_EVENT


@njit_borrowed(inline="always")
def _step_events(fn, meth, ng, t, h, t_new, row0, x, x1, K, B, xs, G, g_dir, g_block, bmask,
                 chat, hit, grid, tbuf, buf, ev_t, ev_i, ist, fst, s_idx, x_idx, sig, p,
                 modes):
    """The guards of the step ``(t, x) -> (t_new, x1)`` (its row recorded with them without
    a grid): a guard that returned unseen has the step retried shorter, a crossing the run
    go on from the event, else the step's guards are accepted. Returns ``(code, ok)``:
    ``code`` 0 (no event), ``STEP_RETRY``, ``STEP_EVENT`` or a failure code; ``ok`` False
    when the step's row is not finite."""
    ok = _guards_at_step_end(fn, meth, t_new, x1, grid, tbuf, buf, ist, G, s_idx, x_idx, sig,
                             p, modes)
    i_unseen = _unseen_return(fn, t, h, t_new, x, x1, K, xs, G, g_dir, ng, sig, p, modes)
    if i_unseen >= 0:
        if _retry_unseen(meth, i_unseen, h, t_new, row0, ist, fst):
            return _stop(FAIL_ZENO, t, x, xs, fst), ok
        return STEP_RETRY, ok
    nh = _events.crossings(G[G_OLD, :ng], G[G_NEW, :ng], g_dir, G[G_ARMED, :ng], hit)
    if nh:
        ist[I_ROWS] = row0               # the step's end lies beyond the event
        return _event_in_step(fn, meth, t, h, nh, x, x1, K, B, xs, G, g_dir, g_block, bmask,
                              chat, hit, grid, tbuf, buf, ev_t, ev_i, ist, fst, s_idx, x_idx,
                              sig, p, modes), ok
    _accept_guards(G, ng)
    return 0, ok


@njit_borrowed(inline="always")
def _one_step(fn, meth, ng, t, t_seg, x, K, x1, xs, JW, jpat, B, G, g_dir, g_block, bmask,
              hit, chat, grid, tbuf, buf, ev_t, ev_i, ist, fst, s_idx, x_idx, sig, p, modes):
    """One step of the method ``meth`` from ``(t, x)`` towards ``t_seg``: a new segment's
    first step size, the step (:func:`_advance`), its guards and events
    (:func:`_step_events`) and rows; returns ``STEP_ON`` (taken, ``fst[F_T]`` its end),
    ``STEP_EVENT`` (the run goes on from an event at ``fst[F_T]``), ``STEP_RETRY`` or a
    failure code."""
    if ist[I_FRESH]:
        _segment_start(fn, meth, t, t_seg, x, K, B, ist, fst, sig, p, modes)
    _cap_for_rows(grid, tbuf, ist, fst)
    h, fac = _advance(meth, fn, t, t_seg, x, K, x1, JW, jpat, B, ist, fst, sig, p, modes)
    if h == 0.0:
        return _stop(FAIL_SMALL_STEP, t, x, xs, fst)
    ist[I_STEPS] += 1
    ist[I_NEW_STEPS] += 1
    t_new = t_seg if t + h >= t_seg else t + h
    if _stalled(h, t_new, ist):
        return _stop(FAIL_STALL, t_new, x1, xs, fst)
    ok = True
    row0 = ist[I_ROWS]
    if ng:
        code, ok = _step_events(fn, meth, ng, t, h, t_new, row0, x, x1, K, B, xs, G, g_dir,
                                g_block, bmask, chat, hit, grid, tbuf, buf, ev_t, ev_i, ist,
                                fst, s_idx, x_idx, sig, p, modes)
        if code:
            return code
    elif not grid:
        ok = _row(fn, t_new, x1, tbuf, buf, ist, s_idx, x_idx, sig, p, modes)
    if grid and ok:
        ok = _record_step(fn, meth, t, t_new, h, x, x1, K, B, tbuf, buf, ist, fst, s_idx,
                          x_idx, sig, p, modes)
    if not ok:
        return _stop(FAIL_NONFINITE, t_new, x1, xs, fst)
    _accept_step(h, fac, t_new, t_seg, x, x1, K, fst)
    return STEP_ON


@njit_borrowed(inline="always")
def _last_grid_row(fn, t_end, x, grid, tbuf, buf, ist, s_idx, x_idx, sig, p, modes):
    """On an output grid, the row at ``t_end`` unless the grid's last row is there."""
    if grid and (ist[I_ROWS] == 0 or tbuf[ist[I_ROWS] - 1] < t_end * (1 - 1e-12)):
        _row(fn, t_end, x, tbuf, buf, ist, s_idx, x_idx, sig, p, modes)


@njit_borrowed
def _run_loop(meth, fn, ist, fst, x, K, x1, xs, JW, jpat, B, G, g_dir, g_block, timed_block,
             fired, bmask, hit, chat, tbuf, buf, ev_t, ev_i, s_idx, x_idx, sig, p, modes,
             pause_steps):
    """Integrate from ``fst[F_T]`` to ``fst[F_TEND]`` with the method ``meth`` (a
    compile-time constant: see :func:`run_loop_dp54`); return a code (module constants).
    ``JW`` and ``jpat`` are the Jacobian work and pattern arrays of
    :mod:`spidersim.solver.rosenbrock` (size 0 for DP54).

    Resumable: on ``ROWS_FULL``, ``EVENTS_FULL`` and ``PAUSE`` every quantity needed to go
    on is in the arrays, and the caller calls again (with grown buffers). On a failure,
    ``fst[F_T]`` is the time reached and ``xs`` the offending state.
    """
    ng = ist[I_NG]
    t = fst[F_T]
    t_end = fst[F_TEND]
    grid = fst[F_DT] > 0.0
    ev_reserve = 4 * (ng + timed_block.size) + 64
    if ist[I_STARTED] == 0:
        code = _start(fn, t, x, K, xs, G, g_dir, g_block, timed_block, fired, bmask, hit,
                      tbuf, buf, ev_t, ev_i, ist, s_idx, x_idx, sig, p, modes)
        if code:
            return code
    ist[I_NEW_STEPS] = 0
    # the blocks' next time event depends on their parameters and modes only (contract,
    # blocks/base.py): asked again only after events, which alone change modes (one call
    # of the system function fewer per step)
    t_next = _sf.next_time(fn, t, p, modes)
    while True:                          # fst[F_T] == t here
        tol = _tol(t)
        if t >= t_end and t_next > t + tol:
            break
        code = _pause_code(t, ev_reserve, pause_steps, tbuf, ev_t, ist, fst)
        if code:
            return code
        if t_next <= t + tol:            # time events due now
            code = _time_events_now(fn, t, x, K, G, g_dir, g_block, timed_block, fired,
                                    bmask, hit, grid, tbuf, buf, ev_t, ev_i, ist, fst,
                                    s_idx, x_idx, sig, p, modes)
            if code:
                return _stop(code, t, x, xs, fst)
            t_next = _sf.next_time(fn, t, p, modes)
            continue
        code = _one_step(fn, meth, ng, t, min(t_next, t_end), x, K, x1, xs, JW, jpat, B, G,
                         g_dir, g_block, bmask, hit, chat, grid, tbuf, buf, ev_t, ev_i, ist,
                         fst, s_idx, x_idx, sig, p, modes)
        if code > 0:
            return code
        t = fst[F_T]
        if code == STEP_EVENT:
            t_next = _sf.next_time(fn, t, p, modes)
    _last_grid_row(fn, t_end, x, grid, tbuf, buf, ist, s_idx, x_idx, sig, p, modes)
    fst[F_T] = t
    return DONE


# The entries, one per method: each is compiled (or loaded from numba's cache) on its own,
# with its method a constant, so that only that method's code is typed and compiled
# (:func:`spidersim.solver._jit.for_method`); :mod:`.loop` calls the run's one. Three
# functions written out, not made by a factory: numba caches top-level functions only.

@njit_borrowed
def run_loop_dp54(fn, ist, fst, x, K, x1, xs, JW, jpat, B, G, g_dir, g_block,
                  timed_block, fired, bmask, hit, chat, tbuf, buf, ev_t, ev_i, s_idx, x_idx,
                  sig, p, modes, pause_steps):
    """:func:`_run_loop` with Dormand-Prince 5(4) (:mod:`.dp54`)."""
    return _run_loop(METHOD_DP54, fn, ist, fst, x, K, x1, xs, JW, jpat, B, G, g_dir, g_block,
                     timed_block, fired, bmask, hit, chat, tbuf, buf, ev_t, ev_i, s_idx,
                     x_idx, sig, p, modes, pause_steps)


@njit_borrowed
def run_loop_ros34pw2(fn, ist, fst, x, K, x1, xs, JW, jpat, B, G, g_dir, g_block,
                      timed_block, fired, bmask, hit, chat, tbuf, buf, ev_t, ev_i, s_idx, x_idx,
                      sig, p, modes, pause_steps):
    """:func:`_run_loop` with the Rosenbrock-W method ROS34PW2 (:mod:`.rosenbrock`)."""
    return _run_loop(METHOD_ROS34PW2, fn, ist, fst, x, K, x1, xs, JW, jpat, B, G, g_dir, g_block,
                     timed_block, fired, bmask, hit, chat, tbuf, buf, ev_t, ev_i, s_idx,
                     x_idx, sig, p, modes, pause_steps)


@njit_borrowed
def run_loop_ndf(fn, ist, fst, x, K, x1, xs, JW, jpat, B, G, g_dir, g_block,
                 timed_block, fired, bmask, hit, chat, tbuf, buf, ev_t, ev_i, s_idx, x_idx,
                 sig, p, modes, pause_steps):
    """:func:`_run_loop` with the variable-order NDF method (:mod:`.bdf`)."""
    return _run_loop(METHOD_NDF, fn, ist, fst, x, K, x1, xs, JW, jpat, B, G, g_dir, g_block,
                     timed_block, fired, bmask, hit, chat, tbuf, buf, ev_t, ev_i, s_idx,
                     x_idx, sig, p, modes, pause_steps)


#: the entry of each method, by its number (``ist[I_METHOD]``, :data:`.loop_state.METHODS`)
ENTRIES = (run_loop_dp54, run_loop_ros34pw2, run_loop_ndf)


def entry(method):
    """The entry of ``method`` (``DP54``, ``ROS34PW2``, ``NDF``; any other name, e.g. a SciPy
    method's, gives DP54's)."""
    return ENTRIES[METHODS.get(method, METHOD_DP54)]
