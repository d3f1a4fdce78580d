"""Variable-order BDF (the NDF variant, orders 1-5) on a system function, compiled, no allocation.

A pure helper module on preallocated arrays, like :mod:`.dp54` and :mod:`.rosenbrock`, but
called on a system function's address ``fn`` (:mod:`.sysfn`): ``sysfn.derivatives(fn, t, y,
sig, p, modes, out)`` gives ``out = f(t, y)``; ``sig``, ``p``, ``modes`` are passed through.

Method (Shampine & Reichelt, "The MATLAB ODE suite", SIAM J. Sci. Comput. 18, 1997;
Hairer & Wanner, *Solving ODEs II*, III.1 and IV.8)
---------------------------------------------------------------------------------------
**Difference form.** The solution is carried as the backward differences of the last
``k + 1`` accepted values at equal spacing ``h`` (``k`` the order): the history ``D`` with
``D[0] = y_n``, ``D[j] = nabla^j y_n``. The predictor is the interpolating polynomial
extrapolated one step, ``y0 = sum_(j=0..k) D[j]``. The NDF of order ``k`` is

    sum_(j=1..k) (1/j) nabla^j y_(n+1) = h f(t_(n+1), y_(n+1)) + kappa_k gamma_k (y_(n+1) - y0)

with ``gamma_k = sum_(j=1..k) 1/j``; in terms of the correction ``d = y_(n+1) - y0`` it is

    (1 - kappa_k) gamma_k d = h f(t_(n+1), y0 + d) - psi,   psi = sum_(j=1..k) gamma_j D[j],

i.e. ``d = c f(t_(n+1), y0 + d) - psi / alpha_k`` with ``alpha_k = (1 - kappa_k) gamma_k`` and
``c = h / alpha_k``. ``kappa = (-0.1850, -1/9, -0.0823, -0.0415, 0)`` for ``k = 1..5``
(Shampine & Reichelt's Table 1: about 26 % larger steps than BDF at orders 1-3, 12 % at 4,
at nearly the same stability angle; order 5 is plain BDF). ``kappa = 0`` everywhere is BDF.

**Error estimate.** The local error of order ``k`` is ``C_k d`` with the error constant
``C_k = kappa_k gamma_k + 1/(k + 1)`` (``d = nabla^(k+1) y_(n+1)`` to leading order), measured as
``err = rms(C_k d / sc)``, ``sc = atol + rtol |y_(n+1)|``; the step is accepted when
``err <= 1``. After acceptance the history is updated in place:
``D[k+2] = d - D[k+1]; D[k+1] = d; D[i] += D[i+1]`` for ``i = k..0`` (then ``D[0] = y_(n+1)``).

**Step and order selection.** A rejected step is retried with
``h * max(0.2, s err^(-1/(k+1)))``; ``s = 0.9 (2 m + 1) / (2 m + it)`` (``m = 4`` Newton
iterations allowed, ``it`` used: a step that needed many iterations grows less). After ``k + 1``
accepted steps of equal size and order, the errors of orders ``k - 1`` and ``k + 1`` are
estimated as ``C_(k-1) D[k]`` and ``C_(k+1) D[k+2]``, each gives a factor
``err_q^(-1/(q+1))``, and the order with the largest factor is taken with
``h * min(10, s * that factor)``; a factor in ``[1, HOLD_MAX]`` at an unchanged order keeps ``h``
(and so the LU factors; ``fw[F_HOLD_MAX]``, 1 = never hold). A change of ``h`` rescales the
history to the new spacing (``D[:k+1] <- (R U)^T D[:k+1]`` with
``R_ij = prod_(m=1..i) (m - 1 - r j) / m``, ``r`` the ratio and ``U`` = ``R`` at ``r = 1``:
the same polynomial at the new spacing). The step never passes ``t_seg`` nor ``max_step``
(``h`` is cut and the history rescaled), and ``h`` below ten spacings of floating-point
numbers at ``t`` is a failure (:func:`advance` returns 0).

**Newton iteration.** ``d`` solves the implicit equation by a simplified Newton iteration
with the matrix ``I - c J``: ``(I - c J) dy = c f(t_(n+1), y0 + d) - psi / alpha_k - d``,
at most 4 iterations, stopped as converged when ``rate / (1 - rate) |dy| < 0.03`` (rms norm in
the scale of the predictor, the norm of the error test, ``rate`` the ratio of successive
``|dy|``) and as diverging when ``rate >= 1`` or when the rate cannot reach 0.03 in the
iterations left (or ``f`` is not finite). The iteration error is thus kept 30 times below
the local error the step is accepted with (CVODE: 10 times). SciPy's ``BDF`` asks for
``min(0.03, sqrt(rtol))``, 1e-3 at ``rtol = 1e-6``: on ``spider.yaml`` that made 40 % more
right-hand-side calls and twice the Jacobians (1,114 against 599 in 10 s) for a base force
within 4e-4 N of this one (peak 9.95 N; the step-to-step integration error is of that
size).

**Jacobian reuse.** ``J`` is kept across steps, orders, step sizes and segments; it is
recomputed only when the Newton iteration fails with a ``J`` that was not computed during this
call of :func:`advance` (then the step is retried with the same ``h``); a failure with a
current ``J`` halves ``h``. It is also computed when none is valid (first step;
:func:`invalidate_jacobian` after an event that changed the equations). ``J`` is taken at
``(t, D[0])``, the start of the step, by finite differences over the column groups of the
structural pattern ``jpat`` (:func:`.rosenbrock.perturb_group` and
:func:`.rosenbrock.store_group`: one evaluation per group, the base value ``f(t, D[0])`` is
kept from the previous step, so a Jacobian costs ``n_groups`` evaluations). The LU factors
of ``I - c J`` (:func:`.dense_lu.lu_factor`: dense, partial pivoting,
LAPACK from order 24) are redone only when
``c = h / alpha_k`` changed (``h`` or the order changed) or ``J`` was recomputed.

Dense output: the interpolating polynomial of the history,
``y(s) = D[0] + sum_(j=1..k) D[j] prod_(m=0..j-1) (s - t + m h) / ((m + 1) h)``, valid on the
last accepted step (order ``k`` accurate).

Arrays (from :func:`work`; all state of the method is in them)
--------------------------------------------------------------
``V`` float64 ``(V_ROWS, n)``: rows ``0..7`` the history ``D`` (``D[0]`` the state at the
current time), then the predictor/iterate, ``psi``, the correction ``d``, ``f`` at the
iterate, the Newton step, the scale, ``f(t, D[0])`` (base of the Jacobian), the LU pivots, and
three scratch rows of the finite differences. ``JW`` float64 ``(2, n, n)``: ``J`` (zero
outside the pattern) and the LU factors. ``iw`` int64 (``I_*``: order, steps at this order,
max order, fixed mode, Jacobian valid, counters) and ``fw`` float64 (``F_*``: next step size,
the ``c`` of the LU factors, last error norm, hold limit, small matrices of the rescaling).

Calling sequence (what is valid after each call)
------------------------------------------------
``restart(t, x, f0, h, ...)`` at a segment start (the start, after each event or time
event: the history is invalid there): order 1, ``D[0] = x``, ``D[1] = h f0``. The Jacobian
is kept (call :func:`invalidate_jacobian` too when the equations changed).
``h = advance(fn, t, t_seg, x1, f1, ...)`` then takes one accepted step from ``(t, D[0])``:
``x1`` the state at ``t + h``, ``f1 = f(t + h, x1)`` (one extra evaluation per step), the
history moved to ``t + h`` (``iw[I_WANT_F1] = 0``: ``f1`` is not evaluated, one evaluation
per step less, and a Jacobian costs one more); ``h = 0.0`` on failure (step size
underflow: ``D`` is still at ``t``). :func:`dense` is valid for ``s`` in ``[t, t + h]``
until the next ``advance`` or ``restart``; ``dense(t + h, ...)`` is given the *new* time.
"""
from __future__ import annotations

