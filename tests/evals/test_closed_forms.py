"""Simulated results against closed-form / independently computed solutions.

Accuracy is stated as the max error normalised by the tolerance asked for::

    ratio = max |y - y_exact| / (atol + rtol * max |y_exact|)

and claimed ``< 5`` (a global error a few times the local tolerance is the normal outcome
of error-per-step control over a run). Tolerances are chosen per method and per problem so
that the claim is meaningful; the measured ratios are noted next to them. Where a method
cannot meet the claim at any tolerance, the case is left out of that test with the measured
numbers written down, plus a test showing the failure is the SciPy method's own behaviour (same
result as ``scipy.integrate.solve_ivp``), not something spidersim adds.
"""
from __future__ import annotations

import math
import os

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import spidersim

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DIAGRAMS = os.path.join(ROOT, "diagrams")
METHODS = ["LSODA", "RK45", "DOP853", "Radau", "BDF"]
BOUND = 5.0


def ratio(y, exact, rtol, atol):
    """max |y - exact| normalised by the tolerance asked for."""
    y, exact = np.asarray(y, float), np.asarray(exact, float)
    assert y.shape == exact.shape
    return float(np.max(np.abs(y - exact)) / (atol + rtol * np.max(np.abs(exact))))


# ---------------------------------------------------------------------------- first-order lag
TAU = 0.5
LAG = """
name: lag
parameters: {tau: 0.5}
blocks:
  step: {type: Step, t_step: 0.0}
  err:  {type: Sum, signs: "+-"}
  g:    {type: Gain, k: 1/tau}
  int:  {type: Integrator}
connections:
  - step.y -> err.u1
  - int.y -> err.u2
  - err.y -> g.u
  - g.y -> int.u
"""

# ---------------------------------------------------------------------------- oscillator
W = 2 * math.pi  # period 1 s; the horizon is two periods
# x'' = -w^2 x exactly as asked: two Integrators and a Gain (a loop of size-inheriting
# blocks whose size comes from the Integrators' x0; see
# test_oscillator_of_two_integrators_and_a_gain_loads).
OSC_MINIMAL = """
name: osc
parameters: {w: 6.283185307179586}
blocks:
  v: {type: Integrator, x0: 0}
  x: {type: Integrator, x0: 1}
  k: {type: Gain, k: -w**2}
connections:
  - x.y -> k.u
  - k.y -> v.u
  - v.y -> x.u
"""
# The same ODE with a sized source in the loop (v' = 0 + (-w^2) x, bit-identical right-hand
# side), so that the accuracy tests run while the size-inference bug stands.
OSC = """
name: osc
parameters: {w: 6.283185307179586}
blocks:
  v:    {type: Integrator, x0: 0}
  x:    {type: Integrator, x0: 1}
  k:    {type: Gain, k: -w**2}
  zero: {type: Constant, value: 0}
  acc:  {type: Sum, signs: "++"}
connections:
  - x.y -> k.u
  - zero.y -> acc.u1
  - k.y -> acc.u2
  - acc.y -> v.u
  - v.y -> x.u
"""

# (rtol, atol) per method for the lag and the oscillator; measured ratios lag / osc x / osc v.
SMOOTH_TOL = {
    "LSODA": (1e-10, 1e-12),   # 0.52 / 2.34 / 1.76   (at 1e-8: 0.41 / 4.22 / 4.55, too close)
    "RK45": (1e-8, 1e-10),     # 0.19 / 1.55 / 1.39
    "DOP853": (1e-8, 1e-10),   # 0.02 / 0.84 / 0.92
    "Radau": (1e-8, 1e-10),    # 0.001 / 0.005 / 0.005
    "BDF": (1e-8, 1e-10),      # 1.67 / 61 / 55  (osc: see BDF_OSC below)
}
BDF_OSC = ("SciPy's BDF accumulates global error (numerical damping, phase drift) on an "
           "undamped oscillator: over two periods "
           "the ratio is 19 at rtol=1e-6, 61 at 1e-8, 144 at 1e-10 (identical to plain "
           "solve_ivp, see test_oscillator_trajectory_is_scipys); no tolerance meets < 5")


@pytest.fixture(scope="module")
def lag():
    return spidersim.loads(LAG)


@pytest.fixture(scope="module")
def osc():
    return spidersim.loads(OSC)


