"""The SciPy-stepper loop's parts on hand-written systems: no YAML, no code generation, no
numba (issue 17, item 1). Each system is a few lines over :class:`PlainSystem`."""
import math
import os
import warnings

import numpy as np
import pytest

from spidersim.errors import IntegrationError
from spidersim.solver.integrate import integrate
from spidersim.solver.system import PlainSystem

G = 9.81


class Ball(PlainSystem):
    """A ball dropped from rest at height ``h0``; impact ``x+ = 0, v+ = e |v-|`` (as the
    package's MassOnStop: near the Zeno time the located ``v-`` can round to a tiny
    positive value, and ``-e v-`` would then send the ball down through the floor)."""
    n_g, event_table = 1, [("ball", "impact", -1)]

    def __init__(self, h0, e):
        super().__init__([h0, 0.0])
        self.e = e

    def rhs(self, t, x):
        return np.array([x[1], -G])

    def guards(self, t, x):
        return np.array([x[0]])

    def apply_event(self, t, x, k, direction):
        x[0] = 0.0                  # on the floor (the located x is ~1e-16 off)
        x[1] = self.e * abs(x[1])


def _impact_times(h0, e, n):
    """Closed form: first impact at sqrt(2 h0 / g), then flights of 2 e^k v1 / g."""
    v1 = math.sqrt(2 * G * h0)
    t, out = v1 / G, []
    for k in range(n):
        out.append(t)
        t += 2 * e ** (k + 1) * v1 / G
    return np.array(out)


@pytest.mark.parametrize("method", ["RK45", "DOP853", "LSODA"])
def test_bouncing_ball_impacts_at_the_closed_form_times(method):
    """Detect + locate + apply: five impacts each at the closed-form time (1e-9 s), the
    velocity reversed and scaled by e at each."""
    r = integrate(Ball(1.0, 0.8), 3.5, method=method, rtol=1e-10, atol=1e-12)
    times = np.array([t for t, blk, name in r.events if name == "impact"])
    exact = _impact_times(1.0, 0.8, len(times))
    assert len(times) >= 5
    assert np.max(np.abs(times - exact)) < 1e-9
    # two rows at the first impact: before (falling at sqrt(2 g h0)) and after (reflected)
    at = np.flatnonzero(np.abs(r.t - exact[0]) < 1e-8)
    assert len(at) == 2
    assert r["x"][at[0], 1] == pytest.approx(-math.sqrt(2 * G), rel=1e-8)
    assert r["x"][at[1], 1] == pytest.approx(0.8 * math.sqrt(2 * G), rel=1e-8)


def test_zeno_ball_is_reported_as_chattering_and_keeps_its_data():
    """e = 0.5 without a rest mode: impacts accumulate at the Zeno time
    t_inf = t1 (1 + e) / (1 - e); the run fails as chattering, names the block, and the
    partial result stops within 1e-8 s of t_inf."""
    e, t1 = 0.5, math.sqrt(2 / G)
    with pytest.raises(IntegrationError) as ei:
        integrate(Ball(1.0, e), 5.0, method="RK45", rtol=1e-10, atol=1e-14)
    err = ei.value
    assert "chattering" in str(err) and "'ball'" in str(err)
    t_inf = t1 * (1 + e) / (1 - e)
    assert err.partial.t[-1] == pytest.approx(t_inf, abs=1e-8)
    assert err.partial.t[-1] <= t_inf + 1e-9


@pytest.mark.parametrize("method", ["LSODA", "BDF", "Radau"])
def test_zeno_ball_on_multistep_and_implicit_steppers_never_crosses_the_floor(method):
    """The multistep steppers take long steps right after an impact: the ball leaves the
    floor and lands again inside one step, a return the crossing test cannot see (the
    guard starts the step at zero, disarmed). Without the unseen-return check LSODA and BDF
    went on below the floor (x = -22.7 m at t = 15 s) and reported success. Now the step is
    retried shorter until the bounce is seen, and the run fails near the Zeno time
    (chattering, or a stall of steps below 1e-10 s) with every recorded x >= -1e-9."""
    e, t1 = 0.5, math.sqrt(2 / G)
    t_inf = t1 * (1 + e) / (1 - e)
    with pytest.raises(IntegrationError) as ei:
        integrate(Ball(1.0, e), 5.0, method=method, rtol=1e-10, atol=1e-14)
    part = ei.value.partial
    assert part.status == "failed"
    assert np.min(part["x"][:, 0]) > -1e-9
    assert abs(part.t[-1] - t_inf) < 1e-4
    assert len(part.events) > 20