import math

import numpy as np

from ._jit import njit, njit_borrowed
from .dense_lu import lu_factor, lu_solve
from .dp54 import initial_h0
from .rosenbrock import analytic, n_groups, perturb_group, store_group
from .sysfn import derivatives
from .sysfn import jacobian as sysfn_jacobian

MAX_ORDER = 5
#: NDF coefficients kappa_k, k = 0..5 (Shampine & Reichelt 1997, Table 1; index 0 unused)
KAPPA = np.array([0.0, -0.1850, -1.0 / 9.0, -0.0823, -0.0415, 0.0, 0.0])
#: gamma_k = sum_(j=1..k) 1/j (k = 0..6)
GAMMA = np.array([0.0] + [sum(1.0 / j for j in range(1, k + 1)) for k in range(1, 7)])
#: alpha_k = (1 - kappa_k) gamma_k
ALPHA = (1.0 - KAPPA) * GAMMA
#: error constants C_k = kappa_k gamma_k + 1/(k + 1), k = 0..6
ERROR_CONST = KAPPA * GAMMA + 1.0 / np.arange(1, 8)

NEWTON_MAXITER = 4
MIN_FACTOR, MAX_FACTOR = 0.2, 10.0
#: Newton convergence: ``rate / (1 - rate) |dy| < NEWTON_TOL`` in the norm of the error test
#: (module docstring)
NEWTON_TOL = 0.03
#: default of ``fw[F_HOLD_MAX]``: factors in [1, HOLD_MAX] at an unchanged order keep h
HOLD_MAX = 1.0
_EPS = 2.220446049250313e-16

