"""A run request -> a :class:`spidersim.Diagram` ready to simulate.

A request (JSON) names the model and may give::

    parameters   {"motor.R": 1.2, "V_max": 20}     diagram or block parameters (--set paths)
    initial      {"arm.q": [0, 0.5, ...]}            initial states (block.state), set through
                                                     the parameter the state starts from
    t_end        simulated time [s]
    log          signals to record (default: the model's log list)
    command      one of the commands below

Commands, at the levels of the paper's section VI:

``{"kind": "table", "block": "ref", "time": [...], "value": [...]}``
    low-level set points: the source block ``ref`` (a scalar Step, Ramp, Sine, Pulse,
    Constant or TimeTable of the top-level diagram) is replaced by a ``TimeTable`` with these
    points (piecewise linear, end values held). In servo.yaml ``ref`` is the position set
    point; a table on a current or voltage source sets motor current set points.
``{"kind": "joint_path", "block": "ref", "points": [q_a, q_b, ...], "times": [t_a, t_b, ...]}``
    a joint-space move given by via points and their times (one time per point, strictly
    increasing from t >= 0) for the trajectory block ``ref`` (a TrapezoidalProfile or
    QuinticProfile of the top-level diagram). Two points become its parameters
    (QuinticProfile: ``q0, q1, T = t_b - t_a, t_start = t_a``; TrapezoidalProfile: the same
    ends with ``v_max = 1.5 d/T`` and ``a_max = 4.5 d/T^2``, so that the move, a third
    accelerating, a third cruising, a third braking, takes exactly T). More points replace
    ``ref`` by a ``ViaPointProfile`` through them (quintic segments, C2, passing every point
    at its time); the request may then not set parameters of ``ref``.
``{"kind": "cartesian_line", "direction": [x, y, z], "distance": m, "speed": m/s,
   "accel": m/s2, "t_start": s}``
    a straight flange move: the parameters of a ``CartesianLineIK`` block and of the
    ``TrapezoidalProfile`` feeding its path length ``s`` (spider.yaml's ``ik`` and ``path``).
``{"kind": "named", "name": "capture_payload", "arguments": {"t_latch": 2.5}}``
    a high-level command the model declares in its ``commands`` section::

        commands:
          capture_payload:
            doc: approach the payload, latch it at t_latch, carry it 20 cm
            set: {carry.q1: 0.2}              # parameter values the command fixes
            arguments:                        # values the user may give
              t_latch: {doc: latch time, unit: s}   # a diagram or block parameter path
            t_end: 12                         # default run length

Units: a parameter, initial state or named-command argument may be given as
``{"value": 1500, "unit": "mOhm"}`` (converted to the declared unit; an incompatible unit is
refused); ``table`` and ``joint_path`` take an optional ``"unit"`` for their values
(converted to the unit the model infers for the block's output), ``cartesian_line`` values
may each be ``{"value", "unit"}`` (distance m, speed m/s, accel m/s2). A plain number is in
the declared unit: for a named command's argument (and its ``default``) the unit the
command declares, else the parameter's. An argument's value ends in the parameter's own unit
(:func:`argument_value`: 500 for ``st.t_step`` declared ``ms`` is 0.5 s); a unit of another
kind than the declared one or the parameter's is refused, and ``spidersim check`` refuses a
declaration in such a unit (:func:`check_argument_units`).

Every value is checked by the diagram loader, so a request gets the CLI's messages (unknown
names with suggestions, bounds, shapes); problems with the command itself raise
:class:`~spidersim.errors.ParameterError` naming the field.
"""
from __future__ import annotations

import difflib
import os
import re

import numpy as np

import spidersim
from spidersim.blocks import REGISTRY, lookup
from spidersim.diagram.spec import BlockSpec
from spidersim.diagram.units import UNKNOWN
from spidersim.diagram.model import sim_setting
from spidersim.diagram.spec import parse_file
from spidersim.errors import DiagramError, ParameterError
from spidersim.text import units as U
from spidersim.text.yamlio import files_only_under, found

TABLE_TYPES = ("Step", "Ramp", "Sine", "Pulse", "Constant", "TimeTable")
PATH_TYPES = ("TrapezoidalProfile", "QuinticProfile")
MAX_TABLE = 10000


def _fail(msg, spec=None):
    raise ParameterError(msg, file=getattr(spec, "file", None))


