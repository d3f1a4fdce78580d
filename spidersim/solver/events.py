"""Zero crossings: which guards crossed over a step, and where (pure helpers).

A guard ``g_i(t, x)`` is a block's zero-crossing function; its event fires when ``g_i``
crosses zero in the block's direction (``+1`` rising, ``-1`` falling, ``0`` either). These
helpers are shared by the SciPy-stepper loop (:mod:`spidersim.solver.scipy_loop`) and the
compiled loop (:mod:`spidersim.solver.loop`) and are tested on plain arrays and functions.
"""
from __future__ import annotations

import numpy as np

from ._jit import njit, njit_borrowed

#: iterations of the bracketing root finder: after the first LOCATE_FREE_ITER the bracket at
#: least halves every third one (2**43 >= the widest step over the narrowest tolerance)
LOCATE_MAX_ITER = 200
LOCATE_FREE_ITER = 8

# the event rules both loops share
#: events (and rounds of time events) allowed at one instant before the run fails
MAX_EVENTS_AT_ONE_TIME = 1000
#: a run stalls when this many consecutive accepted steps are each shorter than
#: STALL_STEP * max(1, |t|): the solution is running into a singularity
STALL_COUNT = 500
STALL_STEP = 1e-10
#: the shortest run [s]: a thousand stall steps (a run shorter than STALL_STEP would be
#: reported as a stall)
MIN_SPAN = 1e-7
#: a step shorter than this times max(1, |t|) is not retried for a guard that left zero and
#: returned unseen (:func:`left_zero_unseen`): chattering; the probe of that test is taken at
#: this fraction of the step
UNSEEN_STEP = 1e-14
UNSEEN_PROBE = 1e-3
#: chattering: this many events of one block within max(1e-9, 1e-6 * span) s is an error
CHATTER_COUNT = 50


def zeno_message(block, name, t):
    """The error of a guard that returns unseen in steps shorter than ``UNSEEN_STEP``."""
    return (f"chattering: block '{block}' fires events ('{name}') faster than the time "
            f"resolution at t = {t:.9g} s (Zeno behaviour: its guard returns to the "
            f"firing side within a step of {UNSEEN_STEP * max(1.0, abs(t)):.3g} s); give the "
            f"block a rest mode or threshold, or stop the run earlier")


#: values of a guard's arming (the loops' ``armed`` arrays): a guard that starts a step
#: exactly at zero fires when it leaves zero to a side it is armed for. ARMED: either side
#: (the start, once the guard has been nonzero, and the other guards of a block whose event
#: has just fired: :func:`rearm_after`); DISARMED: neither (the settling of a jump at an
#: event instant, which compares the guards across the instant instead, and the default of
#: :func:`crossed`); ARMED_UP / ARMED_DOWN: only
#: back to the side it came from (the guard that fired, left on zero by its crossing: moving
#: on the way it crossed is the same crossing, turning back is a new one, as in a sliding
#: mode where the switched output drives the input straight back)
ARMED, DISARMED, ARMED_UP, ARMED_DOWN = 1.0, 0.0, 2.0, -2.0


#: a guard that has just fired and is left within this fraction of its values at the crossing
#: step's ends from zero *on the side it came from* is on zero (:func:`snap_band`): a guard
#: fed by an algebraic loop is only as exact as the loop's Newton tolerance, and the event
#: located a hair early left it there, to fire a second time a few ulps later
SNAP_BAND = 1e-9


@njit_borrowed
def snap_band(g_before, g_after):
    """The band of a guard that crossed from ``g_before`` to ``g_after``: signed, on the side
    it came from (see :data:`SNAP_BAND`; a guard that started on zero came from the side
    opposite ``g_after``)."""
    b = SNAP_BAND * max(abs(g_before), abs(g_after))
    side = g_before if g_before != 0.0 else -g_after    # from zero: the side it left
    if side > 0.0:
        return b
    if side < 0.0:
        return -b
    return 0.0


@njit_borrowed
def snapped(g, band):
    """``g`` taken as zero when it lies within the signed ``band`` (:func:`snap_band`), on
    the band's side."""
    if band > 0.0 and 0.0 < g <= band:
        return 0.0
    if band < 0.0 and band <= g < 0.0:
        return 0.0
    return g


