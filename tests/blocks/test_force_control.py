"""HybridForceController and WrenchSensor against closed forms of their laws.

The controller's torques are checked through the arm's own dynamics (spidersim.multibody
Chain): ``qdd = M^-1 (tau - b)`` and the flange acceleration ``J qdd + Jdot qd``.
"""
import numpy as np
import pytest

import spidersim
from spidersim.multibody.chain import SPIDER, Chain

from .harness import Probe

Q0 = np.array([0.0, 0.6, 0.0, -1.3, 0.0, 0.8, 0.0])
SIZES = {"q": 7, "qd": 7, "p_ref": 3, "F_ref": 3, "F_meas": 6}


@pytest.fixture(scope="module")
def chain():
    return Chain.from_yaml(SPIDER)


def _probe(**params):
    p = Probe("HybridForceController", {"q0": Q0.tolist(), **params}, sizes=SIZES)
    return p


@pytest.fixture(scope="module")
def probe():
    return _probe(Kp=[400.0, 300.0, 200.0, 100.0, 150.0, 120.0], Kd=0.0, k_null=0.0,
                  ki_f=0.0, selection=[1, 1, 1, 1, 1, 1])


def test_position_law_gives_the_commanded_task_acceleration(chain, probe):
    """At rest with a position error e and no orientation error, the flange accelerates at
    exactly Kp e (Lambda = (J M^-1 J^T)^-1 decouples the task directions)."""
    rng = np.random.default_rng(3)
    q = Q0 + rng.normal(0, 0.05, 7)
    T = chain.fk(q)
    e = np.array([0.01, -0.02, 0.015])
    probe.set_param("q0", q.tolist())                  # hold this orientation
    probe.set_input("q", q)
    probe.set_input("qd", np.zeros(7))
    probe.set_input("p_ref", T[:3, 3] + e)
    tau = probe.outputs()["tau"]
    qdd = np.linalg.solve(chain.mass_matrix(q), tau)
    a = chain.jacobian(q) @ qdd
    assert np.allclose(a[:3], np.array([400.0, 300.0, 200.0]) * e, rtol=1e-9, atol=1e-12)
    assert np.allclose(a[3:], 0.0, atol=1e-9)


def test_null_space_damping_does_not_move_the_flange(chain):
    """tau = N^T tau_0 with N^T = I - J^T Lambda J M^-1: J M^-1 tau = 0 (no task
    acceleration), while the joint-space damping power qd . tau < 0."""
    p = _probe(Kp=0.0, Kd=0.0, ki_f=0.0, k_null=5.0, selection=[1, 1, 1, 1, 1, 1])
    rng = np.random.default_rng(5)
    q = Q0 + rng.normal(0, 0.05, 7)
    qd = rng.normal(0, 0.3, 7)
    p.set_input("q", q)
    p.set_input("qd", qd)
    p.set_input("p_ref", chain.fk(q)[:3, 3])
    tau = p.outputs()["tau"]
    J, M = chain.jacobian(q), chain.mass_matrix(q)
    assert np.linalg.norm(tau) > 0.1
    assert np.allclose(J @ np.linalg.solve(M, tau), 0.0, atol=1e-10 * np.linalg.norm(tau))
    assert qd @ tau < 0.0


def test_force_direction_applies_the_force_law(chain):
    """Force-controlled z: with zero position error the joint torques are J^T F with
    F_z = ff F_ref + kp_f (F_ref - F_meas) + ki_f xi; the position-controlled directions
    get nothing."""
    p = _probe(Kp=400.0, Kd=40.0, ff=1.0, kp_f=0.5, ki_f=30.0, k_null=0.0,
               selection=[1, 1, 0, 1, 1, 1])
    q = Q0
    p.set_input("q", q)
    p.set_input("qd", np.zeros(7))
    p.set_input("p_ref", chain.fk(q)[:3, 3])
    p.set_input("F_ref", [3.0, -2.0, 20.0])            # x, y are position-controlled
    p.set_input("F_meas", [0.0, 0.0, 12.0, 0.0, 0.0, 0.0])
    x = p.x0()
    p.set_state(x, "xi", [0.0, 0.0, 0.2])
    out = p.outputs(0.0, x)
    Fz = 1.0 * 20.0 + 0.5 * (20.0 - 12.0) + 30.0 * 0.2
    J = chain.jacobian(q)
    assert np.allclose(out["tau"], J[2] * Fz, rtol=1e-10, atol=1e-10)
    assert np.allclose(out["e_F"], [0.0, 0.0, 8.0])
    assert np.allclose(p.derivatives(0.0, x)["xi"], [0.0, 0.0, 8.0])