class SampledIntegrator(PlainSystem):
    """``x' = u`` with ``u`` a zero-order hold of sin(t) sampled every ``T`` (a time
    event updating mode 0)."""

    def __init__(self, T):
        super().__init__([0.0], modes=[0.0, 0.0])  # held value, index of the next sample
        self.T = T

    def rhs(self, t, x):
        return np.array([self.modes[0]])

    def next_time(self, t):
        return self.modes[1] * self.T

    def time_events(self, t, x, tol):
        if self.modes[1] * self.T > t + tol:
            return []
        self.modes[0] = math.sin(self.modes[1] * self.T)
        self.modes[1] += 1
        return ["zoh"]


@pytest.mark.parametrize("output_interval", [None, 0.05])
def test_sampled_integrator_equals_the_sum_of_held_values(output_interval):
    """Time events cut the run into segments: x(1) = T sum_k sin(k T) exactly (each
    segment integrates a constant), one event per sample instant, on both recordings."""
    T = 0.1
    r = integrate(SampledIntegrator(T), 1.0, method="RK45", rtol=1e-8, atol=1e-12,
                  output_interval=output_interval)
    exact = T * sum(math.sin(k * T) for k in range(10))
    assert r["x"][-1] == pytest.approx(exact, rel=1e-12)
    samples = [t for t, blk, kind in r.events if kind == "time"]
    assert np.allclose(samples, np.arange(11) * T, atol=1e-12)
    assert r.stats["segments"] == 10 and r.stats["time_events"] == 11
    if output_interval:
        assert np.allclose(r.t, np.arange(21) * 0.05, atol=1e-12)
        # a grid point at a sample instant is recorded after the event: x is continuous,
        # so the value there is the sum of the held values so far
        assert r["x"][4] == pytest.approx(T * (math.sin(0) + math.sin(T)), rel=1e-12)


class BlowUp(PlainSystem):
    """``x' = x^2``, x(0) = 1: x = 1 / (1 - t), infinite at t = 1."""

    def __init__(self):
        super().__init__([1.0])

    def rhs(self, t, x):
        return x * x


def test_a_solution_that_blows_up_fails_with_its_data():
    """The loop stops before t = 1 with an IntegrationError whose partial result follows
    the closed form up to where it stopped."""
    with pytest.raises(IntegrationError) as ei:
        integrate(BlowUp(), 2.0, method="RK45", rtol=1e-8, atol=1e-10)
    p = ei.value.partial
    assert abs(p.t[-1] - 1.0) < 1e-6
    ok = p.t < 0.99
    assert np.allclose(p["x"][ok], 1 / (1 - p.t[ok]), rtol=1e-5)


def test_should_stop_interrupts_at_a_step_and_keeps_what_was_computed():
    """An interrupt after the 5th accepted step returns an 'interrupted' result with the
    six rows (start + 5 steps) and the final state at the step reached."""
    calls = []

    def stop():
        calls.append(1)
        return len(calls) >= 5

    class Decay(PlainSystem):
        def rhs(self, t, x):
            return -x

    r = integrate(Decay([1.0]), 30.0, method="RK45", should_stop=stop)
    assert r.status == "interrupted"
    assert len(r.t) == 6 and r.stats["steps"] == 5
    t, x, _ = r.final
    assert t == r.t[-1] < 30.0 and np.array_equal(x, [r["x"][-1]])
    assert r["x"][-1] == pytest.approx(math.exp(-t), rel=1e-5)


