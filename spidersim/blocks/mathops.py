"""Element-wise math: gain, sum with signs, product and quotient, functions, and the
algebraic constraint."""
import math

import numpy as np

from .base import Block, Dim, Param, Port


class Gain(Block):
    """``y = k * u`` element-wise; ``k`` a scalar or one value per element."""

    category = "math"
    parameters = {"k": Param(1.0, "*", "gain (scalar or one per element); its unit is "
                                   "unit(y)/unit(u), inferred or given as {value:, unit:}",
                                   shape="*")}
    inputs = {"u": Port("*", size=None, doc="input")}
    outputs = {"y": Port("@k*@u", size="@u", feedthrough=("u",), doc="k * u")}

    @classmethod
    def check_sizes(cls, params, sizes):
        n = len(params["k"])
        if n not in (1, sizes["u"]):
            raise ValueError(f"parameter 'k' has {n} elements but input 'u' has size "
                             f"{sizes['u']} (use one gain or one per element)")

    @staticmethod
    def output(t, k, u, y):
        nk = k.size
        for i in range(y.size):
            y[i] = k[i if nk > 1 else 0] * u[i]

    @staticmethod
    def partials(t, k, dydu):
        """``dy_i/du_i = k_i``."""
        nk = k.size
        for i in range(dydu.shape[0]):
            dydu[i, i] = k[i if nk > 1 else 0]


#: the only operator tokens a specialised kernel may contain
_OP = {"+": "+", "-": "-", "*": "*", "/": "/"}


def _arity_names(params, key):
    return [f"u{i + 1}" for i in range(len(params[key]))]


class _Nary(Block, abstract=True):
    """Shared machinery of blocks with one input per character of a string parameter."""

    key = ""
    symbols = ""

    @classmethod
    def check(cls, params):
        s = params[cls.key]
        bad = [c for c in s if c not in cls.symbols]
        if not s or bad:
            raise ValueError(f"parameter '{cls.key}' must be a non-empty string of "
                             f"'{cls.symbols}' characters, got '{s}'")

    @classmethod
    def input_names(cls, params):
        return _arity_names(params, cls.key)

    @classmethod
    def input_decl(cls, name):
        return cls.inputs["u1"]

    @classmethod
    def check_sizes(cls, params, sizes):
        names = cls.input_names(params)
        got = {n: sizes[n] for n in names}
        if len(set(got.values())) > 1:
            raise ValueError("all inputs must have the same size, got "
                             + ", ".join(f"{n}: {s}" for n, s in got.items()))

    @classmethod
    def kernel_source(cls, params, kernel):
        if kernel != "output":
            return None
        names = cls.input_names(params)
        return (f"def output(t, {', '.join(names)}, y):\n"
                f"    for i in range(y.size):\n"
                f"        y[i] = {cls.expression(params[cls.key], names)}\n")


class Sum(_Nary):
    """``y = s1 u1 + s2 u2 + ...`` with the signs given as a string such as ``"+-"``.

    The inputs are named ``u1 .. uN``, N = len(signs).
    """

    category = "math"
    key, symbols = "signs", "+-"
    parameters = {"signs": Param("++", kind="str", doc="one sign per input, e.g. '+-+'")}
    inputs = {"u1": Port("@y", size=None, doc="inputs u1 .. uN, one per sign (one unit)")}
    outputs = {"y": Port("*", size="@u1", feedthrough="all", doc="signed sum")}

    @staticmethod
    def expression(signs, names):
        # each character maps to a fixed token (KeyError for anything else): no text
        # from the diagram reaches the generated source
        return " ".join(f"{_OP[s]} {n}[i]" for s, n in zip(signs, names))

    @classmethod
    def derive(cls, params):
        """``sign``: +1.0 or -1.0 per input (for the partials)."""
        return {"sign": np.array([1.0 if c == "+" else -1.0 for c in params["signs"]])}

    @staticmethod
    def output(t, u1, u2, y):
        for i in range(y.size):
            y[i] = u1[i] + u2[i]

    @staticmethod
    def partials(t, sign, dydu):
        """``dy_i / d(u_k)_i = sign_k``: the inputs are the columns ``u1 .. uN`` one after
        the other, each of the output's size."""
        n = dydu.shape[0]
        for k in range(sign.size):
            for i in range(n):
                dydu[i, k * n + i] = sign[k]


def _product_unit(ops):
    """Unit rule of a Product: ``"**/"`` -> ``"@u1*@u2/@u3"`` (``"/*"`` -> ``"1/@u1*@u2"``)."""
    rule = "".join(("/" if op == "/" else "*") + f"@u{k + 1}" for k, op in enumerate(ops))
    return rule[1:] if rule[0] == "*" else "1" + rule


