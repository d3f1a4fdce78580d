"""Switching blocks at their thresholds, on every engine: a Switch whose control input
passes through the threshold (located exactly on it) keeps the side it crossed to, and a
sliding mode (the switched output drives the control input back through the threshold at
once) is reported as chattering, never left in one mode while the input is on the other
side.

The sliding-mode rule guarded here (:func:`spidersim.solver.events.crossings`): a guard
left exactly at zero by its own block's event may not fire again by moving on in the
direction it crossed, but it fires when it turns back (the mode set by the event is then
inconsistent with the side the input went to). Before, both moves were ignored: the Switch
below stayed on ``u3`` with its control input above the threshold, the Relay with equal
points stayed off with its input far above them, exit status 0.
"""
import numpy as np
import pytest

import spidersim
from spidersim.errors import IntegrationError

ENGINES = [dict(jit=False), dict(jit=True, method="DP54"), dict(jit=True, method="ROS34PW2"),
           dict(jit=True, method="NDF"), dict(jit=False, method="RK45")]
IDS = ["scipy-lsoda", "dp54", "ros34pw2", "ndf", "scipy-rk45"]

RAMP_THROUGH = """\
blocks:
  r: {type: Constant, value: -1}
  x: {type: Integrator, x0: 0.1}
  a: {type: Constant, value: 1}
  b: {type: Constant, value: 2}
  s: {type: Switch, threshold: %r}
connections: [r.y -> x.u, a.y -> s.u1, x.y -> s.u2, b.y -> s.u3]
simulation: {t_end: 1, method: LSODA}
"""


@pytest.mark.parametrize("engine", ENGINES, ids=IDS)
@pytest.mark.parametrize("threshold", [0.05, 0.0, -0.3])
def test_switch_follows_a_control_input_falling_through_the_threshold(engine, threshold):
    """x = 0.1 - t: u1 (1) while x >= threshold, then u3 (2) to the end, one event at
    t = 0.1 - threshold."""
    r = spidersim.loads(RAMP_THROUGH % threshold).simulate(**engine)
    t_cross = 0.1 - threshold
    y = r["s.y"]
    assert np.all(y[r.t < t_cross - 1e-9] == 1.0)
    assert np.all(y[r.t > t_cross + 1e-9] == 2.0)
    ev = [t for t, b, n in r.events if b == "s"]
    assert len(ev) == 1 and ev[0] == pytest.approx(t_cross, abs=1e-9)


def test_switch_on_the_threshold_at_the_start_passes_u1():
    """``y = u1 while u2 >= threshold``: equality at t = 0 selects u1."""
    text = RAMP_THROUGH.replace("value: -1}", "value: 0}") % 0.1
    r = spidersim.loads(text).simulate()
    assert np.all(r["s.y"] == 1.0)


SLIDING_SWITCH = """\
blocks:
  x: {type: Integrator, x0: 0.1}
  dn: {type: Constant, value: -1}
  up: {type: Constant, value: 1}
  s: {type: Switch, threshold: %r}
connections: [dn.y -> s.u1, x.y -> s.u2, up.y -> s.u3, s.y -> x.u]
simulation: {t_end: 1, method: LSODA}
"""

SLIDING_RELAY = """\
blocks:
  x: {type: Integrator, x0: 0.1}
  r: {type: Relay, on_point: 0.05, off_point: 0.05, on_value: -1, off_value: 1}
connections: [x.y -> r.u, r.y -> x.u]
simulation: {t_end: 1, method: LSODA}
"""


@pytest.mark.parametrize("engine", ENGINES, ids=IDS)
@pytest.mark.parametrize("text, block, level", [(SLIDING_SWITCH % 0.0, "s", 0.0),
                                                (SLIDING_SWITCH % 0.05, "s", 0.05),
                                                (SLIDING_RELAY, "r", 0.05)],
                         ids=["switch-0", "switch-0.05", "relay-equal-points"])
def test_sliding_mode_is_reported_as_chattering(engine, text, block, level):
    """dx/dt = -1 above the level, +1 below: x reaches the level at t = 0.1 - level and the
    switched output pushes it back at once (a sliding mode, Filippov's x = level): the run
    fails as chattering at that instant, naming the block, with the data up to it; never
    a run that ends with x far from the level."""
    with pytest.raises(IntegrationError, match="chattering") as ei:
        spidersim.loads(text).simulate(**engine)
    err = ei.value
    assert err.block == block
    p = err.partial
    assert p.t[-1] == pytest.approx(0.1 - level, abs=1e-6)
    assert np.max(np.abs(p["x.y"] - np.clip(0.1 - p.t, level, None))) < 1e-6


RELAY_OPEN = """\
blocks:
  u: {type: Sine, amplitude: 1, f: 1}
  r: {type: Relay, on_point: %r, off_point: %r, on_value: 1, off_value: 0}
connections: [u.y -> r.u]
simulation: {t_end: 2, method: LSODA, output_interval: 1.0e-3}
"""


@pytest.mark.parametrize("engine", ENGINES, ids=IDS)
def test_relay_with_equal_points_in_an_open_path_follows_its_input(engine):
    """Without feedback a relay with on_point = off_point = 0.5 is on exactly while
    sin(2 pi t) > 0.5: four events in 2 s (on at 1/12 + k, off at 5/12 + k)."""
    r = spidersim.loads(RELAY_OPEN % (0.5, 0.5)).simulate(**engine)
    on = np.sin(2 * np.pi * r.t) > 0.5
    away = np.abs(np.sin(2 * np.pi * r.t) - 0.5) > 1e-6
    assert np.array_equal(r["r.y"][away] == 1.0, on[away])
    ev = sorted(t for t, b, n in r.events if b == "r")
    want = [1 / 12, 5 / 12, 13 / 12, 17 / 12]
    assert len(ev) == 4 and np.allclose(ev, want, atol=1e-9)
