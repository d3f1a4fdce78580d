"""Translational mechanics with impacts: a point mass above a hard stop.

Sign convention: ``x`` is the height above the stop's reference, positive up; gravity
``g`` acts along -x; ``f`` is an applied force along +x.
"""
import math

from .base import Block, Event, Mode, Param, Port, State


class MassOnStop(Block):
    """Point mass falling on a hard stop at ``x_stop`` with restitution ``e``::

        dx/dt = v,   m dv/dt = f - m g          (free)
        x+ = x_stop, v+ = e |v-|                (impact event when x falls through x_stop)

    If the rebound speed ``e |v-|`` is below ``v_rest`` the mass comes to rest on the stop
    (mode ``rest``: derivatives zero) and lifts off when ``f > m g`` again. With
    ``v_rest = 0`` a bouncing mass shows the Zeno accumulation of impacts, which the
    solver reports as chattering.
    """

    category = "mechanics"
    parameters = {
        "m": Param(1.0, "kg", "mass", gt=0.0),
        "g": Param(9.81, "m/s2", "gravity along -x", ge=0.0),
        "e": Param(0.8, "1", "coefficient of restitution", ge=0.0, le=1.0),
        "x_stop": Param(0.0, "m", "position of the stop"),
        "v_rest": Param(0.0, "m/s", "rebound speed below which the mass comes to rest",
                        ge=0.0),
        "x0": Param(1.0, "m", "initial position"),
        "v0": Param(0.0, "m/s", "initial velocity"),
    }
    inputs = {"f": Port("N", optional=True, doc="applied force along +x")}
    outputs = {"x": Port("m", doc="position"), "v": Port("m/s", doc="velocity")}
    states = {"x": State("m", initial="x0", doc="position"),
              "v": State("m/s", initial="v0", doc="velocity")}
    modes = {"rest": Mode(doc="1 while resting on the stop")}
    events = {"impact": Event(-1, "the mass reaches the stop"),
              "lift_off": Event(1, "the net force lifts a resting mass")}

    @classmethod
    def check(cls, params):
        if params["x0"] < params["x_stop"]:
            raise ValueError(f"x0 ({params['x0']}) must not be below x_stop "
                             f"({params['x_stop']})")

    @staticmethod
    def derivative(t, v, f, m, g, rest, der_x, der_v):
        if rest[0] > 0.5:
            der_x[0] = 0.0
            der_v[0] = 0.0
        else:
            der_x[0] = v[0]
            der_v[0] = f[0] / m - g

    @staticmethod
    def guard(t, x, f, m, g, x_stop, rest, zc):
        resting = rest[0] > 0.5
        zc[0] = 1.0 if resting else x[0] - x_stop
        zc[1] = f[0] / m - g if resting else -1.0

    @staticmethod
    def on_event(t, which, direction, x, v, e, v_rest, x_stop, rest):
        if which == 0:
            # the stop sends the mass back up from the stop: x+ = x_stop, v+ = e |v-| (a
            # crossing located on an integrated flight shorter than the tolerances can
            # carry a tiny v- > 0 or lie a rounding error beyond the stop)
            x[0] = x_stop
            v_new = e * abs(v[0])
            if abs(v_new) <= v_rest:
                rest[0] = 1.0
                v[0] = 0.0
                x[0] = x_stop
            else:
                v[0] = v_new
        else:
            rest[0] = 0.0


class Inertia(Block):
    """Rigid rotating inertia ``J dw/dt = tau``, ``dphi/dt = w``; the acceleration ``a`` is
    an output with direct feedthrough of ``tau`` (what a rigid coupling closes a loop on).
    Positive ``tau`` accelerates positively."""

    category = "mechanics"
    parameters = {"J": Param(1.0, "kg.m2", "moment of inertia", gt=0.0),
                  "w0": Param(0.0, "rad/s", "initial speed"),
                  "phi0": Param(0.0, "rad", "initial angle")}
    inputs = {"tau": Port("N.m", doc="net torque on the inertia")}
    outputs = {"w": Port("rad/s", doc="speed"), "phi": Port("rad", doc="angle"),
               "a": Port("rad/s2", feedthrough=("tau",), doc="angular acceleration tau/J")}
    states = {"w": State("rad/s", initial="w0", doc="speed"),
              "phi": State("rad", initial="phi0", doc="angle")}

    @staticmethod
    def output(t, tau, J, a):
        a[0] = tau[0] / J

    @staticmethod
    def derivative(t, w, tau, J, der_w, der_phi):
        der_w[0] = tau[0] / J
        der_phi[0] = w[0]

    @staticmethod
    def partials(t, J, dfdx, dfdu, dydu):
        """``d(dw/dt)/dtau = 1/J``, ``d(dphi/dt)/dw = 1``, ``da/dtau = 1/J``."""
        dfdu[0, 0] = 1.0 / J
        dfdx[1, 0] = 1.0
        dydu[0, 0] = 1.0 / J


