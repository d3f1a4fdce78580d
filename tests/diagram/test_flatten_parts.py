"""The parts of subsystem flattening (spidersim.diagram.flatten), each on a tiny diagram.

These run the parts alone on specs parsed from short texts: no compilation, no port graph.
Whole diagrams with subsystems are covered by test_subsystem_errors.py and test_errors.py.
"""
import math
import os

import pytest

import spidersim
from spidersim.diagram import flatten as F
from spidersim.diagram.spec import Address, parse_text
from spidersim.diagram.sizes import range_bounds
from spidersim.errors import ParameterError, WiringError

TWO_GAINS = """\
parameters: {k0: 2}
blocks:
  a: {type: Gain, k: k0}
  b: {type: Gain, k: {value: 3, unit: mm}}
connections:
  - a.y -> b.u
"""


def level(text, prefix=""):
    """A fresh :class:`_Level` for the diagram ``text`` with an empty flat diagram."""
    spec = parse_text(text)
    scope, _ = F.eval_parameters(spec, {}, prefix)
    return F._Level(spec, prefix, scope, F.Flat({}, [], {}), [], set())


def test_overrides_split_by_block():
    """``b.p`` is the block's own override, ``b.x.p`` goes deeper, other blocks' entries are
    left out; each keeps the key as written."""
    ov = F._overrides_for("j1", {"j1.R": 1, "j1.motor.R": 2, "j2.R": 3, "j10.R": 4})
    assert ov.own == {"R": ("j1.R", 1)}
    assert ov.deeper == {"motor.R": ("j1.motor.R", 2)}


def test_override_of_an_unknown_block_names_the_level_and_near_blocks():
    """An override whose first part is no block of the level is refused, naming the
    subsystem instance it was looked up in and the closest block names."""
    spec = parse_text(TWO_GAINS)
    with pytest.raises(ParameterError, match=r"--set j1\.aa\.k: there is no block 'aa' in "
                                             r"'j1'; did you mean a\?"):
        F._check_override_targets(spec, "j1.", {"aa.k": 1})
    with pytest.raises(ParameterError, match="in the diagram"):
        F._check_override_targets(spec, "", {"c.k": 1})


def test_block_values_overrides_win_and_are_marked_used():
    """A block's file value is evaluated in the level's scope, an override replaces it and
    its key is recorded as used; a unit given for an inherited-unit parameter is kept."""
    lv = level(TWO_GAINS)
    cls = F._block_class(lv.spec, lv.spec.blocks["a"], "a")
    values, units = F._block_values(lv, lv.spec.blocks["a"], "a", cls, {})
    assert values == {"k": 2} and units == {} and lv.used == set()
    values, units = F._block_values(lv, lv.spec.blocks["a"], "a", cls, {"k": ("a.k", "k0*5")})
    assert values == {"k": 10} and units == {}
    assert lv.used == {"a.k"}
    values, units = F._block_values(lv, lv.spec.blocks["b"], "b", cls, {})
    assert values == {"k": 3} and units == {"k": "mm"}


def test_block_values_unknown_override_parameter():
    """An override of a parameter the block type does not have names the type, the nearest
    parameter and the list of parameters."""
    lv = level(TWO_GAINS)
    cls = F._block_class(lv.spec, lv.spec.blocks["a"], "a")
    with pytest.raises(ParameterError, match=r"--set a\.kk: block type Gain has no parameter "
                                             r"'kk'; did you mean k\? \(parameters: k\)"):
        F._block_values(lv, lv.spec.blocks["a"], "a", cls, {"kk": ("a.kk", 1)})


def test_instantiate_block_validates_and_records_the_instance():
    """A primitive block becomes an Instance with validated parameters (floats) and its
    file line; an override aimed deeper into it is refused (it is not a subsystem)."""
    lv = level(TWO_GAINS)
    F._instantiate_block(lv, "a", lv.spec.blocks["a"], F.BlockOverrides({}, {}))
    inst = lv.flat.blocks["a"]
    assert (inst.path, inst.cls.type_name, inst.params["k"], inst.line) == ("a", "Gain", 2.0, 3)
    with pytest.raises(ParameterError, match="'b' is a Gain block, not a subsystem"):
        F._instantiate_block(lv, "b", lv.spec.blocks["b"],
                             F.BlockOverrides({}, {"x.k": ("b.x.k", 1)}))


