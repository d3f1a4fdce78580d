"""A small safe evaluator for parameter expressions such as ``2*pi*955/60`` or ``ratio*J_m``.

It walks Python's AST and accepts only numbers, lists, names of diagram parameters and
constants, the arithmetic operators ``+ - * / // % **``, unary minus and a few math functions.
Nothing is ever passed to ``eval``; attribute access, subscripts other than ``name[int]``,
comprehensions, lambdas and calls to anything but the listed functions are rejected.
The text is ASCII (a look-alike letter is not read as the letter it resembles), a value is
never complex (refused at the operation that made it), a boolean is neither a number nor
an index, and a list is rectangular.

Non-finite numbers: NaN is refused wherever it appears (a name, an argument, a result:
``min(2, nan)`` would silently be 2; ``inf - inf``, ``0*inf``, ``inf/inf`` give one). An
infinity (``inf``, a parameter set to ``.inf``) takes part in arithmetic where IEEE gives
an exact result: ``2*inf`` and ``inf + 1`` are inf, ``min(inf, 10)`` is 10,
``max(-inf, -5)`` -5, ``1/inf`` 0 (an infinite time constant is a zero rate). An infinite
result of finite operands is refused (an overflow, ``1e200*1e200``, ``exp(1000)``, or
``[1]/[0]``), element by element for lists, and so is a number literal beyond the float
range (``1e400``: write ``inf``). An infinite value then meets the parameter check of the
block it reaches, which refuses it unless the parameter may be infinite (a limit,
``Step.t_step``).

Lists: arithmetic is element by element, a number with a list applies to every element,
and two lists must have the same shape (``[1, 2] + [3]`` is refused, not broadcast);
``min``/``max`` of one flat list is its extreme element, of several arguments the
element-wise extreme (lists of one shape, numbers applied to every element).
"""
from __future__ import annotations

import ast
import difflib
import functools
import math
import operator
import unicodedata

import numpy as np

from ..errors import printable
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
    _check_ascii(text)
    # an expression written over several lines (a YAML block scalar) is one line: line
    # breaks and tabs are spaces, as they would be inside parentheses
    text = " ".join(text.split())
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as exc:
        raise ExprError(f"cannot parse expression '{_short(text)}': {exc.msg}") from None
    except (RecursionError, MemoryError):
        raise ExprError(f"expression nested too deeply to parse (limit "
                        f"{limits.MAX_EXPR_DEPTH} levels): '{_short(text)}'") from None
    if _depth(tree) > limits.MAX_EXPR_DEPTH:
        raise ExprError(f"expression nested deeper than the limit of {limits.MAX_EXPR_DEPTH} "
                        f"levels (a sum or product of n terms is n levels deep): "
                        f"'{_short(text)}'")
    try:
        with np.errstate(all="ignore"):     # overflows: _finite_result; NaN: _eval
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
    if isinstance(value, list):
        check_rectangular(value)
    if np.size(value) > limits.MAX_ARRAY_ELEMENTS:
        raise ExprError(f"expression gives {np.size(value)} elements, more than the limit of "
                        f"{limits.MAX_ARRAY_ELEMENTS}: '{_short(text)}'")
    return value


