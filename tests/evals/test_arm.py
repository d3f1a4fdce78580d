"""The Arm block (and CartesianLineIK) in small diagrams, against the multibody library
(spidersim.multibody.Chain) and conservation laws.

* free motion (g = 0, zero torques): kinetic energy and the angular momentum about the base
  z axis (joint 1 carries no torque) are conserved; the block's outputs are the Chain's
  (flange pose and twist, base wrench with the block's sign: arm on mounting);
* gravity, holding torques: the arm stays at rest and pushes on its mounting with its weight;
* payload latch (30 kg at 0.15 m along the flange z, left at rest where the flange was at
  t = 0, a Step into ``arm.latch`` at 0.5 s): a plastic capture where the payload is,
  ``M'(q) qd+ = M(q) qd-`` with M, M' from Chain objects (M' with the payload merged into
  the last link at its pose relative to the flange at the latch), ``M' - M`` positive
  semidefinite and equal to the payload's own ``m Jv^T Jv + Jw^T I Jw``, kinetic energy
  lost (not gained), one event (the moving payload: tests/evals/test_payload.py);
* rest-to-rest move along a straight line at 2.5 cm/s (spider.yaml's case, 0.2 m, 30 kg
  payload latched, g = 0) with joint PD torques on CartesianLineIK references: the
  impulse of the base force over the run is ~0 against peak force x duration (the momentum
  returns to 0), equals minus the final momentum, and the flange stops within 1 mm of the
  line's end point;
* CartesianLineIK driven by a TrapezoidalProfile: fk(q_ref) follows the line (< 1e-5 m)
  with the orientation held (< 1e-5 rad).

All runs interpreted (``jit=False``).

The latch tests also guard a fixed kernel bug (see tests/multibody/test_chain.py):
``kernels.mass_matrix`` read the external moment from the three floats after the base
wrench, in the Arm block the scratch the latch event fills with ``M qd-``, so M' came out
indefinite and the run failed with "non-finite state: arm.qd" at the latch.
"""
from __future__ import annotations

import numpy as np
import pytest

import spidersim
from spidersim.blocks.arm import _with_payload
from spidersim.multibody import Chain

from blocks.harness import Probe     # tests/ is on sys.path (rootdir-relative imports)

N = 7
Q0 = [0.0, 0.6, 0.0, -1.3, 0.0, 0.8, 0.0]          # spider.yaml's start pose
PAYLOAD = dict(mass=30.0, com=[0.0, 0.0, 0.15], inertia=[0.3, 0.3, 0.3])
KW = dict(method="LSODA", jit=False)


def _yl(v):
    """A list as YAML flow text with plain floats."""
    return "[" + ", ".join(repr(float(x)) for x in v) + "]"


def _chains():
    """(arm, arm with the payload merged into the last link), both with g = 0."""
    ch = Chain.from_yaml()
    chp = Chain.from_yaml()
    chp.P = _with_payload(ch.P, PAYLOAD["mass"], PAYLOAD["com"], PAYLOAD["inertia"])
    for c in (ch, chp):
        # zeros after Chain._base: should the kernel bug of the module docstring return,
        # the references here stay right and the latch tests alone fail
        c._base = np.zeros(9)[:6]
    return ch, chp


def _chain_with_grasp(c_rel, R_rel):
    """Chain (g = 0) with the payload merged into the last link at COM ``c_rel`` and axes
    ``R_rel`` in the flange frame (parallel axes, plain numpy)."""
    ch = Chain.from_yaml()
    P = ch.P.copy()
    row = P[-1]
    m0, c0, I0 = row[3], row[4:7].copy(), row[7:16].reshape(3, 3)
    mp, Ip = PAYLOAD["mass"], R_rel @ np.diag(PAYLOAD["inertia"]) @ R_rel.T
    m = m0 + mp
    c = (m0 * c0 + mp * c_rel) / m

    def shift(mass, d):
        return mass * (d @ d * np.eye(3) - np.outer(d, d))

    row[3], row[4:7] = m, c
    row[7:16] = (I0 + shift(m0, c0 - c) + Ip + shift(mp, c_rel - c)).ravel()
    ch.P = P
    ch._base = np.zeros(9)[:6]
    return ch


