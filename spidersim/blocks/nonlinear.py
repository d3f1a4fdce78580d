"""Discontinuous static nonlinearities: saturation, dead zone, relay with hysteresis, switch.

With ``zero_crossing: true`` (the default, as in Simulink) a block switches *mode* at its
corners through zero-crossing events: between events its output is a smooth function of
its input, so the integrator never steps across a corner, and the event is located to a
tight time tolerance. With ``zero_crossing: false`` the output is computed directly (a
corner inside a step is then left to the step-size control).

Every mode block also has an ``initialize`` kernel: at the start and after every event
(a step input may jump past a corner) it sets the mode from the current input.
"""
import numpy as np

from .base import Block, Event, Mode, Param, Port

_ZC = Param(True, kind="bool", doc="switch modes at the corners by zero-crossing events")
#: the smallest positive float: a guard on its threshold that is still on its positive side
_TINY = 5e-324


def _corner_modes(lo, hi, u, m):
    """Modes from the input: +1 above ``hi``, -1 below ``lo``, 0 between. Exactly on a
    corner either adjacent mode is right: the current one is kept if it is adjacent (an
    event may have just set it). (An input an algebraic loop puts a hair past the corner
    after an event is the event loop's to handle: see ``SciPyLoop._keep_event_modes``.)"""
    for i in range(u.size):
        if u[i] > hi or (u[i] == hi and m[i] > 0.5 and hi > lo):
            m[i] = 1.0
        elif u[i] < lo or (u[i] == lo and m[i] < -0.5 and hi > lo):
            m[i] = -1.0
        else:
            m[i] = 0.0


def _corner_guards(lo, hi, u, zc):
    """One guard per element and corner: ``u - hi`` then ``u - lo``."""
    n = u.size
    for i in range(n):
        zc[i] = u[i] - hi
        zc[n + i] = u[i] - lo


def _jit(fn):
    import numba
    return numba.njit(cache=True, inline="always", error_model="numpy")(fn)


corner_modes = _jit(_corner_modes)
corner_guards = _jit(_corner_guards)


class _Corners(Block, abstract=True):
    """Shared event handling of the blocks with two corners per element (guards exist only
    with ``zero_crossing``): at a crossing ``u`` sits on the corner, so the direction of
    the crossing decides the new mode."""

    @staticmethod
    def on_event(t, which, direction, u, m):
        n = u.size
        if which < n:
            m[which] = 1.0 if direction > 0 else 0.0
        else:
            m[which - n] = -1.0 if direction < 0 else 0.0


class Saturation(_Corners):
    """``y = min(max(u, lower), upper)`` element-wise; mode per element -1 / 0 / +1
    (at lower / linear / at upper)."""

    category = "nonlinear"
    parameters = {"lower": Param(-1.0, "@u", "lower limit", allow_inf=True),
                  "upper": Param(1.0, "@u", "upper limit", allow_inf=True),
                  "zero_crossing": _ZC}
    inputs = {"u": Port("*", size=None, doc="input")}
    outputs = {"y": Port("@u", size="@u", feedthrough=("u",), doc="limited input")}
    modes = {"m": Mode(size="@u", doc="-1 at lower, 0 linear, +1 at upper")}
    events = {"upper": Event(0, "u crosses the upper limit (one guard per element)", "@u",
                             when="zero_crossing"),
              "lower": Event(0, "u crosses the lower limit (one guard per element)", "@u",
                             when="zero_crossing")}

    @classmethod
    def check(cls, params):
        # equal limits: both corner guards fire at one instant and the mode ended linear
        # (y = u past the limit under LSODA); the output would be a constant anyway
        if np.any(np.asarray(params["lower"]) >= np.asarray(params["upper"])):
            raise ValueError(f"lower ({params['lower']}) must be below upper "
                             f"({params['upper']}); equal limits hold the output at one "
                             f"value: use a Constant")

    @staticmethod
    def output(t, lower, upper, zero_crossing, u, m, y):
        for i in range(y.size):
            if zero_crossing:
                y[i] = upper if m[i] > 0.5 else (lower if m[i] < -0.5 else u[i])
            else:
                v = u[i]
                y[i] = lower if v < lower else (upper if v > upper else v)

    @staticmethod
    def initialize(t, lower, upper, u, m):
        corner_modes(lower, upper, u, m)

    @staticmethod
    def guard(t, lower, upper, u, zc):
        corner_guards(lower, upper, u, zc)

    @staticmethod
    def partials(t, lower, upper, zero_crossing, u, m, dydu):
        """``dy_i/du_i`` = 1 in the linear mode (or, without zero crossing, strictly
        between the limits), 0 at a limit."""
        for i in range(dydu.shape[0]):
            if zero_crossing:
                dydu[i, i] = 1.0 if -0.5 <= m[i] <= 0.5 else 0.0
            else:
                dydu[i, i] = 1.0 if lower < u[i] < upper else 0.0