# --- rows of V ------------------------------------------------------------------------------
N_HIST = MAX_ORDER + 3
ROW_Y, ROW_PSI, ROW_D, ROW_F, ROW_DY, ROW_SCALE, ROW_FCUR, ROW_PIV = range(N_HIST, N_HIST + 8)
ROW_YP, ROW_FP, ROW_DJ = range(N_HIST + 8, N_HIST + 11)
V_ROWS = N_HIST + 11

# --- iw: method state and counters ------------------------------------------------------------
I_ORDER, I_NEQUAL, I_MAXORDER, I_FIXED, I_JVALID = range(5)
#: counters: RHS evaluations (Jacobian columns included), Jacobians, LU factorisations,
#: accepted steps, error-test rejections, Newton failures
I_NFEV, I_NJAC, I_NLU, I_NSTEPS, I_NREJECT, I_NNEWTON = range(5, 11)
#: 1 (default): :func:`advance` evaluates ``f1 = f(t + h, x1)`` (one evaluation per step);
#: 0: it leaves ``f1`` alone and a Jacobian evaluates its own base value; whether
#: ``V[ROW_FCUR]`` holds ``f(t, D[0])``
I_WANT_F1, I_FCUR_VALID = 11, 12
I_SIZE = 13

# --- fw ----------------------------------------------------------------------------------------
F_H, F_CLU, F_ERR, F_HOLD_MAX = range(4)
_M = MAX_ORDER + 1                    # side of the rescaling matrices
F_R = 4
F_U = F_R + _M * _M
F_RU = F_U + _M * _M
F_TMP = F_RU + _M * _M
F_SIZE = F_TMP + _M


def work(n, max_order=MAX_ORDER):
    """The work arrays ``(V, JW, iw, fw)`` for ``n`` states (module docstring);
    ``max_order`` (1..5) caps the order."""
    if not 1 <= int(max_order) <= MAX_ORDER:
        raise ValueError(f"BDF max_order must be 1..{MAX_ORDER}, got {max_order}")
    V = np.zeros((V_ROWS, n))
    JW = np.zeros((2, n, n))
    iw = np.zeros(I_SIZE, dtype=np.int64)
    iw[I_ORDER] = 1
    iw[I_MAXORDER] = int(max_order)
    iw[I_WANT_F1] = 1
    fw = np.zeros(F_SIZE)
    fw[F_HOLD_MAX] = HOLD_MAX
    return V, JW, iw, fw


@njit_borrowed
def invalidate_jacobian(iw):
    """Mark ``J`` stale: the next :func:`advance` computes it before its first Newton."""
    iw[I_JVALID] = 0


@njit_borrowed
def rms(v, scale):
    """``sqrt(mean((v / scale)^2))`` (0 for no states)."""
    n = v.size
    if n == 0:
        return 0.0
    acc = 0.0
    for i in range(n):
        acc += (v[i] / scale[i]) ** 2
    return math.sqrt(acc / n)


@njit_borrowed
def _fill_r(fw, off, order, factor):
    """``R(order, factor)`` into ``fw[off:]`` (row-major, side ``MAX_ORDER + 1``):
    ``R[0, j] = 1``, ``R[i, 0] = 0`` (i >= 1), ``R[i, j] = R[i-1, j] (i - 1 - factor j) / i``."""
    for j in range(order + 1):
        fw[off + j] = 1.0
    for i in range(1, order + 1):
        fw[off + i * _M] = 0.0
        for j in range(1, order + 1):
            fw[off + i * _M + j] = fw[off + (i - 1) * _M + j] * (i - 1 - factor * j) / i