def test_addresses_through_a_subsystem_port_map():
    """A slice of a subsystem output is taken inside the slice the output exposes; a
    subsystem input resolves to every primitive input it feeds; a primitive address just
    gets the prefix."""
    spec = parse_text(TWO_GAINS)
    inner = (F.Range(2, 5, "[2:5]", "mux.y", "exposed output 'y'", "sub.yaml", 4),)
    subs = {"s": F.PortMaps({"u": [("p.s.g1", "u"), ("p.s.g2", "u")]},
                            {"y": ("p.s.mux", "y", inner)})}
    addr = F._LocalAddresses(spec, "p.", subs)
    assert addr.source(Address("s", "y"), 1) == ("p.s.mux", "y", inner)
    path, port, ranges = addr.source(Address("s", "y", 1, 3), 7)
    assert (path, port, ranges[0]) == ("p.s.mux", "y", inner[0])
    assert ranges[1] == F.Range(1, 3, "[1:3]", "s.y", "connection source", spec.file, 7,
                                "p.s")                  # reads instance p.s
    assert range_bounds(ranges, 8, path) == (3, 5)          # [1:3] of mux.y[2:5]
    last = addr.source(Address("s", "y", -1, None, single=True), 7)[2]
    assert range_bounds(last, 8, path) == (4, 5)            # [-1] of mux.y[2:5]
    assert addr.source(Address("a", "y", 0, 1), 1)[:2] == ("p.a", "y")
    assert addr.destinations(Address("s", "u"), 1) == [("p.s.g1", "u"), ("p.s.g2", "u")]
    assert addr.destinations(Address("b", "u"), 1) == [("p.b", "u")]


@pytest.mark.parametrize("call,words", [
    (lambda a: a.source(Address("s", "z"), 9), "subsystem instance 's' has no output 'z' "
                                               "(outputs: y)"),
    (lambda a: a.destinations(Address("s", "v"), 9), "has no input 'v' (inputs: none)"),
    (lambda a: a.source(Address("aa", "y"), 9), "unknown block 'aa'; did you mean a?"),
])
def test_address_errors(call, words):
    """Unknown subsystem ports list the ports there are; an unknown block suggests near
    names; all at the connection's line."""
    subs = {"s": F.PortMaps({}, {"y": ("s.g", "y", ())})}
    with pytest.raises(WiringError) as ei:
        call(F._LocalAddresses(parse_text(TWO_GAINS), "", subs))
    assert words in str(ei.value) and ei.value.line == 9


def test_exposed_inputs_record_their_targets():
    """An exposed input maps to the primitive inputs it feeds and each is recorded in
    ``flat.exposed`` with the instance path, the exposed name and the line; a port the
    block does not have is a wiring error naming the block's inputs."""
    text = "blocks:\n  g: {type: Gain}\n  h: {type: Gain}\ninputs:\n  u: [g.u, h.u]\n"
    lv = level(text, prefix="j1.")
    for name in ("g", "h"):
        F._instantiate_block(lv, name, lv.spec.blocks[name], F.BlockOverrides({}, {}))
    addr = F._LocalAddresses(lv.spec, "j1.", {})
    assert F._exposed_inputs(lv, addr) == {"u": [("j1.g", "u"), ("j1.h", "u")]}
    assert lv.flat.exposed[("j1.h", "u")] == ("j1", "u", "<string>", 5)
    lv.spec.inputs["v"] = [Address("g", "w")]
    lv.spec.port_lines[("in", "v")] = 6
    with pytest.raises(WiringError, match=r"block 'g' \(Gain\) has no input 'w'; inputs of "
                                          r"'g': u"):
        F._exposed_inputs(lv, addr)


