"""Static nonlinearities: saturation and dead zone (continuous-time versions)."""
from .base import Block, Param, Port


class Saturation(Block):
    """``y = min(max(u, lower), upper)`` element-wise."""

    category = "nonlinear"
    parameters = {"lower": Param(-1.0, doc="lower limit"), "upper": Param(1.0, doc="upper limit")}
    inputs = {"u": Port(size=None, doc="input")}
    outputs = {"y": Port(size="@u", feedthrough=("u",), doc="limited input")}

    @classmethod
    def check(cls, params):
        if params["lower"] > params["upper"]:
            raise ValueError(f"lower ({params['lower']}) must not exceed upper "
                             f"({params['upper']})")

    @staticmethod
    def output(t, lower, upper, u, y):
        for i in range(y.size):
            v = u[i]
            y[i] = lower if v < lower else (upper if v > upper else v)


class DeadZone(Block):
    """Dead zone: ``y = 0`` for ``start <= u <= end``, ``u - end`` above, ``u - start`` below."""

    category = "nonlinear"
    parameters = {"start": Param(-0.5, doc="lower edge of the zone"),
                  "end": Param(0.5, doc="upper edge of the zone")}
    inputs = {"u": Port(size=None, doc="input")}
    outputs = {"y": Port(size="@u", feedthrough=("u",), doc="output")}

    @classmethod
    def check(cls, params):
        if params["start"] > params["end"]:
            raise ValueError(f"start ({params['start']}) must not exceed end ({params['end']})")

    @staticmethod
    def output(t, start, end, u, y):
        for i in range(y.size):
            v = u[i]
            y[i] = v - end if v > end else (v - start if v < start else 0.0)
