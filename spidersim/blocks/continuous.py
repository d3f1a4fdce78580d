"""Linear continuous-time blocks: integrator, state space and transfer function."""
import math

import numpy as np

from ..text import limits
from .base import Block, Dim, Event, Mode, Param, Port, State


class Integrator(Block):
    """``dx/dt = u``, ``y = x`` with initial value ``x0`` (scalar or one per element)."""

    category = "continuous"
    parameters = {"x0": Param(0.0, "@y", "initial value (scalar or one per element)",
                              shape="*")}
    inputs = {"u": Port("*", size=None, doc="rate")}
    outputs = {"y": Port("@u*s", size="@u", doc="integral of u")}
    states = {"y": State("@u*s", size="@u", initial="x0", doc="integral of u")}

    @classmethod
    def fallback_sizes(cls, params):
        return {"u": len(params["x0"])}

    @classmethod
    def check_sizes(cls, params, sizes):
        n = len(params["x0"])
        if n not in (1, sizes["u"]):
            raise ValueError(f"parameter 'x0' has {n} elements but input 'u' has size "
                             f"{sizes['u']}")

    @staticmethod
    def derivative(t, u, der_y):
        for i in range(der_y.size):
            der_y[i] = u[i]

    @staticmethod
    def partials(t, dfdu):
        """``d(dy_i/dt)/du_i = 1``; the output is the state."""
        for i in range(dfdu.shape[0]):
            dfdu[i, i] = 1.0


class LimitedIntegrator(Block):
    """``dy/dt = u`` with ``lower <= y <= upper``: at a limit the state is *held* (mode
    +1 / -1, derivative zero) until ``u`` turns back; reaching a limit and leaving it are
    events. Nothing is clipped: at the reaching event the state is set to the limit it has
    just crossed by at most the event-location tolerance.
    """

    category = "continuous"
    parameters = {"x0": Param(0.0, "@y", "initial value"),
                  "lower": Param(-1.0, "@y", "lower limit"),
                  "upper": Param(1.0, "@y", "upper limit")}
    inputs = {"u": Port("*", doc="rate")}
    outputs = {"y": Port("@u*s", doc="limited integral")}
    states = {"y": State("@u*s", initial="x0", doc="limited integral")}
    modes = {"m": Mode(doc="-1 held at lower, 0 free, +1 held at upper")}
    events = {"upper": Event(1, "y reaches the upper limit"),
              "lower": Event(-1, "y reaches the lower limit"),
              "leave": Event(0, "u turns back while held at a limit")}

    @classmethod
    def check(cls, params):
        if not params["lower"] < params["upper"]:
            raise ValueError(f"lower ({params['lower']}) must be below upper "
                             f"({params['upper']})")
        if not params["lower"] <= params["x0"] <= params["upper"]:
            raise ValueError(f"x0 ({params['x0']}) must lie within [lower, upper] = "
                             f"[{params['lower']}, {params['upper']}]")

    @staticmethod
    def derivative(t, u, m, der_y):
        der_y[0] = u[0] if m[0] == 0.0 else 0.0

    @staticmethod
    def partials(t, m, dfdu):
        """``d(dy/dt)/du = 1`` while free, 0 while held at a limit (mode +-1)."""
        dfdu[0, 0] = 1.0 if m[0] == 0.0 else 0.0

    @staticmethod
    def initialize(t, y, u, lower, upper, m):
        if m[0] == 0.0:
            if y[0] >= upper and u[0] > 0.0:
                m[0] = 1.0
            elif y[0] <= lower and u[0] < 0.0:
                m[0] = -1.0

    @staticmethod
    def guard(t, y, u, lower, upper, m, zc):
        free = m[0] == 0.0
        zc[0] = y[0] - upper if free else -1.0
        zc[1] = y[0] - lower if free else 1.0
        zc[2] = 0.0 if free else u[0] * m[0]

    @staticmethod
    def on_event(t, which, direction, y, u, lower, upper, m):
        if which == 0:
            m[0] = 1.0
            y[0] = upper
        elif which == 1:
            m[0] = -1.0
            y[0] = lower
        elif which == 2:
            m[0] = 0.0


