"""The rotors' reaction torques in the multibody model (issue 13, item 7).

Drive i (stator, gear housing) sits on link i-1; beyond the joint torque it passes to link
i it applies ``tau_r = -J_m dw_m/dt`` about joint i's axis to link i-1 (the Arm module
docstring derives it from the torque balance of rotor, gear and housing). Checked here:

* the kernels: ``add_reactions`` is the generalized force of those moments by virtual work
  (``Q_j = sum_k J_w,k[:, j] . m_k`` with the angular Jacobian of the link carrying each
  moment, built from ``Chain.jacobian``), the base moment gains the sum of the moments and
  the base force nothing; ``forward_dynamics`` solves ``M qdd = tau - b + Q_r``;
* one joint on a fixed base (base, one link, the rotor; the torque-mode drive train of
  ``diagrams/joint_torque.yaml`` without friction): the torque the mounting applies about
  the axis is ``I_axis qdd + J_m dw_m/dt`` (momentum) and ``tau_em + tau_s (1 - 1/N)`` (the
  housing's torque balance, independent of any acceleration), at every sample;
* the rotor accelerating inside the gear's backlash while the link stays at rest: the base
  sees exactly ``-J_m dw_m/dt = -tau_em``;
* angular momentum from rest: the integral of the base torque equals
  ``I_axis qd + J_m w_m`` at the end (one joint, hand-derived inertia) and
  ``L_links + J_m (w_m1 + w_m2)`` (two joints in a plane, ``Chain.momentum``), to 1e-6
  relative; without the reactions the mismatch is ``J_m w_m`` (4 % here).
"""
from __future__ import annotations

import os

import numpy as np
import pytest

import spidersim
from spidersim.multibody import Chain

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
JOINT = os.path.join(ROOT, "diagrams", "joint_torque.yaml")
J_M, N = 1.0e-4, 160.0

# one link of 0.5 m along x_0 at q = 0, turning about z_0: COM (0.25, 0.05, 0), principal
# inertia about the COM along the base axes
M1, C1, I1 = 4.0, (0.25, 0.05, 0.0), (0.02, 0.1, 0.12)
I_AXIS = I1[2] + M1 * (C1[0] ** 2 + C1[1] ** 2)        # 0.38 kg.m2 about z_0


def _link_yaml(a, m, c, inertia):
    return (f"  - {{d: 0, a: {a}, alpha: 0, mass: {m}, com: [{c[0]}, {c[1]}, {c[2]}], "
            f"inertia: [{inertia[0]}, {inertia[1]}, {inertia[2]}]}}\n")


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    """Arm data files: one link, and two links in a plane (both joints about z)."""
    d = tmp_path_factory.mktemp("arms")
    one = d / "one_link.yaml"
    one.write_text("name: one_link\nlinks:\n" + _link_yaml(0.5, M1, C1, I1))
    two = d / "two_links.yaml"
    two.write_text("name: two_links\nlinks:\n" + _link_yaml(0.5, M1, C1, I1)
                   + _link_yaml(0.4, 2.5, (0.7, -0.02, 0.0), (0.01, 0.05, 0.06)))
    return str(one), str(two)


# ============================================================================ the kernels
def test_reactions_are_the_generalized_force_of_moments_on_the_previous_links():
    """Guards ``kernels.add_reactions`` and the reactions in ``forward_dynamics``: on the
    SPIDER-like chain at random states, the moment ``tau_r,i z_{i-1}`` on link i-1 changes
    the inverse dynamics by minus its virtual-work generalized force (angular Jacobian of
    link i-1: columns ``z_{j-1}``, j <= i-1), the base moment by minus the sum of the
    moments, the base force not at all; forward dynamics then gives
    ``qdd_r - qdd = M^-1 Q_r``."""
    ch = Chain.from_yaml()
    n = ch.n
    rng = np.random.default_rng(7)
    for _ in range(5):
        q, qd, qdd = rng.normal(size=n), rng.normal(size=n), rng.normal(size=n)
        tau_r = rng.normal(size=n)
        J = ch.jacobian(q)
        z = J[3:, :]                                   # z_{i-1}, column i
        Q = np.zeros(n)
        for i in range(n):                             # drive i+1 (1-based) on link i
            m = tau_r[i] * z[:, i]
            for j in range(i):                         # joints 1..i move link i
                Q[j] += z[:, j] @ m
        tau0 = ch.rnea(q, qd, qdd)
        f0, n0 = ch.base_wrench(q, qd, qdd)
        tau1 = ch.rnea(q, qd, qdd, tau_r=tau_r)
        f1, n1 = ch.base_wrench(q, qd, qdd, tau_r=tau_r)
        scale = np.abs(tau0).max()
        np.testing.assert_allclose(tau1 - tau0, -Q, atol=1e-12 * scale)
        np.testing.assert_allclose(f1, f0, rtol=0, atol=1e-12 * np.abs(f0).max())
        np.testing.assert_allclose(n1 - n0, -(z @ tau_r), atol=1e-12 * np.abs(n0).max())
        tau = rng.normal(size=n)
        dq = ch.forward_dynamics(q, qd, tau, tau_r=tau_r) - ch.forward_dynamics(q, qd, tau)
        np.testing.assert_allclose(ch.mass_matrix(q) @ dq, Q, atol=1e-10 * np.abs(Q).max())


