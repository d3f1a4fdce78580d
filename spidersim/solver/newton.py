"""Damped Newton for algebraic loops: fixed compiled functions driven by reverse communication.

A loop has ``n`` tear unknowns ``z`` and a residual ``r(z)`` (``z - F(z)`` for a torn signal
``z = F(z)``, the constraint input ``f(z)`` of an ``AlgebraicConstraint``). The solver never
calls the residual: the generated module owns a small driver per loop that evaluates it when
asked (reverse communication), so the functions here are ordinary numba functions over one
float array, the loop's *workspace* (a slice of ``sig``, layout in :class:`Workspace`),
compiled and cached once for every diagram::

    z = unknowns(ws, n); e = evaluation(ws, n)
    z[:] = current values of the unknowns             # warm start
    task = begin(ws, n)
    while task == EVALUATE:
        put z into the diagram; e[:] = r(z)
        task = resume(ws, n, t, atol, rtol, maxit)
    # z holds the solution (NaN after a failure); the diagram was last evaluated at z

The algorithm (one solve):

1. warm start from the values the unknowns have on entry, the last converged values
   ``z_good`` replacing those that are not finite;
2. evaluate ``r(z)``; stop when

   .. math:: \\|r\\|_w = \\max_i \\frac{|r_i|}{atol_l + rtol_l |z_i|} \\le 1,

   where ``atol_l``, ``rtol_l`` are set from the integrator's tolerances (well below them);
3. otherwise solve ``J dz = -r`` with the forward-difference Jacobian

   .. math:: J_{:,j} = \\frac{r(z + h_j e_j) - r(z)}{h_j}, \\quad
             h_j = \\sqrt{\\epsilon} \\max(|z_j|, 1),

   LU-factored (:func:`lu_factor`) and kept between steps and between solves (a chord
   iteration, as Radau does); it is refreshed when it is not valid (first solve, after a
   failure) or when the convergence rate ``\\|r_k\\|_w / \\|r_{k-1}\\|_w`` exceeds 0.1
   (linear loops keep theirs);
4. accept at once a step at round-off level, ``|dz_i| <= 1e-13 (1 + |z_i|)`` for all ``i``
   (then ``z + dz`` is evaluated and the solve has converged): the residual tolerance can
   sit below what floating point resolves for the terms of the residual;
5. otherwise damp: take ``z + lambda dz`` with ``lambda = 1``, and while
   ``|r(z + lambda dz)|_2^2 > |r(z)|_2^2`` (or is not finite) halve ``lambda``, at most 6
   times (the last halved point is kept whatever its residual);
6. give up after ``maxit`` iterations, reporting instead of raising: ``ws[STATUS]`` is 0
   converged, 1 no convergence, 2 non-finite residual, 3 singular Jacobian; ``ws[ITERS]``
   the iterations of this solve, ``ws[TOTAL]`` the sum over all solves. On a failure the
   unknowns are set to NaN and evaluated once more (the integrator then rejects the step),
   the Jacobian is marked invalid, and the failure record (status, time, iterations,
   residual norm, residuals) stays in the workspace until the next failure, so that when
   the integration fails the caller can explain it (:meth:`Workspace.failure`).

Every solve ends with an evaluation of the diagram at the returned unknowns.
"""
from __future__ import annotations

import math

import numpy as np

from ._jit import njit, njit_borrowed
from .borrow import matrix
from .dense_lu import lu_factor, lu_solve  # noqa: F401  (re-exported: the loop solver's LU)

#: iteration limit of one solve
MAX_ITERATIONS = 30

#: what :func:`begin` and :func:`resume` ask of the driver
DONE, EVALUATE = 0, 1

#: status codes (``ws[STATUS]``, ``ws[FAIL]``)
CONVERGED, NO_CONVERGENCE, NON_FINITE, SINGULAR = 0, 1, 2, 3

