"""ROS34PW2: a linearly implicit (Rosenbrock-W) method for stiff systems, with its Jacobian.

Plain functions on preallocated arrays, compiled by numba, with the contract of
:mod:`.dp54` (work-array layout, trial step and error norm, step-size factor, dense output;
the first step is :mod:`.dp54`'s rule) plus the Jacobian: finite differences over column
groups coloured once from the structural sparsity, and a dense LU (:func:`.dense_lu.lu_factor`,
partial pivoting, in place) reused while ``h`` and the Jacobian are unchanged.

Method (Rang & Angermann, BIT 45, 2005; Hairer & Wanner, *Solving ODEs II*, IV.7)
--------------------------------------------------------------------------------
Four stages, order 3, embedded order 2, L-stable and stiffly accurate, and a *W-method*:
its order conditions hold for any matrix ``W`` in place of the Jacobian ``J = df/dx``, so a
Jacobian from an earlier step (or without ``df/dt``) keeps order 3. In the form without
matrix-vector products (``u_i = sum_j gamma_ij k_j``, Hairer & Wanner (7.4')):

    (I / (h gamma) - W) u_i = f(t + alpha_i h, x + sum_(j<i) a_ij u_j) + sum_(j<i) (c_ij / h) u_j

    x1 = x + sum_i m_i u_i,   error estimate  e = sum_i (m_i - m_hat_i) u_i

with ``gamma = 0.4358665215``, ``a = A Gamma^-1``, ``c = -(Gamma^-1)`` below the diagonal,
``m = b Gamma^-1``, ``m_hat = b_hat Gamma^-1`` from the published ``A``, ``Gamma``, ``b``,
``b_hat`` (computed below at import). ``df/dt`` is not formed: ``W`` is ``J`` with the time
column left out, which a W-method allows without loss of order. Error norm, acceptance
(``err <= 1``) and scale ``sc = atol + rtol max(|x|, |x1|)`` as in :mod:`.dp54`; the new step is
``h * clip(0.9 err^(-1/3), 0.2, 5)`` (the estimate is of order 2).

Dense output is the cubic Hermite interpolant through ``(t, x, f(t, x))`` and
``(t + h, x1, f(t + h, x1))`` (third order, the method's; ``f(t + h, x1)`` is the next step's
first stage, so it costs nothing extra).

Jacobian by finite differences over column groups (Curtis, Powell & Reid 1974)
------------------------------------------------------------------------------
Columns ``j`` and ``k`` may share a group when no row of the structural pattern ``S``
(``S[i, j]``: ``f_i`` depends on ``x_j``) has both: one evaluation ``f(x + sum_(j in g) d_j e_j)``
then gives every column of the group, ``J[i, j] = (f_i(x + ...) - f_i(x)) / d_j`` for the rows
``i`` of column ``j``. The groups come from a greedy colouring of the column-intersection graph
(:func:`colour_columns`, in Python, once per diagram structure). The increment is Hairer's
(RADAU5): ``d_j = sqrt(eps max(1e-5, |x_j|))``, rounded so that ``x_j + d_j`` is exact.

Pattern array ``jpat`` (int64): ``[n_groups, col_ptr (n + 1), row_idx (nnz), grp_ptr
(n_groups + 1), grp_col (n), analytic]``: the rows of column ``j`` are
``row_idx[col_ptr[j]:col_ptr[j+1]]`` and the columns of group ``g`` are
``grp_col[grp_ptr[g]:grp_ptr[g+1]]``; ``analytic`` (the last element) 1 when the Jacobian is
to be asked of the system function instead (:func:`analytic`, the task ``JACOBIAN`` of
:mod:`.sysfn`: one call instead of ``n_groups`` evaluations).
"""
from __future__ import annotations

import math

import numpy as np

from ._jit import njit, njit_borrowed
from .stepsize import factor as _factor
from .dense_lu import lu_factor, lu_solve

