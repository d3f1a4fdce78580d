"""The Arm's payload as a free rigid body: free drift, capture and release (issue 13 item 5).

Every reference is computed with plain numpy (tests/multibody/rigid_ref.py: frames, COM
Jacobians, mass matrix and momenta from the DH link table, the payload a separate body),
never with the compiled kernels.

* free payload: torque-free axisymmetric body, closed form of Euler's equations
  (``w_3`` constant, ``(w_1, w_2)`` turning at ``lambda = (I_1 - I_3) w_3 / I_1``), the
  angular momentum in the base frame and the energy constant, the COM on its straight line
  (with gravity: the parabola), the arm not loaded;
* capture of a drifting, spinning payload by a moving arm (fixed base): (a) the generalized
  momentum ``M qd + J_c^T M_p V_p`` (all n components) is conserved; (b) the base's impulse
  from an impulsive Newton-Euler recursion balances the change of the total momentum, and
  every joint axis takes no impulsive moment; (c) the angular momentum about the joint-1
  axis (the base cannot react about it) is conserved; energy is lost (plastic);
* release: the payload leaves with the twist it had on the flange and drifts on the free
  body's closed form; the joint speeds do not jump, the arm's momentum drops by the
  payload's.
"""
from __future__ import annotations

import numpy as np
import pytest

import spidersim
from spidersim.multibody import Chain

from multibody import rigid_ref as ref      # tests/ is on sys.path

N = 7
Q_FREE = [0.3, 0.7, -0.4, -1.1, 0.5, 0.9, -0.2]
QD_FREE = [0.6, -0.5, 0.8, 0.7, -1.0, 0.9, 1.2]
KW = dict(method="LSODA", jit=False)
LOG = ("log: [arm.q, arm.qd, arm.flange_pos, arm.flange_rot, arm.flange_twist, "
       "arm.payload_pos, arm.payload_rot, arm.payload_twist, arm.grapple_pos, "
       "arm.base_force]")


def _yl(v):
    return "[" + ", ".join(repr(float(x)) for x in v) + "]"


def _diagram(arm, extra_blocks="", extra_conn=""):
    return f"""
name: payload
blocks:
  tau: {{type: Constant, value: {_yl(np.zeros(N))}}}
  arm: {{type: Arm, {arm}}}
{extra_blocks}connections:
  - tau.y -> arm.tau
{extra_conn}{LOG}
"""


def _P():
    return Chain.from_yaml().P.copy()


def _around(r, t_ev):
    rows = np.flatnonzero(r.t == t_ev)
    assert len(rows) == 2, rows
    return rows[0], rows[1]


def _one_event(r, name):
    ev = [e for e in r.events if e[1:] == ("arm", name)]
    assert len(ev) == 1, r.events
    return ev[0][0]


# ==================================================================== free rigid body
I_AXI = [0.4, 0.4, 0.2]
Q0_P = [np.cos(0.3), np.sin(0.3) * 0.6, 0.0, np.sin(0.3) * 0.8]     # some attitude
WB0 = np.array([0.3, 0.0, 1.5])                                       # body axes, rad/s
V0 = np.array([0.02, -0.03, 0.01])
POS0 = np.array([1.0, 0.5, -0.2])


