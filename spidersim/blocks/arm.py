"""The arm: an n-DOF serial chain (standard DH) with an optional payload, compiled dynamics.

    M(q) qdd + b(q, qd) = tau + J^T f_ext           (b: Coriolis, centrifugal, gravity)

The link table comes from a data file (``model: spider`` for the SPIDER-like arm shipped
with spidersim, or a path); see :mod:`spidersim.multibody`. The joint states (link side)
live here; the joint torques come from the gearboxes. ``f_ext`` (force, moment about the
flange origin, base frame) is applied by the environment to the arm.

Payload: a rigid body of mass ``m_p`` and principal inertia ``I_p`` about its COM. Its own
frame (the *payload frame*) has its origin at the grapple fixture and its axes along the
principal axes; ``payload_com`` is the COM in that frame. The nominal grasp puts the payload
frame on the flange frame (then ``payload_com`` is the COM in the flange frame).

* Free (``attached = 0``): a torque-free rigid body in orbit, integrated as states: COM
  position ``x_p`` and velocity ``v_p`` (base frame; ``dv_p/dt = g``), attitude quaternion
  ``Q_p`` (body axes in the base frame, scalar first; ``R_p`` always formed from
  ``Q_p / |Q_p|``) and body-axis angular velocity ``w_b`` (Euler's equations, see
  :mod:`spidersim.multibody.rigid_body`). It does not load the arm. The initial pose is
  ``payload_pos0`` (grapple fixture) and ``payload_quat0`` (payload axes) in the flange frame
  at ``q0`` (``payload_frame: flange``, the default: zeros and [1, 0, 0, 0] are the nominal
  grasp) or in the base frame (``payload_frame: base``); the initial twist ``payload_v0``
  (COM velocity) and ``payload_w0`` (angular velocity) is in the base frame.
* Capture (the ``latch`` input rises through 0.5): the payload is attached *where it is*:
  its pose relative to the flange at that instant (COM ``c_rel``, axes ``R_rel``) is kept
  (no snap to the nominal grasp: the capture logic decides when the flange is close enough),
  and merged into the last link. A plastic impact: the impulses between flange and payload
  and between base and link 1 are unknown, the joint torques finite, so the generalized
  momentum projected on the joints is conserved::

      M'(q) qd+ = M(q) qd- + J_c^T M_p V_p-,   M' = M + J_c^T M_p J_c,
      J_c = [J_v - [r]x J_w; J_w]  (COM Jacobian, r = x_p - o_n),  M_p = diag(m_p E, R_p I_p R_p^T)

  ``V_p- = [v_p; R_p w_b]``. Linear and angular momentum of arm + payload are *not* conserved
  with a fixed base: the ISS takes an impulse; only its moment about the joint-1 axis is
  zero (that component of the momentum is conserved).
* Release (the ``release`` input rises through 0.5 while attached): the payload leaves with
  its current twist, ``v_p = v_n + w_n x r``, ``w = w_n``, as free-body states; the joint
  speeds do not jump (no impulse), the arm's momentum drops by the payload's.
* ``latched: true``: attached from the start at its initial pose (the twist parameters are
  then unused).

Rigid contact on the flange: a :class:`RigidContact` (``constraint``, one normal) or a
:class:`RigidContact6` (``constraint6``, any subset of six directions) engaging a direction
is a plastic impact, ``qd+ = qd- - M^-1 J_c^T (J_c M^-1 J_c^T)^-1 J_c qd-`` over the
engaged rows ``J_c`` of the flange Jacobian in the contact axes. ``flange_alpha`` (the
angular acceleration ``J_w qdd + Jdot_w qd``) closes the rotational rows of such a loop.

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
import os

import numpy as np

from ..multibody.kernels import WS_ACC, WS_ALPHA, WS_O, WS_R
from ..multibody.kernels import WS_PER_LINK as _WS
from ..multibody.kernels import jit_kernel
from ..text.yamlio import readable, refuse_unreadable
from .base import Block, Dim, Event, Mode, Param, Port, State, unit_vector

# grasp mode layout: COM in the flange frame (3), payload axes in the flange frame R_rel
# (row-major 9)
_G_COM, _G_ROT = 0, 3

_CHAINS = {}


def _chain(model):
    from ..multibody.chain import SPIDER, Chain
    path = SPIDER if model == "spider" else model
    refuse_unreadable(path, "arm data file")          # also when cached
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
    """Link table with the payload merged into the last link at the nominal grasp (COM
    ``com`` and principal axes along the flange frame); the block itself merges at the
    actual grasp with :func:`spidersim.multibody.rigid_body.merge_into_link`."""
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


def _payload_start(p):
    """Initial payload state in the base frame: (COM x_p, quaternion Q_p, v_p, w_b), and the
    grasp (COM and axes in the flange frame at q0)."""
    ch = _chain(p["model"])
    T = ch.fk(np.asarray(p["q0"], float) * np.ones(ch.n))
    Rf, of = T[:3, :3], T[:3, 3]
    Qn = _unit_quat(p["payload_quat0"])
    Rq = np.zeros(9)
    quat_to_rot(Qn, Rq)
    Rq = Rq.reshape(3, 3)
    pos0 = np.asarray(p["payload_pos0"], float)
    com = np.asarray(p["payload_com"], float)
    if p["payload_frame"] == "flange":
        Rp, grapple = Rf @ Rq, of + Rf @ pos0
    else:
        Rp, grapple = Rq, pos0
    x = grapple + Rp @ com
    Q = np.zeros(4)
    rot_to_quat(Rp.ravel().copy(), Q)
    w_b = Rp.T @ np.asarray(p["payload_w0"], float)
    grasp = np.zeros(12)
    if p["payload_frame"] == "flange":          # exactly the given grasp (no round trip)
        grasp[_G_COM:_G_COM + 3] = pos0 + Rq @ com
        grasp[_G_ROT:_G_ROT + 9] = Rq.ravel()
    else:
        grasp[_G_COM:_G_COM + 3] = Rf.T @ (x - of)
        grasp[_G_ROT:_G_ROT + 9] = (Rf.T @ Rp).ravel()
    return x, Q, np.asarray(p["payload_v0"], float) * np.ones(3), w_b, grasp


def _unit_quat(Q):
    """``payload_quat0`` normalised (any non-zero finite [w, x, y, z]: 1e-300 and 1e300
    components too, see :func:`unit_vector`)."""
    return unit_vector(Q, "payload_quat0 (a quaternion [w, x, y, z], normalised)")


class Arm(Block):
    """n-DOF serial arm with payload (see the module docstring)."""

    category = "multibody"
    parameters = {
        "model": Param("spider", kind="str", file=True,
                       doc="'spider' (shipped SPIDER-like data) or the path of an arm data "
                           "file"),
        "gravity": Param([0.0, 0.0, 0.0], "m/s2", "gravity in the base frame", shape=3),
        "q0": Param(0.0, "rad", "initial joint angles", shape=_N),
        "qd0": Param(0.0, "rad/s", "initial joint speeds", shape=_N),
        "payload_mass": Param(0.0, "kg", "payload mass", ge=0.0),
        "payload_com": Param([0.0, 0.0, 0.0], "m", "payload COM in the payload frame "
                             "(origin: grapple fixture; the flange frame at the nominal grasp)",
                             shape=3),
        "payload_inertia": Param([0.0, 0.0, 0.0], "kg.m2",
                                 "payload principal inertia about its COM, payload axes",
                                 shape=3, ge=0.0),
        "latched": Param(False, kind="bool", doc="payload attached from the start"),
        "payload_frame": Param("flange", kind="str", choices=("flange", "base"),
                               doc="frame of payload_pos0 and payload_quat0: the flange frame "
                                   "at q0, or the base frame"),
        "payload_pos0": Param([0.0, 0.0, 0.0], "m", "initial grapple fixture position "
                              "(payload frame origin), in payload_frame", shape=3),
        "payload_quat0": Param([1.0, 0.0, 0.0, 0.0], "1", "initial payload axes, quaternion "
                               "[w, x, y, z] in payload_frame (normalised)", shape=4),
        "payload_v0": Param([0.0, 0.0, 0.0], "m/s", "initial payload COM velocity, base frame",
                            shape=3),
        "payload_w0": Param([0.0, 0.0, 0.0], "rad/s",
                            "initial payload angular velocity, base frame", shape=3),
    }
    inputs = {"tau": Port("N.m", size=_N, doc="joint torques (from the gearboxes)"),
              "f_ext": Port("*", size=6, optional=True,
                            doc="external wrench on the flange: force [N], moment [N.m]"),
              "latch": Port("1", optional=True, doc="rising through 0.5: capture the payload"),
              "release": Port("1", optional=True,
                              doc="rising through 0.5: release the payload with its twist"),
              "constraint": Port("*", size=4, optional=True,
                                 doc="[engaged, n] from a RigidContact on the flange: "
                                     "plastic impact when it engages"),
              "constraint6": Port("*", size=15, optional=True,
                                  doc="[engaged per direction (6), R_c row-major (9)] from a "
                                      "RigidContact6: plastic impact when one engages"),
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
        "flange_alpha": Port("rad/s2", size=3, feedthrough=("tau", "f_ext", "tau_r"),
                             doc="flange angular acceleration, J_w qdd + Jdot_w qd"),
        "base_force": Port("N", size=3, feedthrough=("tau", "f_ext", "tau_r"),
                           doc="force the arm applies to its mounting"),
        "base_moment": Port("N.m", size=3, feedthrough=("tau", "f_ext", "tau_r"),
                            doc="moment about the base origin the arm applies to its mounting"),
        "payload_pos": Port("m", size=3, doc="payload COM, base frame"),
        "payload_rot": Port("1", size=9, doc="payload axes in the base frame, row-major"),
        "payload_twist": Port("*", size=6, doc="payload COM velocity [m/s] and angular "
                                               "velocity [rad/s], base frame"),
        "grapple_pos": Port("m", size=3, doc="payload grapple fixture, base frame"),
    }
    states = {"q": State("rad", size=_N, initial="q0", doc="joint angles"),
              "qd": State("rad/s", size=_N, initial="qd0", doc="joint speeds"),
              "x_p": State("m", size=3, initial=lambda p: _payload_start(p)[0],
                           doc="free payload COM, base frame (frozen while attached)"),
              "Q_p": State("1", size=4, initial=lambda p: _payload_start(p)[1],
                           doc="free payload attitude quaternion [w, x, y, z]"),
              "v_p": State("m/s", size=3, initial=lambda p: _payload_start(p)[2],
                           doc="free payload COM velocity, base frame"),
              "w_b": State("rad/s", size=3, initial=lambda p: _payload_start(p)[3],
                           doc="free payload angular velocity, payload axes")}
    modes = {"attached": Mode(initial=lambda p: 1.0 if p["latched"] else 0.0,
                              doc="1 while the payload is attached"),
             "grasp": Mode(size=12, initial=lambda p: _payload_start(p)[4],
                           doc="attached payload's COM (3) and axes (9, row-major) in the "
                               "flange frame")}
    events = {"latch": Event(1, "the latch input rises: the payload is captured"),
              "impact": Event(1, "a rigid constraint on the flange engages: plastic impact"),
              "release": Event(1, "the release input rises: the payload leaves"),
              "impact6": Event(1, "a direction of a RigidContact6 engages: plastic impact "
                                  "on all its engaged directions", size=6)}
    scratch = {"ws": _ws_dim(),
               "Mw": Dim("n^2", lambda p: _n(p) ** 2),
               "Mw2": Dim("n^2", lambda p: _n(p) ** 2),
               "tmp": Dim("6 n", lambda p: 6 * _n(p)), "bw": Dim("6", lambda p: 6),
               "v1": Dim("n", _n), "Jw": Dim("6 n", lambda p: 6 * _n(p)),
               "key": Dim("n + 2", lambda p: _n(p) + 2),
               "Pw": Dim("16 n", lambda p: 16 * _n(p)), "pw": Dim("24", lambda p: 24),
               "Jc": Dim("6 n", lambda p: 6 * _n(p)), "Yc": Dim("6 n", lambda p: 6 * _n(p)),
               "Ac": Dim("36", lambda p: 36), "rc": Dim("6", lambda p: 6),
               "xc": Dim("6", lambda p: 6)}

    @classmethod
    def check(cls, params):
        model = params["model"]
        if model != "spider" and not readable(model):
            raise ValueError(f"arm data file '{model}' is not among the files this server's "
                             f"models may read (a request cannot name files of the server)")
        if model != "spider" and not os.path.isfile(model):
            raise ValueError(f"arm data file not found: {model} (use 'spider' for the "
                             f"shipped SPIDER-like arm)")
        _unit_quat(params["payload_quat0"])
        I1, I2, I3 = (float(v) for v in params["payload_inertia"])
        if I1 > I2 + I3 or I2 > I1 + I3 or I3 > I1 + I2:
            raise ValueError(f"payload_inertia: principal moments {[I1, I2, I3]} break the "
                             f"triangle inequality (no rigid body has them)")

    derives = ("P",)

    @classmethod
    def derive(cls, params):
        return {"P": _chain(params["model"]).P}

    @staticmethod
    def output(t, q, qd, x_p, Q_p, v_p, w_b, tau, f_ext, tau_r, gravity, P, payload_mass,
               payload_com, payload_inertia, attached, grasp, ws, Mw, tmp, bw, Jw, key, Pw, pw,
               inputs_ready, qdd, flange_pos, flange_rot, flange_twist, flange_acc,
               flange_alpha, base_force, base_moment, payload_pos, payload_rot, payload_twist,
               grapple_pos):
        """The outputs; with ``inputs_ready`` False (a call made early for the pose and
        velocity outputs, before the torques are computed) only those, without the forward
        dynamics: the flange twist is ``J(q) qd`` in both cases (the angular rows give the
        same sum, term for term, as the recursive ``w_i = w_(i-1) + qd_i z_(i-1)``)."""
        n = q.size
        if inputs_ready:
            M = Mw.reshape((n, n))
            PP = Pw.reshape((n, 16))
            link_table(P, attached, grasp, payload_mass, payload_inertia, PP)
            # key: the factor of M(q) in Mw is reused while q is unchanged (Newton iterations
            # of a contact loop change f_ext only)
            forward_dynamics(q, qd, tau, gravity, f_ext, tau_r, PP, ws, M, tmp, bw, qdd, key)
            for k in range(3):
                base_force[k] = -bw[k]
                base_moment[k] = -bw[3 + k]
        else:
            fk(q, P, ws)           # the joint frames only need the kinematic columns of P
        b = n * _WS
        for k in range(9):
            flange_rot[k] = ws[b + WS_R + k]
        for k in range(3):
            flange_pos[k] = ws[b + WS_O + k]
            if inputs_ready:
                # the last RNEA pass ran with the base accelerating at -g
                flange_acc[k] = ws[b + WS_ACC + k] + gravity[k]
                flange_alpha[k] = ws[b + WS_ALPHA + k]
        flange_jacobian(n, ws, Jw)
        for r in range(6):
            acc = 0.0
            for i in range(n):
                acc += Jw[r * n + i] * qd[i]
            flange_twist[r] = acc
        if attached[0] > 0.5:
            payload_on_flange(ws, n, flange_twist, grasp, payload_pos, payload_rot,
                              payload_twist)
        else:
            quat_to_rot(Q_p, payload_rot)
            for k in range(3):
                payload_pos[k] = x_p[k]
                payload_twist[k] = v_p[k]
                payload_twist[3 + k] = (payload_rot[3 * k] * w_b[0]
                                        + payload_rot[3 * k + 1] * w_b[1]
                                        + payload_rot[3 * k + 2] * w_b[2])
        for k in range(3):       # the fixture is at -payload_com from the COM, payload axes
            grapple_pos[k] = payload_pos[k] - (payload_rot[3 * k] * payload_com[0]
                                               + payload_rot[3 * k + 1] * payload_com[1]
                                               + payload_rot[3 * k + 2] * payload_com[2])

    @staticmethod
    def derivative(t, qd, qdd, v_p, Q_p, w_b, gravity, payload_inertia, attached,
                   der_q, der_qd, der_x_p, der_Q_p, der_v_p, der_w_b):
        for i in range(qd.size):
            der_q[i] = qd[i]
            der_qd[i] = qdd[i]
        free = 1.0 if attached[0] < 0.5 else 0.0       # frozen while attached
        free_body_rates(Q_p, w_b, payload_inertia, der_Q_p, der_w_b)
        for k in range(4):
            der_Q_p[k] *= free
        for k in range(3):
            der_w_b[k] *= free
            der_x_p[k] = free * v_p[k]
            der_v_p[k] = free * gravity[k]

    @staticmethod
    def guard(t, latch, release, constraint, constraint6, attached, zc):
        zc[0] = latch[0] - 0.5 if attached[0] < 0.5 else -1.0
        zc[1] = constraint[0] - 0.5
        zc[2] = release[0] - 0.5 if attached[0] > 0.5 else -1.0
        for k in range(6):
            zc[3 + k] = constraint6[k] - 0.5

    @staticmethod
    def on_event(t, which, direction, q, qd, x_p, Q_p, v_p, w_b, constraint, constraint6, P,
                 payload_mass, payload_inertia, attached, grasp, ws, Mw, Mw2, tmp, bw, v1,
                 Jw, key, Pw, pw, Jc, Yc, Ac, rc, xc):
        n = q.size
        M = Mw.reshape((n, n))
        M2 = Mw2.reshape((n, n))
        PP = Pw.reshape((n, 16))
        key[n + 1] = 0.0                              # Mw is overwritten here
        b = n * _WS
        if which >= 3:
            # a RigidContact6 direction engages: project on all its engaged directions
            link_table(P, attached, grasp, payload_mass, payload_inertia, PP)
            mass_matrix(q, PP, ws, M, tmp, bw)
            flange_jacobian(n, ws, Jw)
            impact_projection(n, qd, constraint6, M, Jw, Jc, Yc, Ac, rc, xc)
            return
        if which == 1:
            # plastic impact on the plane of normal c: J_n = c^T J_v (1 x n),
            # qd+ = qd- - M^-1 J_n^T (J_n M^-1 J_n^T)^-1 J_n qd-   (approaching only)
            link_table(P, attached, grasp, payload_mass, payload_inertia, PP)
            mass_matrix(q, PP, ws, M, tmp, bw)
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
        if which == 2:
            # release: the payload's twist on the flange becomes its free-body state
            fk(q, P, ws)
            flange_jacobian(n, ws, Jw)
            tw = pw[:6]
            for r in range(6):
                acc = 0.0
                for i in range(n):
                    acc += Jw[r * n + i] * qd[i]
                tw[r] = acc
            Rp = pw[6:15]
            pos = pw[15:18]
            V = pw[18:24]
            payload_on_flange(ws, n, tw, grasp, pos, Rp, V)
            rot_to_quat(Rp, Q_p)
            for k in range(3):
                x_p[k] = pos[k]
                v_p[k] = V[k]
            for k in range(3):                        # w_b = R_p^T w
                w_b[k] = Rp[k] * V[3] + Rp[3 + k] * V[4] + Rp[6 + k] * V[5]
            attached[0] = 0.0
            return
        # capture: attach where it is, M' qd+ = M qd- + J_c^T M_p V_p-
        mass_matrix(q, P, ws, M, tmp, bw)             # also leaves fk(q) in ws
        flange_jacobian(n, ws, Jw)
        Rp = pw[6:15]
        quat_to_rot(Q_p, Rp)
        # grasp: COM and axes in the flange frame, c_rel = R_f^T r, R_rel = R_f^T R_p
        rx = x_p[0] - ws[b + WS_O]
        ry = x_p[1] - ws[b + WS_O + 1]
        rz = x_p[2] - ws[b + WS_O + 2]
        for k in range(3):
            grasp[_G_COM + k] = (ws[b + WS_R + k] * rx + ws[b + WS_R + 3 + k] * ry
                                 + ws[b + WS_R + 6 + k] * rz)
            for c in range(3):
                grasp[_G_ROT + 3 * k + c] = (ws[b + WS_R + k] * Rp[c]
                                             + ws[b + WS_R + 3 + k] * Rp[3 + c]
                                             + ws[b + WS_R + 6 + k] * Rp[6 + c])
        # payload momentum: p = m v_p, L = R_p (I_p w_b) (about its COM)
        px, py, pz = payload_mass * v_p[0], payload_mass * v_p[1], payload_mass * v_p[2]
        hb0 = payload_inertia[0] * w_b[0]
        hb1 = payload_inertia[1] * w_b[1]
        hb2 = payload_inertia[2] * w_b[2]
        Lx = Rp[0] * hb0 + Rp[1] * hb1 + Rp[2] * hb2
        Ly = Rp[3] * hb0 + Rp[4] * hb1 + Rp[5] * hb2
        Lz = Rp[6] * hb0 + Rp[7] * hb1 + Rp[8] * hb2
        for i in range(n):
            acc = 0.0
            for j in range(n):
                acc += M[i, j] * qd[j]
            # J_c column i: [J_v,i + J_w,i x r; J_w,i]
            wx, wy, wz = Jw[3 * n + i], Jw[4 * n + i], Jw[5 * n + i]
            cvx = Jw[i] + wy * rz - wz * ry
            cvy = Jw[n + i] + wz * rx - wx * rz
            cvz = Jw[2 * n + i] + wx * ry - wy * rx
            v1[i] = acc + cvx * px + cvy * py + cvz * pz + wx * Lx + wy * Ly + wz * Lz
        attached[0] = 1.0
        link_table(P, attached, grasp, payload_mass, payload_inertia, PP)
        mass_matrix(q, PP, ws, M2, tmp, bw)
        cholesky_solve(M2, v1, qd)


def _bind():
    from ..multibody import kernels as K
    return K.forward_dynamics, K.mass_matrix, K.cholesky_solve, K.impact_projection


forward_dynamics, mass_matrix, cholesky_solve, impact_projection = _bind()


def _bind_body():
    from ..multibody import rigid_body as B
    return B.quat_to_rot, B.rot_to_quat, B.free_body_rates, B.merge_into_link


quat_to_rot, rot_to_quat, free_body_rates, merge_into_link = _bind_body()


def _link_table(P, attached, grasp, mass, inertia, PP):
    """The link table in use: ``P``, with the payload merged into the last row while
    attached (at its grasp: COM and axes in the flange frame)."""
    n = P.shape[0]
    for i in range(n - 1):
        for k in range(16):
            PP[i, k] = P[i, k]
    if attached[0] > 0.5:
        merge_into_link(P[n - 1], mass, grasp[_G_COM:_G_COM + 3], inertia,
                        grasp[_G_ROT:_G_ROT + 9], PP[n - 1])
    else:
        for k in range(16):
            PP[n - 1, k] = P[n - 1, k]


def _payload_on_flange(ws, n, twist, grasp, pos, rot, V):
    """Pose and twist of the attached payload from the flange's (after ``fk`` in ``ws``):
    ``x_p = o_n + R_n c_rel``, ``R_p = R_n R_rel``, ``v_p = v_n + w_n x r``, ``w = w_n``."""
    b = n * _WS
    for r in range(3):
        acc = ws[b + WS_O + r]
        for k in range(3):
            acc += ws[b + WS_R + 3 * r + k] * grasp[_G_COM + k]
        pos[r] = acc
        for c in range(3):
            acc = 0.0
            for k in range(3):
                acc += ws[b + WS_R + 3 * r + k] * grasp[_G_ROT + 3 * k + c]
            rot[3 * r + c] = acc
    rx = pos[0] - ws[b + WS_O]
    ry = pos[1] - ws[b + WS_O + 1]
    rz = pos[2] - ws[b + WS_O + 2]
    wx, wy, wz = twist[3], twist[4], twist[5]
    V[0] = twist[0] + wy * rz - wz * ry
    V[1] = twist[1] + wz * rx - wx * rz
    V[2] = twist[2] + wx * ry - wy * rx
    V[3], V[4], V[5] = wx, wy, wz


link_table = jit_kernel(_link_table)
payload_on_flange = jit_kernel(_payload_on_flange)


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
        "model": Param("spider", kind="str", file=True, doc="arm data ('spider' or a path)"),
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

    derives = ("P", "p0", "R0", "u")

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
    parameters = {"model": Param("spider", kind="str", file=True,
                                 doc="arm data ('spider' or a path)")}
    inputs = {"q": Port("rad", size=_N, doc="joint angles")}
    outputs = {"pos": Port("m", size=3, feedthrough=("q",), doc="flange origin"),
               "rot": Port("1", size=9, feedthrough=("q",), doc="flange rotation, row-major")}
    scratch = {"ws": _ws_dim()}

    derives = ("P",)

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
    parameters = {"model": Param("spider", kind="str", file=True,
                                 doc="arm data ('spider' or a path)")}
    inputs = {"q": Port("rad", size=_N, doc="joint angles")}
    outputs = {"J": Port("1", size=Dim("6 n", lambda p: 6 * _n(p)), feedthrough=("q",),
                         doc="Jacobian, row-major 6 x n")}
    scratch = {"ws": _ws_dim()}

    derives = ("P",)

    @classmethod
    def derive(cls, params):
        return {"P": _chain(params["model"]).P}

    @staticmethod
    def output(t, q, P, ws, J):
        fk(q, P, ws)
        flange_jacobian(q.size, ws, J)
