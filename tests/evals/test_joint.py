"""One SPIDER joint against independent calculations: brushless motor and NRPI driver
(torque equation, power balance, ripple lines), LuGre friction (steady state, pre-sliding,
the 1995 stick-slip case, rate-dependent break-away), Harmonic Drive (stiffness laws,
backlash and its events) and the whole joint (step tracking, linearized resonance).

Parameters are PHYSICS.md's SPIDER-like values. The runs of small benches are interpreted
(``jit=False``: a compile per structure would cost more than the run); the runs of the
whole joint (the two steps, stiff LuGre friction, 2.5 s, and the 4 s holds of the
quantization limit cycle) run compiled, and one compiled-vs-interpreted
comparison checks the compiled code against the interpreter.

Reference numbers the tests compute themselves (and the measured values at the time of
writing, for the record):

* ripple at 955 rpm: f_e = 7 * 955 / 60 = 111.42 Hz. With an ideal current source the lines
  are the motor block's nominal ones: offset K_t * 0.03 = 4.5e-3 N.m at f_e, unbalance
  K_t I 0.015 / 2 = 2.25e-3 N.m at 2 f_e, h3 K_t I 0.008 = 2.4e-3 N.m at 4 f_e. With the
  NRPI driver (2 kHz PI loops) the BEMF at f_e and 3 f_e is only partly rejected: the mean
  torque is 0.2568 N.m instead of 0.3 N.m, the unbalance line 1.859e-3 (-17 %) and the h3
  line 1.472e-3 (-39 %); the offset line stays 4.500e-3 (integral action rejects a DC
  sensor offset completely). The NRPI values are checked against a phasor model of the two
  PI loops (per-phase LTI at constant speed), not against the nominal ones.
* joint 2 resonance: antiresonance (motor locked) sqrt(K1/J_l)/2pi = 9.00 Hz, resonance
  (motor free) sqrt(K1 (1/J_l + 1/(N^2 J_m)))/2pi = 24.80 Hz; measured 8.997 / 24.68 Hz.

The backlash tests (test_backlash_events_over_a_cycle, test_backlash_slow_reversal_two_events)
also guard a fixed block bug: HarmonicDrive.initialize, which the engine runs after every
event, put the gear back in contact whenever |delta| > b/2. At a separation delta is still
beyond b/2 (by d |ddelta/dt| / K1), so contact was re-entered at once and the gear pulled
through the whole gap. It now engages only where the contact torque would push.
test_backlash_contact_lost_by_damping_returns_past_the_edge and
test_motor_pushing_a_load_through_backlash_stays_engaged guard the converse (found by a
review): teeth parted by the damper while still past b/2 never touched again, since the
gap's guard watched only the deflection crossing b/2.
"""
from __future__ import annotations

import math
import os

import numpy as np
import pytest
import scipy.linalg as sla
from scipy.optimize import brentq

