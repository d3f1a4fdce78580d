"""The arm kernels called through C symbols (spidersim.multibody.native).

Compiled callers of ``mass_matrix``, ``cholesky_solve`` and ``impact_projection`` call a C
function compiled once with spidersim (data pointers and shapes of the arrays) instead of
linking the kernel's code in. These tests guard that the symbol path computes what the
jitted kernel computes (same operations: bit-identical), that it satisfies the mechanics it
stands for (``M qdd`` is the inverse dynamics' inertial part; an impact projection stops the
flange along the engaged directions and never adds kinetic energy), that the forward
dynamics beside them still inverts the inverse dynamics, that arguments of another form work
(the linked fallback), and that a caller's code really holds a call, not the kernel.
"""
from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from spidersim.multibody import Chain
from spidersim.multibody import kernels as K
from spidersim.multibody import native

ARM = Chain.from_yaml()
N = ARM.n


@njit
def _fd_caller(q, qd, tau, g, f_ext, tau_r, P, ws, M, tmp, base, qdd, key):
    K.forward_dynamics(q, qd, tau, g, f_ext, tau_r, P, ws, M, tmp, base, qdd, key)


@njit
def _mm_caller(q, P, ws, M, tmp, base):
    K.mass_matrix(q, P, ws, M, tmp, base)


@njit
def _solve_caller(A, b, x):
    K.cholesky_solve(A, b, x)


@njit
def _impact_caller(n, qd, c, M, J, Jc, Y, A, r, x):
    K.impact_projection(n, qd, c, M, J, Jc, Y, A, r, x)


def _fd_args(seed=1):
    rng = np.random.default_rng(seed)
    q, qd, tau = (rng.uniform(-1.0, 1.0, N) for _ in range(3))
    f_ext = rng.uniform(-5.0, 5.0, 6)
    tau_r = rng.uniform(-0.5, 0.5, N)
    return [q, qd, tau, np.asarray(ARM.gravity, float).copy(), f_ext, tau_r, ARM.P.copy(),
            np.zeros(K.WS_PER_LINK * (N + 1)), np.zeros((N, N)), np.zeros(6 * N),
            np.zeros(6), np.zeros(N), np.zeros(N + 2)]


def test_mass_matrix_through_the_symbol_is_the_inertial_part_of_rnea():
    """``M(q) qdd = rnea(q, 0, qdd) - rnea(q, 0, 0)`` (gravity cancels) for the M a compiled
    caller gets through the symbol, to 1e-9 N m on torques of order 1-100 N m; and M is the
    jitted kernel's bit for bit (all six arrays and their shapes reach the C function in
    order: P is 7 x 16, so swapped shapes would read it wrongly)."""
    q = np.linspace(-0.6, 0.9, N)
    qdd = np.linspace(1.0, -2.0, N)
    ws, M, tmp, base = np.zeros(K.WS_PER_LINK * (N + 1)), np.zeros((N, N)), \
        np.zeros(6 * N), np.zeros(6)
    _mm_caller(q, ARM.P, ws, M, tmp, base)
    zero = np.zeros(N)
    inertial = ARM.rnea(q, zero, qdd) - ARM.rnea(q, zero, zero)
    assert np.max(np.abs(M @ qdd - inertial)) < 1e-9
    M2 = np.zeros_like(M)
    K.mass_matrix.jitted(q, ARM.P, np.zeros_like(ws), M2, np.zeros(6 * N), np.zeros(6))
    assert np.array_equal(M, M2)


def test_forward_dynamics_on_the_symbol_inverts_the_inverse_dynamics():
    """Closed loop on the physics: ``rnea(q, qd, qdd) + reactions = tau`` for the ``qdd`` of
    compiled forward dynamics (linked: on the right-hand side's path), with an
    external wrench and drive reactions: M qdd + b = tau + Q_r + J^T f_ext, to 1e-9 N m on
    torques of order 1-100 N m."""
    args = _fd_args(seed=7)
    q, qd, tau, g, f_ext, tau_r = args[:6]
    _fd_caller(*args)
    qdd = args[11]
    back = ARM.rnea(q, qd, qdd, f_ext=f_ext, tau_r=tau_r)
    assert np.max(np.abs(back - tau)) < 1e-9


