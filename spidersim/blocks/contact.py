"""Contact of a point (the end effector, a mass) with a flat surface.

The surface is the plane through ``point`` with unit ``normal`` pointing out of the surface,
into free space. The signed distance of the contact point ``p`` is the *gap*
``phi = n . (p - point)``; the *penetration* is ``delta = -phi``. Forces are those the
surface applies to the body: positive along ``n`` (pushing out), never pulling.

Two models, as in the paper:

* :class:`ElasticContact`: an elasto-viscous surface, ``F_n = K delta + D d(delta)/dt``
  while in contact, the surface itself optionally a mass-spring-damper; onset and release
  are events, so no step straddles them.
* :class:`RigidContact`: a perfectly stiff surface, a kinematic constraint closed as an
  algebraic loop at acceleration level (the unknown is the constraint force ``lam``), with
  a plastic impact at onset (applied by the body block through its ``constraint`` input)
  and release when ``lam`` changes sign.

Outputs for the bodies: ``force`` (3, base frame) for a point mass, ``wrench`` (6: force,
zero moment about the contact point) for the ``f_ext`` input of an :class:`Arm` whose flange
is the contact point.
"""
import math

from ..multibody.kernels import relative_rotation
from .base import Block, Dim, Event, Mode, Param, Port, State, unit_vector


class _Plane(Block, abstract=True):
    """The surface both contact models share: a plane through ``point`` with outward
    ``normal`` (normalised into the derived parameter ``n``)."""

    plane = {
        "point": Param([0.0, 0.0, 0.0], "m", "a point of the surface (base frame)", shape=3),
        "normal": Param([0.0, 0.0, 1.0], "1", "outward normal of the surface (normalised)",
                        shape=3),
    }

    @classmethod
    def check(cls, params):
        unit_vector(params["normal"], "normal")

    @classmethod
    def derive(cls, params):
        return {"n": unit_vector(params["normal"], "normal")}


