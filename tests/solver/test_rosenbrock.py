"""ROS34PW2 (spidersim.solver.rosenbrock) on plain functions, without a diagram: order,
stiff accuracy against closed forms and a tight Radau reference, the W-method property,
dense output, the column colouring and the finite-difference Jacobian."""
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from spidersim.solver import dp54
from spidersim.solver import rosenbrock as R


def integrate(fun, x0, t_end, rtol, atol, pattern=None, h_fixed=None, freeze_jacobian=False):
    """A plain driver over the helpers (the compiled loop's ``_advance_ros34pw2`` without
    events): a new Jacobian every step (or only the first with ``freeze_jacobian``),
    adaptive steps from the error norm unless ``h_fixed``. Returns ``x(t_end)``, steps."""
    n = len(x0)
    x = np.array(x0, float)
    K, JW, x1 = R.work_array(n), R.jacobian_work(n), np.zeros(n)
    jpat = R.pattern_array(pattern, n)
    t = 0.0
    fun(t, x, None, None, None, K[0])
    h = h_fixed or dp54.first_step(fun, t, x, K[0].copy(), t_end, rtol, atol, K)
    steps = 0
    while t < t_end * (1 - 1e-14):
        if steps == 0 or not freeze_jacobian:
            R.jacobian(fun, t, x, K[0], jpat, JW[0], K)
        rejected = False
        while True:
            h = min(h, t_end - t)
            assert R.factor_matrix(JW[0], JW[1], K[R.ROW_PIV], h)
            err = R.step(fun, t, x, h, K, x1, JW[1], rtol, atol)
            if h_fixed or err <= 1.0:
                break
            h *= R.factor(err, rejected)
            rejected = True
        t += h
        x[:] = x1
        fun(t, x, None, None, None, K[0])
        steps += 1
        if not h_fixed:
            h *= R.factor(err, rejected)
    return x, steps


def smooth(t, x, sig, p, modes, out):
    out[0] = -x[1] + 0.3 * math.cos(t)
    out[1] = x[0] - 0.1 * x[1] ** 3


def observed_order(freeze):
    ref, _ = integrate(smooth, [1.0, 0.5], 2.0, 1e-6, 1e-8, h_fixed=2e-4,
                       freeze_jacobian=freeze)
    errs = [np.linalg.norm(integrate(smooth, [1.0, 0.5], 2.0, 1e-6, 1e-8, h_fixed=h,
                                     freeze_jacobian=freeze)[0] - ref)
            for h in (0.1, 0.05, 0.025)]
    return [math.log2(errs[k] / errs[k + 1]) for k in range(2)]


def test_observed_order_is_three():
    """Global error at t = 2 of a smooth nonlinear, non-autonomous problem with fixed
    steps h, h/2, h/4: the error ratio must be 2^3 (the method's order), which guards the
    transformed coefficients and the stage sequence."""
    for q in observed_order(freeze=False):
        assert 2.9 < q < 3.1


def test_order_three_with_a_frozen_jacobian():
    """The W-method property the reuse of Jacobians relies on: with the Jacobian of the
    first step kept for the whole run (and df/dt never formed), the order is still 3."""
    for q in observed_order(freeze=True):
        assert 2.85 < q < 3.15


def test_linear_stiff_system_against_expm():
    """x' = A x with eigenvalues -1 and -1e4 (non-normal, stiffness ratio 1e4): the
    adaptive run at rtol 1e-6 agrees with expm(A) x0 at t = 1 to 1e-5 relative, in far fewer
    steps than an explicit method's stability limit (h < 2.8e-4 s: > 3500 steps) allows
    (430 measured)."""
    A = np.array([[-1.0, 50.0], [0.0, -1e4]])

    def lin(t, x, sig, p, modes, out):
        out[0] = A[0, 0] * x[0] + A[0, 1] * x[1]
        out[1] = A[1, 1] * x[1]

    x0 = np.array([1.0, 1.0])
    x, steps = integrate(lin, x0, 1.0, 1e-6, 1e-10)
    exact = expm(A) @ x0
    assert np.allclose(x, exact, rtol=1e-5, atol=1e-10)
    assert steps < 1000


def robertson(t, x, sig, p, modes, out):
    out[0] = -0.04 * x[0] + 1e4 * x[1] * x[2]
    out[1] = 0.04 * x[0] - 1e4 * x[1] * x[2] - 3e7 * x[1] ** 2
    out[2] = 3e7 * x[1] ** 2