@njit_borrowed
def rearm_after(direction_fired):
    """The arming of a guard of a block that has just fired: the guard that fired in
    ``direction_fired`` (+1 rising, -1 falling) back the way it came; the block's other
    guards (``direction_fired`` 0) armed: one the event left exactly on zero (a new guard
    of the new mode, such as a clamped PI's "leave" at the limit it has just reached) fires
    as soon as it moves to its firing side."""
    if direction_fired > 0.0:
        return ARMED_DOWN
    if direction_fired < 0.0:
        return ARMED_UP
    return ARMED


@njit_borrowed
def leaves_armed(armed, b):
    """Whether a guard at zero with arming ``armed`` fires by leaving zero to ``b``'s side."""
    if armed == ARMED:
        return True
    if b > 0.0:
        return armed == ARMED_UP
    if b < 0.0:
        return armed == ARMED_DOWN
    return False


@njit_borrowed
def crossings(g_old, g_new, direction, armed, out):
    """Indices of the guards that crossed into ``out`` (ascending); returns how many.

    A guard that starts the step exactly at zero crosses when it leaves zero in the allowed
    direction to a side it is armed for (:data:`ARMED`: a guard zeroed by its own block's
    event has to leave zero before it can fire again, except back the way it came).
    """
    k = 0
    for i in range(g_old.size):
        a, b, d = g_old[i], g_new[i], direction[i]
        z = a == 0.0 and leaves_armed(armed[i], b)
        up = (a < 0.0 and b >= 0.0) or (z and b > 0.0)
        down = (a > 0.0 and b <= 0.0) or (z and b < 0.0)
        if (d >= 0.0 and up) or (d <= 0.0 and down):
            out[k] = i
            k += 1
    return k


@njit_borrowed
def left_zero_unseen(g_old, g_new, direction, armed, g_probe):
    """The first guard that returned to its firing side unseen within a step, or -1.

    A guard exactly at zero at the step start that ends the step on its firing side
    without firing (:func:`leaves_armed` false: it had not left zero since its block's
    event) is a candidate: it may have left zero the other way and come
    back (a ball bouncing off the floor and landing again inside one step), a crossing that
    :func:`crossings` cannot see. ``g_probe`` holds the guards a short Euler step along
    ``f(t, x)`` after the start: a candidate that is there on the other side of zero did
    leave and return. (A candidate that went straight to its firing side, e.g. a saturation whose
    input keeps rising past the corner, did not.) Both loops retry such a step
    shorter; when it cannot be shortened any more (``UNSEEN_STEP``) the events come faster
    than the time resolution: chattering.
    """
    for i in range(g_old.size):
        b, d, q = g_new[i], direction[i], g_probe[i]
        if g_old[i] == 0.0 and not leaves_armed(armed[i], b) and b != 0.0 and (
                d == 0.0 or (b > 0.0) == (d > 0.0)) and q != 0.0 and (q > 0.0) != (b > 0.0):
            return i
    return -1


@njit_borrowed
def zero_start_candidates(g_old, g_new, direction, armed):
    """Whether any guard may have returned unseen (see :func:`left_zero_unseen`): the cheap
    test before the probe is evaluated."""
    for i in range(g_old.size):
        b, d = g_new[i], direction[i]
        if g_old[i] == 0.0 and not leaves_armed(armed[i], b) and b != 0.0 and (
                d == 0.0 or (b > 0.0) == (d > 0.0)):
            return True
    return False


def crossed(g_old, g_new, direction, armed=None):
    """Array of the guards that crossed zero in the allowed direction over a step (see
    :func:`crossings`); ``armed`` defaults to none armed."""
    if armed is None:
        armed = np.full(len(g_old), DISARMED)
    out = np.empty(len(g_old), dtype=np.int64)
    return out[:crossings(np.asarray(g_old, float), np.asarray(g_new, float),
                          np.asarray(direction, float), armed, out)]


