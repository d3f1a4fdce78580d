"""The parts of the service's command translation (spidersim.service.commands), alone.

Each command kind is a function of (model, spec, command, overrides); here the model is a
stand-in holding only what the commands read (inferred units, parameter values, state
declarations), and the spec is parsed from a few lines: no Diagram is built, nothing is
compiled, no server runs. Whole requests on the shipped models are test_commands.py.
"""
import math
from types import SimpleNamespace

import numpy as np
import pytest

from spidersim.blocks.base import State
from spidersim.diagram.spec import parse_text
from spidersim.errors import ParameterError
from spidersim.service import commands as C

MODEL = """\
blocks:
  ref: {type: Step}
  path: {type: TrapezoidalProfile}
  g: {type: Gain}
connections: [ref.y -> g.u]
commands:
  step:
    doc: a step
    set: {ref.t_step: 0.5}
    arguments:
      ref.after: {doc: final value, unit: rad}
      g.k: {default: 2}
    t_end: 3
"""


def fake_model(units=None):
    """What the commands read from a loaded model: units, the Step's parameters and the
    block classes (the units of parameters)."""
    from spidersim.blocks import lookup
    flat = {n: SimpleNamespace(cls=lookup(t), params={})
            for n, t in (("ref", "Step"), ("path", "TrapezoidalProfile"), ("g", "Gain"))}
    return SimpleNamespace(units=units or {}, spec=None, flat=SimpleNamespace(blocks=flat),
                           blocks={"ref": SimpleNamespace(params={"value": 1.0})})


def test_trapezoid_parameters_take_exactly_the_given_time():
    """Hand derivation: accelerating at a_max for t_a = v_max/a_max, cruising, braking
    t_a; distance v_max (T - t_a). With v_max = 1.5 d/T and a_max = 4.5 d/T^2 the
    acceleration phase is T/3 and the distance is d, to rounding."""
    q, t = np.array([0.2, -0.4]), np.array([0.3, 1.5])
    p = C.profile_parameters("TrapezoidalProfile", q, t)
    T, d = 1.2, 0.6
    t_acc = p["v_max"] / p["a_max"]
    assert t_acc == pytest.approx(T / 3, rel=1e-12)
    assert p["v_max"] * (T - t_acc) == pytest.approx(d, rel=1e-12)
    assert (p["q0"], p["q1"], p["t_start"]) == (0.2, -0.4, 0.3)
    assert C.profile_parameters("QuinticProfile", q, t) == {
        "q0": 0.2, "q1": -0.4, "t_start": 0.3, "T": pytest.approx(T, rel=1e-12)}
    still = C.profile_parameters("TrapezoidalProfile", np.array([1.0, 1.0]), t)
    assert still["v_max"] > 0 and still["a_max"] > 0          # valid even with no move


def test_table_replaces_the_source_in_the_inferred_unit():
    """A table given in degrees for a source whose output the model infers in rad becomes
    a TimeTable with the values times pi/180; request parameters of that block are
    refused (the block is gone)."""
    spec = parse_text(MODEL)
    C._table_command(fake_model({("ref", "out", "y"): "rad"}), spec,
                     {"time": [0, 1], "value": [0, 90], "unit": "deg"}, {})
    b = spec.blocks["ref"]
    assert b.type == "TimeTable" and b.params["time"] == [0.0, 1.0]
    np.testing.assert_allclose(b.params["value"], [0.0, math.pi / 2], rtol=1e-15)
    with pytest.raises(ParameterError, match="'ref.after' belongs to block 'ref', which "
                                             "the table command replaces"):
        C._table_command(fake_model(), parse_text(MODEL), {"time": [0], "value": [1]},
                         {"ref.after": 2})


def test_joint_path_of_three_points_is_a_via_point_profile():
    """More than two points replace the trajectory block by a ViaPointProfile through
    them; two points only set its parameters; times must increase from t >= 0."""
    spec = parse_text(MODEL)
    C._joint_path_command(fake_model(), spec, {"points": [0, 1, 0.5],
                                               "times": [0, 1, 2]}, {})
    assert spec.blocks["path"].type == "ViaPointProfile"
    assert spec.blocks["path"].params == {"points": [0, 1, 0.5], "times": [0, 1, 2]}
    over = {}
    C._joint_path_command(fake_model(), parse_text(MODEL), {"points": [0, 1],
                                                            "times": [0, 2]}, over)
    assert over == {"path.q0": 0.0, "path.q1": 1.0, "path.t_start": 0.0,
                    "path.v_max": 0.75, "path.a_max": 1.125}
    with pytest.raises(ParameterError, match="strictly increasing from t >= 0"):
        C._check_path_points(np.array([0, 1]), np.array([1.0, 1.0]), None)