# --- the published coefficients (Rang & Angermann 2005, ROS34PW2) -------------------------
GAMMA = 0.43586652150845900
_A = np.zeros((4, 4))
_A[1, 0] = 0.87173304301691801
_A[2, 0], _A[2, 1] = 0.84457060015369423, -0.11299064236484185
_A[3, 2] = 1.0
_G = np.diag([GAMMA] * 4)
_G[1, 0] = -0.87173304301691801
_G[2, 0], _G[2, 1] = -0.90338057013044082, 0.054180672388095326
_G[3, 0], _G[3, 1], _G[3, 2] = 0.24212380706095346, -1.2232505839045147, 0.54526025533510214
_B = np.array([0.24212380706095346, -1.2232505839045147, 1.5452602553351020, GAMMA])
_BHAT = np.array([0.37810903145819369, -0.096042292212423178, 0.5, 0.21793326075422950])
# --- transformed to the u-form of the module docstring -----------------------------------
_GI = np.linalg.inv(_G)
_AT = _A @ _GI
_C = -np.tril(_GI, -1)
_M = _B @ _GI
_E = (_B - _BHAT) @ _GI
ALPHA2, ALPHA3, ALPHA4 = (float(v) for v in _A.sum(axis=1)[1:])
A21 = float(_AT[1, 0])
A31, A32 = float(_AT[2, 0]), float(_AT[2, 1])
A41, A42, A43 = float(_AT[3, 0]), float(_AT[3, 1]), float(_AT[3, 2])
C21 = float(_C[1, 0])
C31, C32 = float(_C[2, 0]), float(_C[2, 1])
C41, C42, C43 = float(_C[3, 0]), float(_C[3, 1]), float(_C[3, 2])
M1, M2, M3, M4 = (float(v) for v in _M)
E1, E2, E3, E4 = (float(v) for v in _E)

SAFETY, MIN_FACTOR, MAX_FACTOR = 0.9, 0.2, 5.0
ORDER = 2                          # order of the error estimator: exponent -1/(ORDER + 1)
#: accepted steps a Jacobian is kept (a W-method keeps its order with an old one; it is also
#: refreshed at every segment start, i.e. after every event)
JAC_MAX_AGE = 20
#: consecutive rejections of one step after which a Jacobian not computed at its start is
#: refreshed there
JAC_REJECTIONS = 1
#: a step-size factor in [1, HOLD_MAX] keeps h (and so the LU factors)
HOLD_MAX = 1.2

#: rows of the work array ``K``: f(t, x), the stages u1..u4, f of a perturbed state, f(t+h,
#: x1) (the row the loop copies to row 0), the trial state, scratch, the LU pivots
K_ROWS = 10
ROW_FPERT, ROW_END, ROW_TRIAL, ROW_SCRATCH, ROW_PIV = 5, 6, 7, 8, 9


# --- the Jacobian --------------------------------------------------------------------------

def colour_columns(pattern):
    """Greedy colouring of the column-intersection graph of the boolean ``pattern``
    (``pattern[i, j]``: ``f_i`` depends on ``x_j``): a group number for each column such that
    no two columns of a group have a nonzero in the same row (structurally orthogonal).
    Columns are taken in order of decreasing count of nonzeros (largest first); returns an
    int64 array of group numbers ``0..n_groups-1``."""
    S = np.asarray(pattern, dtype=bool)
    n = S.shape[1]
    group = np.full(n, -1, dtype=np.int64)
    rows_of = [np.flatnonzero(S[:, j]) for j in range(n)]
    used = []                       # per group: the rows its columns cover
    for j in sorted(range(n), key=lambda c: (-len(rows_of[c]), c)):
        for g, rows in enumerate(used):
            if not rows[rows_of[j]].any():
                group[j] = g
                rows[rows_of[j]] = True
                break
        else:
            rows = np.zeros(S.shape[0], dtype=bool)
            rows[rows_of[j]] = True
            used.append(rows)
            group[j] = len(used) - 1
    return group


def pattern_array(pattern, n, analytic=False):
    """The ``jpat`` array of the module docstring for an ``(n, n)`` boolean ``pattern``
    (``None``: dense, every column its own group). The diagonal is always included (the
    matrix ``I / (h gamma) - J`` has it). ``analytic``: the system function assembles the
    Jacobian itself (its last element 1)."""
    S = np.ones((n, n), dtype=bool) if pattern is None else np.array(pattern, dtype=bool)
    if S.shape != (n, n):
        raise ValueError(f"Jacobian sparsity pattern of shape {S.shape}, expected {(n, n)}")
    S |= np.eye(n, dtype=bool)
    group = colour_columns(S)
    n_groups = int(group.max()) + 1 if n else 0
    col_ptr = np.zeros(n + 1, dtype=np.int64)
    row_idx = []
    for j in range(n):
        r = np.flatnonzero(S[:, j])
        row_idx.extend(r.tolist())
        col_ptr[j + 1] = col_ptr[j] + len(r)
    order = np.argsort(group, kind="stable")
    grp_ptr = np.zeros(n_groups + 1, dtype=np.int64)
    for g in range(n_groups):
        grp_ptr[g + 1] = grp_ptr[g] + int(np.sum(group == g))
    return np.concatenate(([n_groups], col_ptr, np.array(row_idx, dtype=np.int64), grp_ptr,
                           order, [1 if analytic else 0])).astype(np.int64)