class Product(_Nary):
    """``y = u1 * u2 / u3 ...`` element-wise, operators given as a string such as ``"**/"``.

    The first character applies to ``u1`` (``/`` gives its reciprocal).
    """

    category = "math"
    key, symbols = "ops", "*/"
    parameters = {"ops": Param("**", kind="str", doc="one operator per input, e.g. '**/'")}
    inputs = {"u1": Port("*", size=None, doc="inputs u1 .. uN, one per operator")}
    outputs = {"y": Port(lambda p: _product_unit(p["ops"]), size="@u1", feedthrough="all",
                         doc="product; its unit is the product (quotient) of the input units")}

    @staticmethod
    def expression(ops, names):
        return "1.0" + "".join(f" {_OP[o]} {n}[i]" for o, n in zip(ops, names))

    @staticmethod
    def output(t, u1, u2, y):
        for i in range(y.size):
            y[i] = u1[i] * u2[i]

    @staticmethod
    def partials(t, u1, u2, dydu):
        """Two inputs, ``"**"`` (the specialised kernel of :meth:`kernel_source` replaces it
        for any other ``ops``): ``dy_i/d(u1)_i = (u2)_i``, ``dy_i/d(u2)_i = (u1)_i``."""
        n = dydu.shape[0]
        for i in range(n):
            dydu[i, i] = u2[i]
            dydu[i, n + i] = u1[i]

    @classmethod
    def kernel_source(cls, params, kernel):
        """``output`` as the other N-ary blocks; ``partials`` specialised to ``ops``: for
        ``y = u1^s1 u2^s2 ...`` (``s_k = +1`` for ``*``, ``-1`` for ``/``), element-wise,

        ``dy/du_k = P_k`` for ``*`` and ``dy/du_k = -P_k / u_k^2`` for ``/``, ``P_k`` the
        product (quotient) of the other inputs with their operators (no division by
        ``u_k`` itself: exact at ``u_k = 0`` for ``*``). The inputs are the columns
        ``u1 .. uN`` one after the other, each of the output's size."""
        if kernel != "partials":
            return super().kernel_source(params, kernel)
        ops, names = params[cls.key], cls.input_names(params)
        lines = [f"def partials(t, {', '.join(names)}, dydu):",
                 "    n = dydu.shape[0]",
                 "    for i in range(n):"]
        for k, (op, name) in enumerate(zip(ops, names)):
            others = cls.expression(ops[:k] + ops[k + 1:], names[:k] + names[k + 1:])
            d = others if op == "*" else f"-({others}) / ({name}[i] * {name}[i])"
            lines.append(f"        dydu[i, {k} * n + i] = {d}")
        return "\n".join(lines) + "\n"


class AlgebraicConstraint(Block):
    """Output ``z`` such that the input ``f`` is zero: ``f(z) = 0`` (Simulink's Algebraic
    Constraint). Wire ``z`` into the blocks that compute ``f``: the engine closes the
    implicit equation as an algebraic loop whose unknown is ``z`` and whose residual is
    ``f``, solved by Newton from the guess ``z0`` (then from the last solution).
    """

    category = "math"
    parameters = {"z0": Param(0.0, "@z", "initial guess (scalar or one per element)",
                                    shape="*")}
    inputs = {"f": Port("*", size=Dim("len(z0)", lambda p: len(p["z0"])),
                        doc="residual to drive to zero")}
    outputs = {"z": Port("*", size=Dim("len(z0)", lambda p: len(p["z0"])),
                         doc="solution of f(z) = 0")}
    #: output -> (residual input, initial-guess parameter)
    implicit = {"z": ("f", "z0")}


_FUNC_UNITS = {"abs": "@u", "square": "@u*@u"}
_FUNCS = ("sin", "cos", "tan", "tanh", "atan", "exp", "log", "sqrt", "abs", "square")


class Function(Block):
    """``y = fn(u)`` element-wise, ``fn`` one of sin, cos, tan, tanh, atan, exp, log, sqrt,
    abs, square. ``log`` and ``sqrt`` of values outside their domain give NaN, which the
    solver reports with the block's name."""

    category = "math"
    parameters = {"fn": Param("tanh", kind="str", choices=_FUNCS, doc="the function")}
    inputs = {"u": Port("*", size=None, doc="argument")}
    outputs = {"y": Port(lambda p: _FUNC_UNITS.get(p["fn"], "*"), size="@u",
                         feedthrough=("u",), doc="fn(u); unit: that of u for abs, its square "
                         "for square, else inherited")}

    @classmethod
    def derive(cls, params):
        return {"code": float(_FUNCS.index(params["fn"]))}

    @staticmethod
    def output(t, code, u, y):
        c = int(code)
        for i in range(y.size):
            v = u[i]
            if c == 0:
                y[i] = math.sin(v)
            elif c == 1:
                y[i] = math.cos(v)
            elif c == 2:
                y[i] = math.tan(v)
            elif c == 3:
                y[i] = math.tanh(v)
            elif c == 4:
                y[i] = math.atan(v)
            elif c == 5:
                y[i] = math.exp(v)
            elif c == 6:
                y[i] = math.log(v) if v > 0.0 else (-math.inf if v == 0.0 else math.nan)
            elif c == 7:
                y[i] = math.sqrt(v) if v >= 0.0 else math.nan
            elif c == 8:
                y[i] = abs(v)
            else:
                y[i] = v * v

    @staticmethod
    def partials(t, code, u, dydu):
        """``dy_i/du_i = fn'(u_i)``: cos, -sin, 1/cos^2, 1 - tanh^2, 1/(1 + u^2), exp, 1/u,
        1/(2 sqrt u), sgn u (0 at 0), 2u; NaN outside the domain of ``log`` and ``sqrt``
        (as the value)."""
        c = int(code)
        for i in range(dydu.shape[0]):
            v = u[i]
            if c == 0:
                g = math.cos(v)
            elif c == 1:
                g = -math.sin(v)
            elif c == 2:
                cv = math.cos(v)
                g = 1.0 / (cv * cv)
            elif c == 3:
                th = math.tanh(v)
                g = 1.0 - th * th
            elif c == 4:
                g = 1.0 / (1.0 + v * v)
            elif c == 5:
                g = math.exp(v)
            elif c == 6:
                g = 1.0 / v if v > 0.0 else math.nan
            elif c == 7:
                g = 0.5 / math.sqrt(v) if v > 0.0 else math.nan
            elif c == 8:
                g = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)
            else:
                g = 2.0 * v
            dydu[i, i] = g
