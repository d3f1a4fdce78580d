"""Dormand-Prince 5(4): one step, its error estimate, dense output and the first step size.

Plain functions on preallocated arrays, compiled by numba when it is present and usable on
any right-hand side of the form ``fun(t, x, sig, p, modes, xdot)`` (the generated module's
``derivatives``; ``sig``, ``p``, ``modes`` are passed through untouched).

Method (Dormand & Prince 1980; Hairer, Norsett & Wanner, *Solving ODEs I*, II.5)
-------------------------------------------------------------------------------
Seven stages ``k_i = f(t + c_i h, x + h sum_j a_ij k_j)``; the fifth-order solution
``x1 = x + h sum_i b_i k_i`` is propagated (local extrapolation) and its last stage is
``f(t + h, x1)`` (first same as last: six new evaluations per accepted step). The local error
estimate is ``h sum_i e_i k_i`` with ``e = b - b_hat`` (``b_hat`` the embedded fourth-order
weights), measured as

    err = sqrt(mean((h sum_i e_i k_i / sc)^2)),  sc = atol + rtol max(|x|, |x1|)

and the step is accepted when ``err <= 1``. The new step is ``h * clip(0.9 err^(-1/5), 0.2, 10)``
(no growth right after a rejection): the controller of SciPy's ``RK45``, so that both paths
take comparable steps for the same tolerances.

Dense output is Hairer's fourth-order continuous extension: with ``theta = (s - t)/h``,

    x(s) = r1 + theta (r2 + (1 - theta) (r3 + theta (r4 + (1 - theta) r5)))

    r1 = x, r2 = x1 - x, r3 = h k1 - r2, r4 = r2 - h k7 - r3, r5 = h sum_i d_i k_i

which interpolates ``x`` and ``x1`` exactly and matches both end slopes.
"""
from __future__ import annotations

import math

import numpy as np

from ._jit import njit, njit_borrowed
from .stepsize import factor as _factor

C2, C3, C4, C5 = 1 / 5, 3 / 10, 4 / 5, 8 / 9
A21 = 1 / 5
A31, A32 = 3 / 40, 9 / 40
A41, A42, A43 = 44 / 45, -56 / 15, 32 / 9
A51, A52, A53, A54 = 19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729
A61, A62, A63, A64, A65 = 9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656
B1, B3, B4, B5, B6 = 35 / 384, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84
E1, E3, E4, E5, E6, E7 = 71 / 57600, -71 / 16695, 71 / 1920, -17253 / 339200, 22 / 525, -1 / 40
D1 = -12715105075 / 11282082432
D3 = 87487479700 / 32700410799
D4 = -10690763975 / 1880347072
D5 = 701980252875 / 199316789632
D6 = -1453857185 / 822651844
D7 = 69997945 / 29380423

SAFETY, MIN_FACTOR, MAX_FACTOR = 0.9, 0.2, 10.0
ORDER = 4                         # order of the error estimator: exponent -1/(ORDER + 1)

#: rows of the work array ``K`` (7 stages, then the trial state and a scratch vector)
K_ROWS = 9
ROW_TRIAL, ROW_SCRATCH = 7, 8


@njit_borrowed
def c_of(stage):
    """Time fraction ``c`` of stage ``stage`` (0-based: 0..6)."""
    if stage == 1:
        return C2
    if stage == 2:
        return C3
    if stage == 3:
        return C4
    if stage == 4:
        return C5
    return 1.0 if stage > 0 else 0.0


@njit_borrowed(inline="always")
def stage_state(stage, x, K, h, y):
    """``y = x + h sum_j a_(stage, j) K[j]``: the state at which stage ``stage`` (1..5) is
    evaluated; ``stage == 6`` gives the fifth-order solution (the weights ``b``)."""
    n = x.size
    k1, k2, k3, k4, k5, k6 = K[0], K[1], K[2], K[3], K[4], K[5]
    if stage == 1:
        for i in range(n):
            y[i] = x[i] + h * A21 * k1[i]
    elif stage == 2:
        for i in range(n):
            y[i] = x[i] + h * (A31 * k1[i] + A32 * k2[i])
    elif stage == 3:
        for i in range(n):
            y[i] = x[i] + h * (A41 * k1[i] + A42 * k2[i] + A43 * k3[i])
    elif stage == 4:
        for i in range(n):
            y[i] = x[i] + h * (A51 * k1[i] + A52 * k2[i] + A53 * k3[i] + A54 * k4[i])
    elif stage == 5:
        for i in range(n):
            y[i] = x[i] + h * (A61 * k1[i] + A62 * k2[i] + A63 * k3[i] + A64 * k4[i]
                               + A65 * k5[i])
    else:
        for i in range(n):
            y[i] = x[i] + h * (B1 * k1[i] + B3 * k3[i] + B4 * k4[i] + B5 * k5[i]
                               + B6 * k6[i])


