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
from typing import NamedTuple

import numpy as np

from ..blocks.base import REGISTRY, Block, lookup
from ..errors import DiagramError, ParameterError, SpidersimError, WiringError
from ..text import limits
from ..text import units as U
from ..text.expr import ExprError, check_rectangular, evaluate
from ..text.yamlio import file_problem
from .spec import Address, DiagramSpec, parse_file
from .units import related_names


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


class Range(NamedTuple):
    """An element range as written in a diagram file: ``[start:stop]`` of output ``of``
    (``stop`` None: to the end; negative bounds count from the end), for
    :func:`~.sizes.range_bounds` once the output's size is known."""

    start: int
    stop: int | None
    text: str     #: the range as written: ``[2]`` or ``[0:-1]``
    of: str       #: the output it selects from, as written: ``i.y``, ``s.bad``
    what: str     #: where it is written: ``connection source``, ``exposed output 'y'``
    file: str
    line: int
    #: flat path of the block or subsystem instance it reads (``m.v`` for ``v.y[1:]`` in
    #: the file of instance ``m``): an error names the instances around it
    at: str = ""


@dataclass
class FlatConn:
    """``src`` output (path, port, start, stop) feeding ``dst`` input (path, port).

    ``ranges`` are the element ranges as written, innermost first (an exposed subsystem
    output's own range, then the range a parent takes of it): ``src`` has no range
    (``None, None``) until the size pass resolves them into it and empties ``ranges``."""

    src: tuple
    dst: tuple
    file: str
    line: int
    text: str
    ranges: tuple = ()


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
    #: exposed output (an alias ``"s.out"``, or an output of the top level) -> ``(path,
    #: port, ranges)`` with element ranges as written; the size pass checks them and
    #: writes the resolved alias into ``aliases``
    out_ranges: dict = field(default_factory=dict)

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


def _unit_factor(unit, decl, record):
    """``(a, b)`` converting a value given in ``unit`` to the unit of declaration ``decl``:
    ``value = a * given + b`` (``b`` is 0 but for a temperature on a scale with an offset,
    ``degC`` -> ``K``; see :func:`spidersim.text.units.affine`).

    Without a declaration (a diagram or subsystem parameter) the value goes to coherent SI.
    For a parameter whose unit is inherited (``*`` or a rule, e.g. a Gain's ``k``) there is
    no conversion: ``record(unit)`` keeps the unit for unit inference and None is returned
    (:func:`_check_kept_units` then refuses one on a ``*`` parameter that no unit rule of
    its block uses: TransferFunction ``num``, StateSpace ``A``).

    Raises
    ------
    UnitError
        An unknown or incompatible unit, a unit on an int, bool or str parameter, or a
        scale with an offset on an inherited unit (it could not be multiplied).
    """
    given = U.parse(unit)
    if decl is None:
        return U.affine(given, U.base(given))
    if decl.kind != "real":
        raise U.UnitError(f"a {decl.kind} parameter takes no unit")
    if callable(decl.unit) or decl.unit == U.ANY or "@" in decl.unit:
        U.check_no_offset(given, "a parameter that inherits its unit (kept, not converted)")
        if record is not None:
            record(unit)
        return None
    return U.affine(given, U.parse(decl.unit))


def _quantity(value, scope, decl, file, line, what, block, record):
    """``{value: x, unit: u}``: x converted to the declared unit of ``decl`` (see
    :func:`_unit_factor`); a converted value must be a number or a list of numbers."""
    if set(value) == {"each"}:
        raise ParameterError(f"{what}: 'each' gives one value per instance of a block "
                             f"array (g[1..3]: {{type: Gain, k: {{each: [1, 2, 3]}}}}); "
                             f"this entry is not a block array: write the one value itself",
                             file=file, line=line, block=block)
    if set(value) != {"value", "unit"}:
        raise ParameterError(f"{what}: a value with a unit is written {{value: 2.5, unit: "
                             f"N.m}}; got the keys {', '.join(map(str, value))}", file=file,
                             line=line, block=block)
    if isinstance(value["value"], dict) and set(value["value"]) == {"each"}:
        raise ParameterError(f"{what}: 'each' goes outside the unit, one value with its "
                             f"unit per instance: {{each: [{{value: 1, unit: ms}}, "
                             f"{{value: 2, unit: ms}}]}}", file=file, line=line, block=block)
    if isinstance(value["value"], dict):
        # {value: {value: 1, unit: mm}, unit: V/A} read 1 mm as 0.001 V/A
        raise ParameterError(f"{what}: the value of a value with a unit is a number, a list "
                             f"of numbers or an expression, not another value with a unit",
                             file=file, line=line, block=block)
    x = _eval_value(value["value"], scope, None, file, line, what, block)
    try:
        ab = _unit_factor(value["unit"], decl, record)
    except U.UnitError as exc:
        want = f" (declared [{decl.unit}])" if decl is not None and isinstance(
            decl.unit, str) else ""
        raise ParameterError(f"{what}{want}: {exc}", file=file, line=line,
                             block=block) from None
    if ab is None or ab == (1.0, 0.0):
        return x
    if isinstance(x, bool) or not isinstance(x, (int, float, list)):
        raise ParameterError(f"{what}: a value with a unit must be a number or a list of "
                             f"numbers", file=file, line=line, block=block)
    return _converted(x, ab, value["unit"], file, line, what, block)


