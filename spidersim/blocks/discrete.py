"""Sampled (discrete-time) blocks: zero-order hold, unit delay, discrete transfer function,
discrete PI and PID.

Each block samples at ``t_k = offset + k Ts`` through *time events*: the integrator stops
exactly there, the block reads its input (computed at ``t_k``, after any upstream sampled
block has updated at the same instant) and updates its discrete states; its output is held
until the next sample. Outputs come from held values, so no output is direct feedthrough
in continuous time.
"""
import math

import numpy as np

from .base import Block, Dim, Mode, Param, Port
from .continuous import numerator

_TS = Param(doc="sample period", unit="s", gt=0.0)
_OFF = Param(0.0, "s", "time of the first sample", ge=0.0)
_K = Mode(doc="number of samples taken")



class _Sampled(Block, abstract=True):
    """Shared kernels of the sampled blocks: samples at ``offset + k Ts``, output held."""

    sample_period = "Ts"

    @staticmethod
    def next_time(t, offset, Ts, k):
        return offset + k[0] * Ts

    @staticmethod
    def output(t, held, y):
        for i in range(y.size):
            y[i] = held[i]


class ZeroOrderHold(_Sampled):
    """``y(t) = u(t_k)`` for ``t_k <= t < t_k+1``."""

    category = "discrete"
    parameters = {"Ts": _TS, "offset": _OFF}
    inputs = {"u": Port("*", size=None, doc="sampled input")}
    outputs = {"y": Port("@u", size="@u", doc="held sample")}
    modes = {"held": Mode(size="@u", doc="last sample"), "k": _K}

    @staticmethod
    def time_event(t, u, held, k):
        for i in range(u.size):
            held[i] = u[i]
        k[0] += 1.0


class UnitDelay(_Sampled):
    """``y[k] = u[k-1]``, ``y[0] = x0``: the sample taken at ``t_k-1`` is output from ``t_k``."""

    category = "discrete"
    parameters = {"Ts": _TS, "offset": _OFF,
                  "x0": Param(0.0, "@y", "initial output (scalar or per element)",
                              shape="*")}
    inputs = {"u": Port("*", size=None, doc="sampled input")}
    outputs = {"y": Port("@u", size="@u", doc="delayed sample")}
    modes = {"held": Mode(size="@u", initial="x0", doc="output value"),
             "last": Mode(size="@u", initial="x0", doc="sample to output next"), "k": _K}

    @staticmethod
    def time_output(t, held, last):
        for i in range(held.size):
            held[i] = last[i]

    @staticmethod
    def time_event(t, u, last, k):
        for i in range(u.size):
            last[i] = u[i]
        k[0] += 1.0


class DiscreteTransferFunction(_Sampled):
    """``Y(z)/U(z) = num(z)/den(z)`` (coefficients in descending powers of z, as
    ``control.tf(num, den, Ts)``), direct form II transposed, output held between samples."""

    category = "discrete"
    parameters = {"num": Param(unit="*", doc="numerator, highest power of z first", shape="*"),
                  "den": Param(unit="*", doc="denominator, highest power of z first",
                               shape="*"),
                  "Ts": _TS, "offset": _OFF}
    inputs = {"u": Port("*", doc="sampled input")}
    outputs = {"y": Port("*", doc="held output")}
    modes = {"s": Mode(size=Dim("len(den) - 1", lambda p: len(p["den"]) - 1),
                       doc="direct-form-II-transposed states"),
             "held": Mode(doc="last output"), "k": _K}

    @classmethod
    def sample_feedthrough(cls, params):
        """A proper transfer function (``b_0 != 0``: num as long as den) outputs
        ``b_0 u_k + s_0`` from the sample it takes."""
        return float(params["Ts"]) > 0 and len(numerator(params)) == len(params["den"])

    @classmethod
    def check(cls, params):
        if params["den"][0] == 0:
            raise ValueError("the leading coefficient of 'den' must not be 0")
        if len(numerator(params)) > len(params["den"]):     # leading zeros not counted
            raise ValueError("improper (non-causal) transfer function: num is longer than den")

    @classmethod
    def derive(cls, params):
        den = params["den"] / params["den"][0]
        b = np.zeros(len(den))
        num = numerator(params)
        b[len(den) - len(num):] = num / params["den"][0]
        return {"a_n": den, "b_n": b}

    @staticmethod
    def time_output(t, b_n, s, held):
        # strictly proper (b_0 = 0): y_k = s_0 before the sample is taken
        if b_n[0] == 0.0:
            held[0] = s[0] if s.size > 0 else 0.0

    @staticmethod
    def time_event(t, u, a_n, b_n, s, held, k):
        n = s.size
        yk = b_n[0] * u[0] + (s[0] if n > 0 else 0.0)
        for i in range(n):
            nxt = s[i + 1] if i + 1 < n else 0.0
            s[i] = b_n[i + 1] * u[0] - a_n[i + 1] * yk + nxt
        held[0] = yk
        k[0] += 1.0


