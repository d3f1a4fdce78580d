"""Flatten a diagram: instantiate subsystems recursively into dotted block instances.

Parameter scoping: a diagram's ``parameters`` are evaluated in order, each expression seeing
the ones before it. For a subsystem instance, the instance's entries (evaluated in the
parent's scope) replace the subsystem file's defaults, and the subsystem's blocks see only
the subsystem's parameters. Overrides (``--set``) address ``name`` (a top-level parameter),
``block.param`` or ``sub.block.param`` / ``sub.param`` through any depth of nesting.
"""
from __future__ import annotations

import difflib
import functools
import os
from dataclasses import dataclass, field

import numpy as np

from ..blocks.base import REGISTRY, Block, lookup
from ..errors import DiagramError, ParameterError, SpidersimError, WiringError
from ..text import units as U
from ..text.expr import ExprError, evaluate
from .spec import Address, DiagramSpec, parse_file


@dataclass
class Instance:
    """One primitive block of the flat diagram."""

    path: str
    cls: type
    params: dict
    file: str
    line: int
    param_lines: dict = field(default_factory=dict)
    param_units: dict = field(default_factory=dict)   # name -> unit given in the file


@dataclass
class FlatConn:
    """``src`` output (path, port, start, stop) feeding ``dst`` input (path, port)."""

    src: tuple
    dst: tuple
    file: str
    line: int
    text: str


@dataclass
class Flat:
    blocks: dict                 # path -> Instance
    conns: list                  # FlatConn
    subsystem_instances: dict    # path -> file
    aliases: dict = field(default_factory=dict)  # "sub.out" -> (path, port, start, stop)
    scope: dict = field(default_factory=dict)    # top-level parameters, evaluated
    #: subsystem instance path -> (type, file, line) of its declaration in the parent
    instances: dict = field(default_factory=dict)
    #: (path, port) of a primitive input -> (instance path, exposed input, file, line) of
    #: the outermost exposed subsystem input that feeds it
    exposed: dict = field(default_factory=dict)

    def note_subsystem(self, exc):
        """Append :meth:`used_at` to an error about a block inside a subsystem instance
        (its file:line is in the subsystem's file; this names the parent lines)."""
        path = exc.block or ""
        if "(in subsystem instance" in exc.message or "." not in path:
            return
        exc.message += self.used_at(path)

    def used_at(self, path):
        """`` (subsystem 's' of type 'joint', parent.yaml:12)`` for a block inside
        subsystem instances, naming each enclosing instance's line; '' at the top."""
        notes = []
        parts = path.split(".")
        for k in range(len(parts) - 1, 0, -1):
            inst = self.instances.get(".".join(parts[:k]))
            if inst is not None:
                typ, file, line = inst
                notes.append(f"subsystem instance '{'.'.join(parts[:k])}' of type '{typ}', "
                             f"{os.path.basename(file)}:{line}")
        return f" (in {'; in '.join(notes)})" if notes else ""


def _quantity(value, scope, decl, file, line, what, block, record):
    """``{value: x, unit: u}``: x converted to the declared unit of ``decl`` (to coherent SI
    when there is no declaration: a diagram or subsystem parameter); for a parameter whose
    unit is inherited (``*`` or a rule, e.g. a Gain's ``k``) the value stays and
    ``record(unit)`` keeps the unit for unit inference."""
    if set(value) != {"value", "unit"}:
        raise ParameterError(f"{what}: a value with a unit is written {{value: 2.5, unit: "
                             f"N.m}}; got the keys {', '.join(map(str, value))}", file=file,
                             line=line, block=block)
    x = _eval_value(value["value"], scope, None, file, line, what, block)
    try:
        given = U.parse(value["unit"])
        if decl is None:
            f = U.factor(given, U.base(given))
        elif decl.kind != "real":
            raise U.UnitError(f"a {decl.kind} parameter takes no unit")
        elif decl.unit == U.ANY or "@" in decl.unit or callable(decl.unit):
            if record is not None:
                record(value["unit"])
            return x
        else:
            f = U.factor(given, U.parse(decl.unit))
    except U.UnitError as exc:
        want = f" (declared [{decl.unit}])" if decl is not None and isinstance(
            decl.unit, str) else ""
        raise ParameterError(f"{what}{want}: {exc}", file=file, line=line,
                             block=block) from None
    if f == 1.0:
        return x
    if isinstance(x, bool) or not isinstance(x, (int, float, list)):
        raise ParameterError(f"{what}: a value with a unit must be a number or a list of "
                             f"numbers", file=file, line=line, block=block)
    return (np.asarray(x, dtype=float) * f).tolist()


