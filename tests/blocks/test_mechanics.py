"""Inertia and MassOnStop against closed forms (free flight, impacts, rest, lift-off)."""
import numpy as np
import pytest

from .harness import Probe, simulate

G = 9.81


def test_inertia_constant_torque():
    """J w' = tau: w = w0 + tau/J t, phi = phi0 + w0 t + tau/(2J) t^2, a = tau/J."""
    J, tau, w0, phi0 = 0.5, 2.0, 1.0, 0.5
    r = simulate(f"blocks:\n  tq: {{type: Constant, value: {tau}}}\n"
                 f"  j: {{type: Inertia, J: {J}, w0: {w0}, phi0: {phi0}}}\n"
                 "connections:\n  - tq.y -> j.tau\n", t_end=2.0, rtol=1e-8, atol=1e-10)
    t = r.t
    np.testing.assert_allclose(r["j.w"], w0 + tau / J * t, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(r["j.phi"], phi0 + w0 * t + tau / (2 * J) * t ** 2,
                               rtol=10 * 1e-8, atol=1e-10)
    assert np.all(r["j.a"] == tau / J)


def test_inertia_acceleration_is_feedthrough():
    p = Probe("Inertia", {"J": 4.0})
    assert p.layout.feedthrough["a"] == ("tau",)
    p.set_input("tau", -2.0)
    assert p.outputs()["a"][0] == -0.5
    assert p.derivatives()["w"][0] == -0.5


def _drop(extra="", t_end=2.5, f=None, **prm):
    body = ", ".join(f"{k}: {v}" for k, v in dict(dict(m=1.0, e=0.8, x0=1.0), **prm).items())
    text = f"blocks:\n  m: {{type: MassOnStop, {body}}}\n" + extra
    if f is not None:
        text += f"  f: {f}\nconnections:\n  - f.y -> m.f\n"
    return simulate(text, t_end=t_end, rtol=1e-10, atol=1e-12)


def test_bouncing_impact_times_and_rebound():
    """Drop from x0 = 1: t1 = sqrt(2 x0 / g), then flights of 2 e^n v1 / g; v+ = -e v-."""
    e = 0.8
    r = _drop(e=e)
    t1 = np.sqrt(2.0 / G)
    v1 = G * t1
    expect = [t1]
    for n in range(1, 4):
        expect.append(expect[-1] + 2 * e ** n * v1 / G)
    got = [ev[0] for ev in r.events if ev[2] == "impact"]
    assert len(got) == 4
    np.testing.assert_allclose(got, expect, rtol=0, atol=1e-8)
    k = int(np.flatnonzero(r.t == got[0])[-1])          # first sample after the impact
    assert r["m.v"][k] == pytest.approx(e * v1, rel=1e-8)
    assert r["m.v"][k - 1] == pytest.approx(-v1, rel=1e-8)
    assert np.all(r["m.x"] >= -1e-9)
    # free flight in between: x = v_k (t - t_k) - g (t - t_k)^2 / 2 (apex e^2 x0)
    first = (r.t > got[0]) & (r.t < got[1])
    assert first.sum() >= 3
    tt = r.t[first] - got[0]
    np.testing.assert_allclose(r["m.x"][first], e * v1 * tt - G * tt ** 2 / 2, atol=1e-8)


def test_comes_to_rest_below_v_rest():
    """e = 0.5, v_rest = 1: rebounds 2.21 and 1.11 m/s, then 0.55 <= v_rest: rest at x_stop."""
    r = _drop(e=0.5, v_rest=1.0, t_end=3.0)
    got = [ev[0] for ev in r.events if ev[2] == "impact"]
    t1 = np.sqrt(2.0 / G)
    np.testing.assert_allclose(got, [t1, 2 * t1, 2.5 * t1], rtol=0, atol=1e-8)
    after = r.t > got[-1]
    assert after.sum() >= 1
    assert np.all(r["m.x"][after] == 0.0) and np.all(r["m.v"][after] == 0.0)


def test_lift_off_when_force_exceeds_weight():
    """Resting mass, f = 10 (t - 2) N from t = 2: lift-off where f = m g (t_L = 2.981),
    then x = 10/6 (t - t_L)^3."""
    r = _drop(e=0.5, v_rest=1.0, t_end=4.0, f="{type: Ramp, slope: 10, t_start: 2}")
    lifts = [ev[0] for ev in r.events if ev[2] == "lift_off"]
    tl = 2.0 + G / 10.0
    assert lifts == pytest.approx([tl], abs=1e-8)
    up = r.t > tl
    np.testing.assert_allclose(r["m.x"][up], 10.0 / 6.0 * (r.t[up] - tl) ** 3,
                               rtol=1e-6, atol=1e-9)


def test_lift_off_when_force_steps_past_weight():
    """A force that *steps* past m g (a time event) must lift a resting mass at once: the
    lift-off guard f/m - g jumps from negative to positive at the event, so no step sees it
    cross zero. Regression: with guards only compared at step ends (and no ``initialize``
    hook in MassOnStop) the mass stayed on the stop for ever."""
    r = _drop(e=0.5, v_rest=1.0, t_end=4.0, f="{type: Step, t_step: 3, after: 15}")
    acc = 15.0 - G
    assert r["m.x"][-1] == pytest.approx(acc / 2, rel=1e-6), "the mass never lifted off"
    assert r["m.v"][-1] == pytest.approx(acc, rel=1e-6)