# --- workspace header: one float each ------------------------------------------------------
#: results: last status, its iterations, residual norm at the last failure, Jacobian valid
#: (1.0) or not, iterations summed over all solves, failure record (status, time, iterations)
STATUS, ITERS, NORM, JVALID, TOTAL, FAIL, FAIL_T, FAIL_ITERS = range(8)
#: reverse-communication state of the solve in progress: phase, iteration, norm at the top
#: of this iteration, that of the previous one, ``|r|^2`` before the step, damping factor,
#: halvings done, Jacobian column being differenced, its unperturbed value and increment
PHASE, IT, CUR_NORM, OLD_NORM, N0, LAM, HALVINGS, COL, ZCOL, H = range(8, 18)
HEAD = 18

# --- workspace arrays, after the header, in this order -------------------------------------
#: Jacobian (n x n, LU factors once factored), pivots, residual at z, the driver's
#: evaluation, Newton step, unknowns, last converged unknowns, residuals at the last failure
JAC, PIV, RES, EVAL, STEP, Z, GOOD, RFAIL = range(8)
N_VECTORS = 7

# phases: the evaluation :func:`resume` is waiting for
_P_IDLE, _P_START, _P_COLUMN, _P_STEP, _P_DAMP, _P_ROUNDOFF, _P_FAILED = range(7)

_SQRT_EPS = 1.4901161193847656e-08      # sqrt(2^-52)
_ROUNDOFF = 1e-13
_MAX_HALVINGS = 6
_RATE = 0.1


def _size(n):
    """Length of a loop's workspace for ``n`` unknowns: ``HEAD + n^2 + 7 n``."""
    return HEAD + n * n + N_VECTORS * n


def _offset(n, a):
    """Offset in the workspace of array ``a`` (``JAC``, ``PIV``, ... ``RFAIL``)."""
    if a == JAC:
        return HEAD
    return HEAD + n * n + (a - 1) * n


array_offset = njit(_offset)


@njit
def vector(ws, n, a):
    """View of the length-``n`` array ``a`` (``PIV`` ... ``RFAIL``) of the workspace."""
    o = array_offset(n, a)
    return ws[o:o + n]


@njit
def jacobian(ws, n):
    """View of the ``n x n`` Jacobian (or its LU factors) of the workspace."""
    return ws[HEAD:HEAD + n * n].reshape((n, n))


@njit_borrowed(inline="always")
def _vec(ws, n, a):
    """:func:`vector` for the solver's own functions: compiled without numba's reference
    counting (``njit_borrowed``), as they are. A view taken in a counted function costs an
    atomic increment and decrement of the workspace's count; :func:`begin` and
    :func:`resume` take three to six views per residual evaluation."""
    o = HEAD + n * n + (a - 1) * n
    return ws[o:o + n]


@njit_borrowed(inline="always")
def _jac(ws, n):
    """:func:`jacobian` for the solver's own functions (not counted, see :func:`_vec`):
    a borrowed ``n x n`` view (:func:`spidersim.solver.borrow.matrix`), without the call of
    numba's reshape helper that ``reshape`` makes once per factorisation and solve step."""
    return matrix(ws, HEAD, n, n)


@njit
def unknowns(ws, n):
    """The unknowns ``z``: the driver sets them before :func:`begin` and puts them into the
    diagram before each evaluation."""
    return vector(ws, n, Z)


@njit
def evaluation(ws, n):
    """Where the driver writes ``r(z)`` when asked to evaluate."""
    return vector(ws, n, EVAL)