class ElasticContact(_Plane):
    """Elasto-viscous flat surface (see the module docstring)::

        delta = -(n . (p - point) - w)            penetration [m] (w: surface displacement)
        F_n   = K delta + D d(delta)/dt           while in contact, >= 0
        F_t   = -mu F_n v_t / sqrt(|v_t|^2 + v_eps^2)   (tangential, optional)
        m_s dw'/dt = -K_s w - D_s w' - F_n        (second-order surface, optional)

    ``w`` is the displacement of the surface face along ``n`` (negative: pushed in). Contact
    starts when the penetration and the force ``K delta + D d(delta)/dt`` are both positive
    (event ``onset``: from outside, when ``delta`` becomes positive; a released body still
    inside the surface when the force turns positive again) and ends when the normal force
    would become a pull (event ``release``: with ``D = 0`` at ``delta = 0``, with damping
    slightly before). A body that starts inside the surface, pushed out by it, is in
    contact from the start.

    ``energy`` is the elastic energy stored in the contact (and surface) springs, ``K
    delta^2 / 2 + K_s w^2 / 2`` [J]: its peak is the energy absorbed at an impact.
    """

    category = "contact"
    parameters = {
        **_Plane.plane,
        "K": Param(1e5, "N/m", "contact stiffness", gt=0.0),
        "D": Param(0.0, "N.s/m", "contact damping", ge=0.0),
        "mu": Param(0.0, "1", "tangential (Coulomb) friction coefficient; 0: none", ge=0.0),
        "v_eps": Param(1e-3, "m/s", "tangential speed of the friction regularisation",
                       gt=0.0),
        "surface": Param(False, kind="bool",
                         doc="the surface is a mass-spring-damper (m_s, K_s, D_s)"),
        "m_s": Param(10.0, "kg", "surface mass (second-order surface)", gt=0.0),
        "K_s": Param(1e5, "N/m", "surface suspension stiffness", gt=0.0),
        "D_s": Param(0.0, "N.s/m", "surface suspension damping", ge=0.0),
    }
    inputs = {"pos": Port("m", size=3, doc="position of the contact point (base frame)"),
              "vel": Port("m/s", size=3, doc="velocity of the contact point")}
    outputs = {
        "force": Port("N", size=3, feedthrough=("pos", "vel"),
                      doc="force of the surface on the body"),
        "wrench": Port("*", size=6, feedthrough=("pos", "vel"),
                       doc="force [N] and moment [N.m] (zero) on the body, for Arm.f_ext"),
        "fn": Port("N", feedthrough=("pos", "vel"), doc="normal force (>= 0)"),
        "delta": Port("m", feedthrough=("pos",), doc="penetration (negative: the gap)"),
        "energy": Port("J", feedthrough=("pos",), doc="elastic energy stored"),
    }
    states = {"w": State("m", doc="surface displacement along the normal"),
              "wd": State("m/s", doc="surface velocity")}
    modes = {"engaged": Mode(doc="1 while in contact"),
             "t_off": Mode(initial=-math.inf, doc="time of the last release")}
    events = {"onset": Event(1, "penetrating and pushing: min(K delta, F_n) rises through 0"),
              "release": Event(-1, "the normal force would pull")}


    @staticmethod
    def output(t, pos, vel, w, wd, n, point, K, D, mu, v_eps, K_s, surface, engaged,
               force, wrench, fn, delta, energy):
        d = w[0]                               # face at point + w n
        dd = wd[0]
        for k in range(3):
            d -= n[k] * (pos[k] - point[k])
            dd -= n[k] * vel[k]
        delta[0] = d
        f = 0.0
        if engaged[0] > 0.5:
            f = K * d + D * dd
            if f < 0.0:                        # between the crossing and its event
                f = 0.0
        fn[0] = f
        e = 0.5 * K * d * d if d > 0.0 and engaged[0] > 0.5 else 0.0
        if surface:
            e += 0.5 * K_s * w[0] * w[0]
        energy[0] = e
        vn = 0.0
        for k in range(3):
            vn += n[k] * vel[k]
        vt2 = 0.0
        for k in range(3):
            vt = vel[k] - vn * n[k]
            vt2 += vt * vt
        scale = mu * f / math.sqrt(vt2 + v_eps * v_eps)
        for k in range(3):
            force[k] = f * n[k] - scale * (vel[k] - vn * n[k])
            wrench[k] = force[k]
            wrench[3 + k] = 0.0

    @staticmethod
    def derivative(t, w, wd, fn, m_s, K_s, D_s, surface, der_w, der_wd):
        if surface:
            der_w[0] = wd[0]
            der_wd[0] = (-K_s * w[0] - D_s * wd[0] - fn[0]) / m_s
        else:
            der_w[0] = 0.0
            der_wd[0] = 0.0

    @staticmethod
    def guard(t, pos, vel, w, wd, n, point, K, D, engaged, delta, zc):
        d = delta[0]
        dd = wd[0]
        for k in range(3):
            dd -= n[k] * vel[k]
        push = K * d + D * dd
        if engaged[0] > 0.5:
            zc[0] = -1.0
            zc[1] = push
        else:
            zc[0] = min(K * d, push)           # both positive: in contact
            zc[1] = 1.0

    @staticmethod
    def on_event(t, which, direction, engaged, t_off):
        if which == 0:
            engaged[0] = 1.0
        else:
            engaged[0] = 0.0
            t_off[0] = t

    @staticmethod
    def initialize(t, vel, wd, n, K, D, delta, engaged, t_off):
        # a body already inside the surface and pushed out by it (at the start, or after
        # another block's event) is in contact: the onset guard cannot see a crossing
        # that happened before. Not at a release instant, where the force has just
        # reached zero.
        if engaged[0] < 0.5 and t != t_off[0] and delta[0] > 0.0:
            dd = wd[0]
            for k in range(3):
                dd -= n[k] * vel[k]
            if K * delta[0] + D * dd > 0.0:
                engaged[0] = 1.0


