"""Saturation, DeadZone, Relay and Switch against their piecewise formulas.

The mode blocks switch at their corners through zero-crossing events; between events the
output is a smooth function of the input selected by the mode, which ``initialize`` sets
from the input (at the start and after every event).
"""
import numpy as np
import pytest

import spidersim
from spidersim import ParameterError

from .harness import Probe, simulate

U = np.array([-5.0, -1.2, -1.0, -0.7, 0.0, 0.3, 0.5, 0.50001, 2.0, 2.5, 7.0])
ZC = pytest.mark.parametrize("zc", [True, False], ids=["zero_crossing", "direct"])


def _static(type_name, params, u):
    p = Probe(type_name, params, sizes={"u": len(u)})
    p.set_input("u", u)
    p.initialize()
    return p, p.outputs()["y"]


@ZC
def test_saturation_piecewise(zc):
    lo, hi = -1.0, 2.0
    _, y = _static("Saturation", {"lower": lo, "upper": hi, "zero_crossing": zc}, U)
    expect = np.array([lo if u < lo else hi if u > hi else u for u in U])
    np.testing.assert_array_equal(y, expect)


def test_saturation_default_limits_and_set():
    p, y = _static("Saturation", {}, U)
    np.testing.assert_array_equal(y, np.clip(U, -1.0, 1.0))
    p.set_param("upper", 0.4)
    p.initialize()
    np.testing.assert_array_equal(p.outputs()["y"], np.clip(U, -1.0, 0.4))


def test_saturation_mode_holds_between_events():
    """With zero crossing the mode, not the input, decides the branch: a limited element
    stays at its limit until an event or initialize moves it."""
    p, _ = _static("Saturation", {"lower": -1.0, "upper": 1.0}, [3.0, 0.2])
    np.testing.assert_array_equal(p.mode("m"), [1.0, 0.0])
    p.set_input("u", [0.5, 0.3])
    np.testing.assert_array_equal(p.outputs()["y"], [1.0, 0.3])
    p.initialize()
    np.testing.assert_array_equal(p.outputs()["y"], [0.5, 0.3])


@ZC
def test_saturation_of_a_sine(zc):
    """sin(2 pi t) limited to [-0.5, 0.8]: exact clip at every sample; with zero crossing the
    corners are events at asin(limit) / (2 pi) (+ symmetric times)."""
    r = simulate("blocks:\n  s: {type: Sine, f: 1}\n"
                 f"  sat: {{type: Saturation, lower: -0.5, upper: 0.8, zero_crossing: {zc}}}\n"
                 "connections:\n  - s.y -> sat.u\n", t_end=1.0, rtol=1e-8, atol=1e-10)
    y, u = r["sat.y"], r["s.y"]
    np.testing.assert_allclose(y, np.clip(u, -0.5, 0.8), rtol=0, atol=1e-7)
    # (the sample closing a segment at an event time is on the far side of the corner by
    # the location tolerance, still in the old mode)
    assert np.all(y <= 0.8 + 1e-9) and np.all(y >= -0.5 - 1e-9)
    if zc:
        a, b = np.arcsin(0.8) / (2 * np.pi), np.arcsin(0.5) / (2 * np.pi)
        corners = [a, 0.5 - a, 0.5 + b, 1.0 - b]
        got = sorted(e[0] for e in r.events if e[1] == "sat")
        assert len(got) == 4
        np.testing.assert_allclose(got, corners, rtol=0, atol=1e-7)


def test_saturation_rejects_crossed_limits():
    with pytest.raises(ParameterError, match="lower \\(1.0\\) must be below upper"):
        spidersim.loads("blocks:\n  s: {type: Saturation, lower: 1, upper: 0}\n"
                        "  c: {type: Constant}\nconnections:\n  - c.y -> s.u\n")


