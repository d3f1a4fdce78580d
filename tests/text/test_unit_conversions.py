"""Unit conversions that pint alone gets wrong for a simulator (spidersim.text.units).

Each value is checked against a hand derivation: 1 Hz = 1 rev/s = 2 pi rad/s between a
frequency and an angular unit (pint treats rad as dimensionless and converts rad/s -> Hz
with factor 1), temperatures with an offset (20 degC = 293.15 K, not 20 x 274.15),
logarithmic units and numbers inside a unit text refused (pint reads "1e-3 m" as
1/e**3 m, e the elementary charge). Through the loader, errors carry file:line.
"""
import itertools
import math

import numpy as np
import pytest

import spidersim
from spidersim.diagram.units import UnitMismatchError
from spidersim.errors import ParameterError
from spidersim.text import units as U

TWO_PI = 2.0 * math.pi


def f(src, dst):
    return U.factor(U.parse(src), U.parse(dst))


# ---------------------------------------------------------------- Hz against angles
@pytest.mark.parametrize("src, dst, hand", [
    ("rpm", "Hz", 1 / 60),                    # 60 rpm = 1 rev/s = 1 Hz
    ("rev/min", "Hz", 1 / 60),                # the Modelica spelling of rpm
    ("rad/s", "Hz", 1 / TWO_PI),              # 2 pi rad/s = 1 Hz
    ("Hz", "rad/s", TWO_PI),
    ("kHz", "rad/s", 1000 * TWO_PI),          # prefixed Hz counts too
    ("revolution/s", "Hz", 1.0),
    ("rev/s", "Hz", 1.0),
    ("turn/s", "Hz", 1.0),
    ("cycle/s", "Hz", 1.0),
    ("deg/s", "Hz", 1 / 360),                 # 360 deg/s = 1 rev/s
    ("Hz", "rpm", 60.0),
    ("N.m/Hz", "N.m.s/rad", 1 / TWO_PI),      # per cycle/s -> per rad/s
    ("rad/s2", "Hz/s", 1 / TWO_PI),
    ("Hz.s", "rad", TWO_PI),                  # integrating Hz counts cycles
    # no angle on one side: plain SI (rad dimensionless, Hz = 1/s)
    ("Hz", "1/s", 1.0),
    ("kHz", "1/s", 1000.0),
    ("rad/s", "1/s", 1.0),
    ("rpm", "rad/s", TWO_PI / 60),
    ("deg", "rad", math.pi / 180),
    ("Hz.s", "1", 1.0),
])
def test_hz_is_a_cycle_per_second_against_angles(src, dst, hand):
    """Hand factors of frequency/angle conversions (1 Hz = 1 rev/s = 2 pi rad/s when the
    other side holds an angle, factor 1 to 1/s), and the inverse conversion is 1/f."""
    assert f(src, dst) == pytest.approx(hand, rel=1e-14)
    assert f(dst, src) == pytest.approx(1 / hand, rel=1e-14)


def test_same_separates_rad_per_s_from_hz():
    """The port checks' notion of 'same unit' (factor 1): rad/s is not Hz (2 pi apart), Hz
    is 1/s and rad/s is 1/s (SI), rpm is neither."""
    p = U.parse
    assert not U.same(p("rad/s"), p("Hz"))
    assert not U.same(p("Hz"), p("rad/s"))
    assert U.same(p("Hz"), p("1/s")) and U.same(p("rad/s"), p("1/s"))
    assert U.same(p("rev/s"), p("Hz"))
    assert not U.same(p("rpm"), p("Hz")) and not U.same(p("rpm"), p("rad/s"))


def _param(text, block, name):
    return np.asarray(spidersim.loads(text).blocks[block].params[name], dtype=float)


@pytest.mark.parametrize("block, name, given, hand", [
    ("Sine", "f", "{value: 60, unit: rpm}", 1.0),
    ("Sine", "f", "{value: 6.283185307179586, unit: rad/s}", 1.0),
    ("Sine", "f", "{value: 1, unit: revolution/s}", 1.0),
    ("Sine", "f", "{value: 2, unit: kHz}", 2000.0),
    ("RDC", "f_n", "{value: 3000, unit: rad/s}", 3000 / TWO_PI),   # 477.46 Hz
    ("DCMotor", "w0", "{value: 1, unit: Hz}", TWO_PI),
    ("DCMotor", "w0", "{value: 955, unit: rpm}", 955 * TWO_PI / 60),
])
def test_block_parameters_with_frequency_units(block, name, given, hand):
    """The reviewers' reproducers: Sine f in rpm and rad/s, RDC f_n in rad/s, DCMotor w0 in
    Hz reach the block in its declared unit by the hand factor."""
    feed = {"RDC": "theta", "DCMotor": "v"}.get(block)
    text = f"blocks:\n  b: {{type: {block}, {name}: {given}}}\n"
    if feed:
        text += f"  z: {{type: Constant, value: 0}}\nconnections:\n  - z.y -> b.{feed}\n"
    assert float(_param(text, "b", name)) == pytest.approx(hand, rel=1e-12)