def _feeds(d, block):
    """(destination 'path.port', unit) of the connections leaving top-level ``block``."""
    out = []
    for c in d.flat.conns:
        if c.src[0] == block:
            path, port = c.dst[0], c.dst[1]
            unit = d.layout.blocks[path].cls.inputs.get(port)
            out.append({"from": c.src[1], "to": f"{path}.{port}",
                        "unit": unit.unit if unit is not None else "1"})
    return out


def _table_blocks(d, spec):
    out = []
    for name, b in spec.blocks.items():
        if b.type not in TABLE_TYPES or name not in d.blocks:
            continue
        if b.type == "Constant" and np.size(d.blocks[name].params["value"]) != 1:
            continue
        out.append(name)
    return out


def _line_blocks(spec):
    """(ik block, profile block) pairs: a TrapezoidalProfile's q feeding a CartesianLineIK's s."""
    pairs = []
    for name, b in spec.blocks.items():
        if b.type != "CartesianLineIK":
            continue
        for c in spec.connections:
            if (c.dst.block == name and c.dst.port == "s" and c.src.port == "q"
                    and spec.blocks.get(c.src.block) is not None
                    and spec.blocks[c.src.block].type == "TrapezoidalProfile"):
                pairs.append((name, c.src.block))
    return pairs


#: keys of an argument declaration of a named command
ARGUMENT_KEYS = ("doc", "unit", "default")


def _argument_decl(v, command, name, spec, where):
    """A declared argument ``name`` of named command ``command``: ``{doc, unit, default}``
    (texts, '' when not given; default None). An empty declaration is one without doc,
    unit or default; anything but a mapping of those keys (e.g. ``t_latch: 3``, a value
    where the declaration belongs) is a ParameterError located at ``where``."""
    def fail(msg):
        raise ParameterError(f"command '{command}': argument '{name}' {msg}",
                             file=getattr(spec, "file", None), line=where)

    if v is None:
        v = {}
    if not isinstance(v, dict):
        fail(f"must be declared by a mapping {{doc: ..., unit: ..., default: ...}} (or "
             f"nothing), got {found(v)}; a default value is written {{default: {v!r:.20}}}")
    bad = [str(k) for k in v if k not in ARGUMENT_KEYS]
    if bad:
        fail(f"has unknown key(s) {', '.join(sorted(bad))}; keys are "
             f"{', '.join(ARGUMENT_KEYS)}")
    for k in ("doc", "unit"):
        if not isinstance(v.get(k, ""), str):
            fail(f"'{k}' must be a text, got {found(v[k])}")
    if v.get("unit"):
        try:
            U.parse(v["unit"])
        except U.UnitError as exc:
            fail(f"'unit': {exc}")
    return {"doc": v.get("doc", ""), "unit": v.get("unit", ""),
            "default": v.get("default")}


#: a command's name: an identifier (the JSON schema's name pattern), as a request spells it
COMMAND_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")


def _line(mapping, *keys):
    """The line of the entry reached by ``keys`` in nested mappings of the YAML loader (of
    the deepest key that has one), or None (plain dicts carry no lines)."""
    line = None
    for k in keys:
        if not isinstance(mapping, dict) or k not in mapping:
            break
        if hasattr(mapping, "line_of"):
            line = mapping.line_of(k) or line
        mapping = mapping[k]
    return line


def _command_entry(name, c, spec, where):
    """One entry of the ``commands`` section, checked: ``{doc, set, arguments, t_end}``
    (``arguments`` may be a list of names). Errors are located at ``where`` (the
    command's line) or at the line of the key they concern."""
    def fail(msg, *keys):
        raise ParameterError(f"command '{name}': {msg}", file=getattr(spec, "file", None),
                             line=_line(c, *keys) or where)

    if not isinstance(name, str) or not COMMAND_NAME.match(name):
        fail("not a command name: a request names it, so it is an identifier (letters, "
             "digits, _; not starting with a digit), e.g. capture_payload")
    if not isinstance(c, dict):
        fail(f"must be a mapping {{doc, set, arguments, t_end}}, got {found(c)}")
    bad = set(c) - {"doc", "set", "arguments", "t_end"}
    if bad:
        fail(f"unknown key(s) {', '.join(sorted(map(str, bad)))}; keys are doc, set, "
             f"arguments, t_end")
    if not isinstance(c.get("doc", ""), str):
        fail(f"'doc' must be a text, got {found(c['doc'])}", "doc")
    args = c.get("arguments")
    args = {} if args is None else args     # absent or null; '', 0 or false are errors
    if isinstance(args, list):
        if not all(isinstance(a, str) for a in args):
            fail("a list of 'arguments' must hold parameter paths (texts)", "arguments")
        args = {a: {} for a in args}
    sets = c.get("set")
    sets = {} if sets is None else sets
    for key, v in (("arguments", args), ("set", sets)):
        if not isinstance(v, dict):
            fail(f"'{key}' must be a mapping" + (" or a list of parameter paths"
                                                  if key == "arguments" else "")
                 + f", got {found(v)}", key)
    for k in args:
        if str(k) in map(str, sets):
            fail(f"'{k}' is both fixed by 'set' and an argument (the argument's value would "
                 f"replace the fixed one): keep one; an argument with a default is a value "
                 f"the command sets unless the request gives another", "arguments", k)
    return {"doc": c.get("doc", ""), "set": dict(sets),
            "arguments": {str(k): _argument_decl(v, name, str(k), spec,
                                                 _line(c, "arguments", k) or where)
                          for k, v in args.items()},
            "t_end": _command_t_end(name, c, spec, where)}


