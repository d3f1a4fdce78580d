"""A small safe evaluator for parameter expressions such as ``2*pi*955/60`` or ``ratio*J_m``.

It walks Python's AST and accepts only numbers, lists, names of diagram parameters and
constants, the arithmetic operators ``+ - * / // % **``, unary minus and a few math functions.
Nothing is ever passed to ``eval``; attribute access, subscripts other than ``name[int]``,
comprehensions, lambdas and calls to anything but the listed functions are rejected.
"""
from __future__ import annotations

import ast
import difflib
import math
import operator

import numpy as np

from . import limits

CONSTANTS = {"pi": math.pi, "e": math.e, "inf": math.inf}

FUNCTIONS = {
    "sin": math.sin, "cos": math.cos, "tan": math.tan, "asin": math.asin, "acos": math.acos,
    "atan": math.atan, "atan2": math.atan2, "sqrt": math.sqrt, "exp": math.exp,
    "log": math.log, "log10": math.log10, "abs": abs, "min": min, "max": max,
    "deg": math.degrees, "rad": math.radians, "len": len,
}

_BINOPS = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul,
           ast.Div: operator.truediv, ast.FloorDiv: operator.floordiv, ast.Mod: operator.mod,
           ast.Pow: operator.pow}
_UNOPS = {ast.USub: operator.neg, ast.UAdd: operator.pos}


class ExprError(ValueError):
    """A bad expression; the message says what and where in the expression."""


def _short(text):
    return text if len(text) <= 60 else text[:57] + "..."


def _depth(tree):
    """Nesting depth of a syntax tree (iterative: deep trees cannot exhaust the stack)."""
    deepest, stack = 0, [(tree, 1)]
    while stack:
        node, d = stack.pop()
        deepest = max(deepest, d)
        if deepest > limits.MAX_EXPR_DEPTH:
            break
        stack.extend((c, d + 1) for c in ast.iter_child_nodes(node))
    return deepest


def evaluate(text: str, names: dict):
    """Evaluate ``text`` with the given parameter ``names``; raise :class:`ExprError`.

    Bounded: at most :data:`limits.MAX_EXPR_CHARS` characters and a syntax tree at most
    :data:`limits.MAX_EXPR_DEPTH` deep (see :mod:`spidersim.text.limits`).
    """
    if len(text) > limits.MAX_EXPR_CHARS:
        raise ExprError(f"expression of {len(text)} characters is longer than the limit of "
                        f"{limits.MAX_EXPR_CHARS}: '{_short(text)}'")
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as exc:
        raise ExprError(f"cannot parse expression '{_short(text)}': {exc.msg}") from None
    except (RecursionError, MemoryError):
        raise ExprError(f"expression nested too deeply to parse (limit "
                        f"{limits.MAX_EXPR_DEPTH} levels): '{_short(text)}'") from None
    if _depth(tree) > limits.MAX_EXPR_DEPTH:
        raise ExprError(f"expression nested deeper than the limit of {limits.MAX_EXPR_DEPTH} "
                        f"levels: '{_short(text)}'")
    try:
        value = _eval(tree.body, names, text)
    except ExprError:
        raise
    except RecursionError:
        raise ExprError(f"expression nested too deeply: '{_short(text)}'") from None
    except ZeroDivisionError:
        raise ExprError(f"division by zero in '{text}'") from None
    except (TypeError, ValueError, OverflowError, IndexError) as exc:
        raise ExprError(f"cannot evaluate '{_short(text)}': {exc}") from None
    except MemoryError:
        raise ExprError(f"expression result too large: '{_short(text)}'") from None
    if np.size(value) > limits.MAX_ARRAY_ELEMENTS:
        raise ExprError(f"expression gives {np.size(value)} elements, more than the limit of "
                        f"{limits.MAX_ARRAY_ELEMENTS}: '{_short(text)}'")
    return value


def _eval(node, names, text):
    if isinstance(node, ast.Constant):
        if isinstance(node.value, (int, float)) and not isinstance(node.value, bool):
            try:
                return float(node.value)   # floats only: no huge-integer arithmetic
            except OverflowError:
                raise ExprError(f"number too large in '{text}'") from None
        raise ExprError(f"only numbers are allowed in '{text}', got {node.value!r}")
    if isinstance(node, ast.Name):
        if node.id in names:
            return names[node.id]
        if node.id in CONSTANTS:
            return CONSTANTS[node.id]
        known = list(names) + list(CONSTANTS)
        near = difflib.get_close_matches(node.id, known, n=3)
        hint = f"; did you mean {', '.join(near)}?" if near else ""
        raise ExprError(f"unknown name '{node.id}' in '{text}'{hint}")
    if isinstance(node, ast.BinOp) and type(node.op) in _BINOPS:
        a, b = _eval(node.left, names, text), _eval(node.right, names, text)
        if isinstance(a, int) and not isinstance(a, bool):
            a = float(a)
        if isinstance(b, int) and not isinstance(b, bool):
            b = float(b)
        if isinstance(a, list) or isinstance(b, list):
            a, b = np.asarray(a, float), np.asarray(b, float)
            return _BINOPS[type(node.op)](a, b).tolist()
        return _BINOPS[type(node.op)](a, b)
    if isinstance(node, ast.UnaryOp) and type(node.op) in _UNOPS:
        v = _eval(node.operand, names, text)
        if isinstance(v, list):
            return _UNOPS[type(node.op)](np.asarray(v, float)).tolist()
        return _UNOPS[type(node.op)](v)
    if isinstance(node, (ast.List, ast.Tuple)):
        return [_eval(e, names, text) for e in node.elts]
    if isinstance(node, ast.Subscript) and isinstance(node.value, ast.Name):
        seq = _eval(node.value, names, text)
        idx = _eval(node.slice, names, text)
        if isinstance(idx, float) and idx.is_integer():
            idx = int(idx)
        if not isinstance(seq, list) or not isinstance(idx, int):
            raise ExprError(f"only list[int] indexing is allowed in '{text}'")
        try:
            return seq[idx]
        except IndexError:
            raise ExprError(f"index {idx} out of range in '{text}'") from None
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and not node.keywords:
        fn = FUNCTIONS.get(node.func.id)
        if fn is None:
            raise ExprError(f"unknown function '{node.func.id}' in '{text}' "
                            f"(allowed: {', '.join(sorted(FUNCTIONS))})")
        return fn(*[_eval(a, names, text) for a in node.args])
    raise ExprError(f"'{ast.unparse(node)}' is not allowed in a parameter expression "
                    f"('{text}'): use numbers, parameter names, + - * / ** and math functions")