@njit_borrowed
def analytic(jpat):
    """True when ``jpat`` says the system's analytic Jacobian is to be used."""
    return jpat.size > 0 and jpat[jpat.size - 1] != 0


@njit_borrowed
def n_groups(jpat):
    """Number of column groups (finite-difference evaluations per Jacobian)."""
    return jpat[0] if jpat.size else 0


@njit_borrowed
def perturb_group(g, x, jpat, y, d):
    """``y = x`` with the columns of group ``g`` moved by their increments, kept in ``d``
    (``d[j]`` for the group's columns)."""
    n = x.size
    nnz = jpat[1 + n]
    gp = 2 + n + nnz
    gc = gp + jpat[0] + 1
    for i in range(n):
        y[i] = x[i]
    for k in range(jpat[gp + g], jpat[gp + g + 1]):
        j = jpat[gc + k]
        dj = math.sqrt(2.220446049250313e-16 * max(1e-5, abs(x[j])))
        y[j] = x[j] + dj
        d[j] = y[j] - x[j]            # exactly representable


@njit_borrowed
def store_group(g, f0, fp, d, jpat, J):
    """Columns of group ``g`` of ``J`` from ``f0 = f(x)`` and ``fp`` = f at the perturbed
    state of :func:`perturb_group` (only the structural nonzeros are written)."""
    n = f0.size
    nnz = jpat[1 + n]
    cp = 1
    ri = 2 + n
    gp = 2 + n + nnz
    gc = gp + jpat[0] + 1
    for k in range(jpat[gp + g], jpat[gp + g + 1]):
        j = jpat[gc + k]
        for q in range(jpat[cp + j], jpat[cp + j + 1]):
            i = jpat[ri + q]
            J[i, j] = (fp[i] - f0[i]) / d[j]


def jacobian(fun, t, x, f0, jpat, J, K, sig=None, p=None, modes=None):
    """Finite-difference Jacobian of ``fun(t, x, sig, p, modes, xdot)`` at ``(t, x)`` with
    ``f0 = f(t, x)`` (reference implementation in Python; the compiled loop sequences the
    same helpers). ``J`` must be zero outside the pattern. Returns the evaluations made."""
    y, fp, d = K[ROW_TRIAL], K[ROW_FPERT], K[ROW_SCRATCH]
    ng = n_groups(jpat)
    for g in range(ng):
        perturb_group(g, x, jpat, y, d)
        fun(t, y, sig, p, modes, fp)
        store_group(g, f0, fp, d, jpat, J)
    return ng


# --- the step --------------------------------------------------------------------------------

@njit_borrowed
def factor_matrix(J, LU, piv, h):
    """``LU`` = the LU factors of ``I / (h gamma) - J`` (pivots into ``piv``); False if it is
    singular or not finite."""
    n = J.shape[0]
    d = 1.0 / (h * GAMMA)
    for i in range(n):
        for j in range(n):
            LU[i, j] = -J[i, j]
        LU[i, i] += d
    return lu_factor(LU, piv)


@njit_borrowed
def alpha_of(stage):
    """Time fraction of stage ``stage`` (0-based: 0..3)."""
    if stage == 1:
        return ALPHA2
    if stage == 2:
        return ALPHA3
    if stage == 3:
        return ALPHA4
    return 0.0


@njit_borrowed
def stage_state(stage, x, K, y):
    """``y = x + sum_(j<stage) a_(stage, j) u_j`` (stage 1..3; the u_j in ``K[1..]``)."""
    n = x.size
    u1, u2, u3 = K[1], K[2], K[3]
    if stage == 1:
        for i in range(n):
            y[i] = x[i] + A21 * u1[i]
    elif stage == 2:
        for i in range(n):
            y[i] = x[i] + A31 * u1[i] + A32 * u2[i]
    else:
        for i in range(n):
            y[i] = x[i] + A41 * u1[i] + A42 * u2[i] + A43 * u3[i]