def _command_t_end(name, c, spec, where):
    """A command's ``t_end`` as a float (None when not given), checked by the rule of the
    file's ``simulation.t_end`` (:func:`~spidersim.diagram.model.sim_setting`: a number or
    an expression such as ``1e3`` or ``2*3``, finite and > 0; a boolean is refused)."""
    t_end = c.get("t_end")
    if t_end is None:
        return None
    try:
        return sim_setting("t_end", t_end, f"command '{name}': t_end",
                           file=getattr(spec, "file", None), line=_line(c, "t_end") or where)
    except DiagramError as exc:
        raise ParameterError(exc.message, file=exc.file, line=exc.line) from None


def named_commands(spec):
    """The ``commands`` section, checked: name -> {doc, set, arguments, t_end}."""
    raw = (spec.data or {}).get("commands") or {}
    line = spec.data.line_of("commands") if hasattr(spec.data, "line_of") else None
    if not isinstance(raw, dict):
        raise ParameterError("section 'commands' must map names to {doc, set, arguments, "
                             "t_end}", file=spec.file, line=line)
    return {str(name): _command_entry(name, c, spec, raw.line_of(name)
                                      if hasattr(raw, "line_of") else line)
            for name, c in raw.items()}


def parameter_path_problem(d, path):
    """Why ``path`` (an argument or ``set`` key of a named command) names no parameter of
    the loaded diagram ``d`` (a text for a message), or None when it names one: a
    top-level parameter (``t_latch``), a parameter of a block (``carry.q1``, also inside
    subsystems: ``j3.motor.R``) or of a subsystem instance (``j3.ratio``) — what ``--set``
    accepts."""
    prefix, _, name = str(path).rpartition(".")
    if not prefix:
        if name in d.spec.parameters:
            return None
        return f"the diagram has no parameter '{name}'{_hint(name, d.spec.parameters)}"
    if prefix in d.flat.blocks:
        cls = d.flat.blocks[prefix].cls
        if name in cls.parameters:
            return None
        return (f"block '{prefix}' ({cls.type_name}) has no parameter '{name}'"
                f"{_hint(name, cls.parameters)}")
    if prefix in d.flat.subsystem_instances:
        typ = d.flat.instances[prefix][0]
        params = parse_file(d.flat.subsystem_instances[prefix]).parameters
        if name in params:
            return None
        return (f"subsystem '{prefix}' (type '{typ}') has no parameter '{name}'"
                f"{_hint(name, params)}")
    places = list(d.flat.blocks) + list(d.flat.instances)
    return (f"there is no block or subsystem '{prefix}'{_hint(prefix, places)} (write "
            f"block.param, e.g. motor.R, or a parameter of the diagram)")


def _hint(word, choices):
    """``"; did you mean a, b?"`` with up to three of ``choices`` close to ``word``, or ''."""
    near = difflib.get_close_matches(word, list(choices), n=3)
    return f"; did you mean {', '.join(near)}?" if near else ""


def check_argument_paths(d, cmds):
    """Raise a ParameterError at the argument's line if an argument of a named command
    (``cmds``, from :func:`named_commands`) names no parameter of the loaded diagram
    ``d`` (:func:`parameter_path_problem`): a request could never give it."""
    raw = (d.spec.data or {}).get("commands") or {}
    for name, c in cmds.items():
        for k in c["arguments"]:
            problem = parameter_path_problem(d, k)
            if problem:
                raise ParameterError(
                    f"command '{name}': argument '{k}' names no parameter: {problem}",
                    file=d.file, line=_line(raw, name, "arguments", k))


