"""Linearization, loop transfers, operating points and trim against hand-derived models.

Every reference here is derived independently of spidersim: transfer functions written by
hand (or assembled with python-control from hand-written pieces), the analytic Jacobian of
a pendulum, ``scipy.integrate.solve_ivp`` for a simulated state, python-control's
``bandwidth``/``margin`` for the figures of merit.
"""
import math
import os

import control
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import spidersim
from spidersim.diagram.analysis import AnalysisError
from spidersim.solver.linearize import bandwidth, siso_figures

S = control.tf("s")
FREQS = np.logspace(-1, 5, 20)                   # rad/s
HALF_POWER_DB = 20 * math.log10(1 / math.sqrt(2))   # spidersim's "-3 dB" is |G(0)|/sqrt(2)


# ----------------------------------------------------------------------------- helpers
def _coeffs(tf):
    num = np.atleast_1d(np.squeeze(tf.num[0][0])).astype(float)
    den = np.atleast_1d(np.squeeze(tf.den[0][0])).astype(float)
    return num, den


def _normalised_minimal(sys):
    """(num, den) of a SISO system: minimal, monic denominator, no round-off leading zeros."""
    tf = control.ss2tf(sys) if isinstance(sys, control.StateSpace) else sys
    num, den = _coeffs(tf)
    big = np.max(np.abs(num))
    while len(num) > 1 and abs(num[0]) <= 1e-10 * big:
        num = num[1:]
    num, den = _coeffs(control.tf(num, den).minreal(tol=1e-6))
    return num / den[0], den / den[0]


def _assert_same_tf(sys, ref):
    num, den = _normalised_minimal(sys)
    num_ref, den_ref = _normalised_minimal(ref)
    assert len(den) == len(den_ref), (den, den_ref)
    assert len(num) == len(num_ref), (num, num_ref)
    np.testing.assert_allclose(den, den_ref, rtol=1e-6, atol=0)
    np.testing.assert_allclose(num, num_ref, rtol=1e-6, atol=0)


def _freq(sys, w):
    return np.atleast_1d(np.squeeze(sys(1j * np.asarray(w))))


def _assert_same_response(sys, ref, w=FREQS):
    g, g_ref = _freq(sys, w), _freq(ref, w)
    rel = np.abs(g - g_ref) / np.abs(g_ref)
    assert np.max(rel) < 1e-6, (w[np.argmax(rel)], np.max(rel))


def _state(sys, name):
    return sys.state_labels.index(name)


# ----------------------------------------------------------------------------- round trip
SERIES = """
name: series
blocks:
  r:   {type: Constant, value: 1.0}
  g1:  {type: TransferFunction, num: [2, 3], den: [1, 2, 5]}
  g2:  {type: StateSpace, A: [[0, 1], [-6, -5]], B: [[0], [1]], C: [[4, 1]], D: [[0.5]]}
  g3:  {type: TransferFunction, num: [1.5, 8], den: [0.5, 10]}
connections:
  - r.y -> g1.u
  - g1.y -> g2.u
  - g2.y -> g3.u
"""

FEEDBACK = """
name: feedback
blocks:
  r:   {type: Constant, value: 1.0}
  e:   {type: Sum, signs: "+-"}
  g1:  {type: TransferFunction, num: [2, 3], den: [1, 2, 5]}
  g2:  {type: StateSpace, A: [[0, 1], [-6, -5]], B: [[0], [1]], C: [[4, 1]]}
  h:   {type: TransferFunction, num: [1.5, 8], den: [0.5, 10]}
connections:
  - r.y -> e.u1
  - h.y -> e.u2
  - e.y -> g1.u
  - g1.y -> g2.u
  - g2.y -> h.u
"""


def _round_trip_reference(kind):
    g1 = (2 * S + 3) / (S ** 2 + 2 * S + 5)
    # C (sI - A)^-1 B of the companion pair above is (s + 4) / (s^2 + 5 s + 6)
    g2 = (S + 4) / (S ** 2 + 5 * S + 6)
    h = (1.5 * S + 8) / (0.5 * S + 10)
    if kind == "series":
        return g1 * (g2 + 0.5) * h, SERIES, "g3.y"
    return control.feedback(g1 * g2, h), FEEDBACK, "g2.y"


@pytest.mark.parametrize("kind", ["series", "feedback"])
def test_round_trip_transfer_function_and_state_space_blocks(kind):
    ref, text, out = _round_trip_reference(kind)
    sys = spidersim.loads(text).linearize(["r.y"], [out], jit=False)
    assert sys.input_labels == ["r/y"] and sys.output_labels == [out.replace(".", "/")]
    assert sys.nstates == 5
    _assert_same_tf(sys, ref)


def test_round_trip_opening_removes_the_feedback_path():
    # opened at the error signal, the feedback path h no longer reaches g1: G1 G2 remains
    # (the h state stays in the model, uncontrollable, and cancels)
    sys = spidersim.loads(FEEDBACK).linearize(["e.y"], ["g2.y"], open=["e.y"], jit=False)
    g1 = (2 * S + 3) / (S ** 2 + 2 * S + 5)
    g2 = (S + 4) / (S ** 2 + 5 * S + 6)
    _assert_same_tf(sys, g1 * g2)


# ----------------------------------------------------------------------------- DC motor + PI
MOTOR = dict(R=1.0, L=1e-3, K_t=0.05, J=1e-4, b=1e-5)
KP, KI = 0.3, 30.0

