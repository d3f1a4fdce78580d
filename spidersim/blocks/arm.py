"""The arm: an n-DOF serial chain (standard DH) with an optional payload, compiled dynamics.

    M(q) qdd + b(q, qd) = tau + J^T f_ext           (b: Coriolis, centrifugal, gravity)

The link table comes from a data file (``model: spider`` for the SPIDER-like arm shipped
with spidersim, or a path); see :mod:`spidersim.multibody`. The joint states (link side)
live here; the joint torques come from the gearboxes. ``f_ext`` (force, moment about the
flange origin, base frame) is applied by the environment to the arm.

Payload: a rigid body (mass, COM offset and principal inertia in the flange frame) that is
part of the last link while ``latched``. Before the latch it is fixed in space (at rest);
when the ``latch`` input rises through 0.5 the joint velocities jump so that the
generalized momentum is conserved, ``M'(q) qd+ = M(q) qd-`` (a plastic capture).

``base_force`` and ``base_moment`` (about the base origin, base frame) are the wrench the
arm applies to its mounting (the ISS truss): the opposite of the wrench the mounting
applies to the arm. With ``gravity = 0`` they equal minus the rate of change of the arm's
(and latched payload's, and the rotors') momentum.

Rotor reactions (optional input ``tau_r``)
------------------------------------------
Drive ``i`` (motor stator, gear housing and circular spline) is fixed to link ``i-1``
(joint 1's to the base); its rotor and wave generator (inertia ``J_m``, speed ``w_m``
relative to link ``i-1``, positive in the sense of ``q_i``: the motor turns ``N > 0``
times the output, ``delta = phi_m / N - phi_l``) spin about ``z_{i-1}``. Torques about
that axis, gear massless, on the rotor: ``tau_em`` from the stator, ``-tau_s / N`` from the
wave generator (``tau_m`` of the gearbox block, with motor-side friction ``+tau_f``),
``-tau_b`` from a brake, ``-B w_m`` from the bearings::

    J_m dw_m/dt = tau_em - tau_s / N - tau_b - B w_m                    (the motor block)

The gear takes ``tau_s / N`` from the rotor and gives ``tau_s`` to link ``i`` (its output),
so the circular spline takes ``tau_s - tau_s / N`` from the housing. The housing (link
``i-1``) therefore receives ``-tau_em + tau_b + B w_m`` from the rotor and
``-(tau_s - tau_s / N)`` from the gear, in total::

    -tau_s - (tau_em - tau_s / N - tau_b - B w_m)  =  -tau_s - J_m dw_m/dt

The first term is the joint torque the arm already applies between links ``i-1`` and ``i``
(``tau``); the second, ``tau_r = -J_m dw_m/dt``, is the reaction: a moment
``tau_r z_{i-1}`` on link ``i-1`` (the same with friction on either side of the gear, an
efficiency below 1 or a brake: every torque on the rotor other than its inertia reacts on
the housing). Expressed with the rotor angle in output units ``q_m = phi_m / N`` it is
``-J_m N d^2 q_m/dt^2``: the ``J_m N dw/dt`` of issue 13 when its ``w`` is the motor speed
seen at the output, ``N`` times smaller than the reflected-inertia torque ``J_m N^2 qdd``
(which is part of ``tau``, through the gear). Below the gear resonance (rigid gear,
``w_m = N qd_i``) it adds ``J_m N qdd_i`` about the axis; above it the rotor moves alone
and the motor's torque ripple reaches link ``i-1`` (for joint 1 the base) as
``-J_m dw_m/dt``, no longer filtered by the gear.

The kernels add these moments in the inverse dynamics (link dynamics and base wrench),
``M qdd + b = tau + Q_r`` with ``Q_r,j = z_{j-1} . sum_{i > j} tau_r,i z_{i-1}``, and the
base moment gains ``sum_i tau_r,i z_{i-1}`` (:func:`spidersim.multibody.kernels.
add_reactions`). Unconnected, ``tau_r`` reads zero and the kernels skip it.

Neglected: the rotor's gyroscopic moment ``J_m w_m omega_{i-1} x z_{i-1}`` when link
``i-1`` turns (and its transverse inertia): for SPIDER at the 2.5 cm/s cruise
``w_m <= N qd = 160 x 0.051 = 8 rad/s`` and ``|omega| <= 0.051 rad/s``: below
``1e-4 x 8 x 0.051 = 4e-5 N.m``; with a motor at 955 rpm (100 rad/s) and the link at
0.1 rad/s, ``1e-3 N.m``: below the ripple reaction (the 1.5 % current-sensor offset alone gives
``K_t x 0.03 A = 4.5e-3 N.m`` at the electrical frequency), and nearly constant in the
cruise, where it changes slowly with the pose (no line above the gear resonance). The
motor block integrates ``w_m`` relative to its stator, leaving out ``J_m z . alpha_{i-1}``
(the link's angular acceleration, ``1/N`` of the rotor's in a rigid drive).
"""
import math
import os

