"""The Newton solver of algebraic loops tested alone: no YAML, no diagram, no generated code.

The residuals are plain Python functions ``residual(z, r)`` driven through
:func:`spidersim.solver.newton.solve` (the reverse-communication protocol of the generated
drivers), plus one numba-compiled driver to check the functions in nopython mode.
"""
import math

import numpy as np
import pytest

from spidersim.solver import newton as N
from spidersim.solver.newton import Workspace


class Counted:
    """A residual ``f(z, r)`` that counts its evaluations and keeps the last ``z``."""

    def __init__(self, f):
        self.f = f
        self.calls = 0
        self.last_z = None

    def __call__(self, z, r):
        self.calls += 1
        self.last_z = z.copy()
        self.f(z, r)


def start(n, z0):
    """A fresh workspace with the unknowns set to ``z0``."""
    ws = Workspace(n).new()
    N.unknowns(ws, n)[:] = z0
    return ws


def quadratic_pair(z, r):
    """Root (2, 3): ``z0^2 - z1 - 1 = 0``, ``z0 + z1^2 - 11 = 0``."""
    r[0] = z[0] * z[0] - z[1] - 1.0
    r[1] = z[0] + z[1] * z[1] - 11.0


def linear(b):
    """``A z - b`` with dyadic coefficients: from z = 0 the forward differences (increment
    2^-26) are exact, so the Jacobian is exactly ``A``."""
    def f(z, r):
        r[0] = 3.0 * z[0] + 1.0 * z[1] - b[0]
        r[1] = 1.0 * z[0] + 2.0 * z[1] - b[1]
    return f


A = np.array([[3.0, 1.0], [1.0, 2.0]])


def test_nonlinear_2x2_converges_to_known_root():
    """Guards the Newton iteration itself (step sign, Jacobian by columns, LU solve):
    a 2x2 nonlinear system with the root (2, 3) is solved to 1e-12, status 0, the
    residual evaluated last at the returned unknowns."""
    ws = start(2, [1.5, 2.5])
    res = Counted(quadratic_pair)
    status = N.solve(res, ws, 2, atol=1e-14, rtol=1e-14)
    z = N.unknowns(ws, 2)
    assert status == N.CONVERGED and ws[N.STATUS] == 0.0
    assert np.max(np.abs(z - [2.0, 3.0])) < 1e-12
    assert 1 <= ws[N.ITERS] < N.MAX_ITERATIONS and ws[N.TOTAL] == ws[N.ITERS]
    assert np.array_equal(res.last_z, z)
    assert np.array_equal(Workspace(2).array(ws, N.GOOD), z)     # kept for warm starts
    assert ws[N.JVALID] == 1.0 and ws[N.FAIL] == 0.0


def test_linear_loop_converges_in_one_iteration():
    """Guards the full (undamped) Newton step and the exact use of the Jacobian: with an
    exact Jacobian a linear system needs one step and one evaluation after it (start +
    2 columns + step = 4 evaluations)."""
    b = np.array([1.0, -2.0])
    ws = start(2, [0.0, 0.0])
    res = Counted(linear(b))
    assert N.solve(res, ws, 2, atol=1e-14, rtol=1e-14) == N.CONVERGED
    assert ws[N.ITERS] == 1 and res.calls == 4
    assert np.allclose(N.unknowns(ws, 2), np.linalg.solve(A, b), rtol=1e-14, atol=1e-15)
    # the factored Jacobian kept in the workspace is that of A
    J = N.jacobian(ws, 2)
    piv = Workspace(2).array(ws, N.PIV)
    x = np.array([1.0, 2.0])
    N.lu_solve(J, piv, x)
    assert np.allclose(x, np.linalg.solve(A, [1.0, 2.0]), rtol=1e-14)


def test_non_symmetric_linear_loop_converges_in_one_iteration():
    """Guards the orientation of the Jacobian view (row i = residual i, column j = unknown j;
    the solver's borrowed ``n x n`` matrix of the workspace): for the non-symmetric
    ``A = [[3, 1], [0.5, 2]]`` (dyadic: the differences are exact) one Newton step solves
    ``A z = b``; with ``A^T`` in its place the step would miss and need more iterations.
    The factors kept in the workspace solve ``A x = (1, 2)``."""
    An = np.array([[3.0, 1.0], [0.5, 2.0]])
    b = np.array([1.0, -2.0])

    def f(z, r):
        r[0] = 3.0 * z[0] + 1.0 * z[1] - b[0]
        r[1] = 0.5 * z[0] + 2.0 * z[1] - b[1]
    ws = start(2, [0.0, 0.0])
    res = Counted(f)
    assert N.solve(res, ws, 2, atol=1e-14, rtol=1e-14) == N.CONVERGED
    assert ws[N.ITERS] == 1 and res.calls == 4
    assert np.allclose(N.unknowns(ws, 2), np.linalg.solve(An, b), rtol=1e-14, atol=1e-15)
    x = np.array([1.0, 2.0])
    N.lu_solve(N.jacobian(ws, 2), Workspace(2).array(ws, N.PIV), x)
    assert np.allclose(x, np.linalg.solve(An, [1.0, 2.0]), rtol=1e-14)