import spidersim

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _load_harness():
    """tests/blocks/harness.py by path (tests/ is not a package)."""
    import importlib.util
    spec = importlib.util.spec_from_file_location(
        "_spidersim_test_harness", os.path.join(ROOT, "tests", "blocks", "harness.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


Probe = _load_harness().Probe
DIAGRAMS = os.path.join(ROOT, "diagrams")

# ----------------------------------------------------------------------------- motor data
P, R, L, K_T = 7, 1.5, 1.5e-3, 0.15
I_CMD = 2.0
RPM = 955.0
W0 = 2 * math.pi * RPM / 60          # mechanical speed [rad/s]
WE = P * W0                          # electrical angular frequency [rad/s]
FE = WE / (2 * math.pi)              # 111.42 Hz
KP, KI = L * 2 * math.pi * 2000, R * 2 * math.pi * 2000      # NRPI gains, 2 kHz loops
SPP = 64                             # samples per electrical period
T_SKIP = 0.03                        # transient: slowest current mode exp(-R/L t) = 1e-13
N_PER = 20                           # electrical periods analysed


def fourier(r, signal, n_per=N_PER, spp=SPP, t_skip=T_SKIP, kmax=6):
    """Amplitudes of harmonics 0..kmax of f_e in ``signal``, by sin/cos projection over
    ``n_per`` whole electrical periods of a uniform grid (``output_interval = 1/(spp f_e)``)
    starting at the first grid point after ``t_skip``. Exact for harmonics below spp/2."""
    t, y = r.t, r[signal]
    dt = 1.0 / (spp * FE)
    assert np.allclose(np.diff(t[:10]), dt, rtol=1e-9)     # the uniform grid asked for
    i0 = int(np.searchsorted(t, t_skip))
    n = n_per * spp
    tt, yy = t[i0:i0 + n], y[i0:i0 + n]
    assert len(tt) == n
    amps = [abs(yy.mean())]
    for k in range(1, kmax + 1):
        c = 2.0 / n * np.sum(yy * np.cos(2 * np.pi * k * FE * tt))
        s = 2.0 / n * np.sum(yy * np.sin(2 * np.pi * k * FE * tt))
        amps.append(math.hypot(c, s))
    return np.array(amps), yy


def _ripple_run(text, n_per=N_PER):
    d = spidersim.loads(text)
    return d.simulate(t_end=T_SKIP + (n_per + 1) / FE, rtol=1e-10, atol=1e-12, method="LSODA",
                      output_interval=1.0 / (SPP * FE), jit=False)


def nrpi_bench(offset=0.0, unbalance=0.0, h3=0.0, J=1.0e4):
    """NRPI driver commanding I_CMD into the motor spinning at 955 rpm on a flywheel J."""
    return f"""
name: bench
blocks:
  cmd:    {{type: Constant, value: {I_CMD}}}
  driver: {{type: NRPIDriver, kp: {KP}, ki: {KI}, offset_a: {offset}}}
  motor:  {{type: BrushlessMotor, p: {P}, R: {R}, L: {L}, K_t: {K_T}, J: {J}, w0: {W0},
           h3: {h3}, unbalance: {unbalance}}}
connections:
  - cmd.y -> driver.i_cmd
  - motor.theta_e -> driver.theta_e
  - motor.i_a -> driver.i_a
  - motor.i_b -> driver.i_b
  - driver.v_a -> motor.v_a
  - driver.v_b -> motor.v_b
log: [motor.tau, motor.w, motor.i_a, motor.i_b, motor.theta_e]
"""


def ideal_source_bench(unbalance=0.0, h3=0.0):
    """Ideal current source: phase voltages v = R i* + L di*/dt + bemf with
    i_a* = -I sin(w_e t), i_b* = I cos(w_e t) (the BEMF fed forward from the motor's own
    bemf outputs), so that i -> i* exactly (error decays as exp(-R t / L)). The flywheel
    J = 1e6 is loaded by K_t I, the mean torque, so that the speed stays 955 rpm and the
    rotor angle follows the sources' w_e t (the start-up transient would otherwise leave
    a ~1e-5 rad lag on a light flywheel)."""
    z = I_CMD * math.hypot(R, L * WE)
    ph = math.atan2(L * WE, R)
    return f"""
name: ideal
blocks:
  ua:    {{type: Sine, amplitude: {-z}, f: {FE}, phase: {ph}}}
  ub:    {{type: Sine, amplitude: {z}, f: {FE}, phase: {ph + math.pi / 2}}}
  va:    {{type: Sum, signs: "++"}}
  vb:    {{type: Sum, signs: "++"}}
  motor: {{type: BrushlessMotor, p: {P}, R: {R}, L: {L}, K_t: {K_T}, J: 1.0e6, w0: {W0},
          h3: {h3}, unbalance: {unbalance}}}
  bench: {{type: Constant, value: {K_T * I_CMD}}}
connections:
  - ua.y -> va.u1
  - motor.bemf_a -> va.u2
  - ub.y -> vb.u1
  - motor.bemf_b -> vb.u2
  - va.y -> motor.v_a
  - vb.y -> motor.v_b
  - bench.y -> motor.tau_load
log: [motor.tau, motor.i_a, motor.i_b, motor.theta_e, motor.w]
"""


def phasor_model(offset=0.0, unbalance=0.0, h3=0.0, n=256):
    """Steady-state torque harmonics (amplitudes, k = 0..6) with the NRPI loops, computed in
    the frequency domain: at constant speed each phase is LTI,
    ``i = H(s) (i* - offset) - Q(s) bemf`` with ``C = kp + ki/s``, ``H = C/(Ls+R+C)``,
    ``Q = 1/(Ls+R+C)``; the torque ``K_a f_a i_a + K_b f_b i_b`` is then sampled on a
    theta_e grid and Fourier-analysed."""
    def C(s):
        return KP + KI / s

    def H(w):
        s = 1j * w
        return C(s) / (L * s + R + C(s))

    def Q(w):
        s = 1j * w
        return 1.0 / (L * s + R + C(s))

    ka, kb = K_T * (1 + unbalance / 2), K_T * (1 - unbalance / 2)
    th = 2 * np.pi * np.arange(n) / n
    e1, e3 = np.exp(1j * th), np.exp(3j * th)
    ia = np.imag((-I_CMD * H(WE) + ka * W0 * Q(WE)) * e1 + ka * W0 * h3 * Q(3 * WE) * e3)
    ia -= offset                                      # H(0) = 1: the offset passes fully
    ib = np.real((I_CMD * H(WE) - kb * W0 * Q(WE)) * e1 + kb * W0 * h3 * Q(3 * WE) * e3)
    fa = -np.sin(th) - h3 * np.sin(3 * th)
    fb = np.cos(th) - h3 * np.cos(3 * th)
    tau = ka * fa * ia + kb * fb * ib
    c = np.fft.rfft(tau) / n
    return np.r_[abs(c[0]), 2 * abs(c[1:7])]


# ============================================================================= motor
@pytest.mark.parametrize("h3,unbalance,tau_cog", [(0, 0, 0), (0.008, 0, 0), (0, 0.015, 0),
                                                  (0.008, 0.015, 0.004)])
def test_torque_equation_with_commutated_currents(h3, unbalance, tau_cog):
    """Probe: with i_a = -I sin(theta_e), i_b = I cos(theta_e) the torque output is
    K_t I (1 - (unbalance/2)(1 - h3) cos 2theta_e - h3 cos 4theta_e) + tau_cog sin 2theta_e
    (the h3 unbalance cross term from sin.sin3 + cos.cos3 = cos 2theta_e), and exactly
    K_t I without imperfections, at every rotor angle."""
    p = Probe("BrushlessMotor", dict(p=P, R=R, L=L, K_t=K_T, h3=h3, unbalance=unbalance,
                                     tau_cog=tau_cog))
    for th_e in np.linspace(0, 2 * np.pi, 37):
        x = p.x0()
        p.set_state(x, "theta", th_e / P)
        p.set_state(x, "i_a", -I_CMD * math.sin(th_e))
        p.set_state(x, "i_b", I_CMD * math.cos(th_e))
        p.set_state(x, "w", W0)
        out = p.outputs(0.0, x)
        exp = K_T * I_CMD * (1 - unbalance / 2 * (1 - h3) * math.cos(2 * th_e)
                             - h3 * math.cos(4 * th_e))
        exp += tau_cog * math.sin(2 * th_e)
        assert out["tau"][0] == pytest.approx(exp, rel=1e-13, abs=1e-15)
        assert out["theta_e"][0] == pytest.approx(th_e, rel=1e-14, abs=1e-15)
        # and the electrical equation: L di/dt = v - R i - bemf, bemf = K_a w f_a
        ka = K_T * (1 + unbalance / 2)
        fa = -math.sin(th_e) - h3 * math.sin(3 * th_e)
        assert out["bemf_a"][0] == pytest.approx(ka * W0 * fa, rel=1e-13, abs=1e-13)
        der = p.derivatives(0.0, x)
        assert der["i_a"][0] == pytest.approx((0 - R * x[p.state_slice("i_a")][0]
                                               - ka * W0 * fa) / L, rel=1e-12)


def test_nrpi_constant_torque_without_imperfections():
    """NRPI at constant amplitude, 955 rpm, no imperfections: the torque is constant
    (std/mean < 1e-6 after the transient) and its value is the phasor model's, below
    K_t I because the BEMF at f_e is only partly rejected by the 2 kHz PI loops."""
    r = _ripple_run(nrpi_bench())
    amps, y = fourier(r, "motor.tau")
    assert np.std(y) / np.mean(y) < 1e-6, np.std(y) / np.mean(y)
    model = phasor_model()
    assert np.mean(y) == pytest.approx(model[0], rel=1e-6)    # 0.25682 N.m (1e-8)
    assert 0.8 * K_T * I_CMD < np.mean(y) < 0.9 * K_T * I_CMD
    # currents: amplitude sqrt(i_a^2 + i_b^2) constant (a balanced two-phase set)
    i0 = int(np.searchsorted(r.t, T_SKIP))
    mag = np.hypot(r["motor.i_a"][i0:], r["motor.i_b"][i0:])
    assert np.std(mag) / np.mean(mag) < 1e-6


@pytest.mark.parametrize("case", ["none", "unbalance", "h3", "all"])
def test_ideal_current_source_gives_nominal_lines(case):
    """With the currents forced to -I sin, I cos: torque = K_t I exactly without
    imperfections, and the nominal lines K_t I unbalance/2 at 2 f_e, K_t I h3 at 4 f_e."""
    ub = 0.015 if case in ("unbalance", "all") else 0.0
    h3 = 0.008 if case in ("h3", "all") else 0.0
    r = _ripple_run(ideal_source_bench(unbalance=ub, h3=h3))
    i0 = int(np.searchsorted(r.t, T_SKIP))
    te = r["motor.theta_e"][i0:]
    np.testing.assert_allclose(r["motor.i_a"][i0:], -I_CMD * np.sin(te), atol=1e-8 * I_CMD)
    np.testing.assert_allclose(r["motor.i_b"][i0:], I_CMD * np.cos(te), atol=1e-8 * I_CMD)
    amps, y = fourier(r, "motor.tau")
    assert amps[0] == pytest.approx(K_T * I_CMD, rel=1e-9)
    expected = np.zeros(7)
    expected[2] = K_T * I_CMD * ub / 2 * (1 - h3)       # (with the small cross term)
    expected[4] = K_T * I_CMD * h3
    np.testing.assert_allclose(amps[1:], expected[1:], rtol=1e-6, atol=1e-9 * K_T * I_CMD)
    # and point by point, with the phases: the Probe's torque law on the rotor angle
    te = te[:len(y)]
    law = K_T * I_CMD * (1 - ub / 2 * (1 - h3) * np.cos(2 * te) - h3 * np.cos(4 * te))
    np.testing.assert_allclose(y, law, rtol=0, atol=1e-9 * K_T * I_CMD)
    if case == "none":
        assert np.std(y) / np.mean(y) < 1e-9           # measured 2e-11


@pytest.mark.parametrize("name,kw,k", [("offset", dict(offset=0.03), 1),
                                       ("unbalance", dict(unbalance=0.015), 2),
                                       ("h3", dict(h3=0.008), 4)])
def test_nrpi_single_imperfection_line(name, kw, k):
    """Each imperfection alone, NRPI driver at 955 rpm: one torque line at k f_e (offset
    f_e = 111.4 Hz, unbalance 2 f_e, h3 4 f_e), every other harmonic k = 1..6 below 1e-5 of
    it (the brief asks 1e-3; measured < 1.3e-7); its amplitude equals the phasor model's to
    1e-6 (the simulation is a time-domain solution of the same LTI loops; measured < 2e-8).
    The offset line is K_t * offset to 1e-6: the PI's integral action rejects a DC sensor
    offset completely, so the finite current-loop bandwidth does not reduce it at all (only
    the amplitude of the commutated fundamental and the rejection of the BEMF depend on
    it). The
    unbalance and h3 lines are *not* the nominal K_t I unbalance/2 and K_t I h3 with this
    driver: the partly rejected BEMF (at f_e, and at 3 f_e for h3) lowers them by 17 % and
    39 % (asserted as ranges; the nominal values are reached with an ideal current source,
    test_ideal_current_source_gives_nominal_lines)."""
    r = _ripple_run(nrpi_bench(**kw))
    amps, _ = fourier(r, "motor.tau")
    main = amps[k]
    others = np.delete(amps[1:], k - 1)
    assert np.all(others < 1e-5 * main), (amps, k)
    model = phasor_model(**kw)
    assert main == pytest.approx(model[k], rel=1e-6)
    if name == "offset":
        assert main == pytest.approx(K_T * kw["offset"], rel=1e-6)
        # with its sign: i_a = i_a* - offset adds -K_t f_a offset = +K_t offset sin(theta_e)
        i0 = int(np.searchsorted(r.t, T_SKIP))
        n = N_PER * SPP
        te, y = r["motor.theta_e"][i0:i0 + n], r["motor.tau"][i0:i0 + n]
        y = y - y.mean()
        assert 2 / n * np.sum(y * np.sin(te)) == pytest.approx(K_T * kw["offset"], rel=1e-6)
        assert abs(2 / n * np.sum(y * np.cos(te))) < 1e-6 * K_T * kw["offset"]
    elif name == "unbalance":
        nominal = K_T * I_CMD * kw["unbalance"] / 2
        assert 0.78 * nominal < main < 0.88 * nominal         # measured 0.826
    else:
        nominal = K_T * I_CMD * kw["h3"]
        assert 0.55 * nominal < main < 0.67 * nominal         # measured 0.613


def test_power_balance_with_all_imperfections():
    """int (v_a i_a + v_b i_b) dt = int R (i_a^2 + i_b^2) dt + L (i_a^2 + i_b^2)/2
    + int (tau - cogging) w dt, integrated by Integrator blocks, during a run from rest
    (voltage saturation at the start) with offset, gain error, unbalance, h3 and cogging."""
    tau_cog = 0.01
    text = f"""
name: power
blocks:
  cmd:    {{type: Constant, value: {I_CMD}}}
  driver: {{type: NRPIDriver, kp: {KP}, ki: {KI}, offset_a: 0.03, offset_b: -0.01,
           gain_a: 0.02}}
  motor:  {{type: BrushlessMotor, p: {P}, R: {R}, L: {L}, K_t: {K_T}, J: 2.0e-3, b: 1e-4,
           h3: 0.008, unbalance: 0.015, tau_cog: {tau_cog}}}
  load:   {{type: Constant, value: 0.1}}
  pa:     {{type: Product}}
  pb:     {{type: Product}}
  pin:    {{type: Sum, signs: "++"}}
  ein:    {{type: Integrator}}
  qa:     {{type: Product}}
  qb:     {{type: Product}}
  i2:     {{type: Sum, signs: "++"}}
  pr:     {{type: Gain, k: {R}}}
  er:     {{type: Integrator}}
  two:    {{type: Gain, k: 2.0}}
  s2:     {{type: Function, fn: sin}}
  cog:    {{type: Gain, k: {tau_cog}}}
  tem:    {{type: Sum, signs: "+-"}}
  pm:     {{type: Product}}
  em:     {{type: Integrator}}
connections:
  - cmd.y -> driver.i_cmd
  - motor.theta_e -> driver.theta_e, two.u
  - motor.i_a -> driver.i_a, pa.u2, qa.u1, qa.u2
  - motor.i_b -> driver.i_b, pb.u2, qb.u1, qb.u2
  - driver.v_a -> motor.v_a, pa.u1
  - driver.v_b -> motor.v_b, pb.u1
  - load.y -> motor.tau_load
  - pa.y -> pin.u1
  - pb.y -> pin.u2
  - pin.y -> ein.u
  - qa.y -> i2.u1
  - qb.y -> i2.u2
  - i2.y -> pr.u
  - pr.y -> er.u
  - two.y -> s2.u
  - s2.y -> cog.u
  - motor.tau -> tem.u1
  - cog.y -> tem.u2
  - tem.y -> pm.u1
  - motor.w -> pm.u2
  - pm.y -> em.u
log: [ein.y, er.y, em.y, i2.y, motor.w, driver.v_a, driver.v_b]
"""
    rtol, atol = 1e-9, 1e-12
    r = spidersim.loads(text).simulate(t_end=0.3, rtol=rtol, atol=atol, method="LSODA",
                                       jit=False)
    assert np.max(np.abs(r["driver.v_b"])) == pytest.approx(28.0)    # saturated at start
    assert r["motor.w"][-1] > 20.0
    resid = r["ein.y"] - r["er.y"] - L * r["i2.y"] / 2 - r["em.y"]
    scale = np.max(np.abs(r["ein.y"]))
    assert scale > 1.0
    assert r["em.y"][-1] > 0.1 * scale                # a real share goes to the shaft
    assert np.max(np.abs(resid)) / scale < 5 * rtol, np.max(np.abs(resid)) / scale   # 6.5e-10


# ============================================================================= LuGre
MOTOR_LUGRE = dict(T_c=0.05, T_s=0.07, v_s=1.0, delta=2.0, sigma0=80.0, sigma1=0.1, D=2e-4)
PAPER_LUGRE = dict(T_c=1.0, T_s=1.5, v_s=1e-3, delta=2.0, sigma0=1e5,
                   sigma1=math.sqrt(1e5), D=0.4)


def _g(v, T_c, T_s, v_s, delta, **_):
    return T_c + (T_s - T_c) * math.exp(-abs(v / v_s) ** delta)


def _yaml_params(prm):
    return ", ".join(f"{k}: {v!r}" for k, v in prm.items())


@pytest.mark.parametrize("prm,vs", [(MOTOR_LUGRE, [0.05, -0.3, 1.0, -1.0, 2.5, -8.0]),
                                    (PAPER_LUGRE, [2e-4, -1e-3, 3e-3, -0.05])])
def test_lugre_steady_state_friction(prm, vs):
    """Constant v: after the transient tau = g(v) sgn(v) + D v (1e-9 relative); the bristle
    deflection is g(v) sgn(v)/sigma0."""
    for v in vs:
        rate = prm["sigma0"] * abs(v) / _g(v, **prm)         # z converges as exp(-rate t)
        text = f"""
name: lugre_ss
blocks:
  v: {{type: Constant, value: {v!r}}}
  f: {{type: LuGre, {_yaml_params(prm)}}}
connections:
  - v.y -> f.v
"""
        r = spidersim.loads(text).simulate(t_end=35.0 / rate, rtol=1e-10,
                                           atol=1e-12 * prm["T_c"] / prm["sigma0"],
                                           method="LSODA", jit=False)
        exp = _g(v, **prm) * math.copysign(1.0, v) + prm["D"] * v
        assert r["f.tau"][-1] == pytest.approx(exp, rel=1e-9), v     # measured < 3e-14
        assert r["f.z"][-1] == pytest.approx(_g(v, **prm) * math.copysign(1, v)
                                             / prm["sigma0"], rel=1e-9)


MASS_LUGRE = """
name: mass_lugre
blocks:
  force: {force}
  net:   {{type: Sum, signs: "+-"}}
  mass:  {{type: Inertia, J: 1.0}}
  fric:  {{type: LuGre, {prm}}}
connections:
  - force.y -> net.u1
  - fric.tau -> net.u2
  - net.y -> mass.tau
  - mass.w -> fric.v
"""


@pytest.mark.parametrize("F,tol", [(0.5, 0.01), (0.9, 0.01), (1.2, 0.02)])
def test_lugre_presliding_micro_displacement(F, tol):
    """Unit mass (1995 parameters), force ramped slowly to F < F_s over 2 s, held 2 s,
    ramped back to 0 over 2 s, held: no sliding (|v| << v_s), a bounded displacement of the
    order of F/sigma0. Quasi-statically F = sigma0 z and dz/dx = 1 - sigma0 z sgn(v)/g with
    g ~ F_s (|v| << v_s), so after loading x1 = -(F_s/sigma0) ln(1 - F/F_s), and after
    unloading the mass keeps x2 = -(F_s/sigma0) ln(1 - (F/F_s)^2): the LuGre bristle
    hysteresis does not return the mass to 0 (x2/x1 = 0.29 at F = 0.5, 0.56 at 1.2)."""
    prm = PAPER_LUGRE
    force = f"{{type: TimeTable, time: [0, 2, 4, 6, 8], value: [0, {F}, {F}, 0, 0]}}"
    r = spidersim.loads(MASS_LUGRE.format(force=force, prm=_yaml_params(prm))).simulate(
        t_end=8.0, rtol=1e-9, atol=1e-13, method="LSODA", output_interval=0.01, jit=False)
    t, x, w = r.t, r["mass.phi"], r["mass.w"]
    s0, fs = prm["sigma0"], prm["T_s"]
    x1 = -(fs / s0) * math.log(1 - F / fs)
    x2 = -(fs / s0) * math.log(1 - (F / fs) ** 2)
    assert np.max(np.abs(w)) < 0.05 * prm["v_s"]
    assert x[np.searchsorted(t, 4.0)] == pytest.approx(x1, rel=tol)
    assert np.max(np.abs(x)) < 1.01 * x1
    assert x1 < 2.2 * F / s0                               # micro-displacement ~ F/sigma0
    assert x[-1] == pytest.approx(x2, rel=tol)
    assert 0 < x[-1] < x1                                  # it comes back, partly
    # held load: no creep between t = 3 and 4 s
    i3, i4 = np.searchsorted(t, 3.0), np.searchsorted(t, 4.0)
    assert abs(x[i4] - x[i3]) < 1e-4 * x1


def _crossings_up(t, y, thr):
    i = np.flatnonzero((y[:-1] < thr) & (y[1:] >= thr))
    return t[i] + (thr - y[i]) * (t[i + 1] - t[i]) / (y[i + 1] - y[i]), i


def test_stick_slip_1995():
    """diagrams/lugre_stick_slip.yaml run to 45 s: periodic stick-slip, several cycles, the
    velocity back near 0 (stuck for seconds) in every cycle, period stable to 1 %,
    break-away spring force near F_s = 1.5 (measured 1.487, period 6.363 s)."""
    d = spidersim.load(os.path.join(DIAGRAMS, "lugre_stick_slip.yaml"))
    r = d.simulate(t_end=45.0, output_interval=2e-3, jit=False)
    t, w, F = r.t, r["mass.w"], r["spring.y"]
    thr = 1e-3                                            # = v_s
    t_up, idx = _crossings_up(t, w, thr)
    assert len(t_up) >= 5
    periods = np.diff(t_up)
    assert np.ptp(periods) < 0.01 * np.mean(periods), periods
    f_break = F[idx]
    assert np.all((f_break > 1.0) & (f_break < 1.6)), f_break
    assert np.all(np.abs(f_break - 1.5) < 0.05), f_break
    for a, b in zip(t_up[:-1], t_up[1:]):
        seg = (t > a) & (t < b)
        assert w[seg].max() > 100 * thr                  # it slips ...
        stuck = seg & (np.abs(w) < thr)
        assert np.count_nonzero(stuck) * 2e-3 > 0.3 * (b - a)   # ... and sticks
        assert np.min(np.abs(w[seg])) < 1e-5
    # spring force during slip drops well below the break-away force
    assert F[t > t_up[0]].min() < 1.0


def test_breakaway_force_decreases_with_force_rate():
    """F = rate t on a unit mass with LuGre (1995 parameters), rates 0.1, 1, 10 N/s;
    break-away force = F when the velocity first exceeds v_s = 1e-3 m/s. It decreases
    strictly with the rate (measured 1.492, 1.461, 1.307 N) and tends to F_s at low rate."""
    prm = PAPER_LUGRE
    fb = []
    for rate in (0.1, 1.0, 10.0):
        force = f"{{type: Ramp, slope: {rate}}}"
        r = spidersim.loads(MASS_LUGRE.format(force=force, prm=_yaml_params(prm))).simulate(
            t_end=2.0 / rate, rtol=1e-9, atol=1e-12, method="LSODA", max_step=2e-3 / rate,
            jit=False)
        t_up, _ = _crossings_up(r.t, r["mass.w"], prm["v_s"])
        assert len(t_up) >= 1
        fb.append(rate * t_up[0])
    assert fb[0] > fb[1] > fb[2], fb
    assert fb[0] == pytest.approx(prm["T_s"], abs=0.02)
    assert all(prm["T_c"] < f <= prm["T_s"] for f in fb), fb
    assert fb[0] - fb[2] > 0.1                              # a real effect, not noise


# ============================================================================= gearbox
GEAR = dict(ratio=160.0, K1=5.4e4, K2=7.8e4, K3=1.1e5, T1=29.0, T2=108.0, d=20.0)


def _gear_probe(**kw):
    prm = dict(GEAR, friction=False)
    prm.update(kw)
    return Probe("HarmonicDrive", prm)


def _gear_out(p, phi, phi_l=0.0, w_m=0.0, w_l=0.0):
    p.set_input("phi_m", GEAR["ratio"] * phi)
    p.set_input("phi_l", phi_l)
    p.set_input("w_m", w_m)
    p.set_input("w_l", w_l)
    p.initialize(0.0)
    return {k: v[0] for k, v in p.outputs(0.0).items()}


def test_linear_static_stiffness():
    """phi_l = 0, phi_m = N phi: tau_l = K1 phi, tau_m = tau_l / N, deflection = phi;
    the damping term d (w_m/N - w_l) adds."""
    p = _gear_probe()
    for phi in (-3e-3, -1e-4, 0.0, 2e-5, 1e-3, 5e-3):
        o = _gear_out(p, phi)
        assert o["tau_l"] == pytest.approx(GEAR["K1"] * phi, rel=1e-12, abs=1e-12)
        assert o["tau_m"] == pytest.approx(o["tau_l"] / GEAR["ratio"], rel=1e-12, abs=1e-14)
        assert o["deflection"] == pytest.approx(phi, rel=1e-12, abs=1e-18)
        assert o["tau_f"] == 0.0
    o = _gear_out(p, 1e-3, phi_l=4e-4, w_m=160.0 * 0.3, w_l=0.1)
    assert o["tau_l"] == pytest.approx(GEAR["K1"] * 6e-4 + GEAR["d"] * 0.2, rel=1e-12)


def _catalogue_phi(T):
    """PHYSICS.md's phi(T) (the catalogue's direction), odd in T."""
    K1, K2, K3, T1, T2 = (GEAR[k] for k in ("K1", "K2", "K3", "T1", "T2"))
    a = abs(T)
    if a <= T1:
        ph = a / K1
    elif a <= T2:
        ph = T1 / K1 + (a - T1) / K2
    else:
        ph = T1 / K1 + (T2 - T1) / K2 + (a - T2) / K3
    return math.copysign(ph, T)


def test_three_slope_stiffness():
    """stiffness: three_slope: tau_l at the catalogue deflection phi(T) is T in each of the
    three ranges (both signs); the local slopes are K1, K2, K3; continuous at T1 and T2."""
    p = _gear_probe(stiffness="three_slope")
    for T in (5.0, 29.0, 60.0, 108.0, 150.0, 400.0, -12.0, -80.0, -250.0):
        o = _gear_out(p, _catalogue_phi(T))
        assert o["tau_l"] == pytest.approx(T, rel=1e-12)
    h = 1e-9
    for T, k in ((15.0, "K1"), (70.0, "K2"), (200.0, "K3"), (-70.0, "K2")):
        ph = _catalogue_phi(T)
        slope = (_gear_out(p, ph + h)["tau_l"] - _gear_out(p, ph - h)["tau_l"]) / (2 * h)
        assert slope == pytest.approx(GEAR[k], rel=1e-5)
    for T in (GEAR["T1"], GEAR["T2"], -GEAR["T1"], -GEAR["T2"]):
        ph = _catalogue_phi(T)
        lo, hi = _gear_out(p, ph * (1 - 1e-12))["tau_l"], _gear_out(p, ph * (1 + 1e-12))["tau_l"]
        assert abs(hi - lo) < 1e-12 * 1.2e5 * abs(ph) * 2 + 1e-12
        assert lo == pytest.approx(T, rel=1e-9) and hi == pytest.approx(T, rel=1e-9)


def test_backlash_static():
    """Backlash b: inside the gap tau_l == 0 exactly (and tau_m == 0 without friction),
    whatever the speeds; beyond +-b/2 the teeth are in contact: tau_l = K1 (delta -+ b/2)."""
    b = 2.9e-4
    p = _gear_probe(backlash=b)
    for de in (-0.999 * b / 2, -1e-5, 0.0, 3e-5, 0.999 * b / 2):
        p.set_mode("contact", 0.0)
        o = _gear_out(p, de, w_m=5.0, w_l=-0.01)
        assert p.mode("contact")[0] == 0.0
        assert o["tau_l"] == 0.0 and o["tau_m"] == 0.0
    for de in (b / 2 + 1e-5, 1e-3, -b / 2 - 2e-5, -2e-3):
        p.set_mode("contact", 0.0)
        o = _gear_out(p, de)
        assert p.mode("contact")[0] == math.copysign(1.0, de)
        assert o["tau_l"] == pytest.approx(GEAR["K1"] * (de - math.copysign(b / 2, de)),
                                           rel=1e-9)


BACKLASH_SWEEP = """
name: sweep
blocks:
  pm:   {{type: Sine, amplitude: {amp}, f: {f}, phase: {phase}}}
  wm:   {{type: Sine, amplitude: {wamp}, f: {f}, phase: {wphase}}}
  phi0: {{type: Constant, value: 0}}
  w0:   {{type: Constant, value: 0}}
  gear: {{type: HarmonicDrive, ratio: {N}, K1: {K1}, d: {d}, backlash: {b}, friction: false}}
connections:
  - pm.y -> gear.phi_m
  - wm.y -> gear.w_m
  - phi0.y -> gear.phi_l
  - w0.y -> gear.w_l
"""
B_GAP = 2.9e-4
A_SWEEP = 4e-4          # output-side amplitude of phi_m / N (> b/2)
F_SWEEP = 0.5


def _sweep(phase, t_end):
    """phi_m / N = A sin(w t + phase) against a fixed load (phi_l = w_l = 0)."""
    N, w = GEAR["ratio"], 2 * math.pi * F_SWEEP
    text = BACKLASH_SWEEP.format(amp=N * A_SWEEP, f=F_SWEEP, phase=phase,
                                 wamp=N * A_SWEEP * w, wphase=phase + math.pi / 2, N=N,
                                 K1=GEAR["K1"], d=GEAR["d"], b=B_GAP)
    return spidersim.loads(text).simulate(t_end=t_end, rtol=1e-10, atol=1e-14,
                                          output_interval=1e-3, jit=False)


def _separation_time(t_lo, t_hi, phase, side):
    """Root of the contact torque K1 (delta - side b/2) + d ddelta/dt."""
    w = 2 * math.pi * F_SWEEP

    def ts(t):
        de = A_SWEEP * math.sin(w * t + phase)
        return GEAR["K1"] * (de - side * B_GAP / 2) + GEAR["d"] * A_SWEEP * w * math.cos(
            w * t + phase)
    return brentq(ts, t_lo, t_hi, xtol=1e-14)


def test_backlash_events_over_a_cycle():
    """A full cycle from the middle of the gap: contact at +b/2, separation (where the
    contact torque K1 (delta - b/2) + d ddelta/dt reaches 0), contact at -b/2, separation:
    four events at the analytic times; tau_l == 0 exactly in the gap; in contact
    tau_l = K1 (delta -+ b/2) + d ddelta/dt."""
    w = 2 * math.pi * F_SWEEP
    r = _sweep(0.0, 1.0 / F_SWEEP)
    ev = [(t, e) for t, blk, e in r.events if blk == "gear"]
    assert [e for _, e in ev] == ["contact_pos", "separate", "contact_neg", "separate"], ev
    a = math.asin(B_GAP / 2 / A_SWEEP)
    t_pos, t_neg = a / w, (math.pi + a) / w
    assert ev[0][0] == pytest.approx(t_pos, abs=1e-9)
    assert ev[2][0] == pytest.approx(t_neg, abs=1e-9)
    assert ev[1][0] == pytest.approx(_separation_time(0.3, 0.99, 0.0, 1), abs=1e-9)
    assert ev[3][0] == pytest.approx(_separation_time(1.3, 1.99, 0.0, -1), abs=1e-9)
    t, tau, de = r.t, r["gear.tau_l"], r["gear.deflection"]
    gap = (t < ev[0][0]) | ((t > ev[1][0]) & (t < ev[2][0])) | (t > ev[3][0])
    assert np.count_nonzero(gap) > 300
    assert np.all(tau[gap] == 0.0), np.abs(tau[gap]).max()
    ddef = A_SWEEP * w * np.cos(w * t)
    pos = (t > ev[0][0]) & (t < ev[1][0])
    neg = (t > ev[2][0]) & (t < ev[3][0])
    np.testing.assert_allclose(tau[pos], GEAR["K1"] * (de[pos] - B_GAP / 2)
                               + GEAR["d"] * ddef[pos], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(tau[neg], GEAR["K1"] * (de[neg] + B_GAP / 2)
                               + GEAR["d"] * ddef[neg], rtol=1e-9, atol=1e-9)
    assert np.all(tau[pos] >= -1e-9) and np.all(tau[neg] <= 1e-9)   # contact never pulls


def test_backlash_slow_reversal_two_events():
    """A slow reversal through the gap: phi_m / N = A cos(w t) for half a period, from
    contact on the + side to the - side: exactly two gear events, separation then contact
    at -b/2, and the transmitted torque changes sign only through the gap."""
    w = 2 * math.pi * F_SWEEP
    r = _sweep(math.pi / 2, 0.5 / F_SWEEP)
    ev = [(t, e) for t, blk, e in r.events if blk == "gear"]
    assert [e for _, e in ev] == ["separate", "contact_neg"], ev
    assert ev[1][0] == pytest.approx(math.acos(-B_GAP / 2 / A_SWEEP) / w, abs=1e-9)
    tau = r["gear.tau_l"]
    assert tau[0] > 0 and tau[-1] < 0
    between = (r.t > ev[0][0]) & (r.t < ev[1][0])
    assert np.all(tau[between] == 0.0)


REBOUND = """
name: rebound
blocks:
  pm:   {{type: Sine, amplitude: {amp}, f: {f}, phase: 1.5707963267948966}}
  wm:   {{type: Sine, amplitude: {wamp}, f: {f}, phase: 3.141592653589793}}
  pl:   {{type: Constant, value: {off}}}
  w0:   {{type: Constant, value: 0}}
  gear: {{type: HarmonicDrive, ratio: {N}, K1: {K1}, d: {d}, backlash: {b}, friction: false}}
connections:
  - pm.y -> gear.phi_m
  - wm.y -> gear.w_m
  - pl.y -> gear.phi_l
  - w0.y -> gear.w_l
"""


@pytest.mark.parametrize("jit", [False, True])
def test_backlash_contact_lost_by_damping_returns_past_the_edge(jit):
    """Teeth parted by the damper while the deflection stays past b/2: delta = c + a cos(w t)
    with c - a > b/2 all the time, the contact torque K1 (delta - b/2) + d ddelta/dt turning
    negative and back within each period. The teeth separate and touch again where that
    torque crosses zero (brentq), twice per period, with tau_l = 0 in between and the
    contact torque otherwise. Before, the gap's guard watched only delta crossing b/2, which
    never happened: after the first separation the gear transmitted nothing for good (a
    motor pushing a load through its Harmonic Drive ran away, deflection 0.29 rad)."""
    N, K1, d, b = GEAR["ratio"], GEAR["K1"], 2000.0, B_GAP
    c, a, f = b / 2 + 2e-5, 1e-5, 20.0
    w = 2 * math.pi * f
    text = REBOUND.format(amp=N * a, wamp=N * a * w, f=f, off=-c, N=N, K1=K1, d=d, b=b)
    r = spidersim.loads(text).simulate(t_end=2 / f, rtol=1e-10, atol=1e-14, jit=jit,
                                       method="DP54", output_interval=1e-4)

    def ts(t):
        return K1 * (c + a * math.cos(w * t) - b / 2) - d * a * w * math.sin(w * t)
    grid = np.linspace(0.0, 2 / f, 4001)
    vals = np.array([ts(t) for t in grid])
    roots = [brentq(ts, grid[k], grid[k + 1], xtol=1e-15)
             for k in range(grid.size - 1) if vals[k] * vals[k + 1] < 0]
    ev = [(t, e) for t, blk, e in r.events if blk == "gear"]
    assert [e for _, e in ev] == ["separate", "contact_pos"] * 2, ev
    np.testing.assert_allclose([t for t, _ in ev], roots, atol=1e-9)
    de = r["gear.deflection"]
    assert de.min() > b / 2                                   # never back inside the gap
    tau = r["gear.tau_l"]
    apart = ((r.t > ev[0][0]) & (r.t < ev[1][0])) | ((r.t > ev[2][0]) & (r.t < ev[3][0]))
    assert np.all(tau[apart] == 0.0)
    touch = ~apart & (np.abs(r.t[:, None] - [t for t, _ in ev]).min(axis=1) > 1e-6)
    np.testing.assert_allclose(tau[touch], [ts(t) for t in r.t[touch]], rtol=1e-8, atol=1e-8)


PUSHED_THROUGH_BACKLASH = """
name: pushed
blocks:
  gear: {{type: HarmonicDrive, ratio: 160, backlash: 2.9e-4, friction: false}}
  mot:  {{type: Inertia, J: 1e-4}}
  load: {{type: Inertia, J: 2.56, w0: {w0}}}
  push: {{type: Constant, value: 0.3}}
  s:    {{type: Sum, signs: "+-"}}
connections: [mot.phi -> gear.phi_m, mot.w -> gear.w_m, load.phi -> gear.phi_l,
              load.w -> gear.w_l, push.y -> s.u1, gear.tau_m -> s.u2, s.y -> mot.tau,
              gear.tau_l -> load.tau]
simulation: {{t_end: 0.6, rtol: 1e-10, atol: 1e-13}}
"""


@pytest.mark.parametrize("w0", [-0.1, -0.2, -0.5, -0.7])
@pytest.mark.parametrize("method", ["LSODA", "DP54"])
def test_motor_pushing_a_load_through_backlash_stays_engaged(method, w0):
    """A motor pushing 0.3 N.m into a load coming back at it (the reviewer's case, default
    damping d = 20): after the impacts the teeth stay engaged and both sides accelerate
    together at N tau / (J_l + N^2 J_m) = 9.375 rad/s^2, the deflection about b/2 plus the
    load's share J_l a / K1 (5.9e-4 rad), and angular momentum N J_m w_m + J_l w_l grows at
    N tau exactly. Before, 0.2 and 0.7 rad/s (and 3 more of 30 closing speeds) ended apart
    for good, the deflection 0.29 rad and growing."""
    r = spidersim.loads(PUSHED_THROUGH_BACKLASH.format(w0=w0)).simulate(method=method)
    N, J_m, J_l, K1, tau = 160.0, 1e-4, 2.56, 5.4e4, 0.3
    acc = N * tau / (J_l + N ** 2 * J_m)
    de = r["gear.deflection"]
    assert np.abs(de).max() < 1e-2, np.abs(de).max()      # impacts: |w0| sqrt(m/K1) + b/2
    late = r.t > 0.45
    steady = 2.9e-4 / 2 + J_l * acc / K1
    assert np.all(np.abs(de[late] - steady) < 0.3 * steady), de[late].min()
    assert np.all(r["gear.tau_l"][late] > 0)
    mom = N * J_m * r["mot.w"] + J_l * r["load.w"]
    np.testing.assert_allclose(mom - mom[0], N * tau * r.t, atol=1e-6)


# ============================================================================= joint
def test_joint_step_tracks_trapezoid():
    """diagrams/joint_step.yaml as shipped (LuGre friction, 16-bit resolvers, cascade sampled
    at 1 kHz): the load reaches the 0.01 rad target (final error < 1e-4 rad, measured 5.6e-5;
    5.7e-5 with the continuous cascade). Stiction holds
    the motor until the speed-loop integral has built up T_s = 0.07 N.m, so the tracking
    error during the move is large (measured 2.33e-3 rad, 23 % of the move); it is bounded
    here at 30 %.

    Run compiled: interpreted, this stiff LuGre joint was the suite's longest test (76 s on an
    idle machine; compiled, its compile included, 21 s on a loaded one). The interpreter is
    checked against the compiled code in test_compiled_matches_interpreted_ripple."""
    d = spidersim.load(os.path.join(DIAGRAMS, "joint_step.yaml"))
    r = d.simulate(output_interval=0.005)
    e = r["ref.q"] - r["link.phi"]
    assert r["ref.q"][-1] == pytest.approx(0.01)
    assert abs(e[-1]) < 1e-4, e[-1]
    assert np.max(np.abs(e)) < 0.3 * 0.01
    assert abs(r["link.phi"][-1] - 0.01) < 1e-4


def test_joint_step_without_friction_tracks_closely():
    """The same move without friction and with ideal resolvers: the cascade (P on the load
    position with speed feed-forward, PI on the motor speed; sampled at 1 kHz) tracks the
    trapezoid within 2 % of the move (measured 1.2e-4 rad) and ends within 2e-5 rad
    (measured 9.2e-6). Compiled, as the step above."""
    d = spidersim.load(os.path.join(DIAGRAMS, "joint_step.yaml"),
                       set={"joint.friction": 0, "joint.res_bits": 0})
    r = d.simulate(output_interval=0.005)
    e = r["ref.q"] - r["link.phi"]
    assert np.max(np.abs(e)) < 0.02 * 0.01, np.max(np.abs(e))
    assert abs(e[-1]) < 2e-5, e[-1]


def _settled_step(bits, t_end):
    """The joint step held to ``t_end``, compiled (as the steps above; interpreted, the two
    runs of the limit-cycle test took 35 s, compiled 6 s, with the same figures to the
    digits quoted there)."""
    d = spidersim.load(os.path.join(DIAGRAMS, "joint_step.yaml"),
                       set={"joint.friction": 0, "joint.res_bits": bits})
    r = d.simulate(output_interval=0.0005, t_end=t_end)
    late = r.t > t_end - 1.0             # the move ends at 1.1 s
    return r, late


def test_joint_quantization_limit_cycle_of_one_lsb():
    """The digital joint (1 kHz cascade, friction off) holding the end of the step: with
    16-bit converters the position loop sees q on the 2 pi / 2^16 grid, so the command hunts
    between neighbouring codes (a reference between two codes is never matched, the speed
    loop integrates the residue until q crosses a code edge); one code of q changes the held
    command by dI = kp_w ratio kp_q q_LSB (6.9 mA with joint.yaml's gains). Asserted over
    3-4 s: the command's peak-to-peak is 0.5..4 dI (measured 1.0e-2 A = 1.45 dI) and the
    true position stays within one LSB of the target (measured 2.1e-5 rad = 0.2 LSB); with
    bits 0 the same controller settles (same window): command p-p < 1 % of dI (measured
    1.6e-5 A), error < 5 % LSB (measured 1.8e-6 rad)."""
    lsb = 2 * math.pi / 2 ** 16
    N, f_spd, K_t = 160.0, 3.0, 0.15
    J_tot = 1e-4 + 16.9 / N ** 2
    dI = (J_tot * 2 * math.pi * f_spd / K_t) * N * (2 * math.pi * f_spd / 4) * lsb
    r, late = _settled_step(16, 4.0)     # the hunting is established after about 3 s
    i_pp = np.ptp(r["joint.i_cmd"][late])
    e = r["ref.q"][late] - r["link.phi"][late]
    assert 0.5 * dI < i_pp < 4 * dI, (i_pp, dI)
    assert np.max(np.abs(e)) < lsb
    r0, late0 = _settled_step(0, 4.0)
    assert np.ptp(r0["joint.i_cmd"][late0]) < 0.01 * dI
    assert np.max(np.abs(r0["ref.q"][late0] - r0["link.phi"][late0])) < 0.05 * lsb


def _tzeros(sys):
    """Transmission zeros of a SISO state space (generalized eigenvalues of the Rosenbrock
    matrix)."""
    A, B, C, D = (np.asarray(m) for m in (sys.A, sys.B, sys.C, sys.D))
    n = A.shape[0]
    M = np.block([[A, B], [C, D]])
    E = np.zeros_like(M)
    E[:n, :n] = np.eye(n)
    z = sla.eigvals(M, E)
    return z[np.isfinite(z)]


def _light_pairs(roots, zeta_max=0.1):
    """Natural frequencies [Hz] of the lightly damped complex pairs."""
    c = roots[np.imag(roots) > 1e-6]
    return sorted(abs(x) / (2 * np.pi) for x in c if -x.real / abs(x) < zeta_max)


J_LINK, N_GEAR, J_M, K1 = 16.9, 160.0, 1e-4, 5.4e4
F_LOCKED = math.sqrt(K1 / J_LINK) / (2 * math.pi)                                 # 9.00 Hz
F_FREE = math.sqrt(K1 * (1 / J_LINK + 1 / (N_GEAR ** 2 * J_M))) / (2 * math.pi)   # 24.80 Hz


def test_speed_loop_resonance():
    """Joint + link 2, friction off, ideal resolvers, linearized at rest from the current
    command (speed loop opened at ctrl.i_cmd) to the motor speed: one lightly damped pole
    pair at the motor-free resonance sqrt(K1 (1/J_l + 1/(N^2 J_m)))/2pi = 24.80 Hz and one
    zero pair at the motor-locked antiresonance sqrt(K1/J_l)/2pi = 9.00 Hz; the brief's
    10 % is met with room: 2 % asserted (the rigid two-inertia formula ignores only the
    current loop and the damping d). The magnitude peaks and dips there too."""
    d = spidersim.load(os.path.join(DIAGRAMS, "joint_step.yaml"),
                       set={"joint.friction": 0, "joint.res_bits": 0})
    sys = d.linearize(["joint.ctrl.i_cmd"], ["joint.motor.w"], open=["joint.ctrl.i_cmd"],
                      jit=False)
    # the rigid-body mode (the arm's angle is free with the loop opened; the RDC tracks it)
    # shows as a pair at round-off distance from the origin: the resonances are above 1 Hz
    poles = [f for f in _light_pairs(np.linalg.eigvals(np.asarray(sys.A))) if f > 1.0]
    zeros = [f for f in _light_pairs(_tzeros(sys)) if f > 1.0]
    assert len(poles) == 1 and len(zeros) == 1, (poles, zeros)
    assert poles[0] == pytest.approx(F_FREE, rel=0.02)       # measured 24.68 Hz
    assert zeros[0] == pytest.approx(F_LOCKED, rel=0.02)     # measured 8.997 Hz
    f = np.linspace(3.0, 60.0, 5701)
    A, B, C, D = (np.asarray(m) for m in (sys.A, sys.B, sys.C, sys.D))
    n = A.shape[0]
    mag = np.array([abs((C @ np.linalg.solve(2j * np.pi * fk * np.eye(n) - A, B) + D)[0, 0])
                    for fk in f])
    # remove the integrator-like 1/f trend of the rigid body: |G| f
    shaped = mag * f
    f_peak = f[np.argmax(shaped * (f > 15))]
    f_dip = f[np.argmin(np.where(f < 15, shaped, np.inf))]
    assert f_peak == pytest.approx(F_FREE, rel=0.02)
    assert f_dip == pytest.approx(F_LOCKED, rel=0.02)


def test_linearized_presliding_friction_locks_the_motor():
    """With LuGre on and linearized at rest, the bristles are a spring sigma0 = 80 N.m/rad
    from the rotor to ground (far stiffer than the gear seen from the motor,
    K1/N^2 = 2.1 N.m/rad): the lightly damped mode is the load on the gear in series with
    the bristles, sqrt(K_s/J_l)/2pi with 1/K_s = 1/K1 + 1/(N^2 sigma0): 8.88 Hz (1 %);
    the rotor on the bristles is a well-damped ~144 Hz pair. (Linearizing a joint with
    friction at rest therefore shows the motor-locked, not the motor-free, resonance.)"""
    d = spidersim.load(os.path.join(DIAGRAMS, "joint_step.yaml"),
                       set={"joint.friction": 1, "joint.res_bits": 0})
    sys = d.linearize(["joint.ctrl.i_cmd"], ["joint.motor.w"], open=["joint.ctrl.i_cmd"],
                      jit=False)
    poles = _light_pairs(np.linalg.eigvals(np.asarray(sys.A)))
    ks = 1.0 / (1.0 / K1 + 1.0 / (N_GEAR ** 2 * 80.0))
    assert len(poles) == 1, poles
    assert poles[0] == pytest.approx(math.sqrt(ks / J_LINK) / (2 * math.pi), rel=0.01)
    rotor = math.sqrt((80.0 + K1 / N_GEAR ** 2) / J_M) / (2 * math.pi)
    allp = np.linalg.eigvals(np.asarray(sys.A))
    assert np.any(np.abs(np.abs(allp) / (2 * np.pi) - rotor) < 0.02 * rotor)


# ============================================================================= compiled
def test_compiled_matches_interpreted_ripple():
    """The one jit=True check: the all-imperfections NRPI bench gives the same torque
    compiled and interpreted (1e-8 of K_t I)."""
    text = nrpi_bench(offset=0.03, unbalance=0.015, h3=0.008, J=10.0)
    d = spidersim.loads(text)
    kw = dict(t_end=0.02, rtol=1e-10, atol=1e-12, method="LSODA",
              output_interval=1.0 / (SPP * FE))
    a = d.simulate(jit=False, **kw)
    b = spidersim.loads(text).simulate(jit=True, **kw)
    assert len(a.t) == len(b.t)
    np.testing.assert_allclose(b["motor.tau"], a["motor.tau"], atol=1e-8 * K_T * I_CMD)
