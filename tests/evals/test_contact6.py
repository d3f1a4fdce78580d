"""RigidContact6 (a rigid constraint of the flange frame on any subset of six directions)
against closed forms and an independent integration of the constrained dynamics.

* one direction (unilateral z): the arm hitting a plane reproduces RigidContact (onset
  instant, impact jump, multiplier, trajectory);
* a peg (5 bilateral directions, the insertion translation free): at rest the multipliers
  are the wrench of the statics ``J_c^T lam = g(q) - tau``; pushed along the free direction
  the flange starts with ``a = F / Lambda_zz`` (``Lambda = (J M^-1 J^T)^-1`` in contact
  axes) and follows the index-reduced dynamics integrated by scipy, every constrained
  direction held; the same with the rotation about the peg axis free;
* the 5-direction plastic impact is the projection
  ``qd+ = qd- - M^-1 J_c^T (J_c M^-1 J_c^T)^-1 J_c qd-``;
* release: a ramp of pull makes the unilateral multiplier cross zero at the statics'
  instant, the flange then leaves as the 5-direction constrained dynamics predict;
* bad selections and parameters are refused naming block and parameter.
"""
from __future__ import annotations

import math
import os

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import spidersim
from spidersim.errors import ParameterError
from spidersim.multibody import Chain

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
N = 7
Q0 = np.array([0.0, 0.6, 0.0, -1.3, 0.0, 0.8, 0.0])
G = 9.81
SIM = dict(rtol=1e-10, atol=1e-12, jit=False)


def _yl(v):
    return "[" + ", ".join(repr(float(x)) for x in np.atleast_1d(v)) + "]"


def _events(r, block, name):
    """Instants of ``block``'s event ``name`` (any element of a sized event: onset[2])."""
    return [e[0] for e in r.events if e[1] == block and e[2].split("[")[0] == name]


def _chain(gravity):
    ch = Chain.from_yaml()
    ch.gravity = np.asarray(gravity, float)
    return ch


def rpy_of(R):
    """Inverse of R = Rz(yaw) Ry(pitch) Rx(roll) (away from pitch = +-pi/2)."""
    return np.array([math.atan2(R[2, 1], R[2, 2]), -math.asin(R[2, 0]),
                     math.atan2(R[1, 0], R[0, 0])])


def contact_jacobian(ch, q, Rc, sel):
    """Rows of the flange Jacobian in contact axes for the selected directions."""
    J = ch.jacobian(q)
    J6 = np.vstack([Rc.T @ J[:3], Rc.T @ J[3:]])
    return J6[np.asarray(sel, bool)]


ARM_WIRES = """  - arm.flange_pos -> wall.pos
  - arm.flange_rot -> wall.rot
  - arm.flange_twist -> wall.twist
  - arm.flange_acc -> wall.acc
  - arm.flange_alpha -> wall.alpha
  - wall.wrench -> arm.f_ext
  - wall.constraint -> arm.constraint6
"""


def constrained_reference(ch, q0, qd0, tau_of_t, Rc, sel, t_span, t_eval):
    """Independent integration of ``M qdd = tau - b + J_c^T lam`` with ``J_c qdd + Jdot_c qd
    = 0`` (index reduced, no Baumgarte): numpy linear algebra on the Chain's M, RNEA and
    Jacobian, ``Jdot_c qd`` by central differences along ``qd``."""
    def f(t, x):
        q, qd = x[:N], x[N:]
        M = ch.mass_matrix(q)
        b = ch.rnea(q, qd, np.zeros(N))
        Jc = contact_jacobian(ch, q, Rc, sel)
        h = 1e-6
        Jd = (contact_jacobian(ch, q + h * qd, Rc, sel)
              - contact_jacobian(ch, q - h * qd, Rc, sel)) / (2 * h)
        rhs = tau_of_t(t) - b
        Minv_rhs = np.linalg.solve(M, rhs)
        Y = np.linalg.solve(M, Jc.T)
        lam = -np.linalg.solve(Jc @ Y, Jc @ Minv_rhs + Jd @ qd)
        return np.concatenate([qd, Minv_rhs + Y @ lam])
    return solve_ivp(f, t_span, np.concatenate([q0, qd0]), method="DOP853", rtol=1e-11,
                     atol=1e-13, t_eval=t_eval)


