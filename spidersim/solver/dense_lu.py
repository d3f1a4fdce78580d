"""Dense LU factorisation with partial pivoting, in place, allocation-free, for the stiff
methods' iteration matrices (``I - c J``, ``I/(h gamma) - J``) and the algebraic-loop Newton.

Two implementations behind one pair of functions, chosen by the matrix order ``n`` alone (so
that :func:`lu_factor` and :func:`lu_solve` always agree):

- ``n < LAPACK_MIN_N``: a plain loop (Doolittle, row ``k`` swapped with the largest pivot
  of column ``k``); ``piv[k]`` holds that row (as a float);
- ``n >= LAPACK_MIN_N``: LAPACK ``dgetrf`` (blocked, through numba's own binding to SciPy's
  ``cython_lapack``, which numba caches like any ``np.linalg`` call). The C-ordered
  ``a`` is the Fortran matrix ``B = a^T``; ``dgetrf`` gives ``P B = L U`` and ``a = B^T =
  U^T L^T P``, so ``a x = b`` is solved as ``U^T y = b`` (forward: the lower triangle of the
  stored array with its diagonal, read along rows), ``L^T z = y`` (backward: the strict
  upper triangle, unit diagonal) and ``x = P^T z`` (the row swaps in reverse order). The
  pivot indices (Fortran integers, 1-based) are kept in the bytes of ``piv``.

Measured on a 91 x 91 matrix (SPIDER's 91 states, one core): the loop 110 us per
factorisation, ``dgetrf`` about 30 us; the solve costs the same in both (two triangular
sweeps, ~6 us).
"""
from __future__ import annotations

import math

import numpy as np
from numba import types
from numba.np import linalg as _nplinalg

from ._jit import njit, njit_borrowed

#: matrices of this order or larger use LAPACK's blocked ``dgetrf``
LAPACK_MIN_N = 24

_F_INT = np.int64 if _nplinalg.F_INT_nbtype == types.int64 else np.int32
_getrf = _nplinalg._LAPACK().numba_xxgetrf(types.float64)
_KIND_D = ord("d")


@njit_borrowed
def _factor_small(a, piv):
    n = a.shape[0]
    for k in range(n):
        m = k
        big = abs(a[k, k])
        for i in range(k + 1, n):
            if abs(a[i, k]) > big:
                big = abs(a[i, k])
                m = i
        piv[k] = m
        if big == 0.0 or not math.isfinite(big):
            return False
        if m != k:
            for j in range(n):
                tmp = a[k, j]
                a[k, j] = a[m, j]
                a[m, j] = tmp
        for i in range(k + 1, n):
            a[i, k] /= a[k, k]
            f = a[i, k]
            for j in range(k + 1, n):
                a[i, j] -= f * a[k, j]
    return True


@njit_borrowed
def _solve_small(a, piv, b):
    n = a.shape[0]
    for k in range(n):
        m = int(piv[k])
        if m != k:
            tmp = b[k]
            b[k] = b[m]
            b[m] = tmp
    for i in range(n):
        acc = b[i]
        for j in range(i):
            acc -= a[i, j] * b[j]
        b[i] = acc
    for i in range(n - 1, -1, -1):
        acc = b[i]
        for j in range(i + 1, n):
            acc -= a[i, j] * b[j]
        b[i] = acc / a[i, i]


@njit_borrowed
def _factor_lapack(a, piv):
    n = a.shape[0]
    for i in range(n):                       # dgetrf does not stop at a NaN: check first
        for j in range(n):
            if not math.isfinite(a[i, j]):
                return False
    ipiv = piv.view(_F_INT)
    info = _getrf(_KIND_D, n, n, a.ctypes, n, ipiv.ctypes)
    return info == 0


@njit_borrowed
def _solve_lapack(a, piv, b):
    n = a.shape[0]
    ipiv = piv.view(_F_INT)
    for i in range(n):                       # U^T y = b
        acc = b[i]
        for j in range(i):
            acc -= a[i, j] * b[j]
        b[i] = acc / a[i, i]
    for i in range(n - 1, -1, -1):           # L^T z = y
        acc = b[i]
        for j in range(i + 1, n):
            acc -= a[i, j] * b[j]
        b[i] = acc
    for k in range(n - 1, -1, -1):           # x = P^T z
        m = ipiv[k] - 1
        if m != k:
            tmp = b[k]
            b[k] = b[m]
            b[m] = tmp


@njit_borrowed
def lu_factor(a, piv):
    """In-place LU factorisation with partial pivoting.

    Parameters
    ----------
    a : (n, n) float array, C order
        Overwritten by the factors (layout in the module docstring).
    piv : (n,) float array, contiguous
        Overwritten by the pivots.

    Returns
    -------
    bool
        False if the matrix is singular (an exactly zero pivot) or not finite.
    """
    if a.shape[0] >= LAPACK_MIN_N:
        return _factor_lapack(a, piv)
    return _factor_small(a, piv)


@njit_borrowed
def lu_solve(a, piv, b):
    """Solve ``a x = b`` in place in ``b`` from the factors of :func:`lu_factor`."""
    if a.shape[0] >= LAPACK_MIN_N:
        _solve_lapack(a, piv, b)
    else:
        _solve_small(a, piv, b)
