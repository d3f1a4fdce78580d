"""Continuous PI and PID controllers with output limits and anti-windup.

Parallel form, error ``e`` in, command ``y`` out::

    v = kp e + I + D,   y = min(max(v, y_min), y_max)
    dI/dt = ki e                              (antiwindup = "none")
    dI/dt = ki e + kb (y - v)                 (antiwindup = "backcalc", kb in 1/s)
    dI/dt = 0 while v is beyond a limit and e drives it further, ki e otherwise
                                              (antiwindup = "clamping", the default)
    D = kd N (e - f),  df/dt = N (e - f)      (PID only: derivative filtered at N rad/s)

``I`` is the integral term in units of the output, so the initial value ``I0`` is the
initial command of a controller at zero error.
"""
import math

from .base import Block, Param, Port, State

_AW = ("clamping", "backcalc", "none")


def _i_rate(e, v, ki, y_min, y_max, aw, kb):
    """dI/dt for the anti-windup scheme ``aw`` (0 clamping, 1 back-calculation, 2 none)."""
    if aw == 0.0:
        if (v > y_max and e > 0.0) or (v < y_min and e < 0.0):
            return 0.0
        return ki * e
    if aw == 1.0:
        y = min(max(v, y_min), y_max)
        return ki * e + kb * (y - v)
    return ki * e


def _aw_params(params):
    if params["antiwindup"] == "backcalc" and params["kb"] <= 0:
        raise ValueError("antiwindup 'backcalc' needs a tracking gain kb > 0 [1/s] "
                         "(ki/kp is a common choice)")
    if params["y_min"] >= params["y_max"]:
        raise ValueError(f"y_min ({params['y_min']}) must be below y_max ({params['y_max']})")


_COMMON = {
    "kp": Param(1.0, doc="proportional gain [output/input]"),
    "ki": Param(0.0, doc="integral gain [output/(input s)]"),
    "y_min": Param(-math.inf, doc="lower output limit"),
    "y_max": Param(math.inf, doc="upper output limit"),
    "antiwindup": Param("clamping", kind="str", choices=_AW,
                        doc="anti-windup scheme while the output is limited"),
    "kb": Param(0.0, "1/s", "back-calculation tracking gain", ge=0.0),
    "I0": Param(0.0, doc="initial integral term (output units)"),
}


class PI(Block):
    """PI controller ``kp e + ki int(e)`` with limits and anti-windup (see module doc)."""

    category = "control"
    parameters = dict(_COMMON)
    inputs = {"e": Port(doc="control error")}
    outputs = {"y": Port(feedthrough=("e",), doc="limited command")}
    states = {"I": State(initial="I0", doc="integral term (output units)")}

    @classmethod
    def check(cls, params):
        _aw_params(params)

    @classmethod
    def derive(cls, params):
        return {"aw": float(_AW.index(params["antiwindup"]))}

    @staticmethod
    def output(t, I, e, kp, y_min, y_max, y):
        v = kp * e[0] + I[0]
        y[0] = min(max(v, y_min), y_max)

    @staticmethod
    def derivative(t, I, e, kp, ki, y_min, y_max, aw, kb, der_I):
        v = kp * e[0] + I[0]
        der_I[0] = _i_rate_jit(e[0], v, ki, y_min, y_max, aw, kb)


class PID(Block):
    """PID controller with a first-order derivative filter (see module doc)."""

    category = "control"
    parameters = dict(_COMMON, kd=Param(0.0, doc="derivative gain [output s/input]"),
                      N=Param(100.0, "rad/s", "derivative filter bandwidth", gt=0.0))
    inputs = {"e": Port(doc="control error")}
    outputs = {"y": Port(feedthrough=("e",), doc="limited command")}
    states = {"I": State(initial="I0", doc="integral term (output units)"),
              "f": State(doc="filtered error for the derivative term")}

    @classmethod
    def check(cls, params):
        _aw_params(params)

    @classmethod
    def derive(cls, params):
        return {"aw": float(_AW.index(params["antiwindup"]))}

    @staticmethod
    def output(t, I, f, e, kp, kd, N, y_min, y_max, y):
        v = kp * e[0] + I[0] + kd * N * (e[0] - f[0])
        y[0] = min(max(v, y_min), y_max)

    @staticmethod
    def derivative(t, I, f, e, kp, ki, kd, N, y_min, y_max, aw, kb, der_I, der_f):
        v = kp * e[0] + I[0] + kd * N * (e[0] - f[0])
        der_I[0] = _i_rate_jit(e[0], v, ki, y_min, y_max, aw, kb)
        der_f[0] = N * (e[0] - f[0])


def _jit_helper(fn):
    """Compile a helper the kernels call when numba is used; the plain function otherwise.

    Kernels run in plain Python in interpreted mode, where calling the numba dispatcher
    still works (it is compiled on first call).
    """
    import numba
    return numba.njit(cache=True, inline="always", error_model="numpy")(fn)


_i_rate_jit = _jit_helper(_i_rate)