# =========================================================================== one direction
def _impact_text(block):
    ch = _chain([0, 0, 0])
    qd0 = np.array([0.1, 0.3, -0.2, -0.4, 0.2, 0.1, 0.3])
    point = ch.fk(Q0)[:3, 3] - np.array([0.0, 0.0, 0.01])
    if block == "RigidContact":
        wall = f"{{type: RigidContact, point: {_yl(point)}, normal: [0, 0, 1]}}"
        wires = """  - arm.flange_pos -> wall.pos
  - arm.flange_twist[0:3] -> wall.vel
  - arm.flange_acc -> wall.acc
  - wall.wrench -> arm.f_ext
  - wall.constraint -> arm.constraint
"""
        lam = "wall.lam"
    else:
        wall = (f"{{type: RigidContact6, origin: {_yl(point)}, select: [0, 0, 1, 0, 0, 0], "
                f"unilateral: [0, 0, 1, 0, 0, 0]}}")
        wires = ARM_WIRES
        lam = "wall.lam"
    return f"""
name: arm_impact
blocks:
  tau:  {{type: Constant, value: {_yl(np.zeros(N))}}}
  arm:  {{type: Arm, q0: {_yl(Q0)}, qd0: {_yl(qd0)}}}
  wall: {wall}
connections:
  - tau.y -> arm.tau
{wires}log: [arm.q, arm.qd, {lam}]
"""


def test_one_direction_reproduces_rigid_contact():
    """A 1-direction RigidContact6 (unilateral z, frame axes = base axes) on a coasting arm
    gives RigidContact's run: same onset instant, same impact jump, same trajectory and
    a zero multiplier (g = 0, tau = 0: nothing presses after the plastic impact)."""
    t_end = 0.15
    kw = dict(t_end=t_end, **SIM)
    r1 = spidersim.loads(_impact_text("RigidContact")).simulate(**kw)
    r6 = spidersim.loads(_impact_text("RigidContact6")).simulate(**kw)
    on1, on6 = _events(r1, "wall", "onset"), _events(r6, "wall", "onset")
    assert len(on1) == 1 and len(on6) == 1
    assert on6[0] == pytest.approx(on1[0], abs=1e-12)
    assert _events(r6, "arm", "impact6") == on6
    # the plastic jump of the 1-row formula
    ch = _chain([0, 0, 0])
    rows = np.flatnonzero(r6.t == on6[0])
    i0, i1 = rows[0], rows[-1]
    q, qd_m = r6["arm.q"][i0], r6["arm.qd"][i0]
    M = ch.mass_matrix(q)
    Jn = ch.jacobian(q)[2:3]
    Y = np.linalg.solve(M, Jn.T)
    exact = qd_m - (Y @ np.linalg.solve(Jn @ Y, Jn @ qd_m)).ravel()
    np.testing.assert_allclose(r6["arm.qd"][i1], exact, rtol=1e-9, atol=1e-12)
    # the whole run, sampled every ms: the two blocks give the same motion
    kw["output_interval"] = 1e-3
    r1 = spidersim.loads(_impact_text("RigidContact")).simulate(**kw)
    r6 = spidersim.loads(_impact_text("RigidContact6")).simulate(**kw)
    np.testing.assert_array_equal(r1.t, r6.t)
    np.testing.assert_allclose(r6["arm.q"], r1["arm.q"], atol=1e-9)
    np.testing.assert_allclose(r6["arm.qd"], r1["arm.qd"], atol=1e-8)
    np.testing.assert_allclose(r6["wall.lam"][:, 2], r1["wall.lam"], atol=1e-6)
    assert np.abs(r6["wall.lam"][:, [0, 1, 3, 4, 5]]).max() == 0.0