@njit_borrowed
def rescale(V, order, factor, fw):
    """Change the spacing of the history ``D[:order+1]`` from ``h`` to ``factor h`` (the
    same interpolating polynomial): ``D <- (R U)^T D``."""
    _fill_r(fw, F_R, order, factor)
    _fill_r(fw, F_U, order, 1.0)
    k1 = order + 1
    for i in range(k1):
        for j in range(k1):
            acc = 0.0
            for m in range(k1):
                acc += fw[F_R + i * _M + m] * fw[F_U + m * _M + j]
            fw[F_RU + i * _M + j] = acc
    n = V.shape[1]
    for col in range(n):
        for j in range(k1):
            fw[F_TMP + j] = V[j, col]
        for i in range(k1):
            acc = 0.0
            for j in range(k1):
                acc += fw[F_RU + j * _M + i] * fw[F_TMP + j]
            V[i, col] = acc


@njit_borrowed
def restart(t, x, f0, h, V, JW, iw, fw):
    """Start a segment at ``(t, x)`` with ``f0 = f(t, x)`` and the first step ``h``: order 1,
    history ``D[0] = x``, ``D[1] = h f0`` (``t`` is not stored: the caller passes it to
    :func:`advance`). Keeps ``J`` and the counters; the LU factors are redone."""
    n = x.size
    for j in range(N_HIST):
        for i in range(n):
            V[j, i] = 0.0
    for i in range(n):
        V[0, i] = x[i]
        V[1, i] = h * f0[i]
        V[ROW_FCUR, i] = f0[i]
    iw[I_FCUR_VALID] = 1
    iw[I_ORDER] = 1
    iw[I_NEQUAL] = 0
    fw[F_H] = h
    fw[F_CLU] = 0.0


@njit_borrowed
def first_step(fn, t, x, f0, span, rtol, atol, V, sig, p, modes):
    """Initial step size for order 1 (Hairer, Norsett & Wanner I, II.4, as SciPy's BDF):
    ``h0 = 0.01 |x| / |f0|`` (scaled norms), then bounded by the second-derivative estimate
    from ``f(t + h0, x + h0 f0)``: ``h1 = sqrt(0.01 / max(|f0|, |f'|))``, ``min(100 h0, h1,
    span)``. One evaluation (``V[ROW_Y]``, ``V[ROW_F]`` are used as scratch)."""
    n = x.size
    if n == 0:
        return span
    sc = V[ROW_SCALE]
    y, f1 = V[ROW_Y], V[ROW_F]
    for i in range(n):
        sc[i] = atol + rtol * abs(x[i])
    d1 = rms(f0, sc)
    h0 = initial_h0(x, f0, rtol, atol, span, y)       # the rule's first half, y = x + h0 f0
    derivatives(fn, t + h0, y, sig, p, modes, f1)
    for i in range(n):
        f1[i] -= f0[i]
    d2 = rms(f1, sc) / h0
    if d1 <= 1e-15 and d2 <= 1e-15:
        h1 = max(1e-6, h0 * 1e-3)
    else:
        h1 = (0.01 / max(d1, d2)) ** 0.5
    h = min(100.0 * h0, h1, span)
    if not (h > 0.0) or not math.isfinite(h):
        h = min(1e-6, span)
    return h


@njit_borrowed
def jacobian(fn, t, V, J, jpat, iw, sig, p, modes):
    """``J`` = finite-difference Jacobian at ``(t, D[0])`` with the base ``f(t, D[0])`` in
    ``V[ROW_FCUR]`` (evaluated first when not valid): one evaluation per column group of
    ``jpat``; or, when ``jpat`` says so, the system's analytic one (one call, counted as
    one evaluation: it evaluates the outputs; :mod:`spidersim.diagram.jacobian`)."""
    x = V[0]
    if analytic(jpat) and sysfn_jacobian(fn, t, x, sig, p, modes, J):
        iw[I_NFEV] += 1
        iw[I_NJAC] += 1
        iw[I_JVALID] = 1
        return
    y, fp, d = V[ROW_YP], V[ROW_FP], V[ROW_DJ]
    if iw[I_FCUR_VALID] == 0:
        derivatives(fn, t, x, sig, p, modes, V[ROW_FCUR])
        iw[I_NFEV] += 1
        iw[I_FCUR_VALID] = 1
    ng = n_groups(jpat)
    for g in range(ng):
        perturb_group(g, x, jpat, y, d)
        derivatives(fn, t, y, sig, p, modes, fp)
        store_group(g, V[ROW_FCUR], fp, d, jpat, J)
    iw[I_NFEV] += ng
    iw[I_NJAC] += 1
    iw[I_JVALID] = 1