def test_gravity_compensation_holds_the_arm(chain):
    p = _probe(gravity=[0.0, 0.0, -9.81], Kp=400.0, Kd=40.0, k_null=0.0,
               selection=[1, 1, 1, 1, 1, 1])
    p.set_input("q", Q0)
    p.set_input("qd", np.zeros(7))
    p.set_input("p_ref", chain.fk(Q0)[:3, 3])
    tau = p.outputs()["tau"]
    chain.gravity = np.array([0.0, 0.0, -9.81])
    try:
        g = chain.rnea(Q0, np.zeros(7), np.zeros(7))
    finally:
        chain.gravity = np.zeros(3)
    assert np.abs(g).max() > 1.0
    assert np.allclose(tau, g, rtol=1e-10, atol=1e-9)


def test_selection_must_be_zero_or_one():
    from spidersim.errors import ParameterError
    with pytest.raises(ParameterError, match="selection"):
        _probe(selection=[1, 1, 0.5, 1, 1, 1])


def test_selection_of_a_rotation_must_be_position():
    """The force law regulates forces along x y z only (F_ref, F_meas: 3 entries used): a
    rotation marked 0 was neither position- nor moment-controlled, without a word."""
    from spidersim.errors import ParameterError
    with pytest.raises(ParameterError, match=r"rotations \(entries 4-6: rx ry rz\) must be 1"):
        _probe(selection=[1, 1, 1, 1, 1, 0])


@pytest.mark.parametrize("frame", ["base", "flange"])
def test_wrench_sensor_reads_the_wrench_on_the_environment(frame, chain):
    """Steady state of the first-order sensor: -w_ext in base axes, R^T (-w_ext) in flange
    axes, plus the bias; the derivative is 2 pi f_c (u - F)."""
    p = Probe("WrenchSensor", {"f_c": 40.0, "frame": frame,
                               "bias": [0.1, 0.0, 0.0, 0.0, 0.0, -0.2]},
              sizes={"wrench": 6, "rot": 9})
    R = chain.fk(Q0)[:3, :3]
    w = np.array([3.0, -4.0, 12.0, 0.5, -0.1, 0.3])
    p.set_input("wrench", w)
    p.set_input("rot", R.ravel())
    u = -w.copy()
    if frame == "flange":
        u[:3], u[3:] = R.T @ u[:3], R.T @ u[3:]
    u += [0.1, 0.0, 0.0, 0.0, 0.0, -0.2]
    x = p.x0()
    F = np.linspace(-1.0, 1.0, 6)
    p.set_state(x, "F", F)
    assert np.allclose(p.outputs(0.0, x)["F"], F)
    assert np.allclose(p.derivatives(0.0, x)["F"], 2 * np.pi * 40.0 * (u - F), rtol=1e-12)


def test_wrench_sensor_in_flange_axes_needs_the_rotation():
    """frame 'flange' without 'rot' wired would read zeros as R: refused at load."""
    from spidersim.errors import WiringError
    text = """
blocks:
  w: {type: Constant, value: [1, 2, 3, 0, 0, 0]}
  s: {type: WrenchSensor, frame: %s}
connections:
  - w.y -> s.wrench
"""
    with pytest.raises(WiringError, match=r"input 'rot' .* is not connected \(flange "
                                          r"rotation.*needed for frame 'flange'"):
        spidersim.loads(text % "flange")
    spidersim.loads(text % "base")               # optional there


def test_torques_stay_finite_at_a_singular_pose():
    """q = 0 (arm stretched straight up): J has rank < 6, J M^-1 J^T is singular; the
    factorisation falls back to a damped inverse (torques finite), and a larger damping
    keeps them moderate."""
    sizes = {**SIZES}
    out = {}
    for damping in (0.0, 1e-3):
        p = Probe("HybridForceController", {"q0": [0.0] * 7, "damping": damping,
                                            "selection": [1, 1, 0, 1, 1, 1]}, sizes=sizes)
        p.set_input("q", np.zeros(7))
        p.set_input("qd", np.full(7, 0.1))
        p.set_input("p_ref", Chain.from_yaml().fk(np.zeros(7))[:3, 3] + [0.01, 0.0, 0.0])
        p.set_input("F_ref", [0.0, 0.0, -10.0])
        out[damping] = p.outputs(0.0, p.x0())["tau"]
    assert np.all(np.isfinite(out[0.0])) and np.all(np.isfinite(out[1e-3]))
    assert np.abs(out[1e-3]).max() < np.abs(out[0.0]).max()