@ZC
@pytest.mark.parametrize("start,end", [(-0.5, 0.5), (-1.0, 0.3), (0.2, 2.0)])
def test_deadzone_piecewise(start, end, zc):
    p, y = _static("DeadZone", {"start": start, "end": end, "zero_crossing": zc}, U)
    expect = np.where(U > end, U - end, np.where(U < start, U - start, 0.0))
    np.testing.assert_array_equal(y, expect)
    inside = (U >= start) & (U <= end)
    assert inside.any() and (~inside).any()
    for edge in (start, end):      # continuous at the edges
        p.set_input("u", np.full(U.size, edge))
        p.initialize()
        assert np.all(p.outputs()["y"] == 0.0)


@pytest.mark.parametrize("block,expect_end", [
    ("{type: Saturation, lower: -0.5, upper: 0.5}", 0.5),
    ("{type: DeadZone, start: -0.5, end: 0.5}", 1.5)], ids=["Saturation", "DeadZone"])
def test_mode_survives_an_event_located_exactly_on_the_corner(block, expect_end):
    """u = t - 2 (a ramp) reaches the corners +-0.5 at t = 1.5 and 2.5 *exactly*, so the
    located event sits where the guard is exactly 0.0. ``on_event`` picks the mode from the
    crossing direction; ``initialize`` (run right after every event) must keep it there.
    Regression: it recomputed the mode with strict inequalities (``u > upper``) and put the
    block back in the middle mode; the guard then started the next step at 0.0, which
    ``crossed`` does not count, so the block stayed in the wrong mode for the rest of the
    run (Saturation output 2.0 at t = 4).
    """
    r = simulate(f"blocks:\n  s: {{type: Ramp, offset: -2}}\n  nl: {block}\n"
                 "  i: {type: Integrator}\nconnections:\n  - s.y -> nl.u\n  - nl.y -> i.u\n",
                 t_end=4.0, rtol=1e-8, atol=1e-10)
    assert r["nl.y"][-1] == pytest.approx(expect_end, abs=1e-9)
    if "Saturation" in block:
        assert np.max(r["nl.y"]) <= 0.5 + 1e-12 and np.min(r["nl.y"]) >= -0.5 - 1e-12


def test_deadzone_of_a_ramp():
    """u = t - 2 through the zone [-0.5, 0.5]: y = 0 inside, u -+ edge outside, and the edges
    are events at t = 1.5 and 2.5."""
    r = simulate("blocks:\n  s: {type: Ramp, offset: -2}\n  dz: {type: DeadZone}\n"
                 "connections:\n  - s.y -> dz.u\n", t_end=4.0, rtol=1e-8, atol=1e-10)
    u = r.t - 2.0
    expect = np.where(u > 0.5, u - 0.5, np.where(u < -0.5, u + 0.5, 0.0))
    np.testing.assert_allclose(r["dz.y"], expect, rtol=0, atol=1e-7)
    np.testing.assert_allclose(sorted(e[0] for e in r.events if e[1] == "dz"), [1.5, 2.5],
                               rtol=0, atol=1e-7)


def test_deadzone_rejects_crossed_edges():
    with pytest.raises(ParameterError, match="start \\(1.0\\) must be below end"):
        spidersim.loads("blocks:\n  s: {type: DeadZone, start: 1, end: 0}\n"
                        "  c: {type: Constant}\nconnections:\n  - c.y -> s.u\n")


def test_relay_hysteresis_on_a_sine():
    """u = sin(2 pi t): on when u rises through 0.5 (t = 1/12), off when it falls through
    -0.5 (t = 7/12); stays on between the thresholds."""
    r = simulate("blocks:\n  s: {type: Sine, f: 1}\n"
                 "  rl: {type: Relay, on_point: 0.5, off_point: -0.5, on_value: 2, "
                 "off_value: -1}\nconnections:\n  - s.y -> rl.u\n",
                 t_end=1.5, rtol=1e-8, atol=1e-10)
    ev = sorted(e[0] for e in r.events if e[1] == "rl")
    np.testing.assert_allclose(ev, [1 / 12, 7 / 12, 13 / 12], rtol=0, atol=1e-7)
    t, y = r.t, r["rl.y"]
    away = np.min(np.abs(t[:, None] - np.array(ev)[None, :]), axis=1) > 1e-9
    assert np.sum(~away) == 6          # each event time is recorded twice: old, new level
    on = away & (((t > 1 / 12) & (t < 7 / 12)) | (t > 13 / 12))
    off = away & ((t < 1 / 12) | ((t > 7 / 12) & (t < 13 / 12)))
    assert np.all(y[on] == 2.0) and np.all(y[off] == -1.0)
    assert on.sum() > 5 and off.sum() > 5


