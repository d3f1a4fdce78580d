"""JSON Schema (draft 2020-12) of spidersim diagram files, generated from the block registry.

Editors with yaml-language-server (VS Code's YAML extension, Neovim, Helix, ...) use it for
completion of sections, block types and parameters, hover documentation (units, bounds,
defaults, ports) and inline errors. ``spidersim schema -o FILE`` writes it; the repository
keeps a copy in ``schema/spidersim.schema.json`` that shipped diagrams point to with a
first-line comment ``# yaml-language-server: $schema=../schema/spidersim.schema.json``.

The schema checks the shape of a file (sections, keys, value types, block types and their
parameter names); the loader checks everything else (expressions, bounds after evaluation,
wiring, sizes, units) with file:line errors.
"""
from __future__ import annotations

import json
import math

from .blocks import REGISTRY
from .plots import KEYS as PLOT_KEYS
from .plots import KINDS as PLOT_KINDS

DRAFT = "https://json-schema.org/draft/2020-12/schema"
NAME = r"^[A-Za-z_][A-Za-z0-9_]*$"
_IDX = r"(-?[0-9]+|\{i([+-][0-9]+)?\})"
_ID = r"[A-Za-z_]([A-Za-z0-9_.]|\{i\})*"
#: ``block.port``, ``[i]``, ``[a:b]`` with either bound left out (``[1:]``, ``[:2]``, ``[:]``)
_ADDR = rf"{_ID}\.{_ID}(\[\s*{_IDX}\s*\]|\[\s*({_IDX}\s*)?:\s*({_IDX}\s*)?\])?"
BLOCK_KEY = r"^[A-Za-z_][A-Za-z0-9_]*(\[[0-9]+\.\.[0-9]+\])?$"
CONNECTION = rf"^\s*{_ADDR}\s*->\s*{_ADDR}(\s*,\s*{_ADDR})*\s*$"
SIM_METHODS = ["LSODA", "RK45", "RK23", "DOP853", "Radau", "BDF", "DP54", "ROS34PW2", "NDF"]
REDUCERS = ["max", "min", "absmax", "final", "initial", "mean", "rms", "integral"]

#: plot file extensions (either case), as :func:`spidersim.plots.check_plot_file`
_FIGURE_EXT = "[Pp][Nn][Gg]|[Ss][Vv][Gg]|[Pp][Dd][Ff]"
_GIF = "[Gg][Ii][Ff]"


def _plot_file(ext):
    """A bare file name of at most 121 characters ending in one of ``ext`` (a regex
    alternation), as the loader's ``outputs.BARE_NAME`` and extension check."""
    return rf"^(?=.{{1,121}}$)[A-Za-z0-9_][A-Za-z0-9_.-]*\.({ext})$"


#: a text; a number is taken as its text (as the loader does: ``name: 2024``)
_TEXT = {"type": ["string", "number"]}
#: ``{value: 2.5, unit: mm}``: a value with its unit, converted to the declared one
_QUANTITY = {"type": "object", "required": ["value", "unit"], "additionalProperties": False,
             "properties": {"value": {"$ref": "#/$defs/value"},
                            "unit": {"type": "string", "minLength": 1,
                                     "description": "unit in Modelica notation: N.m, rad/s, "
                                                    "mm, deg, kg.m2"}}}
_NUMBER_OR_EXPR = {"anyOf": [{"type": "number"}, {"type": "string", "minLength": 1},
                             _QUANTITY]}
#: microgravity f_min / f_max: band centres on the ISS limit curve (0.01..300 Hz), a number
#: or an expression of the parameters
_BAND_BOUND = {"anyOf": [{"type": "number", "minimum": 0.01, "maximum": 300},
                         {"type": "string", "minLength": 1}],
               "description": "Hz, band centres assessed: within the ISS limit curve's "
                              "0.01..300 Hz"}
_VALUE = {"anyOf": [{"type": "number"}, {"type": "string", "minLength": 1},
                    {"type": "array", "items": {"$ref": "#/$defs/value"}}, _QUANTITY]}


def _bounds(decl):
    parts = [f"{op} {v:g}" for op, v in ((">", decl.gt), (">=", decl.ge), ("<", decl.lt),
                                         ("<=", decl.le)) if v is not None]
    return " and ".join(parts)


def _default(decl):
    d = decl.default
    if isinstance(d, float) and not math.isfinite(d):
        return None
    if hasattr(d, "tolist"):
        d = d.tolist()
    try:
        json.dumps(d)
    except TypeError:
        return None
    return d