def test_chord_jacobian_is_reused_between_solves():
    """Guards the chord iteration: a second solve of the linear system with a new right-hand
    side keeps the factored Jacobian (no column evaluations: start + step = 2 evaluations,
    one iteration), and the total iteration count accumulates."""
    ws = start(2, [0.0, 0.0])
    N.solve(linear(np.array([1.0, -2.0])), ws, 2, atol=1e-14, rtol=1e-14)
    b = np.array([5.0, 0.25])
    res = Counted(linear(b))
    assert N.solve(res, ws, 2, atol=1e-14, rtol=1e-14) == N.CONVERGED
    assert ws[N.ITERS] == 1 and res.calls == 2
    assert ws[N.TOTAL] == 2
    assert np.allclose(N.unknowns(ws, 2), np.linalg.solve(A, b), rtol=1e-14, atol=1e-15)


def test_stale_jacobian_is_refreshed_when_convergence_is_slow():
    """Guards the refresh rule (rate |r_k| / |r_k-1| > 0.1): a Jacobian kept from z ~ 1 of
    z^3 - 1 is far off for z^3 - 1000 (root 10); the solve must difference it again (more
    evaluations than iterations + 1) and still converge."""
    ws = start(1, [0.5])
    N.solve(lambda z, r: r.__setitem__(0, z[0] ** 3 - 1.0), ws, 1, atol=1e-12, rtol=1e-12)
    assert abs(N.unknowns(ws, 1)[0] - 1.0) < 1e-11
    res = Counted(lambda z, r: r.__setitem__(0, z[0] ** 3 - 1000.0))
    assert N.solve(res, ws, 1, atol=1e-12, rtol=1e-12) == N.CONVERGED
    assert abs(N.unknowns(ws, 1)[0] - 10.0) < 1e-10
    assert res.calls > ws[N.ITERS] + 1


def test_warm_start_takes_fewer_iterations():
    """Guards the warm start: a second solve of a slightly changed system starts from the
    previous solution and needs fewer iterations than a cold start from the first guess;
    non-finite unknowns on entry restart from the last converged values."""
    def shifted(c):
        def f(z, r):
            r[0] = z[0] * z[0] - z[1] - 1.0 - c
            r[1] = z[0] + z[1] * z[1] - 11.0
        return f
    ws = start(2, [1.5, 2.5])
    N.solve(quadratic_pair, ws, 2, atol=1e-12, rtol=1e-12)
    N.solve(shifted(1e-3), ws, 2, atol=1e-12, rtol=1e-12)
    warm = ws[N.ITERS]
    cold = start(2, [1.5, 2.5])
    N.solve(shifted(1e-3), cold, 2, atol=1e-12, rtol=1e-12)
    assert warm < cold[N.ITERS]
    assert np.allclose(N.unknowns(ws, 2), N.unknowns(cold, 2), rtol=1e-12)
    # NaN unknowns (left by a failed solve) restart from the last good values
    good = N.unknowns(ws, 2).copy()
    N.unknowns(ws, 2)[:] = math.nan
    res = Counted(shifted(1e-3))
    N.solve(res, ws, 2, atol=1e-12, rtol=1e-12)
    assert ws[N.ITERS] == 0 and res.calls == 1
    assert np.array_equal(N.unknowns(ws, 2), good)


def test_damping_brings_back_a_diverging_newton():
    """Guards the damping (halving while |r|^2 grows): plain Newton on atan(z) from z = 3
    diverges (|z| grows each step); damped, it converges to 0."""
    ws = start(1, [3.0])
    status = N.solve(lambda z, r: r.__setitem__(0, math.atan(z[0])), ws, 1,
                     atol=1e-12, rtol=1e-12)
    assert status == N.CONVERGED and abs(N.unknowns(ws, 1)[0]) < 1e-12


def test_round_off_step_is_accepted():
    """Guards the acceptance of a step at round-off level: z^2 - 2 is not zero at any
    floating-point z (4.4e-16 at the nearest to sqrt(2)), so with a residual tolerance of
    1e-30 only a step at round-off level ends the solve: status 0, z at sqrt(2) to 1e-13,
    instead of a failure after maxit iterations."""
    ws = start(1, [1.0])
    status = N.solve(lambda z, r: r.__setitem__(0, z[0] * z[0] - 2.0), ws, 1,
                     atol=1e-30, rtol=1e-30)
    assert status == N.CONVERGED and ws[N.ITERS] < N.MAX_ITERATIONS
    assert abs(N.unknowns(ws, 1)[0] - math.sqrt(2.0)) < 1e-13      # the acceptance level