MOTOR_PI = f"""
name: motor_pi
blocks:
  ref:   {{type: Constant, value: 0.0}}
  err:   {{type: Sum, signs: "+-"}}
  pi:    {{type: PI, kp: {KP}, ki: {KI}, antiwindup: none}}
  motor: {{type: DCMotor, R: {MOTOR['R']}, L: {MOTOR['L']}, K_t: {MOTOR['K_t']}, J: {MOTOR['J']},
          b: {MOTOR['b']}}}
connections:
  - ref.y -> err.u1
  - motor.w -> err.u2
  - err.y -> pi.e
  - pi.y -> motor.v
"""


def _motor_hand():
    """Speed loop by hand: (L s + R) I = V - K W, (J s + b) W = K I  =>  W/V = P(s)."""
    R, L, K, J, b = (MOTOR[k] for k in ("R", "L", "K_t", "J", "b"))
    plant = K / ((L * S + R) * (J * S + b) + K ** 2)
    pi = KP + KI / S
    loop = pi * plant                       # the PI output, around the loop, back to itself
    closed = control.feedback(loop, 1)      # reference -> speed: L / (1 + L)
    return closed, loop


def test_dc_motor_pi_closed_loop_and_loop_transfer_match_hand_derivation():
    d = spidersim.loads(MOTOR_PI)
    closed_ref, loop_ref = _motor_hand()
    closed = d.linearize(["ref.y"], ["motor.w"], jit=False)
    assert closed.input_labels == ["ref/y"] and closed.output_labels == ["motor/w"]
    assert sorted(closed.state_labels) == ["motor/i", "motor/phi", "motor/w", "pi/I"]
    _assert_same_response(closed, closed_ref)

    loop = d.loop_transfer("pi.y", jit=False)
    _assert_same_response(loop, loop_ref)
    # the opening itself: from the opening's input to the returning pi.y is -L
    opened = d.linearize(["pi.y"], ["pi.y"], open=["pi.y"], jit=False)
    _assert_same_response(opened, -loop_ref)


def test_dc_motor_pi_figures_match_python_control_on_hand_model():
    d = spidersim.loads(MOTOR_PI)
    closed_ref, loop_ref = _motor_hand()
    fig_closed = siso_figures(d.linearize(["ref.y"], ["motor.w"], jit=False))
    fig_loop = siso_figures(d.loop_transfer("pi.y", jit=False))

    assert fig_closed["dc_gain"] == pytest.approx(1.0, rel=1e-9)
    # spidersim's -3 dB point is the half-power point |G(0)|/sqrt(2): ask python-control
    # for exactly that drop (its default -3 dB is 10^(-3/20), 0.24 % different)
    bw_ref = float(control.bandwidth(closed_ref, dbdrop=HALF_POWER_DB))
    assert fig_closed["bandwidth"] == pytest.approx(bw_ref, rel=1e-6)
    assert fig_closed["states"] == 3         # the angle is invisible from the speed

    gm, pm, wcg, wcp = control.margin(loop_ref)
    assert np.isfinite(pm) and 30 < pm < 90 and np.isfinite(wcp)
    assert fig_loop["phase_margin"] == pytest.approx(float(pm), rel=1e-6)
    assert fig_loop["gain_crossover"] == pytest.approx(float(wcp), rel=1e-6)
    # relative degree 2 with an integrator: the phase never reaches -180 deg
    assert math.isinf(gm) and math.isinf(fig_loop["gain_margin"])
    assert math.isnan(wcg) and math.isnan(fig_loop["phase_crossover"])
    assert fig_loop["bandwidth"] is None and "integrator" in fig_loop["bandwidth_note"]


def test_jit_linearization_agrees_with_interpreted():
    d = spidersim.loads(MOTOR_PI)
    for make in (lambda jit: d.linearize(["ref.y"], ["motor.w", "motor.i"], jit=jit),
                 lambda jit: d.loop_transfer("pi.y", jit=jit)):
        a, b = make(True), make(False)
        assert a.state_labels == b.state_labels
        for m in "ABCD":
            x, y = getattr(a, m), getattr(b, m)
            np.testing.assert_allclose(x, y, rtol=1e-9, atol=1e-9 * np.max(np.abs(y)))


# ----------------------------------------------------------------------------- pendulum
G, LEN, C = 9.81, 0.5, 0.4

PENDULUM = f"""
name: pendulum
parameters: {{g: {G}, l: {LEN}, c: {C}, theta0: 0.0}}
blocks:
  th:   {{type: Integrator, x0: theta0}}
  om:   {{type: Integrator, x0: 0.0}}
  s:    {{type: Function, fn: sin}}
  kg:   {{type: Gain, k: -g/l}}
  kc:   {{type: Gain, k: -c}}
  acc:  {{type: Sum, signs: "++"}}
connections:
  - om.y -> th.u
  - th.y -> s.u
  - s.y -> kg.u
  - om.y -> kc.u
  - kg.y -> acc.u1
  - kc.y -> acc.u2
  - acc.y -> om.u
simulation: {{t_end: 1.0, rtol: 1e-11, atol: 1e-13}}
"""


def _pendulum_A(theta):
    return np.array([[0.0, 1.0], [-G / LEN * math.cos(theta), -C]])


def _ordered(sys):
    """A of the pendulum with states ordered (theta, omega)."""
    idx = [_state(sys, "th/y"), _state(sys, "om/y")]
    return sys.A[np.ix_(idx, idx)]