@pytest.mark.parametrize("section, target, words", [
    # an output mapped to an input port was an internal error (KeyError: 'j1.g.u')
    ("outputs", "g.u", "exposed output 'x' maps to 'g.u', but 'u' is an input port of block "
                       "'g' (Gain): an exposed output must name an output port; outputs of "
                       "'g': y"),
    ("outputs", "g.yy", "block 'g' (Gain) has no output 'yy'; did you mean y?; outputs of "
                        "'g': y"),
    ("inputs", "g.y", "exposed input 'x' maps to 'g.y', but 'y' is an output port of block "
                      "'g' (Gain): an exposed input must name an input port; inputs of 'g': u"),
    ("inputs", "g.uu", "block 'g' (Gain) has no input 'uu'; did you mean u?; inputs of 'g': u"),
])
def test_exposed_port_of_the_wrong_kind_is_refused_at_its_line(section, target, words):
    """An exposed output must name an output port of its block and an exposed input an
    input port: a port of the other kind is named as such, an unknown one gets near names;
    the block's ports of the right kind are listed, at the exposed port's line (line 4 of
    the subsystem file), with the instance path."""
    lv = level(f"blocks:\n  g: {{type: Gain}}\n{section}:\n  x: {target}\n", prefix="j1.")
    F._instantiate_block(lv, "g", lv.spec.blocks["g"], F.BlockOverrides({}, {}))
    addr = F._LocalAddresses(lv.spec, "j1.", {})
    with pytest.raises(WiringError) as ei:
        F._exposed_inputs(lv, addr)
        F._exposed_outputs(lv, addr)
    assert words in ei.value.message
    assert (ei.value.line, ei.value.block) == (4, "j1.g")


def test_exposed_outputs_of_output_ports_are_accepted():
    """The check lets an output port through: the flat output it exposes is returned with
    the element range as written (checked once the sizes are known)."""
    lv = level("blocks:\n  g: {type: Gain}\noutputs:\n  x: g.y\n  z: g.y[0]\n", prefix="j1.")
    F._instantiate_block(lv, "g", lv.spec.blocks["g"], F.BlockOverrides({}, {}))
    out = F._exposed_outputs(lv, F._LocalAddresses(lv.spec, "j1.", {}))
    z = F.Range(0, 1, "[0]", "g.y", "exposed output 'z'", lv.spec.file, 5, "j1.g")
    assert out == {"x": ("j1.g", "y", ()), "z": ("j1.g", "y", (z,))}


def test_unit_factor_to_declared_unit_or_si():
    """mOhm -> Ohm is 1e-3; rpm -> rad/s is 2 pi/60; without a declaration a value goes to
    coherent SI (deg -> rad: pi/180; degC -> K: x + 273.15, the one case with an offset);
    the result is (a, b) of value = a given + b; an inherited unit converts nothing and is
    recorded (but a scale with an offset is refused there); an int parameter takes no unit."""
    import math

    from spidersim.blocks.base import Param
    from spidersim.text.units import UnitError
    a, b = F._unit_factor("mOhm", Param(1.0, "Ohm"), None)
    assert a == pytest.approx(1e-3, rel=1e-15) and b == 0.0
    a, b = F._unit_factor("rpm", Param(1.0, "rad/s"), None)
    assert a == pytest.approx(2 * math.pi / 60, rel=1e-15) and b == 0.0
    a, b = F._unit_factor("deg", None, None)
    assert a == pytest.approx(math.pi / 180, rel=1e-15) and b == 0.0
    assert F._unit_factor("degC", None, None) == pytest.approx((1.0, 273.15), rel=1e-15)
    seen = []
    assert F._unit_factor("N.m", Param(1.0, "*"), seen.append) is None and seen == ["N.m"]
    with pytest.raises(UnitError, match="offset"):
        F._unit_factor("degC", Param(1.0, "*"), seen.append)
    assert seen == ["N.m"]
    with pytest.raises(UnitError, match="a int parameter takes no unit"):
        F._unit_factor("m", Param(1, kind="int"), None)
    with pytest.raises(UnitError):
        F._unit_factor("V", Param(1.0, "Ohm"), None)


