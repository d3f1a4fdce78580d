"""Direction parameters normalised whatever their scale (a hostile review, session 15).

``ElasticContact normal: [0, 0, 1e-300]`` was refused as "the zero vector" (the squares
underflowed), ``Arm payload_quat0: [1e-300, 0, 0, 0]`` as "a unit quaternion ... is needed"
although documented as normalised, and ``[1e300, 1e300, 0, 0]`` passed check and failed with
NaN (the norm overflowed: the quaternion became 0). Only an exactly zero or a non-finite
vector is refused, with its values printed as plain numbers.
"""
import math

import numpy as np
import pytest

import spidersim
from spidersim.blocks.base import unit_vector


@pytest.mark.parametrize("v, unit", [
    ([0, 0, 1e-300], [0, 0, 1]),
    ([5e-324, 0, 0, 0], [1, 0, 0, 0]),
    ([1e300, 1e300, 0, 0], [math.sqrt(0.5), math.sqrt(0.5), 0, 0]),
    ([-1e308, 1e308, 1e308], [-1 / math.sqrt(3), 1 / math.sqrt(3), 1 / math.sqrt(3)]),
    ([1e-200, 3e-200, 1e-300], [1 / math.sqrt(10), 3 / math.sqrt(10), 1e-100 / math.sqrt(10)]),
])
def test_tiny_and_huge_vectors_normalised(v, unit):
    u = unit_vector(v, "normal")
    assert np.allclose(u, unit, rtol=1e-15, atol=1e-300)
    assert abs(np.linalg.norm(u) - 1.0) < 4e-16


def test_usual_directions_unchanged_to_the_bit():
    """Vectors of ordinary size are divided by their norm as before (no rescaling)."""
    rng = np.random.default_rng(7)
    usual = [[0.219006686859, 0, 0.975723357924, 0], [0, -1, 0]] + list(rng.normal(size=(50, 4)))
    for v in usual:
        v = np.asarray(v, float)
        assert np.array_equal(unit_vector(v, "v"), v / np.linalg.norm(v))


@pytest.mark.parametrize("v, words", [
    ([0, 0, 0], ["normal must not be the zero vector"]),
    ([0.0, -0.0, 0.0], ["normal must not be the zero vector"]),
    ([math.inf, 0, 1e-300], ["normal must be finite, got [inf, 0.0, 1e-300]"]),
    ([math.nan, 1, 0], ["normal must be finite, got [nan, 1.0, 0.0]"]),
])
def test_zero_or_non_finite_refused_in_plain_numbers(v, words):
    with pytest.raises(ValueError) as ei:
        unit_vector(v, "normal")
    for w in words:
        assert w in str(ei.value)
    assert "np.float64" not in str(ei.value)


ARM = """\
blocks:
  c: {type: Constant, value: {value: [0, 0, 0, 0, 0, 0, 0], unit: N.m}}
  arm: {type: Arm, payload_quat0: %s}
connections: [c.y -> arm.tau]
simulation: {t_end: 0.01}
log: [arm.q, arm.payload_pos]
"""


def test_payload_quaternion_of_any_scale():
    """[1e300, 1e300, 0, 0] and [1e-300, 0, 0, 0] run as [1, 1, 0, 0] and [1, 0, 0, 0]."""
    for odd, plain in (("[1e300, 1e300, 0, 0]", "[1, 1, 0, 0]"),
                       ("[1e-300, 0, 0, 0]", "[1, 0, 0, 0]")):
        a = spidersim.loads(ARM % odd).simulate(jit=False)
        b = spidersim.loads(ARM % plain).simulate(jit=False)
        assert np.all(np.isfinite(a["arm.payload_pos"]))
        assert np.allclose(a["arm.payload_pos"], b["arm.payload_pos"], rtol=1e-14, atol=1e-14)
        assert np.allclose(a["arm.q"], b["arm.q"], rtol=1e-14, atol=1e-14)


def test_zero_payload_quaternion_refused():
    with pytest.raises(spidersim.SpidersimError) as ei:
        spidersim.loads(ARM % "[0, 0, 0, 0]")
    msg = str(ei.value)
    assert "block 'arm'" in msg and "payload_quat0" in msg and "zero vector" in msg, msg
    assert "np.float64" not in msg


CONTACT = """\
blocks:
  ec: {type: ElasticContact, normal: %s}
  pm: {type: PointMass, m: 1, p0: [0, 0, 0.1], v0: [0, 0, -1]}
connections: [pm.pos -> ec.pos, pm.vel -> ec.vel, ec.force -> pm.f]
simulation: {t_end: 0.2}
log: [pm.pos, ec.fn]
"""


def test_tiny_contact_normal_is_the_axis():
    """normal [0, 0, 1e-300] is the plane z = 0 of normal [0, 0, 1]: the same bounce."""
    a = spidersim.loads(CONTACT % "[0, 0, 1e-300]").simulate(jit=False)
    b = spidersim.loads(CONTACT % "[0, 0, 1]").simulate(jit=False)
    assert np.max(a["ec.fn"]) > 0
    assert np.array_equal(a["pm.pos"], b["pm.pos"]) and np.array_equal(a["ec.fn"], b["ec.fn"])