def test_no_root_reports_status_1_with_iterations_and_residual():
    """Guards the failure record of a solve that does not converge (z^2 + 1 = 0 has no real
    root): status 1 after maxit iterations, failure time, iterations, norm and residual in
    the workspace (read by Workspace.failure), unknowns NaN and evaluated once more, the
    Jacobian marked for a refresh."""
    ws = start(1, [0.5])
    res = Counted(lambda z, r: r.__setitem__(0, z[0] * z[0] + 1.0))
    status = N.solve(res, ws, 1, t=0.25, atol=1e-10, rtol=1e-10, maxit=12)
    assert status == N.NO_CONVERGENCE and ws[N.ITERS] == 12
    fail = Workspace(1).failure(ws)
    assert fail["status"] == 1 and fail["t"] == 0.25 and fail["iterations"] == 12
    assert fail["residuals"][0] >= 1.0 and fail["norm"] > 1e9     # |r| / (atol + rtol |z|)
    assert math.isnan(N.unknowns(ws, 1)[0]) and math.isnan(res.last_z[0])
    assert ws[N.JVALID] == 0.0
    # a later successful solve keeps the failure record
    N.unknowns(ws, 1)[:] = 1.0
    N.solve(lambda z, r: r.__setitem__(0, z[0] - 2.0), ws, 1, atol=1e-12, rtol=1e-12)
    assert ws[N.STATUS] == 0.0 and Workspace(1).failure(ws)["t"] == 0.25


def test_non_finite_residual_reports_status_2():
    """Guards the check of the residual for NaN/inf: sqrt of a negative number stops the
    solve at once with status 2, the NaN residual in the failure record."""
    def f(z, r):
        with np.errstate(invalid="ignore"):
            r[0] = np.sqrt(-1.0 - z[0] ** 2)
    ws = start(1, [1.0])
    status = N.solve(f, ws, 1)
    assert status == N.NON_FINITE
    fail = Workspace(1).failure(ws)
    assert fail["status"] == 2 and fail["iterations"] == 0 and math.isnan(fail["residuals"][0])


def test_singular_jacobian_reports_status_3():
    """Guards the detection of a singular Jacobian (the unknowns do not determine the
    residual: two parallel equations): status 3, the Jacobian marked invalid."""
    def f(z, r):
        r[0] = z[0] + z[1] - 1.0
        r[1] = 2.0 * z[0] + 2.0 * z[1] - 3.0
    ws = start(2, [0.0, 0.0])
    assert N.solve(f, ws, 2) == N.SINGULAR
    fail = Workspace(2).failure(ws)
    assert fail["status"] == 3 and fail["iterations"] == 0
    assert np.array_equal(fail["residuals"], [-1.0, -3.0])
    assert ws[N.JVALID] == 0.0 and np.all(np.isnan(N.unknowns(ws, 2)))


def test_workspace_layout_is_one_partition():
    """Guards the single layout: the arrays of Workspace(n) and the views the compiled
    functions use coincide, do not overlap, and fill the workspace after the header."""
    for n in (1, 2, 5):
        L = Workspace(n)
        ws = np.arange(L.size, dtype=float)
        spans = []
        for a in (N.JAC, N.PIV, N.RES, N.EVAL, N.STEP, N.Z, N.GOOD, N.RFAIL):
            v = L.array(ws, a).ravel()
            spans.append((int(v[0]), int(v[-1]) + 1))
            if a == N.JAC:
                assert np.array_equal(N.jacobian(ws, n).ravel(), v)
            else:
                assert np.array_equal(N.vector(ws, n, a), v)
        assert spans[0][0] == N.HEAD and spans[-1][1] == L.size
        assert all(spans[k][1] == spans[k + 1][0] for k in range(len(spans) - 1))
        assert np.array_equal(N.unknowns(ws, n), L.array(ws, N.Z))
        assert np.array_equal(N.evaluation(ws, n), L.array(ws, N.EVAL))


def test_compiled_driver_matches_python_driver():
    """Guards the nopython use of the solver (as in the generated modules): a numba driver
    with a compiled residual gives the same unknowns, iterations and evaluations as the
    Python driver."""
    numba = pytest.importorskip("numba")

    @numba.njit
    def drive(ws, n):
        z = N.unknowns(ws, n)
        e = N.evaluation(ws, n)
        calls = 0
        task = N.begin(ws, n)
        while task == N.EVALUATE:
            e[0] = z[0] * z[0] - z[1] - 1.0
            e[1] = z[0] + z[1] * z[1] - 11.0
            calls += 1
            task = N.resume(ws, n, 0.0, 1e-14, 1e-14, N.MAX_ITERATIONS)
        return calls

    ws = start(2, [1.5, 2.5])
    calls = drive(ws, 2)
    ref = start(2, [1.5, 2.5])
    res = Counted(quadratic_pair)
    N.solve(res, ref, 2, atol=1e-14, rtol=1e-14)
    assert calls == res.calls and np.array_equal(ws, ref)