def test_one_direction_static_normal_force():
    """Arm under gravity resting on the plane (tilted frame: z_c along a unit normal n),
    tau = g(q) - J_v^T n lam0: the multiplier is lam0, the flange at rest on the plane."""
    ch = _chain([0, 0, -G])
    R = ch.fk(Q0)
    Rc = np.array(R[:3, :3])
    rpy = rpy_of(Rc)
    from spidersim.blocks.contact import rpy_matrix
    np.testing.assert_allclose(rpy_matrix(rpy), Rc, atol=1e-14)
    lam0 = 35.0
    Jz = contact_jacobian(ch, Q0, Rc, [0, 0, 1, 0, 0, 0])[0]
    tau = ch.rnea(Q0, np.zeros(N), np.zeros(N)) - Jz * lam0
    text = f"""
name: plane
blocks:
  tau:  {{type: Constant, value: {_yl(tau)}}}
  arm:  {{type: Arm, q0: {_yl(Q0)}, gravity: [0, 0, {-G}]}}
  wall: {{type: RigidContact6, origin: {_yl(R[:3, 3])}, rpy: {_yl(rpy)}, engaged: true}}
connections:
  - tau.y -> arm.tau
{ARM_WIRES}log: [arm.q, arm.qd, wall.lam, wall.error]
"""
    r = spidersim.loads(text).simulate(t_end=0.2, output_interval=1e-2, **SIM)
    assert not r.events
    np.testing.assert_allclose(r["wall.lam"][:, 2], lam0, rtol=1e-9)
    assert np.abs(r["wall.error"][:, 2]).max() < 1e-12
    assert np.abs(r["arm.qd"]).max() < 1e-10


# =========================================================================== the peg
PEG = [1, 1, 0, 1, 1, 1]            # insertion (contact z) free
PEG_ROT = [1, 1, 1, 1, 1, 0]        # rotation about the peg axis free
LAM0 = np.array([6.0, -4.0, 0.0, 1.5, -0.8, 0.6])   # lateral forces and moments held


def peg_run(sel, lam0, push, t_end=0.2, unilateral=(0,) * 6, ramp=None, extra_log="",
            dense=True):
    """Arm under gravity, the contact frame on the flange frame at Q0, ``sel`` engaged from
    the start; tau = g(q0) - J_c^T lam0[sel] + J6^T push (push: contact-axes wrench
    along the free directions); ``ramp = (t0, slope, row)``: plus slope (t - t0) J6[row]^T
    from t0."""
    ch = _chain([0, 0, -G])
    T = ch.fk(Q0)
    Rc = T[:3, :3].copy()
    J6 = contact_jacobian(ch, Q0, Rc, [1] * 6)
    selb = np.asarray(sel, bool)
    tau = ch.rnea(Q0, np.zeros(N), np.zeros(N)) - J6[selb].T @ lam0[selb] + J6.T @ push
    ramp_blocks = ramp_wires = ""
    if ramp is not None:
        t0, slope, row = ramp
        ramp_blocks = (f"  pull: {{type: Ramp, t_start: {t0}, slope: {slope}}}\n"
                       f"  pv:   {{type: Mux, n: {N}}}\n"
                       f"  kp:   {{type: Gain, k: {_yl(J6[row])}}}\n"
                       f"  sum:  {{type: Sum, signs: \"++\"}}\n")
        ramp_wires = "".join(f"  - pull.y -> pv.u{i + 1}\n" for i in range(N)) + \
            "  - pv.y -> kp.u\n  - kp.y -> sum.u2\n  - tau.y -> sum.u1\n" \
                     "  - sum.y -> arm.tau\n"
    else:
        ramp_wires = "  - tau.y -> arm.tau\n"
    text = f"""
name: peg
blocks:
  tau:  {{type: Constant, value: {_yl(tau)}}}
{ramp_blocks}  arm:  {{type: Arm, q0: {_yl(Q0)}, gravity: [0, 0, {-G}]}}
  wall: {{type: RigidContact6, origin: {_yl(T[:3, 3])}, rpy: {_yl(rpy_of(Rc))},
          select: {_yl(sel)}, unilateral: {_yl(unilateral)}, engaged: true}}
connections:
{ramp_wires}{ARM_WIRES}log: [arm.q, arm.qd, arm.flange_pos, arm.flange_twist, wall.lam,
      wall.error, wall.drift{extra_log}]
"""
    kw = dict(output_interval=1e-3) if dense else {}
    r = spidersim.loads(text).simulate(t_end=t_end, **kw, **SIM)
    return r, ch, Rc, tau, J6