class DeadZone(_Corners):
    """Dead zone: ``y = 0`` for ``start <= u <= end``, ``u - end`` above, ``u - start`` below.
    Mode per element -1 / 0 / +1 (below / inside / above)."""

    category = "nonlinear"
    parameters = {"start": Param(-0.5, "@u", "lower edge of the zone"),
                  "end": Param(0.5, "@u", "upper edge of the zone"), "zero_crossing": _ZC}
    inputs = {"u": Port("*", size=None, doc="input")}
    outputs = {"y": Port("@u", size="@u", feedthrough=("u",), doc="output")}
    modes = {"m": Mode(size="@u", doc="-1 below, 0 inside, +1 above the zone")}
    events = {"end": Event(0, "u crosses the upper edge (one guard per element)", "@u",
                           when="zero_crossing"),
              "start": Event(0, "u crosses the lower edge (one guard per element)", "@u",
                             when="zero_crossing")}

    @classmethod
    def check(cls, params):
        # a zone of width 0 is no dead zone (y = u); both edge guards at one point gave
        # y = 0 for every u
        if np.any(np.asarray(params["start"]) >= np.asarray(params["end"])):
            raise ValueError(f"start ({params['start']}) must be below end ({params['end']}); "
                             f"a zone of width 0 is no dead zone (y = u)")

    @staticmethod
    def output(t, start, end, zero_crossing, u, m, y):
        for i in range(y.size):
            v = u[i]
            if zero_crossing:
                y[i] = v - end if m[i] > 0.5 else (v - start if m[i] < -0.5 else 0.0)
            else:
                y[i] = v - end if v > end else (v - start if v < start else 0.0)

    @staticmethod
    def initialize(t, start, end, u, m):
        corner_modes(start, end, u, m)

    @staticmethod
    def partials(t, start, end, zero_crossing, u, m, dydu):
        """``dy_i/du_i`` = 1 outside the zone (by the mode; without zero crossing, strictly
        outside ``[start, end]``), 0 inside."""
        for i in range(dydu.shape[0]):
            if zero_crossing:
                dydu[i, i] = 0.0 if -0.5 <= m[i] <= 0.5 else 1.0
            else:
                dydu[i, i] = 1.0 if (u[i] > end or u[i] < start) else 0.0

    @staticmethod
    def guard(t, start, end, u, zc):
        corner_guards(start, end, u, zc)