@njit_borrowed(inline="always")
def error_norm(x, x1, K, h, rtol, atol):
    """Scaled RMS norm of the local error estimate ``h sum_i e_i K[i]`` (accept if <= 1)."""
    n = x.size
    if n == 0:
        return 0.0
    acc = 0.0
    for i in range(n):
        e = h * (E1 * K[0, i] + E3 * K[2, i] + E4 * K[3, i] + E5 * K[4, i] + E6 * K[5, i]
                 + E7 * K[6, i])
        sc = atol + rtol * max(abs(x[i]), abs(x1[i]))
        acc += (e / sc) ** 2
    err = math.sqrt(acc / n)
    if not math.isfinite(err):
        return math.inf
    return err


def step(fun, t, x, h, K, x1, rtol, atol, sig=None, p=None, modes=None):
    """One trial step of size ``h`` from ``(t, x)`` with ``K[0] = f(t, x)`` (reference
    implementation in Python for ``fun(t, x, sig, p, modes, xdot)``; the compiled loop
    sequences the same helpers). Fills ``K[1..6]`` (``K[6] = f(t + h, x1)``) and ``x1``;
    returns the error norm."""
    y = K[ROW_TRIAL]
    for s in range(1, 6):
        stage_state(s, x, K, h, y)
        fun(t + c_of(s) * h, y, sig, p, modes, K[s])
    stage_state(6, x, K, h, x1)
    fun(t + h, x1, sig, p, modes, K[6])
    return error_norm(x, x1, K, h, rtol, atol)


@njit_borrowed
def factor(err, rejected):
    """Step-size factor after a trial step with error norm ``err`` (this method's constants
    in :func:`spidersim.solver.stepsize.factor`)."""
    return _factor(err, rejected, ORDER, SAFETY, MIN_FACTOR, MAX_FACTOR)


@njit_borrowed
def dense(t, h, x, x1, K, s, out):
    """State at ``s`` in ``[t, t + h]`` from the accepted step ``(t, x) -> (t + h, x1)``
    whose stages are in ``K`` (the continuous extension of the module docstring)."""
    n = x.size
    if h == 0.0:
        for i in range(n):
            out[i] = x1[i]
        return
    th = (s - t) / h
    th1 = 1.0 - th
    k1, k3, k4, k5, k6, k7 = K[0], K[2], K[3], K[4], K[5], K[6]
    for i in range(n):
        r2 = x1[i] - x[i]
        r3 = h * k1[i] - r2
        r4 = r2 - h * k7[i] - r3
        r5 = h * (D1 * k1[i] + D3 * k3[i] + D4 * k4[i] + D5 * k5[i] + D6 * k6[i]
                  + D7 * k7[i])
        out[i] = x[i] + th * (r2 + th1 * (r3 + th * (r4 + th1 * r5)))


@njit_borrowed
def scaled_rms(v, x, rtol, atol):
    """RMS of ``v`` scaled by ``atol + rtol |x|`` (the sizes of the initial-step rule)."""
    n = x.size
    acc = 0.0
    for i in range(n):
        acc += (v[i] / (atol + abs(x[i]) * rtol)) ** 2
    return math.sqrt(acc / n)


@njit_borrowed
def initial_h0(x, f0, rtol, atol, span, y):
    """First guess of the initial step (Hairer, Norsett & Wanner, II.4) from the sizes of
    ``x`` and ``f0``; fills ``y = x + h0 f0`` for the Euler trial."""
    n = x.size
    if n == 0:
        return span
    d0 = scaled_rms(x, x, rtol, atol)
    d1 = scaled_rms(f0, x, rtol, atol)
    if d0 < 1e-5 or d1 < 1e-5:
        h0 = 1e-6
    else:
        h0 = 0.01 * d0 / d1
    h0 = min(h0, span)
    for i in range(n):
        y[i] = x[i] + h0 * f0[i]
    return h0


@njit_borrowed
def initial_step(x, f0, f1, h0, rtol, atol, span):
    """The initial step from the guess ``h0`` and ``f1 = f(t + h0, x + h0 f0)`` (``f1`` is
    overwritten): the second derivative estimate bounds it; never longer than ``span``."""
    n = x.size
    if n == 0:
        return span
    d1 = scaled_rms(f0, x, rtol, atol)
    for i in range(n):
        f1[i] -= f0[i]                 # f1 is scratch: the change of f over h0
    d2 = scaled_rms(f1, x, rtol, atol) / h0
    if d1 <= 1e-15 and d2 <= 1e-15:
        h1 = max(1e-6, h0 * 1e-3)
    else:
        h1 = (0.01 / max(d1, d2)) ** (1.0 / (ORDER + 1))
    h = min(100 * h0, h1, span)
    if not (h > 0.0) or not math.isfinite(h):
        h = min(1e-6, span)
    return h


def first_step(fun, t, x, f0, span, rtol, atol, K, sig=None, p=None, modes=None):
    """Initial step size for ``fun`` (reference implementation in Python; the compiled
    loop sequences the same helpers)."""
    y, f1 = K[ROW_TRIAL], K[ROW_SCRATCH]
    h0 = initial_h0(x, f0, rtol, atol, span, y)
    if x.size == 0:
        return h0
    fun(t + h0, y, sig, p, modes, f1)
    return initial_step(x, f0, f1, h0, rtol, atol, span)


def work_array(n):
    """The stage work array ``K`` for a state of size ``n``."""
    return np.zeros((K_ROWS, n))