def test_a_sine_given_in_rpm_has_the_period_of_its_rpm():
    """60 rpm is one period a second: the simulated Sine (interpreted) is 1 at t = 0.25 s
    and -1 at 0.75 s, 0 at 0.5 s (the old factor 2 pi gave 6.28 Hz)."""
    d = spidersim.loads("blocks:\n  s: {type: Sine, f: {value: 60, unit: rpm}}\n"
                        "simulation: {t_end: 1.0, method: DP54}\nlog: all\n")
    r = d.simulate(output_interval=0.25, jit=False)
    y = np.interp([0.25, 0.5, 0.75], r.t, r["s.y"])
    assert y == pytest.approx([1.0, 0.0, -1.0], abs=1e-9)


PORTS = """
blocks:
  c: {{type: Constant, value: 1}}
  a: {{type: UnitCast, unit: "{a}"}}
  b: {{type: UnitCast, unit: "{b}"}}
  s: {{type: Sum, signs: "+-"}}
connections:
  - c.y -> a.u, b.u
  - a.y -> s.u1
  - b.y -> s.u2
"""


def test_a_signal_in_rad_per_s_against_hz_is_a_unit_mismatch():
    """Ports: a Sum of a rad/s and a Hz signal is a 2 pi error and refused at the block;
    Hz with 1/s and rad/s with 1/s pass (factor 1)."""
    with pytest.raises(UnitMismatchError, match=r"rad/s|Hz"):
        spidersim.loads(PORTS.format(a="rad/s", b="Hz"))
    spidersim.loads(PORTS.format(a="Hz", b="1/s"))
    spidersim.loads(PORTS.format(a="rad/s", b="1/s"))


THREE = """
blocks:
  c: {{type: Constant, value: 1}}
  a: {{type: UnitCast, unit: "{}"}}
  b: {{type: UnitCast, unit: "{}"}}
  e: {{type: UnitCast, unit: "{}"}}
  s: {{type: Sum, signs: "+++"}}
connections:
  - c.y -> a.u, b.u, e.u
  - a.y -> s.u1
  - b.y -> s.u2
  - e.y -> s.u3
"""


@pytest.mark.parametrize("order", list(itertools.permutations(["1/s", "Hz", "rad/s"])))
def test_hz_and_rad_per_s_meeting_through_one_per_second_are_refused_in_any_order(order):
    """'Same unit' is not transitive (Hz ~ 1/s ~ rad/s): a Sum of the three is refused
    whatever the order of its inputs (comparing with the class's first unit only accepted
    two of the six orders)."""
    with pytest.raises(UnitMismatchError, match=r"rad/s.*Hz|Hz.*rad/s"):
        spidersim.loads(THREE.format(*order))


# ---------------------------------------------------------------- offsets
@pytest.mark.parametrize("src, dst, a, b", [
    ("degC", "K", 1.0, 273.15),
    ("K", "degC", 1.0, -273.15),
    ("degF", "K", 5 / 9, 273.15 - 32 * 5 / 9),      # 255.372...
    ("degC", "degF", 9 / 5, 32.0),
    ("degR", "K", 5 / 9, 0.0),                      # Rankine: absolute, no offset
    ("K", "K", 1.0, 0.0),
])
def test_temperatures_convert_with_their_offset(src, dst, a, b):
    """value_dst = a value_src + b for lone temperatures, by hand: 0 degC = 273.15 K,
    a degree F is 5/9 K and 32 degF = 0 degC."""
    got_a, got_b = U.affine(U.parse(src), U.parse(dst))
    assert got_a == pytest.approx(a, rel=1e-14)
    assert got_b == pytest.approx(b, rel=1e-14, abs=1e-12)


def test_a_temperature_in_a_product_is_a_difference():
    """pint reads degC inside a product as a difference (W/degC = W/K, factor 1); a lone
    degC never converts by a factor, nor to a difference."""
    assert f("W/degC", "W/K") == pytest.approx(1.0, rel=1e-15)
    assert f("degC/s", "K/s") == pytest.approx(1.0, rel=1e-15)
    with pytest.raises(U.UnitError, match="offset"):
        f("degC", "K")                        # the old factor was 274.15
    with pytest.raises(U.UnitError, match="offset"):
        U.affine(U.parse("degC"), U.parse("delta_degC"))


def test_diagram_parameters_in_degc_and_degf_become_kelvin():
    """20 degC, 68 degF -> 293.15 K; a list [0, 100] degC -> [273.15, 373.15] K."""
    d = spidersim.loads("parameters:\n  T0: {value: 20, unit: degC}\n"
                        "  T1: {value: 68, unit: degF}\n  T2: {value: [0, 100], unit: degC}\n"
                        "blocks:\n  c: {type: Constant, value: [T0, T1]}\n"
                        "  c2: {type: Constant, value: T2}\n")
    assert d.blocks["c"].params["value"] == pytest.approx([293.15, 293.15], rel=1e-14)
    assert d.blocks["c2"].params["value"] == pytest.approx([273.15, 373.15], rel=1e-14)