import numpy as np

from ..multibody.kernels import WS_ACC, WS_O, WS_R, WS_W
from ..multibody.kernels import WS_PER_LINK as _WS
from .base import Block, Dim, Event, Mode, Param, Port, State, unit_vector

_CHAINS = {}


def _chain(model):
    from ..multibody.chain import SPIDER, Chain
    path = SPIDER if model == "spider" else model
    if path not in _CHAINS:
        _CHAINS[path] = Chain.from_yaml(path)
    return _CHAINS[path]


def _ws_dim():
    """Scratch of the multibody kernels: WS_PER_LINK floats per link and the base."""
    return Dim(f"{_WS} (n + 1)", lambda p: _WS * (_n(p) + 1))


def _n(p):
    return _chain(p["model"]).n


_N = Dim("number of joints of the model", _n)


def _with_payload(P, mass, com, inertia):
    """Link table with the payload merged into the last link (link coordinates)."""
    P = P.copy()
    last = P[-1]
    m0, c0 = last[3], last[4:7].copy()
    I0 = last[7:16].reshape(3, 3)
    # flange frame = frame n: the payload COM and inertia are given in it already
    mp, cp, Ip = mass, np.asarray(com, float), np.diag(np.asarray(inertia, float))
    m = m0 + mp
    if m <= 0:
        return P
    c = (m0 * c0 + mp * cp) / m

    def shift(I, mass_, r):
        return I + mass_ * (np.dot(r, r) * np.eye(3) - np.outer(r, r))

    Inew = shift(I0, m0, c0 - c) + shift(Ip, mp, cp - c)
    last[3] = m
    last[4:7] = c
    last[7:16] = Inew.ravel()
    return P


