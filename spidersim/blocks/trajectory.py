"""Reference trajectories: trapezoidal-velocity point-to-point, quintic, quintic through via
points, constant speed.

Each outputs position ``q``, velocity ``qd`` and acceleration ``qdd``; the corners between
phases are time events, so each integration step sees one polynomial piece.
"""
import math

from .base import Block, Mode, Param, Port

#: the shortest segment of a via-point path [s]: the shortest run the engine integrates
#: (``solver.events.MIN_SPAN``); a shorter one is a typing slip whose slope and polynomial
#: coefficients would be huge (1e-13 s between two points: a reference of 1e11 units/s)
MIN_SEGMENT = 1e-7

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


class ViaPointProfile(Block):
    """A path through via points: position ``q_k = points[k]`` at time ``t_k = times[k]``.

    Holds ``q_0`` before ``t_0`` and ``q_n`` after ``t_n``. Between two consecutive via
    points the path is the quintic polynomial with the given position, velocity and
    acceleration at both ends, so position, velocity and acceleration are continuous (C2)
    and the path passes exactly through every via point at its time. Every via time is a
    time event, so each integration step sees one polynomial.

    Positions are in the unit of ``points``, velocities in that unit per second,
    accelerations in that unit per second squared; times are in s.

    Notes
    -----
    Velocities at the via points (the classic heuristic, Craig, Introduction to Robotics,
    ch. 7): ``v_0 = v_n = 0``; at an interior point ``k``, with the slopes of the adjacent
    segments ``m_k = (q_k - q_{k-1}) / (t_k - t_{k-1})`` and ``m_{k+1}``,
    ``v_k = (m_k + m_{k+1}) / 2`` when both slopes have the same sign
    (``m_k m_{k+1} > 0``), else ``v_k = 0`` (a sign change or a zero slope, so that the
    path does not overshoot a turning point). The accelerations at every via point are 0.

    On segment ``k`` (``t_k <= t <= t_{k+1}``), with ``h = t_{k+1} - t_k``,
    ``s = (t - t_k) / h`` and ``d = q_{k+1} - q_k``::

        q   = q_k + h v_k s + c3 s^3 + c4 s^4 + c5 s^5
        qd  = (h v_k + 3 c3 s^2 + 4 c4 s^3 + 5 c5 s^4) / h
        qdd = (6 c3 s + 12 c4 s^2 + 20 c5 s^3) / h^2
        c3  = 10 d - h (6 v_k + 4 v_{k+1})
        c4  = -15 d + h (8 v_k + 7 v_{k+1})
        c5  = 6 d - 3 h (v_k + v_{k+1})

    With two points this is ``QuinticProfile`` (``q0 = q_0``, ``q1 = q_1``,
    ``T = t_1 - t_0``, ``t_start = t_0``).
    """

    category = "sources"
    parameters = {
        "points": Param(unit="@q", doc="via positions q_0 .. q_n (at least 2)", shape="*"),
        "times": Param(doc="times of the via points, strictly increasing from t_0 >= 0, "
                           "at least 1e-7 s apart",
                       unit="s", shape="points", ge=0.0),
    }
    outputs = _OUT
    modes = {"k": Mode(doc="number of via times passed (0 before t_0, n + 1 after t_n)")}

    @classmethod
    def check(cls, params):
        import numpy as np
        if np.size(params["points"]) < 2:
            raise ValueError(f"parameter 'points' needs at least 2 via points, got "
                             f"{np.size(params['points'])}")
        if np.any(np.diff(params["times"]) <= 0):
            v = np.ravel(params["times"])
            k = int(np.flatnonzero(np.diff(v) <= 0)[0])
            raise ValueError(f"parameter 'times' must be strictly increasing: "
                             f"times[{k + 1}] = {v[k + 1]:g} s is not after "
                             f"times[{k}] = {v[k]:g} s")
        v = np.ravel(params["times"]).astype(float)
        if not np.all(np.isfinite(v)):
            raise ValueError("parameter 'times' must be finite")
        h = np.diff(v)
        if np.any(h < MIN_SEGMENT * (1 - 1e-6)):    # 10.0000001 - 10 = 9.99999994e-8
            k = int(np.argmin(h))
            raise ValueError(f"parameter 'times': the segment from times[{k}] = {v[k]:.15g} s "
                             f"to times[{k + 1}] = {v[k + 1]:.15g} s lasts {h[k]:.3g} s, "
                             f"shorter than {MIN_SEGMENT:g} s (the run's time resolution); "
                             f"its slope would be (q_{k + 1} - q_{k}) / {h[k]:.3g} s")

    @classmethod
    def derive(cls, params):
        import numpy as np
        q = np.asarray(params["points"], dtype=float)
        t = np.asarray(params["times"], dtype=float)
        v = np.zeros(q.size)
        for k in range(1, q.size - 1):
            m_in = (q[k] - q[k - 1]) / (t[k] - t[k - 1])
            m_out = (q[k + 1] - q[k]) / (t[k + 1] - t[k])
            if m_in * m_out > 0.0:
                v[k] = 0.5 * (m_in + m_out)
        return {"v_via": v}

    @staticmethod
    def output(t, points, times, v_via, k, q, qd, qdd):
        n = points.size
        j = int(k[0])
        if j <= 0:
            q[0], qd[0], qdd[0] = points[0], 0.0, 0.0
        elif j >= n:
            q[0], qd[0], qdd[0] = points[n - 1], 0.0, 0.0
        else:
            h = times[j] - times[j - 1]
            s = (t - times[j - 1]) / h
            d = points[j] - points[j - 1]
            v0, v1 = v_via[j - 1], v_via[j]
            c3 = 10.0 * d - h * (6.0 * v0 + 4.0 * v1)
            c4 = -15.0 * d + h * (8.0 * v0 + 7.0 * v1)
            c5 = 6.0 * d - 3.0 * h * (v0 + v1)
            q[0] = points[j - 1] + s * (h * v0 + s * s * (c3 + s * (c4 + s * c5)))
            qd[0] = (h * v0 + s * s * (3.0 * c3 + s * (4.0 * c4 + s * 5.0 * c5))) / h
            qdd[0] = s * (6.0 * c3 + s * (12.0 * c4 + s * 20.0 * c5)) / (h * h)

    @staticmethod
    def next_time(t, times, k):
        j = int(k[0])
        return times[j] if j < times.size else math.inf

    @staticmethod
    def time_event(t, k):
        k[0] += 1.0
