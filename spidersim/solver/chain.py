"""The chain rule over a diagram's blocks: the compiled helpers of the analytic Jacobian.

A generated diagram module that can assemble ``J = df/dx`` from its blocks' declared partial
derivatives (:mod:`spidersim.diagram.jacobian`) keeps, in a workspace after the signals,
the *sensitivities* ``S[r, c] = d v_r / d x_c`` of every value ``v_r`` on a path into a
derivative (the states themselves: ``S[x_k] = e_k``), then, block by block in schedule order::

    S[y_block]   = dydx S[x_block] + dydu S[u_block]      (outputs that are not states)
    J[x'_block]  = dfdx S[x_block] + dfdu S[u_block]      (the block's derivative rows)

each row only over the columns ``c`` it can depend on (the structural pattern, decided by
the generator). The index lists (rows of the block's states and of the sources of its
inputs, target rows, columns) are slices of one constant int64 table of the module.
Pure functions on arrays, compiled once for every diagram, allocation-free.
"""
from __future__ import annotations

from ._jit import njit_borrowed


#: the fields of one :func:`chain` call's record in the index table (``tab[h + FIELD]``)
D0, DST0, NDST, SRC0, NSRC, COL0, NCOL, ACC = range(8)
RECORD = 8


@njit_borrowed
def chain(T, D, S, tab, h):
    """``T[dst_i, c] (+)= sum_j D[d0 + i, j] S[src_j, c]`` for the target rows ``dst_i =
    tab[dst0 + i]`` (``i < ndst``), source rows ``src_j = tab[src0 + j]`` (``j < nsrc``) and
    columns ``c = tab[col0 + q]`` (``q < ncol``); ``acc``: add to ``T`` instead of
    overwriting it. The eight numbers ``d0, dst0, ndst, src0, nsrc, col0, ncol, acc`` are
    the call's record ``tab[h:h + 8]`` (:data:`RECORD`): the generated module passes one
    run-time integer ``h`` (``np.int64(h)``), so that numba compiles this function once for
    every diagram instead of once for every combination of constants (a literal integer
    argument is a type of its own). Zero entries of ``D`` are skipped, and a source row
    that is a state's (``src_j < n_x``, ``S[src_j] = e_(src_j)``, always among the target's
    columns) adds ``D[d0 + i, j]`` to the one entry ``T[dst_i, src_j]`` instead of a pass
    over the columns (a block's own states: ``dfdx`` costs its entries, not entries times
    columns)."""
    n_x = S.shape[1]
    d0, dst0, ndst = tab[h + D0], tab[h + DST0], tab[h + NDST]
    src0, nsrc = tab[h + SRC0], tab[h + NSRC]
    col0, ncol, acc = tab[h + COL0], tab[h + NCOL], tab[h + ACC] != 0
    for i in range(ndst):
        r = tab[dst0 + i]
        if not acc:
            for q in range(ncol):
                T[r, tab[col0 + q]] = 0.0
        for j in range(nsrc):
            d = D[d0 + i, j]
            if d != 0.0:
                s = tab[src0 + j]
                if s < n_x:
                    T[r, s] += d
                else:
                    for q in range(ncol):
                        c = tab[col0 + q]
                        T[r, c] += d * S[s, c]


@njit_borrowed
def zero(a):
    """``a[:] = 0`` element by element (a block's partial matrices before its kernel)."""
    for i in range(a.size):
        a[i] = 0.0


@njit_borrowed
def seed(S, n):
    """``S[k, k] = 1`` for the ``n`` state rows (``d x_k / d x_k``; the other entries of those
    rows are never written). ``n`` is passed as a run-time integer (``np.int64(n)``), as
    :func:`chain`'s record."""
    for k in range(n):
        S[k, k] = 1.0