def commandables(d, spec):
    """What a request can command on this model (part of the model's description)."""
    tables = [{"block": n, "type": spec.blocks[n].type, "feeds": _feeds(d, n)}
              for n in _table_blocks(d, spec)]
    paths = []
    for name, b in spec.blocks.items():
        if b.type in PATH_TYPES and name in d.blocks:
            p = d.blocks[name].params
            paths.append({"block": name, "type": b.type, "q0": float(p["q0"]),
                          "q1": float(p["q1"]), "feeds": _feeds(d, name)})
    lines = []
    for ik, prof in _line_blocks(spec):
        pi, pp = d.blocks[ik].params, d.blocks[prof].params
        lines.append({"ik": ik, "profile": prof,
                      "direction": np.ravel(pi["direction"]).tolist(),
                      "distance": float(pp["q1"] - pp["q0"]), "speed": float(pp["v_max"]),
                      "accel": float(pp["a_max"]), "t_start": float(pp["t_start"])})
    return {"table": tables, "joint_path": paths, "cartesian_line": lines,
            "named": named_commands(spec)}


def _numbers(v, what, spec, n_max=MAX_TABLE):
    if not isinstance(v, (list, tuple)) or not v:
        _fail(f"command.{what} must be a non-empty list of numbers", spec)
    if len(v) > n_max:
        _fail(f"command.{what} has {len(v)} values, at most {n_max} allowed", spec)
    if any(isinstance(x, (bool, np.bool_)) for x in v):
        _fail(f"command.{what} must hold numbers, got a boolean (true/false is not a "
              f"number; write 1 or 0)", spec)
    try:
        a = np.array(v, dtype=float)
    except (TypeError, ValueError, OverflowError):
        _fail(f"command.{what} must hold numbers only, got {v!r:.80}", spec)
    if a.ndim != 1 or not np.all(np.isfinite(a)):
        _fail(f"command.{what} must be a flat list of finite numbers", spec)
    return a


def _to_unit(values, given, target, what, spec):
    """``values`` given in unit ``given`` (text or None), in the unit ``target`` (the
    signal's inferred unit, or ``?``): converted when both are known; ``(values, unit)``
    with the unit to record when the target is not fixed (None: no unit given)."""
    if given is None:
        return values, None
    try:
        g = U.parse(given)
        if target in (None, UNKNOWN, U.ANY) or "@" in target:
            U.check_no_offset(g, "a signal whose unit the model does not fix")
            return values, str(given)
        a, b = U.affine(g, U.parse(target))
        return values * a + b, None
    except U.UnitError as exc:
        _fail(f"command.unit of {what}: {exc}", spec)


def _scalar_with_unit(value, key, unit, spec):
    """A number, or ``{"value": x, "unit": u}`` converted to ``unit``."""
    if isinstance(value, dict):
        if set(value) != {"value", "unit"}:
            _fail(f"command.{key}: a value with a unit is {{\"value\": 2, \"unit\": "
                  f"\"{unit}\"}}", spec)
        x = _numbers([value["value"]], key, spec)[0]
        return float(_to_unit(np.array([x]), value["unit"], unit, key, spec)[0][0])
    return float(_numbers([value], key, spec)[0])


def _pick(options, given, what, spec, key="block"):
    names = [o if isinstance(o, str) else o[key] for o in options]
    if not names:
        _fail(f"command: this model has no {what}", spec)
    if given is None:
        if len(names) > 1:
            _fail(f"command: give '{key}', one of {', '.join(names)}", spec)
        return options[0]
    if given not in names:
        _fail(f"command.{key}: '{given}' is not a {what} of this model; choose from "
              f"{', '.join(names)}", spec)
    return options[names.index(given)]


def _set(overrides, key, value, spec):
    if key in overrides:
        _fail(f"parameter '{key}' is set by the command; leave it out of 'parameters'", spec)
    overrides[key] = value


def _refuse_overrides_of(overrides, name, replaced_by, spec):
    """Refuse request parameters of block ``name`` when the command replaces the block
    (``replaced_by`` ends the message: what replaces it)."""
    for k in list(overrides):
        if k.startswith(name + "."):
            _fail(f"parameter '{k}' belongs to block '{name}', which {replaced_by}", spec)