class Arm(Block):
    """n-DOF serial arm with payload (see the module docstring)."""

    category = "multibody"
    parameters = {
        "model": Param("spider", kind="str", doc="'spider' (shipped SPIDER-like data) or the "
                                                 "path of an arm data file"),
        "gravity": Param([0.0, 0.0, 0.0], "m/s2", "gravity in the base frame", shape=3),
        "q0": Param(0.0, "rad", "initial joint angles", shape=_N),
        "qd0": Param(0.0, "rad/s", "initial joint speeds", shape=_N),
        "payload_mass": Param(0.0, "kg", "payload mass", ge=0.0),
        "payload_com": Param([0.0, 0.0, 0.0], "m", "payload COM in the flange frame", shape=3),
        "payload_inertia": Param([0.0, 0.0, 0.0], "kg.m2",
                                 "payload principal inertia about its COM, flange axes",
                                 shape=3, ge=0.0),
        "latched": Param(False, kind="bool", doc="payload attached from the start"),
    }
    inputs = {"tau": Port("N.m", size=_N, doc="joint torques (from the gearboxes)"),
              "f_ext": Port("*", size=6, optional=True,
                            doc="external wrench on the flange: force [N], moment [N.m]"),
              "latch": Port("1", optional=True, doc="rising through 0.5: capture the payload"),
              "constraint": Port("*", size=4, optional=True,
                                 doc="[engaged, n] from a RigidContact on the flange: "
                                     "plastic impact when it engages"),
              "tau_r": Port("N.m", size=_N, optional=True,
                            doc="drive reactions -J_m dw_m/dt: joint i's on link i-1 "
                                "(joint 1's on the base), about joint i's axis")}
    outputs = {
        "q": Port("rad", size=_N, doc="joint angles (link side)"),
        "qd": Port("rad/s", size=_N, doc="joint speeds"),
        "qdd": Port("rad/s2", size=_N, feedthrough=("tau", "f_ext", "tau_r"),
                    doc="joint accelerations"),
        "flange_pos": Port("m", size=3, doc="flange origin, base frame"),
        "flange_rot": Port("1", size=9, doc="flange rotation matrix, row-major"),
        "flange_twist": Port("*", size=6, doc="flange linear [m/s] and angular [rad/s] velocity"),
        "flange_acc": Port("m/s2", size=3, feedthrough=("tau", "f_ext", "tau_r"),
                           doc="flange origin acceleration, J qdd + Jdot qd"),
        "base_force": Port("N", size=3, feedthrough=("tau", "f_ext", "tau_r"),
                           doc="force the arm applies to its mounting"),
        "base_moment": Port("N.m", size=3, feedthrough=("tau", "f_ext", "tau_r"),
                            doc="moment about the base origin the arm applies to its mounting"),
    }
    states = {"q": State("rad", size=_N, initial="q0", doc="joint angles"),
              "qd": State("rad/s", size=_N, initial="qd0", doc="joint speeds")}
    modes = {"attached": Mode(initial=lambda p: 1.0 if p["latched"] else 0.0,
                              doc="1 once the payload is attached")}
    events = {"latch": Event(1, "the latch input rises: the payload is captured"),
              "impact": Event(1, "a rigid constraint on the flange engages: plastic impact")}
    scratch = {"ws": _ws_dim(),
               "Mw": Dim("n^2", lambda p: _n(p) ** 2),
               "Mw2": Dim("n^2", lambda p: _n(p) ** 2),
               "tmp": Dim("6 n", lambda p: 6 * _n(p)), "bw": Dim("6", lambda p: 6),
               "v1": Dim("n", _n), "Jw": Dim("6 n", lambda p: 6 * _n(p)),
               "key": Dim("n + 2", lambda p: _n(p) + 2)}

    @classmethod
    def check(cls, params):
        model = params["model"]
        if model != "spider" and not os.path.isfile(model):
            raise ValueError(f"arm data file not found: {model} (use 'spider' for the "
                             f"shipped SPIDER-like arm)")

    @classmethod
    def derive(cls, params):
        P = _chain(params["model"]).P
        return {"P": P, "P_lat": _with_payload(P, params["payload_mass"],
                                               params["payload_com"],
                                               params["payload_inertia"])}

    @staticmethod
    def output(t, q, qd, tau, f_ext, tau_r, gravity, P, P_lat, attached, ws, Mw, tmp, bw, Jw, key,
               qdd, flange_pos, flange_rot, flange_twist, flange_acc, base_force,
               base_moment):
        n = q.size
        M = Mw.reshape((n, n))
        PP = P_lat if attached[0] > 0.5 else P
        # key: the factor of M(q) in Mw is reused while q is unchanged (Newton iterations
        # of a contact loop change f_ext only)
        forward_dynamics(q, qd, tau, gravity, f_ext, tau_r, PP, ws, M, tmp, bw, qdd, key)
        for k in range(3):
            base_force[k] = -bw[k]
            base_moment[k] = -bw[3 + k]
        b = n * _WS
        for k in range(9):
            flange_rot[k] = ws[b + WS_R + k]
        for k in range(3):
            flange_pos[k] = ws[b + WS_O + k]
            flange_twist[3 + k] = ws[b + WS_W + k]
            # the last RNEA pass ran with the base accelerating at -g
            flange_acc[k] = ws[b + WS_ACC + k] + gravity[k]
        flange_jacobian(n, ws, Jw)
        for r in range(3):
            acc = 0.0
            for i in range(n):
                acc += Jw[r * n + i] * qd[i]
            flange_twist[r] = acc

    @staticmethod
    def derivative(t, qd, qdd, der_q, der_qd):
        for i in range(qd.size):
            der_q[i] = qd[i]
            der_qd[i] = qdd[i]

    @staticmethod
    def guard(t, latch, constraint, attached, zc):
        zc[0] = latch[0] - 0.5 if attached[0] < 0.5 else -1.0
        zc[1] = constraint[0] - 0.5

    @staticmethod
    def on_event(t, which, direction, q, qd, constraint, P, P_lat, attached, ws, Mw, Mw2,
                 tmp, bw, v1, Jw, key):
        n = q.size
        M = Mw.reshape((n, n))
        M2 = Mw2.reshape((n, n))
        key[n + 1] = 0.0                              # Mw is overwritten here
        if which == 1:
            # plastic impact on the plane of normal c: J_n = c^T J_v (1 x n),
            # qd+ = qd- - M^-1 J_n^T (J_n M^-1 J_n^T)^-1 J_n qd-   (approaching only)
            mass_matrix(q, P_lat if attached[0] > 0.5 else P, ws, M, tmp, bw)
            flange_jacobian(n, ws, Jw)
            vn = 0.0
            for i in range(n):
                acc = 0.0
                for r in range(3):
                    acc += constraint[1 + r] * Jw[r * n + i]
                v1[i] = acc                           # J_n^T
                vn += acc * qd[i]
            if vn >= 0.0:
                return
            y = tmp[:n]
            cholesky_solve(M, v1, y)                  # M^-1 J_n^T
            s = 0.0
            for i in range(n):
                s += v1[i] * y[i]
            for i in range(n):
                qd[i] -= y[i] * vn / s
            return
        mass_matrix(q, P, ws, M, tmp, bw)
        for i in range(n):
            acc = 0.0
            for j in range(n):
                acc += M[i, j] * qd[j]
            v1[i] = acc                               # generalized momentum M qd-
        mass_matrix(q, P_lat, ws, M2, tmp, bw)
        cholesky_solve(M2, v1, qd)                    # M' qd+ = M qd-
        attached[0] = 1.0