def _grasp(r, i):
    """Payload COM and axes in the flange frame at sample i (from the logged poses)."""
    Rf = r["arm.flange_rot"][i].reshape(3, 3)
    return (Rf.T @ (r["arm.payload_pos"][i] - r["arm.flange_pos"][i]),
            Rf.T @ r["arm.payload_rot"][i].reshape(3, 3))


def _payload_yaml():
    return (f"payload_mass: {PAYLOAD['mass']}, payload_com: {_yl(PAYLOAD['com'])}, "
            f"payload_inertia: {_yl(PAYLOAD['inertia'])}")


# ============================================================================= free motion
Q_FREE = [0.3, 0.7, -0.4, -1.1, 0.5, 0.9, -0.2]
QD_FREE = [0.6, -0.5, 0.8, 0.7, -1.0, 0.9, 1.2]


def free_arm(extra="", t_latch=None):
    lat = (f"  lat: {{type: Step, t_step: {t_latch}}}\n" if t_latch is not None else "")
    con = "  - lat.y -> arm.latch\n" if t_latch is not None else ""
    return f"""
name: free_arm
blocks:
  tau: {{type: Constant, value: {_yl(np.zeros(N))}}}
{lat}  arm: {{type: Arm, q0: {_yl(Q_FREE)}, qd0: {_yl(QD_FREE)}{extra}}}
connections:
  - tau.y -> arm.tau
{con}log: [arm.q, arm.qd, arm.qdd, arm.flange_pos, arm.flange_rot, arm.flange_twist,
      arm.base_force, arm.base_moment, arm.payload_pos, arm.payload_rot]
"""


def test_free_motion_conserves_energy_and_axial_momentum():
    """g = 0, tau = 0 for 2 s (rtol 1e-8): kinetic energy constant to 1e3 rtol = 1e-5
    relative; L_z about the base axis (= the generalized momentum of joint 1) likewise;
    the moment the arm applies about the base z axis stays 0."""
    rtol = 1e-8
    r = spidersim.loads(free_arm()).simulate(t_end=2.0, rtol=rtol, atol=1e-10, **KW)
    ch, _ = _chains()
    q, qd = r["arm.q"], r["arm.qd"]
    T = np.array([ch.kinetic_energy(a, b) for a, b in zip(q, qd)])
    Lz = np.array([ch.momentum(a, b)[1][2] for a, b in zip(q, qd)])
    assert len(T) > 20 and T[0] > 0.5
    assert np.ptp(q, axis=0).max() > 0.5                   # the arm really moved
    assert np.abs(T / T[0] - 1).max() < 1e3 * rtol, np.abs(T / T[0] - 1).max()
    assert np.abs(Lz - Lz[0]).max() < 1e3 * rtol * max(abs(Lz[0]), 1.0)
    assert np.abs(r["arm.base_moment"][:, 2]).max() < 1e-9
    assert np.abs(r["arm.base_force"]).max() > 1.0


