"""Integrator, TransferFunction and StateSpace against closed-form solutions.

Errors are normalised by the tolerance asked for: ``|y - y_exact| / (atol + rtol |y_exact|)``
must stay below ``FACTOR`` (the solvers' global error is a few times their local tolerance).
"""
import numpy as np
import pytest
from scipy.linalg import expm

import spidersim
from spidersim import ParameterError

from .harness import Probe, simulate

RTOL, ATOL = 1e-8, 1e-10
FACTOR = 10.0


def norm_err(y, exact, rtol=RTOL, atol=ATOL, peak=False):
    """Largest error in units of the tolerance, relative to ``|exact|`` at each sample or, with
    ``peak``, to the peak of each component (for oscillating components crossing zero)."""
    exact = np.asarray(exact)
    scale = np.max(np.abs(exact), axis=0) if peak else np.abs(exact)
    return float(np.max(np.abs(y - exact) / (atol + rtol * scale)))


def _tf_step(num, den, t_step=0.2, t_end=5.0, **kw):
    kw.setdefault("rtol", RTOL)
    kw.setdefault("atol", ATOL)
    d = spidersim.loads(f"blocks:\n  s: {{type: Step, t_step: {t_step}}}\n"
                        f"  tf: {{type: TransferFunction, num: {num}, den: {den}}}\n"
                        f"connections:\n  - s.y -> tf.u\n")
    return d, d.simulate(t_end=t_end, jit=False, **kw)


def _after_step(r, t_step):
    """Mask of the samples recorded after the step was applied (the sample at t_step that
    closes the first segment still has u = 0)."""
    mask = r.t >= t_step
    mask[np.flatnonzero(r.t == t_step)[0]] = r["s.y"][np.flatnonzero(r.t == t_step)[0]] > 0.5
    return mask


def test_integrator_of_a_constant_is_an_exact_ramp():
    x0, u = [1.0, -2.0, 0.5], [0.5, 3.0, -1.25]
    r = simulate(f"blocks:\n  c: {{type: Constant, value: {u}}}\n"
                 f"  i: {{type: Integrator, x0: {x0}}}\nconnections:\n  - c.y -> i.u\n",
                 t_end=3.0, rtol=RTOL, atol=ATOL)
    y = r["i.y"]
    assert y.shape == (len(r.t), 3)
    np.testing.assert_allclose(y[0], x0, rtol=0, atol=0)
    exact = np.asarray(x0) + np.outer(r.t, u)
    np.testing.assert_allclose(y, exact, rtol=1e-12, atol=1e-12)
    assert r.t[-1] == 3.0


