"""LuGre friction levels at their edges (LuGre and the HarmonicDrive's friction).

A hostile review (session 12) found that with the friction level ``g(v) = 0`` the bristle
equation was taken as ``dz/dt = v``: the bristles wound up as a spring without bound
(80 N.m after 1 s at 1 rad/s with T_c = T_s = 0 and D = 0.01, where the friction is D v =
0.01 N.m; 2,403 N.m at 30 rad/s with T_c = 0, T_s = 0.07, where g underflows). Guarded here:
T_c = T_s = 0 is viscous friction only (z stays 0), T_c = 0 < T_s is refused naming the fix,
and the steady sliding friction g(v) sgn(v) + D v still holds for T_c > 0.
"""
import re

import numpy as np
import pytest

import spidersim
from spidersim.errors import ParameterError

LUGRE = """
blocks:
  v: {type: Constant, value: {value: %(v)s, unit: rad/s}}
  f: {type: LuGre, T_c: %(T_c)s, T_s: %(T_s)s, D: %(D)s, z0: %(z0)s}
connections:
  - v.y -> f.v
simulation: {t_end: %(t_end)s, method: %(method)s}
log: [f.tau, f.z]
"""


def _lugre(v=1.0, T_c=0.0, T_s=0.0, D=0.01, z0=0.0, t_end=1.0, method="LSODA"):
    return spidersim.loads(LUGRE % dict(v=v, T_c=T_c, T_s=T_s, D=D, z0=z0, t_end=t_end,
                                        method=method))


@pytest.mark.parametrize("method", ["LSODA", "DP54", "NDF"])
def test_zero_levels_leave_viscous_friction_only(method):
    r = _lugre(v=1.0, method=method).simulate()
    assert np.all(r["f.z"] == 0.0)
    np.testing.assert_allclose(r["f.tau"], 0.01, rtol=0, atol=1e-15)     # D v


@pytest.mark.parametrize("levels, words", [
    (dict(T_c=0.0, T_s=0.07), "T_c = 0 with T_s = 0.07"),
    (dict(T_c=0.0, T_s=0.0, z0=1e-3), "z0 = 0.001 with T_c = T_s = 0"),
    (dict(T_c=0.08, T_s=0.07), "T_s (0.07) must not be below T_c (0.08)"),
])
def test_levels_without_a_solution_are_refused(levels, words):
    with pytest.raises(ParameterError, match=re.escape(words)):
        _lugre(**levels)


def test_steady_sliding_friction_with_a_small_coulomb_level():
    """T_c > 0 (1e-4 N.m) at 30 rad/s, far past the Stribeck bump: the friction settles
    at g(v) + D v = T_c + D v (the exponential is 0 there)."""
    T_c, D, v = 1e-4, 2e-4, 30.0
    r = _lugre(v=v, T_c=T_c, T_s=0.07, D=D, t_end=0.5).simulate()
    assert r["f.tau"][-1] == pytest.approx(T_c + D * v, rel=1e-6)
    assert r["f.z"][-1] == pytest.approx(T_c / 80.0, rel=1e-6)             # g / sigma0


def test_harmonic_drive_with_zero_levels_transmits_without_friction():
    """The HarmonicDrive's LuGre with T_c = T_s = D = 0: no friction torque; the motor
    side carries the elastic torque only (here zero: no deflection)."""
    text = """
blocks:
  wm: {type: Constant, value: {value: 1, unit: rad/s}}
  phm: {type: Ramp, slope: {value: 1, unit: rad/s}}
  phl: {type: Ramp, slope: {value: 0.00625, unit: rad/s}}
  wl: {type: Constant, value: {value: 0.00625, unit: rad/s}}
  hd: {type: HarmonicDrive, ratio: 160, T_c: 0, T_s: 0, D: 0}
connections:
  - wm.y -> hd.w_m
  - phm.y -> hd.phi_m
  - phl.y -> hd.phi_l
  - wl.y -> hd.w_l
simulation: {t_end: 1}
log: [hd.tau_f, hd.tau_m]
"""
    r = spidersim.loads(text).simulate()
    assert np.abs(r["hd.tau_f"]).max() == 0.0
    assert np.abs(r["hd.tau_m"]).max() < 1e-9 * 160
    with pytest.raises(ParameterError, match="T_c = 0 with T_s = 0.07"):
        spidersim.loads(text.replace("T_s: 0,", "T_s: 0.07,"))