@njit_borrowed
def _newton(fn, t_new, c, tol, V, LU, iw, sig, p, modes):
    """Simplified Newton for the correction ``d`` (``V[ROW_D]``) from the predictor in
    ``V[ROW_Y]`` (overwritten by ``y0 + d``); returns ``(converged, iterations)``."""
    n = V.shape[1]
    y, psi, d, f, dy, sc, piv = (V[ROW_Y], V[ROW_PSI], V[ROW_D], V[ROW_F], V[ROW_DY],
                                 V[ROW_SCALE], V[ROW_PIV])
    for i in range(n):
        d[i] = 0.0
    dy_norm_old = -1.0
    converged = False
    it = 0
    while it < NEWTON_MAXITER:
        derivatives(fn, t_new, y, sig, p, modes, f)
        iw[I_NFEV] += 1
        it += 1
        finite = True
        for i in range(n):
            if not math.isfinite(f[i]):
                finite = False
        if not finite:
            break
        for i in range(n):
            dy[i] = c * f[i] - psi[i] - d[i]
        lu_solve(LU, piv, dy)
        dy_norm = rms(dy, sc)
        if not math.isfinite(dy_norm):
            break
        rate = -1.0
        if dy_norm_old > 0.0:
            rate = dy_norm / dy_norm_old
            if rate >= 1.0 or rate ** (NEWTON_MAXITER - it + 1) / (1.0 - rate) * dy_norm > tol:
                break
        for i in range(n):
            y[i] += dy[i]
            d[i] += dy[i]
        if dy_norm == 0.0 or (rate >= 0.0 and rate / (1.0 - rate) * dy_norm < tol):
            converged = True
            break
        dy_norm_old = dy_norm
    return converged, it


@njit_borrowed
def _error_norm(V, order, rtol, atol, q):
    """``rms(C_q v / sc)`` with ``sc = atol + rtol |y|`` of the iterate ``V[ROW_Y]`` already
    in ``V[ROW_SCALE]``, for ``v = d`` (q = order), ``D[order]`` (q = order - 1) or
    ``D[order + 2]`` (q = order + 1)."""
    if q == order:
        v = V[ROW_D]
    elif q < order:
        v = V[order]
    else:
        v = V[order + 2]
    return ERROR_CONST[q] * rms(v, V[ROW_SCALE])


@njit_borrowed
def _change_h(V, order, factor, h, iw, fw):
    rescale(V, order, factor, fw)
    iw[I_NEQUAL] = 0
    return h * factor


@njit_borrowed
def _predict(V, order, rtol, atol):
    """Predictor ``y0 = sum_(j<=k) D[j]`` into ``V[ROW_Y]``, ``psi = sum_j gamma_j D[j] /
    alpha_k`` into ``V[ROW_PSI]``, the scale of the predictor into ``V[ROW_SCALE]``."""
    n = V.shape[1]
    y, psi, sc = V[ROW_Y], V[ROW_PSI], V[ROW_SCALE]
    a = ALPHA[order]
    for i in range(n):
        acc = V[0, i]
        ps = 0.0
        for j in range(1, order + 1):
            acc += V[j, i]
            ps += GAMMA[j] * V[j, i]
        y[i] = acc
        psi[i] = ps / a
        sc[i] = atol + rtol * abs(acc)


@njit_borrowed
def _factor(c, V, JW, iw, fw):
    """LU factors of ``I - c J`` into ``JW[1]`` unless they are those of this ``c`` already
    (``fw[F_CLU]``); False if singular (then ``fw[F_CLU] = 0``)."""
    if c == fw[F_CLU]:
        return True
    J, LU = JW[0], JW[1]
    n = V.shape[1]
    for i in range(n):
        for j in range(n):
            LU[i, j] = -c * J[i, j]
        LU[i, i] += 1.0
    ok = lu_factor(LU, V[ROW_PIV])
    iw[I_NLU] += 1
    fw[F_CLU] = c if ok else 0.0
    return ok


