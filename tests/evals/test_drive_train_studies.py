"""The paper's force-control (Fig. 10) and capture (Fig. 6) studies with the drive trains in
the loop: the HybridForceController's joint torques are the commands of seven torque-mode
SPIDER joints (diagrams/joint_torque.yaml).

Force control (friction off here, to keep the run short; tools/study_force_control.py runs
friction on as well): the force loop crosses over at f_F = 1.5 Hz (ki_f = 2 pi f_F) with the
gear mode damped actively (zeta_a = 0.5), so a force step is nearly first order: time
constant 1 / ki_f = 0.106 s, 2 % settling in about 4 / ki_f = 0.42 s, no overshoot beyond a
few per cent. Without the active damping the same loop rings (the gear resonance has a
25 dB peak): the test of the overshoot fails then.
"""
from __future__ import annotations

import math
import os

import numpy as np
import pytest

import spidersim

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DIAGRAMS = os.path.join(ROOT, "diagrams")
KI_F = 2 * math.pi * 1.5


@pytest.fixture(scope="module")
def force_run():
    """The friction-free study to 2.9 s (the 20 -> 50 N step and its settling; the file runs
    to 4.5 s for the third step) with the file's NDF, which replaced LSODA: the same figures
    (measured, NDF and LSODA alike: settling 310 ms, overshoot 1.75 %, steady error
    -0.144 N, largest |tau_l - tau_cmd| 1.877 N.m) in 3,366 steps instead of 71,963
    (1.9 s against 111 s on a loaded machine)."""
    d = spidersim.load(os.path.join(DIAGRAMS, "force_control_rigid.yaml"),
                       set={"friction": 0})
    return d.simulate(2.9)


def test_force_step_through_the_drive_trains(force_run):
    r = force_run
    t, lam, ref = r.t, r["wall.lam"], r["fset.y"]
    step = (t > 1.5) & (t < 2.9)                         # 20 N -> 50 N at t = 1.5 s
    assert ref[step][-1] == 50.0
    err = lam[step] - 50.0
    assert lam[step].max() - 50.0 < 0.05 * 30.0           # overshoot < 5 %
    late = np.flatnonzero(np.abs(err) > 0.02 * 30.0)
    settle = t[step][late[-1]] - 1.5
    assert settle < 1.5 * 4 / KI_F                        # ~0.42 s designed
    assert abs(np.mean(err[t[step] > 2.7])) < 0.5         # steady error < 0.5 N
    assert np.abs(r["wall.gap"][t > 0.2]).max() < 1e-6    # the plane holds


def test_the_drive_trains_are_in_the_loop(force_run):
    """The delivered joint torques lag the commanded ones (gear compliance, current loop):
    with ideal torques they would be equal."""
    r = force_run
    diff = np.abs(r["tau_l.y"] - r["ctrl.tau"]).max()
    assert diff > 0.1


@pytest.fixture(scope="module")
def capture_run():
    """payload_capture.yaml as shipped (NDF, which replaced LSODA: the same figures, measured
    with both methods: approach lag 24.62 mm, flange 13.41 mm from the fixture at the latch,
    payload carried 199.3 mm, in 22,233 steps instead of 44,771: 6.0 s against 27.7 s on a
    loaded machine)."""
    return spidersim.load(os.path.join(DIAGRAMS, "payload_capture.yaml")).simulate()


def test_capture_through_the_drive_trains(capture_run):
    r = capture_run
    assert [e for e in r.events if e[1:] == ("arm", "latch")] == [(3.0, "arm", "latch")]
    # the approach (0.05 m/s down): ideal torques lag by Kd v / Kp = 0.01 m; friction in the
    # drive trains adds to the lag, and the joints still follow within a few centimetres
    cruise = (r.t > 1.5) & (r.t < 2.2)
    lag = -np.mean(r["perr.y"][cruise, 2])
    assert 0.01 < lag < 0.05
    # the drifting payload (2 cm/s along y) is met at the latch within the approach lag,
    # and captured where it is: its fixture then stays put on the flange
    k = np.searchsorted(r.t, 3.0)
    assert np.linalg.norm(r["arm.flange_pos"][k] - r["arm.grapple_pos"][k]) < 0.02
    Rf = r["arm.flange_rot"].reshape(-1, 3, 3)
    d_f = np.einsum("kji,kj->ki", Rf, r["arm.grapple_pos"] - r["arm.flange_pos"])
    assert np.abs(d_f[r.t > 3.0] - d_f[k]).max() < 1e-9
    assert r["arm.grapple_pos"][k, 1] - r["arm.grapple_pos"][0, 1] == pytest.approx(0.06,
                                                                                  abs=1e-9)
    # the payload is carried: the flange ends 20 cm along x from its start
    assert r["arm.flange_pos"][-1, 0] - r["arm.flange_pos"][0, 0] == pytest.approx(0.2,
                                                                                  abs=0.02)