def _converted(x, ab, unit, file, line, what, block):
    """``a * x + b`` for ``ab = (a, b)`` (``x`` a number or a list given in ``unit``), as
    a list or a float. A finite value the conversion makes infinite (``1e308 km``) is a
    ParameterError: it was kept as inf, read as 'never' by ``Step.t_step``; an infinity
    given with a unit stays one, element by element (``[1e306, -.inf] km`` was kept whole as
    ``[inf, -inf]``: the check looked at the list as a whole)."""
    a, b = ab
    given = np.asarray(x, dtype=float)
    with np.errstate(all="ignore"):
        out = given * a + b
    if (np.isinf(out) & np.isfinite(given)).any():
        raise ParameterError(f"{what}: {x!r} [{unit}] overflows to infinity when "
                             f"converted (beyond 1.8e308)", file=file, line=line, block=block)
    return out.tolist()


def _plain_value(value, scope, file, line, what, block=None):
    """A value without a unit: an expression (evaluated in ``scope``), a list (element by
    element, an error in an element located like one in the whole value: same file, line
    and ``block``), a number or a boolean; an empty entry or anything else is an
    ExprError."""
    if isinstance(value, str):
        return evaluate(value, scope)
    if isinstance(value, list):
        out = [_eval_value(v, scope, None, file, line, what, block) for v in value]
        check_rectangular(out)
        return out
    if value is None:
        raise ExprError("no value given (empty entry)")
    if isinstance(value, (bool, int, float)):
        return value
    raise ExprError(f"unsupported value {value!r}")


def _eval_value(value, scope, decl, file, line, what, block=None, record=None):
    """Evaluate a YAML parameter value in ``scope``; strings of str-kind params stay.

    ``{value, unit}`` mappings are converted (:func:`_quantity`); errors are
    ParameterErrors located at ``file:line`` and starting with ``what``.
    """
    if decl is not None and decl.kind == "str":
        return value
    if isinstance(value, dict):
        return _quantity(value, scope, decl, file, line, what, block, record)
    try:
        return _plain_value(value, scope, file, line, what, block)
    except ExprError as exc:
        lead = ("expected a number or an expression of parameters; "
                if isinstance(value, str) else "")
        raise ParameterError(f"{what}: {lead}{exc}", file=file, line=line,
                             block=block) from None


def _parameter_value(raw, scope, file, line, what, block=None):
    """The value of a diagram or subsystem parameter (in the file, of an instance, by
    ``--set`` or ``set=``): :func:`_eval_value` without a declaration, and never NaN (a
    ParameterError located at ``file:line``). NaN has no use as a parameter and vanished
    silently (``min(2, tau)`` was 2). An infinity is kept: passed on whole it meets the
    check of the block parameter it reaches (allowed for a limit, ``Step.t_step``), and
    an expression refuses to compute with it (see :mod:`spidersim.text.expr`)."""
    value = _eval_value(raw, scope, None, file, line, what, block)
    if isinstance(value, (int, float, list)) and not isinstance(value, bool):
        with np.errstate(all="ignore"):
            try:
                nan = np.isnan(np.asarray(value, dtype=float)).any()
            except (TypeError, ValueError, OverflowError):
                nan = False
        if nan:
            raise ParameterError(f"{what} must not be NaN, got {value!r}: a parameter is a "
                                 f"number (min, max and comparisons would drop a NaN "
                                 f"silently)", file=file, line=line, block=block)
    return value