@pytest.mark.parametrize("theta0", [0.0, math.pi], ids=["lower", "upper"])
def test_pendulum_A_at_equilibria_is_analytic(theta0):
    d = spidersim.loads(PENDULUM, set={"theta0": theta0})
    sys = d.linearize(["acc.y"], ["th.y", "s.y"], jit=False)       # at: initial state
    A = _ordered(sys)
    np.testing.assert_allclose(A, _pendulum_A(theta0), rtol=1e-7, atol=1e-8)
    # the perturbation enters the speed's derivative; s.y = sin(theta) reads cos(theta0)
    it, io = _state(sys, "th/y"), _state(sys, "om/y")
    assert sys.B[io, 0] == pytest.approx(1.0, rel=1e-9) and sys.B[it, 0] == 0.0
    assert sys.C[1, it] == pytest.approx(math.cos(theta0), rel=1e-7)


def test_pendulum_trim_from_near_start_finds_upper_equilibrium():
    d = spidersim.loads(PENDULUM)
    probe = d.linearize(["acc.y"], ["th.y"], jit=False)
    it, io = _state(probe, "th/y"), _state(probe, "om/y")
    x0 = np.zeros(2)
    x0[it] = 3.0
    op = d.trim(x0=x0, jit=False)
    assert abs(op.x[it] - math.pi) < 1e-8
    assert abs(op.x[io]) < 1e-8
    # zero derivatives, by the analytic model and by trim's own residuals
    assert abs(-G / LEN * math.sin(op.x[it]) - C * op.x[io]) < 1e-8
    assert set(op.residuals) == {"d/dt th.y", "d/dt om.y"}
    assert max(abs(v) for v in op.residuals.values()) < 1e-10
    # linearized there: the upper (unstable) equilibrium
    A = _ordered(d.linearize(["acc.y"], ["th.y"], at=op, jit=False))
    np.testing.assert_allclose(A, _pendulum_A(math.pi), rtol=1e-7, atol=1e-8)


def test_linearize_at_time_uses_the_simulated_state():
    theta0, T = 0.3, 0.5
    d = spidersim.loads(PENDULUM, set={"theta0": theta0})
    sol = solve_ivp(lambda t, x: [x[1], -G / LEN * math.sin(x[0]) - C * x[1]], (0.0, T),
                    [theta0, 0.0], method="DOP853", rtol=1e-12, atol=1e-14)
    theta_T = sol.y[0, -1]
    # the test discriminates: A differs between the initial and the simulated state
    assert abs(math.cos(theta_T) - math.cos(theta0)) * G / LEN > 0.1

    sys = d.linearize(["acc.y"], ["th.y", "s.y"], at=T, jit=False)
    np.testing.assert_allclose(_ordered(sys), _pendulum_A(theta_T), rtol=1e-7, atol=1e-8)
    assert sys.C[1, _state(sys, "th/y")] == pytest.approx(math.cos(theta_T), rel=1e-7)


# ----------------------------------------------------------------------------- algebraic loop
LOOP = """
parameters: {K: 3.0}
blocks:
  u:   {type: Constant, value: 0.7}
  sum: {type: Sum, signs: "+-"}
  fb:  {type: Gain, k: K}
  x:   {type: Integrator}
connections:
  - u.y -> sum.u1
  - sum.y -> fb.u
  - fb.y -> sum.u2
  - sum.y -> x.u
"""

LOOP_FREE = """
parameters: {K: 3.0}
blocks:
  u:   {type: Constant, value: 0.7}
  sum: {type: Gain, k: 1/(1+K)}
  x:   {type: Integrator}
connections:
  - u.y -> sum.u
  - sum.y -> x.u
"""


@pytest.mark.parametrize("K", [3.0, 0.25])
def test_algebraic_loop_linearizes_like_its_loop_free_equivalent(K):
    a = spidersim.loads(LOOP, set={"K": K}).linearize(["u.y"], ["x.y", "sum.y"], jit=False)
    b = spidersim.loads(LOOP_FREE, set={"K": K}).linearize(["u.y"], ["x.y", "sum.y"],
                                                            jit=False)
    assert a.state_labels == b.state_labels == ["x/y"]
    for m in "ABCD":
        np.testing.assert_allclose(getattr(a, m), getattr(b, m), rtol=1e-9, atol=1e-12)
    # and both are x' = u / (1 + K), sum.y = u / (1 + K)
    assert a.B[0, 0] == pytest.approx(1 / (1 + K), rel=1e-9)
    assert a.D[1, 0] == pytest.approx(1 / (1 + K), rel=1e-9)


# ----------------------------------------------------------------------------- bandwidth
def _tf_diagram(num, den):
    return f"""
blocks:
  u: {{type: Constant}}
  g: {{type: TransferFunction, num: {list(num)}, den: {list(den)}}}
connections: [u.y -> g.u]
"""


@pytest.mark.parametrize("num, den, wb", [
    ([-3.0], [1.0, 2.0], 2.0),
    # wn = 2, zeta = 0.5: wb = wn sqrt(1 - 2 z^2 + sqrt((1 - 2 z^2)^2 + 1))
    ([-5.0], [1.0, 2.0, 4.0], 2 * math.sqrt(0.5 + math.sqrt(1.25))),
], ids=["first_order", "second_order"])
def test_bandwidth_of_negative_dc_gain_system(num, den, wb):
    sys = spidersim.loads(_tf_diagram(num, den)).linearize(["u.y"], ["g.y"], jit=False)
    value, note = bandwidth(sys)
    assert value == pytest.approx(wb, rel=1e-9) and note == ""
    fig = siso_figures(sys)
    assert fig["dc_gain"] == pytest.approx(num[0] / den[-1], rel=1e-9)
    assert fig["bandwidth"] == pytest.approx(wb, rel=1e-9)


LAG_INTEGRATOR = """
blocks:
  u: {type: Constant}
  g: {type: TransferFunction, num: [5], den: [1, 50]}
  i: {type: Integrator}
connections: [u.y -> g.u, g.y -> i.u]
"""

