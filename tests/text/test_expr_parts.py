"""The parameter-expression evaluator (spidersim.text.expr), one syntax element at a time.

Each evaluator of :data:`_EVALUATORS` is called on a node parsed from a few characters, and
:func:`evaluate` on whole expressions with values derived by hand. Whole diagrams using
expressions are covered by tests/diagram and the hostile corpus.
"""
import ast
import math

import numpy as np
import pytest

from spidersim.text import expr as X
from spidersim.text.expr import ExprError, evaluate

NAMES = {"a": 2.0, "n": 7, "L": [1.0, 2.0, 3.0], "pi": 3.0}


def node(text):
    """The body node of the expression ``text``."""
    return ast.parse(text, mode="eval").body


def test_constants_are_floats_and_only_numbers():
    """Integer literals become floats (no exact big-integer arithmetic); a literal beyond
    the float range, a string or a boolean is refused."""
    v = X._constant(node("3"), {}, "3")
    assert v == 3.0 and type(v) is float
    for big in ("1" + "0" * 400, "1e400", "1e309", "1.5e308" + "0"):
        with pytest.raises(ExprError, match="beyond the float range .*write inf"):
            X._constant(node(big), {}, big)
    assert X._constant(node("1.7e308"), {}, "1.7e308") == 1.7e308
    for text in ("'x'", "True", "None"):
        with pytest.raises(ExprError, match="only numbers are allowed"):
            X._constant(node(text), {}, text)


def test_parameters_shadow_constants_and_unknown_names_suggest():
    """A diagram parameter named like a constant wins; an unknown name gets the nearest
    parameters and constants."""
    assert X._name(node("pi"), NAMES, "pi") == 3.0
    assert X._name(node("e"), NAMES, "e") == math.e
    with pytest.raises(ExprError, match=r"unknown name 'aa' in 'aa'; did you mean a\?"):
        X._name(node("aa"), NAMES, "aa")


def test_binary_operators_on_numbers_and_lists():
    """Integer parameters take part as floats (7 // 2 = 3.0, a float); a list on either
    side is element-wise: [1, 2, 3] * 2 = [2, 4, 6]; other operators are refused."""
    v = X._binop(node("n // 2"), NAMES, "n // 2")
    assert v == 3.0 and type(v) is float
    assert X._binop(node("L * a"), NAMES, "") == [2.0, 4.0, 6.0]
    assert X._binop(node("1 - L"), NAMES, "") == [0.0, -1.0, -2.0]
    assert X._unaryop(node("-L"), NAMES, "") == [-1.0, -2.0, -3.0]
    for text in ("a ^ 1", "a << 1", "~a"):
        with pytest.raises(ExprError, match="is not allowed in a parameter expression"):
            X._eval(node(text), NAMES, text)


def test_integer_parameters_cannot_make_huge_integers():
    """Integer parameters (YAML ints stay ints in the scope) are turned into floats before
    an operator, so ``n ** n`` with n = 1000 overflows at once (an error) instead of
    computing a 3000-digit integer; a tower of them cannot stall the loader."""
    with pytest.raises(ExprError, match="cannot evaluate 'n \\*\\* n'"):
        evaluate("n ** n", {"n": 1000})
    v = X._binop(node("n // n"), NAMES, "")
    assert v == 1.0 and type(v) is float


def test_list_indexing_by_integer_values_only():
    """``L[1]`` and ``L[1.0]`` pick element 1, negative indices count from the end; a
    fractional index, an index of a number or past the end is refused."""
    assert X._subscript(node("L[1.0]"), NAMES, "") == 2.0
    assert X._subscript(node("L[-1]"), NAMES, "") == 3.0
    with pytest.raises(ExprError, match="only list\\[int\\] indexing"):
        X._subscript(node("L[1.5]"), NAMES, "L[1.5]")
    with pytest.raises(ExprError, match="only list\\[int\\] indexing"):
        X._subscript(node("a[0]"), NAMES, "a[0]")
    with pytest.raises(ExprError, match="index 3 out of range"):
        X._subscript(node("L[3]"), NAMES, "L[3]")


def test_calls_to_listed_functions_with_positional_arguments():
    """Only the functions of FUNCTIONS, called by name with positional arguments; anything
    else (keywords, methods, unknown names) is refused and the allowed ones are listed."""
    assert X._call(node("atan2(1, 1)"), NAMES, "") == pytest.approx(math.pi / 4, rel=1e-15)
    assert X._call(node("max(L)"), NAMES, "") == 3.0
    with pytest.raises(ExprError, match=r"unknown function 'open' .*\(allowed: abs, acos"):
        X._call(node("open(1)"), NAMES, "open(1)")
    for text in ("sin(x=1)", "L.index(1)"):
        with pytest.raises(ExprError, match="is not allowed"):
            X._call(node(text), NAMES, text)