def eval_parameters(spec: DiagramSpec, given: dict, prefix: str):
    """Evaluate the diagram's parameters in order, with instance values ``given``."""
    scope = {}
    for name, raw in spec.parameters.items():
        if name in given:
            scope[name] = given[name]
            continue
        scope[name] = _parameter_value(raw, scope, spec.file, spec.param_lines.get(name),
                                       f"parameter '{prefix}{name}'")
    unknown = [k for k in given if k not in spec.parameters]
    return scope, unknown


def _check_declared_unit(raw, declared, file, line, what, block=None):
    """A value given with a unit for a diagram or subsystem parameter declared with one
    (``tau: {value: 1, unit: s}``) must have the declared dimension: it is converted to
    coherent SI like the default, so ``{value: 5, unit: m}`` was 5 s (``degC`` 278.15 s).
    A ParameterError naming both units otherwise; a unit that does not parse is left to
    the conversion's own error."""
    if not (isinstance(raw, dict) and isinstance(declared, dict)):
        return
    try:
        given, want = U.parse(raw.get("unit")), U.parse(declared.get("unit"))
    except U.UnitError:
        return
    if given.dimensionality != want.dimensionality:
        raise ParameterError(
            f"{what}: [{raw['unit']}] is not a unit of the parameter's dimension: it is "
            f"declared in [{declared['unit']}] ({want.dimensionality}, not "
            f"{given.dimensionality}); give the value in [{declared['unit']}] or a unit "
            f"of the same kind", file=file, line=line, block=block)


def _top_level_given(spec, overrides, used):
    """The overrides of top-level parameters (keys without a dot), evaluated without a
    scope and marked used; a name the diagram does not have suggests near ones."""
    given = {}
    for k, v in overrides.items():
        if "." in k:
            continue
        if k not in spec.parameters:
            near = difflib.get_close_matches(k, list(spec.parameters), n=3)
            hint = f"; did you mean {', '.join(near)}?" if near else ""
            raise ParameterError(f"--set {k}: the diagram has no parameter '{k}'{hint}",
                                 file=spec.file)
        _check_declared_unit(v, spec.parameters[k], spec.file, None, f"--set {k}")
        given[k] = _parameter_value(v, {}, spec.file, None, f"--set {k}")
        used.add(k)
    return given


def flatten(spec: DiagramSpec, overrides: dict | None = None) -> Flat:
    """Flatten the top-level ``spec`` with ``overrides`` (dotted path -> value).

    Top-level parameter overrides replace the file's values before the other parameters
    are evaluated; dotted overrides go to blocks and subsystems (:func:`_instantiate`);
    an override that reaches nothing is a ParameterError.
    """
    overrides = dict(overrides or {})
    used = set()
    top_given = _top_level_given(spec, overrides, used)
    # override values that are expressions are evaluated with the top-level scope
    scope0, _ = eval_parameters(spec, top_given, "")
    for k, v in list(top_given.items()):
        scope0[k] = v
    flat = Flat({}, [], {}, scope=dict(scope0))
    sub_overrides = {k: v for k, v in overrides.items() if "." in k}
    _instantiate(spec, "", scope0, sub_overrides, flat, [os.path.realpath(spec.file)], used,
                 top=True)
    missing = [k for k in overrides if k not in used]
    if missing:
        raise ParameterError(f"--set {missing[0]}: no such block parameter or subsystem "
                             f"parameter (write block.param, e.g. motor.R)", file=spec.file)
    return flat


class PortMaps(NamedTuple):
    """The exposed ports of one instantiated diagram, in flat terms."""

    #: exposed input -> list of primitive inputs ``(path, port)`` it feeds
    inputs: dict
    #: exposed output -> ``(path, port, ranges)``: the primitive output and the element
    #: ranges (:class:`Range`, innermost first) it takes of it
    outputs: dict


class BlockOverrides(NamedTuple):
    """The ``--set`` entries addressed to one block of a diagram level.

    Each value is ``(key, value)`` with ``key`` the entry as written below this level
    (``"motor.R"``), so messages and the ``used`` set name it.
    """

    own: dict       #: parameter of the block (or of the subsystem) -> (key, value)
    deeper: dict    #: ``block.param`` inside the subsystem -> (key, value)


@dataclass(frozen=True)
class _Level:
    """One diagram being instantiated under ``prefix`` (``""`` at the top, ``"j3."`` for
    the blocks of subsystem instance ``j3``)."""

    spec: DiagramSpec
    prefix: str
    scope: dict       #: the diagram's parameters, evaluated
    flat: Flat        #: the flat diagram being filled
    stack: list       #: real paths of the files being instantiated (cycle check)
    used: set         #: override keys of this level that found their target