# ====================================================================== one joint, diagrams
ONE = """
name: one_joint
subsystems: {{joint: {joint}}}
blocks:
  cmd: {{type: Step, t_step: 0.01, after: {tau}}}
  j:   {{type: joint, N: {N}, J_m: {J_m}, friction: 0, zeta_a: {zeta_a},
         backlash: {backlash}}}
  arm: {{type: Arm, model: "{model}"}}
  imp: {{type: Integrator}}
connections:
  - cmd.y -> j.tau_ref
  - arm.q -> j.phi_l
  - arm.qd -> j.w_l
  - j.tau_l -> arm.tau
  - {react}j.tau_r -> arm.tau_r
  - arm.base_moment -> imp.u
simulation: {{t_end: {t_end}, method: LSODA, rtol: 1e-10, atol: 1e-12}}
log: [arm.q, arm.qd, arm.qdd, arm.base_moment, arm.base_force, imp.y, j.tau_r, j.motor.w,
      j.motor.dw, j.motor.tau, j.gear.tau_l, j.deflection]
"""


def _one(model, tau=2.0, zeta_a=0.5, backlash=0.0, t_end=0.3, react=True):
    text = ONE.format(joint=JOINT, model=model, tau=tau, N=N, J_m=J_M, zeta_a=zeta_a,
                      backlash=backlash, t_end=t_end, react="" if react else "# ")
    if not react:
        text = text.replace("  - # j.tau_r -> arm.tau_r\n", "")
    return spidersim.loads(text).simulate()