@pytest.mark.parametrize("text", ["a.real", "().__class__", "lambda: 1", "[x for x in L]",
                                  "a if a else 1", "a < 2", "{1: 2}", "f'{a}'"])
def test_everything_else_is_refused(text):
    """Attribute access, lambdas, comprehensions, comparisons, conditionals, dicts and
    f-strings have no evaluator: the message names the element and what is allowed."""
    with pytest.raises(ExprError, match="is not allowed in a parameter expression"):
        evaluate(text, NAMES)


def test_whole_expressions():
    """Values derived by hand: 2*pi*955/60 with pi = 3 (a parameter) is 95.5; a list of
    expressions is a list; division by zero is named."""
    assert evaluate("2*pi*955/60", NAMES) == pytest.approx(95.5, rel=1e-15)
    assert evaluate("2*pi*955/60", {}) == pytest.approx(2 * math.pi * 955 / 60, rel=1e-15)
    assert evaluate("[a, L[0] + 1, -n]", NAMES) == [2.0, 2.0, -7.0]
    with pytest.raises(ExprError, match="division by zero in '1/0'"):
        evaluate("1/0", NAMES)


@pytest.mark.parametrize("text", ["2*flag", "-flag", "flag + 1", "max(flag, 0)", "2*flags",
                                  "sin(flag)"])
def test_booleans_are_not_numbers_in_arithmetic(text):
    """A parameter set to true/false used in arithmetic or a function (``2*flag``) is an
    ExprError, not silently 2 or 0 (Python counts True as 1); ``len`` still counts a list
    of booleans."""
    with pytest.raises(ExprError, match="a boolean \\(true/false\\) is not a number"):
        evaluate(text, {"flag": True, "flags": [1.0, False]})
    assert evaluate("len(flags)", {"flags": [True, False]}) == 2


@pytest.mark.parametrize("text, words", [
    # Python's parser reads these as 2*k + pi (NFKC): they were accepted as that
    ("2*\uff4b + pi", "non-ASCII character '\uff4b' (U+FF4B FULLWIDTH LATIN SMALL LETTER K) "
                      "at character 3 of '2*\uff4b + pi'"),
    ("2*k + \U0001d429\U0001d422", "'\U0001d429' (U+1D429 MATHEMATICAL BOLD SMALL P) at "
                                    "character 7"),
    ("\u212f", "U+212F SCRIPT SMALL E"),
    ("k\u200b", "'\\u200b' (U+200B ZERO WIDTH SPACE) at character 2"),  # shown escaped
    ("2*\u03c0", "U+03C0 GREEK SMALL LETTER PI"),
    ("1\u00a0+ k", "U+00A0 NO-BREAK SPACE"),
])
def test_non_ascii_characters_are_refused_where_they_stand(text, words):
    """Expressions hold no string literals, so any non-ASCII character is refused, naming
    it, its code point and its position: a look-alike letter would otherwise be read as a
    parameter's name (names are ASCII identifiers, see the README's limits)."""
    with pytest.raises(ExprError) as ei:
        evaluate(text, {"k": 3.0})
    assert words in str(ei.value) and "expressions are ASCII" in str(ei.value)


@pytest.mark.parametrize("text", ["v[f]", "v[t]", "v[bs[0]]"])
def test_a_boolean_is_not_an_index(text):
    """``v[f]`` with ``f: true`` picked element 1 (Python counts True as 1)."""
    names = {"v": [10.0, 20.0], "f": True, "t": np.bool_(False), "bs": [True]}
    with pytest.raises(ExprError, match=r"a boolean \(true/false\) is not an index"):
        evaluate(text, names)
    assert evaluate("v[i]", dict(names, i=1)) == 20.0