@pytest.mark.parametrize("method", METHODS)
def test_first_order_lag(lag, method):
    rtol, atol = SMOOTH_TOL[method]
    r = lag.simulate(t_end=5 * TAU, method=method, rtol=rtol, atol=atol, jit=False)
    assert r.status == "ok" and r.t[-1] == pytest.approx(5 * TAU)
    exact = 1 - np.exp(-r.t / TAU)
    assert ratio(r["int.y"], exact, rtol, atol) < BOUND
    # the derivative path too: err.y = u - y
    assert ratio(r["err.y"], np.exp(-r.t / TAU), rtol, atol) < BOUND


# BDF is left out here: it cannot meet the bound at any tolerance (BDF_OSC), exactly as plain
# SciPy; its convergence is checked by its own test below.
@pytest.mark.parametrize("method", [m for m in METHODS if m != "BDF"])
def test_harmonic_oscillator(osc, method):
    rtol, atol = SMOOTH_TOL[method]
    r = osc.simulate(t_end=2.0, method=method, rtol=rtol, atol=atol, jit=False)
    assert r.status == "ok" and r.t[-1] == pytest.approx(2.0)
    assert ratio(r["x.y"], np.cos(W * r.t), rtol, atol) < BOUND
    assert ratio(r["v.y"], -W * np.sin(W * r.t), rtol, atol) < BOUND


@pytest.mark.parametrize("method", ["NDF", "ROS34PW2", "DP54"])
def test_compiled_loop_methods_on_the_lag(lag, method):
    """The compiled loop's methods on the first-order lag, y = 1 - exp(-t/tau), against the
    closed form: NDF (variable order) within 5 tolerances at 1e-8/1e-10 (measured below),
    like SciPy's BDF above; the stiff ROS34PW2 and DP54 too."""
    rtol, atol = 1e-8, 1e-10
    r = lag.simulate(t_end=5 * TAU, method=method, rtol=rtol, atol=atol)
    assert r.stats["method"] == method and r.t[-1] == pytest.approx(5 * TAU)
    assert ratio(r["int.y"], 1 - np.exp(-r.t / TAU), rtol, atol) < BOUND
    assert ratio(r["err.y"], np.exp(-r.t / TAU), rtol, atol) < BOUND


def test_compiled_ndf_on_the_oscillator_converges():
    """The undamped oscillator through the compiled NDF: a multistep BDF damps and drifts
    (as SciPy's BDF, see BDF_OSC), so its error is checked to shrink with the tolerance:
    1e-6 -> 1e-9 cuts the largest error of x = cos(w t) over two periods at least 100-fold,
    and at 1e-9/1e-11 it is below 1e-5."""
    osc = spidersim.loads(OSC)
    errs = []
    for tol in (1e-6, 1e-9):
        r = osc.simulate(t_end=2.0, method="NDF", rtol=tol, atol=tol * 1e-2)
        errs.append(np.max(np.abs(r["x.y"] - np.cos(W * r.t))))
    assert errs[1] < errs[0] / 100 and errs[1] < 1e-5


@pytest.mark.parametrize("method", METHODS)
def test_oscillator_trajectory_is_scipys(osc, method):
    """spidersim adds nothing to the solver's error: same steps, same values as SciPy."""
    rtol, atol = SMOOTH_TOL[method]
    # unbounded max_step, as solve_ivp's default (spidersim's own default is t_end / 50)
    r = osc.simulate(t_end=2.0, method=method, rtol=rtol, atol=atol, max_step=np.inf,
                     jit=False)
    s = solve_ivp(lambda t, y: [-W ** 2 * y[1], y[0]], (0.0, 2.0), [0.0, 1.0], method=method,
                  rtol=rtol, atol=atol)
    if method in ("Radau", "BDF"):
        # implicit methods differ from solve_ivp in the last digits through the
        # finite-difference Jacobian (spidersim passes jac_sparsity), and BDF's order and step
        # choices amplify that; the error level is what must agree
        assert ratio(r["x.y"], np.cos(W * r.t), rtol, atol) == pytest.approx(
            ratio(s.y[1], np.cos(W * s.t), rtol, atol), rel=0.1)
        return
    assert len(r.t) == len(s.t)
    np.testing.assert_allclose(r.t, s.t, rtol=1e-13, atol=0)
    np.testing.assert_allclose(r["x.y"], s.y[1], rtol=0, atol=1e-12)
    np.testing.assert_allclose(r["v.y"], s.y[0], rtol=0, atol=1e-12 * W)