def _table_command(d0, spec, cmd, overrides):
    """``{"kind": "table", "block", "time", "value", "unit"}``: replace the source block by a
    ``TimeTable`` through the points (values converted to the unit the model infers for
    the block's output ``y``; kept with their unit when that is not fixed)."""
    name = _pick(_table_blocks(d0, spec), cmd.get("block"), "table-commandable source "
                 "block", spec)
    t = _numbers(cmd.get("time"), "time", spec)
    v = _numbers(cmd.get("value"), "value", spec)
    if len(t) != len(v):
        _fail(f"command: 'time' has {len(t)} values and 'value' {len(v)}; give one value "
              f"per time", spec)
    _refuse_overrides_of(overrides, name, "the table command replaces", spec)
    v, unit = _to_unit(v, cmd.get("unit"), d0.units.get((name, "out", "y")),
                       f"block '{name}'", spec)
    old = spec.blocks[name]
    value = v.tolist() if unit is None else {"value": v.tolist(), "unit": unit}
    spec.blocks[name] = BlockSpec(name, "TimeTable", {"time": t.tolist(), "value": value},
                                  old.line, {})


def _check_path_points(q, t, spec):
    """At least two points, one time per point, times strictly increasing from t >= 0."""
    if len(q) < 2 or len(q) != len(t):
        _fail(f"command: give at least 2 points and one time per point, got {len(q)} "
              f"points and {len(t)} times", spec)
    if not (t[0] >= 0 and np.all(np.diff(t) > 0)):
        _fail(f"command.times must be strictly increasing from t >= 0, got {t.tolist()}",
              spec)


def profile_parameters(typ, q, t):
    """Parameters of a two-point move for a trajectory block of type ``typ``.

    Parameters
    ----------
    typ : {"QuinticProfile", "TrapezoidalProfile"}
    q : array of 2 floats
        Start and end position ``q_a, q_b`` (the block's unit).
    t : array of 2 floats
        Start and end time ``t_a < t_b`` [s].

    Returns
    -------
    dict
        ``q0 = q_a``, ``q1 = q_b``, ``t_start = t_a`` and, with ``T = t_b - t_a`` and
        ``d = |q_b - q_a|``: for a QuinticProfile ``T``; for a TrapezoidalProfile
        ``v_max = 1.5 d/T`` and ``a_max = 4.5 d/T^2`` (accelerating for T/3 reaches
        ``a_max T/3 = v_max``; cruising T/3 and braking T/3 then cover
        ``v_max (2T/3) = d``: the move takes exactly T). For d = 0 both are 1 (any
        positive value: nothing moves).
    """
    T = t[1] - t[0]
    out = {"q0": float(q[0]), "q1": float(q[1]), "t_start": float(t[0])}
    if typ == "QuinticProfile":
        out["T"] = float(T)
    else:
        dist = abs(q[1] - q[0])
        out["v_max"] = float(1.5 * dist / T) if dist > 0 else 1.0
        out["a_max"] = float(4.5 * dist / T ** 2) if dist > 0 else 1.0
    return out


def _joint_path_command(d0, spec, cmd, overrides):
    """``{"kind": "joint_path", "block", "points", "times"}``: two points set the
    trajectory block's parameters (:func:`profile_parameters`); more points replace the
    block by a ``ViaPointProfile`` through them."""
    opts = [n for n, b in spec.blocks.items() if b.type in PATH_TYPES]
    name = _pick(opts, cmd.get("block"), "trajectory block (TrapezoidalProfile, "
                 "QuinticProfile)", spec)
    q = _numbers(cmd.get("points"), "points", spec)
    t = _numbers(cmd.get("times"), "times", spec)
    q, unit = _to_unit(q, cmd.get("unit"), d0.units.get((name, "out", "q")),
                       f"block '{name}'", spec)
    if unit is not None:
        _fail(f"command.unit: the unit of block '{name}''s positions is not fixed by the "
              f"model; give the points without a unit", spec)
    _check_path_points(q, t, spec)
    if len(q) > 2:
        _refuse_overrides_of(overrides, name, "a joint_path of more than 2 points replaces "
                                              "by a ViaPointProfile", spec)
        old = spec.blocks[name]
        spec.blocks[name] = BlockSpec(name, "ViaPointProfile", {
            "points": q.tolist(), "times": t.tolist()}, old.line, {})
        return
    for param, value in profile_parameters(spec.blocks[name].type, q, t).items():
        _set(overrides, f"{name}.{param}", value, spec)