def _bind():
    from ..multibody import kernels as K
    return K.forward_dynamics, K.mass_matrix, K.cholesky_solve


forward_dynamics, mass_matrix, cholesky_solve = _bind()


class CartesianLineIK(Block):
    """Joint references for a straight line of the flange, by damped least squares::

        p_d(s) = p_0 + s u,  R_d = R_0                     (p_0, R_0: flange pose at q0)
        v = [sd u + K (p_d - p(q_r)); K e_R]               (e_R: orientation error)
        dq_r/dt = J^T (J J^T + lambda^2 I)^-1 v

    ``s`` and ``sd`` (path length [m] and speed [m/s], e.g. from a TrapezoidalProfile) are
    inputs; the joint references ``q_ref`` are states integrated from ``q0``, ``qd_ref`` is
    their rate (the controllers' speed feed-forward).
    """

    category = "multibody"
    parameters = {
        "model": Param("spider", kind="str", doc="arm data ('spider' or a path)"),
        "q0": Param(0.0, "rad", "initial joint angles", shape=_N),
        "direction": Param([1.0, 0.0, 0.0], "1", "line direction (normalised)", shape=3),
        "K": Param(20.0, "1/s", "task-space error gain", ge=0.0),
        "damping": Param(0.01, "1", "damped-least-squares lambda", gt=0.0),
    }
    inputs = {"s": Port("m", doc="path length"), "sd": Port("m/s", doc="path speed")}
    outputs = {"q_ref": Port("rad", size=_N, doc="joint references"),
               "qd_ref": Port("rad/s", size=_N, feedthrough=("sd", "s"),
                              doc="joint reference speeds"),
               "p_ref": Port("m", size=3, feedthrough=("s",), doc="desired flange position")}
    states = {"q_ref": State("rad", size=_N, initial="q0", doc="joint references")}
    scratch = {"ws": _ws_dim(),
               "A6": Dim("36", lambda p: 36), "v6": Dim("6", lambda p: 6),
               "y6": Dim("6", lambda p: 6), "Jw": Dim("6 n", lambda p: 6 * _n(p))}

    @classmethod
    def check(cls, params):
        unit_vector(params["direction"], "direction")

    @classmethod
    def derive(cls, params):
        ch = _chain(params["model"])
        T = ch.fk(params["q0"])
        u = unit_vector(params["direction"], "direction")
        return {"P": ch.P, "p0": T[:3, 3].copy(), "R0": T[:3, :3].ravel().copy(), "u": u}

    @staticmethod
    def output(t, q_ref, s, sd, P, p0, R0, u, K, damping, ws, A6, v6, y6, Jw, qd_ref, p_ref):
        n = q_ref.size
        fk(q_ref, P, ws)
        b = n * _WS
        for k in range(3):
            p_ref[k] = p0[k] + s[0] * u[k]
            v6[k] = sd[0] * u[k] + K * (p_ref[k] - ws[b + WS_O + k])
        orientation_error(ws, n, R0, y6)               # 0.5 sum_i r_i x r_d,i
        v6[3], v6[4], v6[5] = K * y6[0], K * y6[1], K * y6[2]
        A = A6.reshape((6, 6))
        flange_jacobian(n, ws, Jw)                     # A = J J^T + lambda^2 I
        for r in range(6):
            for c in range(6):
                acc = damping * damping if r == c else 0.0
                for i in range(n):
                    acc += Jw[r * n + i] * Jw[c * n + i]
                A[r, c] = acc
        cholesky_solve(A, v6, y6)
        for i in range(n):
            acc = 0.0
            for r in range(6):
                acc += Jw[r * n + i] * y6[r]
            qd_ref[i] = acc

    @staticmethod
    def derivative(t, qd_ref, der_q_ref):
        for i in range(qd_ref.size):
            der_q_ref[i] = qd_ref[i]


