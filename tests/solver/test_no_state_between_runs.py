"""A run of the compiled loop sees nothing of an earlier run of the same diagram.

What a compiled system keeps from one run to the next (the record layout, the event tables:
``CompiledSystem.shared``) is structure only; every array a run writes (state, signals,
modes, Newton workspace, event arming, row buffers) is new for each run. These tests run
one diagram twice in a row with different parameters and end times and compare the second
run with the same run in a freshly loaded diagram, bit for bit, and check both against the
closed forms, so that a leak that happened to give the same wrong answer twice would fail.
"""
import math
import os

import numpy as np
import pytest

import spidersim

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _same(a, b):
    """Every logged array, the times, the event log and the step counts identical."""
    assert a.names == b.names
    np.testing.assert_array_equal(a.t, b.t)
    for name in a.names:
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)
    assert a.events == b.events
    for k in ("steps", "rhs_calls", "events", "newton_iterations"):
        assert a.stats[k] == b.stats[k], k
    assert a.stats.get("rejected_steps") == b.stats.get("rejected_steps")   # compiled loop


def test_algebraic_loop_second_run_as_a_fresh_one():
    """The loop y = u - K y, x' = y with u = sin(2 pi t): y = u / (1 + K) and
    x = (1 - cos 2 pi t) / (2 pi (1 + K)). A run with K = 3 to 2 s, then K = 9 to 1.3 s on
    the same diagram (Newton's workspace, warm start and iteration count live in the
    signal array) must equal K = 9 to 1.3 s on a fresh diagram, and both the closed form;
    K = 3 again afterwards must equal the first run."""
    path = os.path.join(ROOT, "diagrams/algebraic_loop.yaml")
    kw = dict(rtol=1e-9, atol=1e-12, method="DP54")
    d = spidersim.load(path)
    first = d.simulate(t_end=2.0, **kw)
    d.set("fb.k", 9.0)
    second = d.simulate(t_end=1.3, **kw)
    fresh = spidersim.load(path, set={"K": 9.0}).simulate(t_end=1.3, **kw)
    _same(second, fresh)
    t = second.t
    assert t[-1] == 1.3
    np.testing.assert_allclose(second["x.y"], (1 - np.cos(2 * np.pi * t)) / (2 * np.pi * 10),
                               atol=1e-9)
    np.testing.assert_allclose(second["sum.y"], np.sin(2 * np.pi * t) / 10, atol=1e-9)
    assert second.stats["newton_iterations"] > 0
    d.set("fb.k", 3.0)
    _same(d.simulate(t_end=2.0, **kw), first)


def _ball_t_end(e, g, h0, impacts):
    """Time of the last of ``impacts`` impacts plus half the next flight (closed form)."""
    t1 = math.sqrt(2 * h0 / g)
    return t1 + sum(2 * e ** k * t1 for k in range(1, impacts)) + e ** impacts * t1


@pytest.mark.parametrize("method", ["DP54", "ROS34PW2"])
def test_bouncing_ball_second_run_as_a_fresh_one(method):
    """Events arm and disarm guards, change modes and fill the event log: a ball run with
    e = 0.95 for 12 impacts, then e = 0.7 for 5 impacts on the same diagram must equal the
    second run on a fresh diagram, with exactly 5 impacts at the closed-form times
    t_k = t_1 (1 + 2 (e + ... + e^(k-1))), t_1 = sqrt(2 h0 / g)."""
    path = os.path.join(ROOT, "diagrams/bouncing_ball.yaml")
    kw = dict(rtol=1e-10, atol=1e-12, method=method, max_step=math.inf)
    d = spidersim.load(path, set={"ball.v_rest": 0, "ball.e": 0.95})
    d.simulate(t_end=_ball_t_end(0.95, 9.81, 10.0, 12), **kw)
    d.set("ball.e", 0.7)
    t_end = _ball_t_end(0.7, 9.81, 10.0, 5)
    second = d.simulate(t_end=t_end, **kw)
    fresh = spidersim.load(path, set={"ball.v_rest": 0, "ball.e": 0.7}).simulate(
        t_end=t_end, **kw)
    _same(second, fresh)
    t1 = math.sqrt(2 * 10.0 / 9.81)
    expect = [t1 * (1 + 2 * sum(0.7 ** j for j in range(1, k))) for k in range(1, 6)]
    got = [ev[0] for ev in second.events]
    assert len(got) == 5
    np.testing.assert_allclose(got, expect, rtol=1e-7)


@pytest.mark.parametrize("method", ["RK45", "DP54"])
def test_a_results_units_are_its_own(method):
    """Editing one result's units does not reach later results (found in review: the
    units dict kept per layout went into every SciPy-stepper Result as is)."""
    import spidersim
    d = spidersim.loads("blocks:\n  c: {type: Constant, value: 1}\n  i: {type: Integrator}\n"
                        "connections: [c.y -> i.u]\n")
    r1 = d.simulate(t_end=0.1, method=method)
    unit = r1.units["i.y"]
    r1.units["i.y"] = "furlong"
    for m in ("RK45", "DP54"):
        assert d.simulate(t_end=0.1, method=m).units["i.y"] == unit


@pytest.mark.parametrize("name, kw", [
    ("bouncing_ball.yaml", dict(t_end=15.0, rtol=1e-10, atol=1e-12, method="DP54",
                                max_step=math.inf)),        # ends at rest: its mode changed
    ("algebraic_loop.yaml", dict(t_end=1.0, rtol=1e-9, atol=1e-12, method="DP54")),
    ("lugre_stick_slip.yaml", dict(t_end=2.0, method="ROS34PW2")),
    ("servo.yaml", dict(t_end=0.2, method="LSODA")),
])
def test_same_run_twice_equals_a_fresh_run(name, kw):
    """``simulate`` keeps the system of its last run and resets it for the next
    (``Diagram._run_system``): the modes a run changed (the ball's contact, LuGre's
    regime), the event arming, Newton's warm start and iteration count and the parameters
    must all be back at their start values. The third run of one diagram equals the first
    run of a freshly loaded one, bit for bit, with either loop."""
    path = os.path.join(ROOT, "diagrams", name)
    d = spidersim.load(path)
    d.simulate(**kw)
    d.simulate(**kw)
    again = d.simulate(**kw)
    fresh = spidersim.load(path).simulate(**kw)
    _same(again, fresh)
    assert again.stats["steps"] > 10
    # each run ends with modes other than the start's (the ball at rest, LuGre sticking,
    # the servo's saturation): without the reset the next run would start from those
    changed = not np.array_equal(fresh.final[2], d.initial_modes())
    assert changed or name == "algebraic_loop.yaml"   # (its state: Newton's workspace)


def test_a_failed_run_leaves_nothing_for_the_next():
    """A run that fails half-way (the ball with e = 0.5 and no rest threshold chatters
    at t = 4.28 s, the Zeno point 3 t_1) is not kept for reuse: the next run, shorter
    than the failure, equals a fresh one."""
    path = os.path.join(ROOT, "diagrams/bouncing_ball.yaml")
    sets = {"ball.v_rest": 0, "ball.e": 0.5}
    kw = dict(t_end=4.25, rtol=1e-10, atol=1e-12, method="DP54", max_step=math.inf)
    d = spidersim.load(path, set=sets)
    with pytest.raises(spidersim.errors.IntegrationError, match="chattering"):
        d.simulate(**dict(kw, t_end=10.0))
    assert not d._idle                  # nothing kept for reuse
    after = d.simulate(**kw)
    _same(after, spidersim.load(path, set=sets).simulate(**kw))
    assert len(after.events) > 5