#: cartesian_line request key -> (TrapezoidalProfile parameter, unit of the value)
LINE_KEYS = {"distance": ("q1", "m"), "speed": ("v_max", "m/s"), "accel": ("a_max", "m/s2"),
             "t_start": ("t_start", "s")}


def _cartesian_line_command(d0, spec, cmd, overrides):
    """``{"kind": "cartesian_line", "ik", "direction", "distance", "speed", "accel",
    "t_start"}``: the direction of the CartesianLineIK block and the parameters of the
    TrapezoidalProfile feeding its path length (starting at 0)."""
    pairs = _line_blocks(spec)
    ik, prof = _pick([{"ik": a, "p": b} for a, b in pairs], cmd.get("ik"),
                     "straight-line path (CartesianLineIK fed by a TrapezoidalProfile)",
                     spec, key="ik").values()
    u = _numbers(cmd.get("direction"), "direction", spec)
    if len(u) != 3:
        _fail(f"command.direction must have 3 components, got {len(u)}", spec)
    _set(overrides, f"{ik}.direction", u.tolist(), spec)
    _set(overrides, f"{prof}.q0", 0.0, spec)
    for key, (param, unit) in LINE_KEYS.items():
        if cmd.get(key) is not None:
            val = _scalar_with_unit(cmd[key], key, unit, spec)
            _set(overrides, f"{prof}.{param}", val, spec)


def parameter_unit(d, path):
    """The unit a value of parameter ``path`` of the loaded diagram ``d`` is read in.

    Parameters
    ----------
    d : Diagram
    path : str
        A parameter path as ``--set`` takes it (``st.t_step``, ``T0``, ``j3.ratio``).

    Returns
    -------
    str or None
        The unit the block declares (``s`` for a Step's ``t_step``); for a unit inherited
        from the wiring (a Step's ``after``, a Gain's ``k``) the unit the model infers, or
        ``"*"`` (:data:`~spidersim.text.units.ANY`) when the wiring leaves it open; None
        for a parameter without a unit of its own (a diagram or subsystem parameter, whose
        value with a unit goes to coherent SI).

    Raises
    ------
    UnitError
        For an int, bool or str parameter, which takes no unit.
    """
    prefix, _, name = str(path).rpartition(".")
    inst = d.flat.blocks.get(prefix) if prefix else None
    decl = inst.cls.parameters.get(name) if inst is not None else None
    if decl is None:
        return None
    if decl.kind != "real":
        raise U.UnitError(f"a {decl.kind} parameter takes no unit")
    unit = inst.cls.unit_of(decl, inst.params)
    if unit == U.ANY or "@" in unit:
        unit = d.units.get((prefix, "param", name))
    return U.ANY if unit in (None, UNKNOWN, U.ANY) or "@" in unit else unit


def _numeric(x):
    """``x`` as a float array when it is a number or a (nested) list of numbers, else None
    (an expression, a boolean: the loader reads and judges it)."""
    if isinstance(x, (bool, str, dict)) or x is None:
        return None
    try:
        a = np.asarray(x, dtype=float)
    except (TypeError, ValueError, OverflowError):
        return None
    return None if a.dtype == object else a


def argument_value(d, path, value, declared, what):
    """What the loader gets for the named-command argument ``path`` given ``value``.

    A plain value is in the ``declared`` unit (none declared: in the parameter's own
    unit, passed on unchanged); ``{"value": x, "unit": u}`` is in ``u``, which must
    convert to the declared unit. A number or list is converted to the parameter's own
    unit (:func:`parameter_unit`: 500 ms for a Step's ``t_step`` is 0.5; 45 deg for a
    Step's ``after`` the model reads in rad is pi/4), or, when the wiring leaves that
    open, to the declared unit (a plain number, as the file's values of that block);
    anything else (an expression, a parameter without a unit of its own) goes to the
    loader as ``{"value", "unit"}``, which converts it the same way (a diagram parameter
    to coherent SI).

    Parameters
    ----------
    d : Diagram
        The model loaded (units and parameters the conversion reads).
    path : str
        The argument, a parameter path.
    value : object
        The request's value or the declared default.
    declared : str
        The unit the command declares for the argument, '' when none.
    what : str
        Start of an error message, e.g. ``command 'go': argument 'st.t_step'``.

    Raises
    ------
    ParameterError
        A malformed value with a unit, a unit that does not convert to the declared unit
        or to the parameter's (the command declares ``K`` for a time), a unit on a
        parameter that takes none.
    """
    if isinstance(value, dict):
        if set(value) != {"value", "unit"}:
            _fail(f"{what}: a value with a unit is {{\"value\": x, \"unit\": "
                  f"\"{declared or 'm'}\"}}", d.spec)
        x, given = value["value"], value["unit"]
    elif declared:
        x, given = value, declared
    else:
        return value
    try:
        g = U.parse(given)
        if declared:
            _converts(g, U.parse(declared), f"the command declares it in {declared}")
        target = parameter_unit(d, path)
        plain = target == U.ANY             # open: the number is read as it is written
        if plain:
            target = declared or None
        if target is not None:
            a, b = _converts(g, U.parse(target), f"the parameter is in {target}")
    except U.UnitError as exc:
        _fail(f"{what}: {exc}", d.spec)
    arr = _numeric(x)
    if target is None or arr is None:
        return {"value": x, "unit": given}
    with np.errstate(all="ignore"):        # an overflow is inf: the loader's checks say so
        x = (arr * a + b).tolist()
    return x if plain else {"value": x, "unit": target}