def _hint(word, choices):
    """``"; did you mean a, b?"`` with up to three of ``choices`` close to ``word``, or ''."""
    near = difflib.get_close_matches(word, list(choices), n=3)
    return f"; did you mean {', '.join(near)}?" if near else ""


def _check_override_targets(spec, prefix, overrides):
    """Every override key must start with a block of ``spec`` (ParameterError naming the
    nearest blocks otherwise)."""
    for k in overrides:
        head = k.partition(".")[0]
        if head not in spec.blocks:
            where = f"in '{prefix[:-1]}'" if prefix else "in the diagram"
            raise ParameterError(f"--set {prefix}{k}: there is no block '{head}' "
                                 f"{where}{_hint(head, spec.blocks)}", file=spec.file)


def _overrides_for(bname, overrides) -> BlockOverrides:
    """Split the overrides addressed to block ``bname``: ``bname.p`` -> own ``p``,
    ``bname.x.p`` -> deeper ``x.p``."""
    own, deeper = {}, {}
    for k, v in overrides.items():
        head, _, rest = k.partition(".")
        if head == bname:
            (deeper if "." in rest else own)[rest] = (k, v)
    return BlockOverrides(own, deeper)


def _note_parent_line(exc, b, path, spec):
    """Append to ``exc`` which parent line brought subsystem type ``b.type`` in."""
    exc.message += (f" (subsystem type '{b.type}' of block '{path}', "
                    f"{os.path.basename(spec.file)}:{b.line})")


def _load_subsystem(level, b, path, sub_specs):
    """``(file, DiagramSpec)`` of the subsystem type of block ``b``, parsed once per file
    (``sub_specs`` caches them).

    Raises
    ------
    DiagramError
        When the type includes itself (the chain of files is named; files are compared by
        their real paths, so a link such as ``d -> .`` in ``d/x.yaml`` cannot hide a
        cycle), the nesting is deeper than :data:`limits.MAX_SUBSYSTEM_DEPTH`, its file is
        missing or not a regular file, or the file has an error (the parent line is
        appended).
    """
    spec = level.spec
    sub_file = spec.subsystems[b.type]
    if os.path.realpath(sub_file) in level.stack:
        chain = " -> ".join(os.path.basename(s) for s in level.stack + [sub_file])
        real = os.path.realpath(sub_file)
        if real != os.path.abspath(sub_file):
            chain += f"; {sub_file} is {real} through a link"
        raise DiagramError(f"subsystem type '{b.type}' includes itself ({chain})",
                           file=spec.file, line=b.line, block=path)
    if len(level.stack) > limits.MAX_SUBSYSTEM_DEPTH:
        raise _too_deep(level, path, sub_file)
    if sub_file not in sub_specs:
        what = file_problem(sub_file)
        if what:
            raise DiagramError(f"subsystem file for type '{b.type}' {what}: {sub_file}",
                               file=spec.file, line=spec.subsystem_lines.get(b.type),
                               block=path)
        try:
            sub_specs[sub_file] = parse_file(sub_file)
        except DiagramError as exc:
            _note_parent_line(exc, b, path, spec)
            raise
    return sub_file, sub_specs[sub_file]


def _too_deep(level, path, sub_file):
    """The error for subsystem instance ``path`` nested deeper than
    :data:`limits.MAX_SUBSYSTEM_DEPTH`, located at the top-level instance that starts the
    chain (one file of a long chain is not to blame) and naming the chain's ends."""
    names = [os.path.basename(s) for s in level.stack + [sub_file]]
    chain = " -> ".join(names[:3] + ["..."] + names[-2:]) if len(names) > 6 else \
        " -> ".join(names)
    top = path.split(".")[0]
    typ, file, line = level.flat.instances[top]
    return DiagramError(f"subsystems nested more than {limits.MAX_SUBSYSTEM_DEPTH} levels "
                        f"deep (limit MAX_SUBSYSTEM_DEPTH): instance '{top}' of type '{typ}' "
                        f"starts a chain of files {chain} that reaches level "
                        f"{len(level.stack)} at '{path}'", file=file,
                        line=line, block=top)