# two inertias coupled by a spring (a flexible joint): torque -> motor speed has the
# rigid-body integrator; its pole at 0 is a double eigenvalue of A (common angle and speed)
TWO_MASS = """
parameters: {J1: 1.0e-4, J2: 2.0e-4, k: 1000.0}
blocks:
  tau:  {type: Constant}
  a1:   {type: Sum, signs: "+-"}
  j1:   {type: Gain, k: 1/J1}
  w1:   {type: Integrator}
  p1:   {type: Integrator}
  j2:   {type: Gain, k: 1/J2}
  w2:   {type: Integrator}
  p2:   {type: Integrator}
  dp:   {type: Sum, signs: "+-"}
  ks:   {type: Gain, k: k}
connections:
  - tau.y -> a1.u1
  - ks.y -> a1.u2
  - a1.y -> j1.u
  - j1.y -> w1.u
  - w1.y -> p1.u
  - p1.y -> dp.u1
  - p2.y -> dp.u2
  - dp.y -> ks.u
  - ks.y -> j2.u
  - j2.y -> w2.u
  - w2.y -> p2.u
"""


@pytest.mark.parametrize("text, inp, out", [
    (LAG_INTEGRATOR, "u.y", "i.y"),
    (TWO_MASS, "tau.y", "w1.y"),
], ids=["lag_integrator", "two_mass_rigid_body"])
def test_bandwidth_undefined_for_system_with_integrator(text, inp, out):
    sys = spidersim.loads(text).linearize([inp], [out], jit=False)
    # sanity, independent of spidersim's figures: |G(jw)| grows like 1/w at low frequency
    g = np.abs(_freq(sys, [1e-3, 1e-2]))
    assert g[0] / g[1] == pytest.approx(10.0, rel=1e-2)
    value, note = bandwidth(sys)
    fig = siso_figures(sys)
    got = {"bandwidth()": (value, note),
           "siso_figures()": (fig["bandwidth"], fig["bandwidth_note"])}
    assert all(v is None and "integrator" in n for v, n in got.values()), (
        got, "poles:", control.poles(sys), "figure poles:", fig["poles"])


# ----------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("call, bad, near", [
    (lambda d: d.linearize(["acc.yy"], ["th.y"], jit=False), "acc.yy", "acc.y"),
    (lambda d: d.linearize(["acc.y"], ["th.z"], jit=False), "th.z", "th.y"),
    (lambda d: d.linearize(["acc.y"], ["th.y"], open=["kgg.y"], jit=False), "kgg.y", "kg.y"),
    (lambda d: d.loop_transfer("om.yy", jit=False), "om.yy", "om.y"),
    (lambda d: d.trim(targets={"sx.y": 0.0}, jit=False), "sx.y", "s.y"),
], ids=["input", "output", "open", "loop_transfer", "trim_target"])
def test_unknown_signal_is_reported_with_near_name(call, bad, near):
    d = spidersim.loads(PENDULUM)
    with pytest.raises(AnalysisError) as ei:
        call(d)
    msg = str(ei.value)
    assert f"unknown signal '{bad}'" in msg
    assert "did you mean" in msg and near in msg.split("did you mean", 1)[1]


def test_opening_a_signal_that_is_not_a_connection():
    d = spidersim.loads(LOOP)          # nothing reads the integrator's output x.y
    with pytest.raises(AnalysisError, match="cannot open 'x.y': it is not a connection"):
        d.linearize(["u.y"], ["x.y"], open=["x.y"], jit=False)
    with pytest.raises(AnalysisError, match="not a connection"):
        d.loop_transfer("x.y", jit=False)


CONST_INTO_INTEGRATOR = """
blocks:
  c:  {type: Constant, value: 2.0}
  x:  {type: Integrator}
  sq: {type: Function, fn: square}
connections: [c.y -> x.u, x.y -> sq.u]
"""


def test_trim_that_cannot_converge_names_the_residuals():
    d = spidersim.loads(CONST_INTO_INTEGRATOR)
    # x' = 2 whatever x is
    with pytest.raises(AnalysisError) as ei:
        d.trim(jit=False)
    msg = str(ei.value)
    assert "trim did not converge" in msg and "d/dt x.y = 2" in msg
    # a target no state reaches: x^2 = -1
    with pytest.raises(AnalysisError) as ei:
        d.trim(targets={"sq.y": -1.0}, derivatives=[], jit=False)
    msg = str(ei.value)
    assert "trim did not converge" in msg and "sq.y = 1" in msg


def test_loop_notes_against_routh():
    """L = K (s+1)^2 / s^3: closed loop s^3 + K s^2 + 2K s + K is stable iff K > 1/2
    (Routh), so at K = 10 the loop is conditionally stable with gain margin 0.05; an
    unstable open loop 2/(s-1) is stabilised (Nyquist: one counter-clockwise encirclement)."""
    import control

    from spidersim.solver.linearize import loop_notes
    notes = loop_notes(control.tf([10, 20, 10], [1, 0, 0, 0]))
    assert len(notes) == 1 and "conditionally stable" in notes[0] and "0.05 " in notes[0]
    assert loop_notes(control.tf([0.6, 1.2, 0.6], [1, 0, 0, 0]))[0].startswith("conditionally")
    assert "UNSTABLE" in loop_notes(control.tf([0.4, 0.8, 0.4], [1, 0, 0, 0]))[0]
    un = loop_notes(control.tf([2], [1, -1]))
    assert "open loop unstable: 1" in un[0] and "closed loop has 0" in un[0]
    assert "closed loop has 1" in loop_notes(control.tf([0.5], [1, -1]))[0]
    assert loop_notes(control.tf([1], [1, 1])) == []      # a plain stable loop: no note