def _converts(given, to, why):
    """``(a, b)`` of :func:`~spidersim.text.units.affine` from ``given`` to ``to``; its
    UnitError says ``why`` the value must be in ``to``."""
    try:
        return U.affine(given, to)
    except U.UnitError as exc:
        raise U.UnitError(f"{exc} ({why})") from None


def check_argument_units(d, cmds):
    """Raise a ParameterError at the argument's line if a named command (``cmds``, from
    :func:`named_commands`) declares a unit that does not convert to the unit of the
    parameter its argument sets (``unit: K`` for a Step's ``t_step``), or a unit on a
    parameter that takes none: every value a request gave would be refused."""
    raw = (d.spec.data or {}).get("commands") or {}
    for name, c in cmds.items():
        for k, a in c["arguments"].items():
            if not a["unit"]:
                continue
            target = None
            try:
                target = parameter_unit(d, k)
                if target not in (None, U.ANY):
                    U.affine(U.parse(a["unit"]), U.parse(target))
            except U.UnitError as exc:
                where = f", but the parameter is in {target}" if target not in (
                    None, U.ANY) else ""
                raise ParameterError(
                    f"command '{name}': argument '{k}' is declared in {a['unit']}{where}: "
                    f"{exc}", file=d.file, line=_line(raw, name, "arguments", k)) from None


def _named_command(d0, spec, cmd, overrides):
    """``{"kind": "named", "name", "arguments"}``: a command of the model's ``commands``
    section: its ``set`` values, the arguments given, then the defaults of those not
    given. Returns the command's run length (None: the model's)."""
    cmds = named_commands(spec)
    name = cmd.get("name")
    if name not in cmds:
        _fail(f"command.name: the model declares no command {name!r}; commands: "
              f"{', '.join(cmds) or 'none'}", spec)
    c = cmds[name]
    for k, v in c["set"].items():
        _set(overrides, str(k), v, spec)
    _set_arguments(d0, name, c["arguments"], cmd.get("arguments") or {}, overrides, spec)
    return c["t_end"]


def _set_arguments(d0, name, declared, args, overrides, spec):
    """Set the ``args`` given to named command ``name`` (each must be ``declared``), then
    the declared defaults of the arguments not given, each in the parameter's unit
    (:func:`argument_value`)."""
    if not isinstance(args, dict):
        _fail("command.arguments must be a mapping", spec)
    for k, v in args.items():
        if k not in declared:
            _fail(f"command '{name}' has no argument '{k}'; arguments: "
                  f"{', '.join(declared) or 'none'}", spec)
    for k, a in declared.items():
        if k in args or a["default"] is not None:
            v = args[k] if k in args else a["default"]
            _set(overrides, k, argument_value(d0, k, v, a["unit"],
                                              f"command '{name}': argument '{k}'"), spec)


#: command kind -> function(d0, spec, cmd, overrides) -> run length or None
COMMANDS = {"table": _table_command, "joint_path": _joint_path_command,
            "cartesian_line": _cartesian_line_command, "named": _named_command}


