"""The torque-mode joint (diagrams/joint_torque.yaml) alone, against closed forms.

The load is held (phi_l = w_l = 0), friction off: in steady state (the gear mode, 23 Hz with
zeta = 0.027, has decayed by 3 s) the motor current is
``tau_ref / (K_t N)`` and the gear passes ``tau_l = K_t N i`` to the load, the gear deflected
by ``tau_l / K1``; beyond ``K_t N I_max`` the current limit holds the torque there. With
friction on, the motor-side LuGre torque at rest takes part of the command (presliding):
the delivered torque is lower.
"""
from __future__ import annotations

import os

import numpy as np
import pytest

import spidersim

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
JOINT = os.path.join(ROOT, "diagrams", "joint_torque.yaml")

HELD = """
subsystems: {{joint: {joint}}}
blocks:
  cmd:  {{type: Step, t_step: 0.001, after: {tau}}}
  held: {{type: Constant, value: 0}}
  w0:   {{type: Constant, value: 0}}
  j:    {{type: joint, friction: {friction}, N: 160}}
connections:
  - cmd.y -> j.tau_ref
  - held.y -> j.phi_l
  - w0.y -> j.w_l
simulation: {{t_end: 3.0, rtol: 1e-8, atol: 1e-10}}
log: [j.tau_l, j.i_cmd, j.deflection]
"""
K_T, N, I_MAX, K1 = 0.15, 160, 4.0, 5.4e4


def _run(tau, friction=0):
    return spidersim.loads(HELD.format(joint=JOINT, tau=tau, friction=friction)).simulate()


@pytest.mark.parametrize("tau", [30.0, -60.0])
def test_held_load_receives_the_commanded_torque(tau):
    r = _run(tau)
    assert r["j.i_cmd"][-1] == pytest.approx(tau / (K_T * N), rel=1e-12)
    assert r["j.tau_l"][-1] == pytest.approx(tau, rel=1e-4)
    assert r["j.deflection"][-1] == pytest.approx(tau / K1, rel=1e-3)


def test_current_limit_caps_the_torque():
    r = _run(200.0)
    assert r["j.i_cmd"][-1] == I_MAX
    assert r["j.tau_l"][-1] == pytest.approx(K_T * N * I_MAX, rel=1e-4)     # 96 N.m


def test_friction_takes_part_of_the_command():
    ideal, rough = _run(30.0)["j.tau_l"][-1], _run(30.0, friction=1)["j.tau_l"][-1]
    assert ideal == pytest.approx(30.0, rel=1e-4)
    assert abs(rough - 30.0) > 0.05


def test_active_damping_of_the_gear_mode():
    """Held load, torque step: the gear deflection is a second-order response of the rotor's
    reflected inertia on K1. Its own damping gives zeta = d / (2 sqrt(K1 J_m N^2)) = 0.027
    (overshoot exp(-pi zeta / sqrt(1 - zeta^2)) = 92 %); the active damping term sets
    zeta_a = 0.5 (overshoot 16 %)."""
    import math

    def overshoot(zeta_a):
        text = HELD.format(joint=JOINT, tau=30.0, friction=0).replace(
            "N: 160}", f"N: 160, zeta_a: {zeta_a}}}")
        r = spidersim.loads(text).simulate(0.3)
        x = r["j.deflection"]
        return x.max() / (30.0 / K1) - 1.0

    for zeta, got in ((0.027, overshoot(0)), (0.5, overshoot(0.5))):
        assert got == pytest.approx(math.exp(-math.pi * zeta / math.sqrt(1 - zeta ** 2)),
                                    abs=0.03)
