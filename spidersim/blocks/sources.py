"""Signal sources: constant, step, ramp, sine, pulse and interpolated time table.

Sources with corners or jumps (step, ramp, pulse, time table) switch through *time events*:
the integrator stops exactly at the switching time and restarts, so that no step straddles a
discontinuity. Their output between events is a smooth function of time selected by a mode.
"""
import math

from .base import Block, Dim, Mode, Param, Port


class Constant(Block):
    """Constant signal ``y = value`` (scalar or vector)."""

    category = "sources"
    parameters = {"value": Param(0.0, "@y", "output value", shape="*")}
    outputs = {"y": Port("*", size=Dim("len(value)", lambda p: len(p["value"])),
                         doc="value; unit from what it feeds, or value: {value:, unit:}")}

    @staticmethod
    def output(t, value, y):
        for i in range(y.size):
            y[i] = value[i]


class Step(Block):
    """Step ``y = before`` for ``t < t_step``, ``y = after`` from ``t_step`` on (time event;
    ``t_step = inf``: never, ``y = before`` throughout)."""

    category = "sources"
    parameters = {
        "t_step": Param(0.0, "s", "switching time (inf: never)", allow_inf=True),
        "before": Param(0.0, "@y", "value before the step"),
        "after": Param(1.0, "@y", "value from the step on"),
    }
    outputs = {"y": Port("*", doc="step signal")}
    modes = {"on": Mode(doc="0 before the step, 1 after")}

    @staticmethod
    def output(t, before, after, on, y):
        y[0] = after if on[0] > 0.5 else before

    @staticmethod
    def next_time(t, t_step, on):
        return t_step if on[0] < 0.5 else math.inf

    @staticmethod
    def time_event(t, on):
        on[0] = 1.0


class Ramp(Block):
    """Ramp ``y = offset + slope (t - t_start)`` for ``t >= t_start``, ``offset`` before."""

    category = "sources"
    parameters = {
        "slope": Param(1.0, "@y/s", "rate of change after t_start"),
        "t_start": Param(0.0, "s", "start time"),
        "offset": Param(0.0, "@y", "value before t_start"),
    }
    outputs = {"y": Port("*", doc="ramp signal")}
    modes = {"on": Mode(doc="0 before t_start, 1 after")}

    @staticmethod
    def output(t, slope, t_start, offset, on, y):
        y[0] = offset + (slope * (t - t_start) if on[0] > 0.5 else 0.0)

    @staticmethod
    def next_time(t, t_start, on):
        return t_start if on[0] < 0.5 else math.inf

    @staticmethod
    def time_event(t, on):
        on[0] = 1.0


class Sine(Block):
    """Sine wave ``y = offset + amplitude sin(2 pi f t + phase)``."""

    category = "sources"
    parameters = {
        "amplitude": Param(1.0, "@y", "peak value"),
        "f": Param(1.0, "Hz", "frequency", ge=0.0),
        "phase": Param(0.0, "rad", "phase at t = 0"),
        "offset": Param(0.0, "@y", "mean value"),
    }
    outputs = {"y": Port("*", doc="sine signal")}

    @staticmethod
    def output(t, amplitude, f, phase, offset, y):
        y[0] = offset + amplitude * math.sin(2.0 * math.pi * f * t + phase)


class Pulse(Block):
    """Periodic rectangular pulse train.

    ``y = low + amplitude`` during the first ``duty * period`` of each period, ``low``
    otherwise, starting at ``delay``. Edges are time events.
    """

    category = "sources"
    parameters = {
        "amplitude": Param(1.0, "@y", "height above low"),
        "period": Param(1.0, "s", "period", gt=0.0),
        "duty": Param(0.5, "1", "fraction of the period spent high", gt=0.0, lt=1.0),
        "delay": Param(0.0, "s", "time of the first rising edge", ge=0.0),
        "low": Param(0.0, "@y", "value between pulses"),
    }
    outputs = {"y": Port("*", doc="pulse signal")}
    modes = {"high": Mode(doc="1 while the pulse is high"),
             "k": Mode(doc="number of completed periods")}

    @staticmethod
    def output(t, amplitude, low, high, y):
        y[0] = low + (amplitude if high[0] > 0.5 else 0.0)

    @staticmethod
    def next_time(t, period, duty, delay, high, k):
        return delay + k[0] * period + (duty * period if high[0] > 0.5 else 0.0)

    @staticmethod
    def time_event(t, high, k):
        if high[0] > 0.5:
            high[0] = 0.0
            k[0] += 1.0
        else:
            high[0] = 1.0


class TimeTable(Block):
    """Piecewise-linear interpolation of a table ``(time, value)``; holds the end values.

    The table's time points are time events, so that each integration step sees one linear
    piece.
    """

    category = "sources"
    parameters = {
        "time": Param(doc="strictly increasing sample times", unit="s", shape="*"),
        "value": Param(unit="@y", doc="values at the sample times", shape="time"),
    }
    outputs = {"y": Port("*", doc="interpolated value")}
    modes = {"k": Mode(doc="number of table times passed")}

    @classmethod
    def check(cls, params):
        import numpy as np
        if np.any(np.diff(params["time"]) <= 0):
            v = np.ravel(params["time"])
            k = int(np.flatnonzero(np.diff(v) <= 0)[0])
            raise ValueError(f"parameter 'time' must be strictly increasing: "
                             f"time[{k + 1}] = {v[k + 1]:g} s is not after "
                             f"time[{k}] = {v[k]:g} s")

    @staticmethod
    def output(t, time, value, k, y):
        n = time.size
        j = int(k[0])
        if j <= 0:
            y[0] = value[0]
        elif j >= n:
            y[0] = value[n - 1]
        else:
            s = (t - time[j - 1]) / (time[j] - time[j - 1])
            y[0] = value[j - 1] + s * (value[j] - value[j - 1])

    @staticmethod
    def next_time(t, time, k):
        j = int(k[0])
        return time[j] if j < time.size else math.inf

    @staticmethod
    def time_event(t, k):
        k[0] += 1.0