@njit_borrowed
def _accept(fn, t_new, x1, f1, V, order, iw, sig, p, modes):
    """Move the history to ``t_new`` with the converged correction ``d``:
    ``D[k+2] = d - D[k+1]; D[k+1] = d; D[i] += D[i+1]`` (``i = k..0``); ``x1 = D[0]`` and,
    when asked (``iw[I_WANT_F1]``), ``f1 = f(t_new, x1)``."""
    n = V.shape[1]
    d = V[ROW_D]
    for i in range(n):
        V[order + 2, i] = d[i] - V[order + 1, i]
        V[order + 1, i] = d[i]
    for j in range(order, -1, -1):
        for i in range(n):
            V[j, i] += V[j + 1, i]
    for i in range(n):
        x1[i] = V[0, i]
    if iw[I_WANT_F1]:
        derivatives(fn, t_new, x1, sig, p, modes, f1)
        for i in range(n):
            V[ROW_FCUR, i] = f1[i]
        iw[I_NFEV] += 1
    else:
        iw[I_FCUR_VALID] = 0
    iw[I_NSTEPS] += 1
    iw[I_NEQUAL] += 1


@njit_borrowed
def _next_order_and_h(V, order, err, safety, h, rtol, atol, iw, fw):
    """After ``k + 1`` steps of equal size and order: the order among ``k - 1, k, k + 1``
    whose error estimate allows the largest step, and that step (module docstring);
    returns the next ``h`` (``iw[I_ORDER]`` updated, the history rescaled)."""
    if iw[I_NEQUAL] < order + 1:
        return h
    fac_m = 0.0
    if order > 1:
        e = _error_norm(V, order, rtol, atol, order - 1)
        fac_m = math.inf if e == 0.0 else e ** (-1.0 / order)
    fac_k = math.inf if err == 0.0 else err ** (-1.0 / (order + 1))
    fac_p = 0.0
    if order < iw[I_MAXORDER]:
        e = _error_norm(V, order, rtol, atol, order + 1)
        fac_p = math.inf if e == 0.0 else e ** (-1.0 / (order + 2))
    delta = 0
    best = fac_k
    if fac_m > best:
        delta, best = -1, fac_m
    if fac_p > best:
        delta, best = 1, fac_p
    fac = min(MAX_FACTOR, safety * best)
    if delta == 0 and 1.0 <= fac <= fw[F_HOLD_MAX]:
        return h                               # keep h and the LU factors
    order += delta
    iw[I_ORDER] = order
    return _change_h(V, order, fac, h, iw, fw)


@njit_borrowed
def _bounded_h(t, max_step, V, order, iw, fw):
    """The step size to try first: ``fw[F_H]`` within ``max_step`` and at least ten
    spacings of floating-point numbers at ``t`` (the history rescaled if it changed)."""
    h = fw[F_H]
    h_min = 10.0 * (np.nextafter(t, math.inf) - t)
    if h > max_step:
        h = _change_h(V, order, max_step / h, h, iw, fw)
    if h < h_min:
        h = _change_h(V, order, h_min / h, h, iw, fw)
    return h


