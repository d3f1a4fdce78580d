"""PI and PID controllers, open loop, against the formulas of controllers.py's docstring::

    v = kp e + I + D,  y = min(max(v, y_min), y_max)
    dI/dt = ki e (none) | ki e + kb (y - v) (backcalc) | 0 while v beyond a limit and e
    drives it further, ki e otherwise (clamping);  D = kd N (e - f), df/dt = N (e - f)
"""
import numpy as np
import pytest

import spidersim
from spidersim import ParameterError

from .harness import Probe, simulate

RTOL, ATOL = 1e-8, 1e-10


def _run(ctrl, error, t_end, **kw):
    """``error`` (a source block) -> ``ctrl`` (PI or PID named c); interpreted run."""
    return simulate(f"blocks:\n  e: {error}\n  c: {ctrl}\nconnections:\n  - e.y -> c.e\n",
                    t_end=t_end, rtol=RTOL, atol=ATOL, **kw)


@pytest.mark.parametrize("ctrl", ["PI", "PID"])
@pytest.mark.parametrize("aw", ["clamping", "backcalc", "none"])
def test_constant_error_gives_proportional_plus_ramp(ctrl, aw):
    """Unlimited: y = kp e0 + ki e0 t (+ the derivative term of a PID, zero for kd = 0)."""
    kp, ki, e0 = 1.5, 4.0, -0.75
    r = _run(f"{{type: {ctrl}, kp: {kp}, ki: {ki}, antiwindup: {aw}, kb: 1}}",
             f"{{type: Constant, value: {e0}}}", t_end=2.0)
    np.testing.assert_allclose(r["c.y"], kp * e0 + ki * e0 * r.t, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(r["c.I"], ki * e0 * r.t, rtol=1e-10, atol=1e-10)


def test_initial_integral_term_is_the_initial_command():
    p = Probe("PI", {"kp": 3.0, "ki": 1.0, "I0": 0.4})
    assert p.outputs()["y"][0] == 0.4
    p.set_input("e", 0.1)
    assert p.outputs()["y"][0] == pytest.approx(0.7)
    assert p.derivatives()["I"][0] == pytest.approx(0.1)


@pytest.mark.parametrize("ctrl", ["PI", "PID"])
def test_output_limits_hold(ctrl):
    p = Probe(ctrl, {"kp": 2.0, "ki": 1.0, "y_min": -0.5, "y_max": 1.5})
    for e, expect in ((10.0, 1.5), (-10.0, -0.5), (0.25, 0.5)):
        p.set_input("e", e)
        assert p.outputs()["y"][0] == expect


@pytest.mark.parametrize("sign", [1.0, -1.0])
@pytest.mark.parametrize("aw", ["clamping", "none"])
def test_clamping_stops_integration_while_saturated(aw, sign):
    """e = +-1 until t = 3, then -+1; kp = 1, ki = 2, limits +-2.

    clamping: I = 2 t until v = 1 + 2 t reaches the limit at t = 0.5, then I stays 1; at the
    reversal the output leaves the limit at once: y = -2 (t - 3) (for sign +1), until it
    reaches the other limit at t = 4 where I is clamped again at -1.
    none: I winds up to 6 and holds the output at the limit until t = 4.5.
    """
    r = _run("{type: PI, kp: 1, ki: 2, y_min: -2, y_max: 2, antiwindup: " + aw + "}",
             f"{{type: Step, t_step: 3, before: {sign}, after: {-sign}}}", t_end=5.0)
    t, y, I = r.t, r["c.y"] * sign, r["c.I"] * sign
    assert np.all(np.abs(y) <= 2.0)
    if aw == "clamping":
        early = t <= 0.5
        np.testing.assert_allclose(I[early], 2 * t[early], rtol=1e-9, atol=1e-9)
        held = (t > 0.5) & (t <= 3.0)
        assert np.max(np.abs(I[held] - 1.0)) < 1e-5      # "none" reaches 6 here
        late = (t > 3.0) & (r["e.y"] * sign < 0)
        np.testing.assert_allclose(I[late], np.maximum(-1.0, 1.0 - 2 * (t[late] - 3.0)),
                                   rtol=0, atol=1e-5)
        assert np.max(np.abs(I[t > 4.0] + 1.0)) < 1e-5
        np.testing.assert_allclose(y[late], np.maximum(-2.0, -2 * (t[late] - 3.0)),
                                   rtol=0, atol=1e-5)
    else:
        wound = t <= 3.0
        np.testing.assert_allclose(I[wound], 2 * t[wound], rtol=1e-9, atol=1e-9)
        late = (t > 3.0) & (r["e.y"] * sign < 0)
        v = -1.0 + 6.0 - 2 * (t[late] - 3.0)
        np.testing.assert_allclose(y[late], np.clip(v, -2.0, 2.0), rtol=0, atol=1e-6)
        assert np.all(y[(t > 3.0) & (t < 4.4)] == 2.0)


@pytest.mark.parametrize("ctrl", ["PI", "PID"])
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_backcalc_converges_with_rate_kb(ctrl, sign):
    """Saturated throughout: dI/dt = ki e0 + kb (y_lim - kp e0 - I), so
    I = I* + (I0 - I*) exp(-kb t) with I* = y_lim - kp e0 + ki e0 / kb."""
    kp, ki, kb, e0, I0, lim = 1.0, 2.0, 4.0, sign, 5.0 * sign, 2.0
    r = _run(f"{{type: {ctrl}, kp: {kp}, ki: {ki}, kb: {kb}, y_min: {-lim}, y_max: {lim}, "
             f"antiwindup: backcalc, I0: {I0}}}", f"{{type: Constant, value: {e0}}}",
             t_end=3.0)
    istar = sign * lim - kp * e0 + ki * e0 / kb
    exact = istar + (I0 - istar) * np.exp(-kb * r.t)
    err = np.abs(r["c.I"] - exact) / (ATOL + RTOL * np.abs(exact))
    assert err.max() < 20
    assert np.all(r["c.y"] == sign * lim)
    assert r["c.I"][-1] == pytest.approx(istar, rel=1e-4)


def test_pid_derivative_filter_step_response():
    """Error step e0 at ts: y = kp e0 + ki e0 (t - ts) + kd N e0 exp(-N (t - ts))."""
    kp, ki, kd, N, e0, ts = 0.5, 2.0, 0.05, 40.0, 1.5, 0.1
    r = _run(f"{{type: PID, kp: {kp}, ki: {ki}, kd: {kd}, N: {N}}}",
             f"{{type: Step, t_step: {ts}, after: {e0}}}", t_end=0.5)
    t, y = r.t, r["c.y"]
    on = r["e.y"] > 0
    tau = t[on] - ts
    exact = kp * e0 + ki * e0 * tau + kd * N * e0 * np.exp(-N * tau)
    err = np.abs(y[on] - exact) / (ATOL + RTOL * np.abs(exact))
    assert err.max() < 20
    assert y[on][0] == pytest.approx(kp * e0 + kd * N * e0)      # the kick at the step
    assert np.all(y[~on] == 0.0)
    np.testing.assert_allclose(r["c.f"][on], e0 * (1 - np.exp(-N * tau)), rtol=0, atol=1e-7)


def test_pid_probe_formula():
    p = Probe("PID", {"kp": 2.0, "ki": 3.0, "kd": 0.5, "N": 10.0})
    x = p.x0()
    p.set_state(x, "I", 0.25)
    p.set_state(x, "f", -0.5)
    p.set_input("e", 1.0)
    assert p.outputs(0.0, x)["y"][0] == pytest.approx(2.0 + 0.25 + 0.5 * 10.0 * 1.5)
    der = p.derivatives(0.0, x)
    assert der["I"][0] == pytest.approx(3.0)
    assert der["f"][0] == pytest.approx(10.0 * 1.5)


@pytest.mark.parametrize("extra,match", [("antiwindup: backcalc", "kb > 0"),
                                         ("y_min: 1, y_max: 1", "below y_max"),
                                         ("antiwindup: clamp", "must be one of")])
def test_controller_parameter_checks(extra, match):
    with pytest.raises(ParameterError, match=match):
        spidersim.loads(f"blocks:\n  c: {{type: PI, {extra}}}\n  z: {{type: Constant}}\n"
                        f"connections:\n  - z.y -> c.e\n")


class _TooManySteps(Exception):
    pass


LOOP = """
blocks:
  ref:  {{type: Step, t_step: 0.05, after: 1.0}}
  err:  {{type: Sum, signs: "+-"}}
  c:    {{type: {ctrl}, kp: 2, ki: 2, y_min: -1.3, y_max: 1.3, antiwindup: {aw}}}
  plant: {{type: TransferFunction, num: [1], den: [1, 2, 1]}}
connections:
  - ref.y -> err.u1
  - plant.y -> err.u2
  - err.y -> c.e
  - c.y -> plant.u
"""


def _loop(ctrl, aw, max_steps=20000):
    n, last = [0], [0.0]

    def budget(t):
        n[0] += 1
        last[0] = t
        if n[0] > max_steps:
            raise _TooManySteps(f"{ctrl} ({aw}) in a loop: {max_steps} steps only reach "
                                f"t = {last[0]:.9g} s")

    return spidersim.loads(LOOP.format(ctrl=ctrl, aw=aw)).simulate(
        t_end=10.0, rtol=1e-6, atol=1e-8, jit=False, progress=budget)


@pytest.mark.parametrize("ctrl", ["PI", "PID"])
def test_loop_without_antiwindup_winds_up(ctrl):
    """Reference for the test below: plant 1/(s+1)^2, kp = ki = 2, command limited to 1.3;
    without anti-windup the loop overshoots to about 1.27."""
    r = _loop(ctrl, "none")
    assert np.all(np.abs(r["c.y"]) <= 1.3)
    assert r["plant.y"].max() > 1.2
    assert r["plant.y"][-1] == pytest.approx(1.0, abs=1e-2)


@pytest.mark.parametrize("ctrl", ["PI", "PID"])
def test_clamping_in_a_closed_loop_does_not_stall(ctrl):
    """The same loop with clamping: the command sits at y_max while the error decreases, and
    the free rate ki e would push v back above the limit at once (Filippov sliding on
    v = y_max, where I = y_max - kp e). Regression: when dI/dt switched between 0 and ki e
    at v = y_max inside ``derivative`` (a discontinuity of the right-hand side without an
    event), the integrator crawled with steps of ~1e-12 s from t = 1.06 s (LSODA and RK45
    never finished; Radau failed with "Required step size is less than spacing between
    numbers").

    The run must finish in a sensible number of steps, hold the limit, overshoot less than
    without anti-windup, and (integral action) drive the error to zero.
    """
    try:
        r = _loop(ctrl, "clamping")
    except _TooManySteps as exc:
        pytest.fail(f"clamping anti-windup stalls: {exc}")
    assert np.all(np.abs(r["c.y"]) <= 1.3)
    assert np.any(r["c.y"] == 1.3)                      # it did saturate
    assert r["plant.y"].max() < 1.15
    assert r["plant.y"][-1] == pytest.approx(1.0, abs=1e-2)


ALL_METHODS = ["DP54", "ROS34PW2", "NDF", "RK45", "RK23", "DOP853", "LSODA", "BDF", "Radau"]
CLAMPED_LOOP = """\
blocks:
  r:  {type: Constant, value: 1}
  e:  {type: Sum, signs: "+-"}
  c:  {type: %s, kp: 0.2, ki: 10, y_max: 0.5, y_min: -0.5}
  pl: {type: Integrator}
connections: [r.y -> e.u1, pl.y -> e.u2, e.y -> c.e, c.y -> pl.u]
"""


def _clamped_loop_reference(t_end=5.0, kp=0.2, ki=10.0, y_max=0.5):
    """The loop of CLAMPED_LOOP by the clamping model of controllers.py: linear until
    v = kp e + I reaches y_max at t1 (solve_ivp, an event); then the output held at y_max
    while the error falls (the integral sliding, I = y_max - kp e) until e = 0 at
    t2 = t1 + (1 - pl(t1)) / y_max, where the release sets I = y_max; then linear again
    (pl' = kp (1 - pl) + I, I' = ki (1 - pl)). Returns pl(t_end)."""
    from scipy.integrate import solve_ivp

    def f(t, z):
        pl, i = z
        return [kp * (1 - pl) + i, ki * (1 - pl)]

    def hit(t, z):
        return kp * (1 - z[0]) + z[1] - y_max
    hit.terminal, hit.direction = True, 1
    a = solve_ivp(f, (0, t_end), [0.0, 0.0], events=hit, rtol=1e-12, atol=1e-14)
    t1, pl1 = a.t_events[0][0], a.y_events[0][0][0]
    t2 = t1 + (1 - pl1) / y_max
    b = solve_ivp(f, (t2, t_end), [1.0, y_max], rtol=1e-12, atol=1e-14)
    return b.y[0, -1]


@pytest.mark.parametrize("ctrl", ["PI", "PID"])
@pytest.mark.parametrize("method", ALL_METHODS)
def test_clamped_output_leaving_its_limit_at_once_is_seen(method, ctrl):
    """A PI/PID clamped at y_max whose v = kp e + I falls back below it at once (the plant
    integrates the limited output, so the error falls as soon as the clamp is on): its
    "leave" guard starts the clamped mode exactly on zero and goes straight to its firing
    side; it fires there, the controller slides on the limit until the error reverses and
    the run follows the reference above (solve_ivp, 1e-12). Before, a guard of the block
    that had just fired had to leave zero first: the leave never fired when the guard was
    exactly 0.0 (DP54, RK45, LSODA, DOP853), pl(5) = 1.0744 instead of 0.9966, exit 0."""
    r = spidersim.loads(CLAMPED_LOOP % ctrl).simulate(t_end=5.0, method=method, rtol=RTOL,
                                                      atol=ATOL)
    assert r["pl.y"][-1] == pytest.approx(_clamped_loop_reference(), abs=1e-6)
    names = [n for _t, b, n in r.events if b == "c"]
    assert names[:3] == ["clamp_upper", "leave", "clamp_upper"] and "release" in names


@pytest.mark.parametrize("ctrl", ["PI", "PID"])
@pytest.mark.parametrize("method", ALL_METHODS)
def test_clamped_sine_error_closed_form(method, ctrl):
    """e = sin(pi t) into kp = 1, ki = 2, limits (-0.7, 1.5): clamped at 1.5 over each
    positive half period (leave and clamp again at the same instant past the peak, the
    integral sliding), released at t = 1, 2, 3 with I = y_max - kp e = 1.5; from t = 3,
    I = 1.5 - (2 / pi)(1 + cos(3.3 pi)) at t = 3.3 and y = sin(3.3 pi) + I (0.4285589).
    DP54, NDF and ROS34PW2 ended at -0.498, -0.117 and -0.554 before (a re-clamp missed)."""
    text = ("blocks:\n  r: {type: Sine, amplitude: 1, f: 0.5}\n"
            f"  c: {{type: {ctrl}, kp: 1, ki: 2, y_max: 1.5, y_min: -0.7}}\n"
            "connections: [r.y -> c.e]\n")
    r = spidersim.loads(text).simulate(t_end=3.3, method=method, rtol=RTOL, atol=ATOL)
    i_end = 1.5 - (2 / np.pi) * (1 + np.cos(3.3 * np.pi))
    assert r["c.y"][-1] == pytest.approx(np.sin(3.3 * np.pi) + i_end, abs=1e-6)
    assert r["c.I"][-1] == pytest.approx(i_end, abs=1e-6)


@pytest.mark.parametrize("method", ["DP54", "LSODA", "RK45", "NDF"])
def test_pid_with_derivative_term_starts_below_its_limit(method):
    """e = 1 into PID kp 0.5, ki 1, kd 0.005, N 100, y_max 1.2 (clamping): the filtered
    derivative term is D = kd N exp(-N t) = 0.5 exp(-100 t), so v = 0.5 + t + D starts at
    1.0, below the limit: I = t until v reaches 1.2 at t = 0.7, then y = 1.2 with I held
    at 0.7. Before, the start compared kp e + I + 2 D (the term counted twice, against
    limits already shifted by D) with 1.2, clamped at t = 0 and never released: I = 0,
    y(1) = 0.5, exit 0."""
    r = simulate("blocks:\n  e: {type: Constant, value: 1}\n"
                 "  c: {type: PID, kp: 0.5, ki: 1, kd: 0.005, N: 100, y_max: 1.2}\n"
                 "connections:\n  - e.y -> c.e\n", t_end=1.0, rtol=RTOL, atol=ATOL,
                 method=method)
    early = r.t < 0.69
    np.testing.assert_allclose(r["c.I"][early], r.t[early], atol=1e-6)
    assert r["c.I"][-1] == pytest.approx(0.7, abs=1e-6)
    assert r["c.y"][-1] == pytest.approx(1.2, abs=1e-9)
