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


QUANTIZERS = [pytest.param(False, id="python"), pytest.param(True, id="numba")]


def _quantizers(jit):
    from spidersim.blocks import sensors
    if jit:
        return sensors.quantize_jit, sensors.quantize_speed_jit
    return sensors._quantize, sensors._quantize_speed


@pytest.mark.parametrize("jit", QUANTIZERS)
def test_angle_grid_beyond_int64_counts_keeps_sign_and_value(jit):
    """1e8 rad at 40 bits is 1.7e19 counts, beyond 2^63: under numba ``math.floor`` returned
    an int64 that wrapped to -2^63 (theta_m = -5.27e7 rad, exit status 0). The count is a
    float now; beyond 2^52 counts the angle itself is its grid value to round-off."""
    quantize, _ = _quantizers(jit)
    for theta in (1e8, -1e8, 3e15, 1e300, -1e300, math.inf, -math.inf):
        assert quantize(theta, 40) == theta
    assert math.isnan(quantize(math.nan, 40))
    q = 2 * math.pi / 2 ** 40                   # below 2^52 counts: the nearest grid value
    for k in (3, -3, 2 ** 40, -(2 ** 51)):
        assert quantize(k * q + 0.3 * q, 40) == pytest.approx(k * q, rel=1e-15, abs=1e-25)
        assert quantize(k * q - 0.3 * q, 40) == pytest.approx(k * q, rel=1e-15, abs=1e-25)
    q16 = 2 * math.pi / 2 ** 16
    assert quantize(2.5 * q16, 16) == 3 * q16 and quantize(-2.5 * q16, 16) == -2 * q16


@pytest.mark.parametrize("jit", QUANTIZERS)
def test_speed_word_saturates_on_the_side_of_the_speed(jit):
    """``w_max = 1e-300`` at 16 bits puts +10 rad/s at 3e305 counts: the positive full scale
    ``(2^15 - 1) lsb``, not the negative one (the int64 count wrapped to -2^63, w_d =
    -1e-300 for a positive speed). Counts round to the nearest and saturate at -2^15 and
    2^15 - 1; a subnormal ``w_max`` whose lsb underflows to 0 still reads 0 for 0."""
    _, word = _quantizers(jit)
    assert word(10.0, 16, 1e-300) == 1e-300 * (2 ** 15 - 1) / 2 ** 15
    assert word(-10.0, 16, 1e-300) == -1e-300
    assert word(math.inf, 16, 5.0) == 5.0 * (2 ** 15 - 1) / 2 ** 15
    assert word(-math.inf, 16, 5.0) == -5.0
    assert word(0.0, 40, 5e-324) == 0.0 and word(1.0, 40, 5e-324) == 5e-324
    lsb = 5.0 / 2 ** 15
    assert word(2.6 * lsb, 16, 5.0) == 3 * lsb and word(-2.6 * lsb, 16, 5.0) == -3 * lsb
    assert word(2.4 * lsb, 16, 5.0) == 2 * lsb
    assert word(5.0, 16, 5.0) == (2 ** 15 - 1) * lsb and word(-5.0, 16, 5.0) == -5.0
    assert word(-6.0, 16, 5.0) == -5.0
    assert word(1.234, 0, 5.0) == 1.234


def test_huge_angles_and_tiny_full_scale_in_a_run():
    """The reviewer's diagrams through a run: a constant 1e8 rad into a 40-bit Resolver and
    RDC, and a +10 rad/s ramp into an RDC with w_max = 1e-300 (both read the wrong sign)."""
    r = spidersim.loads("""\
blocks:
  c: {type: Constant, value: {value: 1e8, unit: rad}}
  a: {type: Resolver, bits: 40}
  r: {type: RDC, bits: 40, theta0: 1e8}
  v: {type: Ramp, slope: 10}
  s: {type: RDC, w_bits: 16, w_max: 1e-300}
connections: [c.y -> a.theta, c.y -> r.theta, v.y -> s.theta]
simulation: {t_end: 0.1}
""").simulate(jit=False)
    assert np.all(r["a.theta_m"] == 1e8) and np.all(r["r.theta_d"] == 1e8)
    assert r["s.w_r"][-1] == pytest.approx(10.0, rel=1e-3)
    assert r["s.w_d"][-1] == 1e-300 * (2 ** 15 - 1) / 2 ** 15


def test_one_bit_speed_word_refused():
    """``w_bits = 1`` leaves only the counts -1 and 0: every speed above -w_max/2 read 0
    (+10 rad/s with w_max 5: w_d = 0). Refused, naming the choices."""
    with pytest.raises(spidersim.SpidersimError) as ei:
        spidersim.loads("""\
blocks:
  v: {type: Ramp, slope: 10}
  s: {type: RDC, w_bits: 1, w_max: 5}
connections: [v.y -> s.theta]
""")
    msg = str(ei.value)
    assert "block 's'" in msg and "w_bits = 1 is a sign bit only" in msg, msg
    assert "use 0 (w_d = w_r) or at least 2 bits" in msg, msg