def _subsystem_given(level, b, path, sub):
    """The subsystem parameters given by the instance entry ``b``, evaluated in the
    parent's scope (name -> value); an unknown name is a ParameterError at its line."""
    spec, given = level.spec, {}
    for pname, raw in b.params.items():
        if pname not in sub.parameters:
            raise ParameterError(
                f"unknown parameter '{pname}' for subsystem type '{b.type}'"
                f"{_hint(pname, sub.parameters)} "
                f"(parameters: {', '.join(sub.parameters) or 'none'})",
                file=spec.file, line=b.param_lines.get(pname), block=path)
        _check_declared_unit(raw, sub.parameters[pname], spec.file,
                             b.param_lines.get(pname), f"parameter '{pname}'", block=path)
        given[pname] = _parameter_value(raw, level.scope, spec.file,
                                        b.param_lines.get(pname), f"parameter '{pname}'",
                                        block=path)
    return given


def _subsystem_overrides(level, b, path, sub, own, given):
    """Add the ``--set path.p`` overrides of subsystem parameters to ``given`` (evaluated in
    the parent's scope) and mark them used. ``path.blk`` without a parameter, or a name
    that is not a subsystem parameter, is a ParameterError."""
    spec, prefix = level.spec, level.prefix
    for pname, (key, v) in own.items():
        if pname in sub.parameters:
            _check_declared_unit(v, sub.parameters[pname], spec.file, b.line,
                                 f"--set {prefix}{key}", block=path)
            given[pname] = _parameter_value(v, level.scope, spec.file, b.line,
                                            f"--set {prefix}{key}", block=path)
            level.used.add(key)
            continue
        what = (f"'{pname}' is a block of it: write {prefix}{key}.param"
                if pname in sub.blocks else
                f"it has no parameter '{pname}'{_hint(pname, sub.parameters)}")
        raise ParameterError(
            f"--set {prefix}{key}: '{path}' is a subsystem of type '{b.type}'; "
            f"{what} (parameters: {', '.join(sub.parameters) or 'none'})",
            block=path, file=spec.file, line=b.line)


def _instantiate_subsystem(level, bname, b, ov: BlockOverrides, sub_specs) -> PortMaps:
    """Instantiate block ``b`` of ``level``, whose type is a subsystem, under
    ``prefix + bname + "."``: evaluate its parameters, recurse, record the instance and its
    output aliases in the flat diagram; return its port maps.

    An error raised in the subsystem's own file gets the parent line appended (once).
    """
    spec, flat = level.spec, level.flat
    path = level.prefix + bname
    sub_file, sub = _load_subsystem(level, b, path, sub_specs)
    given = _subsystem_given(level, b, path, sub)
    _subsystem_overrides(level, b, path, sub, ov.own, given)
    sub_scope, _ = eval_parameters(sub, given, path + ".")
    sub_over = {k: v for k, (key, v) in ov.deeper.items()}
    keymap = {k: key for k, (key, v) in ov.deeper.items()}
    sub_used = set()
    flat.instances[path] = (b.type, spec.file, b.line)
    try:
        maps = _instantiate(sub, path + ".", sub_scope, sub_over, flat,
                            level.stack + [os.path.realpath(sub_file)], sub_used)
    except SpidersimError as exc:
        if exc.file == sub_file and not getattr(exc, "_used_at", False):
            _note_parent_line(exc, b, path, spec)
            exc._used_at = True
        raise
    level.used.update(keymap[k] for k in sub_used if k in keymap)
    for oname, (opath, oport, ranges) in maps.outputs.items():
        flat.aliases[f"{path}.{oname}"] = (opath, oport, None, None)
        if ranges:
            flat.out_ranges[f"{path}.{oname}"] = (opath, oport, ranges)
    flat.subsystem_instances[path] = sub_file
    return maps


def _block_class(spec, b, path):
    """The Block class of ``b.type`` (BlockTypeError naming the block path when unknown;
    the subsystem types of ``spec`` are among the suggestions)."""
    try:
        return lookup(b.type, spec.file, b.line, extra=list(spec.subsystems))
    except SpidersimError as exc:
        exc.block = path
        raise


def _beside_file(value, decl, file):
    """A relative path given to a file parameter (``Arm.model: arms/my_arm.yaml``) in a
    diagram file names a file beside that diagram file, as subsystem paths do; the
    parameter's default (``spider``: the data shipped with spidersim), absolute paths and
    values of diagrams read from text keep their meaning (``--set`` values are paths of the
    command line: relative to the current folder)."""
    if (decl is None or not decl.file or not isinstance(value, str) or value == decl.default
            or os.path.isabs(value) or not os.path.isfile(file or "")):
        return value
    return os.path.join(os.path.dirname(os.path.abspath(file)), value)


