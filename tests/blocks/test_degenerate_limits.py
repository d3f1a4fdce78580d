"""Saturation and DeadZone with coinciding limits are refused (a hostile review, session 12).

``lower == upper``: both corner guards fire at one instant and the mode ended linear, so
under LSODA the output followed the input past the limit (up to 1.996 for limits 0.5); an
input starting on the limit gave y = u on every method. A DeadZone with ``start == end``
(width 0, which is y = u) gave y = 0 for every input. Both are refused naming the fix; the
limits just apart still behave (the closed forms below).
"""
import re

import numpy as np
import pytest

import spidersim
from spidersim.errors import ParameterError

SAT = """
blocks:
  u: {type: Sine, amplitude: 2, f: 1}
  s: {type: %s}
connections:
  - u.y -> s.u
simulation: {t_end: 1, output_interval: 0.01}
log: [u.y, s.y]
"""


@pytest.mark.parametrize("block, words", [
    ("Saturation, lower: 0.5, upper: 0.5", "lower (0.5) must be below upper (0.5)"),
    ("DeadZone, start: 0, end: 0", "start (0.0) must be below end (0.0)"),
])
def test_coinciding_limits_are_refused(block, words):
    with pytest.raises(ParameterError, match=re.escape(words)):
        spidersim.loads(SAT % block)


@pytest.mark.parametrize("method", ["LSODA", "DP54"])
def test_narrow_limits_still_saturate(method):
    r = spidersim.loads(SAT % "Saturation, lower: 0.4999, upper: 0.5").simulate(
        method=method)
    u, y = r["u.y"], r["s.y"]
    np.testing.assert_allclose(y, np.clip(u, 0.4999, 0.5), rtol=0, atol=1e-12)
    r = spidersim.loads(SAT % "DeadZone, start: 0, end: 1e-4").simulate(method=method)
    u, y = r["u.y"], r["s.y"]
    expect = np.where(u > 1e-4, u - 1e-4, np.where(u < 0, u, 0.0))
    np.testing.assert_allclose(r["s.y"], expect, rtol=0, atol=1e-12)