@pytest.mark.parametrize("u,initially_on,expect", [(0.0, False, 0.0), (0.0, True, 1.0),
                                                   (0.7, False, 1.0), (-0.7, True, 0.0)])
def test_relay_initial_state(u, initially_on, expect):
    p = Probe("Relay", {"initially_on": initially_on})
    p.set_input("u", u)
    p.initialize()
    assert p.outputs()["y"][0] == expect


def test_switch_selects_by_control_input():
    """u2 = sin(2 pi t) against threshold 0.5: y = u1 while u2 >= 0.5, else u3."""
    r = simulate("blocks:\n  a: {type: Constant, value: [1, 2]}\n"
                 "  b: {type: Constant, value: [-1, -2]}\n  c: {type: Sine, f: 1}\n"
                 "  sw: {type: Switch, threshold: 0.5}\nconnections:\n"
                 "  - a.y -> sw.u1\n  - c.y -> sw.u2\n  - b.y -> sw.u3\n",
                 t_end=1.0, rtol=1e-8, atol=1e-10)
    ev = sorted(e[0] for e in r.events if e[1] == "sw")
    np.testing.assert_allclose(ev, [1 / 12, 5 / 12], rtol=0, atol=1e-7)
    t, y = r.t, r["sw.y"]
    away = np.min(np.abs(t[:, None] - np.array(ev)[None, :]), axis=1) > 1e-9
    first = away & (t > 1 / 12) & (t < 5 / 12)
    third = away & ((t < 1 / 12) | (t > 5 / 12))
    np.testing.assert_array_equal(y[first], np.tile([1.0, 2.0], (first.sum(), 1)))
    np.testing.assert_array_equal(y[third], np.tile([-1.0, -2.0], (third.sum(), 1)))


def test_switch_rejects_different_data_sizes():
    with pytest.raises(ParameterError, match="same size"):
        spidersim.loads("blocks:\n  a: {type: Constant, value: [1, 2]}\n"
                        "  b: {type: Constant}\n  sw: {type: Switch}\nconnections:\n"
                        "  - a.y -> sw.u1\n  - b.y -> sw.u2, sw.u3\n")


@pytest.mark.parametrize("method", ["DP54", "LSODA"])
def test_saturations_in_series_initialize_in_order(method):
    """Two saturations in series start beyond their limits: s1 (+-1) clips 5 to 1, and s2
    (+-2) must take its mode from s1's clipped output (inside: 1), not from s1's output
    before s1's own mode was set (5: s2 would start clipping at 2). The outputs are
    evaluated again between the two ``initialize`` kernels because s1 reaches s2's input
    (``codegen.influence``); a third saturation fed by the constant directly needs none."""
    from spidersim.diagram.codegen import influence
    text = ("blocks:\n  c: {type: Constant, value: 5.0}\n"
            "  s1: {type: Saturation, lower: -1.0, upper: 1.0}\n"
            "  s2: {type: Saturation, lower: -2.0, upper: 2.0}\n"
            "  s3: {type: Saturation, lower: -3.0, upper: 3.0}\n"
            "connections:\n  - c.y -> s1.u\n  - s1.y -> s2.u\n  - c.y -> s3.u\n")
    d = spidersim.loads(text)
    r = d.simulate(t_end=0.1, method=method)
    np.testing.assert_array_equal(r["s1.y"], 1.0)
    np.testing.assert_array_equal(r["s2.y"], 1.0)
    np.testing.assert_array_equal(r["s3.y"], 3.0)
    init = [d.layout.blocks[p] for p in ("s1", "s2", "s3")]
    assert influence(d.layout, init) == [[], [0], []]