def _block_values(level, b, path, cls, own):
    """The parameter values of primitive block ``b``: the file's entries, then its
    ``--set`` overrides (marked used), evaluated with their declarations.

    Returns
    -------
    values : dict
        name -> evaluated value (not yet validated).
    units : dict
        name -> unit text given with a value whose declared unit is inherited.
    """
    spec, prefix = level.spec, level.prefix
    values, punits = {}, {}
    for pname, raw in b.params.items():
        values[pname] = _eval_value(raw, level.scope, cls.parameters.get(pname), spec.file,
                                    b.param_lines.get(pname), f"parameter '{pname}'",
                                    block=path,
                                    record=functools.partial(punits.__setitem__, pname))
        values[pname] = _beside_file(values[pname], cls.parameters.get(pname), spec.file)
    for pname, (key, v) in own.items():
        decl = cls.parameters.get(pname)
        if decl is None:
            raise ParameterError(f"--set {prefix}{key}: block type {cls.type_name} has no "
                                 f"parameter '{pname}'{_hint(pname, cls.parameters)} "
                                 f"(parameters: {', '.join(cls.parameters)})", block=path,
                                 file=spec.file, line=b.line)
        if decl.kind == "str" and isinstance(v, str):
            values[pname] = v
        else:
            values[pname] = _eval_value(v, level.scope, decl, spec.file, b.line,
                                        f"--set {prefix}{key}", block=path,
                                        record=functools.partial(punits.__setitem__, pname))
        level.used.add(key)
    return values, punits


def _instantiate_block(level, bname, b, ov: BlockOverrides):
    """Add primitive block ``b`` of ``level`` to the flat diagram as an :class:`Instance`
    with validated parameters (errors name the block path and the parameter's line)."""
    spec, flat = level.spec, level.flat
    path = level.prefix + bname
    cls = _block_class(spec, b, path)
    values, punits = _block_values(level, b, path, cls, ov.own)
    if ov.deeper:
        k = next(iter(ov.deeper.values()))[0]
        raise ParameterError(f"--set {level.prefix}{k}: '{path}' is a {cls.type_name} block, "
                             f"not a subsystem", block=path, file=spec.file, line=b.line)

    def where(name):
        return spec.file, (b.param_lines.get(name) if name else b.line)

    try:
        params = cls.validate_params(values, where=where)
    except ParameterError as exc:
        exc.block = path
        raise
    _check_kept_units(cls, params, punits, path, where,
                      lambda n: (f"--set {level.prefix}{ov.own[n][0]}" if n in ov.own else
                                 f"parameter '{n}'"))
    if path in flat.blocks:
        raise DiagramError(f"duplicate block path '{path}'", file=spec.file, line=b.line)
    if len(flat.blocks) >= limits.MAX_BLOCKS:
        raise DiagramError(f"more than {limits.MAX_BLOCKS} blocks once the subsystems are "
                           f"expanded (limit MAX_BLOCKS; the compile time and memory grow "
                           f"with the blocks): split the study into smaller diagrams",
                           file=spec.file, line=b.line, block=path)
    flat.blocks[path] = Instance(path, cls, params, spec.file, b.line, dict(b.param_lines),
                                 {k: v for k, v in punits.items() if k in params})


def _check_kept_units(cls, params, punits, path, where, what):
    """A unit given with a parameter declared ``*`` (kept for unit inference, not
    converted: see :func:`_unit_factor`) that no unit rule or relation of the block uses is
    refused: it would be dropped, and the number used as written (a TransferFunction's
    ``num: {value: [10], unit: percent}`` was 10, not 0.1). ``punits``: name -> unit text
    kept; ``where(name)`` -> (file, line); ``what(name)`` starts the message (``parameter
    'num'``, ``--set t.num``)."""
    related = None
    for name, unit in punits.items():
        decl = cls.parameters.get(name)
        if decl is None or cls.unit_of(decl, params) != U.ANY:
            continue                      # a rule such as "@y": the unit joins the port's
        related = related_names(cls, params) if related is None else related
        if name in related:
            continue
        file, line = where(name)
        if line is None:                  # a --set of a parameter the file leaves out
            file, line = where(None)
        raise ParameterError(
            f"{what(name)}: {cls.type_name} keeps no unit for '{name}' (declared [*]: "
            f"no port's unit depends on it), so [{unit}] would be dropped and the number "
            f"used as written; give the plain number, converted by hand (10 percent is "
            f"0.1, 5 mm is 0.005 in m)", file=file, line=line, block=path)


