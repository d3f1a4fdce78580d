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

from .base import Block, Event, Mode, Param, Port, State, unit_vector


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
        "engaged": Param(False, kind="bool", doc="in contact from the start"),
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