class Relay(Block):
    """Relay with hysteresis: switches on when ``u`` rises through ``on_point``, off when it
    falls through ``off_point`` (``off_point <= on_point``); ``y`` is ``on_value`` or
    ``off_value``."""

    category = "nonlinear"
    parameters = {"on_point": Param(0.5, "@u", "switch-on threshold"),
                  "off_point": Param(-0.5, "@u", "switch-off threshold"),
                  "on_value": Param(1.0, "@y", "output when on"),
                  "off_value": Param(0.0, "@y", "output when off"),
                  "initially_on": Param(False, kind="bool", doc="state at the start between "
                                                                 "the thresholds")}
    inputs = {"u": Port("*", doc="input")}
    outputs = {"y": Port("*", doc="relay output")}
    modes = {"on": Mode(initial=lambda p: 1.0 if p["initially_on"] else 0.0,
                        doc="1 when on")}
    events = {"switch": Event(0, "u crosses the active threshold")}

    @classmethod
    def check(cls, params):
        if params["off_point"] > params["on_point"]:
            raise ValueError(f"off_point ({params['off_point']}) must not exceed on_point "
                             f"({params['on_point']})")

    @staticmethod
    def output(t, on_value, off_value, on, y):
        y[0] = on_value if on[0] > 0.5 else off_value

    @staticmethod
    def initialize(t, on_point, off_point, u, on):
        if u[0] > on_point:
            on[0] = 1.0
        elif u[0] < off_point:
            on[0] = 0.0

    @staticmethod
    def guard(t, on_point, off_point, u, on, zc):
        zc[0] = u[0] - (off_point if on[0] > 0.5 else on_point)

    @staticmethod
    def on_event(t, which, direction, on):
        if on[0] < 0.5 and direction > 0:
            on[0] = 1.0
        elif on[0] > 0.5 and direction < 0:
            on[0] = 0.0


class Switch(Block):
    """``y = u1`` while ``u2 >= threshold``, else ``u3`` (Simulink's Switch); the control
    input's crossings are events."""

    category = "nonlinear"
    parameters = {"threshold": Param(0.0, "@u2", "threshold on the control input u2")}
    inputs = {"u1": Port("@y", size=None, doc="passed while u2 >= threshold"),
              "u2": Port("*", doc="control input"),
              "u3": Port("@y", size=None, doc="passed while u2 < threshold")}
    outputs = {"y": Port("*", size="@u1", feedthrough=("u1", "u2", "u3"), doc="selected input")}
    modes = {"first": Mode(doc="1 while u1 is passed")}
    events = {"switch": Event(0, "u2 crosses the threshold")}

    @classmethod
    def check_sizes(cls, params, sizes):
        if sizes["u1"] != sizes["u3"]:
            raise ValueError(f"u1 and u3 must have the same size, got {sizes['u1']} and "
                             f"{sizes['u3']}")

    @staticmethod
    def output(t, u1, u3, first, y):
        for i in range(y.size):
            y[i] = u1[i] if first[0] > 0.5 else u3[i]

    @staticmethod
    def partials(t, first, dydu):
        """``dy_i/d(u1)_i = 1`` while ``u1`` is passed, ``dy_i/d(u3)_i = 1`` otherwise; the
        control input acts through events only (``dy/du2 = 0`` between them). Columns:
        ``u1`` (n), ``u2`` (1), ``u3`` (n)."""
        n = dydu.shape[0]
        for i in range(n):
            if first[0] > 0.5:
                dydu[i, i] = 1.0
            else:
                dydu[i, n + 1 + i] = 1.0

    @staticmethod
    def initialize(t, threshold, u2, first):
        first[0] = 1.0 if u2[0] >= threshold else 0.0

    @staticmethod
    def guard(t, threshold, u2, first, zc):
        """``u2 - threshold``; while ``u1`` is passed, ``u2`` exactly on the threshold is
        still on its side (``u2 >= threshold``): the guard is then the smallest positive
        number, so that only ``u2`` strictly below the threshold is a crossing (a crossing
        located exactly on it was undone by ``initialize``, and the switch stayed on ``u1``
        while ``u2`` went on down)."""
        g = u2[0] - threshold
        if g == 0.0 and first[0] > 0.5:
            g = _TINY
        zc[0] = g

    @staticmethod
    def on_event(t, which, direction, first):
        first[0] = 1.0 if direction > 0 else 0.0