class _LocalAddresses:
    """Resolves ``block.port`` addresses of one diagram level into flat ones, through the
    port maps of its subsystem instances (``local_subs``: block name -> PortMaps)."""

    def __init__(self, spec, prefix, local_subs):
        self.spec, self.prefix, self.local_subs = spec, prefix, local_subs

    def source(self, a: Address, line, what="connection source"):
        """``(path, port, ranges)``: the flat output that source ``a`` names and the element
        ranges taken of it (:class:`Range`, innermost first); a range of a subsystem output
        is taken of the range the output exposes. Checked once the sizes are known."""
        own = () if a.start is None else (
            Range(a.start, a.stop, str(a)[len(a.block) + len(a.port) + 1:],
                  f"{a.block}.{a.port}", what, self.spec.file, line, self.prefix + a.block),)
        if a.block in self.local_subs:
            out_map = self.local_subs[a.block].outputs
            if a.port not in out_map:
                raise WiringError(
                    f"subsystem instance '{self.prefix}{a.block}' has no output '{a.port}' "
                    f"(outputs: {', '.join(out_map) or 'none'})", file=self.spec.file,
                    line=line)
            path, port, ranges = out_map[a.port]
            return (path, port, ranges + own)
        self._check_block(a, line)
        return (self.prefix + a.block, a.port, own)

    def destinations(self, a: Address, line):
        """The flat inputs ``[(path, port), ...]`` that destination ``a`` names (a
        subsystem input may feed several)."""
        if a.block in self.local_subs:
            in_map = self.local_subs[a.block].inputs
            if a.port not in in_map:
                raise WiringError(
                    f"subsystem instance '{self.prefix}{a.block}' has no input '{a.port}' "
                    f"(inputs: {', '.join(in_map) or 'none'})", file=self.spec.file,
                    line=line)
            return in_map[a.port]
        self._check_block(a, line)
        return [(self.prefix + a.block, a.port)]

    def _check_block(self, a, line):
        """``a.block`` must be a block of this level (WiringError with near names)."""
        if a.block not in self.spec.blocks:
            raise WiringError(f"connection refers to unknown block '{a.block}'"
                              f"{_hint(a.block, self.spec.blocks)}", file=self.spec.file,
                              line=line)


def _wire_connections(level, addresses):
    """Append a :class:`FlatConn` for every connection of the level and destination."""
    spec = level.spec
    for c in spec.connections:
        path, port, ranges = addresses.source(c.src, c.line)
        for dst in addresses.destinations(c.dst, c.line):
            level.flat.conns.append(FlatConn((path, port, None, None), dst, spec.file,
                                             c.line, f"{c.src} -> {c.dst}", ranges))


def _check_exposed_target(level, kind, name, a, path, port, line):
    """Exposed ``kind`` (``"input"`` or ``"output"``) ``name`` maps to ``a``: primitive block
    ``path`` must have a port ``port`` of that kind. A WiringError at the exposed port's
    line otherwise, saying when it is a port of the other kind and listing the block's
    ports of the right kind (an output mapped to an input port was an internal error)."""
    inst = level.flat.blocks[path]
    names = (inst.cls.input_names if kind == "input" else inst.cls.output_names)(inst.params)
    if port in names:
        return
    other = "output" if kind == "input" else "input"
    others = (inst.cls.output_names if kind == "input" else inst.cls.input_names)(inst.params)
    if port in others:
        what = f"'{port}' is an {other} port of block '{a.block}' ({inst.cls.type_name})"
        why = f": an exposed {kind} must name an {kind} port"
    else:
        near = difflib.get_close_matches(port, names, n=2)
        what = (f"block '{a.block}' ({inst.cls.type_name}) has no {kind} '{port}'"
                + (f"; did you mean {', '.join(near)}?" if near else ""))
        why = ""
    raise WiringError(f"exposed {kind} '{name}' maps to '{a}', but {what}{why}; {kind}s of "
                      f"'{a.block}': {', '.join(names) or 'none'}", file=level.spec.file,
                      line=line, block=path)


def _exposed_inputs(level, addresses):
    """The level's exposed inputs -> flat inputs they feed; each fed primitive input is
    recorded in ``flat.exposed`` (the outermost exposure is written last and stays)."""
    spec, flat = level.spec, level.flat
    in_map = {}
    for name, addrs in spec.inputs.items():
        line = spec.port_lines[("in", name)]
        targets = []
        for a in addrs:
            if a.start is not None:
                raise WiringError(f"exposed input '{name}' must map to whole input ports",
                                  file=spec.file, line=line)
            got = addresses.destinations(a, line)
            for dst_path, dst_port in got:
                if a.block not in addresses.local_subs:
                    _check_exposed_target(level, "input", name, a, dst_path, dst_port, line)
                flat.exposed[(dst_path, dst_port)] = (level.prefix[:-1], name, spec.file,
                                                      line)
            targets += got
        in_map[name] = targets
    return in_map