def _R(Q):
    w, x, y, z = np.asarray(Q) / np.linalg.norm(Q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _free_arm(gravity=(0, 0, 0)):
    R0 = _R(Q0_P)
    return (f"q0: {_yl(Q_FREE)}, gravity: {_yl(gravity)}, payload_mass: 30, "
            f"payload_com: [0, 0, 0.15], payload_inertia: {_yl(I_AXI)}, "
            f"payload_frame: base, payload_pos0: {_yl(POS0)}, payload_quat0: {_yl(Q0_P)}, "
            f"payload_v0: {_yl(V0)}, payload_w0: {_yl(R0 @ WB0)}")


def test_free_payload_follows_eulers_closed_form():
    """Axisymmetric payload (I = 0.4, 0.4, 0.2 kg m2) spinning at 1.5 rad/s about its
    symmetry axis with 0.3 rad/s across it, drifting at 3.7 cm/s, 6 s (rtol 1e-10): the
    body-axis angular velocity is ``[a cos(lam t), -a sin(lam t), w_3]`` with
    ``lam = (I_1 - I_3) w_3 / I_1 = 0.75 rad/s`` (4.5 rad of precession: a wrong sign in
    Euler's equations turns it the other way) to 1e-7 rad/s; the angular momentum
    ``R I w_b`` in the base frame and the kinetic energy are constant to 1e-8 relative; the
    COM moves on ``x0 + v t`` to 1e-9 m; the grapple fixture stays 0.15 m from the COM
    along the body axis; the arm at rest is not loaded (qd = 0, base force 0)."""
    r = spidersim.loads(_diagram(_free_arm())).simulate(t_end=6.0, rtol=1e-10, atol=1e-12,
                                                         **KW)
    t = r.t
    R = r["arm.payload_rot"].reshape(-1, 3, 3)
    w = r["arm.payload_twist"][:, 3:]
    w_b = np.einsum("kji,kj->ki", R, w)                       # R^T w
    lam = (I_AXI[0] - I_AXI[2]) * WB0[2] / I_AXI[0]
    ref_wb = np.stack([WB0[0] * np.cos(lam * t), -WB0[0] * np.sin(lam * t),
                       WB0[2] * np.ones_like(t)], axis=1)
    assert lam * t[-1] > 4.0
    assert np.abs(w_b - ref_wb).max() < 1e-7, np.abs(w_b - ref_wb).max()
    L = np.einsum("kij,kj->ki", R, w_b * I_AXI)
    assert np.abs(L - L[0]).max() < 1e-8 * np.linalg.norm(L[0])
    E = 0.5 * np.sum(I_AXI * w_b ** 2, axis=1)
    assert np.abs(E / E[0] - 1).max() < 1e-8
    x0 = POS0 + _R(Q0_P) @ [0, 0, 0.15]
    np.testing.assert_allclose(r["arm.payload_pos"], x0 + np.outer(t, V0), atol=1e-9)
    np.testing.assert_allclose(r["arm.payload_twist"][:, :3], np.tile(V0, (len(t), 1)),
                               atol=1e-12)
    d = r["arm.payload_pos"] - r["arm.grapple_pos"]
    np.testing.assert_allclose(d, R[:, :, 2] * 0.15, atol=1e-12)
    np.testing.assert_allclose(R @ R.transpose(0, 2, 1), np.tile(np.eye(3), (len(t), 1, 1)),
                               atol=1e-12)
    assert np.abs(r["arm.qd"]).max() == 0.0 and np.abs(r["arm.base_force"]).max() == 0.0


def test_free_payload_falls_with_gravity():
    """With the Arm's gravity (g = 9.81 along -z) the free payload's COM follows
    ``x0 + v t + g t^2 / 2`` (1e-9 m over 1 s) and its velocity ``v + g t``."""
    g = np.array([0.0, 0.0, -9.81])
    r = spidersim.loads(_diagram(_free_arm(g))).simulate(t_end=1.0, rtol=1e-10, atol=1e-12,
                                                          **KW)
    t = r.t
    x0 = POS0 + _R(Q0_P) @ [0, 0, 0.15]
    np.testing.assert_allclose(r["arm.payload_pos"],
                               x0 + np.outer(t, V0) + 0.5 * np.outer(t ** 2, g), atol=1e-9)
    np.testing.assert_allclose(r["arm.payload_twist"][:, :3], V0 + np.outer(t, g), atol=1e-9)


# ====================================================================== capture
T_CAP = 0.3
CAP = dict(mass=30.0, com=[0.02, -0.01, 0.15], inertia=[0.3, 0.4, 0.5])
CAP_Q = [0.9, 0.2, -0.3, 0.1]
CAP_W0 = [0.1, -0.2, 0.15]


@pytest.fixture(scope="module")
def capture_run():
    """The arm moving freely (tau = 0, g = 0) from Q_FREE at QD_FREE; a payload starting
    near the flange, drifting at [5, -2, 3] cm/s and turning; latch at 0.3 s."""
    arm = (f"q0: {_yl(Q_FREE)}, qd0: {_yl(QD_FREE)}, payload_mass: {CAP['mass']}, "
           f"payload_com: {_yl(CAP['com'])}, payload_inertia: {_yl(CAP['inertia'])}, "
           f"payload_pos0: [0.01, 0.02, -0.03], payload_quat0: {_yl(CAP_Q)}, "
           f"payload_v0: [0.05, -0.02, 0.03], payload_w0: {_yl(CAP_W0)}")
    text = _diagram(arm, f"  lat: {{type: Step, t_step: {T_CAP}}}\n",
                    "  - lat.y -> arm.latch\n")
    return spidersim.loads(text).simulate(t_end=0.6, rtol=1e-10, atol=1e-12, **KW)


def _capture_state(r, i):
    """(q, qd, payload R, COM x, COM v, w) of sample i."""
    return (r["arm.q"][i], r["arm.qd"][i], r["arm.payload_rot"][i].reshape(3, 3),
            r["arm.payload_pos"][i], r["arm.payload_twist"][i, :3],
            r["arm.payload_twist"][i, 3:])


def _Mp(R):
    return np.block([[CAP["mass"] * np.eye(3), np.zeros((3, 3))],
                     [np.zeros((3, 3)), R @ np.diag(CAP["inertia"]) @ R.T]])


def test_capture_conserves_generalized_momentum(capture_run):
    """(a) Across the capture, with J_c the Jacobian of the payload's COM on the last link
    and M_p = diag(m E, R I R^T): ``M qd + J_c^T M_p V_p`` before equals ``M qd+ +
    J_c^T M_p J_c qd+`` after, all 7 components to 1e-9 relative (joint torques are finite,
    so no joint takes an impulse). After it the payload moves with the flange: its twist
    is J_c qd+ (1e-12), and its pose relative to the flange is the one at the capture
    instant, to the end of the run. Energy is lost (a plastic impact)."""
    r = capture_run
    t_ev = _one_event(r, "latch")
    assert t_ev == pytest.approx(T_CAP, abs=1e-12)
    i0, i1 = _around(r, t_ev)
    P = _P()
    q, qd_m, R, x, v, w = _capture_state(r, i0)
    np.testing.assert_array_equal(r["arm.q"][i1], q)
    np.testing.assert_allclose(r["arm.payload_pos"][i1], x, atol=1e-15)   # no snap
    qd_p = r["arm.qd"][i1]
    M = ref.mass_matrix(P, q)
    Jc = ref.point_jacobian(P, q, N, x)
    V_m = np.concatenate([v, w])
    h_m = M @ qd_m + Jc.T @ _Mp(R) @ V_m
    h_p = M @ qd_p + Jc.T @ _Mp(R) @ Jc @ qd_p
    assert np.linalg.norm(qd_p - qd_m) > 0.1 * np.linalg.norm(qd_m)       # a real jump
    assert np.linalg.norm(h_p - h_m) < 1e-9 * np.linalg.norm(h_m), np.linalg.norm(h_p - h_m)
    np.testing.assert_allclose(r["arm.payload_twist"][i1], Jc @ qd_p, atol=1e-12)
    T_m = 0.5 * qd_m @ M @ qd_m + 0.5 * V_m @ _Mp(R) @ V_m
    T_p = 0.5 * qd_p @ (M + Jc.T @ _Mp(R) @ Jc) @ qd_p
    assert T_p < T_m * (1 - 1e-3)
    # rigidly attached afterwards: relative pose constant
    after = np.flatnonzero(r.t > t_ev)
    Rf = r["arm.flange_rot"].reshape(-1, 3, 3)
    c_rel = np.einsum("kji,kj->ki", Rf, r["arm.payload_pos"] - r["arm.flange_pos"])
    R_rel = Rf.transpose(0, 2, 1) @ r["arm.payload_rot"].reshape(-1, 3, 3)
    assert np.abs(c_rel[after] - c_rel[i0]).max() < 1e-12
    assert np.abs(R_rel[after] - R_rel[i0]).max() < 1e-12
    assert np.ptp(r["arm.q"][after], axis=0).max() > 0.05                   # it moved


def _impulse_recursion(P, q, dqd, x, R, dV):
    """Impulsive Newton-Euler, outward to inward: the impulse (force F_i, moment N_i about
    o_{i-1}) link i-1 gives link i, from the links' velocity jumps and the impulse the last
    link gives the payload (its momentum jump). Returns [(F_i, N_i)], i = 1..n."""
    F = ref.frames(P, q)
    bodies = ref.link_bodies(P, q)
    # what the flange gives the payload: force = m dv, moment about o_n
    f_next = CAP["mass"] * dV[:3]
    o_n = F[N][1]
    n_next = R @ np.diag(CAP["inertia"]) @ R.T @ dV[3:] + np.cross(x - o_n, f_next)
    out = []
    for i in range(N - 1, -1, -1):
        m, c, I, k = bodies[i]
        J = ref.point_jacobian(P, q, k, c)
        dv, dw = J[:3] @ dqd, J[3:] @ dqd
        o_prev, o_i = F[i][1], F[i + 1][1]
        Fi = m * dv + f_next
        Ni = I @ dw + np.cross(c - o_prev, m * dv) + n_next + np.cross(o_i - o_prev, f_next)
        out.append((Fi, Ni))
        f_next, n_next = Fi, Ni
    return out[::-1]


def test_capture_momentum_balance_with_the_base_impulse(capture_run):
    """(b) The total linear and angular momentum (about the base origin) of arm + payload
    after the capture equal those before plus the base's impulsive reaction, 1e-9 relative.
    The reaction comes from an impulsive Newton-Euler recursion over the links (their
    velocity jumps, the payload's momentum jump handed over at the flange); the same
    recursion shows each joint axis z_{i-1} taking no impulsive moment (< 1e-9 of the
    moments: the joints' torques are finite), and the base's impulse is far from zero
    (the fixed-base subtlety: the ISS takes momentum). (c) About the joint-1 axis, where the
    base cannot react, the angular momentum of arm + payload is conserved to 1e-9."""
    r = capture_run
    i0, i1 = _around(r, _one_event(r, "latch"))
    P = _P()
    q, qd_m, R, x, v, w = _capture_state(r, i0)
    _, qd_p, _, _, v_p, w_p = _capture_state(r, i1)
    pa_m, La_m = ref.arm_momentum(P, q, qd_m)
    pp_m, Lp_m = ref.body_momentum(CAP["mass"], CAP["inertia"], R, x, v, w)
    pa_p, La_p = ref.arm_momentum(P, q, qd_p)
    pp_p, Lp_p = ref.body_momentum(CAP["mass"], CAP["inertia"], R, x, v_p, w_p)
    p_m, L_m = pa_m + pp_m, La_m + Lp_m
    p_p, L_p = pa_p + pp_p, La_p + Lp_p
    rec = _impulse_recursion(P, q, qd_p - qd_m, x, R, np.concatenate([v_p - v, w_p - w]))
    F_base, N_base = rec[0]
    scale_p, scale_L = np.linalg.norm(p_m), np.linalg.norm(L_m)
    assert np.linalg.norm(p_p - (p_m + F_base)) < 1e-9 * scale_p
    assert np.linalg.norm(L_p - (L_m + N_base)) < 1e-9 * scale_L
    assert np.linalg.norm(F_base) > 0.05 * scale_p                 # the base does react
    Fr = ref.frames(P, q)
    for i, (Fi, Ni) in enumerate(rec):
        z = Fr[i][0][:, 2]
        assert abs(z @ Ni) < 1e-9 * max(np.linalg.norm(Ni), scale_L), (i, z @ Ni)
    z0 = np.array([0.0, 0.0, 1.0])
    assert abs(L_p @ z0 - L_m @ z0) < 1e-9 * scale_L
    assert abs(L_m @ z0) > 0.1 * scale_L                           # not trivially zero


# ====================================================================== release
T_REL = 0.25
REL_COM = [0.01, 0.03, 0.15]
REL_I = [0.3, 0.3, 0.3]           # spherical: w constant after the release (closed form)


@pytest.fixture(scope="module")
def release_run():
    """The arm moving freely with the payload latched from the start at a grasp off the
    nominal one; release at 0.25 s."""
    arm = (f"q0: {_yl(Q_FREE)}, qd0: {_yl(QD_FREE)}, payload_mass: 30, "
           f"payload_com: {_yl(REL_COM)}, payload_inertia: {_yl(REL_I)}, latched: true, "
           f"payload_pos0: [0.0, 0.01, 0.02], payload_quat0: {_yl(CAP_Q)}")
    text = _diagram(arm, f"  rel: {{type: Step, t_step: {T_REL}}}\n",
                    "  - rel.y -> arm.release\n")
    return spidersim.loads(text).simulate(t_end=1.0, rtol=1e-10, atol=1e-12, **KW)


def test_release_drifts_with_the_twist_it_had(release_run):
    """At the release the joint speeds do not jump; the payload's twist is the one it had on
    the flange, J_c qd (numpy, 1e-12); afterwards the payload is a free body: COM on
    ``x_r + v_r (t - t_r)`` (1e-9 m), axes ``Rot(w_r (t - t_r)) R_r`` (spherical inertia,
    1e-8), grapple fixture at ``-payload_com`` in its axes. The arm's momentum drops by the
    payload's at the release (links only, numpy: 1e-9 relative), and afterwards its angular
    momentum about the joint-1 axis stays at that lower value (1e-7 relative)."""
    r = release_run
    t_ev = _one_event(r, "release")
    assert t_ev == pytest.approx(T_REL, abs=1e-12)
    assert not [e for e in r.events if e[1:] == ("arm", "latch")]
    i0, i1 = _around(r, t_ev)
    np.testing.assert_array_equal(r["arm.qd"][i1], r["arm.qd"][i0])
    P = _P()
    q, qd = r["arm.q"][i0], r["arm.qd"][i0]
    x_r = r["arm.payload_pos"][i1]
    R_r = r["arm.payload_rot"][i1].reshape(3, 3)
    Jc = ref.point_jacobian(P, q, N, x_r)
    V_r = r["arm.payload_twist"][i1]
    np.testing.assert_allclose(V_r, Jc @ qd, atol=1e-12)
    np.testing.assert_allclose(r["arm.payload_twist"][i0], V_r, atol=1e-12)
    after = r.t > t_ev
    tau_ = r.t[after] - t_ev
    np.testing.assert_allclose(r["arm.payload_pos"][after], x_r + np.outer(tau_, V_r[:3]),
                               atol=1e-9)
    np.testing.assert_allclose(r["arm.payload_twist"][after],
                               np.tile(V_r, (after.sum(), 1)), atol=1e-9)
    Rs = np.array([ref.rotation(V_r[3:] * s) @ R_r for s in tau_])
    assert np.abs(r["arm.payload_rot"][after].reshape(-1, 3, 3) - Rs).max() < 1e-8
    g = r["arm.payload_pos"][after] - np.einsum("kij,j->ki", Rs, REL_COM)
    np.testing.assert_allclose(r["arm.grapple_pos"][after], g, atol=1e-8)
    # momentum: arm + payload before = arm alone after + payload
    pa_m, La_m = ref.arm_momentum(P, q, qd)
    pp, Lp = ref.body_momentum(30.0, REL_I, R_r, x_r, V_r[:3], V_r[3:])
    pa_p, La_p = ref.arm_momentum(P, q, r["arm.qd"][i1])
    tot_p, tot_L = pa_m + pp, La_m + Lp
    assert np.linalg.norm(pa_p - (tot_p - pp)) < 1e-9 * np.linalg.norm(tot_p)
    assert np.linalg.norm(pp) > 0.1 * np.linalg.norm(pa_p)          # a real drop
    Lz = [ref.arm_momentum(P, a, b)[1][2] for a, b in zip(r["arm.q"][after],
                                                          r["arm.qd"][after])]
    assert np.abs(np.array(Lz) - La_p[2]).max() < 1e-7 * abs(La_p[2])
    assert abs(La_p[2] - tot_L[2]) > 1e-3 * abs(tot_L[2])            # it did drop


def test_bad_payload_parameters_are_refused():
    """A zero quaternion and principal moments no rigid body has are refused, naming the
    block and the parameter."""
    for bad, word in (("payload_quat0: [0, 0, 0, 0]", "payload_quat0"),
                      ("payload_inertia: [1.0, 0.1, 0.1]", "payload_inertia")):
        with pytest.raises(spidersim.SpidersimError if hasattr(spidersim, "SpidersimError")
                           else Exception) as exc:
            spidersim.loads(_diagram(f"q0: {_yl(Q_FREE)}, {bad}")).simulate(t_end=0.1, **KW)
        assert "arm" in str(exc.value) and word in str(exc.value), str(exc.value)


def test_release_then_capture_again():
    """Edge-triggered inputs: released at 0.25 s (release stays high), captured again at
    0.6 s (latch rising): exactly one event of each, no spurious release after the second
    capture although the release input is still high, and the second capture conserves
    the generalized momentum (1e-9 relative, numpy)."""
    arm = (f"q0: {_yl(Q_FREE)}, qd0: {_yl(QD_FREE)}, payload_mass: 30, "
           f"payload_com: {_yl(REL_COM)}, payload_inertia: {_yl(REL_I)}, latched: true, "
           f"payload_pos0: [0.0, 0.01, 0.02], payload_quat0: {_yl(CAP_Q)}")
    text = _diagram(arm, f"  rel: {{type: Step, t_step: {T_REL}}}\n"
                         "  lat: {type: Step, t_step: 0.6}\n",
                    "  - rel.y -> arm.release\n  - lat.y -> arm.latch\n")
    r = spidersim.loads(text).simulate(t_end=0.8, rtol=1e-10, atol=1e-12, **KW)
    assert [e for e in r.events if e[1] == "arm"] == [(T_REL, "arm", "release"),
                                                      (0.6, "arm", "latch")]
    i0, i1 = _around(r, 0.6)
    P = _P()
    q, qd_m, qd_p = r["arm.q"][i0], r["arm.qd"][i0], r["arm.qd"][i1]
    R, x = r["arm.payload_rot"][i0].reshape(3, 3), r["arm.payload_pos"][i0]
    Mp = np.block([[30.0 * np.eye(3), np.zeros((3, 3))],
                   [np.zeros((3, 3)), R @ np.diag(REL_I) @ R.T]])
    M, Jc = ref.mass_matrix(P, q), ref.point_jacobian(P, q, N, x)
    h_m = M @ qd_m + Jc.T @ Mp @ r["arm.payload_twist"][i0]
    h_p = (M + Jc.T @ Mp @ Jc) @ qd_p
    assert np.linalg.norm(h_p - h_m) < 1e-9 * np.linalg.norm(h_m)
    assert np.linalg.norm(qd_p - qd_m) > 1e-3 * np.linalg.norm(qd_m)