def test_peg_statics_multipliers_are_the_wrench():
    """5 bilateral directions held, tau = g(q) - J_c^T lam0: the arm stays at rest (the
    free insertion direction has no net force) and the multipliers are lam0, the wrench the
    statics J_c^T lam = g(q) - tau give."""
    r, ch, Rc, tau, J6 = peg_run(PEG, LAM0, np.zeros(6))
    assert not r.events
    sel = np.asarray(PEG, bool)
    # the statics solved independently: least squares of J_c^T lam = g(q0) - tau
    lam_ls = np.linalg.lstsq(J6[sel].T, ch.rnea(Q0, np.zeros(N), np.zeros(N)) - tau,
                             rcond=None)[0]
    np.testing.assert_allclose(lam_ls, LAM0[sel], rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(r["wall.lam"][:, sel], np.tile(lam_ls, (len(r.t), 1)),
                               rtol=1e-8, atol=1e-8)
    assert np.abs(r["wall.lam"][:, 2]).max() == 0.0
    assert np.abs(r["arm.qd"]).max() < 1e-9
    assert np.abs(r["wall.drift"]).max() < 1e-12


@pytest.mark.parametrize("sel, free", [(PEG, 2), (PEG_ROT, 5)])
def test_peg_free_direction_follows_the_reduced_dynamics(sel, free):
    """Pushed along its free direction (a force of 15 N along the peg axis, or a moment of
    20 mN.m about it: 0.2 rad in 0.2 s), the flange starts with the acceleration ``F / Lambda_ff`` of the
    operational-space inertia ``Lambda = (J6 M^-1 J6^T)^-1`` (contact axes) and then follows
    the constrained dynamics integrated independently (scipy, index-reduced); every
    constrained direction is held (errors below 1e-9)."""
    push = np.zeros(6)
    push[free] = 15.0 if free < 3 else 0.02
    t_end = 0.2
    r, ch, Rc, tau, J6 = peg_run(sel, LAM0 * np.asarray(sel), push, t_end=t_end,
                                 extra_log=", arm.flange_acc, arm.flange_alpha")
    assert not r.events
    M = ch.mass_matrix(Q0)
    Lam = np.linalg.inv(J6 @ np.linalg.solve(M, J6.T))
    acc0 = Rc.T @ (r["arm.flange_acc"][0] if free < 3 else r["arm.flange_alpha"][0])
    assert acc0[free % 3] == pytest.approx(push[free] / Lam[free, free], rel=1e-9)
    # multipliers at t = 0: the constrained rows of Lambda (J6 M^-1 J6^T) w = 0
    A = J6 @ np.linalg.solve(M, J6.T)
    selb = np.asarray(sel, bool)
    lam_t0 = LAM0[selb] - np.linalg.solve(A[np.ix_(selb, selb)], A[selb, free] * push[free])
    np.testing.assert_allclose(r["wall.lam"][0, selb], lam_t0, rtol=1e-8, atol=1e-8)
    # the independent integration
    ref = constrained_reference(ch, Q0, np.zeros(N), lambda t: tau, Rc, sel, (0.0, t_end),
                                r.t)
    assert ref.success
    np.testing.assert_allclose(r["arm.q"], ref.y[:N].T, atol=2e-9)
    np.testing.assert_allclose(r["arm.qd"], ref.y[N:].T, atol=2e-8)
    assert np.abs(r["wall.drift"]).max() < 1e-9
    moved = abs(r["wall.error"][-1, free])
    assert moved > 1e-3                                  # the free direction really moved


def test_peg_bottom_impact_is_the_projection():
    """g = 0, tau = 0: a coasting arm reaches the bottom of a hole 1 cm ahead along the
    contact z (frame axes = the flange's at q0; x, y, rx, ry bilateral, z unilateral, rz
    free, nothing engaged at the start). The z onset engages the bilateral directions too:
    the jump is the 5-row projection qd+ = qd- - M^-1 J_c^T (J_c M^-1 J_c^T)^-1 J_c qd-,
    after which every engaged direction is at rest (the bilateral ones where they were
    touched, z on the surface) and kinetic energy was lost."""
    ch = _chain([0, 0, 0])
    qd0 = -np.array([0.1, 0.3, -0.2, -0.4, 0.2, 0.1, 0.3])
    T = ch.fk(Q0)
    Rc = T[:3, :3].copy()
    assert (Rc.T @ ch.jacobian(Q0)[:3] @ qd0)[2] < -0.3           # approaching
    origin = T[:3, 3] - 0.01 * Rc[:, 2]
    sel = [1, 1, 1, 1, 1, 0]
    text = f"""
name: peg_impact
blocks:
  tau:  {{type: Constant, value: {_yl(np.zeros(N))}}}
  arm:  {{type: Arm, q0: {_yl(Q0)}, qd0: {_yl(qd0)}}}
  wall: {{type: RigidContact6, origin: {_yl(origin)}, rpy: {_yl(rpy_of(Rc))},
          select: {_yl(sel)}, unilateral: [0, 0, 1, 0, 0, 0]}}
connections:
  - tau.y -> arm.tau
{ARM_WIRES}log: [arm.q, arm.qd, arm.flange_twist, wall.error, wall.drift, wall.lam]
"""
    r = spidersim.loads(text).simulate(t_end=0.1, **SIM)
    on = _events(r, "wall", "onset")
    assert len(on) == 1 and 0.0 < on[0] < 0.1
    assert on[0] in _events(r, "arm", "impact6")
    rows = np.flatnonzero(r.t == on[0])
    i0, i1 = rows[0], rows[-1]
    q, qd_m = r["arm.q"][i0], r["arm.qd"][i0]
    M = ch.mass_matrix(q)
    Jc = contact_jacobian(ch, q, Rc, sel)
    Y = np.linalg.solve(M, Jc.T)
    exact = qd_m - Y @ np.linalg.solve(Jc @ Y, Jc @ qd_m)
    np.testing.assert_allclose(r["arm.qd"][i1], exact, rtol=1e-9, atol=1e-12)
    assert np.linalg.norm(r["arm.qd"][i1] - qd_m) > 0.05 * np.linalg.norm(qd_m)
    assert np.abs(Jc @ r["arm.qd"][i1]).max() < 1e-12
    assert exact @ M @ exact < qd_m @ M @ qd_m
    # afterwards the bilateral directions hold where they were touched, z at the surface
    after = r.t > on[0]
    assert np.abs(r["wall.drift"][after]).max() < 1e-9
    hold = r["wall.error"][i1]
    np.testing.assert_allclose(r["wall.error"][after][:, :3],
                               np.tile(hold[:3], (after.sum(), 1)), atol=1e-9)
    assert abs(hold[0]) + abs(hold[1]) > 1e-4            # it was not touched at the origin
    assert abs(r["wall.error"][-1, 5] - hold[5]) > 1e-3  # rz free: it keeps turning


# =========================================================================== release
def test_release_on_the_unilateral_multiplier():
    """All six directions held, z unilateral pushed with 30 N; from t0 a pull ramps up
    along z at 300 N/s. At rest the statics give lam_z = 30 - 300 (t - t0): release at
    t0 + 0.1 s; the bilateral multipliers stay lam0 until then. After the release the
    flange leaves along z as the 5-direction constrained dynamics predict (scipy
    integration from rest at the release instant)."""
    lam0 = LAM0.copy()
    lam0[2] = 30.0
    t0, slope, t_end = 0.05, 300.0, 0.25
    r, ch, Rc, tau, J6 = peg_run([1] * 6, lam0, np.zeros(6), t_end=t_end,
                                 unilateral=[0, 0, 1, 0, 0, 0], ramp=(t0, slope, 2),
                                 dense=False)
    t_rel = t0 + lam0[2] / slope
    off = _events(r, "wall", "release")
    assert off == [pytest.approx(t_rel, abs=1e-9)]
    before = r.t < t_rel
    lam_z = lam0[2] - slope * np.clip(r.t[before] - t0, 0.0, None)
    np.testing.assert_allclose(r["wall.lam"][before, 2], lam_z, rtol=1e-7, atol=1e-7)
    np.testing.assert_allclose(r["wall.lam"][before][:, [0, 1, 3, 4, 5]],
                               np.tile(lam0[[0, 1, 3, 4, 5]], (before.sum(), 1)),
                               rtol=1e-7, atol=1e-7)
    # after the located release (within 1e-9 s of t_rel, asserted above; a grid sample
    # can fall between the two): exactly zero
    after = r.t > off[0]
    assert np.abs(r["wall.lam"][after, 2]).max() == 0.0
    # the flange leaves along +z_c, the other five still held
    ez = r["wall.error"][after, 2]
    assert ez[-1] > 1e-4 and np.all(np.diff(ez) >= 0)
    assert np.abs(r["wall.drift"][after]).max() < 1e-9
    # ... with the motion the 5-direction dynamics predict
    k = np.flatnonzero(r.t == off[0])[-1]
    sel5 = [1, 1, 0, 1, 1, 1]
    ts = r.t[k:]
    ref = constrained_reference(
        ch, r["arm.q"][k], r["arm.qd"][k],
        lambda t: tau + slope * (t - t0) * J6[2], Rc, sel5, (ts[0], ts[-1]), ts)
    assert ref.success
    np.testing.assert_allclose(r["arm.qd"][k:], ref.y[N:].T, atol=1e-8)
    vz = (Rc.T @ r["arm.flange_twist"][-1, :3])[2]
    vz_ref = contact_jacobian(ch, ref.y[:N, -1], Rc, [0, 0, 1, 0, 0, 0])[0] @ ref.y[N:, -1]
    assert vz > 1e-3 and vz == pytest.approx(vz_ref, rel=1e-6)


def test_pull_at_onset_lets_go_at_once():
    """Engaged at the start with the applied forces already pulling on the unilateral
    direction: it lets go at t = 0 (no release event, the multiplier stays 0), the
    bilateral ones keep holding."""
    lam0 = LAM0.copy()
    lam0[2] = -10.0                                      # a pull
    r, *_ = peg_run([1] * 6, lam0, np.zeros(6), t_end=0.05,
                    unilateral=[0, 0, 1, 0, 0, 0])
    assert not _events(r, "wall", "release")
    assert np.abs(r["wall.lam"][:, 2]).max() < 1e-30
    assert r["wall.error"][-1, 2] > 1e-5
    assert np.abs(r["wall.drift"]).max() < 1e-9


# =========================================================================== bad parameters
@pytest.mark.parametrize("params, words", [
    ("select: [0, 0, 2, 0, 0, 0]", ["wall", "select[2]", "z", "0 or 1"]),
    ("select: [0, 0, 0, 0, 0, 0], engaged: true", ["wall", "select", "no direction"]),
    ("select: [1, 1, 0, 0, 0, 0], unilateral: [0, 0, 1, 0, 0, 0]",
     ["wall", "unilateral[2]", "select[2] is 0"]),
    ("select: [1, 1, 1], unilateral: [0, 0, 1, 0, 0, 0]", ["wall", "select", "6 elements"]),
    ("select: [1, 1, 1, 1, 1, 1], unilateral: [0, 0, 0, 0, 0, 0]",
     ["wall", "never engage", "engaged"]),
    ("unilateral: [0, 0, 0.5, 0, 0, 0]", ["wall", "unilateral[2]", "0 or 1"]),
    ("select: [0, 0, 1, 1, 0, 0], unilateral: [0, 0, 1, 1, 0, 0]",
     ["wall", "unilateral[3]", "rx", "only translations"]),
    ("omega: 0", ["wall", "omega", "> 0"]),
    ("lam0: [1, 2]", ["wall", "lam0", "1 or 6"]),
    ("rpy: [0, .nan, 0]", ["wall", "rpy", "nan"]),
])
def test_bad_parameters_are_refused_naming_block_and_parameter(params, words):
    """Each bad selection or parameter is a ParameterError whose message names the block
    and the parameter (and the direction for a selection entry)."""
    text = f"""
name: bad
blocks:
  tau:  {{type: Constant, value: {_yl(np.zeros(N))}}}
  arm:  {{type: Arm, q0: {_yl(Q0)}}}
  wall: {{type: RigidContact6, {params}}}
connections:
  - tau.y -> arm.tau
{ARM_WIRES}"""
    with pytest.raises(ParameterError) as exc:
        spidersim.loads(text).simulate(t_end=0.01, jit=False)
    msg = str(exc.value).lower()
    for w in words:
        assert w.lower() in msg, (w, msg)


# =========================================================================== the demo
def test_peg_contact_diagram():
    """diagrams/peg_contact.yaml (the README's demo): the peg slides to the bottom of the
    hole at the instant the 4-direction constrained dynamics (x, y, rx, ry held, scipy)
    predict, the bottom engages with the 5-direction plastic impact, holds with a push
    (lam_z > 0) and lets go the instant the pull steps in; every engaged direction held
    to 1e-9 throughout."""
    d = spidersim.load(os.path.join(ROOT, "diagrams", "peg_contact.yaml"))
    r = d.simulate(jit=False, output_interval=None)
    on = _events(r, "wall", "onset")
    assert len(on) == 1 and _events(r, "arm", "impact6") == on
    assert _events(r, "wall", "release") == [pytest.approx(0.6, abs=1e-12)]
    from spidersim.blocks.contact import rpy_matrix
    Rc = rpy_matrix([0.0, 2.7, 0.0])
    bottom = np.array(d.spec.parameters["bottom"], float)
    tau = np.array(d.spec.parameters["tau_push"], float)
    ch = _chain([0, 0, 0])

    def gap(t, x):
        return Rc[:, 2] @ (ch.fk(x[:N])[:3, 3] - bottom)
    gap.terminal, gap.direction = True, -1
    ref = _reference_with_event(ch, tau, Rc, gap)
    assert on[0] == pytest.approx(ref, rel=1e-7)
    assert np.abs(r["wall.drift"]).max() < 1e-9
    held = (r.t > on[0]) & (r.t < 0.6)
    assert r["wall.lam"][held, 2].min() > 15.0
    out = r.t > 0.6
    assert np.all(np.diff(r["wall.error"][out, 2]) >= 0) and r["wall.error"][-1, 2] > 0.05


def _reference_with_event(ch, tau, Rc, event):
    sel = [1, 1, 0, 1, 1, 0]

    def f(t, x):
        q, qd = x[:N], x[N:]
        M = ch.mass_matrix(q)
        b = ch.rnea(q, qd, np.zeros(N))
        Jc = contact_jacobian(ch, q, Rc, sel)
        h = 1e-6
        Jd = (contact_jacobian(ch, q + h * qd, Rc, sel)
              - contact_jacobian(ch, q - h * qd, Rc, sel)) / (2 * h)
        Minv_rhs = np.linalg.solve(M, tau - b)
        Y = np.linalg.solve(M, Jc.T)
        lam = -np.linalg.solve(Jc @ Y, Jc @ Minv_rhs + Jd @ qd)
        return np.concatenate([qd, Minv_rhs + Y @ lam])
    q0 = np.array([0, 0.6, 0, -1.3, 0, 0.8, 0.0])
    sol = solve_ivp(f, (0.0, 0.5), np.concatenate([q0, np.zeros(N)]), method="DOP853",
                    rtol=1e-11, atol=1e-13, events=event)
    return sol.t_events[0][0]


def test_engaged_with_a_gap_waits_for_the_onset():
    """``engaged: true`` with the flange 1 um above the plane (unilateral z) and pushed
    towards it with F = 20 N (g = 0, tau = -J_z^T F): the direction is not engaged at the
    start (lam_z = 0; the Baumgarte terms would otherwise hold it at the gap and push back),
    the flange falls with a = F J_z M^-1 J_z^T and lands at t = sqrt(2 gap / a) (the motion
    is tiny: the closed form holds to 1e-4), with the plastic impact there."""
    ch = _chain([0, 0, 0])
    F, gap = 20.0, 1e-6
    T = ch.fk(Q0)
    Jz = ch.jacobian(Q0)[2]
    tau = -Jz * F
    text = f"""
name: gap_start
blocks:
  tau:  {{type: Constant, value: {_yl(tau)}}}
  arm:  {{type: Arm, q0: {_yl(Q0)}}}
  wall: {{type: RigidContact6, origin: {_yl(T[:3, 3] - [0, 0, gap])}, engaged: true}}
connections:
  - tau.y -> arm.tau
{ARM_WIRES}log: [wall.lam, wall.error]
"""
    r = spidersim.loads(text).simulate(t_end=0.004, **SIM)
    a = F * Jz @ np.linalg.solve(ch.mass_matrix(Q0), Jz)
    on = _events(r, "wall", "onset")
    assert on == [pytest.approx(math.sqrt(2 * gap / a), rel=1e-4)]
    assert _events(r, "arm", "impact6") == on
    before = r.t < on[0]
    assert np.abs(r["wall.lam"][before]).max() < 1e-12
    after = r.t > on[0]
    assert r["wall.lam"][after, 2].min() > 0.99 * F