@njit_borrowed
def advance(fn, t, t_seg, x1, f1, rtol, atol, max_step, V, JW, iw, fw, jpat, sig, p, modes):
    """One accepted step from ``(t, D[0])`` (after :func:`restart` or a previous
    ``advance``), never past ``t_seg`` nor longer than ``max_step``.

    Returns the step ``h`` taken: ``x1`` = the state at ``t + h``, ``f1 = f(t + h, x1)``, the
    history moved there (``D[0] = x1``) and rescaled to the next step size ``fw[F_H]`` and
    order ``iw[I_ORDER]``. Returns 0.0 when the step size fell below ten spacings of
    floating-point numbers at ``t`` (nothing moved). Counters in ``iw``.

    Each try: predict (:func:`_predict`), factor ``I - c J`` if ``c = h / alpha_k`` changed
    (:func:`_factor`), Newton (:func:`_newton`; on failure a fresh Jacobian, or half the
    step if it was fresh), error test (rejected: a smaller step); then :func:`_accept` and
    :func:`_next_order_and_h`.
    """
    n = V.shape[1]
    J, LU = JW[0], JW[1]
    order = iw[I_ORDER]
    fixed = iw[I_FIXED] != 0
    h = _bounded_h(t, max_step, V, order, iw, fw)
    h_min = 10.0 * (np.nextafter(t, math.inf) - t)
    current_jac = False
    if iw[I_JVALID] == 0:
        jacobian(fn, t, V, J, jpat, iw, sig, p, modes)
        current_jac = True
        fw[F_CLU] = 0.0
    y, sc = V[ROW_Y], V[ROW_SCALE]
    while True:
        if h < h_min:
            fw[F_H] = h
            return 0.0
        t_new = t + h
        if t_new > t_seg:
            t_new = t_seg
            h = _change_h(V, order, (t_seg - t) / h, h, iw, fw)
        _predict(V, order, rtol, atol)
        c = h / ALPHA[order]
        converged = False
        it = NEWTON_MAXITER
        if _factor(c, V, JW, iw, fw):
            converged, it = _newton(fn, t_new, c, NEWTON_TOL, V, LU, iw, sig, p, modes)
        if not converged:
            iw[I_NNEWTON] += 1
            if not current_jac:
                jacobian(fn, t, V, J, jpat, iw, sig, p, modes)
                current_jac = True
                fw[F_CLU] = 0.0
            else:
                h = _change_h(V, order, 0.5, h, iw, fw)
            continue
        safety = 0.9 * (2 * NEWTON_MAXITER + 1) / (2 * NEWTON_MAXITER + it)
        for i in range(n):
            sc[i] = atol + rtol * abs(y[i])
        err = _error_norm(V, order, rtol, atol, order)
        fw[F_ERR] = err
        if err > 1.0 and not fixed:
            fac = max(MIN_FACTOR, safety * err ** (-1.0 / (order + 1)))
            h = _change_h(V, order, fac, h, iw, fw)
            iw[I_NREJECT] += 1
            continue
        break
    _accept(fn, t_new, x1, f1, V, order, iw, sig, p, modes)
    h_taken = t_new - t
    if not fixed:
        h = _next_order_and_h(V, order, err, safety, h, rtol, atol, iw, fw)
    fw[F_H] = h
    return h_taken


@njit_borrowed
def dense(t, V, iw, fw, s, out):
    """The state at ``s`` in ``[t_old, t]`` of the last accepted step (``t`` its end, the
    time of ``D[0]``): the interpolating polynomial of the history (module docstring)."""
    n = V.shape[1]
    order = iw[I_ORDER]
    h = fw[F_H]
    for i in range(n):
        out[i] = V[0, i]
    prod = 1.0
    for j in range(1, order + 1):
        prod *= (s - (t - (j - 1) * h)) / (j * h)
        for i in range(n):
            out[i] += prod * V[j, i]


@njit
def solve(fn, t0, t_end, x0, rtol, atol, jpat, t_out, out, sig, p, modes, V, JW, iw, fw,
          max_steps=10 ** 9):
    """Integrate from ``(t0, x0)`` to ``t_end`` (one segment) and write the dense output at
    the increasing times ``t_out`` into the rows of ``out`` (a driver for tests and
    benchmarks; work arrays from :func:`work`). Returns the time reached (< ``t_end`` on a
    step-size failure or after ``max_steps`` accepted steps)."""
    n = x0.size
    f0 = np.empty(n)
    x1 = np.empty(n)
    derivatives(fn, t0, x0, sig, p, modes, f0)
    iw[I_NFEV] += 1
    h = first_step(fn, t0, x0, f0, t_end - t0, rtol, atol, V, sig, p, modes)
    iw[I_NFEV] += 1
    restart(t0, x0, f0, h, V, JW, iw, fw)
    t = t0
    k = 0
    while k < t_out.size and t_out[k] <= t0:
        out[k, :] = x0
        k += 1
    while t < t_end and iw[I_NSTEPS] < max_steps:
        h = advance(fn, t, t_end, x1, f0, rtol, atol, math.inf, V, JW, iw, fw, jpat, sig,
                    p, modes)
        if h == 0.0:
            break
        t = t_end if t + h >= t_end else t + h
        while k < t_out.size and t_out[k] <= t:
            dense(t, V, iw, fw, t_out[k], out[k])
            k += 1
    return t