class RigidContact(_Plane):
    """Perfectly stiff flat surface: a kinematic constraint on the contact point, closed as
    an algebraic loop at acceleration level (Baumgarte stabilisation)::

        phi = n . (p - point)                                gap [m]
        r(lam) = n . a(lam) + 2 zeta omega n . v + omega^2 phi = 0     while engaged
        r(lam) = lam                                          free (lam = 0)
        force on the body = lam n,  lam >= 0

    ``a`` is the body's acceleration, which depends directly on the force (wire the body's
    acceleration output, e.g. ``Arm.flange_acc`` or ``PointMass.acc``, into ``acc`` and
    ``wrench``/``force`` back into the body): the engine closes the loop and solves for
    ``lam`` by Newton (``r`` is affine in ``lam``, one or two iterations).

    Onset (event): the gap falls through zero; the ``constraint`` output ``[engaged, n]``
    rises and the body block applies the plastic impact that removes the normal velocity
    (for an arm ``qd+ = qd- - M^-1 J_n^T (J_n M^-1 J_n^T)^-1 J_n qd-``). Release (event):
    ``lam`` falls through zero, the body is pulled away; if the applied forces already pull
    at the onset instant (after the impact) the constraint lets go at once. ``engaged``
    starts the run in contact (the contact point on the plane, at rest along the normal);
    if the applied forces pull at the start, it lets go there.
    """

    category = "contact"
    parameters = {
        **_Plane.plane,
        "zeta": Param(1.0, "1", "Baumgarte damping ratio", gt=0.0),
        "omega": Param(100.0, "rad/s", "Baumgarte natural frequency", gt=0.0),
        "engaged": Param(False, kind="bool", doc="in contact from the start (the point "
                         "must be on the plane at t = 0: not checked)"),
        "lam0": Param(0.0, "N", "initial guess of the constraint force"),
    }
    inputs = {"pos": Port("m", size=3, doc="position of the contact point (base frame)"),
              "vel": Port("m/s", size=3, doc="velocity of the contact point"),
              "acc": Port("m/s2", size=3, doc="acceleration of the contact point "
                                              "(depends directly on the force)")}
    outputs = {
        "lam": Port("N", feedthrough=("pos", "vel", "acc"),
                    doc="constraint (normal) force, the loop's unknown (solved from them)"),
        "residual": Port("m/s2", feedthrough=("pos", "vel", "acc", "lam"),
                         doc="constraint residual at acceleration level"),
        "force": Port("N", size=3, feedthrough=("lam",), doc="force on the body, lam n"),
        "wrench": Port("*", size=6, feedthrough=("lam",),
                       doc="force [N] and moment [N.m] (zero) on the body, for Arm.f_ext"),
        "gap": Port("m", feedthrough=("pos",), doc="signed distance to the surface"),
        "constraint": Port("*", size=4, doc="[engaged, n_x, n_y, n_z] for the body's impact"),
    }
    modes = {"active": Mode(initial=lambda p: 1.0 if p["engaged"] else 0.0,
                            doc="1 while the constraint is engaged"),
             "t_on": Mode(initial=lambda p: 0.0 if p["engaged"] else -math.inf,
                          doc="time of the last onset (the start when engaged)"),
             "gap_off": Mode(doc="onset level after a release: min(gap at release, 0) - 1 nm "
                                 "(0 before any release)")}
    events = {"onset": Event(-1, "the gap falls through the onset level (zero, or just below "
                                 "where a release left the point): impact, engaged"),
              "release": Event(-1, "the constraint force falls through zero")}
    #: output -> (residual, initial guess)
    implicit = {"lam": ("residual", "lam0")}


    @staticmethod
    def output(t, pos, vel, acc, lam, n, point, zeta, omega, active, residual, force,
               wrench, gap, constraint):
        phi = 0.0
        vn = 0.0
        an = 0.0
        for k in range(3):
            phi += n[k] * (pos[k] - point[k])
            vn += n[k] * vel[k]
            an += n[k] * acc[k]
        gap[0] = phi
        on = active[0] > 0.5
        residual[0] = an + 2.0 * zeta * omega * vn + omega * omega * phi if on else lam[0]
        constraint[0] = 1.0 if on else 0.0
        for k in range(3):
            force[k] = lam[0] * n[k]
            wrench[k] = force[k]
            wrench[3 + k] = 0.0
            constraint[1 + k] = n[k]

    @staticmethod
    def guard(t, gap, lam, active, gap_off, zc):
        if active[0] > 0.5:
            zc[0] = 1.0
            zc[1] = lam[0]
        else:
            zc[0] = gap[0] - gap_off[0]
            zc[1] = 1.0

    @staticmethod
    def on_event(t, which, direction, gap, active, t_on, gap_off):
        if which == 0:
            active[0] = 1.0
            t_on[0] = t
        else:
            # released where the constraint held the point: at zero gap, or a Baumgarte
            # round-off below. The onset level sits just below that point, so that a body
            # the applied forces push back in (a force set point that pulls for an instant,
            # a force loop's noise at zero force) is caught again by an impact instead of
            # sinking through the surface.
            active[0] = 0.0
            gap_off[0] = min(gap[0], 0.0) - 1e-9

    @staticmethod
    def initialize(t, lam, active, t_on):
        # a constraint that would pull at its onset lets go at once: right after the
        # impact, or at the start of a run that begins ``engaged`` (the release guard sees
        # no crossing at the instant its block fired or the run began). Later the release
        # is the event ``release``.
        if active[0] > 0.5 and lam[0] < 0.0 and t == t_on[0]:
            active[0] = 0.0