class PointMass(Block):
    """Point mass in space, base frame::

        m dv/dt = f + m g,   dp/dt = v

    ``g`` is the acceleration of free fall (``[0, 0, -9.81]`` on the ground). The
    acceleration ``acc`` depends directly on ``f`` (what a rigid contact closes its loop
    on). With a :class:`RigidContact` wired to ``constraint``, the engagement of the
    constraint is a plastic impact: the velocity along the normal ``n`` is removed,
    ``v+ = v- - (n . v-) n`` when approaching.
    """

    category = "mechanics"
    parameters = {"m": Param(1.0, "kg", "mass", gt=0.0),
                  "g": Param([0.0, 0.0, 0.0], "m/s2", "gravity (base frame)", shape=3),
                  "p0": Param([0.0, 0.0, 0.0], "m", "initial position", shape=3),
                  "v0": Param([0.0, 0.0, 0.0], "m/s", "initial velocity", shape=3)}
    inputs = {"f": Port("N", size=3, optional=True, doc="applied force"),
              "constraint": Port("*", size=4, optional=True,
                                 doc="[engaged, n] from a RigidContact: impact on engagement")}
    outputs = {"pos": Port("m", size=3, doc="position"),
               "vel": Port("m/s", size=3, doc="velocity"),
               "acc": Port("m/s2", size=3, feedthrough=("f",), doc="acceleration")}
    states = {"pos": State("m", size=3, initial="p0", doc="position"),
              "vel": State("m/s", size=3, initial="v0", doc="velocity")}
    events = {"impact": Event(1, "a rigid constraint engages (plastic impact)")}

    @staticmethod
    def output(t, f, m, g, acc):
        for k in range(3):
            acc[k] = f[k] / m + g[k]

    @staticmethod
    def derivative(t, vel, acc, der_pos, der_vel):
        for k in range(3):
            der_pos[k] = vel[k]
            der_vel[k] = acc[k]

    @staticmethod
    def guard(t, constraint, zc):
        zc[0] = constraint[0] - 0.5

    @staticmethod
    def on_event(t, which, direction, constraint, vel):
        vn = 0.0
        for k in range(3):
            vn += constraint[1 + k] * vel[k]
        if vn < 0.0:
            for k in range(3):
                vel[k] -= vn * constraint[1 + k]


class Brake(Block):
    """Fail-safe friction brake on a shaft, engaged after a fault is detected::

        fault rises through 0.5 at t_f  (event)  ->  engaged from t_f + t_detect + t_engage
        tau = -engaged * T_hold * tanh(w / w_eps)                      [N.m]

    ``t_detect`` is the fault detection (monitoring) delay and ``t_engage`` the mechanical
    engagement time of the brake; from then on the brake applies up to its holding torque
    ``T_hold`` against the speed ``w`` (regularized Coulomb friction: ``|tau| -> T_hold``
    for ``|w| >> w_eps``; a shaft held against a torque below ``T_hold`` creeps at about
    ``w_eps atanh(tau_ext / T_hold)``). Engagement is a time event; it latches until the
    end of the run (the release command of the real brake is not modelled). Sign:
    ``tau`` acts on the shaft whose speed is ``w``; wire it into the shaft's torque sum.
    """

    category = "mechanics"
    parameters = {
        "T_hold": Param(10.0, "N.m", "holding torque", gt=0.0),
        "t_detect": Param(0.01, "s", "fault detection delay", ge=0.0),
        "t_engage": Param(0.02, "s", "engagement time once commanded", ge=0.0),
        "w_eps": Param(1e-3, "rad/s", "speed of the friction regularization", gt=0.0),
    }
    inputs = {"fault": Port("1", optional=True,
                            doc="fault flag (> 0.5: a fault is present); unconnected: none"),
              "w": Port("rad/s", doc="shaft speed")}
    outputs = {"tau": Port("N.m", feedthrough=("w",), doc="brake torque on the shaft"),
               "engaged": Port("1", doc="1 once the brake holds, else 0")}
    modes = {"t_on": Mode(initial=math.inf, doc="engagement time (inf: not commanded)"),
             "on": Mode(doc="engaged (1) or not (0)")}
    events = {"fault": Event(1, "fault flag rises through 0.5: engagement is commanded")}

    @staticmethod
    def output(t, w, T_hold, w_eps, on, tau, engaged):
        tau[0] = -on[0] * T_hold * math.tanh(w[0] / w_eps)
        engaged[0] = on[0]

    @staticmethod
    def initialize(t, fault, t_detect, t_engage, t_on):
        if fault[0] > 0.5 and t_on[0] == math.inf:       # faulty from the start
            t_on[0] = t + t_detect + t_engage

    @staticmethod
    def guard(t, fault, zc):
        zc[0] = fault[0] - 0.5

    @staticmethod
    def on_event(t, which, direction, t_detect, t_engage, t_on):
        if direction > 0 and t_on[0] == math.inf:
            t_on[0] = t + t_detect + t_engage

    @staticmethod
    def next_time(t, t_on, on):
        return t_on[0] if on[0] < 0.5 else math.inf

    @staticmethod
    def time_event(t, t_on, on):
        on[0] = 1.0