_LIM = {"y_min": Param(-math.inf, "@y", "lower output limit", allow_inf=True),
        "y_max": Param(math.inf, "@y", "upper output limit", allow_inf=True),
        "I0": Param(0.0, "@y", "initial integral term (output units)")}


def _held_before_first_sample(params):
    """``y0``: what a discrete controller outputs before its first sample (an ``offset``
    > 0): its initial integral term within the limits, the command at zero error, as the
    continuous PI starts (before, 0 whatever ``I0``)."""
    return {"y0": min(max(float(params["I0"]), float(params["y_min"])),
                      float(params["y_max"]))}


class DiscretePI(_Sampled):
    """Sampled PI, forward-Euler integral (``C(z) = kp + ki Ts / (z - 1)``)::

        y_k = sat(kp e_k + I_k),   I_k+1 = I_k + ki Ts e_k
    except while the output is limited and ``e_k`` drives it further (clamping)."""

    category = "discrete"
    parameters = dict({"kp": Param(1.0, "@y/@e", "proportional gain"),
                       "ki": Param(0.0, "@y/@e/s", "integral gain"), "Ts": _TS,
                       "offset": _OFF}, **_LIM)
    inputs = {"e": Port("*", doc="control error")}
    outputs = {"y": Port("*", doc="held command")}
    modes = {"I": Mode(initial="I0", doc="integral term"),
             "held": Mode(initial="y0", doc="last output (before the first sample: I0 "
                                            "within the limits)"), "k": _K}
    derive = classmethod(lambda cls, params: _held_before_first_sample(params))

    @staticmethod
    def time_event(t, e, kp, ki, Ts, y_min, y_max, I, held, k):
        v = kp * e[0] + I[0]
        held[0] = min(max(v, y_min), y_max)
        if not ((v > y_max and e[0] > 0.0) or (v < y_min and e[0] < 0.0)):
            I[0] += ki * Ts * e[0]
        k[0] += 1.0


class DiscretePID(_Sampled):
    """Sampled PID: ``y_k = sat(kp e_k + I_k + kd (e_k - e_k-1) / Ts)``, integral as in
    DiscretePI (clamping).

    The first sample (``k = 0``) has no derivative term: the error before the start is
    taken equal to the first one (``e_-1 = e_0``), so that a controller switched on with an
    error does not kick by ``kd e_0 / Ts``. From zero initial conditions instead
    (``e_-1 = 0``, the z-transform ``C(z) = kp + ki Ts / (z - 1) + kd (z - 1) / (Ts z)``
    applied to a step), the first output would be larger by ``kd e_0 / Ts``; every later
    sample is the same.
    """

    category = "discrete"
    parameters = dict({"kp": Param(1.0, "@y/@e", "proportional gain"),
                       "ki": Param(0.0, "@y/@e/s", "integral gain"),
                       "kd": Param(0.0, "@y*s/@e", "derivative gain"), "Ts": _TS,
                       "offset": _OFF}, **_LIM)
    inputs = {"e": Port("*", doc="control error")}
    outputs = {"y": Port("*", doc="held command")}
    modes = {"I": Mode(initial="I0", doc="integral term"), "e_prev": Mode(doc="last error"),
             "held": Mode(initial="y0", doc="last output (before the first sample: I0 "
                                            "within the limits)"), "k": _K}
    derive = classmethod(lambda cls, params: _held_before_first_sample(params))

    @staticmethod
    def time_event(t, e, kp, ki, kd, Ts, y_min, y_max, I, e_prev, held, k):
        d = kd * (e[0] - e_prev[0]) / Ts if k[0] > 0.5 else 0.0
        v = kp * e[0] + I[0] + d
        held[0] = min(max(v, y_min), y_max)
        if not ((v > y_max and e[0] > 0.0) or (v < y_min and e[0] < 0.0)):
            I[0] += ki * Ts * e[0]
        e_prev[0] = e[0]
        k[0] += 1.0