@njit_borrowed
def stage_rhs(stage, K, h, r):
    """Add ``sum_(j<stage) (c_(stage, j) / h) u_j`` to ``r = f(stage state)`` (stage 1..3)."""
    n = r.size
    u1, u2, u3 = K[1], K[2], K[3]
    if stage == 1:
        for i in range(n):
            r[i] += (C21 / h) * u1[i]
    elif stage == 2:
        for i in range(n):
            r[i] += (C31 * u1[i] + C32 * u2[i]) / h
    else:
        for i in range(n):
            r[i] += (C41 * u1[i] + C42 * u2[i] + C43 * u3[i]) / h


@njit_borrowed
def solution(x, K, x1):
    """``x1 = x + sum_i m_i u_i``."""
    for i in range(x.size):
        x1[i] = x[i] + M1 * K[1, i] + M2 * K[2, i] + M3 * K[3, i] + M4 * K[4, i]


@njit_borrowed
def error_norm(x, x1, K, rtol, atol):
    """Scaled RMS norm of the local error estimate ``sum_i (m_i - m_hat_i) u_i``."""
    n = x.size
    if n == 0:
        return 0.0
    acc = 0.0
    for i in range(n):
        e = E1 * K[1, i] + E2 * K[2, i] + E3 * K[3, i] + E4 * K[4, i]
        sc = atol + rtol * max(abs(x[i]), abs(x1[i]))
        acc += (e / sc) ** 2
    err = math.sqrt(acc / n)
    if not math.isfinite(err):
        return math.inf
    return err


def step(fun, t, x, h, K, x1, LU, rtol, atol, sig=None, p=None, modes=None):
    """One trial step of size ``h`` from ``(t, x)`` with ``K[0] = f(t, x)`` and ``LU`` the
    factors of ``I / (h gamma) - J`` (pivots in ``K[ROW_PIV]``) (reference implementation
    in Python; the compiled loop sequences the same helpers). Fills the stages ``K[1..4]``
    and ``x1``; returns the error norm. ``f(t + h, x1)`` is left to the caller."""
    piv = K[ROW_PIV]
    y = K[ROW_TRIAL]
    K[1, :] = K[0]
    lu_solve(LU, piv, K[1])
    for s in range(1, 4):
        stage_state(s, x, K, y)
        fun(t + alpha_of(s) * h, y, sig, p, modes, K[s + 1])
        stage_rhs(s, K, h, K[s + 1])
        lu_solve(LU, piv, K[s + 1])
    solution(x, K, x1)
    return error_norm(x, x1, K, rtol, atol)


@njit_borrowed
def factor(err, rejected):
    """Step-size factor after a trial step with error norm ``err`` (this method's constants
    in :func:`spidersim.solver.stepsize.factor`)."""
    return _factor(err, rejected, ORDER, SAFETY, MIN_FACTOR, MAX_FACTOR)


@njit_borrowed
def dense(t, h, x, x1, K, s, out):
    """State at ``s`` in ``[t, t + h]``: the cubic Hermite interpolant through ``x``,
    ``x1`` with slopes ``K[0] = f(t, x)`` and ``K[ROW_END] = f(t + h, x1)``."""
    n = x.size
    if h == 0.0:
        for i in range(n):
            out[i] = x1[i]
        return
    th = (s - t) / h
    h00 = (1.0 + 2.0 * th) * (1.0 - th) ** 2
    h10 = th * (1.0 - th) ** 2
    h01 = th * th * (3.0 - 2.0 * th)
    h11 = th * th * (th - 1.0)
    f0, f1 = K[0], K[ROW_END]
    for i in range(n):
        out[i] = h00 * x[i] + h01 * x1[i] + h * (h10 * f0[i] + h11 * f1[i])


def work_array(n):
    """The stage work array ``K`` for a state of size ``n``."""
    return np.zeros((K_ROWS, n))


def jacobian_work(n):
    """``JW``: ``JW[0]`` the Jacobian, ``JW[1]`` the LU factors."""
    return np.zeros((2, n, n))