def _eval_value(value, scope, decl, file, line, what, block=None, record=None):
    """Evaluate a YAML parameter value in ``scope``; strings of str-kind params stay."""
    if decl is not None and decl.kind == "str":
        return value
    if isinstance(value, dict):
        return _quantity(value, scope, decl, file, line, what, block, record)
    try:
        if isinstance(value, str):
            return evaluate(value, scope)
        if isinstance(value, list):
            return [_eval_value(v, scope, None, file, line, what) for v in value]
        if isinstance(value, bool) or value is None or isinstance(value, (int, float)):
            if value is None:
                raise ExprError("no value given (empty entry)")
            return value
        raise ExprError(f"unsupported value {value!r}")
    except ExprError as exc:
        lead = ("expected a number or an expression of parameters; "
                if isinstance(value, str) else "")
        raise ParameterError(f"{what}: {lead}{exc}", file=file, line=line,
                             block=block) from None


def eval_parameters(spec: DiagramSpec, given: dict, prefix: str):
    """Evaluate the diagram's parameters in order, with instance values ``given``."""
    scope = {}
    for name, raw in spec.parameters.items():
        if name in given:
            scope[name] = given[name]
            continue
        scope[name] = _eval_value(raw, scope, None, spec.file, spec.param_lines.get(name),
                                  f"parameter '{prefix}{name}'")
    unknown = [k for k in given if k not in spec.parameters]
    return scope, unknown


def flatten(spec: DiagramSpec, overrides: dict | None = None) -> Flat:
    """Flatten the top-level ``spec`` with ``overrides`` (dotted path -> value)."""
    overrides = dict(overrides or {})
    used = set()
    top_given = {}
    for k, v in overrides.items():
        if "." not in k:
            if k not in spec.parameters:
                near = difflib.get_close_matches(k, list(spec.parameters), n=3)
                hint = f"; did you mean {', '.join(near)}?" if near else ""
                raise ParameterError(f"--set {k}: the diagram has no parameter '{k}'{hint}",
                                     file=spec.file)
            top_given[k] = _eval_value(v, {}, None, spec.file, None, f"--set {k}")
            used.add(k)
    # override values that are expressions are evaluated with the top-level scope
    scope0, _ = eval_parameters(spec, top_given, "")
    for k, v in list(top_given.items()):
        scope0[k] = v
    flat = Flat({}, [], {}, scope=dict(scope0))
    sub_overrides = {k: v for k, v in overrides.items() if "." in k}
    _instantiate(spec, "", scope0, sub_overrides, flat, [os.path.abspath(spec.file)], used,
                 top=True)
    missing = [k for k in overrides if k not in used]
    if missing:
        raise ParameterError(f"--set {missing[0]}: no such block parameter or subsystem "
                             f"parameter (write block.param, e.g. motor.R)", file=spec.file)
    return flat