def test_robertson_against_a_tight_radau_reference():
    """Robertson's chemical kinetics (stiffness ~1e9) to t = 40 at rtol 1e-6, atol 1e-10:
    every component within 1e-4 relative (1e-9 absolute for the tiny x2) of SciPy's Radau
    at rtol 1e-12; mass x0 + x1 + x2 = 1 conserved to 1e-10 (the stages conserve linear
    invariants exactly)."""
    x, steps = integrate(robertson, [1.0, 0.0, 0.0], 40.0, 1e-6, 1e-10)
    ref = solve_ivp(lambda t, y: (lambda o: (robertson(t, y, None, None, None, o), o)[1])(
        np.zeros(3)), (0, 40), [1.0, 0, 0], method="Radau", rtol=1e-12, atol=1e-16).y[:, -1]
    assert abs(x[0] - ref[0]) < 1e-4 * ref[0]
    assert abs(x[1] - ref[1]) < 1e-4 * ref[1] + 1e-9
    assert abs(x[2] - ref[2]) < 1e-4 * ref[2]
    assert abs(x.sum() - 1.0) < 1e-10
    assert steps < 400


def test_dense_output_is_exact_for_cubics():
    """The Hermite dense output reproduces a cubic from its end values and slopes."""
    c = np.array([0.3, -1.2, 0.7, 2.0])
    X = lambda s: c[0] + c[1] * s + c[2] * s ** 2 + c[3] * s ** 3   # noqa: E731
    dX = lambda s: c[1] + 2 * c[2] * s + 3 * c[3] * s ** 2          # noqa: E731
    t, h = 0.5, 0.25
    K = R.work_array(1)
    K[0, 0], K[R.ROW_END, 0] = dX(t), dX(t + h)
    out = np.zeros(1)
    for s in np.linspace(t, t + h, 7):
        R.dense(t, h, np.array([X(t)]), np.array([X(t + h)]), K, s, out)
        assert out[0] == pytest.approx(X(s), abs=1e-14)


def banded(t, x, sig, p, modes, out):
    """Tridiagonal coupling plus one coupling x0 -> x7."""
    n = x.size
    for i in range(n):
        out[i] = -2.0 * x[i] ** 3
        if i > 0:
            out[i] += math.sin(x[i - 1])
        if i < n - 1:
            out[i] += x[i] * x[i + 1]
    out[7] += 4.0 * x[0] ** 2


def banded_jacobian(x):
    n = x.size
    J = np.zeros((n, n))
    for i in range(n):
        J[i, i] = -6.0 * x[i] ** 2 + (x[i + 1] if i < n - 1 else 0.0)
        if i > 0:
            J[i, i - 1] = math.cos(x[i - 1])
        if i < n - 1:
            J[i, i + 1] = x[i]
    J[7, 0] += 8.0 * x[0]
    return J


def test_colouring_groups_are_structurally_orthogonal_and_fd_jacobian_is_exact():
    """Columns of a group never share a row of the pattern; a tridiagonal pattern needs 3
    groups (its chromatic number), here 4 with the extra x0 -> x7 coupling; the Jacobian from
    one evaluation per group equals the analytic one to finite-difference accuracy."""
    n = 12
    S = np.abs(banded_jacobian(np.full(n, 0.7))) > 0
    S |= np.eye(n, dtype=bool)
    S[7, 0] = True
    group = R.colour_columns(S)
    for g in range(group.max() + 1):
        cols = np.flatnonzero(group == g)
        assert S[:, cols].sum(axis=1).max() <= 1
    assert group.max() + 1 <= 4
    tri = np.eye(n, dtype=bool) | np.eye(n, k=1, dtype=bool) | np.eye(n, k=-1, dtype=bool)
    assert R.colour_columns(tri).max() + 1 == 3
    rng = np.random.default_rng(1)
    x = rng.uniform(-1, 1, n)
    jpat = R.pattern_array(S, n)
    K = R.work_array(n)
    banded(0.0, x, None, None, None, K[0])
    J = np.zeros((n, n))
    assert R.jacobian(banded, 0.0, x, K[0], jpat, J, K) == group.max() + 1
    assert np.allclose(J, banded_jacobian(x), atol=2e-7, rtol=1e-6)
    assert np.all(J[~S] == 0.0)