def test_outputs_are_the_chain_quantities():
    """Every logged sample: qdd = forward dynamics, flange pose = fk, twist = J qd,
    base force/moment = minus the mounting's wrench on the arm from Chain.base_wrench."""
    r = spidersim.loads(free_arm()).simulate(t_end=0.5, rtol=1e-8, atol=1e-10, **KW)
    ch, _ = _chains()
    for k in range(0, len(r.t), max(1, len(r.t) // 15)):
        q, qd = r["arm.q"][k], r["arm.qd"][k]
        qdd = ch.forward_dynamics(q, qd, np.zeros(N))
        np.testing.assert_allclose(r["arm.qdd"][k], qdd, rtol=1e-10, atol=1e-10)
        T = ch.fk(q)
        np.testing.assert_allclose(r["arm.flange_pos"][k], T[:3, 3], atol=1e-12)
        np.testing.assert_allclose(r["arm.flange_rot"][k], T[:3, :3].ravel(), atol=1e-12)
        np.testing.assert_allclose(r["arm.flange_twist"][k], ch.jacobian(q) @ qd, atol=1e-12)
        f0, n0 = ch.base_wrench(q, qd, qdd)
        np.testing.assert_allclose(r["arm.base_force"][k], -f0, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(r["arm.base_moment"][k], -n0, rtol=1e-9, atol=1e-9)


def test_gravity_holding_torques_keep_the_arm_at_rest():
    """g = 9.81 along -z, tau = the static torques: q stays put for 1 s and the arm pushes
    down on its mounting with its weight 58 kg x 9.81."""
    ch, _ = _chains()
    ch.gravity = np.array([0.0, 0.0, -9.81])
    tau = ch.rnea(Q_FREE, np.zeros(N), np.zeros(N))
    text = f"""
name: hold
blocks:
  tau: {{type: Constant, value: {_yl(tau)}}}
  arm: {{type: Arm, q0: {_yl(Q_FREE)}, gravity: [0, 0, -9.81]}}
connections:
  - tau.y -> arm.tau
log: [arm.q, arm.base_force, arm.base_moment]
"""
    r = spidersim.loads(text).simulate(t_end=1.0, rtol=1e-10, atol=1e-12, **KW)
    assert np.abs(r["arm.q"] - Q_FREE).max() < 1e-9
    np.testing.assert_allclose(r["arm.base_force"][-1], [0, 0, -58.0 * 9.81], atol=1e-8)
    _f0, n0 = ch.base_wrench(Q_FREE, np.zeros(N), np.zeros(N))
    np.testing.assert_allclose(r["arm.base_moment"][-1], -n0, atol=1e-8)


# ============================================================================= payload latch
T_LATCH = 0.5


@pytest.fixture(scope="module")
def latch_run():
    """The run, or the IntegrationError it raised (reported by each test as a failure)."""
    text = free_arm(extra=", " + _payload_yaml(), t_latch=T_LATCH)
    try:
        return spidersim.loads(text).simulate(t_end=1.0, rtol=1e-10, atol=1e-12, **KW)
    except spidersim.IntegrationError as exc:
        return exc


def _ok(r):
    assert not isinstance(r, Exception), f"the latch run failed: {r}"
    return r


def _around(r, t_ev):
    """Rows just before and just after the event (two samples at the event time)."""
    rows = np.flatnonzero(r.t == t_ev)
    assert len(rows) == 2, f"expected a pre- and a post-event sample at {t_ev}: {rows}"
    return rows[0], rows[1]


def test_latch_conserves_generalized_momentum(latch_run):
    r = _ok(latch_run)
    latches = [e for e in r.events if e[1] == "arm" and e[2] == "latch"]
    assert len(latches) == 1, r.events
    t_ev = latches[0][0]
    assert t_ev == pytest.approx(T_LATCH, abs=1e-9)
    i0, i1 = _around(r, t_ev)
    q = r["arm.q"][i0]
    np.testing.assert_array_equal(r["arm.q"][i1], q)        # positions do not jump
    qd_m, qd_p = r["arm.qd"][i0], r["arm.qd"][i1]
    ch, _ = _chains()
    chp = _chain_with_grasp(*_grasp(r, i0))
    M, Mp = ch.mass_matrix(q), chp.mass_matrix(q)
    h = M @ qd_m
    assert np.linalg.norm(qd_p - qd_m) > 0.1 * np.linalg.norm(qd_m)     # a real jump
    assert np.linalg.norm(Mp @ qd_p - h) < 1e-9 * np.linalg.norm(h)
    # plastic capture: kinetic energy lost, never gained
    T_m, T_p = 0.5 * qd_m @ M @ qd_m, 0.5 * qd_p @ Mp @ qd_p
    assert T_p < T_m * (1 - 1e-3)
    # after the latch the arm moves with the payload: its energy is conserved, and so is
    # the generalized momentum of joint 1 (L_z) from before the latch
    q_e, qd_e = r["arm.q"][-1], r["arm.qd"][-1]
    assert chp.kinetic_energy(q_e, qd_e) == pytest.approx(T_p, rel=1e-6)
    assert (chp.mass_matrix(q_e) @ qd_e)[0] == pytest.approx(h[0], rel=1e-6, abs=1e-9)


def test_latch_mass_matrix_rises(latch_run):
    """M'(q) - M(q) is positive semidefinite, nonzero (rank <= 6), and equals the
    payload's own m Jv^T Jv + Jw^T (R_p I R_p^T) Jw at its COM (its logged pose at the end:
    attached where it was at the latch, not at the nominal grasp)."""
    r = _ok(latch_run)
    q = r["arm.q"][-1]
    ch, _ = _chains()
    c_rel, R_rel = _grasp(r, -1)
    assert np.linalg.norm(c_rel - PAYLOAD["com"]) > 0.05     # far from the nominal grasp
    chp = _chain_with_grasp(c_rel, R_rel)
    dM = chp.mass_matrix(q) - ch.mass_matrix(q)
    ev = np.linalg.eigvalsh(dM)
    assert ev.min() > -1e-10 * ev.max()
    assert ev.max() > 1.0
    rp = r["arm.payload_pos"][-1] - r["arm.flange_pos"][-1]
    J = ch.jacobian(q)
    skew = np.array([[0, -rp[2], rp[1]], [rp[2], 0, -rp[0]], [-rp[1], rp[0], 0]])
    Jv = J[:3] - skew @ J[3:]
    R = r["arm.payload_rot"][-1].reshape(3, 3)
    Ip = R @ np.diag(PAYLOAD["inertia"]) @ R.T
    ref = PAYLOAD["mass"] * Jv.T @ Jv + J[3:].T @ Ip @ J[3:]
    assert np.abs(dM - ref).max() < 1e-10 * np.abs(ref).max()
    # the latched run itself is finite and reached t_end
    assert r.t[-1] == pytest.approx(1.0) and np.all(np.isfinite(r["arm.qd"]))


# ============================================================================= rest to rest
V_LINE, A_LINE, DIST, T_START = 0.025, 0.05, 0.2, 0.5
T_MOVE = T_START + V_LINE / A_LINE + DIST / V_LINE        # 9.0 s: end of the profile
T_END = T_MOVE + 1.5


def _pd_gains(chp, wn=2 * np.pi * 2.0, zeta=1.0):
    Md = np.diag(chp.mass_matrix(Q0))
    return Md * wn ** 2, 2 * zeta * wn * Md


@pytest.fixture(scope="module")
def move_run():
    _, chp = _chains()
    kp, kd = _pd_gains(chp)
    text = f"""
name: line_move
blocks:
  path: {{type: TrapezoidalProfile, q0: 0, q1: {DIST}, v_max: {V_LINE}, a_max: {A_LINE},
         t_start: {T_START}}}
  ik:   {{type: CartesianLineIK, q0: {_yl(Q0)}, direction: [0, 0, 1]}}
  arm:  {{type: Arm, q0: {_yl(Q0)}, {_payload_yaml()}, latched: true}}
  e:    {{type: Sum, signs: "+-"}}
  ed:   {{type: Sum, signs: "+-"}}
  kp:   {{type: Gain, k: {_yl(kp)}}}
  kd:   {{type: Gain, k: {_yl(kd)}}}
  tau:  {{type: Sum, signs: "++"}}
connections:
  - path.q -> ik.s
  - path.qd -> ik.sd
  - ik.q_ref -> e.u1
  - arm.q -> e.u2
  - ik.qd_ref -> ed.u1
  - arm.qd -> ed.u2
  - e.y -> kp.u
  - ed.y -> kd.u
  - kp.y -> tau.u1
  - kd.y -> tau.u2
  - tau.y -> arm.tau
log: [arm.q, arm.qd, arm.base_force, arm.base_moment, arm.flange_pos, ik.p_ref]
"""
    return spidersim.loads(text).simulate(t_end=T_END, rtol=1e-8, atol=1e-10,
                                          output_interval=2e-3, **KW)


def test_rest_to_rest_base_impulse_vanishes(move_run):
    """Integral of the base force (moment) over the run ~ 0 against peak x duration: the
    arm starts and ends at rest. And exactly: impulse = minus the final momentum."""
    r = move_run
    t, F, Mo = r.t, r["arm.base_force"], r["arm.base_moment"]
    I_F, I_M = np.trapezoid(F, t, axis=0), np.trapezoid(Mo, t, axis=0)
    peak_F, peak_M = np.abs(F).max(), np.abs(Mo).max()
    assert peak_F > 0.1 and peak_M > 0.1                     # the move did load the base
    assert np.abs(I_F).max() < 1e-5 * peak_F * t[-1], (I_F, peak_F)
    assert np.abs(I_M).max() < 1e-5 * peak_M * t[-1], (I_M, peak_M)
    # the impulse the arm gives the mounting = minus the momentum it has gained
    _, chp = _chains()
    p_end, L_end = chp.momentum(r["arm.q"][-1], r["arm.qd"][-1])
    assert np.abs(I_F + p_end).max() < 1e-6 * peak_F * t[-1]
    assert np.abs(I_M + L_end).max() < 1e-6 * peak_M * t[-1]


def test_rest_to_rest_flange_reaches_line_end(move_run):
    r = move_run
    ch, _ = _chains()
    p0 = ch.fk(Q0)[:3, 3]
    p_end = p0 + DIST * np.array([0.0, 0.0, 1.0])
    assert np.linalg.norm(r["arm.flange_pos"][-1] - p_end) < 1e-3
    assert np.linalg.norm(r["ik.p_ref"][-1] - p_end) < 1e-12
    assert np.abs(r["arm.qd"][-1]).max() < 1e-4                 # stopped
    # it moved along the line on the way: mid-run the flange is well off its start
    k = np.searchsorted(r.t, T_START + (T_MOVE - T_START) / 2)
    assert np.linalg.norm(r["arm.flange_pos"][k] - p0) > 0.05


# ============================================================================= IK
@pytest.mark.parametrize("direction", [[0.0, 0.0, 1.0], [1.0, 0.5, -0.3]])
def test_cartesian_line_ik_follows_the_line(direction):
    text = f"""
name: ik_line
blocks:
  path: {{type: TrapezoidalProfile, q0: 0, q1: {DIST}, v_max: {V_LINE}, a_max: {A_LINE},
         t_start: {T_START}}}
  ik:   {{type: CartesianLineIK, q0: {_yl(Q0)}, direction: {_yl(direction)}}}
connections:
  - path.q -> ik.s
  - path.qd -> ik.sd
log: [ik.q_ref, ik.qd_ref, ik.p_ref, path.q]
"""
    r = spidersim.loads(text).simulate(t_end=T_MOVE + 0.5, rtol=1e-10, atol=1e-12,
                                       output_interval=0.01, **KW)
    ch, _ = _chains()
    T0 = ch.fk(Q0)
    u = np.array(direction) / np.linalg.norm(direction)
    s = r["path.q"]
    assert s[-1] == pytest.approx(DIST, abs=1e-12)
    pos_err, ang_err = [], []
    for q, sk in zip(r["ik.q_ref"], s):
        T = ch.fk(q)
        pos_err.append(np.linalg.norm(T[:3, 3] - (T0[:3, 3] + sk * u)))
        dR = T0[:3, :3].T @ T[:3, :3]
        ang_err.append(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1)))
    assert max(pos_err) < 1e-5, max(pos_err)
    assert max(ang_err) < 1e-5, max(ang_err)
    np.testing.assert_allclose(r["ik.p_ref"], T0[:3, 3] + s[:, None] * u, atol=1e-12)
    assert np.abs(r["ik.qd_ref"][-1]).max() < 1e-4                 # references stop too


def test_mass_matrix_factor_reused_only_while_valid():
    """The Arm block keeps the Cholesky factor of M(q) between evaluations at the same q
    (Newton iterations of a contact loop change only f_ext). Every answer must still be
    the Chain's forward dynamics: new f_ext at the same q (reuse), a new payload at the
    same q (P changed: no reuse), a new q."""
    p = Probe("Arm", {"q0": Q_FREE, "qd0": QD_FREE, "latched": True,
                      "payload_mass": PAYLOAD["mass"], "payload_com": PAYLOAD["com"],
                      "payload_inertia": PAYLOAD["inertia"]},
              sizes={"tau": N, "f_ext": 6, "latch": 1, "constraint": 4,
                     "constraint6": 15, "tau_r": N})
    rng = np.random.default_rng(7)
    tau = rng.normal(0.0, 5.0, N)
    p.set_input("tau", tau)
    _, chp = _chains()
    for k in range(3):
        f = rng.normal(0.0, 20.0, 6)
        p.set_input("f_ext", f)
        out = p.outputs(0.0, p.x0())
        np.testing.assert_allclose(out["qdd"], chp.forward_dynamics(Q_FREE, QD_FREE, tau, f),
                                   rtol=1e-10, atol=1e-10)
    # the payload changes with q unchanged: the kept factor must not be used
    p.set_param("payload_mass", 10.0)
    heavy = Chain.from_yaml()
    heavy._base = np.zeros(9)[:6]
    heavy.P = _with_payload(heavy.P, 10.0, PAYLOAD["com"], PAYLOAD["inertia"])
    out = p.outputs(0.0, p.x0())
    np.testing.assert_allclose(out["qdd"], heavy.forward_dynamics(Q_FREE, QD_FREE, tau, f),
                               rtol=1e-10, atol=1e-10)
    # another q
    x = p.x0()
    x[:N] += 0.1
    out = p.outputs(0.0, x)
    np.testing.assert_allclose(out["qdd"], heavy.forward_dynamics(x[:N], QD_FREE, tau, f),
                               rtol=1e-10, atol=1e-10)


def test_early_pose_call_then_full_call():
    """The arm's flange twist fed back as f_ext (through a Gain): the schedule calls the
    arm early for its pose and velocity outputs (``inputs_ready`` False: no forward
    dynamics) and again once f_ext is known. One evaluation at a new state must give the
    new twist J(q) qd and the qdd of the forward dynamics under f_ext = k J(q) qd (a
    stale or skipped early output would leave f_ext from the previous state)."""
    k = -40.0
    p = Probe("Arm", {"q0": Q0, "qd0": [0.3, -0.2, 0.1, 0.4, -0.5, 0.2, 0.6]},
              sizes={"tau": N, "latch": 1, "constraint": 4, "constraint6": 15, "tau_r": N},
              extra={"g": ("Gain", {"k": k})}, feed={"f_ext": "g.y"},
              wires=["blk.flange_twist -> g.u"])
    steps = p.d.layout.calls
    arm_calls = [i for i, s in enumerate(steps) if s.what == "blk"]
    assert len(arm_calls) == 2 and set(p.d.layout.partial) == {arm_calls[0]}
    calls = [ln for ln in p.d.source(jit=False).splitlines() if "_Arm_output(" in ln]
    assert len(calls) == 2 and ", False, " in calls[0] and ", True, " in calls[1]
    tau = np.linspace(-3.0, 3.0, N)
    p.set_input("tau", tau)
    ch, _ = _chains()
    x = p.x0()
    p.system.outputs(0.0, x)                         # the previous state
    q, qd = x[:N] + 0.2, x[N:2 * N] - 0.7
    x[:N], x[N:2 * N] = q, qd
    p.system.outputs(0.0, x)                         # one evaluation at the new state
    out = {o: p.system.sig[slice(*p.layout.ports[("out", o)].loc[1:])]
           for o in ("flange_twist", "qdd")}
    twist = ch.jacobian(q) @ qd
    np.testing.assert_allclose(out["flange_twist"], twist, atol=1e-12)
    qdd = ch.forward_dynamics(q, qd, tau, k * twist)
    np.testing.assert_allclose(out["qdd"], qdd, rtol=1e-10, atol=1e-10)
    assert np.abs(qdd - ch.forward_dynamics(q, qd, tau)).max() > 1e-2   # f_ext matters