# ------------------------------------------------------- figures of widely spread models
# The figures come from the minimal pole-zero form (spidersim.solver.siso), never from
# polynomial coefficients: expanding G into num/den and cutting "round-off" leading terms
# lost the zeros of these models (DC gain 12x off, bandwidths 20-80 % off).

def _hand_bandwidth(g, g0):
    """-3 dB point of the response function ``g(w)`` below DC gain ``g0``: a fine grid
    and Brent's method on |g| (complex arithmetic, no polynomial)."""
    from scipy.optimize import brentq
    w = np.logspace(-2, 7, 20000)
    m = np.abs([g(v) for v in w])
    k = np.flatnonzero(m < abs(g0) / math.sqrt(2))[0]
    return brentq(lambda v: abs(g(v)) - abs(g0) / math.sqrt(2), w[k - 1], w[k], xtol=1e-10)


def test_zeros_dc_gain_and_bandwidth_of_a_triple_zero_near_fast_poles():
    """G = (s + 1e4)^3 / ((s + 100)(s + 2e4)^3): DC gain 1e12 / (100 * 8e12) = 1.25e-3,
    three zeros at -1e4 (a triple root: computed to about eps^(1/3) of its size), four
    poles; the bandwidth from the factored form by hand."""
    num = [1.0, 3e4, 3e8, 1e12]                            # (s + 1e4)^3 expanded
    den = [1.0, 60100.0, 1206000000.0, 8120000000000.0, 8.0e14]
    sys = spidersim.loads(_tf_diagram(num, den)).linearize(["u.y"], ["g.y"], jit=False)
    fig = siso_figures(sys)
    assert fig["dc_gain"] == pytest.approx(1.25e-3, rel=1e-9)
    assert fig["states"] == 4 and len(fig["zeros"]) == 3
    assert np.allclose(fig["zeros"], -1e4, rtol=1e-3, atol=0)
    hand = lambda w: (1j * w + 1e4) ** 3 / ((1j * w + 100) * (1j * w + 2e4) ** 3)   # noqa: E731
    assert fig["bandwidth"] == pytest.approx(_hand_bandwidth(hand, 1.25e-3), rel=1e-8)


CURRENT_LOOP = """
blocks:
  icmd:  {type: Constant, value: 0.0}
  e:     {type: Sum, signs: "+-"}
  pi:    {type: PI, kp: 3, ki: 2000, antiwindup: none}
  motor: {type: DCMotor, R: 2, L: 5e-3, K_t: 0.08, J: 2e-4, b: 3e-4}
connections:
  - icmd.y -> e.u1
  - motor.i -> e.u2
  - e.y -> pi.e
  - pi.y -> motor.v
"""

# a second, unconnected drive in the same file (a current-fed brushless motor)
SECOND_DRIVE = """
  icmd2: {type: Constant, value: 0.0}
  drv:   {type: NRPIDriver}
  mot:   {type: BrushlessMotor, J: 1e6}
"""
SECOND_WIRES = """
  - icmd2.y -> drv.i_cmd
  - mot.theta_e -> drv.theta_e
  - mot.i_a -> drv.i_a
  - mot.i_b -> drv.i_b
  - drv.v_a -> mot.v_a
  - drv.v_b -> mot.v_b
"""


def _current_loop_hand():
    """PI current loop of a DC motor by hand at s = jw: C = kp + ki/s, plant
    I/V = 1 / (L s + R + K^2 / (J s + b)); closed I/I_cmd = C P / (1 + C P)."""
    kp, ki, R, L, K, J, b = 3.0, 2000.0, 2.0, 5e-3, 0.08, 2e-4, 3e-4

    def loop(w):
        s = 1j * w
        return (kp + ki / s) / (L * s + R + K ** 2 / (J * s + b))
    return loop, (lambda w: loop(w) / (1 + loop(w)))


@pytest.mark.parametrize("second", [False, True], ids=["alone", "beside_another_drive"])
def test_current_loop_figures_whatever_else_the_file_holds(second):
    """Bandwidth of the closed current loop and the margins of its loop transfer equal the
    hand model's, and an unconnected second drive in the file changes nothing (it put a
    gain margin of 30 at 12846 rad/s into the loop's figures and moved its crossover)."""
    from scipy.optimize import brentq
    text = CURRENT_LOOP
    if second:
        blocks, wires = text.split("connections:")
        text = blocks.rstrip("\n") + SECOND_DRIVE + "connections:" + wires.rstrip("\n") + \
            SECOND_WIRES
    d = spidersim.loads(text)
    loop, closed = _current_loop_hand()
    g0 = 1.0                                   # the PI's integrator: no error at DC
    fig = siso_figures(d.linearize(["icmd.y"], ["motor.i"], jit=False))
    assert fig["dc_gain"] == pytest.approx(g0, rel=1e-9)
    assert fig["bandwidth"] == pytest.approx(_hand_bandwidth(closed, g0), rel=1e-7)
    fl = siso_figures(d.loop_transfer("pi.y", jit=False))
    wc = brentq(lambda w: abs(loop(w)) - 1, 10, 1e5, xtol=1e-12)
    pm = 180 + math.degrees(np.angle(loop(wc)))
    assert fl["gain_crossover"] == pytest.approx(wc, rel=1e-8)
    assert fl["phase_margin"] == pytest.approx(pm, rel=1e-8)
    # PI (phase -90 at 0) times a first-order-dominated plant: never -180 deg
    assert math.isinf(fl["gain_margin"]) and math.isnan(fl["phase_crossover"])