@pytest.mark.parametrize("text, part", [
    ("(-8)**(1/3)", "'(-8) ** (1 / 3)' gives the complex number 1+1.73205j (a negative "
                    "number to a fractional power has no real value)"),
    ("abs((-8)**(1/3))", "'(-8) ** (1 / 3)' gives"),        # abs() made it 2.0
    ("a**0.5 + 1", "'a ** 0.5' gives"),
    ("[1, (-1)**0.5]", "'(-1) ** 0.5' gives"),
])
def test_complex_values_are_refused_at_the_operation(text, part):
    """Parameters are real: a complex value is refused where it arises (the sub-expression
    is named), before ``abs`` or ``min`` could turn it into a wrong real number."""
    with pytest.raises(ExprError) as ei:
        evaluate(text, {"a": -4.0})
    assert part in str(ei.value) and "parameters are real numbers" in str(ei.value)
    assert evaluate("(8)**(1/3)", {}) == pytest.approx(2.0)


@pytest.mark.parametrize("text", ["[[1, 2], [3]]", "((1,2),(3,))", "[1, [2, 3]]", "[L, 1]"])
def test_a_ragged_list_from_an_expression_is_refused(text):
    """The same error as for a ragged YAML list (it was an internal ValueError from
    numpy's inhomogeneous shape)."""
    with pytest.raises(ExprError, match="must be a number list or a matrix .* ragged"):
        evaluate(text, NAMES)
    assert evaluate("[[1, 2], [3, a]]", NAMES) == [[1.0, 2.0], [3.0, 2.0]]


def _axis_list(n, k, dims=4):
    """A nested list literal with ``n`` zeros along axis ``k`` and 1 along the others."""
    def build(d):
        if d == dims:
            return "0"
        return "[" + ",".join(build(d + 1) for _ in range(n if d == k else 1)) + "]"
    return build(0)


def test_broadcasting_is_refused_before_it_allocates():
    """Four short nested lists broadcast to 98^4 = 9.2e7 elements (a 1,979-character
    expression that took 4.7 GB in the service): two lists of different shapes are refused
    at the first operation, naming the shapes, before numpy computes anything; lists of one
    shape are combined element by element."""
    e = "+".join(_axis_list(98, k) for k in range(4))
    assert len(e) < 2000
    with pytest.raises(ExprError, match=r"lists of different shapes \(98 x 1 x 1 x 1 and "
                                        r"1 x 98 x 1 x 1\)"):
        evaluate(e, {})
    assert np.shape(evaluate("+".join(_axis_list(30, 0) for _ in range(4)), {})) == \
        (30, 1, 1, 1)


@pytest.mark.parametrize("text, shapes", [
    ("[1, 2] + [3]", "2 elements and 1 element"),       # was [4, 5]
    ("[1, 2] + [[1], [2]]", "2 elements and 2 x 1"),    # was a 2 x 2 matrix
    ("[[1, 2], [3, 4]] * [1, 2]", "2 x 2 and 2 elements"),
    ("L - [1, 2]", "3 elements and 2 elements"),
])
def test_lists_of_different_shapes_are_not_broadcast(text, shapes):
    """Two lists are combined element by element only when their shapes are equal (numpy
    broadcast a one-element list over the other, ``[1, 2] + [3]`` = ``[4, 5]``); a number
    with a list still applies to every element (the README's expressions)."""
    with pytest.raises(ExprError, match="combines lists of different shapes") as ei:
        evaluate(text, NAMES)
    assert f"({shapes})" in str(ei.value)
    assert evaluate("[1, 2] * [3, 4]", NAMES) == [3.0, 8.0]
    assert evaluate("[[1, 2], [3, 4]] - a", NAMES) == [[-1.0, 0.0], [1.0, 2.0]]
    assert evaluate("a * [1, 2]", NAMES) == [2.0, 4.0]


@pytest.mark.parametrize("text, want", [
    ("max([1, 5], [2, 0])", [2.0, 5.0]),      # Python compared the lists: [2, 0]
    ("min([1, 5], [2, 0])", [1.0, 0.0]),      # Python: [1, 5]
    ("max([1, 5], 2)", [2.0, 5.0]),           # a number applies to every element
    ("min([[1, 9], [3, 4]], [[2, 0], [5, 1]])", [[1.0, 0.0], [3.0, 1.0]]),
    ("max(L)", 3.0), ("min(L)", 1.0), ("max(2, a, 1)", 2.0),
])
def test_min_and_max_of_lists_are_element_wise(text, want):
    """Several arguments: the element-wise extreme; one flat list: its extreme element."""
    assert evaluate(text, NAMES) == want


@pytest.mark.parametrize("text, words", [
    ("min([[1, 2], [3, 4]])", "non-empty flat list"),   # Python gave the row [1, 2]
    ("max(2)", "non-empty flat list"),
    ("max([])", "non-empty flat list"),
    ("max([1, 2], [3])", "lists of different shapes (1 element and 2 elements)"),
    ("max()", "at least one argument"),
])
def test_min_and_max_refuse_what_has_no_element_wise_meaning(text, words):
    with pytest.raises(ExprError) as ei:
        evaluate(text, NAMES)
    assert words in str(ei.value)