def test_integrator_scalar_x0_broadcasts():
    p = Probe("Integrator", {"x0": 4.0}, sizes={"u": 3})
    np.testing.assert_array_equal(p.outputs()["y"], [4.0, 4.0, 4.0])
    p.set_input("u", [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(p.derivatives()["y"], [1.0, 2.0, 3.0])


def test_integrator_rejects_x0_size_mismatch():
    with pytest.raises(ParameterError, match="x0"):
        spidersim.loads("blocks:\n  c: {type: Constant, value: [1, 2, 3]}\n"
                        "  i: {type: Integrator, x0: [1, 2]}\nconnections:\n  - c.y -> i.u\n")


@pytest.mark.parametrize("method", ["LSODA", "RK45", "Radau", "BDF"])
def test_first_order_lag_step_response(method):
    t_step = 0.2
    _, r = _tf_step([1.0], [1.0, 1.0], t_step=t_step, method=method)
    t = r.t
    exact = np.where(t < t_step, 0.0, 1.0 - np.exp(-(t - t_step)))
    assert norm_err(r["tf.y"], exact) < 2 * FACTOR
    assert r["tf.y"][-1] == pytest.approx(1.0 - np.exp(-4.8), rel=1e-6)


@pytest.mark.parametrize("scale", [1.0, 2.5])
def test_second_order_step_response(scale):
    """1/(s^2 + 2 zeta wn s + wn^2) (coefficients scaled: the realisation normalises den)."""
    wn, zeta, t_step = 4.0, 0.3, 0.2
    num = [scale]
    den = [scale, scale * 2 * zeta * wn, scale * wn ** 2]
    _, r = _tf_step(num, den, t_step=t_step)
    tau = r.t - t_step
    wd = wn * np.sqrt(1 - zeta ** 2)
    exact = np.where(tau < 0, 0.0, (1.0 - np.exp(-zeta * wn * tau) / np.sqrt(1 - zeta ** 2)
                                    * np.sin(wd * tau + np.arccos(zeta))) / wn ** 2)
    assert norm_err(r["tf.y"], exact) < FACTOR
    # the overshoot of the second-order step response
    peak = (1 + np.exp(-np.pi * zeta / np.sqrt(1 - zeta ** 2))) / wn ** 2
    assert r["tf.y"].max() == pytest.approx(peak, rel=1e-3)


def test_biproper_transfer_function_has_feedthrough():
    """(s + 2)/(s + 1): y jumps to 1 with the step (direct feedthrough), then 2 - exp(-t)."""
    t_step = 0.2
    _, r = _tf_step([1.0, 2.0], [1.0, 1.0], t_step=t_step)
    after = _after_step(r, t_step)
    exact = np.where(after, 2.0 - np.exp(-(r.t - t_step)), 0.0)
    assert norm_err(r["tf.y"], exact) < FACTOR
    k = int(np.flatnonzero(r.t == t_step)[-1])
    assert r["tf.y"][k] == pytest.approx(1.0, abs=1e-12)    # same instant as the step
    assert r["tf.y"][k - 1] == 0.0
    p = Probe("TransferFunction", {"num": [1.0, 2.0], "den": [1.0, 1.0]})
    assert p.layout.feedthrough["y"] == ("u",)
    p.set_input("u", 3.0)
    assert p.outputs()["y"][0] == pytest.approx(3.0)      # D = 1, zero state
    x = p.set_state(p.x0(), "x", 0.5)
    assert p.outputs(0.0, x)["y"][0] == pytest.approx(3.0 + 0.5)   # C = 2 - 1 = 1


def test_strictly_proper_transfer_function_has_no_feedthrough():
    p = Probe("TransferFunction", {"num": [1.0], "den": [1.0, 3.0, 2.0]})
    assert p.layout.feedthrough["y"] == ()
    p.set_input("u", 5.0)
    assert p.outputs()["y"][0] == 0.0


def test_transfer_function_set_rederives_the_realisation():
    """d.set on den re-derives A, B, C, D: 1/(s + 2) without recompiling."""
    d, _ = _tf_step([1.0], [1.0, 1.0], t_step=0.0, t_end=1.0)
    d.set("tf.den", [1.0, 2.0])
    r = d.simulate(t_end=3.0, rtol=RTOL, atol=ATOL, jit=False)
    assert norm_err(r["tf.y"], (1 - np.exp(-2 * r.t)) / 2) < FACTOR


@pytest.mark.parametrize("num,den,match", [([1.0, 2.0, 3.0], [1.0, 1.0], "improper"),
                                           ([1.0], [0.0, 1.0], "leading coefficient")])
def test_transfer_function_rejects(num, den, match):
    with pytest.raises(ParameterError, match=match):
        spidersim.loads(f"blocks:\n  tf: {{type: TransferFunction, num: {num}, den: {den}}}\n"
                        f"  c: {{type: Constant}}\nconnections:\n  - c.y -> tf.u\n")


A = np.array([[-0.5, 2.0], [-3.0, -1.0]])
B = np.array([[1.0, 0.0], [0.5, -1.0]])
C = np.array([[1.0, -1.0], [0.0, 2.0], [1.0, 1.0]])
D = np.array([[0.0, 0.5], [0.0, 0.0], [1.0, 0.0]])


def _ss_exact(t, x0, u):
    """x(t) = e^{At} x0 + A^{-1} (e^{At} - I) B u for constant u."""
    Ainv_Bu = np.linalg.solve(A, B @ u)
    xs = np.array([expm(A * tk) @ x0 + (expm(A * tk) - np.eye(2)) @ Ainv_Bu for tk in t])
    return xs, xs @ C.T + D @ u


def test_state_space_matches_matrix_exponential():
    x0, u = np.array([1.0, -0.5]), np.array([0.7, -1.3])
    text = (f"blocks:\n  c: {{type: Constant, value: {u.tolist()}}}\n"
            f"  ss: {{type: StateSpace, A: {A.tolist()}, B: {B.tolist()}, C: {C.tolist()}, "
            f"D: {D.tolist()}, x0: {x0.tolist()}}}\nconnections:\n  - c.y -> ss.u\n")
    r = simulate(text, t_end=4.0, rtol=RTOL, atol=ATOL)
    xs, ys = _ss_exact(r.t, x0, u)
    assert r["ss.y"].shape == (len(r.t), 3)
    assert norm_err(r["ss.x"], xs, peak=True) < FACTOR
    assert norm_err(r["ss.y"], ys, peak=True) < FACTOR
    p = Probe("StateSpace", {"A": A, "B": B, "C": C, "D": D}, sizes={"u": 2})
    assert p.layout.feedthrough["y"] == ("u",)


def test_state_space_without_d_has_no_feedthrough():
    p = Probe("StateSpace", {"A": A, "B": B, "C": C, "x0": [1.0, 2.0]}, sizes={"u": 2})
    assert p.layout.feedthrough["y"] == ()
    p.set_input("u", [3.0, 4.0])
    np.testing.assert_allclose(p.outputs()["y"], C @ [1.0, 2.0], rtol=1e-15)
    np.testing.assert_allclose(p.derivatives()["x"], A @ [1.0, 2.0] + B @ [3.0, 4.0],
                               rtol=1e-15)


@pytest.mark.parametrize("field,value,match", [
    ("A", [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], "square"),
    ("B", [[1.0], [0.0], [0.0]], "B must have 2 rows"),
    ("C", [[1.0, 0.0, 0.0]], "C must have 2 columns"),
    ("D", [[1.0, 0.0]], "D must have shape"),
    ("x0", [1.0, 2.0, 3.0], "x0"),
])
def test_state_space_rejects_inconsistent_shapes(field, value, match):
    prm = {"A": [[0.0, 1.0], [-1.0, 0.0]], "B": [[0.0], [1.0]], "C": [[1.0, 0.0]]}
    prm[field] = value
    body = ", ".join(f"{k}: {v}" for k, v in prm.items())
    with pytest.raises(ParameterError, match=match):
        spidersim.loads(f"blocks:\n  ss: {{type: StateSpace, {body}}}\n"
                        f"  c: {{type: Constant}}\nconnections:\n  - c.y -> ss.u\n")


@pytest.mark.parametrize("A, x0, words", [
    ([[-1.0]], [1, 2, 3], "x0 must have 1 element (A is 1 x 1: one state), got 3"),
    ([[0.0, 1.0], [-1.0, 0.0]], [1, 2, 3],
     "x0 must have 1 element (the same for every state) or 2 (one per state: A is 2 x 2), "
     "got 3"),
])
def test_state_space_x0_count_in_words(A, x0, words):
    """One state: 'x0 must have 1 or 1 elements' (a hostile review, session 15) is said as
    one element; more states name both choices."""
    B, C = [[1.0]] * len(A), [[1.0] * len(A)]
    with pytest.raises(ParameterError) as ei:
        spidersim.loads(f"blocks:\n  ss: {{type: StateSpace, A: {A}, B: {B}, C: {C}, "
                        f"x0: {x0}}}\n  c: {{type: Constant}}\nconnections:\n  - c.y -> ss.u\n")
    assert words in str(ei.value) and "1 or 1" not in str(ei.value)


@pytest.mark.parametrize("lower, upper", [(1.0, -1.0), (0.5, 0.5)])
def test_limited_integrator_refuses_limits_out_of_order(lower, upper):
    """``lower`` must be below ``upper``; said so, not as an ``x0`` outside [1, -1]."""
    with pytest.raises(ParameterError, match=rf"lower \({lower}\) must be below upper"):
        spidersim.loads(f"blocks:\n  li: {{type: LimitedIntegrator, x0: 0.5, lower: {lower}, "
                        f"upper: {upper}}}\n  c: {{type: Constant}}\n"
                        f"connections:\n  - c.y -> li.u\n")


def _limited(src, t_end=4.0, max_step=None, **prm):
    body = ", ".join(f"{k}: {v}" for k, v in dict(dict(x0=0.0, lower=-1.0, upper=0.5),
                                                   **prm).items())
    return simulate(f"blocks:\n  u: {src}\n  li: {{type: LimitedIntegrator, {body}}}\n"
                    "connections:\n  - u.y -> li.u\n", t_end=t_end, rtol=RTOL, atol=ATOL,
                    max_step=max_step)


@pytest.mark.parametrize("max_step", [0.05, None], ids=["max_step", "default_step"])
def test_limited_integrator_holds_and_leaves_on_a_sine(max_step):
    """u = cos(pi t / 2) (Sine with phase pi/2, f = 1/4): y = 2/pi sin(pi t / 2) until it
    reaches 0.5 at t1 = 2/pi asin(pi/4); held there until u turns negative at t = 1 (exact
    'leave' event), then y = 0.5 + 2/pi (sin(pi t/2) - 1) down to the lower limit -0.5.

    With an unbounded max_step this would fail: while held, the only state has a zero
    derivative, so the solver would step from t = 0.576 straight to t_end = 4; the leave
    guard u*m is positive at both ends of that step (u < 0 on (1, 3) in between) and guards
    are compared at step ends. The default max_step, (t_end - t0)/50 as in Simulink, keeps
    steps short enough.
    """
    r = _limited("{type: Sine, f: 0.25, phase: 1.5707963267948966}", t_end=4.0, lower=-0.5,
                 max_step=max_step)
    t1 = 2 / np.pi * np.arcsin(np.pi / 4)
    ev = [(e[0], e[2]) for e in r.events if e[1] == "li"]
    assert [n for _, n in ev][:2] == ["upper", "leave"]
    assert ev[0][0] == pytest.approx(t1, abs=1e-8)
    assert ev[1][0] == pytest.approx(1.0, abs=1e-8)
    t, y = r.t, r["li.y"]
    assert np.all(y <= 0.5 + 1e-9) and np.all(y >= -0.5 - 1e-9)
    rising = t < t1
    np.testing.assert_allclose(y[rising], 2 / np.pi * np.sin(np.pi * t[rising] / 2),
                               rtol=0, atol=1e-7)
    assert np.all(np.abs(y[(t > t1) & (t < 1.0)] - 0.5) <= 1e-12)
    # falls as 0.5 + 2/pi (sin(pi t / 2) - 1): reaches -0.5 where sin(pi t / 2) = 1 - pi/2
    t2 = 2.0 + 2 / np.pi * np.arcsin(np.pi / 2 - 1.0)
    falling = (t > 1.0) & (t < t2)
    np.testing.assert_allclose(y[falling],
                               0.5 + 2 / np.pi * (np.sin(np.pi * t[falling] / 2) - 1.0),
                               rtol=0, atol=1e-7)
    assert len(ev) == 4 and ev[2] == (pytest.approx(t2, abs=1e-6), "lower")
    assert ev[3] == (pytest.approx(3.0, abs=1e-8), "leave")      # u = cos turns positive
    assert np.all(np.abs(y[(t > t2) & (t < 3.0)] + 0.5) <= 1e-12)
    rising = t > 3.0        # leaves the lower limit: -0.5 + 2/pi (sin(pi t / 2) + 1)
    np.testing.assert_allclose(y[rising],
                               -0.5 + 2 / np.pi * (np.sin(np.pi * t[rising] / 2) + 1.0),
                               rtol=0, atol=1e-7)


def test_limited_integrator_leaves_when_the_input_steps_back():
    """u = +1 then -1 from t = 1 (a Step: a time event). Held at 0.5 from t = 0.5, it must
    leave at t = 1 and reach -1 at t = 2.5. The leave guard u*m jumps from +1 to -1 at the
    time event, so no step sees it cross zero: the solver compares the guards just before
    and just after the event and fires 'leave' at t = 1."""
    r = _limited("{type: Step, t_step: 1, before: 1, after: -1}")
    t, y = r.t, r["li.y"]
    np.testing.assert_allclose(y[t <= 0.5], t[t <= 0.5], atol=1e-9)
    assert np.all(y[(t > 0.5) & (t <= 1.0)] == 0.5)
    assert y[-1] == -1.0, f"y(4) = {y[-1]}: the held integrator never left the limit"
    falling = (t > 1.0) & (t < 2.5)
    np.testing.assert_allclose(y[falling], 0.5 - (t[falling] - 1.0), atol=1e-9)
    names = [e[2] for e in r.events if e[1] == "li"]
    assert names[0] == "upper" and names[-1] == "lower"
    assert [e[0] for e in r.events if e[2] == "lower"] == pytest.approx([2.5], abs=1e-9)


def test_limited_integrator_starting_at_a_limit():
    """x0 = upper with u > 0: initialize holds it from the start."""
    r = _limited("{type: Constant, value: 2}", x0=0.5, t_end=1.0)
    assert np.all(r["li.y"] == 0.5)
    p = Probe("LimitedIntegrator", {"x0": 0.5, "upper": 0.5})
    p.set_input("u", 2.0)
    p.initialize()
    assert p.mode("m")[0] == 1.0
    assert p.derivatives()["y"][0] == 0.0


def test_limited_integrator_rejects_x0_outside():
    with pytest.raises(ParameterError, match="x0"):
        spidersim.loads("blocks:\n  li: {type: LimitedIntegrator, x0: 2}\n"
                        "  c: {type: Constant}\nconnections:\n  - c.y -> li.u\n")


def test_transfer_function_numerator_leading_zeros_do_not_count():
    """``num: [0, 0, 1]`` over ``[1, 1]`` is 1/(s+1) (it was refused as improper), and
    ``num: [0, 1]`` is strictly proper: unity feedback around it is no algebraic loop (it
    was taken as biproper, a false loop solved by Newton in 93 iterations); a hostile
    review, session 12. Closed forms: 1 - exp(-t), and 0.5 (1 - exp(-2 t)) closed-loop."""
    import math
    import spidersim
    r = spidersim.loads("""
blocks:
  r: {type: Step}
  g: {type: TransferFunction, num: [0, 0, 1], den: [1, 1]}
connections:
  - r.y -> g.u
simulation: {t_end: 1, rtol: 1e-10, atol: 1e-12}
log: [g.y]
""").simulate(jit=False)
    assert r["g.y"][-1] == pytest.approx(1 - math.exp(-1), rel=1e-8)
    d = spidersim.loads("""
blocks:
  r: {type: Step}
  e: {type: Sum, signs: "+-"}
  g: {type: TransferFunction, num: [0, 1], den: [1, 1]}
connections:
  - r.y -> e.u1
  - g.y -> e.u2
  - e.y -> g.u
simulation: {t_end: 1, rtol: 1e-10, atol: 1e-12}
log: [g.y]
""")
    assert not d.layout.loops
    r = d.simulate(jit=False)
    assert r.stats["newton_iterations"] == 0
    assert r["g.y"][-1] == pytest.approx(0.5 * (1 - math.exp(-2)), rel=1e-8)