def test_brushless_current_loop_bandwidth_against_the_hand_formula():
    """NRPI driver on a motor with a huge rotor inertia (no back-EMF): the q-axis current
    follows w_c / (s + w_c) with w_c = kp / L (the driver's design, 2000 Hz at the
    defaults); its bandwidth was printed 20 % low."""
    text = "blocks:" + SECOND_DRIVE + "connections:" + SECOND_WIRES
    d = spidersim.loads(text)
    fig = siso_figures(d.linearize(["icmd2.y"], ["mot.i_b"], jit=False))
    assert fig["dc_gain"] == pytest.approx(1.0, rel=1e-6)
    # the finite rotor inertia (1e6 kg.m2) leaves a back-EMF effect of a few 1e-5
    assert fig["bandwidth"] / (2 * math.pi) == pytest.approx(2000.0, rel=1e-4)


@pytest.mark.parametrize("num, den", [
    ([1.0], [1.0, -2.0, 101.0]),            # unstable pair 1 +- 10j: no crossing at 10 rad/s
    ([-2.0], [1.0, 1.0]),                   # negative DC gain: -180 deg at w = 0, gm 0.5
    ([1e5], [1.0, 0.0]),                    # integrator, gain 1e5: crossover at 1e5 rad/s
    ([1e10], [1.0, 1.0, 0.0]),              # crossover near 1e5 rad/s, far beyond the pole
    ([1.0, -1.0], [-1.0, -2.0, -1.0]),      # non-minimum-phase zero: gm 2 at sqrt(3)
    ([1.0], [1.0, 0.0, 0.0]),               # double integrator: -180 deg at every w
], ids=["unstable_pair", "negative_dc", "fast_integrator", "far_crossover", "nmp_zero",
        "double_integrator"])
def test_loop_margins_agree_with_python_control(num, den):
    """Gain and phase margins and their frequencies equal ``control.margin`` on well
    conditioned loops (each case a defect of the first pole-zero version, found by review:
    the phase of a right-half-plane pair wrapped, w = 0 was not a crossover, the search
    ended 1e4 times above the largest root, round-off around -180 deg made crossings)."""
    sys = spidersim.loads(_tf_diagram(num, den)).linearize(["u.y"], ["g.y"], jit=False)
    fig = siso_figures(sys)
    gm, pm, wcg, wcp = (float(v) for v in control.margin(control.tf(num, den)))
    for got, ref in ((fig["gain_margin"], gm), (fig["phase_margin"], pm),
                     (fig["phase_crossover"], wcg), (fig["gain_crossover"], wcp)):
        if math.isnan(ref) or math.isinf(ref):
            assert got == ref or (math.isnan(ref) and math.isnan(got)), (got, ref, fig)
        else:
            assert got == pytest.approx(ref, rel=1e-7, abs=1e-9), (got, ref, fig)


def test_slow_pole_beside_fast_pole_is_not_an_integrator():
    """1 / ((s + 0.05)(s / 1e5 + 1)): DC gain 20, bandwidth about 0.05 rad/s (a pole
    0.05 rad/s was taken for an integrator when 'at the origin' was relative to the
    fastest pole); (s + 0.05) / ((s + 1)(s / 1e5 + 1)): DC gain 0.05, not 0."""
    den = np.polymul([1.0, 0.05], [1e-5, 1.0])
    fig = siso_figures(spidersim.loads(_tf_diagram([1.0], den.tolist())).linearize(
        ["u.y"], ["g.y"], jit=False))
    assert fig["dc_gain"] == pytest.approx(20.0, rel=1e-9)
    assert fig["bandwidth"] == pytest.approx(0.05, rel=1e-3)
    den2 = np.polymul([1.0, 1.0], [1e-5, 1.0])
    fig2 = siso_figures(spidersim.loads(_tf_diagram([1.0, 0.05], den2.tolist())).linearize(
        ["u.y"], ["g.y"], jit=False))
    assert fig2["dc_gain"] == pytest.approx(0.05, rel=1e-9)


def test_feedthrough_with_large_coefficients_keeps_its_zeros():
    """A proper 4th-order transfer function (relative degree 0) with a denominator constant
    of 2.7e7 (the companion form's largest entry): its four zeros and DC gain num(0)/den(0)
    (the unbalanced pencil gave -6.77 and -3.52 for -6.58 and -3.84, DC gain 6 % off)."""
    zeros = np.array([-3.8417, -6.5797, -28.8804, -73.9246])
    num = (39.6 * np.poly(zeros)).tolist()
    den = [1.0, 74.2566, 12618.38366, 292027.514199, 26647825.4991]
    fig = siso_figures(spidersim.loads(_tf_diagram(num, den)).linearize(
        ["u.y"], ["g.y"], jit=False))
    assert fig["dc_gain"] == pytest.approx(num[-1] / den[-1], rel=1e-9)
    # the pencil of a companion form stays ill-conditioned: about 2e-6 here
    assert np.sort(fig["zeros"].real) == pytest.approx(np.sort(zeros), rel=1e-5)