def test_an_offset_unit_on_an_inheriting_parameter_is_refused_at_its_line():
    """A Constant's value keeps its unit without converting: a signal in degC could not be
    multiplied or compared by a factor, so it is refused (write K)."""
    with pytest.raises(ParameterError) as e:
        spidersim.loads("blocks:\n  c: {type: Constant, value: {value: 20, unit: degC}}\n")
    assert ":2:" in str(e.value) and "offset" in str(e.value) and "K" in str(e.value)


# ---------------------------------------------------------------- refused texts
@pytest.mark.parametrize("text, words", [
    ("dB", "logarithmic"), ("Np", "logarithmic"), ("octave", "logarithmic"),
    ("decade", "logarithmic"), ("dBm", "logarithmic"), ("dB/s", "logarithmic"),
    ("B", "byte"), ("kB", "byte"),
    ("1e-3 m", "a number"), ("1e3", "a number"), ("1E-3 m", "a number"), ("1 m", "a number"),
    ("0.001 m", "a number"), ("2/s", "a number"), ("m.1e3", "a number"),
    ("e", "elementary_charge"), ("ke", "elementary_charge"), ("m/e", "elementary_charge"),
    ("pi", "constant pi"), ("c", "speed_of_light"), ("k", "boltzmann"),
    ("m s", "side by side"), ("N m", "side by side"), ("m(s)", "dot"),
    ("Nm", "N.m"),
])
def test_texts_that_are_not_units_are_refused(text, words):
    """pint would give these a factor: dB 1.26, B (byte) 8, '1e-3 m' 2.4e56 (1/e**3), e the
    elementary charge 1.6e-19, 'm s' the millisecond, 'Nm' km/kg; each is a UnitError
    naming why."""
    with pytest.raises(U.UnitError, match=words):
        U.parse(text)


@pytest.mark.parametrize("text, dst, hand", [
    ("1/s", "Hz", 1.0), ("(1/s)", "Hz", 1.0), ("s-1", "Hz", 1.0), ("1/(m.s)", "1/(m.s)", 1.0),
    ("m2", "m2", 1.0), ("mm", "m", 1e-3), ("um", "m", 1e-6), ("mA.h", "A.s", 3.6),
])
def test_the_one_of_one_per_second_and_powers_still_read(text, dst, hand):
    """The numbers a unit may hold: the 1 of 1/s and integer powers after a name."""
    assert f(text, dst) == pytest.approx(hand, rel=1e-14)


@pytest.mark.parametrize("unit, words", [
    ("dB", "logarithmic"), ("1e-3 m", "a number"), ("e", "elementary_charge"),
])
def test_the_loader_refuses_them_at_the_parameter_line(unit, words):
    """A diagram parameter and a block parameter with such a unit: ParameterError with
    file:line and the parameter's name, never a value."""
    with pytest.raises(ParameterError) as e:
        spidersim.loads(f"parameters:\n  G: {{value: 20, unit: '{unit}'}}\n"
                        "blocks:\n  c: {type: Constant, value: G}\n")
    assert ":2:" in str(e.value) and "'G'" in str(e.value) and words in str(e.value)
    with pytest.raises(ParameterError) as e:
        spidersim.loads(f"blocks:\n  m: {{type: DCMotor, R: {{value: 1, unit: '{unit}'}}}}\n"
                        "  z: {type: Constant, value: 0}\nconnections:\n  - z.y -> m.v\n")
    assert ":2:" in str(e.value) and "'R'" in str(e.value) and words in str(e.value)


def test_overrides_with_units_convert_the_same_way():
    """--set / load(set=...) values with units go through the same conversion."""
    text = "blocks:\n  s: {type: Sine}\n"
    d = spidersim.loads(text, set={"s.f": {"value": 120, "unit": "rpm"}})
    assert d.blocks["s"].params["f"] == pytest.approx(2.0, rel=1e-14)
    with pytest.raises(ParameterError, match="a number"):
        spidersim.loads(text, set={"s.f": {"value": 1, "unit": "1e3 Hz"}})


def test_a_value_with_a_unit_inside_another_is_refused():
    """{value: {value: 1, unit: mm}, unit: V/A} gave a gain of 0.001 V/A (the inner mm
    converted to m, the outer unit then kept): refused at the parameter's line."""
    with pytest.raises(ParameterError) as e:
        spidersim.loads("blocks:\n  g: {type: Gain, k: {value: {value: 1, unit: mm}, "
                        "unit: V/A}}\n  c: {type: Constant, value: 1}\n"
                        "connections:\n  - c.y -> g.u\n")
    assert ":2:" in str(e.value) and "not another value with a unit" in str(e.value)