def _ss_derivative(t, x, u, A, B, der_x):
    n = x.size
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += A[i, j] * x[j]
        for k in range(u.size):
            acc += B[i, k] * u[k]
        der_x[i] = acc


def _ss_partials(t, A, B, C, D, dfdx, dfdu, dydx, dydu):
    """The partials of a linear state space are its matrices: ``dfdx = A``, ``dfdu = B``,
    ``dydx = C``, ``dydu = D``."""
    n, m = B.shape
    for i in range(n):
        for j in range(n):
            dfdx[i, j] = A[i, j]
        for k in range(m):
            dfdu[i, k] = B[i, k]
    for r in range(C.shape[0]):
        for j in range(n):
            dydx[r, j] = C[r, j]
        for k in range(m):
            dydu[r, k] = D[r, k]


def _ss_output(t, x, u, C, D, y):
    for i in range(y.size):
        acc = 0.0
        for j in range(x.size):
            acc += C[i, j] * x[j]
        for k in range(u.size):
            acc += D[i, k] * u[k]
        y[i] = acc


class StateSpace(Block):
    """Linear state space ``dx/dt = A x + B u``, ``y = C x + D u``.

    ``D`` is structural: where it is non-zero the output is direct feedthrough of the input,
    so changing it between zero and non-zero changes the schedule (and recompiles).
    """

    category = "continuous"
    parameters = {
        "A": Param(unit="*", doc="state matrix (n x n)", shape=("*", "*")),
        "B": Param(unit="*", doc="input matrix (n x m)", shape=("*", "*")),
        "C": Param(unit="*", doc="output matrix (p x n)", shape=("*", "*")),
        "D": Param(0.0, "*", doc="feedthrough matrix (p x m); 0 for none", shape=("*", "*"),
                   structural=True),
        "x0": Param(0.0, "*", doc="initial state (scalar or n values)", shape="*"),
    }
    inputs = {"u": Port("*", size=Dim("columns of B", lambda p: p["B"].shape[1]), doc="input")}
    outputs = {"y": Port("*", size=Dim("rows of C", lambda p: p["C"].shape[0]),
                         feedthrough=lambda p: ("u",) if np.any(p["D"] != 0) else (),
                         doc="output")}
    states = {"x": State("*", size=Dim("rows of A", lambda p: p["A"].shape[0]), initial="x0",
                         doc="state vector")}

    @classmethod
    def check(cls, params):
        A, B, C, D = (params[k] for k in "ABCD")
        n = A.shape[0]
        if A.shape != (n, n):
            raise ValueError(f"A must be square, got shape {A.shape}")
        if B.shape[0] != n:
            raise ValueError(f"B must have {n} rows (as A), got shape {B.shape}")
        if C.shape[1] != n:
            raise ValueError(f"C must have {n} columns (as A), got shape {C.shape}")
        if D.shape == (1, 1) and D[0, 0] == 0:
            check_matrix_size(C.shape[0], B.shape[1], f"D = 0 with {C.shape[0]} outputs "
                              f"(rows of C) and {B.shape[1]} inputs (columns of B)",
                              "give fewer outputs or inputs")
            params["D"] = np.zeros((C.shape[0], B.shape[1]))
        elif D.shape != (C.shape[0], B.shape[1]):
            raise ValueError(f"D must have shape {(C.shape[0], B.shape[1])}, got {D.shape}")
        if len(params["x0"]) not in (1, n):
            raise ValueError(_x0_count_message(n, len(params["x0"])))

    derivative = staticmethod(_ss_derivative)
    output = staticmethod(_ss_output)
    partials = staticmethod(_ss_partials)


def _x0_count_message(n, got):
    """Why ``got`` start values do not fit ``n`` states (A is ``n x n``)."""
    if n == 1:
        return f"x0 must have 1 element (A is 1 x 1: one state), got {got}"
    return (f"x0 must have 1 element (the same for every state) or {n} (one per state: A is "
            f"{n} x {n}), got {got}")