def check_rectangular(values):
    """A list value is an array of numbers: every row of the same length, at every depth
    (``[1, [2, 3]]`` or ``[[1, 2], [3]]`` is no array; numpy refuses them with a
    ValueError about an inhomogeneous shape). An ExprError says so. Used for a list
    written in YAML and for one an expression gives (``"[[1, 2], [3]]"``)."""
    try:
        np.asarray(values, dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise ExprError("a list value must be a number list or a matrix (rows of equal "
                        "length, numbers only), got a ragged or mixed list") from None


def _check_ascii(text):
    """Expressions are ASCII (they hold no string literals): Python's parser would read a
    look-alike letter as its plain form (NFKC: fullwidth ``ｋ`` is ``k``, bold ``𝐩𝐢`` is
    ``pi``), so a name that looks foreign would silently mean a parameter. The first
    non-ASCII character is an ExprError naming it, its code point and its position."""
    for pos, ch in enumerate(text):
        if ord(ch) > 127:
            name = unicodedata.name(ch, "unnamed")
            raise ExprError(f"non-ASCII character '{printable(ch)}' (U+{ord(ch):04X} "
                            f"{name}) at character {pos + 1} of '{printable(_short(text))}':"
                            f" expressions are ASCII (names are ASCII identifiers: a "
                            f"look-alike letter would be read as another name)")


def _not_allowed(node, text):
    """The error for a syntax element the evaluator does not accept."""
    return ExprError(f"'{ast.unparse(node)}' is not allowed in a parameter expression "
                     f"('{text}'): use numbers, parameter names, + - * / ** and math "
                     f"functions")


def _constant(node, names, text):
    """A number literal, as a float (no huge-integer arithmetic); strings, booleans and
    ``None`` are refused."""
    if isinstance(node.value, (int, float)) and not isinstance(node.value, bool):
        try:
            value = float(node.value)
        except OverflowError:
            value = math.inf
        if math.isinf(value):
            raise ExprError(f"a number beyond the float range (1.8e308) in '{_short(text)}': "
                            f"it would be read as infinity; write inf if an infinity is "
                            f"meant")
        return value
    raise ExprError(f"only numbers are allowed in '{text}', got {node.value!r}")


def _name(node, names, text):
    """A parameter of ``names`` or one of :data:`CONSTANTS` (parameters first); an unknown
    name suggests the nearest ones."""
    if node.id in names:
        return names[node.id]
    if node.id in CONSTANTS:
        return CONSTANTS[node.id]
    known = list(names) + list(CONSTANTS)
    near = difflib.get_close_matches(node.id, known, n=3)
    hint = f"; did you mean {', '.join(near)}?" if near else ""
    raise ExprError(f"unknown name '{node.id}' in '{text}'{hint}")


def _int_as_float(v):
    """An int operand (not a bool) as a float, anything else unchanged."""
    return float(v) if isinstance(v, int) and not isinstance(v, bool) else v


def _has_bool(v):
    """``v`` is a boolean or a list holding one (at any depth)."""
    if isinstance(v, (bool, np.bool_)):
        return True
    return isinstance(v, (list, tuple)) and any(_has_bool(x) for x in v)


def _operand(v, text):
    """``v`` as an operand of arithmetic or of a function: a boolean (a parameter set to
    true/false) is not a number, so ``2*flag`` is an ExprError rather than 2 or 0."""
    if _has_bool(v):
        raise ExprError(f"a boolean (true/false) is not a number in '{_short(text)}'; "
                        f"write 1 or 0 if a number is meant")
    return v


def _binop(node, names, text):
    """``a op b`` for ``+ - * / // % **``; with a list on either side, element-wise and a
    list again: a number with a list applies to every element, two lists must have the same
    shape (:func:`_same_shape`). An infinite result of finite operands is refused
    (:func:`_finite_result`)."""
    op = _BINOPS.get(type(node.op))
    if op is None:
        raise _not_allowed(node, text)
    a = _int_as_float(_operand(_eval(node.left, names, text), text))
    b = _int_as_float(_operand(_eval(node.right, names, text), text))
    if isinstance(a, list) or isinstance(b, list):
        a, b = np.asarray(a, float), np.asarray(b, float)
        _same_shape(node, a.shape if a.ndim else None, b.shape if b.ndim else None, text)
        value = op(a, b).tolist()
    else:
        value = op(a, b)
    return _finite_result(node, [a, b], value, text)


def _shape_text(shape):
    """``3 elements`` for a flat list (``1 element``), ``2 x 3`` for a matrix."""
    if len(shape) == 1:
        return f"{shape[0]} element{'' if shape[0] == 1 else 's'}"
    return " x ".join(map(str, shape))


def _same_shape(node, sa, sb, text):
    """Two lists in one element-wise operation must have the same shape (``sa``, ``sb``;
    None for a number, which applies to every element): numpy broadcasting read
    ``[1, 2] + [3]`` as ``[4, 5]`` and ``[1, 2] + [[1], [2]]`` as a 2 x 2 matrix (and four
    short nested lists as 9.2e7 elements). An ExprError naming both shapes otherwise."""
    if sa is None or sb is None or sa == sb:
        return
    raise ExprError(f"'{_short(ast.unparse(node))}' combines lists of different shapes "
                    f"({_shape_text(sa)} and {_shape_text(sb)}) in '{_short(text)}': two "
                    f"lists are combined element by element and must have the same shape "
                    f"(a number with a list applies to every element)")


def _nonfinite(v):
    """``"NaN"`` or ``"inf"`` when the number or list ``v`` holds one (NaN first), else
    None (also for what is no number: a boolean, a text, a ragged list, refused
    elsewhere). Numbers and lists are looked at without numpy (this runs at every node)."""
    if isinstance(v, float):
        return None if math.isfinite(v) else ("NaN" if math.isnan(v) else "inf")
    if isinstance(v, list):
        kinds = {_nonfinite(x) for x in v}
        return "NaN" if "NaN" in kinds else ("inf" if "inf" in kinds else None)
    if isinstance(v, (bool, np.bool_, str, int)) or v is None:
        return None
    return _nonfinite_array(v)


def _nonfinite_array(v):
    """:func:`_nonfinite` of anything else (a NumPy value given from Python)."""
    try:
        arr = np.asarray(v, dtype=float)
    except (TypeError, ValueError, OverflowError):
        return None
    if np.isnan(arr).any():
        return "NaN"
    return "inf" if np.isinf(arr).any() else None


def _finite_result(node, operands, value, text):
    """``value``, unless the operation ``node`` made it infinite from finite ``operands``
    (an overflow, ``1e200*1e200``, or a list divided by zero): an ExprError. An infinite
    result of an infinite operand is exact and kept (``2*inf``, ``-inf + 1``)."""
    if _nonfinite(value) == "inf" and _overflowed(operands, value):
        raise ExprError(f"'{_short(ast.unparse(node))}' gives an infinite value from finite "
                        f"numbers (an overflow beyond 1.8e308 or a division by zero) in "
                        f"'{_short(text)}'")
    return value


def _overflowed(operands, value):
    """Whether an infinite element of ``value`` comes from finite ``operands`` only: a
    number from no infinite operand at all, a list's element from finite elements at its
    place (a number operand applies to every element). An element-wise ``min``/``max``
    or a binary operator gives a list of the operands' shape."""
    if not isinstance(value, list):
        return all(_nonfinite(v) != "inf" for v in operands)
    out = np.asarray(value, dtype=float)
    made = np.isinf(out)
    for v in operands:
        made &= np.isfinite(np.broadcast_to(np.asarray(v, dtype=float), out.shape))
    return bool(made.any())


def _unaryop(node, names, text):
    """``-v`` or ``+v``; element-wise for a list."""
    op = _UNOPS.get(type(node.op))
    if op is None:
        raise _not_allowed(node, text)
    v = _operand(_eval(node.operand, names, text), text)
    if isinstance(v, list):
        return op(np.asarray(v, float)).tolist()
    return op(v)


def _sequence(node, names, text):
    """``[a, b, ...]`` or ``(a, b, ...)``: a list of the evaluated elements."""
    return [_eval(e, names, text) for e in node.elts]


def _subscript(node, names, text):
    """``name[i]``: element ``i`` (an integer value) of a list parameter."""
    if not isinstance(node.value, ast.Name):
        raise _not_allowed(node, text)
    seq = _eval(node.value, names, text)
    idx = _eval(node.slice, names, text)
    if isinstance(idx, (bool, np.bool_)):
        raise ExprError(f"a boolean (true/false) is not an index in '{_short(text)}'; "
                        f"write 0 or 1 if an index is meant")
    if isinstance(idx, float) and idx.is_integer():
        idx = int(idx)
    if not isinstance(seq, list) or not isinstance(idx, int):
        raise ExprError(f"only list[int] indexing is allowed in '{text}'")
    try:
        return seq[idx]
    except IndexError:
        raise ExprError(f"index {idx} out of range in '{text}'") from None


def _call(node, names, text):
    """``f(a, ...)`` for ``f`` in :data:`FUNCTIONS` (positional arguments only); ``min`` and
    ``max`` are :func:`_extreme`. An infinite result of finite arguments is refused
    (:func:`_finite_result`)."""
    if not isinstance(node.func, ast.Name) or node.keywords:
        raise _not_allowed(node, text)
    name = node.func.id
    if name not in FUNCTIONS:
        raise ExprError(f"unknown function '{name}' in '{text}' "
                        f"(allowed: {', '.join(sorted(FUNCTIONS))})")
    args = [_eval(a, names, text) for a in node.args]
    if name == "len":
        return len(*args)
    args = [_operand(a, text) for a in args]
    if name in ("min", "max"):
        return _finite_result(node, args, _extreme(name, args), text)
    return _finite_result(node, args, FUNCTIONS[name](*args), text)


def _extreme(name, args):
    """``min`` or ``max`` (``name``) of evaluated ``args``: of one flat list of numbers its
    extreme element; of several numbers the extreme one; of several arguments holding a
    list the element-wise extreme (:func:`_element_wise_extreme`). Python's own compared
    lists as sequences (``max([1, 5], [2, 0])`` was ``[2, 0]``, ``min([[1, 2], [3, 4]])``
    the row ``[1, 2]``); a ValueError says what is wrong."""
    if not args:
        raise ValueError(f"{name}() needs at least one argument")
    if len(args) == 1:
        arr = np.asarray(args[0], dtype=float)
        if arr.ndim != 1 or arr.size == 0:
            raise ValueError(f"{name}() of one argument takes a non-empty flat list of "
                             f"numbers (its {'smallest' if name == 'min' else 'largest'} "
                             f"element); for the element-wise {name} of rows give them as "
                             f"separate arguments: {name}([1, 2], [3, 4])")
        return float(arr.min() if name == "min" else arr.max())
    if not any(isinstance(a, list) for a in args):
        return min(args) if name == "min" else max(args)
    return _element_wise_extreme(name, args)


def _element_wise_extreme(name, args):
    """The element-wise ``min`` or ``max`` of ``args`` holding lists, all of one shape (a
    number applies to every element), as a list; a ValueError naming the shapes
    otherwise."""
    arrs = [np.asarray(a, dtype=float) for a in args]
    shapes = {a.shape for a in arrs if a.ndim}
    if len(shapes) > 1:
        raise ValueError(f"{name}() of lists of different shapes "
                         f"({' and '.join(_shape_text(s) for s in sorted(shapes))}): the "
                         f"element-wise {name} needs lists of one shape (a number applies to "
                         f"every element)")
    fn = np.minimum if name == "min" else np.maximum
    return functools.reduce(fn, arrs).tolist()


#: syntax node type -> its evaluator ``f(node, names, text)``; any other node is refused
_EVALUATORS = {ast.Constant: _constant, ast.Name: _name, ast.BinOp: _binop,
               ast.UnaryOp: _unaryop, ast.List: _sequence, ast.Tuple: _sequence,
               ast.Subscript: _subscript, ast.Call: _call}


def _eval(node, names, text):
    """Value of syntax node ``node`` with parameters ``names`` (``text``: the whole
    expression, for messages); only the node types of :data:`_EVALUATORS` are accepted."""
    evaluator = _EVALUATORS.get(type(node))
    if evaluator is None:
        raise _not_allowed(node, text)
    value = evaluator(node, names, text)
    if isinstance(value, complex):
        raise _complex(node, value, text)
    if _nonfinite(value) == "NaN":
        what = "is" if isinstance(node, ast.Name) else "gives"
        raise ExprError(f"'{_short(ast.unparse(node))}' {what} NaN (not a number) in "
                        f"'{_short(text)}': parameters are numbers (min and max would drop a "
                        f"NaN silently)")
    return value


def _complex(node, value, text):
    """The error for a complex value (a negative number to a fractional power, ``(-8) **
    (1/3)``): parameters are real, and a later ``abs`` would silently make it one."""
    why = (" (a negative number to a fractional power has no real value)"
           if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Pow) else "")
    return ExprError(f"'{_short(ast.unparse(node))}' gives the complex number {value:.6g}"
                     f"{why} in '{_short(text)}': parameters are real numbers")
