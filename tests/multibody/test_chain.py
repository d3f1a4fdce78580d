"""The serial-chain library (spidersim.multibody) against an independent NumPy model of the
SPIDER-like arm built from PHYSICS.md's table.

The reference model below recomputes everything from the table (standard DH
``A_i = Rz(q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``, COMs in the base frame at q = 0, principal
inertias along the base axes at q = 0): frame transforms by matrix products, link COMs and
inertias carried along by ``T_i(q) T_i(0)^-1``, COM and angular Jacobians from the joint
axes ``z_{k-1}``, ``M = sum m Jv^T Jv + Jw^T I Jw``, momentum ``sum m v``,
``sum (c x m v + I w)``. None of it goes through the compiled kernels or the packed link
table ``Chain.P``.

Sign conventions (kernels.py): ``f_ext`` (force, moment about the flange origin) is applied
by the environment *to the arm*, so ``M qdd + b = tau + J^T f_ext`` and
``rnea(.., f_ext) = rnea(..) - J^T f_ext``; ``base_wrench`` is the wrench the mounting
applies to the arm (the Arm block outputs its opposite).

Regression guard: test_mass_matrix_ignores_workspace_contents and
test_chain_mass_matrix_does_not_read_past_base. ``kernels.mass_matrix`` once passed
``base[3:6]`` (3 elements) as the 6-element ``f_ext`` of ``rnea``, so the external moment
of every column came from whatever followed ``base`` in memory (no bounds check in numba):
heap contents in ``Chain``, the latch event's scratch in the Arm block. Fixed by passing all
six elements of ``base`` (zeroed before each column; rnea reads ``f_ext`` before it writes
``base``); the two tests put data after ``base`` and fail if it is read again.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from spidersim.multibody import Chain
from spidersim.multibody.chain import dh_transform
from spidersim.multibody import kernels as K

# ----------------------------------------------------------------------------- PHYSICS.md
PI = math.pi
D = [0.4603, 0.0, 0.5371, 0.0, 0.5115, 0.0, 0.1611]
ALPHA = [-PI / 2, PI / 2, PI / 2, -PI / 2, -PI / 2, PI / 2, 0.0]
MASS = [14.105, 17.378, 5.594, 10.616, 3.876, 5.506, 0.925]
COM0 = [(0, -0.0179, 0.3254), (0, 0.0038, 0.5422), (0, 0.0243, 0.8830),
        (0, -0.0115, 1.1074), (0, -0.0166, 1.3535), (0, -0.0026, 1.5293), (0, 0, 1.6247)]
INERTIA0 = [(0.2485, 0.2557, 0.0720), (0.2881, 0.2881, 0.0360), (0.2161, 0.2161, 0.0720),
            (0.1441, 0.1080, 0.0432), (0.0360, 0.0360, 0.0360), (0.0252, 0.0216, 0.0180),
            (0.0011, 0.0011, 0.0018)]
N = 7
G_EARTH = np.array([0.0, 0.0, -9.81])
GRAVITIES = {"g0": np.zeros(3), "g": G_EARTH}
SEED = 20240611
N_DRAWS = 6


def _dh(q, d, alpha):
    ct, st, ca, sa = math.cos(q), math.sin(q), math.cos(alpha), math.sin(alpha)
    return np.array([[ct, -st * ca, st * sa, 0.0], [st, ct * ca, -ct * sa, 0.0],
                     [0.0, sa, ca, d], [0.0, 0.0, 0.0, 1.0]])


class Ref:
    """Independent rigid-body model of the PHYSICS.md arm (plain NumPy)."""

    @staticmethod
    def frames(q):
        """T_0 .. T_n (4x4), T_0 = identity."""
        T = [np.eye(4)]
        for i in range(N):
            T.append(T[-1] @ _dh(q[i], D[i], ALPHA[i]))
        return T

    @classmethod
    def links(cls, q):
        """Per link: (mass, COM [base], inertia about COM [base], Jv_com (3 x n), Jw (3 x n))."""
        T, T0 = cls.frames(q), cls.frames(np.zeros(N))
        out = []
        for i in range(N):
            X = T[i + 1] @ np.linalg.inv(T0[i + 1])          # carries the q = 0 pose along
            c = (X @ np.r_[COM0[i], 1.0])[:3]
            I = X[:3, :3] @ np.diag(INERTIA0[i]) @ X[:3, :3].T
            Jv, Jw = np.zeros((3, N)), np.zeros((3, N))
            for k in range(i + 1):                               # joint k+1 moves link i+1
                z, o = T[k][:3, 2], T[k][:3, 3]
                Jv[:, k] = np.cross(z, c - o)
                Jw[:, k] = z
            out.append((MASS[i], c, I, Jv, Jw))
        return out

    @classmethod
    def mass_matrix(cls, q):
        return sum(m * Jv.T @ Jv + Jw.T @ I @ Jw for m, _c, I, Jv, Jw in cls.links(q))

    @classmethod
    def momentum(cls, q, qd):
        p, L = np.zeros(3), np.zeros(3)
        for m, c, I, Jv, Jw in cls.links(q):
            v, w = Jv @ qd, Jw @ qd
            p += m * v
            L += m * np.cross(c, v) + I @ w
        return p, L

    @classmethod
    def kinetic_energy(cls, q, qd):
        return sum(0.5 * m * (Jv @ qd) @ (Jv @ qd) + 0.5 * (Jw @ qd) @ I @ (Jw @ qd)
                   for m, _c, I, Jv, Jw in cls.links(q))

    @classmethod
    def potential_energy(cls, q, g):
        return -sum(m * g @ c for m, c, _I, _Jv, _Jw in cls.links(q))

    @classmethod
    def static_base_wrench(cls, q, g):
        """Wrench the mounting applies to the arm at rest: minus the weight and its moment."""
        L = cls.links(q)
        f = -sum(m for m, *_ in L) * g
        n = -sum(np.cross(c, m * g) for m, c, *_ in L)
        return f, n


def _draws():
    rng = np.random.default_rng(SEED)
    return [dict(q=rng.uniform(-PI, PI, N), qd=rng.uniform(-1.5, 1.5, N),
                 qdd=rng.uniform(-3.0, 3.0, N), tau=rng.uniform(-40.0, 40.0, N),
                 f_ext=np.r_[rng.uniform(-50, 50, 3), rng.uniform(-10, 10, 3)])
            for _ in range(N_DRAWS)]


DRAWS = _draws()


def _chain(g=None, pad=True):
    """The shipped arm. ``pad``: Chain._base is followed by zeros in memory, so that a
    return of the kernel bug above (floats read past ``base``) fails only the two
    ``*_past_base`` / ``*_workspace_*`` tests, deterministically, not others at random."""
    ch = Chain.from_yaml()
    ch.gravity = np.zeros(3) if g is None else np.asarray(g, float)
    if pad:
        ch._base = np.zeros(9)[:6]
    return ch


def _rel(a, b):
    return np.linalg.norm(np.asarray(a) - np.asarray(b)) / max(np.linalg.norm(b), 1e-300)


def _skew_inv(S):
    return np.array([S[2, 1] - S[1, 2], S[0, 2] - S[2, 0], S[1, 0] - S[0, 1]]) / 2


# ============================================================================= data
def test_data_file_is_the_physics_table():
    """Loaded link table: 7 links, DH d/a/alpha and masses as PHYSICS.md, total 58 kg."""
    ch = _chain()
    assert ch.n == N
    np.testing.assert_allclose(ch.P[:, 0], D, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ch.P[:, 1], 0.0, rtol=0, atol=0)
    np.testing.assert_allclose(ch.P[:, 2], ALPHA, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ch.P[:, 3], MASS, rtol=0, atol=1e-12)
    assert ch.P[:, 3].sum() == pytest.approx(58.0, abs=1e-9)
    assert sum(D) == pytest.approx(1.67, abs=1e-12)


# ============================================================================= kinematics
def test_fk_at_zero_and_joint_axes():
    """q = 0: straight up, flange at (0, 0, 1.67) with the base orientation; joint axes
    (frames 0..6 z axes, the angular rows of the Jacobian) z, y, z, -y, z, y, z."""
    ch = _chain()
    q = np.zeros(N)
    T = ch.fk(q)
    np.testing.assert_allclose(T[:3, 3], [0, 0, 1.67], rtol=0, atol=1e-12)
    np.testing.assert_allclose(T[:3, :3], np.eye(3), rtol=0, atol=1e-12)
    o = ch.frames(q)
    assert o.shape == (N + 1, 3)
    np.testing.assert_allclose(o[:, :2], 0.0, atol=1e-12)
    np.testing.assert_allclose(o[:, 2], np.r_[0, np.cumsum(D)], atol=1e-12)
    z, y = [0, 0, 1], [0, 1, 0]
    axes = np.array([z, y, z, [0, -1, 0], z, y, z], dtype=float)
    np.testing.assert_allclose(ch.jacobian(q)[3:].T, axes, rtol=0, atol=1e-12)


@pytest.mark.parametrize("k", range(N_DRAWS))
def test_fk_and_frames_match_reference(k):
    ch = _chain()
    q = DRAWS[k]["q"]
    T = Ref.frames(q)
    np.testing.assert_allclose(ch.fk(q), T[-1], rtol=0, atol=1e-12)
    np.testing.assert_allclose(ch.frames(q), np.array([Ti[:3, 3] for Ti in T]),
                               rtol=0, atol=1e-12)


@pytest.mark.parametrize("k", range(N_DRAWS))
def test_jacobian_matches_finite_differences_of_fk(k):
    """Linear rows: central differences of the flange position; angular rows: the axial
    vector of dR/dq_j R^T (h = 1e-6, truncation ~h^2 = 1e-12, rounding ~1e-10)."""
    ch = _chain()
    q = DRAWS[k]["q"]
    J = ch.jacobian(q)
    R = ch.fk(q)[:3, :3]
    h = 1e-6
    for j in range(N):
        e = np.zeros(N)
        e[j] = h
        Tp, Tm = ch.fk(q + e), ch.fk(q - e)
        v = (Tp[:3, 3] - Tm[:3, 3]) / (2 * h)
        w = _skew_inv((Tp[:3, :3] - Tm[:3, :3]) / (2 * h) @ R.T)
        np.testing.assert_allclose(J[:3, j], v, rtol=0, atol=1e-8)
        np.testing.assert_allclose(J[3:, j], w, rtol=0, atol=1e-8)


# ============================================================================= dynamics
@pytest.mark.parametrize("k", range(N_DRAWS))
def test_mass_matrix_spd_and_matches_reference(k):
    ch = _chain(G_EARTH)                 # gravity must not enter M
    q = DRAWS[k]["q"]
    M = ch.mass_matrix(q)
    ref = Ref.mass_matrix(q)
    assert np.abs(M - M.T).max() <= 1e-12 * np.abs(M).max()
    assert np.linalg.eigvalsh(M).min() > 1e-4             # smallest ~ wrist inertia
    assert _rel(M, ref) < 1e-10


def test_mass_matrix_ignores_workspace_contents():
    """The kernel must depend on q and P only: not on what its work arrays held before nor
    on the memory that follows them. Here base is a 6-element slice of a longer buffer whose
    tail holds unrelated data (as the Arm block's scratch does: v1 follows bw); see the
    fixed bug in the module docstring."""
    ch = _chain()
    q = DRAWS[0]["q"]
    ref = Ref.mass_matrix(q)
    buf = np.full(16, 3.0)
    ws = np.full(K.WS_PER_LINK * (N + 1), 7.0)
    tmp = np.full(6 * N, -5.0)
    M = np.full((N, N), 11.0)
    K.mass_matrix(q, ch.P, ws, M, tmp, buf[:6])
    np.testing.assert_array_equal(buf[6:], 3.0)              # nothing written past base
    assert _rel(M, ref) < 1e-10, f"M off by {_rel(M, ref):.3g} (relative)"


def test_chain_mass_matrix_does_not_read_past_base():
    """Chain.mass_matrix / forward_dynamics must not depend on the memory after the
    Chain's 6-element base workspace (here: data 3.0; in practice: whatever the heap holds,
    which made unpadded results vary from run to run): the fixed bug of the module
    docstring."""
    ch = _chain(pad=False)
    buf = np.full(9, 3.0)
    ch._base = buf[:6]
    s = DRAWS[1]
    ref = Ref.mass_matrix(s["q"])
    assert _rel(ch.mass_matrix(s["q"]), ref) < 1e-10, _rel(ch.mass_matrix(s["q"]), ref)
    qdd = ch.forward_dynamics(s["q"], s["qd"], s["tau"])
    b = _chain().rnea(s["q"], s["qd"], np.zeros(N))
    assert _rel(ref @ qdd + b, s["tau"]) < 1e-9


@pytest.mark.parametrize("gname", sorted(GRAVITIES))
def test_rnea_inverts_forward_dynamics(gname):
    ch = _chain(GRAVITIES[gname])
    for s in DRAWS:
        qdd = ch.forward_dynamics(s["q"], s["qd"], s["tau"])
        tau = ch.rnea(s["q"], s["qd"], qdd)
        assert _rel(tau, s["tau"]) < 1e-9
        # and the other way round: forward dynamics of the RNEA torques
        tau2 = ch.rnea(s["q"], s["qd"], s["qdd"])
        assert _rel(ch.forward_dynamics(s["q"], s["qd"], tau2), s["qdd"]) < 1e-9
        # rnea is M qdd + b: linear in qdd with the mass matrix as slope
        b = ch.rnea(s["q"], s["qd"], np.zeros(N))
        assert _rel(tau2, Ref.mass_matrix(s["q"]) @ s["qdd"] + b) < 1e-10


@pytest.mark.parametrize("k", range(N_DRAWS))
def test_static_gravity_torques_and_base_force(k):
    """g = 9.81 along -z, at rest: joint torques = dV/dq (central differences of the
    reference potential energy), base force = total weight upwards, base moment = minus the
    moment of the weights about the base origin."""
    ch = _chain(G_EARTH)
    q = DRAWS[k]["q"]
    z = np.zeros(N)
    tau = ch.rnea(q, z, z)
    h = 1e-6
    dV = np.array([(Ref.potential_energy(q + h * e, G_EARTH)
                    - Ref.potential_energy(q - h * e, G_EARTH)) / (2 * h) for e in np.eye(N)])
    np.testing.assert_allclose(tau, dV, rtol=0, atol=1e-7 * np.abs(dV).max())
    f, n = ch.base_wrench(q, z, z)
    np.testing.assert_allclose(f, [0, 0, 58.0 * 9.81], rtol=0, atol=1e-10)
    f_ref, n_ref = Ref.static_base_wrench(q, G_EARTH)
    np.testing.assert_allclose(f, f_ref, rtol=0, atol=1e-10)
    np.testing.assert_allclose(n, n_ref, rtol=0, atol=1e-10)
    # at rest, forward dynamics with exactly these torques gives zero acceleration
    assert np.abs(ch.forward_dynamics(q, z, tau)).max() < 1e-10


@pytest.mark.parametrize("k", range(N_DRAWS))
def test_momentum_and_kinetic_energy_match_reference(k):
    ch = _chain()
    s = DRAWS[k]
    p, L = ch.momentum(s["q"], s["qd"])
    p_ref, L_ref = Ref.momentum(s["q"], s["qd"])
    assert _rel(p, p_ref) < 1e-12 and _rel(L, L_ref) < 1e-12
    T = ch.kinetic_energy(s["q"], s["qd"])
    assert T == pytest.approx(Ref.kinetic_energy(s["q"], s["qd"]), rel=1e-12)


def _path(ch, q, qd, offsets, dt):
    """States at times ``offsets`` (multiples of dt, either sign) along the free motion
    (tau = 0) through (q, qd), by RK4 with step dt."""
    def f(x):
        return np.r_[x[N:], ch.forward_dynamics(x[:N], x[N:], np.zeros(N))]

    def rk4(x, h, steps):
        for _ in range(steps):
            k1 = f(x)
            k2 = f(x + h / 2 * k1)
            k3 = f(x + h / 2 * k2)
            k4 = f(x + h * k3)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        return x

    x0 = np.r_[q, qd]
    return [rk4(x0, math.copysign(dt, m), abs(m)) for m in offsets]


@pytest.mark.parametrize("k", range(3))
def test_base_wrench_is_rate_of_momentum(k):
    """g = 0, tau = 0: the wrench the mounting applies = d/dt (p, L about the base origin),
    the derivative by a 5-point stencil (h = 1 ms) along the motion integrated by RK4 with
    50 us steps (errors ~1e-12 relative)."""
    ch = _chain()
    s = DRAWS[k]
    q, qd = s["q"], s["qd"]
    qdd = ch.forward_dynamics(q, qd, np.zeros(N))
    f0, n0 = ch.base_wrench(q, qd, qdd)
    sub, dt = 20, 5e-5
    h = sub * dt
    xs = _path(ch, q, qd, [-2 * sub, -sub, sub, 2 * sub], dt)
    P = [np.r_[Ref.momentum(x[:N], x[N:])] for x in xs]
    rate = (P[0] - 8 * P[1] + 8 * P[2] - P[3]) / (12 * h)
    assert np.linalg.norm(f0) > 0.1 and np.linalg.norm(n0) > 0.1
    assert _rel(f0, rate[:3]) < 1e-6, (f0, rate[:3])
    assert _rel(n0, rate[3:]) < 1e-6, (n0, rate[3:])
    # joint 1 carries no torque: the moment about the base z axis is zero
    assert abs(n0[2]) < 1e-10 * np.linalg.norm(n0)


@pytest.mark.parametrize("k", range(N_DRAWS))
def test_external_wrench_enters_as_J_transpose(k):
    """f_ext is applied to the arm: M qdd + b = tau + J^T f_ext, i.e.
    rnea(q, qd, qdd, f_ext) = rnea(q, qd, qdd) - J^T f_ext, forward dynamics with f_ext =
    forward dynamics of tau + J^T f_ext, and at rest (g = 0) the mounting balances it."""
    ch = _chain(G_EARTH)
    s = DRAWS[k]
    q, qd, qdd, f = s["q"], s["qd"], s["qdd"], s["f_ext"]
    J = ch.jacobian(q)
    tau0 = ch.rnea(q, qd, qdd)
    tau_f = ch.rnea(q, qd, qdd, f)
    assert _rel(tau_f, tau0 - J.T @ f) < 1e-12
    assert np.linalg.norm(J.T @ f) > 1.0
    a = ch.forward_dynamics(q, qd, s["tau"], f)
    b = ch.forward_dynamics(q, qd, s["tau"] + J.T @ f)
    assert _rel(a, b) < 1e-10
    ch.gravity = np.zeros(3)
    z = np.zeros(N)
    f0, n0 = ch.base_wrench(q, z, z, f)
    p = ch.fk(q)[:3, 3]
    np.testing.assert_allclose(f0, -f[:3], rtol=0, atol=1e-12)
    np.testing.assert_allclose(n0, -(f[3:] + np.cross(p, f[:3])), rtol=0, atol=1e-12)


# ------------------------------------------------- forward dynamics: one fk per call (issue 14)
def _fd_kernel(q, qd, tau, f_ext, tau_r, ws, M, key):
    """``kernels.forward_dynamics`` on the shipped arm under gravity: (qdd, base wrench)."""
    qdd, base = np.zeros(N), np.zeros(6)
    K.forward_dynamics(q, qd, tau, G_EARTH, f_ext, tau_r, Chain.from_yaml().P, ws, M,
                       np.zeros(6 * N), base, qdd, key)
    return qdd, base


def _fd_composed(q, qd, tau, f_ext, tau_r):
    """The same from the separate kernels, each with its own forward kinematics: ``M`` by
    mass_matrix, ``b`` by rnea with ``qdd = 0`` (plus the drives' reactions), ``qdd`` from
    the Cholesky factor of ``M``, the base wrench by rnea of the resulting motion."""
    P = Chain.from_yaml().P
    ws = np.zeros(K.WS_PER_LINK * (N + 1))
    M, bias, base, qdd = np.zeros((N, N)), np.zeros(N), np.zeros(6), np.zeros(N)
    K.mass_matrix(q, P, ws, M, np.zeros(6 * N), base)
    K.cholesky_factor(M)
    K.rnea(q, qd, np.zeros(N), G_EARTH, f_ext, P, ws, bias, base)
    K.add_reactions(N, ws, tau_r, bias, base)
    K.cholesky_subst(M, tau - bias, qdd)
    K.rnea(q, qd, qdd, G_EARTH, f_ext, P, ws, bias, base)
    K.add_reactions(N, ws, tau_r, bias, base)
    return qdd, base


def _fd_draw(seed):
    rng = np.random.default_rng(seed)
    q, qd, tau = rng.uniform(-2.0, 2.0, N), rng.uniform(-1.5, 1.5, N), rng.uniform(-50, 50, N)
    return q, qd, tau, rng.uniform(-20.0, 20.0, 6), rng.uniform(-0.5, 0.5, N)


@pytest.mark.parametrize("seed", range(8))
def test_forward_dynamics_equals_the_kernels_it_fuses(seed):
    """forward_dynamics runs forward kinematics once and lets the RNEA passes reuse the
    COMs and base-frame inertias mass_matrix computed; it must give what mass_matrix + rnea
    + add_reactions give with their own fk each (same operations but for the order of the
    products in the lower triangle of R I R^T: equal to 1e-13 relative; 2,000 draws showed
    at most 2e-15), whatever ``ws`` held before (here: garbage 7.0) and with reactions on or
    off. Guards a pass that reads frames, COMs or inertias left for another q, or wrong."""
    q, qd, tau, f_ext, tau_r = _fd_draw(seed)
    for tr in (tau_r, np.zeros(N)):
        ref_qdd, ref_base = _fd_composed(q, qd, tau, f_ext, tr)
        ws = np.full(K.WS_PER_LINK * (N + 1), 7.0)
        qdd, base = _fd_kernel(q, qd, tau, f_ext, tr, ws, np.zeros((N, N)), np.zeros(0))
        np.testing.assert_allclose(qdd, ref_qdd, rtol=1e-13, atol=1e-13 * np.abs(ref_qdd).max())
        np.testing.assert_allclose(base, ref_base, rtol=1e-13,
                                   atol=1e-13 * np.abs(ref_base).max())
        # and the motion it leaves in ws is rnea's: flange frame and acceleration
        ws_r = np.zeros_like(ws)
        K.rnea(q, qd, qdd, G_EARTH, f_ext, Chain.from_yaml().P, ws_r, np.zeros(N), np.zeros(6))
        b = N * K.WS_PER_LINK
        np.testing.assert_allclose(ws[b:b + 24], ws_r[b:b + 24], rtol=0, atol=1e-12)


def test_forward_dynamics_reused_factor_recomputes_the_frames():
    """With ``key`` the Cholesky factor of M(q) is reused while q is unchanged, so
    mass_matrix (which leaves fk, the COMs and inertias in ws) does not run; if something
    wrote those of another q into ws in between (an event, another kernel on the same
    scratch: here rnea at q + 0.7), the RNEA passes must still see q's. The second call must
    reuse the factor (its strict upper triangle, poisoned with NaN, stays untouched) and
    equal a fresh evaluation to 1e-13 relative."""
    q, qd, tau, f_ext, tau_r = _fd_draw(11)
    ws = np.zeros(K.WS_PER_LINK * (N + 1))
    M, key = np.zeros((N, N)), np.zeros(N + 2)
    first, _ = _fd_kernel(q, qd, tau, f_ext, tau_r, ws, M, key)
    assert key[N + 1] == 1.0
    M[np.triu_indices(N, 1)] = np.nan
    K.rnea(q + 0.7, qd, tau, G_EARTH, f_ext, Chain.from_yaml().P, ws, np.zeros(N),
           np.zeros(6))                        # another q's frames, COMs, inertias in ws
    qdd, base = _fd_kernel(q, qd, tau, f_ext, tau_r, ws, M, key)
    assert np.isnan(M[np.triu_indices(N, 1)]).all(), "the factor was not reused"
    ref_qdd, ref_base = _fd_composed(q, qd, tau, f_ext, tau_r)
    np.testing.assert_allclose(qdd, ref_qdd, rtol=1e-13, atol=1e-13 * np.abs(ref_qdd).max())
    np.testing.assert_allclose(base, ref_base, rtol=1e-13, atol=1e-13 * np.abs(ref_base).max())
    np.testing.assert_array_equal(qdd, first)


def _fk_flange(P, ws, q):
    K.fk(q, P, ws)
    b = N * K.WS_PER_LINK
    T = np.eye(4)
    T[:3, :3] = ws[b:b + 9].reshape(3, 3)
    T[:3, 3] = ws[b + K.WS_O:b + K.WS_O + 3]
    return T


def test_fk_twist_memo_follows_the_table_and_ignores_an_empty_workspace():
    """fk keeps cos/sin of the constant twists alpha_i in ws (slots WS_TWIST): the flange
    pose must be the DH product ``prod Rz(q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)`` (NumPy, 1e-12)
    (a) on a zeroed ws, where the empty memo of the last link (alpha = 0) reads ``alpha = 0,
    cos = sin = 0`` and must not be taken, (b) on a ws the same fk filled for another table
    whose twists differ (each alpha + 0.3): the memo must follow P, not the first table."""
    P = Chain.from_yaml().P.copy()
    q = np.linspace(-1.1, 0.8, N)

    def dh_product(P):
        T = np.eye(4)
        for i in range(N):
            T = T @ dh_transform(q[i], P[i, 0], P[i, 1], P[i, 2])
        return T

    assert P[N - 1, 2] == 0.0
    ws = np.zeros(K.WS_PER_LINK * (N + 1))
    np.testing.assert_allclose(_fk_flange(P, ws, q), dh_product(P), rtol=0, atol=1e-12)
    P2 = P.copy()
    P2[:, 2] += 0.3
    np.testing.assert_allclose(_fk_flange(P2, ws, q), dh_product(P2), rtol=0, atol=1e-12)
    np.testing.assert_allclose(_fk_flange(P, ws, q), dh_product(P), rtol=0, atol=1e-12)
    assert np.abs(dh_product(P2) - dh_product(P)).max() > 0.1
