"""Damped Newton for algebraic loops, specialised per loop and run inside the compiled RHS.

For a loop with tear unknowns ``z`` (n values) and residual ``r(z)`` (``z - F(z)`` for torn
signals, the constraint input for an ``AlgebraicConstraint``), :func:`newton_source` emits
a function ``solve(t, x, sig, p, modes)`` that:

1. warm-starts from the last solution (the values left in the signal array; the last
   converged values if those are not finite);
2. evaluates the residual; stops when ``max_i |r_i| / (atol_l + rtol_l |z_i|) <= 1``,
   where ``atol_l``, ``rtol_l`` are set from the integrator's tolerances (well below them);
3. otherwise takes a Newton step ``J dz = -r`` with the finite-difference Jacobian
   ``J[:, j] = (r(z + h e_j) - r(z)) / h``, ``h = sqrt(eps) max(|z_j|, 1)``, kept between
   calls (a chord iteration, as Radau does) and refreshed when the convergence rate
   ``|r_new| / |r_old|`` exceeds 0.1 (linear loops keep theirs) or a step fails;
4. damps: halves the step up to 6 times while the residual norm grows;
5. gives up after ``maxit`` iterations, reporting instead of raising: the workspace holds
   the status (0 converged, 1 no convergence, 2 non-finite residual, 3 singular Jacobian),
   the iteration count and the residual; the unknowns are set to NaN so the integrator
   rejects the step. The last failure (status, time, iterations, residuals) stays in the
   workspace, so that when the integration fails the caller can walk the loop to explain it.

Convergence is also accepted when a Newton step is at round-off level
(``|dz_i| <= 1e-13 (1 + |z_i|)``): the residual tolerance can sit below what floating point
resolves for the terms of the residual.

Everything lives in the flat arrays: the workspace is a slice of ``sig`` (Jacobian, LU
pivots, residuals, last good values, status), the tolerances two entries of ``p``.
"""
from __future__ import annotations

import math

WS_STATUS, WS_ITERS, WS_NORM, WS_JVALID, WS_TOTAL, WS_FAIL, WS_FAIL_T, WS_FAIL_ITERS = range(8)
WS_HEAD = 8


def workspace_size(n):
    """Length of a loop's workspace in ``sig`` for ``n`` unknowns."""
    return WS_HEAD + n * n + 6 * n


def fail_residual_offset(n):
    """Offset in the workspace of the residuals saved at the last failure."""
    return WS_HEAD + n * n + 5 * n


def lu_factor(a, piv):
    """In-place LU with partial pivoting of the square matrix ``a``; False if singular."""
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


def lu_solve(a, piv, b):
    """Solve ``a x = b`` in place in ``b`` from the factors of :func:`lu_factor`."""
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


_TEMPLATE = '''
@_jit
def {name}(t, x, sig, p, modes):
    """Newton solve of algebraic loop {index} ({n} unknowns)."""
    n = {n}
    zi = {zidx}
    ws = sig[{ws0}:{ws1}]
    J = ws[{oJ}:{oJ} + n * n].reshape((n, n))
    piv = ws[{oP}:{oP} + n]
    r = ws[{oR}:{oR} + n]
    r2 = ws[{oR2}:{oR2} + n]
    dz = ws[{oD}:{oD} + n]
    zgood = ws[{oG}:{oG} + n]
    rfail = ws[{oF}:{oF} + n]
    atol = p[{p_atol}]
    rtol = p[{p_rtol}]
    for i in range(n):
        if not math.isfinite(sig[zi[i]]):
            sig[zi[i]] = zgood[i]
    {resfn}(t, x, sig, p, modes, r)
    status = 1.0
    it = 0
    old = 0.0
    while it < {maxit}:
        nrm = 0.0
        ok = True
        for i in range(n):
            if not math.isfinite(r[i]):
                ok = False
            s = abs(r[i]) / (atol + rtol * abs(sig[zi[i]]))
            if s > nrm:
                nrm = s
        if not ok:
            status = 2.0
            break
        if nrm <= 1.0:
            status = 0.0
            break
        if ws[{jv}] < 0.5 or (it > 0 and nrm > 0.1 * old):
            for j in range(n):
                zj = sig[zi[j]]
                h = 1.4901161193847656e-08 * max(abs(zj), 1.0)
                sig[zi[j]] = zj + h
                {resfn}(t, x, sig, p, modes, r2)
                for i in range(n):
                    J[i, j] = (r2[i] - r[i]) / h
                sig[zi[j]] = zj
            if not lu_factor(J, piv):
                ws[{jv}] = 0.0
                status = 3.0
                break
            ws[{jv}] = 1.0
        for i in range(n):
            dz[i] = -r[i]
        lu_solve(J, piv, dz)
        tiny = True
        for i in range(n):
            if abs(dz[i]) > 1e-13 * (1.0 + abs(sig[zi[i]])):
                tiny = False
        if tiny and ws[{jv}] > 0.5:
            for i in range(n):
                sig[zi[i]] += dz[i]
            {resfn}(t, x, sig, p, modes, r)
            status = 0.0
            it += 1
            break
        n0 = 0.0
        for i in range(n):
            n0 += r[i] * r[i]
        lam = 1.0
        for i in range(n):
            sig[zi[i]] += dz[i]
        {resfn}(t, x, sig, p, modes, r)
        for _k in range(6):
            n1 = 0.0
            for i in range(n):
                n1 += r[i] * r[i]
            if math.isfinite(n1) and n1 <= n0:
                break
            lam *= 0.5
            for i in range(n):
                sig[zi[i]] -= lam * dz[i]
            {resfn}(t, x, sig, p, modes, r)
        old = nrm
        it += 1
    ws[{st}] = status
    ws[{its}] = it
    ws[{tot}] += it
    if status == 0.0:
        for i in range(n):
            zgood[i] = sig[zi[i]]
    else:
        ws[{nm}] = nrm
        ws[{fs}] = status
        ws[{ft}] = t
        ws[{fi}] = it
        for i in range(n):
            rfail[i] = r[i]
        ws[{jv}] = 0.0
        for i in range(n):
            sig[zi[i]] = math.nan
        {resfn}(t, x, sig, p, modes, r2)
'''


def newton_source(name, resfn, index, zidx, ws0, p_atol, p_rtol, maxit=30):
    """Source text of the Newton solve of one loop (see the module docstring)."""
    n = len(zidx)
    oJ = WS_HEAD
    oP = oJ + n * n
    oR, oR2, oD, oG, oF = oP + n, oP + 2 * n, oP + 3 * n, oP + 4 * n, oP + 5 * n
    return _TEMPLATE.format(
        name=name, resfn=resfn, index=index, n=n,
        zidx="(" + "".join(f"{int(i)}, " for i in zidx) + ")",
        ws0=ws0, ws1=ws0 + workspace_size(n), oJ=oJ, oP=oP, oR=oR, oR2=oR2, oD=oD, oG=oG, oF=oF,
        fs=WS_FAIL, ft=WS_FAIL_T, fi=WS_FAIL_ITERS,
        p_atol=p_atol, p_rtol=p_rtol, maxit=maxit, jv=WS_JVALID, st=WS_STATUS, its=WS_ITERS,
        tot=WS_TOTAL, nm=WS_NORM)
