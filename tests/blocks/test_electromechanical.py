"""DCMotor: analytic steady state, the linear solution (matrix exponential) and the energy
balance  int v i dt = int (R i^2 + b w^2 + tau_load w) dt + J w^2/2 + L i^2/2."""
import numpy as np
import pytest
from scipy.linalg import expm

from .harness import Probe, simulate

RTOL, ATOL = 1e-8, 1e-10
M = dict(R=1.2, L=2e-3, K_t=0.05, J=1e-4, b=1e-5)


def _motor(v, tau=None, t_end=1.0, extra="", conns="", **params):
    prm = dict(M, **params)
    body = ", ".join(f"{k}: {val}" for k, val in prm.items())
    text = (f"blocks:\n  v: {{type: Constant, value: {v}}}\n  m: {{type: DCMotor, {body}}}\n"
            + (f"  tl: {{type: Constant, value: {tau}}}\n" if tau is not None else "")
            + extra + "connections:\n  - v.y -> m.v\n"
            + ("  - tl.y -> m.tau_load\n" if tau is not None else "") + conns)
    return simulate(text, t_end=t_end, rtol=RTOL, atol=ATOL)


@pytest.mark.parametrize("v,tau", [(12.0, None), (12.0, 0.01), (-6.0, -0.005)])
def test_steady_state(v, tau):
    """w = (K v - R tau) / (R b + K^2), i = (b w + tau) / K (no load: w = K v / (R b + K^2))."""
    R, K, b = M["R"], M["K_t"], M["b"]
    r = _motor(v, tau, t_end=1.5)
    tl = tau or 0.0
    w = (K * v - R * tl) / (R * b + K ** 2)
    i = (b * w + tl) / K
    assert r["m.w"][-1] == pytest.approx(w, rel=100 * RTOL)
    assert r["m.i"][-1] == pytest.approx(i, rel=100 * RTOL, abs=100 * ATOL)
    assert r["m.tau"][-1] == pytest.approx(K * i, rel=100 * RTOL, abs=100 * ATOL)
    assert np.sign(r["m.w"][-1]) == np.sign(v)


def test_matches_linear_solution():
    """x = (i, w, phi): dx/dt = A x + B (v, tau_load) from i0, w0, phi0 (matrix exponential)."""
    R, L, K, J, b = (M[k] for k in ("R", "L", "K_t", "J", "b"))
    x0 = np.array([0.5, -20.0, 1.0])
    u = np.array([9.0, 0.004])
    A = np.array([[-R / L, -K / L, 0.0], [K / J, -b / J, 0.0], [0.0, 1.0, 0.0]])
    B = np.array([[1 / L, 0.0], [0.0, -1 / J], [0.0, 0.0]])
    r = _motor(u[0], u[1], t_end=0.3, i0=x0[0], w0=x0[1], phi0=x0[2])
    # augmented exponential: d/dt [x; u] = [[A, B], [0, 0]] [x; u]
    Aa = np.zeros((5, 5))
    Aa[:3, :3], Aa[:3, 3:] = A, B
    xs = np.array([(expm(Aa * t) @ np.r_[x0, u])[:3] for t in r.t])
    got = np.column_stack([r["m.i"], r["m.w"], r["m.phi"]])
    err = np.abs(got - xs) / (ATOL + RTOL * np.max(np.abs(xs), axis=0))
    assert err.max() < 10, err.max(axis=0)
    np.testing.assert_allclose(r["m.tau"], K * r["m.i"], rtol=1e-14)


def test_energy_balance():
    """Power integrals as Integrator states: the balance holds to a few times rtol of the
    input energy."""
    R, L, J, b = M["R"], M["L"], M["J"], M["b"]
    extra = f"""  pin:  {{type: Product}}
  ein:  {{type: Integrator}}
  i2:   {{type: Product}}
  pr:   {{type: Gain, k: {R}}}
  er:   {{type: Integrator}}
  w2:   {{type: Product}}
  pb:   {{type: Gain, k: {b}}}
  eb:   {{type: Integrator}}
  pl:   {{type: Product}}
  el:   {{type: Integrator}}
"""
    conns = """  - v.y -> pin.u1
  - m.i -> pin.u2, i2.u1, i2.u2
  - pin.y -> ein.u
  - i2.y -> pr.u
  - pr.y -> er.u
  - m.w -> w2.u1, w2.u2, pl.u2
  - w2.y -> pb.u
  - pb.y -> eb.u
  - tl.y -> pl.u1
  - pl.y -> el.u
"""
    r = _motor(12.0, 0.004, t_end=0.5, extra=extra, conns=conns)
    w, i = r["m.w"], r["m.i"]
    stored = 0.5 * J * w ** 2 + 0.5 * L * i ** 2
    resid = r["ein.y"] - r["er.y"] - r["eb.y"] - r["el.y"] - stored
    scale = np.max(np.abs(r["ein.y"]))
    assert scale > 1.0                              # a meaningful amount of energy moved
    assert np.max(np.abs(resid)) < 5 * (ATOL + RTOL * scale), np.max(np.abs(resid)) / scale


def test_positive_load_torque_decelerates():
    p = Probe("DCMotor", dict(M))
    x = p.set_state(p.x0(), "w", 100.0)
    free = p.derivatives(0.0, x)["w"][0]
    p.set_input("tau_load", 0.01)
    loaded = p.derivatives(0.0, x)["w"][0]
    assert loaded == pytest.approx(free - 0.01 / M["J"])
    assert p.derivatives(0.0, x)["phi"][0] == 100.0
    p.set_input("v", 5.0)
    assert p.derivatives(0.0, x)["i"][0] == pytest.approx((5.0 - M["K_t"] * 100.0) / M["L"])


def test_unconnected_load_reads_zero():
    r = _motor(12.0, None, t_end=0.05)
    r2 = _motor(12.0, 0.0, t_end=0.05)
    np.testing.assert_array_equal(r.t, r2.t)
    np.testing.assert_array_equal(r["m.w"], r2["m.w"])


def test_zero_inductance_is_first_order_with_algebraic_current():
    """L = 0: i = (v - K w)/R (feedthrough of v), J w' = K i - b w - tau: a first-order lag
    w = w_ss + (w0 - w_ss) exp(-t / T), T = J / (K^2/R + b), w_ss = (K v/R - tau) T / J."""
    R, K, J, b = M["R"], M["K_t"], M["J"], M["b"]
    v, tau, w0 = 12.0, 0.004, 30.0
    r = _motor(v, tau, t_end=0.5, L=0.0, w0=w0)
    c = K ** 2 / R + b
    w_ss = (K * v / R - tau) / c
    w = w_ss + (w0 - w_ss) * np.exp(-r.t * c / J)
    err = np.abs(r["m.w"] - w) / (ATOL + RTOL * np.abs(w))
    assert err.max() < 10
    np.testing.assert_allclose(r["m.i"], (v - K * r["m.w"]) / R, rtol=1e-12)
    np.testing.assert_allclose(r["m.tau"], K * r["m.i"], rtol=1e-12)
    p = Probe("DCMotor", dict(M, L=0.0))
    assert p.layout.feedthrough["i"] == ("v",) and p.layout.feedthrough["tau"] == ("v",)
    assert p.state_names == ["w", "phi"]