def test_named_command_sets_arguments_and_defaults():
    """A named command sets its fixed values, the arguments given (a value with a unit is
    converted to the parameter's unit, here the rad the wiring gives the Step) and the
    defaults of the others; it returns its run length."""
    over = {}
    model = fake_model({("ref", "param", "after"): "rad"})
    t_end = C._named_command(model, parse_text(MODEL), {
        "name": "step", "arguments": {"ref.after": {"value": 180, "unit": "deg"}}}, over)
    assert t_end == 3
    assert over == {"ref.t_step": 0.5, "g.k": 2, "ref.after": {
        "value": pytest.approx(math.pi, rel=1e-15), "unit": "rad"}}
    with pytest.raises(ParameterError, match="has no argument 'x'; arguments: ref.after, g.k"):
        C._named_command(fake_model(), parse_text(MODEL), {"name": "step",
                                                           "arguments": {"x": 1}}, {})
    with pytest.raises(ParameterError, match="'ref.t_step' is set by the command"):
        C._named_command(fake_model(), parse_text(MODEL), {"name": "step"},
                         {"ref.t_step": 1})


def test_argument_value_units():
    """A list with a unit stays a list, a number a float, both in the parameter's unit
    (a Step's t_step in s, whatever the command declares); a plain number is in the
    declared unit; without a declared unit a plain value is passed on unchanged; a
    parameter whose unit the wiring leaves open gets a number in the declared unit (none
    declared: the value with its unit, which the loader keeps); a diagram parameter the
    value with its unit (the loader converts it to SI); a malformed one names the form."""
    m = fake_model()
    assert C.argument_value(m, "ref.t_step", {"value": [1, 2], "unit": "ms"}, "s", "a") == {
        "value": [0.001, 0.002], "unit": "s"}
    assert C.argument_value(m, "ref.t_step", 5, "ms", "a") == {"value": 0.005, "unit": "s"}
    assert C.argument_value(m, "ref.t_step", {"value": 1, "unit": "min"}, "ms", "a") == {
        "value": 60.0, "unit": "s"}
    assert C.argument_value(m, "ref.t_step", 5, "", "a") == 5
    # a unit the wiring leaves open: a plain number in the declared unit
    assert C.argument_value(m, "ref.after", {"value": 1, "unit": "cm"}, "mm", "a") == 10.0
    assert C.argument_value(m, "ref.after", {"value": 1, "unit": "cm"}, "", "a") == {
        "value": 1, "unit": "cm"}
    assert C.argument_value(m, "T0", "2*x", "ms", "a") == {"value": "2*x", "unit": "ms"}
    with pytest.raises(ParameterError, match=r'a: a value with a unit is \{"value": x, '
                                             r'"unit": "s"\}'):
        C.argument_value(m, "ref.t_step", {"value": 5}, "s", "a")


@pytest.mark.parametrize("kind", ["bogus", None, ["table"], {"a": 1}])
def test_unknown_command_kind(kind):
    """Any kind that is not one of the four (also a list or a mapping from JSON) is a
    ParameterError listing the kinds, not a TypeError."""
    with pytest.raises(ParameterError, match="command.kind must be table, joint_path, "
                                             "cartesian_line or named"):
        C.apply_command(fake_model(), parse_text(MODEL), {"kind": kind}, {})


def test_named_commands_section_checks():
    """Entries must be mappings with known keys; a list of argument names is accepted."""
    entry = C._command_entry("c", {"arguments": ["a.x"], "t_end": 2}, None, 5)
    assert entry["arguments"] == {"a.x": {"doc": "", "unit": "", "default": None}}
    with pytest.raises(ParameterError, match="unknown key\\(s\\) dco; keys are doc") as ei:
        C._command_entry("c", {"dco": "x"}, SimpleNamespace(file="m.yaml"), 5)
    assert ei.value.line == 5
    assert C._command_entry("c", {"arguments": None, "set": None}, None, 5)["set"] == {}
    with pytest.raises(ParameterError, match="command 'c': must be a mapping .*, got 3"):
        C._command_entry("c", 3, None, 5)