def test_unit_factor_with_a_unit_rule_records_without_converting():
    """A declared unit that is a rule (a function of the block's parameters, not a text)
    is inherited like ``*``: recorded, no factor. The rule is tested before the text
    tests (``"@" in unit`` on a function was a TypeError)."""
    from spidersim.blocks.base import Param
    seen = []
    assert F._unit_factor("N", Param(1.0, lambda p: "N"), seen.append) is None
    assert seen == ["N"]


def test_error_in_a_list_element_keeps_the_block():
    """An error inside one element of a list-valued block parameter is located like one
    in the whole value: file, line and the block's path (the list branch passed none)."""
    spec = parse_text("blocks:\n  c: {type: Constant, value: [1, 'nope + 1', 3]}\n",
                      file="d.yaml")
    with pytest.raises(ParameterError) as ei:
        F.flatten(spec)
    assert ei.value.block == "c" and ei.value.line == 2 and ei.value.file == "d.yaml"
    assert "nope" in ei.value.message
    with pytest.raises(ParameterError) as ei:
        F._eval_value([[1, "2 +"]], {}, None, "f", 3, "p", block="x.y")
    assert ei.value.block == "x.y" and ei.value.line == 3


def test_plain_values():
    """Expressions see the scope, lists are evaluated element by element, numbers and
    booleans stay; an empty entry says so."""
    from spidersim.text.expr import ExprError
    assert F._plain_value("2*a", {"a": 1.5}, "f", 1, "p") == 3.0
    assert F._plain_value([1, "a", True], {"a": 1.5}, "f", 1, "p") == [1, 1.5, True]
    with pytest.raises(ExprError, match="no value given"):
        F._plain_value(None, {}, "f", 1, "p")
    with pytest.raises(ParameterError, match="p: no value given"):
        F._plain_value([None], {}, "f", 1, "p")


@pytest.mark.parametrize("value", [[1, [2, 3]], [[1, 2], [3]], [[1], 2]])
def test_ragged_lists_are_refused(value):
    """A list value is a number list or a matrix: rows of unequal length at any depth are
    an ExprError (numpy's inhomogeneous-shape ValueError escaped as an internal error when
    such a diagram parameter was used); a rectangular nested list stays."""
    from spidersim.text.expr import ExprError
    with pytest.raises(ExprError, match="ragged or mixed list"):
        F._plain_value(value, {}, "f", 1, "p")
    assert F._plain_value([[1, 2], [3, 4]], {}, "f", 1, "p") == [[1, 2], [3, 4]]


def test_top_level_overrides_are_evaluated_and_marked_used():
    """Only keys without a dot are top-level; they are evaluated without a scope (so an
    expression of numbers works) and marked used; an unknown one suggests near names."""
    spec = parse_text(TWO_GAINS)
    used = set()
    assert F._top_level_given(spec, {"k0": "3*2", "a.k": 1}, used) == {"k0": 6.0}
    assert used == {"k0"}
    with pytest.raises(ParameterError, match=r"--set k00: the diagram has no parameter 'k00'; "
                                             r"did you mean k0\?"):
        F._top_level_given(spec, {"k00": 1}, set())


def test_quantity_converts_numbers_and_lists():
    """1500 mOhm for an Ohm parameter is 1.5; [90, 180] deg for a diagram parameter is
    [pi/2, pi] rad; a boolean with a unit that needs converting is refused."""
    import math

    from spidersim.blocks.base import Param
    assert F._quantity({"value": 1500, "unit": "mOhm"}, {}, Param(1.0, "Ohm"), "f", 1, "p",
                       None, None) == pytest.approx(1.5, rel=1e-15)
    np_rad = F._quantity({"value": [90, 180], "unit": "deg"}, {}, None, "f", 1, "p", None,
                         None)
    assert np_rad == pytest.approx([math.pi / 2, math.pi], rel=1e-15)
    with pytest.raises(ParameterError, match="a value with a unit must be a number"):
        F._quantity({"value": True, "unit": "mOhm"}, {}, Param(1.0, "Ohm"), "f", 1, "p",
                    None, None)


