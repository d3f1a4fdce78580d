"""The dense LU of the stiff methods and the loop Newton (``solver/dense_lu.py``), tested
alone against numpy on both of its implementations (the plain loop below
``LAPACK_MIN_N``, LAPACK ``dgetrf`` with the transposed-storage solve from there on)."""
import numpy as np
import pytest

from spidersim.solver import dense_lu as D

ORDERS = [1, 2, 5, D.LAPACK_MIN_N - 1, D.LAPACK_MIN_N, D.LAPACK_MIN_N + 1, 91]


@pytest.mark.parametrize("n", ORDERS)
def test_solves_like_numpy_with_pivoting(n):
    """Guards both factorisations and their solves, including row swaps: the leading
    pivot is zero (a swap is needed at step 0) and the matrix is not diagonally dominant,
    so a solve that applies the swaps in the wrong order or the wrong triangle fails."""
    rng = np.random.default_rng(n)
    a = rng.normal(size=(n, n))
    if n > 1:
        a[0, 0] = 0.0
        a[1, 0] = 5.0                            # row 1 is the first pivot
    lu, piv = a.copy(), np.zeros(n)
    assert D.lu_factor(lu, piv)
    for _ in range(2):                           # factors reused for several right-hand sides
        b = rng.normal(size=n)
        x = b.copy()
        D.lu_solve(lu, piv, x)
        ref = np.linalg.solve(a, b)
        assert np.allclose(x, ref, rtol=1e-10, atol=1e-10 * np.abs(ref).max())


@pytest.mark.parametrize("n", [2, D.LAPACK_MIN_N, 40])
def test_singular_and_non_finite_are_reported(n):
    """Guards the failure report the stiff methods rely on (a step is then retried smaller):
    an exactly singular matrix (two equal rows) and a NaN entry both return False."""
    a = np.eye(n)
    a[1] = a[0]
    assert not D.lu_factor(a.copy(), np.zeros(n))
    b = np.eye(n)
    b[n - 1, 0] = np.nan
    assert not D.lu_factor(b, np.zeros(n))


def test_iteration_matrix_of_a_stiff_system():
    """Guards the use in the stiff methods: ``(I - c J) x = r`` for the Jacobian of a
    91-state chain of lags with one dense coupled block (the shape of SPIDER's arm rows),
    against numpy, at a step where ``c |lambda|`` spans 1e-3 .. 1e4."""
    n = 91
    rng = np.random.default_rng(7)
    J = np.diag(-np.logspace(0, 7, n))
    J[np.arange(1, n), np.arange(n - 1)] = 1.0
    J[-14:, :] += rng.normal(size=(14, n))
    c = 1e-3
    M = np.eye(n) - c * J
    lu, piv = M.copy(), np.zeros(n)
    assert D.lu_factor(lu, piv)
    r = rng.normal(size=n)
    x = r.copy()
    D.lu_solve(lu, piv, x)
    assert np.linalg.norm(M @ x - r) <= 1e-12 * np.linalg.norm(r)