class Corner(PlainSystem):
    """Two guards: a state jump at t = 0.5 (time event) makes x leave +1 to -1, which
    crosses guard 1 (another 'block'); settle must fire it at the same instant."""
    n_g = 1
    event_table = [("sign", "flip", 0)]

    def __init__(self):
        super().__init__([1.0], modes=[0.0, 0.0])   # [time event done, flips seen]

    def rhs(self, t, x):
        return np.zeros(1)

    def guards(self, t, x):
        return np.array([x[0]])

    def apply_event(self, t, x, k, direction):
        self.modes[1] += 1

    def next_time(self, t):
        return 0.5 if self.modes[0] == 0 else np.inf

    def time_events(self, t, x, tol):
        if self.modes[0] == 0 and t >= 0.5 - tol:
            self.modes[0] = 1
            x[0] = -1.0
            return ["jump"]
        return []


def test_a_jump_at_a_time_event_fires_the_crossing_it_causes():
    """Settle: the guard on x changes sign across the time event's jump, so its event is
    applied at t = 0.5 exactly, once."""
    s = Corner()
    r = integrate(s, 1.0, method="RK45")
    flips = [t for t, blk, name in r.events if name == "flip"]
    assert flips == [0.5] and s.modes[1] == 1


def test_a_system_without_rhs_is_a_clear_error():
    """PlainSystem has no default right-hand side: integrating one says which method is
    missing instead of failing somewhere inside SciPy."""
    with pytest.raises(TypeError, match="Empty does not define rhs"):
        integrate(type("Empty", (PlainSystem,), {})([0.0]), 1.0, method="RK45")


def test_a_run_shorter_than_the_shortest_run_is_refused():
    """The API refuses a span below ``MIN_SPAN`` (1e-7 s) before stepping."""
    from spidersim.errors import SpidersimError
    with pytest.raises(SpidersimError, match="shorter than the shortest run of 1e-07 s"):
        integrate(Ball(1.0, 0.8), 1e-300, method="RK45")
    assert integrate(Ball(1.0, 0.8), 1e-7, method="RK45").t[-1] == 1e-7


class Warner(PlainSystem):
    """x' = 1, warning once from its right-hand side: as SciPy's own code (a file under a
    ``scipy`` folder) or as any other code; the state turns NaN at t = 0.5 if ``fail``."""

    def __init__(self, as_scipy, fail):
        super().__init__([0.0])
        self.as_scipy, self.fail, self.warned = as_scipy, fail, False

    def rhs(self, t, x):
        if not self.warned:
            self.warned = True
            where = os.path.join(os.sep, "lib", "scipy", "integrate", "x.py") \
                if self.as_scipy else __file__
            warnings.warn_explicit("lsoda: Repeated convergence failures", UserWarning,
                                   where, 7)
        return np.array([math.nan if self.fail and t > 0.5 else 1.0])


def test_scipy_warnings_go_into_the_failure_message_not_to_stderr(recwarn):
    """SciPy's steppers say why they fail in a warning of their own (LSODA: "Repeated
    convergence failures", then only "Unexpected istate"): it printed as raw lines before
    the clean error (``--set motor.b=1e300``). It is now part of the failure's message and
    not issued."""
    with pytest.raises(IntegrationError) as ei:
        integrate(Warner(as_scipy=True, fail=True), 1.0, method="RK45")
    assert "(SciPy: lsoda: Repeated convergence failures)" in str(ei.value)
    assert not [w for w in recwarn if "Repeated" in str(w.message)]


@pytest.mark.parametrize("as_scipy", [True, False])
def test_other_warnings_and_those_of_a_good_run_are_issued_again(as_scipy):
    """Only a failure takes SciPy's warnings in; any other warning, and every warning of a
    run that succeeds, is issued after the run as before."""
    with pytest.warns(UserWarning, match="Repeated convergence failures"):
        r = integrate(Warner(as_scipy=as_scipy, fail=False), 1.0, method="RK45")
    assert r.t[-1] == 1.0
    if not as_scipy:
        with pytest.warns(UserWarning, match="Repeated"), pytest.raises(IntegrationError) as ei:
            integrate(Warner(as_scipy=False, fail=True), 1.0, method="RK45")
        assert "SciPy:" not in str(ei.value)