NAN_PARAM = """\
parameters:
  tau: 1
blocks:
  c: {type: Constant, value: 1}
  g: {type: Gain, k: 'min(2, tau)'}
connections:
  - c.y -> g.u
"""


@pytest.mark.parametrize("text, overrides, words", [
    (NAN_PARAM.replace("tau: 1", "tau: .nan"), {}, "d.yaml:2: parameter 'tau' must not be NaN"),
    (NAN_PARAM.replace("tau: 1", "tau: [1, .nan]"), {}, "parameter 'tau' must not be NaN"),
    (NAN_PARAM, {"tau": float("nan")}, "--set tau must not be NaN"),
])
def test_a_nan_diagram_parameter_is_refused_where_it_is_given(text, overrides, words):
    """``tau: .nan`` with ``k: min(2, tau)`` gave k = 2 (Python's min drops a NaN after a
    number): the parameter is refused at its line, or the override naming it."""
    with pytest.raises(ParameterError) as ei:
        F.flatten(parse_text(text, "d.yaml"), overrides)
    assert words in str(ei.value)


def test_a_nan_subsystem_parameter_is_refused_at_the_instance(tmp_path):
    """An instance value and a ``--set`` of a subsystem parameter get the same check."""
    (tmp_path / "sub.yaml").write_text("parameters:\n  a: 1\nblocks:\n"
                                       "  g: {type: Gain, k: 'max(a, 0)'}\n"
                                       "inputs: {u: g.u}\noutputs: {y: g.y}\n")
    top = ("subsystems: {s: sub.yaml}\nblocks:\n  c: {type: Constant, value: 1}\n"
           "  x: {type: s, a: .nan}\nconnections:\n  - c.y -> x.u\n")
    path = tmp_path / "top.yaml"
    path.write_text(top)
    with pytest.raises(ParameterError, match=r"top.yaml:4: block 'x': parameter 'a' must "
                                             r"not be NaN"):
        F.flatten(F.parse_file(str(path)))
    path.write_text(top.replace("a: .nan", "a: 2"))
    with pytest.raises(ParameterError, match="--set x.a must not be NaN"):
        F.flatten(F.parse_file(str(path)), {"x.a": float("nan")})
    assert F.flatten(F.parse_file(str(path))).blocks["x.g"].params["k"][0] == 2.0


INF_PARAM = """\
parameters:
  t_cut: inf
blocks:
  c: {type: Constant, value: 1}
  cut: {type: Step, t_step: t_cut}
  g: {type: Gain, k: K}
connections:
  - c.y -> g.u
"""


@pytest.mark.parametrize("k, want", [("1/t_cut", 0.0),       # an infinite time: a zero rate
                                     ("min(2, t_cut)", 2.0), ("max(-t_cut, -5)", -5.0)])
def test_an_infinite_diagram_parameter_in_exact_arithmetic_is_kept(k, want):
    """``t_cut: inf`` passed on whole to ``Step.t_step`` (allowed: never) is kept, as in
    joint_torque.yaml; arithmetic with an exact result uses it (``1/t_cut`` is 0, also
    when ``--set`` makes it infinite)."""
    flat = F.flatten(parse_text(INF_PARAM.replace("K}", f"'{k}'}}"), "d.yaml"))
    assert flat.blocks["cut"].params["t_step"] == float("inf")
    assert flat.blocks["g"].params["k"][0] == want
    flat = F.flatten(parse_text(INF_PARAM.replace("K}", f"'{k}'}}").replace("t_cut: inf",
                                                                             "t_cut: 5"),
                                "d.yaml"), {"t_cut": float("inf")})
    assert flat.blocks["g"].params["k"][0] == want