class Workspace:
    """Layout of the Newton workspace of a loop with ``n`` unknowns.

    The workspace is ``size`` floats (a slice of ``sig`` starting at the loop's offset):
    a header of ``HEAD`` named slots (module constants ``STATUS`` ... ``H``), then the
    arrays ``JAC`` (``n x n``), ``PIV``, ``RES``, ``EVAL``, ``STEP``, ``Z``, ``GOOD``,
    ``RFAIL`` (``n`` each). It starts as zeros (no valid Jacobian, last good values 0).

    Parameters
    ----------
    n : int
        Number of unknowns (tear variables, element by element).
    """

    def __init__(self, n):
        self.n = int(n)
        self.size = _size(self.n)

    def offset(self, a):
        """Offset of array ``a`` (``JAC`` ... ``RFAIL``) in the workspace."""
        return _offset(self.n, a)

    def array(self, ws, a):
        """View of array ``a`` of the workspace ``ws`` (``n x n`` for ``JAC``)."""
        o = self.offset(a)
        if a == JAC:
            return ws[o:o + self.n * self.n].reshape((self.n, self.n))
        return ws[o:o + self.n]

    def new(self):
        """A fresh workspace (zeros)."""
        return np.zeros(self.size)

    @staticmethod
    def total_iterations(ws):
        """Newton iterations summed over every solve of the workspace ``ws``."""
        return int(ws[TOTAL])

    def failure(self, ws):
        """The last failure recorded in ``ws``: ``None``, or a dict with ``status`` (1 no
        convergence, 2 non-finite residual, 3 singular Jacobian), ``t``, ``iterations``,
        ``norm`` (weighted residual norm) and ``residuals`` (a copy)."""
        status = int(ws[FAIL])
        if not status:
            return None
        return {"status": status, "t": float(ws[FAIL_T]), "iterations": int(ws[FAIL_ITERS]),
                "norm": float(ws[NORM]), "residuals": self.array(ws, RFAIL).copy()}


@njit_borrowed
def begin(ws, n):
    """Start a solve from the unknowns in ``unknowns(ws, n)`` (non-finite ones replaced by
    the last converged values); returns ``EVALUATE`` (the residual at the start)."""
    z = _vec(ws, n, Z)
    good = _vec(ws, n, GOOD)
    for i in range(n):
        if not math.isfinite(z[i]):
            z[i] = good[i]
    ws[IT] = 0.0
    ws[OLD_NORM] = 0.0
    ws[PHASE] = _P_START
    return EVALUATE


@njit_borrowed
def resume(ws, n, t, atol, rtol, maxit):
    """Go on with the solve once ``evaluation(ws, n)`` holds ``r(z)`` as asked.

    Parameters
    ----------
    ws : float array
        The loop's workspace.
    n : int
        Number of unknowns.
    t : float
        Time (kept in the failure record).
    atol, rtol : float
        Weights of the residual norm ``max_i |r_i| / (atol + rtol |z_i|)``.
    maxit : int
        Iteration limit.

    Returns
    -------
    int
        ``EVALUATE``: put ``unknowns(ws, n)`` into the diagram, evaluate the residual into
        ``evaluation(ws, n)`` and call again; ``DONE``: finished, ``ws[STATUS]`` says how.
    """
    phase = int(ws[PHASE])
    e = _vec(ws, n, EVAL)
    r = _vec(ws, n, RES)
    z = _vec(ws, n, Z)
    if phase == _P_COLUMN:
        j = int(ws[COL])
        h = ws[H]
        J = _jac(ws, n)
        for i in range(n):
            J[i, j] = (e[i] - r[i]) / h
        z[j] = ws[ZCOL]
        if j + 1 < n:
            return _perturb(ws, z, j + 1)
        if not lu_factor(J, _vec(ws, n, PIV)):
            ws[JVALID] = 0.0
            return _finish(ws, n, t, SINGULAR)
        ws[JVALID] = 1.0
        return _step(ws, n)
    if phase == _P_FAILED:
        ws[PHASE] = _P_IDLE
        return DONE
    for i in range(n):
        r[i] = e[i]
    if phase == _P_START:
        return _top(ws, n, t, atol, rtol, maxit)
    if phase == _P_ROUNDOFF:
        return _finish(ws, n, t, CONVERGED)
    if phase == _P_DAMP:
        ws[HALVINGS] += 1.0
    # after the full step or a halving: damp while the residual grows
    if ws[HALVINGS] < _MAX_HALVINGS:
        n1 = 0.0
        for i in range(n):
            n1 += r[i] * r[i]
        if not (math.isfinite(n1) and n1 <= ws[N0]):
            lam = 0.5 * ws[LAM]
            ws[LAM] = lam
            dz = _vec(ws, n, STEP)
            for i in range(n):
                z[i] -= lam * dz[i]
            ws[PHASE] = _P_DAMP
            return EVALUATE
    ws[OLD_NORM] = ws[CUR_NORM]
    ws[IT] += 1.0
    return _top(ws, n, t, atol, rtol, maxit)


