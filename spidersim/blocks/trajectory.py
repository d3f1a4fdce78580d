"""Reference trajectories: trapezoidal-velocity point-to-point, quintic, constant speed.

Each outputs position ``q``, velocity ``qd`` and acceleration ``qdd``; the corners between
phases are time events, so each integration step sees one polynomial piece.
"""
import math

from .base import Block, Mode, Param, Port

_OUT = {"q": Port("*", doc="position (rad or m: the unit of the positions given)"),
        "qd": Port("@q/s", doc="velocity [unit/s]"),
        "qdd": Port("@q/s2", doc="acceleration [unit/s2]")}


class TrapezoidalProfile(Block):
    """Point-to-point move from ``q0`` to ``q1`` starting at ``t_start`` with speed limit
    ``v_max`` and acceleration ``a_max``: accelerate, cruise, decelerate (triangular when
    the distance is too short to reach ``v_max``)."""

    category = "sources"
    parameters = {"q0": Param(0.0, "@q", "start position"),
                  "q1": Param(1.0, "@q", "end position"),
                  "v_max": Param(1.0, "@q/s", "speed limit [unit/s]", gt=0.0),
                  "a_max": Param(1.0, "@q/s2", "acceleration limit [unit/s2]", gt=0.0),
                  "t_start": Param(0.0, "s", "start time")}
    outputs = _OUT
    modes = {"phase": Mode(doc="0 before, 1 accelerating, 2 cruising, 3 decelerating, 4 done")}

    @classmethod
    def derive(cls, p):
        dist = abs(p["q1"] - p["q0"])
        sgn = 1.0 if p["q1"] >= p["q0"] else -1.0
        v, a = p["v_max"], p["a_max"]
        if dist < v * v / a:
            ta = math.sqrt(dist / a)
            v = a * ta
            tc = 0.0
        else:
            ta = v / a
            tc = (dist - v * ta) / v
        return {"sgn": sgn, "v_peak": v, "t_a": ta, "t_c": tc}

    @staticmethod
    def output(t, q0, q1, a_max, t_start, sgn, v_peak, t_a, t_c, phase, q, qd, qdd):
        ph = phase[0]
        a = a_max if t_a > 0.0 else 0.0
        if ph < 0.5:
            q[0], qd[0], qdd[0] = q0, 0.0, 0.0
        elif ph < 1.5:
            s = t - t_start
            q[0], qd[0], qdd[0] = q0 + sgn * 0.5 * a * s * s, sgn * a * s, sgn * a
        elif ph < 2.5:
            s = t - t_start - t_a
            q[0] = q0 + sgn * (0.5 * v_peak * t_a + v_peak * s)
            qd[0], qdd[0] = sgn * v_peak, 0.0
        elif ph < 3.5:
            s = t - t_start - t_a - t_c
            q[0] = q0 + sgn * (0.5 * v_peak * t_a + v_peak * t_c + v_peak * s - 0.5 * a * s * s)
            qd[0], qdd[0] = sgn * (v_peak - a * s), -sgn * a
        else:
            q[0], qd[0], qdd[0] = q1, 0.0, 0.0

    @staticmethod
    def next_time(t, t_start, t_a, t_c, phase):
        ph = phase[0]
        if ph < 0.5:
            return t_start
        if ph < 1.5:
            return t_start + t_a
        if ph < 2.5:
            return t_start + t_a + t_c
        if ph < 3.5:
            return t_start + 2.0 * t_a + t_c
        return math.inf

    @staticmethod
    def time_event(t, t_c, phase):
        phase[0] += 2.0 if (phase[0] > 0.5 and phase[0] < 1.5 and t_c == 0.0) else 1.0


class QuinticProfile(Block):
    """Quintic move from ``q0`` to ``q1`` in ``T`` seconds from ``t_start``, with zero
    velocity and acceleration at both ends: ``q = q0 + (q1 - q0)(10 s^3 - 15 s^4 + 6 s^5)``,
    ``s = (t - t_start) / T``."""

    category = "sources"
    parameters = {"q0": Param(0.0, "@q", "start position"),
                  "q1": Param(1.0, "@q", "end position"),
                  "T": Param(1.0, "s", "duration", gt=0.0), "t_start": Param(0.0, "s", "start")}
    outputs = _OUT
    modes = {"phase": Mode(doc="0 before, 1 moving, 2 done")}

    @staticmethod
    def output(t, q0, q1, T, t_start, phase, q, qd, qdd):
        d = q1 - q0
        if phase[0] < 0.5:
            q[0], qd[0], qdd[0] = q0, 0.0, 0.0
        elif phase[0] < 1.5:
            s = (t - t_start) / T
            q[0] = q0 + d * s * s * s * (10.0 - 15.0 * s + 6.0 * s * s)
            qd[0] = d / T * s * s * (30.0 - 60.0 * s + 30.0 * s * s)
            qdd[0] = d / (T * T) * s * (60.0 - 180.0 * s + 120.0 * s * s)
        else:
            q[0], qd[0], qdd[0] = q1, 0.0, 0.0

    @staticmethod
    def next_time(t, T, t_start, phase):
        if phase[0] < 0.5:
            return t_start
        return t_start + T if phase[0] < 1.5 else math.inf

    @staticmethod
    def time_event(t, phase):
        phase[0] += 1.0


class ConstantSpeed(Block):
    """``q = q0`` before ``t_start``, then ``q0 + speed (t - t_start)``."""

    category = "sources"
    parameters = {"q0": Param(0.0, "@q", "start position"),
                  "speed": Param(1.0, "@q/s", "speed [unit/s]"), "t_start": Param(0.0, "s", "start")}
    outputs = _OUT
    modes = {"on": Mode(doc="1 once moving")}

    @staticmethod
    def output(t, q0, speed, t_start, on, q, qd, qdd):
        moving = on[0] > 0.5
        q[0] = q0 + (speed * (t - t_start) if moving else 0.0)
        qd[0] = speed if moving else 0.0
        qdd[0] = 0.0

    @staticmethod
    def next_time(t, t_start, on):
        return t_start if on[0] < 0.5 else math.inf

    @staticmethod
    def time_event(t, on):
        on[0] = 1.0
