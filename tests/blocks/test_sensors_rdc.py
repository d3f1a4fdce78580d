"""The resolver-to-digital converter (RDC) alone against the closed forms of a type-II loop
(issue #13 item 6)."""
import math

import numpy as np
import pytest

import spidersim

DIAGRAM = """\
blocks:
  src:  {{type: {src}}}
  rdc:  {{type: RDC, f_n: {f_n}, zeta: {zeta}}}
connections:
  - src.y -> rdc.theta
simulation: {{t_end: {t_end}, rtol: 1e-10, atol: 1e-13, output_interval: 1.0e-5}}
"""


def _run(src, f_n=200.0, zeta=0.5, t_end=0.02):
    d = spidersim.loads(DIAGRAM.format(src=src, f_n=f_n, zeta=zeta, t_end=t_end))
    return d.simulate(jit=False)


@pytest.mark.parametrize("zeta", [0.3, 0.7])
def test_speed_step_tracking_error_closed_form(zeta):
    """theta = w0 t from rest: e(t) = w0/w_d exp(-zeta w_n t) sin(w_d t); the speed output
    settles on w0 with no steady error (type II)."""
    w0, f_n = 2.0, 200.0
    r = _run(f"Ramp, slope: {w0}, t_start: 0", f_n=f_n, zeta=zeta)
    wn = 2 * math.pi * f_n
    wd = wn * math.sqrt(1 - zeta ** 2)
    t = r.t
    e_ref = w0 / wd * np.exp(-zeta * wn * t) * np.sin(wd * t)
    e = w0 * t - r["rdc.theta_r"]
    # linear closed form vs sin(e) loop: |e| < 2e-3 rad, so they differ by < e^3/6 relative
    assert np.max(np.abs(e - e_ref)) < 1e-6 * np.max(np.abs(e_ref)) + 1e-10
    # the velocity output w_r = dtheta_r/dt - 2 zeta w_n e = w0 - de/dt - 2 zeta w_n e
    s_ = zeta * wn
    de = w0 / wd * np.exp(-s_ * t) * (wd * np.cos(wd * t) - s_ * np.sin(wd * t))
    w_ref = w0 - de - 2 * zeta * wn * e_ref
    assert np.max(np.abs(r["rdc.w_r"] - w_ref)) < 1e-5 * w0
    assert abs(w_ref[-1] - w0) < 2e-3 * w0            # settling on w0: no steady error


def test_constant_acceleration_steady_error():
    """theta = a t^2 / 2: the steady tracking error is a / w_n^2 and the velocity output
    lags a t by 2 zeta a / w_n."""
    a, f_n = 50.0, 100.0
    d = spidersim.loads(f"""\
blocks:
  acc: {{type: Constant, value: {a}}}
  w:   {{type: Integrator}}
  th:  {{type: Integrator}}
  rdc: {{type: RDC, f_n: {f_n}, zeta: 0.7}}
connections:
  - acc.y -> w.u
  - w.y -> th.u
  - th.y -> rdc.theta
simulation: {{t_end: 0.1, rtol: 1e-10, atol: 1e-13}}
""")
    r = d.simulate(jit=False)
    e = r["th.y"][-1] - r["rdc.theta_r"][-1]
    assert e == pytest.approx(a / (2 * math.pi * f_n) ** 2, rel=1e-4)
    wn = 2 * math.pi * f_n
    assert r["rdc.w_r"][-1] == pytest.approx(a * 0.1 - 2 * 0.7 * a / wn, rel=1e-4)


def test_tracks_through_wrap_and_quantization():
    """A fast spin (many turns) is tracked; with bits the digital output theta_d stays within
    one LSB of the true angle after the transient (the tracked angle itself is continuous)."""
    w0 = 300.0
    d = spidersim.loads(DIAGRAM.format(src=f"Ramp, slope: {w0}", f_n=500, zeta=0.7,
                                       t_end=0.05).replace("zeta: 0.7}",
                                                           "zeta: 0.7, bits: 12}"))
    r = d.simulate(jit=False)
    late = r.t > 0.02
    lsb = 2 * math.pi / 2 ** 12
    assert np.max(np.abs(w0 * r.t[late] - r["rdc.theta_r"][late])) < 1.5 * lsb
    assert np.max(np.abs(w0 * r.t[late] - r["rdc.theta_d"][late])) < 1.5 * lsb