def _bind_kinematics():
    from ..multibody import kernels as K
    return K.fk, K.flange_jacobian, K.orientation_error


fk, flange_jacobian, orientation_error = _bind_kinematics()


class ForwardKinematics(Block):
    """Flange pose of the arm at the joint angles ``q``: position [m] and rotation matrix
    (row-major), base frame."""

    category = "multibody"
    parameters = {"model": Param("spider", kind="str", doc="arm data ('spider' or a path)")}
    inputs = {"q": Port("rad", size=_N, doc="joint angles")}
    outputs = {"pos": Port("m", size=3, feedthrough=("q",), doc="flange origin"),
               "rot": Port("1", size=9, feedthrough=("q",), doc="flange rotation, row-major")}
    scratch = {"ws": _ws_dim()}

    @classmethod
    def derive(cls, params):
        return {"P": _chain(params["model"]).P}

    @staticmethod
    def output(t, q, P, ws, pos, rot):
        fk(q, P, ws)
        b = q.size * _WS
        for k in range(9):
            rot[k] = ws[b + k]
        for k in range(3):
            pos[k] = ws[b + WS_O + k]


class Jacobian(Block):
    """Geometric Jacobian of the flange (6 x n, row-major: linear velocity rows first, then
    angular), base frame: ``[v; w] = J(q) qd``."""

    category = "multibody"
    parameters = {"model": Param("spider", kind="str", doc="arm data ('spider' or a path)")}
    inputs = {"q": Port("rad", size=_N, doc="joint angles")}
    outputs = {"J": Port("1", size=Dim("6 n", lambda p: 6 * _n(p)), feedthrough=("q",),
                         doc="Jacobian, row-major 6 x n")}
    scratch = {"ws": _ws_dim()}

    @classmethod
    def derive(cls, params):
        return {"P": _chain(params["model"]).P}

    @staticmethod
    def output(t, q, P, ws, J):
        fk(q, P, ws)
        flange_jacobian(q.size, ws, J)