@pytest.mark.parametrize("k, words", [
    ("t_cut", "must be finite"),                          # the Gain's own check
    ("2*t_cut", "must be finite"),
    ("t_cut - t_cut", "'t_cut - t_cut' gives NaN"),
    ("0*t_cut", "'0 * t_cut' gives NaN"),
    ("1e200*1e200", "gives an infinite value from finite numbers"),
    ("1/1e400", "beyond the float range"),
])
def test_an_infinite_or_undefined_value_is_refused_at_the_block(k, words):
    """An infinity reaching a parameter that must be finite, a NaN made from infinities, an
    overflow or a literal beyond the float range: refused at the block's line."""
    with pytest.raises(ParameterError) as ei:
        F.flatten(parse_text(INF_PARAM.replace("K}", f"'{k}'}}"), "d.yaml"))
    assert "d.yaml:6" in str(ei.value) and words in str(ei.value)


LIMIT_PARAM = """\
parameters:
  lim: .inf
  lo: -.inf
  x: [1, .inf]
blocks:
  s: {type: Sine, amplitude: 2, f: 1}
  sat: {type: Saturation, lower: LOWER, upper: UPPER}
connections:
  - s.y -> sat.u
"""


@pytest.mark.parametrize("lower, upper, want", [
    ("-lim", "2*lim", (-math.inf, math.inf)),
    ("'max(lo, -5)'", "'min(lim, 10)'", (-5.0, 10.0)),
    ("-5", "'min(x)'", (-5.0, 1.0)),
    ("lo - 1", "lim + 1", (-math.inf, math.inf)),
])
def test_infinite_limits_in_arithmetic_are_accepted(lower, upper, want):
    """The regression review's cases (refused by the rule that no operator may take an
    infinity): a Saturation's limits from infinite parameters with exact results."""
    flat = F.flatten(parse_text(LIMIT_PARAM.replace("LOWER", lower).replace("UPPER", upper),
                                "d.yaml"))
    p = flat.blocks["sat"].params
    assert (p["lower"], p["upper"]) == want


def test_an_infinite_fault_time_is_the_no_fault_baseline():
    """``check diagrams/impact_fault.yaml --set t_fault=inf`` (no fault) was refused at
    ``detect: t_fault + t_detect``; the detection and the current cut are never too."""
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    m = spidersim.load(os.path.join(root, "diagrams", "impact_fault.yaml"),
                       set={"t_fault": math.inf})
    assert [m.flat.blocks[b].params["t_step"] for b in ("fault", "detect")] == [math.inf] * 2


def test_a_unit_conversion_that_overflows_is_refused():
    """1e308 km is 1e311 m: infinite; it was kept as inf (accepted by a parameter that may
    be infinite, Step.t_step as 'never'); an infinity given with a unit stays one."""
    from spidersim.blocks.base import Param
    with pytest.raises(ParameterError, match="overflows to infinity when converted"):
        F._quantity({"value": 1e308, "unit": "ks"}, {}, Param(0.0, "s", allow_inf=True),
                    "f", 1, "p", None, None)
    assert F._quantity({"value": "inf", "unit": "ks"}, {}, Param(0.0, "s", allow_inf=True),
                       "f", 1, "p", None, None) == float("inf")


def test_a_unit_conversion_that_overflows_in_a_list_with_an_infinity_is_refused():
    """``lims: {value: [1e306, -.inf], unit: km}`` then ``upper: lims[0]``: the element
    1e306 km overflowed to inf and was kept (the check skipped a list holding any
    infinity; check said OK); element by element, the given infinity stays one."""
    text = ("parameters:\n  lims: {value: [1e306, -.inf], unit: km}\n  hi: 'lims[0]'\n"
            "blocks:\n  s: {type: Sine}\n  sat: {type: Saturation, upper: hi}\n"
            "connections:\n  - s.y -> sat.u\n")
    with pytest.raises(ParameterError, match=r"d.yaml:2: parameter 'lims': .*overflows to "
                                             r"infinity when converted"):
        F.flatten(parse_text(text, "d.yaml"))
    flat = F.flatten(parse_text(text.replace("1e306", "2"), "d.yaml"))
    assert flat.blocks["sat"].params["upper"] == 2000.0
    assert F._converted([1.0, -math.inf], (1000.0, 0.0), "km", "f", 1, "p",
                        None) == [1000.0, -math.inf]