def test_one_joint_base_torque_is_link_plus_rotor_acceleration(models):
    """Guards the reaction's sign and size through the whole chain (motor ``dw`` output,
    the joint's ``tau_r``, the Arm's input, the base moment): one link on a fixed base,
    driven through the compliant gear (2 N.m step, the 23 Hz gear mode excited). The torque
    the mounting applies about the axis, ``-base_moment_z``, equals at every sample the
    rate of the angular momentum ``I_axis qdd + J_m dw_m/dt`` and, from the housing's
    torque balance (stator reaction ``-tau_em``, circular spline ``-(tau_s - tau_s/N)``),
    ``tau_em + tau_s (1 - 1/N)``; the other moment components and the force's z stay 0."""
    r = _one(models[0])
    Mz = -r["arm.base_moment"][:, 2]
    rotor = J_M * r["j.motor.dw"]
    inertial = I_AXIS * r["arm.qdd"] + rotor
    housing = r["j.motor.tau"] + r["j.gear.tau_l"] * (1.0 - 1.0 / N)
    scale = np.abs(Mz).max()
    assert np.abs(rotor).max() > 0.02 * scale           # J_m N / (I_axis + J_m N) = 4 %
    np.testing.assert_allclose(Mz, inertial, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(Mz, housing, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(r["j.tau_r"], -rotor, rtol=1e-14)
    assert np.abs(r["arm.base_moment"][:, :2]).max() < 1e-12 * scale
    assert np.abs(r["arm.base_force"][:, 2]).max() < 1e-12


def test_rotor_spinning_in_the_backlash_loads_the_base_with_its_own_acceleration(models):
    """Guards the reaction alone: inside the gear's backlash (0.02 rad, the rotor starting
    centred, no active damping) the rotor accelerates under the 0.042 A current while the
    link stays at rest: the base moment is exactly ``-J_m dw_m/dt``, which is the
    electromagnetic torque ``-tau_em`` (no friction, no load)."""
    r = _one(models[0], tau=1.0, zeta_a=0.0, backlash=0.02, t_end=0.15)
    assert np.abs(r["j.deflection"]).max() < 0.01                 # still in the gap
    assert np.all(r["arm.q"] == 0.0) and np.all(r["arm.qdd"] == 0.0)
    Mz = r["arm.base_moment"][:, 2]
    tau_em = r["j.motor.tau"]
    assert tau_em[-1] == pytest.approx(1.0 / N, rel=0.05)          # K_t i ~ tau_ref / N
    np.testing.assert_allclose(Mz, -J_M * r["j.motor.dw"], rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(Mz, -tau_em, rtol=1e-12, atol=1e-18)


@pytest.mark.parametrize("react", [True, False])
def test_one_joint_angular_momentum_from_rest(models, react):
    """Guards the momentum balance of base, link and rotor: from rest, the integral of the
    torque the mounting applies about the axis equals ``I_axis qd + J_m w_m`` at the end
    (relative 1e-6; LSODA at rtol 1e-10). Without the reaction wired (``react=False``)
    the integral misses the rotor's ``J_m w_m`` (4 % of the total): the check is sharp."""
    r = _one(models[0], react=react)
    impulse = -r["imp.y"][-1, 2]
    L_link = I_AXIS * r["arm.qd"][-1]
    L_rotor = J_M * r["j.motor.w"][-1]
    assert L_rotor > 0.03 * L_link > 0.0
    if react:
        assert impulse == pytest.approx(L_link + L_rotor, rel=1e-6)
    else:
        assert impulse == pytest.approx(L_link, rel=1e-6)
        assert abs(impulse - (L_link + L_rotor)) > 0.03 * impulse


TWO = """
name: two_joints
subsystems: {{joint: {joint}}}
blocks:
  cmd1: {{type: Step, t_step: 0.01, after: 2.0}}
  cmd2: {{type: Step, t_step: 0.05, after: -1.5}}
  j1:  {{type: joint, N: {N}, J_m: {J_m}, friction: 0}}
  j2:  {{type: joint, N: {N}, J_m: {J_m}, friction: 0}}
  arm: {{type: Arm, model: "{model}"}}
  q:   {{type: Demux, sizes: [1, 1]}}
  qd:  {{type: Demux, sizes: [1, 1]}}
  tau: {{type: Mux, n: 2}}
  tau_r: {{type: Mux, n: 2}}
  imp: {{type: Integrator}}
connections:
  - cmd1.y -> j1.tau_ref
  - cmd2.y -> j2.tau_ref
  - arm.q -> q.u
  - arm.qd -> qd.u
  - q.y1 -> j1.phi_l
  - q.y2 -> j2.phi_l
  - qd.y1 -> j1.w_l
  - qd.y2 -> j2.w_l
  - j1.tau_l -> tau.u1
  - j2.tau_l -> tau.u2
  - j1.tau_r -> tau_r.u1
  - j2.tau_r -> tau_r.u2
  - tau.y -> arm.tau
  - tau_r.y -> arm.tau_r
  - arm.base_moment -> imp.u
simulation: {{t_end: 0.3, method: LSODA, rtol: 1e-10, atol: 1e-12}}
log: [arm.q, arm.qd, imp.y, j1.motor.w, j2.motor.w]
"""


def test_two_joints_angular_momentum_from_rest(models):
    """Guards the reaction of joint 2 on link 1 (not on the base): two links in a plane,
    both drives stepping (2 and -1.5 N.m); the integral of the mounting's torque about z
    equals the links' angular momentum (``Chain.momentum``) plus ``J_m (w_m1 + w_m2)``
    (rotor 2's spin relative to link 1, which the motor block integrates; its share
    carried by link 1's rotation belongs to link 1's mass data), relative 1e-6."""
    r = spidersim.loads(TWO.format(joint=JOINT, model=models[1], N=N, J_m=J_M)).simulate()
    ch = Chain.from_yaml(models[1])
    _, L = ch.momentum(r["arm.q"][-1], r["arm.qd"][-1])
    L_rot = J_M * (r["j1.motor.w"][-1] + r["j2.motor.w"][-1])
    impulse = -r["imp.y"][-1, 2]
    assert abs(J_M * r["j2.motor.w"][-1]) > 1e-3 * abs(impulse)
    assert impulse == pytest.approx(L[2] + L_rot, rel=1e-6)


def test_zero_reactions_change_nothing():
    """Guards the optional input: an empty or all-zero ``tau_r`` gives the same
    accelerations and base wrench as the kernels without reactions (bit for bit)."""
    ch = Chain.from_yaml()
    rng = np.random.default_rng(3)
    q, qd, tau = rng.normal(size=7), rng.normal(size=7), rng.normal(size=7)
    a = ch.forward_dynamics(q, qd, tau)
    base_a = ch._base.copy()
    b = ch.forward_dynamics(q, qd, tau, tau_r=np.zeros(7))
    assert np.array_equal(a, b) and np.array_equal(base_a, ch._base)