def apply_command(d0, spec, cmd, overrides):
    """Change ``spec`` (block replacements) and ``overrides`` for ``cmd``; return the
    command's default run length or None.

    Parameters
    ----------
    d0 : Diagram
        The model loaded with the request's parameters (units and parameter values the
        command reads).
    spec : DiagramSpec
        The model's spec, changed in place when a block is replaced.
    cmd : dict
        The request's ``command``; ``kind`` selects the function in :data:`COMMANDS`.
    overrides : dict
        The request's parameters, completed in place with what the command sets.
    """
    kind = cmd.get("kind")
    if not isinstance(kind, str) or kind not in COMMANDS:
        _fail(f"command.kind must be table, joint_path, cartesian_line or named, got "
              f"{kind!r}", spec)
    return COMMANDS[kind](d0, spec, cmd, overrides)


def _set_initial_states(d0, initial, overrides, spec):
    """Initial states ``block.state -> value`` of a request, set through the parameter each
    state starts from (a state with a fixed initial value cannot be set)."""
    for name, value in initial.items():
        path, _, state = str(name).rpartition(".")
        bl = d0.layout.blocks.get(path)
        decl = bl.cls.states.get(state) if bl is not None else None
        if decl is None:
            _fail(f"initial: no state '{name}' (write block.state, e.g. motor.w)", spec)
        if not (isinstance(decl.initial, str) and decl.initial in bl.cls.parameters):
            _fail(f"initial: state '{name}' of {bl.cls.type_name} starts from a fixed "
                  f"value, not from a parameter; it cannot be set", spec)
        _set(overrides, f"{path}.{decl.initial}", value, spec)


def _log_only(spec, log):
    """Record only the signals ``log``; plots of signals not recorded are dropped."""
    from spidersim.plots import split_signal
    spec.log = list(log)
    logged = set(spec.log)
    spec.plots = [p for p in spec.plots if isinstance(p, dict) and all(
        split_signal(s)[0] in logged for s in p.get("signals", []))]


def _is_time(v):
    """``v`` is a number (not a boolean: JSON/YAML ``true`` is not 1 s), finite and > 0."""
    return (isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)
            and np.isfinite(v) and v > 0)


def _run_length(req, t_cmd, d, spec):
    """The run length [s]: the request's ``t_end``, else the command's, else the model's;
    it must be a positive finite number (a boolean, a text or a list is refused)."""
    t_end = req.get("t_end")
    if t_end is None:
        t_end = t_cmd if t_cmd is not None else d.simulation["t_end"]
    if not _is_time(t_end):
        _fail(f"t_end must be a positive number of seconds, got {found(t_end)}", spec)
    from spidersim.solver.events import MIN_SPAN
    if t_end < MIN_SPAN:                   # the CLI's check: refused before it is queued
        _fail(f"t_end must be at least {MIN_SPAN:g} s (the solvers take steps shorter "
              f"than 1e-10 s as a stall), got {found(t_end)}", spec)
    return float(t_end)


def _model_roots(model, spec):
    """Folders whose files a request's model may read: the model's folder, its subsystems'
    folders and the package's data (the shipped arm)."""
    from spidersim.multibody.chain import DATA
    return {model.folder, DATA} | {os.path.dirname(f) for f in spec.subsystems.values()}


def _refuse_file_parameters(spec, overrides):
    """A request may not set a parameter that names a file of the server (``Param.file``,
    e.g. ``arm.model``): refused by name before anything is loaded."""
    for key in overrides:
        block, _, pname = str(key).rpartition(".")
        b = spec.blocks.get(block)
        cls = lookup(b.type) if b is not None and b.type in REGISTRY else None
        decl = cls.parameters.get(pname) if cls is not None else None
        if decl is not None and decl.file:
            _fail(f"parameter '{key}' names a file of the server; a request cannot set it",
                  spec)


def prepare(model, req):
    """``(Diagram, t_end)`` for the request ``req`` (a dict) on ``model``. Only files of
    the model's folders are read meanwhile (:func:`.yamlio.files_only_under`)."""
    spec = model.spec()
    with files_only_under(_model_roots(model, spec)):
        return _prepare(spec, req)


def _prepare(spec, req):
    overrides = dict(req.get("parameters") or {})
    _refuse_file_parameters(spec, overrides)
    t_cmd = None
    if req.get("command") or req.get("initial"):
        d0 = spidersim.Diagram(spec, dict(overrides))
        if req.get("command"):
            t_cmd = apply_command(d0, spec, dict(req["command"]), overrides)
        _set_initial_states(d0, req.get("initial") or {}, overrides, spec)
    if req.get("log"):
        _log_only(spec, req["log"])
    d = spidersim.Diagram(spec, overrides)
    return d, _run_length(req, t_cmd, d, spec)