NONFINITE = {"nan": float("nan"), "inf": float("inf"), "L": [1.0, float("inf")],
             "N": [1.0, float("nan")]}


@pytest.mark.parametrize("text, words", [
    ("min(2, nan)", "'nan' is NaN"),          # was 2: Python's min drops a NaN after 2
    ("max(2, nan)", "'nan' is NaN"),
    ("nan", "'nan' is NaN"),
    ("[1, nan]", "'nan' is NaN"),
    ("N", "'N' is NaN"),
    ("[-1, 4] ** 0.5", "'[-1, 4] ** 0.5' gives NaN"),
])
def test_nan_is_refused_wherever_it_appears(text, words):
    """A NaN name, element or result is an ExprError (``min(2, nan)`` was 2, silently);
    ``nan`` here is a parameter named so, as a diagram parameter ``.nan`` would be."""
    with pytest.raises(ExprError) as ei:
        evaluate(text, NONFINITE)
    assert words in str(ei.value) and "NaN (not a number)" in str(ei.value)


@pytest.mark.parametrize("text, want", [
    ("inf", math.inf), ("-inf", -math.inf), ("[0, inf]", [0.0, math.inf]),
    ("L[1]", math.inf), ("-L[1]", -math.inf), ("len(L)", 2),
    ("2*inf", math.inf), ("inf + 1", math.inf), ("1 - inf", -math.inf),
    ("1/inf", 0.0),                         # an infinite time constant is a zero rate
    ("min(inf, 10)", 10.0), ("max(-inf, -5)", -5.0), ("min(L)", 1.0), ("max(L)", math.inf),
    ("L * 2", [2.0, math.inf]), ("min(L, 5)", [1.0, 5.0]), ("max(L, [3, 4])", [3.0, math.inf]),
    ("abs(-inf)", math.inf), ("exp(-inf)", 0.0), ("atan(inf)", math.pi / 2),
    ("2 ** inf", math.inf), ("inf + 1e308", math.inf),
])
def test_an_infinity_with_an_exact_result_is_kept(text, want):
    """Where IEEE arithmetic gives an exact result an infinity takes part (``2*lim`` with
    ``lim: .inf`` is inf, ``min(inf, 10)`` 10, ``1/inf`` 0): ``inf`` and ``L`` are
    parameters set to infinities here; the block parameter the value reaches decides
    whether it may be infinite (see tests/diagram for the block check)."""
    assert evaluate(text, NONFINITE) == want


@pytest.mark.parametrize("text, words", [
    ("inf - inf", "'inf - inf' gives NaN"), ("0 * inf", "'0 * inf' gives NaN"),
    ("inf / inf", "'inf / inf' gives NaN"), ("L - L", "'L - L' gives NaN"),
    ("inf % 2", "'inf % 2' gives NaN"),
])
def test_an_infinity_with_no_meaningful_result_is_refused(text, words):
    """``inf - inf``, ``0*inf``, ``inf/inf`` have no value: refused by the NaN rule."""
    with pytest.raises(ExprError) as ei:
        evaluate(text, NONFINITE)
    assert words in str(ei.value)


@pytest.mark.parametrize("text", ["1e200*1e200", "[1]/[0]", "[1e200] * 1e200", "1e308 + 1e308",
                                  "-[1e308] - 1e308", "L * [1e300, 1] * 1e10",
                                  "L + [1, 1e308] * [1, 10]", "[inf, 1e300] * [1, 1e300]",
                                  "BIG * 10", "max([1, BIG * 10])"])
def test_an_infinite_result_of_finite_operands_is_refused(text):
    """An overflow or a list divided by zero (a number divided by zero is named as such),
    element by element: an infinity elsewhere in the lists excuses no overflow
    (``[inf, 1e300] * [1, 1e300]``)."""
    with pytest.raises(ExprError, match="gives an infinite value from finite numbers"):
        evaluate(text, dict(NONFINITE, BIG=1e308))


@pytest.mark.parametrize("text", ["exp(1000)", "10.0 ** 400"])
def test_a_function_overflow_is_refused(text):
    """Python raises for these overflows; still an ExprError."""
    with pytest.raises(ExprError, match="cannot evaluate"):
        evaluate(text, {})