@pytest.mark.parametrize("zeta", [0.01, 0.05, 0.3])
def test_peak_gain_of_a_resonance_is_the_closed_form(zeta):
    """Second-order lag wn^2 / (s^2 + 2 zeta wn s + wn^2): the resonant peak
    1 / (2 zeta sqrt(1 - zeta^2)) at wn sqrt(1 - 2 zeta^2). The grid alone read it at the
    pole magnitude wn (1/(2 zeta): 0.1 % low at zeta = 0.05, 4.6 % at 0.3)."""
    from spidersim.solver.linearize import peak_gain
    wn = 10.0
    pk, w = peak_gain(control.ss(control.tf([wn ** 2], [1, 2 * zeta * wn, wn ** 2])))
    assert pk == pytest.approx(1 / (2 * zeta * np.sqrt(1 - zeta ** 2)), rel=1e-9)
    assert w == pytest.approx(wn * np.sqrt(1 - 2 * zeta ** 2), rel=1e-6)


@pytest.mark.parametrize("num, den, peak, w_peak", [
    ([1.0], [1.0, 1.0], 1.0, 0.0),             # low-pass: the DC gain, at w = 0
    ([1.0], [1.0, 0.0], np.inf, 0.0),          # a free integrator: unbounded as w -> 0
    ([2.0, 1.0], [1.0, 1.0], 2.0, np.inf),     # lead (biproper): |G(j inf)| = 2
])
def test_peak_gain_at_the_ends_of_the_axis(num, den, peak, w_peak):
    """A peak at w = 0 or w = inf is reported there, not at the grid's last point
    (0.001 rad/s with -4e-6 dB for a plain lag)."""
    from spidersim.solver.linearize import peak_gain
    pk, w = peak_gain(control.ss(control.tf(num, den)))
    assert pk == pytest.approx(peak, rel=1e-12) and w == w_peak


@pytest.mark.parametrize("num, den, gm, pm", [
    ([math.sqrt(2)], [1, 1], math.inf, 135.0),      # |L| = 1 exactly at 1 rad/s, a grid point
    ([2, 4, 2], [1, 0, 0, 0], 0.25, None),          # -180 deg exactly at 1 rad/s
    ([8, 16, 8], [1, 0, 0, 0], 0.0625, None),
])
def test_margins_of_crossings_on_a_pole_or_zero_magnitude(num, den, gm, pm):
    """Crossovers that fall exactly on a pole or zero magnitude, where the search grid has
    a point (a symmetric design such as 2 (s + 1)^2 / s^3): the margins equal
    control.margin's. Before, a grid value within 1e-9 of the target was taken as
    touching, not crossing: "phase crossover: none, gain margin: inf" for 0.25, and
    "phase margin: inf" for 135 deg."""
    sys = control.ss(control.tf(num, den))
    fig = siso_figures(sys)
    ref_gm, ref_pm, _wg, _wp = control.margin(sys)
    assert fig["gain_margin"] == pytest.approx(gm if math.isfinite(gm) else ref_gm, rel=1e-6)
    if math.isfinite(gm):
        assert fig["phase_crossover"] == pytest.approx(1.0, rel=1e-9)
    if pm is not None:
        assert fig["phase_margin"] == pytest.approx(pm, rel=1e-6)
        assert fig["phase_margin"] == pytest.approx(ref_pm, rel=1e-6)


def test_bandwidth_finds_a_narrow_notch():
    """|G| = |s^2 + 2e-4 s + 1| / |s^2 + 2e-3 s + 1| / |s/100 + 1|: a notch to 0.1 at
    1 rad/s, narrower than the plain logarithmic grid's spacing; the first -3 dB point is
    just below it (brentq on |G|), not the pole at 100 rad/s."""
    s = control.tf("s")
    g = control.ss((s ** 2 + 2e-4 * s + 1) / (s ** 2 + 2e-3 * s + 1) / (s / 100 + 1))
    wb, _note = bandwidth(g)
    from scipy.optimize import brentq

    def mag(w):
        return abs(complex(control.evalfr(g, 1j * w))) - 1 / math.sqrt(2)
    assert wb == pytest.approx(brentq(mag, 0.99, 0.99999999), rel=1e-9)
    assert wb == pytest.approx(0.99901, abs=1e-5)


# ------------------------------------------------------- consumers of another slice
SLICES = """
name: slices
blocks:
  c: {type: Constant, value: [1, 2]}
  g: {type: Gain, k: 3}
  h: {type: Gain, k: 5}
  i: {type: Integrator, x0: [0, 0]}
  j: {type: Integrator}
connections: [c.y -> g.u, g.y -> i.u, "c.y[1] -> h.u", h.y -> j.u]
"""


def test_input_reaches_consumers_of_any_overlapping_slice():
    # g reads all of c.y, h only c.y[1]: each element reaches exactly its readers
    d = spidersim.loads(SLICES)
    D = np.asarray(d.linearize(["c.y[0]"], ["g.y", "h.y"], jit=False).D)
    np.testing.assert_allclose(D, [[3.0], [0.0], [0.0]], atol=1e-9)
    D = np.asarray(d.linearize(["c.y"], ["g.y", "h.y"], jit=False).D)
    np.testing.assert_allclose(D, [[3.0, 0.0], [0.0, 3.0], [0.0, 5.0]], atol=1e-9)
    D = np.asarray(d.linearize(["c.y[0]", "c.y[1]"], ["g.y", "h.y"], jit=False).D)
    np.testing.assert_allclose(D, [[3.0, 0.0], [0.0, 3.0], [0.0, 5.0]], atol=1e-9)


VECTOR_LOOP = """
name: vloop
blocks:
  r: {type: Constant, value: [1, 1]}
  e: {type: Sum, signs: "+-"}
  g: {type: Gain, k: 2}
  x: {type: Integrator, x0: [0, 0]}
connections: [r.y -> e.u1, x.y -> e.u2, e.y -> g.u, g.y -> x.u]
"""