def test_cholesky_solve_through_the_symbol():
    """cholesky_solve from a compiled caller satisfies M x = b (1e-12 relative) and equals
    the jitted kernel bit for bit."""
    M = ARM.mass_matrix(np.linspace(-0.6, 0.9, N))
    b = np.arange(1.0, N + 1.0)
    x, x2 = np.zeros(N), np.zeros(N)
    _solve_caller(M.copy(), b, x)
    K.cholesky_solve.jitted(M.copy(), b, x2)
    assert np.array_equal(x, x2)
    assert np.max(np.abs(M @ x - b)) < 1e-12 * np.max(np.abs(M)) * np.max(np.abs(x))


def test_impact_projection_through_the_symbol_stops_the_engaged_directions():
    """A plastic impact on three engaged directions (translation along x and z, rotation
    about y of an identity contact frame): after the projection the flange's velocity along
    them is zero (1e-12 m/s), the kinetic energy 1/2 qd^T M qd did not grow, and the result
    is the jitted kernel's bit for bit (the integer n and nine arrays reach the C function)."""
    q = np.linspace(-0.6, 0.9, N)
    M = ARM.mass_matrix(q)
    J = ARM.jacobian(q)
    c = np.zeros(15)
    c[[0, 2, 4]] = 1.0
    c[6:] = np.eye(3).ravel()
    qd0 = np.linspace(0.3, -0.2, N)
    out = []
    for fn in (_impact_caller, K.impact_projection.jitted):
        qd = qd0.copy()
        fn(N, qd, c, M.copy(), J.ravel().copy(), np.zeros(6 * N), np.zeros(6 * N),
           np.zeros(36), np.zeros(6), np.zeros(6))
        out.append(qd)
    assert np.array_equal(out[0], out[1])
    v = J @ out[0]
    assert np.max(np.abs(v[[0, 2, 4]])) < 1e-12 and np.max(np.abs(J @ qd0)) > 0.01
    assert out[0] @ M @ out[0] <= qd0 @ M @ qd0


def test_other_argument_forms_fall_back_to_the_linked_kernel():
    """A strided (non-contiguous) array cannot go through the C signature: the caller links
    the jitted kernel instead and gets the same answer."""
    M = ARM.mass_matrix(np.linspace(-0.6, 0.9, N))
    b = np.arange(1.0, N + 1.0)
    big = np.zeros(2 * N)
    x = big[::2]                                   # layout 'A'
    _solve_caller(M.copy(), b, x)
    x2 = np.zeros(N)
    K.cholesky_solve.jitted(M.copy(), b, x2)
    assert np.array_equal(x, x2)


def test_a_caller_holds_a_call_not_the_kernel():
    """The compiled caller's code declares and calls ``spidersim_mb_mass_matrix`` and
    contains none of the kernel's own functions (no RNEA, no FK): what makes a new
    diagram's compile independent of the arm's code size."""
    q = np.linspace(-0.6, 0.9, N)
    _mm_caller(q, ARM.P, np.zeros(K.WS_PER_LINK * (N + 1)), np.zeros((N, N)),
               np.zeros(6 * N), np.zeros(6))
    (ov,) = [o for sig, o in _mm_caller.overloads.items()]
    ir = ov.library.get_llvm_str()
    assert "call void @spidersim_mb_mass_matrix(" in ir
    defined = [line for line in ir.splitlines() if line.startswith("define")]
    assert not any("rnea" in line or "kernels2fk" in line for line in defined)


@pytest.mark.parametrize("kinds, n_args", [("i11", 5), ("211", 7), ("i112111111", 20)])
def test_c_signature_flattens_arrays_to_pointer_and_shape(kinds, n_args):
    """Every array is its data pointer then one int64 per dimension; integers one int64."""
    sig = native.c_signature(kinds)
    assert len(sig.args) == n_args
    assert str(sig.return_type) == "none"