@pytest.mark.parametrize("name, entry, line, words", [
    ("c", "doc: [a, b]", 3, "'doc' must be a text, got a list"),
    ("c", "doc: {a: 1}", 3, "'doc' must be a text, got a mapping"),
    ("c", "doc: 3", 3, "'doc' must be a text, got 3"),
    ("'c 1'", "doc: x", 2, "not a command name: .* an identifier"),
    ("1c", "doc: x", 2, "not a command name"),
    ("c-1", "doc: x", 2, "not a command name"),
    ("c", "set: {g.k: 3}\n    arguments:\n      g.k: {doc: gain}", 5,
     "'g.k' is both fixed by 'set' and an argument"),
    ("c", "set: {g.k: 3}\n    arguments: [g.k]", 4,
     "'g.k' is both fixed by 'set' and an argument"),
])
def test_malformed_command_entries_located(name, entry, line, words):
    """A ``doc`` that is not a text (was written as its Python repr), a name a request
    cannot spell, a parameter both fixed and an argument: refused at the line of what is
    wrong, naming the command."""
    spec = parse_text(f"blocks: {{g: {{type: Gain}}}}\ncommands:\n  {name}:\n    {entry}\n")
    with pytest.raises(ParameterError, match=f"command '{name.strip(chr(39))}': {words}") \
            as ei:
        C.named_commands(spec)
    assert ei.value.line == line + 1


def test_valid_command_entries_as_documented():
    """What the README documents stays valid: a doc text, arguments as a mapping or a
    list, set on other parameters, a t_end."""
    spec = parse_text("blocks: {g: {type: Gain}, h: {type: Gain}}\ncommands:\n"
                      "  move_1:\n    doc: a move\n    set: {h.k: 2}\n"
                      "    arguments: [g.k]\n    t_end: 12\n  _other: {}\n")
    cmds = C.named_commands(spec)
    assert cmds["move_1"] == {"doc": "a move", "set": {"h.k": 2}, "t_end": 12.0,
                              "arguments": {"g.k": {"doc": "", "unit": "", "default": None}}}
    assert cmds["_other"]["doc"] == ""


@pytest.mark.parametrize("key, value", [("arguments", ""), ("arguments", 0),
                                        ("arguments", False), ("arguments", "a.x"),
                                        ("set", ""), ("set", []), ("set", 0)])
def test_named_command_arguments_and_set_must_be_mappings(key, value):
    """An empty text, 0 or false for ``arguments`` or ``set`` is an error naming the key
    and what was found (they used to pass as "nothing", hiding a typo)."""
    with pytest.raises(ParameterError, match=f"command 'c': '{key}' must be a mapping"):
        C._command_entry("c", {key: value}, SimpleNamespace(file="m.yaml"), 5)


def test_initial_states_through_their_parameters_and_run_length():
    """An initial state is set through the parameter it starts from; a state with a fixed
    start is refused. The run length is the request's, else the command's, else the
    model's, and must be positive."""
    class Motor:
        type_name = "Motor"
        parameters = {"w0": None}
        states = {"w": State(initial="w0"), "i": State(initial=0.0)}
    d0 = SimpleNamespace(layout=SimpleNamespace(blocks={"m": SimpleNamespace(cls=Motor)}))
    over = {}
    C._set_initial_states(d0, {"m.w": 3.0}, over, None)
    assert over == {"m.w0": 3.0}
    with pytest.raises(ParameterError, match="starts from a fixed value"):
        C._set_initial_states(d0, {"m.i": 1.0}, {}, None)
    d = SimpleNamespace(simulation={"t_end": 7.0})
    assert [C._run_length({"t_end": 2}, 5, d, None), C._run_length({}, 5, d, None),
            C._run_length({}, None, d, None)] == [2.0, 5.0, 7.0]
    with pytest.raises(ParameterError, match="t_end must be a positive number"):
        C._run_length({"t_end": -1}, None, d, None)


@pytest.mark.parametrize("decl, words", [
    (3, "argument 't_latch' must be declared by a mapping .* got 3; a default value is "
        "written \\{default: 3\\}"),
    ([1, 2], "argument 't_latch' must be declared by a mapping .* got a list"),
    ({"defualt": 3}, "argument 't_latch' has unknown key\\(s\\) defualt; keys are doc, "
                     "unit, default"),
    ({"unit": 5}, "argument 't_latch' 'unit' must be a text, got 5"),
    ({"unit": "xyz"}, "argument 't_latch' 'unit': unknown unit 'xyz'"),
])
def test_argument_declaration_that_is_not_a_mapping(decl, words):
    """An argument declared by a plain value (``t_latch: 3``: the default written where the
    declaration belongs), a list, an unknown key, a unit that is not a text or not a unit:
    a ParameterError naming the command and the argument at the command's line (was an
    AttributeError from ``3.get``)."""
    with pytest.raises(ParameterError, match="command 'c': " + words) as ei:
        C._command_entry("c", {"arguments": {"t_latch": decl}},
                         SimpleNamespace(file="m.yaml"), 5)
    assert ei.value.line == 5 and ei.value.file == "m.yaml"
    assert C._command_entry("c", {"arguments": {"t_latch": None}}, None, 5)["arguments"] == {
        "t_latch": {"doc": "", "unit": "", "default": None}}