def locate(gfun, t_a, t_b, g_a, xtol):
    """Time of the zero crossing of ``gfun`` in ``(t_a, t_b]``, on the far side.

    ``brentq`` brackets the root to ``xtol``; the returned time is the first bracket point
    where the guard has left the side it started on, so that the event is applied after
    the crossing and cannot fire twice.
    """
    from scipy.optimize import brentq
    g_b = gfun(t_b)
    if g_b == 0.0 or np.sign(g_b) == np.sign(g_a):
        return t_b
    g_a_now = gfun(t_a)
    if g_a_now == 0.0 or np.sign(g_a_now) == np.sign(g_b):
        # evaluated again, the guard is already across at t_a (a guard fed by an algebraic
        # loop can differ in the last digits from the value the step began with): the
        # crossing is at t_a, within round-off
        return t_a
    r = brentq(gfun, t_a, t_b, xtol=xtol, rtol=4 * np.finfo(float).eps)
    # the far side: a few nudges of xtol, then growing ones (a guard fed by an algebraic loop
    # solved to its tolerance from a warm start stays on its old side a little past the
    # root; falling back to t_b put such an event up to a whole step late)
    dr = xtol
    for k in range(LOCATE_MAX_ITER):
        g = gfun(r)
        if g == 0.0 or np.sign(g) != np.sign(g_a) or r >= t_b:
            return r
        r = min(t_b, r + dr)
        if k >= 7:
            dr *= 2.0
    return t_b


@njit_borrowed
def bracket_trial(a, b, fa, fb, it, xtol):
    """Next trial time inside the bracket ``[a, b]`` (``fa``, ``fb`` of opposite signs):
    regula falsi on the weighted end values of :func:`bracket_weight`; from iteration
    ``LOCATE_FREE_ITER`` on, a bisection every third iteration (the bracket at least halves
    every three, whatever the guard); the trial is kept ``xtol/2`` away from the ends, so a
    secant that has converged on one side closes the bracket with its next trial."""
    if fb == fa or (it >= LOCATE_FREE_ITER and (it - LOCATE_FREE_ITER) % 3 == 2):
        s = 0.5 * (a + b)
    else:
        s = b - fb * (b - a) / (fb - fa)
    lo = a + 0.5 * xtol
    hi = b - 0.5 * xtol
    if not (s > lo):
        s = lo
    if not (s < hi):
        s = hi
    return s


@njit_borrowed
def bracket_weight(f_new, f_old):
    """Anderson-Bjoerck weight of the bracket end kept twice in a row: the moving end went
    from ``f_old`` to ``f_new`` (same sign), the kept end's value is multiplied by
    ``m = 1 - f_new / f_old`` (``0.5``, the Illinois weight, when ``m <= 0``). Without it
    regula falsi converges from one side only and the bracket never closes.

    On the ball's parabolas this halves the iterations of the former Illinois weight with a
    bisection every third trial (5.5 against 11.6 on average, ``tools/bench_loop.py``)."""
    m = 1.0 - f_new / f_old
    return m if m > 0.0 else 0.5


@njit_borrowed
def bracket_done(a, b, xtol):
    """The bracket is as narrow as asked, or as floating point allows."""
    return b - a <= xtol or b - a <= 4e-16 * max(abs(a), abs(b))


@njit_borrowed
def bracket_update(a, b, fa, fb, side, s, fs):
    """The bracket after the trial ``(s, fs)``: ``s`` replaces the end of the same sign;
    the end kept for the second time in a row is weighted by :func:`bracket_weight`.
    ``side`` is ``-1`` when ``b`` moved last, ``1`` when ``a`` did (``0`` at the start).
    Returns ``(a, b, fa, fb, side)``."""
    if fs == 0.0 or (fs > 0.0) != (fa > 0.0):
        if side == -1:
            fa *= bracket_weight(fs, fb)
        return a, s, fa, fs, -1
    if side == 1:
        fb *= bracket_weight(fs, fa)
    return s, b, fs, fb, 1


def locate_on(gfun, a, b, fa, fb, xtol):
    """Crossing of ``gfun`` in ``(a, b]`` by the bracketing of :func:`bracket_trial`
    (reference implementation in Python of the compiled loop's location): returns the first
    point found on the far side, within ``xtol`` of the crossing."""
    side = 0
    for it in range(LOCATE_MAX_ITER):
        if bracket_done(a, b, xtol):
            break
        s = bracket_trial(a, b, fa, fb, it, xtol)
        a, b, fa, fb, side = bracket_update(a, b, fa, fb, side, s, gfun(s))
    return b