def test_bdf_oscillator_error_converges(osc):
    """BDF misses the < 5 claim on the oscillator but its error does fall with the
    tolerance (about x0.03 per x0.01 in tolerance)."""
    errs = []
    for rtol in (1e-6, 1e-8, 1e-10):
        r = osc.simulate(t_end=2.0, method="BDF", rtol=rtol, atol=rtol / 100, jit=False)
        errs.append(np.max(np.abs(r["x.y"] - np.cos(W * r.t))))
    assert errs[0] < 1e-4
    assert errs[1] < errs[0] / 10 and errs[2] < errs[1] / 10, errs


def test_oscillator_of_two_integrators_and_a_gain_loads():
    """Guards size inference through a loop made only of size-inheriting blocks
    (Integrator -> Gain -> Integrator -> Integrator): the sizes come from the Integrators'
    x0 (``Block.fallback_sizes``), so the most basic ODE diagram loads and follows
    cos(w t). (It once failed with "cannot infer the size of output 'y'".)"""
    d = spidersim.loads(OSC_MINIMAL)
    rtol, atol = SMOOTH_TOL["RK45"]
    r = d.simulate(t_end=2.0, method="RK45", rtol=rtol, atol=atol, jit=False)
    assert ratio(r["x.y"], np.cos(W * r.t), rtol, atol) < BOUND