def _instantiate(spec, prefix, scope, overrides, flat, stack, used, top=False):
    """Add the blocks of ``spec`` under ``prefix``; return (in_map, out_map)."""
    sub_specs = {}
    local_subs = {}  # instance name -> (in_map, out_map)
    for k in overrides:
        head = k.partition(".")[0]
        if head not in spec.blocks:
            near = difflib.get_close_matches(head, list(spec.blocks), n=3)
            hint = f"; did you mean {', '.join(near)}?" if near else ""
            where = f"in '{prefix[:-1]}'" if prefix else "in the diagram"
            raise ParameterError(f"--set {prefix}{k}: there is no block '{head}' {where}{hint}",
                                 file=spec.file)
    for bname, b in spec.blocks.items():
        path = prefix + bname
        own = {}  # overrides addressed to this block: param -> value
        deeper = {}
        for k, v in overrides.items():
            head, _, rest = k.partition(".")
            if head == bname:
                if "." in rest:
                    deeper[rest] = (k, v)
                else:
                    own[rest] = (k, v)
        if b.type in spec.subsystems:
            sub_file = spec.subsystems[b.type]
            if os.path.abspath(sub_file) in stack:
                chain = " -> ".join(os.path.basename(s) for s in stack + [sub_file])
                raise DiagramError(f"subsystem type '{b.type}' includes itself ({chain})",
                                   file=spec.file, line=b.line, block=path)
            if sub_file not in sub_specs:
                if not os.path.isfile(sub_file):
                    raise DiagramError(f"subsystem file for type '{b.type}' not found: "
                                       f"{sub_file}", file=spec.file,
                                       line=spec.subsystem_lines.get(b.type), block=path)
                try:
                    sub_specs[sub_file] = parse_file(sub_file)
                except DiagramError as exc:
                    # say which parent line brought the subsystem in
                    exc.message += (f" (subsystem type '{b.type}' of block '{path}', "
                                    f"{os.path.basename(spec.file)}:{b.line})")
                    raise
            sub = sub_specs[sub_file]
            given = {}
            for pname, raw in b.params.items():
                if pname not in sub.parameters:
                    near = difflib.get_close_matches(pname, list(sub.parameters), n=3)
                    hint = f"; did you mean {', '.join(near)}?" if near else ""
                    raise ParameterError(
                        f"unknown parameter '{pname}' for subsystem type '{b.type}'{hint} "
                        f"(parameters: {', '.join(sub.parameters) or 'none'})",
                        file=spec.file, line=b.param_lines.get(pname), block=path)
                given[pname] = _eval_value(raw, scope, None, spec.file,
                                           b.param_lines.get(pname), f"parameter '{pname}'",
                                           block=path)
            for pname, (key, v) in own.items():
                if pname in sub.parameters:
                    given[pname] = _eval_value(v, scope, None, spec.file, b.line,
                                               f"--set {prefix}{key}", block=path)
                    used.add(key)
                else:
                    near = difflib.get_close_matches(pname, list(sub.parameters), n=3)
                    hint = f"; did you mean {', '.join(near)}?" if near else ""
                    what = (f"'{pname}' is a block of it: write {prefix}{key}.param"
                            if pname in sub.blocks else f"it has no parameter '{pname}'{hint}")
                    raise ParameterError(
                        f"--set {prefix}{key}: '{path}' is a subsystem of type '{b.type}'; "
                        f"{what} (parameters: {', '.join(sub.parameters) or 'none'})",
                        block=path, file=spec.file, line=b.line)
            sub_scope, _ = eval_parameters(sub, given, path + ".")
            sub_over = {k: v for k, (key, v) in deeper.items()}
            keymap = {k: key for k, (key, v) in deeper.items()}
            sub_used = set()
            flat.instances[path] = (b.type, spec.file, b.line)
            try:
                maps = _instantiate(sub, path + ".", sub_scope, sub_over, flat,
                                    stack + [os.path.abspath(sub_file)], sub_used)
            except SpidersimError as exc:
                # an error in the subsystem's file: say which parent line brought it in
                if exc.file == sub_file and not getattr(exc, "_used_at", False):
                    exc.message += (f" (subsystem type '{b.type}' of block '{path}', "
                                    f"{os.path.basename(spec.file)}:{b.line})")
                    exc._used_at = True
                raise
            used.update(keymap[k] for k in sub_used if k in keymap)
            local_subs[bname] = maps
            for oname, src in maps[1].items():
                flat.aliases[f"{path}.{oname}"] = src
            flat.subsystem_instances[path] = sub_file
            continue
        try:
            cls = lookup(b.type, spec.file, b.line, extra=list(spec.subsystems))
        except SpidersimError as exc:
            exc.block = path
            raise
        values = {}
        punits = {}
        for pname, raw in b.params.items():
            decl = cls.parameters.get(pname)
            values[pname] = _eval_value(raw, scope, decl, spec.file, b.param_lines.get(pname),
                                        f"parameter '{pname}'", block=path,
                                        record=functools.partial(punits.__setitem__, pname))
        for pname, (key, v) in own.items():
            decl = cls.parameters.get(pname)
            if decl is None:
                near = difflib.get_close_matches(pname, list(cls.parameters), n=3)
                hint = f"; did you mean {', '.join(near)}?" if near else ""
                raise ParameterError(f"--set {prefix}{key}: block type {cls.type_name} has no "
                                     f"parameter '{pname}'{hint} (parameters: "
                                     f"{', '.join(cls.parameters)})", block=path,
                                     file=spec.file, line=b.line)
            if decl.kind == "str" and isinstance(v, str):
                values[pname] = v
            else:
                values[pname] = _eval_value(v, scope, decl, spec.file, b.line,
                                            f"--set {prefix}{key}", block=path,
                                            record=functools.partial(punits.__setitem__,
                                                                     pname))
            used.add(key)
        if deeper:
            k = next(iter(deeper.values()))[0]
            raise ParameterError(f"--set {prefix}{k}: '{path}' is a {cls.type_name} block, "
                                 f"not a subsystem", block=path, file=spec.file, line=b.line)

        def where(name, _b=b):
            return spec.file, (_b.param_lines.get(name) if name else _b.line)

        try:
            params = cls.validate_params(values, where=where)
        except ParameterError as exc:
            exc.block = path
            raise
        if path in flat.blocks:
            raise DiagramError(f"duplicate block path '{path}'", file=spec.file, line=b.line)
        flat.blocks[path] = Instance(path, cls, params, spec.file, b.line, dict(b.param_lines),
                                     {k: v for k, v in punits.items() if k in params})

    # resolve local addresses into flat ones
    def resolve_src(a: Address, line):
        if a.block in local_subs:
            out_map = local_subs[a.block][1]
            if a.port not in out_map:
                raise WiringError(
                    f"subsystem instance '{prefix}{a.block}' has no output '{a.port}' "
                    f"(outputs: {', '.join(out_map) or 'none'})", file=spec.file, line=line)
            path, port, s0, s1 = out_map[a.port]
            if a.start is not None:
                base = s0 or 0
                return (path, port, base + a.start, base + a.stop)
            return (path, port, s0, s1)
        _check_block(a, line)
        return (prefix + a.block, a.port, a.start, a.stop)

    def resolve_dst(a: Address, line):
        if a.block in local_subs:
            in_map = local_subs[a.block][0]
            if a.port not in in_map:
                raise WiringError(
                    f"subsystem instance '{prefix}{a.block}' has no input '{a.port}' "
                    f"(inputs: {', '.join(in_map) or 'none'})", file=spec.file, line=line)
            return in_map[a.port]
        _check_block(a, line)
        return [(prefix + a.block, a.port)]

    def _check_block(a, line):
        if a.block not in spec.blocks:
            near = difflib.get_close_matches(a.block, list(spec.blocks), n=3)
            hint = f"; did you mean {', '.join(near)}?" if near else ""
            raise WiringError(f"connection refers to unknown block '{a.block}'{hint}",
                              file=spec.file, line=line)

    for c in spec.connections:
        src = resolve_src(c.src, c.line)
        for dst in resolve_dst(c.dst, c.line):
            flat.conns.append(FlatConn(src, dst, spec.file, c.line, f"{c.src} -> {c.dst}"))

    in_map = {}
    for name, addrs in spec.inputs.items():
        line = spec.port_lines[("in", name)]
        targets = []
        for a in addrs:
            if a.start is not None:
                raise WiringError(f"exposed input '{name}' must map to whole input ports",
                                  file=spec.file, line=line)
            got = resolve_dst(a, line)
            for dst_path, dst_port in got:
                if a.block not in local_subs:
                    inst = flat.blocks[dst_path]
                    if dst_port not in inst.cls.input_names(inst.params):
                        near = difflib.get_close_matches(
                            dst_port, inst.cls.input_names(inst.params), n=2)
                        hint = f"; did you mean {', '.join(near)}?" if near else ""
                        raise WiringError(
                            f"exposed input '{name}' maps to '{a}', but block '{a.block}' "
                            f"({inst.cls.type_name}) has no input '{dst_port}'{hint}; inputs: "
                            f"{', '.join(inst.cls.input_names(inst.params)) or 'none'}",
                            file=spec.file, line=line, block=dst_path)
                flat.exposed[(dst_path, dst_port)] = (prefix[:-1], name, spec.file, line)
            targets += got
        in_map[name] = targets
    out_map = {}
    for name, a in spec.outputs.items():
        out_map[name] = resolve_src(a, spec.port_lines[("out", name)])
    return in_map, out_map