def _exposed_outputs(level, addresses):
    """The level's exposed outputs -> the flat output slices they are; one naming a port of
    a primitive block must name an output port (:func:`_check_exposed_target`)."""
    spec, out = level.spec, {}
    for name, a in spec.outputs.items():
        line = spec.port_lines[("out", name)]
        out[name] = addresses.source(a, line, f"exposed output '{name}'")
        if a.block not in addresses.local_subs:
            _check_exposed_target(level, "output", name, a, out[name][0], a.port, line)
    return out


def _check_no_shadowing(spec):
    """A subsystem type may not have the name of a library block: ``subsystems: {Gain:
    lag.yaml}`` silently made every ``type: Gain`` of the file a lag. A DiagramError at
    the subsystem entry's line names the library block it would hide."""
    for name in spec.subsystems:
        if name in REGISTRY:
            raise DiagramError(
                f"subsystem type '{name}' has the name of the library block {name} "
                f"(`spidersim blocks {name}`): every 'type: {name}' of this file would "
                f"silently mean {os.path.basename(spec.subsystems[name])} instead; give the "
                f"subsystem type another name", file=spec.file,
                line=spec.subsystem_lines.get(name))


def _check_unused_subsystems(spec):
    """Every subsystem type of ``spec`` that no block uses still names a readable diagram
    file: such an entry was never opened, so ``subsystems: {A: nothere.yaml, B: /dev/zero}``
    passed ``check``. A missing, unreadable or malformed file is a DiagramError at the
    entry's line, or the file's own error (a DiagramError, a WiringError for a bad
    connection) in that file with the entry named; the file's own subsystems are not
    opened (nothing instantiates it). A valid unused entry is allowed."""
    used = {b.type for b in spec.blocks.values()}
    for name, path in spec.subsystems.items():
        if name in used:
            continue
        line = spec.subsystem_lines.get(name)
        what = file_problem(path)
        if what:
            raise DiagramError(f"subsystem file for type '{name}' {what}: {path} (no block "
                               f"uses the type: fix the path or remove the entry)",
                               file=spec.file, line=line)
        try:
            parse_file(path)
        except SpidersimError as exc:     # a DiagramError, a WiringError (c.y[1:2:3]), ...
            exc.message += (f" (subsystem type '{name}', {os.path.basename(spec.file)}:"
                            f"{line}, used by no block)")
            raise


def _instantiate(spec, prefix, scope, overrides, flat, stack, used, top=False) -> PortMaps:
    """Add the blocks of ``spec`` under ``prefix`` to ``flat``; return its port maps.

    Parameters
    ----------
    spec : DiagramSpec
        The diagram (top level or a subsystem file).
    prefix : str
        Dotted path of the instance with a trailing dot (``""`` at the top).
    scope : dict
        The diagram's parameters, evaluated.
    overrides : dict
        ``--set`` entries relative to this level (``"motor.R"``, ``"j1.motor.R"``).
    flat : Flat
        Filled in place.
    stack : list of str
        Files being instantiated, outermost first (a type including itself is an error).
    used : set
        Receives the override keys that found their target.

    The blocks are instantiated in file order (subsystems recursively), then the
    connections are wired and the exposed ports mapped.
    """
    level = _Level(spec, prefix, scope, flat, stack, used)
    _check_no_shadowing(spec)
    _check_unused_subsystems(spec)
    _check_override_targets(spec, prefix, overrides)
    sub_specs = {}
    local_subs = {}  # instance name -> PortMaps
    for bname, b in spec.blocks.items():
        ov = _overrides_for(bname, overrides)
        if b.type in spec.subsystems:
            local_subs[bname] = _instantiate_subsystem(level, bname, b, ov, sub_specs)
        else:
            _instantiate_block(level, bname, b, ov)
    addresses = _LocalAddresses(spec, prefix, local_subs)
    _wire_connections(level, addresses)
    maps = PortMaps(_exposed_inputs(level, addresses), _exposed_outputs(level, addresses))
    if top:   # a file checked on its own: its exposed ranges are checked too
        flat.out_ranges.update((k, v) for k, v in maps.outputs.items() if v[2])
    return maps