def _param_schema(cls, name, decl):
    from .blocks.base import REQUIRED
    desc = decl.doc or name
    unit = cls.unit_of(decl)
    if unit and unit != "1":
        desc += f" [{unit}]"
    b = _bounds(decl)
    if b:
        desc += f"; {b}"
    if decl.kind == "str":
        out = {"type": "string"}
        if decl.choices:
            out["enum"] = list(decl.choices)
    elif decl.kind == "bool":
        out = {"anyOf": [{"type": "boolean"}, {"enum": [0, 1]},
                         {"type": "string", "minLength": 1}]}
    elif decl.kind == "int":
        out = {"anyOf": [{"type": "integer"}, {"type": "string", "minLength": 1}]}
    elif decl.shape == ():
        out = dict(_NUMBER_OR_EXPR)
    else:
        out = {"$ref": "#/$defs/value"}
        desc += " (a list; a scalar is repeated where a size is known)"
    if decl.default is not REQUIRED:
        d = _default(decl)
        if d is not None:
            out["default"] = d
            desc += f"; default {d!r}"
    else:
        desc += "; required"
    out["description"] = desc
    return out


def _port_text(cls, kind):
    ports = cls.inputs if kind == "in" else cls.outputs
    if not ports:
        return "none"
    return ", ".join(f"{n} [{cls.unit_of(p)}]" + (" (optional)" if p.optional is True else "")
                     for n, p in ports.items())


def block_schema(cls):
    """Schema of one block entry ``{type: Name, param: value, ...}``."""
    from .blocks.base import REQUIRED
    first = (cls.__doc__ or "").strip().split("\n\n")[0].replace("\n", " ")
    props = {"type": {"const": cls.type_name}}
    for n, d in cls.parameters.items():
        inner = _param_schema(cls, n, d)
        # in an array entry 'name[a..b]' a value may be {each: [one per instance]}
        props[n] = {"description": inner.pop("description"),
                    "anyOf": [inner, {"$ref": "#/$defs/each"}]}
        if "default" in inner:
            props[n]["default"] = inner.pop("default")
    for old, new in cls.renamed.items():      # accepted for one release, flagged
        props[old] = {**props[new], "deprecated": True,
                      "description": f"old name of '{new}' (rename it): "
                                     + props[new]["description"]}
        props[old].pop("default", None)
    required = ["type"] + [n for n, d in cls.parameters.items() if d.default is REQUIRED]
    return {"type": "object", "title": cls.type_name,
            "description": f"{first}\nInputs: {_port_text(cls, 'in')}.\n"
                           f"Outputs: {_port_text(cls, 'out')}.\n"
                           f"(`spidersim blocks {cls.type_name}` documents it in full.)",
            "properties": props, "required": required, "additionalProperties": False}


