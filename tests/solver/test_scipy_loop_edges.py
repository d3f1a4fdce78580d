"""Edges of the SciPy steppers' loop that the compiled loop already handled, every SciPy
method against the compiled DP54 and a closed form: time events due at ``t_end`` when a
state event lands exactly there, and a ``first_step`` longer than a segment."""
import numpy as np
import pytest

import spidersim

SCIPY = ["RK45", "RK23", "DOP853", "LSODA", "BDF", "Radau"]

EVENT_AT_END = """\
blocks:
  r:   {type: Ramp, slope: 1}
  sat: {type: Saturation, lower: -1, upper: 0.5}
  st:  {type: Step, t_step: 0.5, after: 5}
  z:   {type: ZeroOrderHold, Ts: 0.25}
connections: [r.y -> sat.u, r.y -> z.u]
simulation: {t_end: 0.5}
"""


@pytest.mark.parametrize("method", SCIPY + ["DP54"])
def test_time_events_at_t_end_fire_after_a_state_event_there(method):
    """The ramp reaches the saturation's corner at t_end = 0.5 exactly (a state event) and
    the Step and the hold's third sample are due at the same instant: the last row holds
    the step's new value 5 and the sample 0.5 (before, the SciPy methods ended with 0 and
    0.25)."""
    r = spidersim.loads(EVENT_AT_END).simulate(method=method)
    assert r.t[-1] == 0.5
    assert r["st.y"][-1] == 5.0
    assert r["z.y"][-1] == pytest.approx(0.5, abs=1e-12)
    kinds = sorted(n for t, b, n in r.events if b == "sat")
    assert kinds == ["upper"]


FIRST_STEP = """\
blocks:
  u:   {type: Sine, amplitude: 1, f: 1}
  z:   {type: ZeroOrderHold, Ts: 0.1}
  x:   {type: Integrator}
connections: [u.y -> z.u, z.y -> x.u]
simulation: {t_end: 1, first_step: 0.5, rtol: 1.0e-9, atol: 1.0e-12}
"""


@pytest.mark.parametrize("method", SCIPY + ["DP54"])
def test_a_first_step_longer_than_a_segment_is_cut_to_it(method):
    """first_step 0.5 with samples every 0.1 s: the integral of the held sine equals the sum
    of its samples times 0.1 (before, every SciPy method failed at t = 0 with SciPy's
    'first_step exceeds bounds')."""
    r = spidersim.loads(FIRST_STEP).simulate(method=method)
    exact = 0.1 * sum(np.sin(2 * np.pi * 0.1 * k) for k in range(10))
    assert r["x.y"][-1] == pytest.approx(exact, abs=1e-8)


@pytest.mark.parametrize("method, stepper", [("DP54", "RK45"), ("ROS34PW2", "Radau"),
                                             ("NDF", "BDF")])
def test_an_interpreted_compiled_method_says_which_stepper_ran(method, stepper):
    """Interpreted (jit off), DP54 / ROS34PW2 / NDF run SciPy's RK45 / Radau / BDF: the
    report says so under ``stepper`` (it showed the compiled method's name alone); a
    compiled run and a SciPy method have no such line."""
    d = spidersim.loads(FIRST_STEP)
    r = d.simulate(method=method, jit=False)
    assert r.stats["stepper"] == f"SciPy {stepper} (the interpreted form of {method})"
    assert f"stepper: SciPy {stepper}" in r.report()
    assert "stepper" not in d.simulate(method=method).stats
    assert "stepper" not in d.simulate(method="LSODA", jit=False).stats