_DIRS = ("x", "y", "z", "rx", "ry", "rz")


def rpy_matrix(rpy):
    """``R = Rz(yaw) Ry(pitch) Rx(roll)`` for ``rpy = [roll, pitch, yaw]`` [rad]: the
    columns of ``R`` are the axes of the rotated frame in the base frame."""
    import numpy as np
    r, p, y = (float(v) for v in rpy)
    cr, sr, cp, sp, cy, sy = (math.cos(r), math.sin(r), math.cos(p), math.sin(p),
                              math.cos(y), math.sin(y))
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def _flags(v, name):
    """A 6-entry 0/1 selection as booleans; ValueError naming the parameter otherwise."""
    out = []
    for k, x in enumerate(v):
        if x not in (0.0, 1.0):
            raise ValueError(f"{name}[{k}] ({_DIRS[k]}) must be 0 or 1, got {x:g}")
        out.append(x == 1.0)
    return out


class RigidContact6(Block):
    """Rigid constraint between the flange frame and a fixed contact frame, on any subset
    of the six directions (3 translations, 3 rotations, given in the contact frame), closed
    as an algebraic loop at acceleration level (Baumgarte) like :class:`RigidContact`.

    Contact frame: origin ``origin`` [m] and axes ``R_c = Rz(yaw) Ry(pitch) Rx(roll)``
    (``rpy = [roll, pitch, yaw]`` [rad]; column k of ``R_c`` is contact axis k in the base
    frame). Direction k of ``select`` (order ``x, y, z, rx, ry, rz``) is constrained when
    1. The pose of the flange (origin ``p``, rotation ``R_f``, base frame) in the contact
    frame, output ``error``::

        e_t = R_c^T (p - origin)                         translation [m]
        R_e = R_c^T R_f,  e_r = vee(R_e - R_e^T) / 2     rotation [rad]
        (e_r,x = (R_e[2,1] - R_e[1,2]) / 2, ...: the rotation vector for small angles)

    Velocities and accelerations in contact axes: ``v_c = R_c^T v``, ``w_c = R_c^T w``,
    ``a_c = R_c^T a``, ``alpha_c = R_c^T alpha`` (from ``Arm.flange_twist``, ``flange_acc``,
    ``flange_alpha``). The position-level violation ``d`` (output ``drift``, 0 in free
    directions) and the residual of each engaged direction::

        d_t,k = e_t,k - h_k                    (h_k: held value, 0 for a unilateral one)
        d_r   = vee(E - E^T) / 2,  E = R_e R_h^T     (R_h: held orientation)
        r_k = du_k + 2 zeta omega u_k + omega^2 d_k    while engaged
        r_k = lam_k                                   free or released

    (``u_k``, ``du_k``: component k of ``[v_c; w_c]``, ``[a_c; alpha_c]``); the engine
    solves ``r(lam) = 0`` by Newton (``r`` is affine in ``lam``). ``lam_k`` is the force [N]
    along (k < 3) or the moment [N.m] about (k >= 3) contact axis k that the environment
    applies to the flange; ``wrench = [R_c lam_t; R_c lam_r]`` (moment about the flange
    origin, base frame) is what ``Arm.f_ext`` expects. ``d_r`` vanishes exactly when the
    flange has turned from ``R_h`` about the free rotation axes only (``E = Rz(theta)``
    with rz free); near it, the position feedback of rx, ry is scaled by ``cos(theta / 2)``
    and rotated by ``theta / 2`` about the free axis: full for small turns, vanishing at a
    half turn, where only the velocity-level terms hold those rows.

    Unilateral directions (``unilateral`` 1: translations only, a subset of ``select``):
    the free side is ``e_t,k > 0`` (contact axis k is the outward normal of a surface
    through ``origin``), ``lam_k >= 0`` pushes. Onset (event): ``e_t,k`` falls through zero;
    release (event): ``lam_k`` falls through zero; each unilateral direction on its own. If
    the applied forces already pull at the onset instant (after the impact), that direction
    lets go at once; with ``engaged``, one that starts with a gap (``e_t,k > 1 nm``) waits for
    its onset. Bilateral directions never release: they engage at the start
    (``engaged``) holding the contact frame (``h = 0``, ``R_h = I``: start the flange on
    it), or with the first unilateral onset holding the pose of that instant (``h_k =
    e_t,k``, ``R_h = R_e``: a fixture that latches where it is touched).

    ``constraint = [engaged per direction (6), R_c row-major (9)]`` goes to
    ``Arm.constraint6``: when a direction engages the arm applies the plastic impact
    ``qd+ = qd- - M^-1 J_c^T (J_c M^-1 J_c^T)^-1 J_c qd-`` over every engaged direction
    (``J_c``: those rows of the flange Jacobian in contact axes).
    """

    category = "contact"
    parameters = {
        "origin": Param([0.0, 0.0, 0.0], "m", "origin of the contact frame (base frame)",
                        shape=3),
        "rpy": Param([0.0, 0.0, 0.0], "rad", "roll, pitch, yaw of the contact frame: "
                                             "R_c = Rz(yaw) Ry(pitch) Rx(roll)", shape=3),
        "select": Param([0.0, 0.0, 1.0, 0.0, 0.0, 0.0], "1",
                        "constrained directions x, y, z, rx, ry, rz in the contact frame "
                        "(1: constrained, 0: free)", shape=6),
        "unilateral": Param([0.0, 0.0, 1.0, 0.0, 0.0, 0.0], "1",
                            "translations x, y, z that can release (1; constrained ones), "
                            "the others bilateral; rx, ry, rz entries must be 0", shape=6),
        "zeta": Param(1.0, "1", "Baumgarte damping ratio", gt=0.0),
        "omega": Param(100.0, "rad/s", "Baumgarte natural frequency", gt=0.0),
        "engaged": Param(False, kind="bool", doc="every selected direction engaged from "
                                                 "the start (the flange must be on the "
                                                 "frame at t = 0: not checked)"),
        "lam0": Param(0.0, "*", "initial guess of the multipliers (1 or 6 values)",
                      shape="*"),
    }
    inputs = {"pos": Port("m", size=3, doc="flange origin (base frame), Arm.flange_pos"),
              "rot": Port("1", size=9, doc="flange rotation, row-major, Arm.flange_rot"),
              "twist": Port("*", size=6, doc="flange velocity [m/s] and angular velocity "
                                             "[rad/s], Arm.flange_twist"),
              "acc": Port("m/s2", size=3, doc="flange origin acceleration, Arm.flange_acc "
                                              "(depends directly on the wrench)"),
              "alpha": Port("rad/s2", size=3, doc="flange angular acceleration, "
                                                  "Arm.flange_alpha")}
    outputs = {
        "lam": Port("*", size=6, feedthrough=("pos", "rot", "twist", "acc", "alpha"),
                    doc="multipliers: force [N] along, moment [N.m] about the contact axes, "
                        "the loop's unknowns"),
        "residual": Port("*", size=6, feedthrough=("pos", "rot", "twist", "acc", "alpha",
                                                   "lam"),
                         doc="constraint residuals at acceleration level"),
        "wrench": Port("*", size=6, feedthrough=("lam",),
                       doc="force [N] and moment about the flange origin [N.m] on the "
                           "flange, base frame, for Arm.f_ext"),
        "error": Port("*", size=6, feedthrough=("pos", "rot"),
                      doc="flange pose in the contact frame: e_t [m], e_r [rad]"),
        "drift": Port("*", size=6, feedthrough=("pos", "rot"),
                      doc="position-level violation of the engaged directions [m, rad] "
                          "(0 in free ones)"),
        "constraint": Port("*", size=15, doc="[engaged (6), R_c (9)] for Arm.constraint6"),
    }
    modes = {"active": Mode(size=6, initial=lambda p: [
                 1.0 if p["engaged"] and s == 1.0 else 0.0 for s in p["select"]],
                 doc="1 while direction k is engaged"),
             "t_on": Mode(size=6, initial=lambda p: 0.0 if p["engaged"] else -math.inf,
                          doc="time of the last onset of direction k"),
             "hold": Mode(size=3, doc="translation h a bilateral direction holds [m]"),
             "R_hold": Mode(size=9, initial=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                            doc="orientation R_h the rotation rows hold (row-major)"),
             "fresh": Mode(initial=1.0, doc="1 until the start has been initialised"),
             "gap_off": Mode(size=3, doc="onset level after a release: min(e_t,k at "
                                         "release, 0) - 1 nm (0 before any release)")}
    events = {"onset": Event(-1, "a unilateral translation falls through its onset level: "
                                 "impact, engaged (with the bilateral directions)", size=3),
              "release": Event(-1, "a unilateral direction's multiplier falls through zero",
                               size=3)}
    implicit = {"lam": ("residual", "lam0")}
    scratch = {"Re": Dim("9", lambda p: 9)}

    @classmethod
    def check(cls, params):
        sel = _flags(params["select"], "select")
        uni = _flags(params["unilateral"], "unilateral")
        if not any(sel):
            raise ValueError("select constrains no direction (give at least one 1 among "
                             "x, y, z, rx, ry, rz)")
        for k in range(6):
            if uni[k] and k >= 3:
                raise ValueError(f"unilateral[{k}] ({_DIRS[k]}) is 1: only translations "
                                 f"(x, y, z) can be unilateral")
            if uni[k] and not sel[k]:
                raise ValueError(f"unilateral[{k}] ({_DIRS[k]}) is 1 but select[{k}] is 0: "
                                 f"only a constrained direction can be unilateral")
        if not params["engaged"] and not any(uni):
            raise ValueError("only bilateral directions and engaged: false: the constraint "
                             "would never engage (set engaged: true, or make a direction "
                             "unilateral)")
        if len(params["lam0"]) not in (1, 6):
            raise ValueError(f"lam0 must have 1 or 6 entries, got {len(params['lam0'])}")

    @classmethod
    def derive(cls, params):
        return {"Rc": rpy_matrix(params["rpy"]).ravel()}

    @staticmethod
    def output(t, pos, rot, twist, acc, alpha, lam, origin, Rc, select, zeta, omega,
               active, hold, R_hold, Re, residual, wrench, error, drift, constraint):
        relative_rotation(Rc, rot, Re)                  # R_e = R_c^T R_f
        for k in range(3):
            et = 0.0
            u = 0.0
            du = 0.0
            w = 0.0
            dw = 0.0
            for r in range(3):
                c = Rc[3 * r + k]                        # column k of R_c
                et += c * (pos[r] - origin[r])
                u += c * twist[r]
                du += c * acc[r]
                w += c * twist[3 + r]
                dw += c * alpha[r]
            error[k] = et
            drift[k] = et - hold[k]
            residual[k] = du + 2.0 * zeta * omega * u
            residual[3 + k] = dw + 2.0 * zeta * omega * w
        for k in range(3):
            i = (k + 1) % 3
            j = (k + 2) % 3
            error[3 + k] = 0.5 * (Re[3 * j + i] - Re[3 * i + j])
            eij = 0.0                                    # E = R_e R_h^T
            eji = 0.0
            for m in range(3):
                eij += Re[3 * i + m] * R_hold[3 * j + m]
                eji += Re[3 * j + m] * R_hold[3 * i + m]
            drift[3 + k] = 0.5 * (eji - eij)
        for k in range(6):
            on = select[k] > 0.5 and active[k] > 0.5
            if on:
                residual[k] += omega * omega * drift[k]
            else:
                residual[k] = lam[k]
                drift[k] = 0.0
            constraint[k] = 1.0 if on else 0.0
        for r in range(3):
            f = 0.0
            m = 0.0
            for k in range(3):
                f += Rc[3 * r + k] * lam[k]
                m += Rc[3 * r + k] * lam[3 + k]
            wrench[r] = f
            wrench[3 + r] = m
        for k in range(9):
            constraint[6 + k] = Rc[k]

    @staticmethod
    def guard(t, error, lam, unilateral, active, gap_off, zc):
        for k in range(3):
            if unilateral[k] > 0.5 and active[k] < 0.5:
                zc[k] = error[k] - gap_off[k]
            else:
                zc[k] = 1.0
            if unilateral[k] > 0.5 and active[k] > 0.5:
                zc[3 + k] = lam[k]
            else:
                zc[3 + k] = 1.0

    @staticmethod
    def on_event(t, which, direction, rot, error, Rc, select, unilateral, active, t_on,
                 hold, R_hold, gap_off, Re):
        if which < 3:
            first = True                                 # bilateral directions not held yet
            for k in range(6):
                if select[k] > 0.5 and unilateral[k] < 0.5 and active[k] > 0.5:
                    first = False
            active[which] = 1.0
            t_on[which] = t
            if first:
                relative_rotation(Rc, rot, Re)
                for k in range(9):
                    R_hold[k] = Re[k]
                for k in range(6):
                    if select[k] > 0.5 and unilateral[k] < 0.5:
                        active[k] = 1.0
                        t_on[k] = t
                        if k < 3:
                            hold[k] = error[k]
        else:
            # as RigidContact: the onset level sits just below where the constraint let go
            k = which - 3
            active[k] = 0.0
            gap_off[k] = min(error[k], 0.0) - 1e-9

    @staticmethod
    def initialize(t, lam, error, unilateral, active, t_on, fresh):
        # a unilateral direction that would pull at its onset (right after the impact, or
        # at the start of a run that begins engaged) lets go at once; at the start, one
        # with a gap (e_t,k > 1 nm) waits for its onset
        for k in range(3):
            if unilateral[k] > 0.5 and active[k] > 0.5 and t == t_on[k] and (
                    lam[k] < 0.0 or (fresh[0] > 0.5 and error[k] > 1e-9)):
                active[k] = 0.0
        fresh[0] = 0.0