def check_matrix_size(rows, cols, what, instead):
    """Refuse a ``rows x cols`` matrix a block would build from its parameters beyond
    ``MAX_ARRAY_ELEMENTS`` values (the limit of an array parameter), before it is allocated:
    a transfer function's ``den`` of 6,501 coefficients (a 19.6 KB request) built a 6,500 x
    6,500 state matrix, 4.2 s and 650 MB, and 256 KiB of coefficients would ask for 58 GB.
    ``what`` names the matrix, ``instead`` says what to do; raise ``ValueError``."""
    n = int(rows) * int(cols)
    if n > limits.MAX_ARRAY_ELEMENTS:
        raise ValueError(f"{what} would be a {rows} x {cols} matrix ({n:,} values, "
                         f"{8 * n / 1e6:,.0f} MB), more than the limit of "
                         f"{limits.MAX_ARRAY_ELEMENTS:,} values of an array "
                         f"(MAX_ARRAY_ELEMENTS); {instead}")


def numerator(params):
    """The numerator without its leading zeros (at least one coefficient): ``[0, 1]`` over
    ``[1, 1]`` is strictly proper, with no direct feedthrough (it was taken as biproper: a
    false algebraic loop solved by Newton)."""
    num = np.atleast_1d(np.asarray(params["num"], dtype=float))
    nz = np.flatnonzero(num)
    return num[nz[0]:] if nz.size else num[-1:]


class TransferFunction(Block):
    """SISO transfer function ``Y(s)/U(s) = num(s)/den(s)``, coefficients in descending
    powers of s, realised in controllable canonical form (zero initial state).

    It must be proper (degree of num <= degree of den, leading zeros of ``num`` not
    counted: ``[0, 0, 1]`` is 1); it has direct feedthrough when the degrees are equal.
    """

    category = "continuous"
    parameters = {
        "num": Param(unit="*", doc="numerator coefficients, highest power first", shape="*"),
        "den": Param(unit="*", doc="denominator coefficients, highest power first", shape="*"),
    }
    inputs = {"u": Port("*", doc="input")}
    outputs = {"y": Port("*", doc="output", feedthrough=lambda p: (
        ("u",) if len(numerator(p)) == len(p["den"]) else ()))}
    states = {"x": State("*", size=Dim("len(den) - 1", lambda p: len(p["den"]) - 1),
                         doc="controllable canonical state")}

    @classmethod
    def check(cls, params):
        num, den = numerator(params), params["den"]
        n = len(den) - 1
        check_matrix_size(n, n, f"the state matrix A of this transfer function (den of "
                                f"degree {n}, realised in controllable canonical form)",
                          f"at most degree {math.isqrt(limits.MAX_ARRAY_ELEMENTS)}: split it "
                          f"into a cascade of lower-order TransferFunction blocks")
        if den[0] == 0:
            raise ValueError("the leading coefficient of 'den' must not be 0")
        if len(num) > len(den):
            raise ValueError(f"improper transfer function: num has degree {len(num) - 1}, "
                             f"den has degree {len(den) - 1}")

    @classmethod
    def derive(cls, params):
        """Controllable canonical form: first row of A is ``-a1..-an`` (den/den[0])."""
        den = params["den"] / params["den"][0]
        n = len(den) - 1
        num = np.zeros(n + 1)
        num[n + 1 - len(numerator(params)):] = numerator(params) / params["den"][0]
        A = np.zeros((n, n))
        if n:
            A[0, :] = -den[1:]
            A[1:, :-1] = np.eye(n - 1)
        B = np.zeros((n, 1))
        if n:
            B[0, 0] = 1.0
        C = (num[1:] - den[1:] * num[0]).reshape(1, n)
        D = np.array([[num[0]]])
        return {"A": A, "B": B, "C": C, "D": D}

    derivative = staticmethod(_ss_derivative)
    output = staticmethod(_ss_output)
    partials = staticmethod(_ss_partials)