# ---------------------------------------------------------------------------- PI speed loop
MOTOR = dict(R=1.0, L=1e-3, K_t=0.05, J=1e-4, b=1e-5)
KP, KI, W_REF = 0.05, 5.0, 100.0   # closed-loop poles -950, -25 +- 44.8j
PI_LOOP = f"""
name: speed_pi
blocks:
  ref:   {{type: Step, t_step: 0, after: {W_REF}}}
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
PI_STATES = ["motor.i", "motor.w", "pi.I", "motor.phi"]
PI_T_END, PI_DT = 0.3, 1e-3


def pi_loop_ss(R=MOTOR["R"]):
    """Closed loop by hand, states (i, w, I, phi), input the speed reference r::

        L di/dt = v - R i - K w,   v = kp (r - w) + I
        J dw/dt = K i - b w
        dI/dt   = ki (r - w)
        dphi/dt = w
    """
    L, K, J, b = MOTOR["L"], MOTOR["K_t"], MOTOR["J"], MOTOR["b"]
    A = np.array([[-R / L, -(K + KP) / L, 1 / L, 0],
                  [K / J, -b / J, 0, 0],
                  [0, -KI, 0, 0],
                  [0, 1, 0, 0]])
    B = np.array([[KP / L], [0], [KI], [0]])
    return A, B


def pi_loop_exact(t, R=MOTOR["R"]):
    """States at arbitrary times for the step r = W_REF at t = 0, by the eigenvectors of the
    (i, w, I) block A3 (distinct eigenvalues, invertible)::

        z(t)   = A3^-1 (e^(A3 t) - 1) b,      b = B W_REF
        phi(t) = [A3^-2 (e^(A3 t) - 1) b - A3^-1 b t]_w
    """
    A, B = pi_loop_ss(R)
    A3, b = A[:3, :3], B[:3, 0] * W_REF
    lam, V = np.linalg.eig(A3)
    c = np.linalg.solve(V, b)
    t = np.asarray(t, float)
    E = np.exp(np.outer(lam, t)) - 1.0                    # (3, n)
    z = (V @ (c[:, None] / lam[:, None] * E)).real
    phi = (V[1] @ (c[:, None] / lam[:, None] ** 2 * E)).real - (V[1] @ (c / lam)).real * t
    return np.vstack([z, phi])


# (rtol, atol), measured ratios on the grid / at the steps (i, w, I). The multistep methods'
# global error grows as the tolerance tightens (LSODA 3.3 at 1e-8, 7.9 at 1e-10; BDF 5.5 at
# 1e-8), so they are held to the claim at 1e-6.
PI_TOL = {
    "LSODA": (1e-6, 1e-8),     # 0.70 / 0.69
    "RK45": (1e-8, 1e-10),     # 0.35 / 0.35
    "DOP853": (1e-8, 1e-10),   # not in the bound test, see DOP853_PI
    "Radau": (1e-8, 1e-10),    # 0.12 / 0.004
    "BDF": (1e-6, 1e-8),       # 2.3 / 2.3
}
DOP853_PI = ("SciPy's DOP853 on this stiff loop (pole at -950 1/s): once the step reaches the "
             "explicit stability limit its error estimate misses a bad step; current error "
             "ratio ~37 at the steps and ~4000 on the dense-output grid at rtol=1e-8 "
             "(plain solve_ivp on the same ODE: 14 and 950)")


@pytest.fixture(scope="module")
def pi_loop():
    return spidersim.loads(PI_LOOP)


# DOP853 is left out here (DOP853_PI: the SciPy method's own limit on this stiff loop, shown
# equal to plain solve_ivp by its own test).
@pytest.mark.parametrize("method", [m for m in METHODS if m != "DOP853"])
def test_pi_speed_loop_against_python_control(pi_loop, method):
    import control

    rtol, atol = PI_TOL[method]
    # uniform grid: python-control's forced_response needs equally spaced times
    r = pi_loop.simulate(t_end=PI_T_END, method=method, rtol=rtol, atol=atol,
                         output_interval=PI_DT, jit=False)
    A, B = pi_loop_ss()
    sys = control.ss(A, B, np.eye(4), np.zeros((4, 1)))
    resp = control.forced_response(sys, T=r.t, U=np.full(len(r.t), W_REF))
    ref = np.asarray(resp.outputs)
    for k, name in enumerate(PI_STATES):
        assert ratio(r[name], ref[k], rtol, atol) < BOUND, name
    # the command too: v = kp (r - w) + I
    v_ref = KP * (W_REF - ref[1]) + ref[2]
    assert ratio(r["pi.y"], v_ref, rtol, atol) < BOUND
    # sanity of the reference itself: underdamped, settles to W_REF
    assert ref[1].max() > 1.05 * W_REF and abs(ref[1][-1] - W_REF) < 1e-3 * W_REF

    # and at the solver's own steps, against the matrix exponential
    r = pi_loop.simulate(t_end=PI_T_END, method=method, rtol=rtol, atol=atol, jit=False)
    ex = pi_loop_exact(r.t)
    for k, name in enumerate(PI_STATES):
        assert ratio(r[name], ex[k], rtol, atol) < BOUND, name


# ---------------------------------------------------------------------------- subsystems
@pytest.fixture(scope="module")
def three_lags():
    d = spidersim.load(os.path.join(DIAGRAMS, "three_lags.yaml"))
    return d, d.simulate(jit=False)


def lag_exact(t, tau, k=1.0):
    return k * (1 - np.exp(-t / tau))


def two_lags_exact(t, t1, t2):
    return 1 - (t1 * np.exp(-t / t1) - t2 * np.exp(-t / t2)) / (t1 - t2)


def test_subsystem_instances_match_closed_forms(three_lags):
    d, r = three_lags
    rtol, atol = d.simulation["rtol"], d.simulation["atol"]   # 1e-8, 1e-10 from the file
    t = r.t
    assert t[-1] == pytest.approx(2.0)
    cases = {"fast": (0.1, 1.0), "mid": (0.2, 1.0), "slow": (0.5, 2.0)}
    for name, (tau, k) in cases.items():
        assert ratio(r[f"{name}.y"], lag_exact(t, tau, k), rtol, atol) < BOUND, name
        np.testing.assert_array_equal(r[f"{name}.y"], r[f"{name}.int.y"])
    # the nested pair: tau1 = 0.1 then tau2 = 0.3
    assert ratio(r["pair.mid"], lag_exact(t, 0.1), rtol, atol) < BOUND
    assert ratio(r["pair.y"], two_lags_exact(t, 0.1, 0.3), rtol, atol) < BOUND
    np.testing.assert_array_equal(r["pair.y"], r["pair.b.int.y"])
    # the instances really are different: their parameters were evaluated per instance
    assert d.blocks["fast.fb"].params["k"][0] == pytest.approx(10.0)
    assert d.blocks["mid.fb"].params["k"][0] == pytest.approx(5.0)
    assert d.blocks["slow.gain"].params["k"][0] == pytest.approx(4.0)


def test_set_subsystem_parameter_changes_only_that_instance(three_lags):
    d0, _ = three_lags
    d = spidersim.load(os.path.join(DIAGRAMS, "three_lags.yaml"), set={"slow.k": 3})
    # parameter level: only slow.gain's k (k/tau = 3/0.5) moved
    changed = [p for p in d.blocks if not all(
        np.array_equal(np.asarray(v), np.asarray(d0.blocks[p].params[n]))
        for n, v in d.blocks[p].params.items())]
    assert changed == ["slow.gain"]
    assert d.blocks["slow.gain"].params["k"][0] == pytest.approx(6.0)
    assert d.blocks["slow.fb"].params["k"][0] == pytest.approx(2.0)
    # result level, on a common grid
    r0 = d0.simulate(jit=False, output_interval=0.01)
    r = d.simulate(jit=False, output_interval=0.01)
    np.testing.assert_array_equal(r.t, r0.t)
    rtol, atol = d.simulation["rtol"], d.simulation["atol"]
    assert ratio(r["slow.y"], lag_exact(r.t, 0.5, 3.0), rtol, atol) < BOUND
    assert np.max(np.abs(r["slow.y"] - r0["slow.y"])) > 0.9   # 3 vs 2 at t = 2 s: 0.98
    for name in ("fast.y", "mid.y", "pair.mid", "pair.y"):
        np.testing.assert_allclose(r[name], r0[name], rtol=0, atol=2 * BOUND * (atol + rtol))


# ---------------------------------------------------------------------------- servo
@pytest.fixture(scope="module")
def servo_runs():
    d = spidersim.load(os.path.join(DIAGRAMS, "servo.yaml"))
    rj = d.simulate(jit=True)
    ri = d.simulate(jit=False)
    return d, rj, ri


def test_servo_compiled_equals_interpreted(servo_runs):
    _, rj, ri = servo_runs
    assert rj.stats["jit"] is True and ri.stats["jit"] is False
    assert len(rj.t) == len(ri.t)
    np.testing.assert_allclose(rj.t, ri.t, rtol=1e-12, atol=0)
    assert set(rj.names) == set(ri.names)
    for name in ri.names:
        scale = max(np.max(np.abs(ri[name])), 1e-300)
        np.testing.assert_allclose(rj[name], ri[name], rtol=1e-12, atol=1e-12 * scale,
                                   err_msg=name)
    assert rj.stats["steps"] == ri.stats["steps"]


def test_servo_reaches_reference(servo_runs):
    d, _, r = servo_runs
    assert r.t[-1] == pytest.approx(1.0)
    assert abs(r["motor.phi"][-1] - 1.0) < 1e-3          # measured 7.6e-4
    assert r["ref.y"][0] == 0 and r["ref.y"][-1] == 1
    assert [e[:2] for e in r.events] == [(pytest.approx(0.01), "ref")]
    v = r["sat.y"]
    assert np.all(np.abs(v) <= 24.0)
    # NOTE: with a 1 rad step the voltage does NOT reach the 24 V limit: the first command
    # is kp_cur * kp_spd * k_pos * 1 rad = 5 * 0.05 * 20 = 5 V and it only falls from there
    # (an independent solve_ivp of the same equations agrees). Saturation is exercised by
    # test_servo_voltage_saturates_early_on_a_large_step.
    assert v.max() == pytest.approx(5.0, rel=1e-9)


def test_servo_voltage_saturates_early_on_a_large_step():
    d = spidersim.load(os.path.join(DIAGRAMS, "servo.yaml"), set={"ref.after": 10})
    r = d.simulate(jit=False)
    v, t = r["sat.y"], r.t
    assert np.all(np.abs(v) <= 24.0)
    sat = t[v == 24.0]
    assert len(sat) > 3
    assert sat.min() == pytest.approx(0.01)     # from the step on (first command 50 V)
    assert sat.max() < 0.02                     # early on only (measured up to 0.0104 s)
    assert np.all(v[t > 0.02] < 24.0)
    assert abs(r["motor.phi"][-1] - 10.0) < 1e-2


# ---------------------------------------------------------------------------- set() and compile
def test_set_parameter_without_recompiling_interpreted():
    d = spidersim.loads(PI_LOOP)
    rtol, atol = PI_TOL["LSODA"]
    kw = dict(t_end=PI_T_END, method="LSODA", rtol=rtol, atol=atol, jit=False)
    r1 = d.simulate(**kw)
    d.set("motor.R", 2.0)
    r2 = d.simulate(**kw)
    assert r2.stats["compile_time"] == 0
    assert r2.stats["structure_key"] == r1.stats["structure_key"]
    ex1, ex2 = pi_loop_exact(r1.t, R=1.0), pi_loop_exact(r2.t, R=2.0)
    for k, name in enumerate(PI_STATES):
        assert ratio(r1[name], ex1[k], rtol, atol) < BOUND, name
        assert ratio(r2[name], ex2[k], rtol, atol) < BOUND, name
    # and it did change: the current peak drops with the doubled resistance
    assert r2["motor.i"].max() < 0.9 * r1["motor.i"].max()


def test_set_parameter_without_recompiling_compiled():
    path = os.path.join(DIAGRAMS, "servo.yaml")
    d = spidersim.load(path)
    r1 = d.simulate(t_end=0.2, jit=True)
    d.set("motor.R", 2.0)
    r2 = d.simulate(t_end=0.2, jit=True)
    assert r2.stats["compile_time"] == 0
    assert r2.stats["structure_key"] == r1.stats["structure_key"]
    assert np.max(np.abs(r2["motor.i"] - np.interp(r2.t, r1.t, r1["motor.i"]))) > 1e-2
    # the same as loading with the value in the first place
    r3 = spidersim.load(path, set={"motor.R": 2.0}).simulate(t_end=0.2, jit=False)
    assert len(r3.t) == len(r2.t)
    for name in r3.names:
        scale = max(np.max(np.abs(r3[name])), 1e-300)
        np.testing.assert_allclose(r2[name], r3[name], rtol=1e-9, atol=1e-9 * scale,
                                   err_msg=name)


# ---------------------------------------------------------------------------- output_interval
PULSE_LAG = """
name: pulse_lag
parameters: {tau: 0.2}
blocks:
  src: {type: Pulse, amplitude: 1, period: 0.4, duty: 0.5}
  err: {type: Sum, signs: "+-"}
  g:   {type: Gain, k: 1/tau}
  int: {type: Integrator}