@pytest.mark.parametrize("text", ["12", "1e3", "2*3", "1.5", "0.5e-3", ".inf", "true",
                                  "[3]", "0", "-1", "1e3x", "'12'", "1e400", ".nan", "pi"])
def test_command_t_end_follows_the_simulation_section(text):
    """A command's ``t_end`` takes what ``simulation.t_end`` takes, with the same value
    (``1e3``, a YAML text, and ``2*3`` are expressions; it refused them), and refuses what
    it refuses, with its message (a boolean, a list, 0, infinite, not a number)."""
    import spidersim
    from spidersim.diagram.spec import parse_text as parse
    model = ("blocks: {c: {type: Constant}, g: {type: Gain}}\nconnections: [c.y -> g.u]\n"
             f"simulation: {{t_end: {text}}}\n")
    command = f"blocks: {{g: {{type: Gain}}}}\ncommands:\n  c:\n    t_end: {text}\n"
    try:
        expected = spidersim.loads(model).simulation["t_end"]
    except spidersim.SpidersimError as exc:
        expected = exc.message.replace("simulation.t_end", "command 'c': t_end")
    try:
        got = C.named_commands(parse(command))["c"]["t_end"]
    except ParameterError as exc:
        assert exc.line == 4
        got = exc.message
    assert got == expected and type(got) is type(expected)


@pytest.mark.parametrize("t_end", [True, False, "2", [1], {"a": 1}, math.inf])
def test_request_t_end_booleans_and_texts_refused(t_end):
    """A request's ``t_end`` of JSON ``true`` ran for 1 s and a text was a ValueError:
    both are ParameterErrors now, like a negative time."""
    d = SimpleNamespace(simulation={"t_end": 7.0})
    with pytest.raises(ParameterError, match="t_end must be a positive number of seconds"):
        C._run_length({"t_end": t_end}, None, d, None)


def test_command_numbers_refuse_booleans():
    """``[0, true]`` as table times is not ``[0, 1]``: a boolean among the numbers of a
    command is refused, naming the field."""
    with pytest.raises(ParameterError, match="command.time must hold numbers, got a boolean"):
        C._numbers([0, True], "time", None)
    with pytest.raises(ParameterError, match="command.distance must hold numbers"):
        C._scalar_with_unit(True, "distance", "m", None)


@pytest.mark.parametrize("body", [
    '{"model": "servo", "t_end": true}',
    '{"model": "servo", "t_end": "2"}',
    '{"model": "servo", "command": {"kind": "table", "time": [0, true], "value": [0, 1]}}',
    '{"model": "servo", "command": {"kind": "cartesian_line", "direction": [1, 0, 0], '
    '"distance": false}}',
    '{"model": "servo", "parameters": {"motor.R": {"value": true, "unit": "Ohm"}}}',
])
def test_request_numbers_refuse_booleans_and_texts(body):
    """A request's numbers are JSON numbers: pydantic's lax mode read ``"t_end": true`` as
    1.0 s and ``[0, true]`` as ``[0, 1]`` before any check of ours saw them; now the
    request is invalid (422), naming the field."""
    from pydantic import ValidationError

    from spidersim.service.app import RunRequest
    with pytest.raises(ValidationError, match="valid number"):
        RunRequest.model_validate_json(body)
    ok = RunRequest.model_validate_json('{"model": "servo", "t_end": 2, "command": {"kind": '
                                        '"table", "time": [0, 1.5], "value": [0, 1]}}')
    assert ok.t_end == 2.0 and ok.command.time == [0.0, 1.5]


@pytest.mark.parametrize("t_end", [1e-300, 5e-324, 9.9e-8])
def test_command_t_end_shorter_than_the_shortest_run_is_refused(t_end):
    """A command's t_end below the solvers' shortest run (1e-7 s) passed check and failed
    when run: refused by the rule of the file's simulation.t_end, at its line; 1e-7 s is
    accepted."""
    spec = SimpleNamespace(file="m.yaml")
    with pytest.raises(ParameterError, match=r"command 'c': t_end must be at least 1e-07 s "
                                             r"\(the shortest run") as ei:
        C._command_entry("c", {"t_end": t_end}, spec, 5)
    assert ei.value.file == "m.yaml" and ei.value.line == 5
    assert C._command_entry("c", {"t_end": 1e-7}, spec, 5)["t_end"] == 1e-7