def schema() -> dict:
    """The JSON Schema of a diagram file (a plain dict, ready for ``json.dump``)."""
    types = sorted(REGISTRY)
    defs = {"value": _VALUE,
            "each": {"type": "object", "required": ["each"], "additionalProperties": False,
                     "properties": {"each": {"type": "array"}},
                     "description": "one value per instance of a block array"}}
    defs.update({f"block_{t}": block_schema(REGISTRY[t]) for t in types})
    block = {
        "type": "object", "required": ["type"],
        "description": "a block: {type: TypeName, parameter: value, ...}; the type is a "
                       "library block or a subsystem type of the 'subsystems' section",
        "properties": {"type": {"type": "string", "pattern": NAME,
                                "anyOf": [{"enum": types}, {"type": "string"}],
                                "description": "block type (library: " + ", ".join(types)
                                + ") or a subsystem type"}},
        "allOf": [{"if": {"properties": {"type": {"const": t}}, "required": ["type"]},
                   "then": {"$ref": f"#/$defs/block_{t}"}} for t in types],
    }
    defs["block"] = block
    plot = {"type": "object", "required": ["signals"], "additionalProperties": False,
            "properties": {
                "title": _TEXT,
                "signals": {"type": "array", "minItems": 1, "items": {"type": "string"},
                            "description": "logged signals: block.port or block.port[i]"},
                "kind": {"enum": list(PLOT_KINDS)},
                "file": {"type": "string", "pattern": _plot_file(_FIGURE_EXT + "|" + _GIF),
                         "description": "bare file name in the results folder: .png, .svg, "
                                        ".pdf (.gif for animations)"},
                "t_min": {"type": "number"}, "t_max": {"type": "number"},
                "f_max": {"type": "number", "exclusiveMinimum": 0},
                "peaks": {"type": "integer", "minimum": 0, "maximum": 20},
                "ylabel": {"type": "string"}, "one_panel": {"type": "boolean"},
                "model": {"type": "string"}, "frames": {"type": "integer", "minimum": 2},
                "fps": {"type": "number", "exclusiveMinimum": 0},
                "trace": {"type": "boolean"}}}
    assert set(plot["properties"]) == set(PLOT_KEYS), "plot keys out of date"
    # as the loader: an animation writes a GIF, the other kinds a figure
    plot["if"] = {"properties": {"kind": {"const": "animation"}}, "required": ["kind"]}
    plot["then"] = {"properties": {"file": {"pattern": _plot_file(_GIF)}}}
    plot["else"] = {"properties": {"file": {"pattern": _plot_file(_FIGURE_EXT)}}}
    signal_list = {"anyOf": [{"type": "string"}, {"type": "array",
                                                  "items": {"type": "string"}}]}
    return {
        "$schema": DRAFT,
        "$id": "https://spidersim.example/schema/diagram.json",
        "title": "spidersim diagram",
        "description": "A spidersim block diagram (YAML). See the README's YAML reference.",
        "type": "object", "required": ["blocks"], "additionalProperties": False,
        "properties": {
            "name": dict(_TEXT, description="display name; names the results folder "
                                            "(letters, digits, - and _)"),
            "description": _TEXT,
            "parameters": {"type": "object", "propertyNames": {"pattern": NAME},
                           "additionalProperties": {"$ref": "#/$defs/value"},
                           "description": "name: value or expression of earlier ones"},
            "subsystems": {"type": "object", "propertyNames": {"pattern": NAME},
                           "additionalProperties": {"anyOf": [
                               {"type": "string"},
                               {"type": "object", "properties": {"file": {"type": "string"}},
                                "required": ["file"]}]},
                           "description": "type name: path/to/file.yaml (relative)"},
            "blocks": {"type": "object", "minProperties": 1,
                       "propertyNames": {"pattern": BLOCK_KEY},
                       "additionalProperties": {"$ref": "#/$defs/block"}},
            "connections": {"type": "array", "items": {
                "type": "string", "pattern": CONNECTION,
                "description": "src.port[i:j] -> dst.port ([i:], [:j] too; several "
                               "destinations: commas)"}},
            "inputs": {"type": "object", "propertyNames": {"pattern": NAME},
                       "additionalProperties": signal_list,
                       "description": "(subsystem files) exposed input: block.port or a "
                                      "list of them"},
            "outputs": {"type": "object", "propertyNames": {"pattern": NAME},
                        "additionalProperties": {"type": "string"},
                        "description": "(subsystem files) exposed output: block.port[...]"},
            "simulation": {"type": "object", "additionalProperties": False, "properties": {
                "t_end": _NUMBER_OR_EXPR, "method": {"enum": SIM_METHODS},
                "rtol": _NUMBER_OR_EXPR, "atol": _NUMBER_OR_EXPR,
                "max_step": _NUMBER_OR_EXPR, "first_step": _NUMBER_OR_EXPR,
                "output_interval": _NUMBER_OR_EXPR}},
            "log": {"anyOf": [{"const": "all"}, {"type": "array",
                                                 "items": {"type": "string"}}]},
            "plots": {"type": "array", "items": plot},
            "analysis": {"type": "object", "propertyNames": {"pattern": NAME},
                         "additionalProperties": {
                             "type": "object", "additionalProperties": False,
                             "properties": {"inputs": signal_list, "outputs": signal_list,
                                            "open": signal_list, "loop": {"type": "string"},
                                            "at": {"anyOf": [{"type": "number"},
                                                             {"enum": ["initial", "trim"]},
                                                             {"type": "object"}]}}}},
            "metrics": {"type": "object", "propertyNames": {"pattern": NAME},
                        "additionalProperties": {
                            "type": "object", "required": ["signal"],
                            "properties": {"signal": {"type": "string"},
                                           "reduce": {"enum": REDUCERS},
                                           "unit": _TEXT}}},
            "commands": {"type": "object", "propertyNames": {"pattern": NAME},
                         "additionalProperties": {"type": "object"},
                         "description": "named commands of the remote service"},
            "microgravity": {"type": "object", "additionalProperties": False,
                             "required": ["signal", "mass"], "properties": {
                                 "signal": {"type": "string"}, "mass": _NUMBER_OR_EXPR,
                                 "window": {"type": "array", "items": {"type": "number"},
                                            "minItems": 2, "maxItems": 2},
                                 "f_min": _BAND_BOUND, "f_max": _BAND_BOUND}},
        },
        "$defs": defs,
    }


def dumps() -> str:
    """The schema as stable, indented JSON text (what ``spidersim schema`` writes)."""
    return json.dumps(schema(), indent=1, sort_keys=True) + "\n"