connections:
  - src.y -> err.u1
  - int.y -> err.u2
  - err.y -> g.u
  - g.y -> int.u
"""


def pulse_lag_exact(t, tau=0.2, period=0.4, high=0.2):
    """Lag driven by a 0/1 pulse train, piecewise exponential through the edges."""
    out = np.empty(len(t))
    y, t0 = 0.0, 0.0
    edges = []
    k = 0
    while k * period <= t[-1] + period:
        edges += [k * period + high, (k + 1) * period]
        k += 1
    j = 0
    for i, tk in enumerate(t):
        while j < len(edges) and edges[j] <= tk:
            u = 1.0 if j % 2 == 0 else 0.0          # value before edge j
            y = u + (y - u) * math.exp(-(edges[j] - t0) / tau)
            t0 = edges[j]
            j += 1
        u = 1.0 if j % 2 == 0 else 0.0
        out[i] = u + (y - u) * math.exp(-(tk - t0) / tau)
    return out


@pytest.mark.parametrize("method", ["LSODA", "RK45", "Radau"])
def test_output_interval_grid_and_values(method):
    d = spidersim.loads(PULSE_LAG)
    rtol, atol = 1e-8, 1e-10
    dt, t_end = 0.05, 2.0
    g = d.simulate(t_end=t_end, method=method, rtol=rtol, atol=atol, output_interval=dt,
                   jit=False)
    s = d.simulate(t_end=t_end, method=method, rtol=rtol, atol=atol, jit=False)
    # on the grid, once each, ending at t_end
    k = np.arange(len(g.t))
    np.testing.assert_allclose(g.t, k * dt, rtol=0, atol=1e-12)
    assert len(g.t) == round(t_end / dt) + 1 and g.t[-1] == pytest.approx(t_end)
    assert np.all(np.diff(g.t) > 0)
    # dense-output values as accurate as the steps
    assert ratio(g["int.y"], pulse_lag_exact(g.t), rtol, atol) < BOUND
    assert ratio(s["int.y"], pulse_lag_exact(s.t), rtol, atol) < BOUND
    # shared times (0, every pulse edge at 0.2 k, t_end): the same state
    shared = [(i, j) for i, tg in enumerate(g.t) for j in np.flatnonzero(np.abs(s.t - tg)
                                                                       < 1e-12)]
    assert len({i for i, _ in shared}) == 11
    for i, j in shared:
        assert abs(g["int.y"][i] - s["int.y"][j]) < atol + rtol, (g.t[i], method)


def test_output_interval_not_a_multiple():
    d = spidersim.loads(LAG)
    g = d.simulate(t_end=1.0, output_interval=0.3, rtol=1e-8, atol=1e-10, jit=False)
    np.testing.assert_allclose(g.t, [0.0, 0.3, 0.6, 0.9, 1.0], rtol=0, atol=1e-12)
    assert ratio(g["int.y"], 1 - np.exp(-g.t / TAU), 1e-8, 1e-10) < BOUND


def test_output_interval_sample_at_an_event_time_is_post_event():
    """Guards the output grid at a time event: a grid time that falls on a time event is
    recorded after the event is applied, so a Step's output there is ``after`` (the block
    defines y = after from t_step on), like the step-based output (whose last sample at that
    time is post-event) and the grid sample at t = 0. (It was once recorded before.)"""
    text = LAG.replace("t_step: 0.0", "t_step: 0.25")
    d = spidersim.loads(text)
    s = d.simulate(t_end=0.5, rtol=1e-8, atol=1e-10, jit=False)
    at = np.flatnonzero(np.abs(s.t - 0.25) < 1e-12)
    assert s["step.y"][at[-1]] == 1.0
    g = d.simulate(t_end=0.5, rtol=1e-8, atol=1e-10, output_interval=0.05, jit=False)
    i = int(np.flatnonzero(np.abs(g.t - 0.25) < 1e-12)[0])
    assert g["step.y"][i - 1] == 0.0
    assert g["step.y"][i] == 1.0, "grid sample at the step time shows the pre-step value"
    assert g["err.y"][i] == pytest.approx(s["err.y"][at[-1]])


BALL = """
name: ball
blocks:
  ball: {type: MassOnStop, m: 1, g: 9.81, e: 0.8, x0: 10, v_rest: 0.05}