@njit_borrowed
def _top(ws, n, t, atol, rtol, maxit):
    """Top of a Newton iteration, ``r = r(z)`` known: test, refresh the Jacobian or step."""
    if ws[IT] >= maxit:
        return _finish(ws, n, t, NO_CONVERGENCE)
    r = _vec(ws, n, RES)
    z = _vec(ws, n, Z)
    nrm = 0.0
    ok = True
    for i in range(n):
        if not math.isfinite(r[i]):
            ok = False
        s = abs(r[i]) / (atol + rtol * abs(z[i]))
        if s > nrm:
            nrm = s
    ws[CUR_NORM] = nrm
    if not ok:
        return _finish(ws, n, t, NON_FINITE)
    if nrm <= 1.0:
        return _finish(ws, n, t, CONVERGED)
    if ws[JVALID] < 0.5 or (ws[IT] > 0 and nrm > _RATE * ws[OLD_NORM]):
        return _perturb(ws, z, 0)
    return _step(ws, n)


@njit_borrowed
def _perturb(ws, z, j):
    """Ask for ``r(z + h_j e_j)``, Jacobian column ``j``."""
    zj = z[j]
    h = _SQRT_EPS * max(abs(zj), 1.0)
    ws[COL] = j
    ws[ZCOL] = zj
    ws[H] = h
    z[j] = zj + h
    ws[PHASE] = _P_COLUMN
    return EVALUATE


@njit_borrowed
def _step(ws, n):
    """Newton step ``dz = -J^{-1} r`` from the factored Jacobian; ask for ``r(z + dz)``."""
    r = _vec(ws, n, RES)
    z = _vec(ws, n, Z)
    dz = _vec(ws, n, STEP)
    for i in range(n):
        dz[i] = -r[i]
    lu_solve(_jac(ws, n), _vec(ws, n, PIV), dz)
    tiny = True
    for i in range(n):
        if abs(dz[i]) > _ROUNDOFF * (1.0 + abs(z[i])):
            tiny = False
    if tiny and ws[JVALID] > 0.5:
        for i in range(n):
            z[i] += dz[i]
        ws[IT] += 1.0
        ws[PHASE] = _P_ROUNDOFF
        return EVALUATE
    n0 = 0.0
    for i in range(n):
        n0 += r[i] * r[i]
    ws[N0] = n0
    ws[LAM] = 1.0
    ws[HALVINGS] = 0.0
    for i in range(n):
        z[i] += dz[i]
    ws[PHASE] = _P_STEP
    return EVALUATE


@njit_borrowed
def _finish(ws, n, t, status):
    """Record the outcome; on a failure set the unknowns to NaN and ask for their
    evaluation."""
    it = ws[IT]
    ws[STATUS] = status
    ws[ITERS] = it
    ws[TOTAL] += it
    z = _vec(ws, n, Z)
    if status == CONVERGED:
        good = _vec(ws, n, GOOD)
        for i in range(n):
            good[i] = z[i]
        ws[PHASE] = _P_IDLE
        return DONE
    ws[NORM] = ws[CUR_NORM]
    ws[FAIL] = status
    ws[FAIL_T] = t
    ws[FAIL_ITERS] = it
    r = _vec(ws, n, RES)
    rf = _vec(ws, n, RFAIL)
    for i in range(n):
        rf[i] = r[i]
    ws[JVALID] = 0.0
    for i in range(n):
        z[i] = math.nan
    ws[PHASE] = _P_FAILED
    return EVALUATE


def solve(residual, ws, n, t=0.0, atol=1e-12, rtol=1e-12, maxit=MAX_ITERATIONS):
    """Drive one solve from Python (the protocol of the generated drivers, for tests and
    tools): ``residual(z, r)`` writes ``r(z)`` into ``r``; the unknowns start from
    ``unknowns(ws, n)``. Returns the status (``ws[STATUS]``)."""
    z = unknowns(ws, n)
    e = evaluation(ws, n)
    task = begin(ws, n)
    while task == EVALUATE:
        residual(z, e)
        task = resume(ws, n, t, atol, rtol, maxit)
    return int(ws[STATUS])