def test_opening_one_element_of_a_signal_read_whole():
    # e reads all of x.y: opening x.y[0] cuts element 0's loop only
    d = spidersim.loads(VECTOR_LOOP)
    sys = d.linearize(["r.y"], ["x.y"], open=["x.y[0]"], jit=False)
    np.testing.assert_allclose(np.asarray(sys.A), np.diag([0.0, -2.0]), atol=1e-9)
    loop = d.loop_transfer("x.y[0]", jit=False)
    _assert_same_response(loop, control.ss(2 / S))


with open(os.path.join(os.path.dirname(__file__), "..", "data", "lag_loop.yaml")) as _fh:
    LAG = _fh.read()


def test_trim_with_free_inputs_and_no_targets():
    # d/dt x = 4 (r + u - x) = 0: an equilibrium x = 2 + u (was a raw ValueError: no
    # targets, so no outputs to evaluate)
    op = spidersim.loads(LAG).trim(free_inputs=["r.y"], jit=False)
    assert op.x[0] == pytest.approx(2.0 + op.inputs["r.y"], abs=1e-9)
    assert op.residuals == {"d/dt x.y": pytest.approx(0.0, abs=1e-9)}


def test_trim_from_a_start_with_non_finite_residuals_is_named():
    # sq.y = x^2 overflows at x0 = 1e308 (was SciPy's raw ValueError)
    d = spidersim.loads(CONST_INTO_INTEGRATOR)
    with pytest.raises(AnalysisError, match=r"trim cannot start from the given x0: the "
                       r"residuals there are not finite \(sq.y = inf\)"):
        d.trim(targets={"sq.y": 1.0}, derivatives=[], x0=[1e308], jit=False)


FB_THROUGH_LAG = """
name: fb
subsystems: {lag: %s}
blocks:
  r: {type: Constant, value: 1}
  e: {type: Sum, signs: "+-"}
  k: {type: Gain, k: 4}
  p: {type: lag, tau: 0.5, k: 1}
connections: [r.y -> e.u1, p.y -> e.u2, e.y -> k.u, k.y -> p.u]
"""


@pytest.mark.parametrize("cut", ["k.y", "e.y", "p.y"])
def test_loop_cut_at_a_subsystem_output_keeps_its_inner_loop(cut):
    """One loop through the library lag (tau dy/dt = k u - y, its own inner feedback on
    int.y, the signal its output y names): L = 4 / (0.5 s + 1) = 8 / (s + 2) wherever the
    loop is cut, p.y included. Cutting p.y opened the lag's inner feedback too (its
    Gain reads the same int.y): L = 10/s, "a free integrator", a 90 deg phase margin."""
    lib = os.path.join(os.path.dirname(__file__), "..", "..", "diagrams", "lib", "lag.yaml")
    d = spidersim.loads(FB_THROUGH_LAG % os.path.abspath(lib))
    _assert_same_response(d.loop_transfer(cut, jit=False), control.ss(8 / (S + 2)))
    sys = d.linearize(["r.y"], ["p.y"], open=["p.y"], jit=False)
    _assert_same_response(sys, control.ss(8 / (S + 2)))


@pytest.mark.parametrize("kw", [dict(open=["pos_ctrl.y", "pos_ctrl.y"]),
                                dict(inputs=["ref.y", "ref.y"])])
def test_a_signal_named_twice_is_refused_as_such(kw):
    """An opening (or input) given twice is said to be given twice (it was "not a
    connection (no block reads it)": the first point had taken its readers)."""
    d = spidersim.load(os.path.join(os.path.dirname(__file__), "..", "..", "diagrams",
                                    "servo.yaml"))
    args = dict(inputs=["ref.y"], outputs=["motor.w"], open=[], jit=False)
    args.update(kw)
    with pytest.raises(AnalysisError, match="'(pos_ctrl|ref).y' is given twice"):
        d.linearize(**args)


@pytest.mark.parametrize("inputs, outputs, open_, what", [
    (["c.y", "c.y[2]"], ["g.y"], [], "inputs"),
    (["c.y[-1]", "c.y[2]"], ["g.y"], [], "inputs"),
    (["c.y"], ["g.y", "g.y[2]"], [], "outputs"),
    (["c.y[0]"], ["g.y"], ["c.y", "c.y[1]"], "open"),
])
def test_inputs_sharing_an_element_are_refused(inputs, outputs, open_, what):
    """Two inputs (outputs, openings) that share an element of one signal: the model had
    one column (row) more than names (4 columns, 3 labels for ``c.y`` and ``c.y[2]``) and
    the shared element's perturbation was added twice. Refused, naming both."""
    d = spidersim.loads("blocks:\n  c: {type: Constant, value: [1, 2, 3]}\n"
                        "  g: {type: Gain, k: 5}\nconnections: [c.y -> g.u]\n"
                        "simulation: {t_end: 1}\n")
    with pytest.raises(AnalysisError, match=rf"{what}: .* share element"):
        d.linearize(inputs, outputs, open=open_)


def test_disjoint_elements_of_one_signal_are_two_inputs():
    """``c.y[0]`` and ``c.y[1:]``-like disjoint elements stay allowed: one column each."""
    d = spidersim.loads("blocks:\n  c: {type: Constant, value: [1, 2, 3]}\n"
                        "  g: {type: Gain, k: 5}\nconnections: [c.y -> g.u]\n"
                        "simulation: {t_end: 1}\n")
    sys = d.linearize(["c.y[0]", "c.y[2]"], ["g.y"])
    assert sys.ninputs == 2 and len(sys.input_labels) == 2
    np.testing.assert_allclose(sys.D, [[5, 0], [0, 0], [0, 5]], atol=1e-9)