"""


def ball_exact(t, h=10.0, g=9.81, e=0.8):
    """Height of the ball through its first two impacts."""
    t1 = math.sqrt(2 * h / g)
    v1 = e * g * t1
    t2 = t1 + 2 * v1 / g
    v2 = e * v1
    return np.where(t < t1, h - 0.5 * g * t ** 2,
                    np.where(t < t2, v1 * (t - t1) - 0.5 * g * (t - t1) ** 2,
                             v2 * (t - t2) - 0.5 * g * (t - t2) ** 2))


def test_output_interval_grid_with_state_events():
    """Regression: a run that asks for a uniform grid gets no off-grid sample at a located
    zero crossing (the impacts at 1.428 s and 3.712 s), and the grid values match the
    step-based run."""
    d = spidersim.loads(BALL)
    rtol, atol, dt, t_end = 1e-10, 1e-12, 0.05, 4.0
    s = d.simulate(t_end=t_end, method="DOP853", rtol=rtol, atol=atol, jit=False)
    g = d.simulate(t_end=t_end, method="DOP853", rtol=rtol, atol=atol, output_interval=dt,
                   jit=False)
    assert [e[2] for e in g.events] == ["impact", "impact"]
    # values: as accurate on the grid as at the steps (measured 4e-12 at the steps)
    assert ratio(s["ball.x"], ball_exact(s.t), rtol, atol) < BOUND
    assert ratio(g["ball.x"], ball_exact(g.t), rtol, atol) < BOUND
    assert g["ball.x"][-1] == pytest.approx(s["ball.x"][-1], abs=atol + rtol * 10)
    # times: on the grid
    k = np.round(g.t / dt)
    off = g.t[np.abs(g.t - k * dt) > 1e-12]
    assert len(off) == 0, f"off-grid samples at {off}"
    np.testing.assert_allclose(g.t, np.arange(len(g.t)) * dt, rtol=0, atol=1e-12)
