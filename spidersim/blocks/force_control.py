"""Hybrid position/force control in operational space (Raibert & Craig 1981; Khatib 1987).

A selection matrix ``S = diag(s)`` (``s_i = 1``: direction ``i`` of the task space is
position-controlled, ``0``: force-controlled; base-frame axes, translations then rotations)
splits the task. With the flange Jacobian ``J`` (6 x n), ``M(q)`` the joint-space inertia
and ``Lambda = (J M^-1 J^T)^-1`` the operational-space inertia::

    e   = [p_ref - p;  e_R]                 e_R = 1/2 sum_i r_i x r_ref,i  (orientation)
    a_m = S (Kp e - Kd J qd)                desired task acceleration (position part)
    e_F = (I - S_t)(F_ref - F_meas)         force error (translations)
    F_f = (I - S_t)(ff F_ref + kp_f e_F + ki_f xi),   d xi/dt = e_F
    tau = J^T (Lambda a_m + F_f) + N^T tau_0 + g(q)
    N^T = I - J^T Lambda J M^-1,  tau_0 = -k_null qd      (null-space damping, 7th DOF)

``F_ref`` and ``F_meas`` are the force the end effector applies to the environment (a
:class:`~spidersim.blocks.sensors.WrenchSensor` reading, base frame). Against a rigid
surface whose normal is a force-controlled axis, the contact force equals ``F_f`` plus
velocity terms, so with ``ff = 0`` and a sensor of bandwidth ``f_c`` the force loop is
``tau_s F'' + (1 + kp_f) F' + ki_f F = ki_f F_ref + kp_f F_ref'`` (``tau_s = 1/(2 pi f_c)``).
``g(q)`` compensates the gravity ``gravity`` (zero in orbit).

Near a singular pose ``A = J M^-1 J^T`` loses rank and ``Lambda`` grows without bound.
``damping`` scales the diagonal of ``A`` by ``1 + damping`` (damped least squares in the
task's own units: e.g. 1e-3 trades accuracy for moderate torques near singularities; the
default 0 is the exact law). At a pose where ``A`` is singular to working precision the
factorisation falls back to adding ``1e-6 tr(A) / 6`` to its diagonal, so the torques stay
finite.
"""
import numpy as np

from ..multibody.kernels import WS_O
from .arm import _N, _WS, _chain, _n, _ws_dim
from .base import Block, Dim, Param, Port, State


class HybridForceController(Block):
    """Operational-space hybrid position/force controller (see the module docstring)."""

    category = "control"
    parameters = {
        "model": Param("spider", kind="str", file=True, doc="arm data ('spider' or a path)"),
        "q0": Param(0.0, "rad", "pose whose flange orientation is held", shape=_N),
        "selection": Param([1.0, 1.0, 0.0, 1.0, 1.0, 1.0], "1",
                           "1: position-controlled, 0: force-controlled (x y z; the "
                           "rotations rx ry rz are position-controlled: 1)",
                           shape=6),
        "Kp": Param(400.0, "1/s2", "position stiffness per unit task inertia", shape=6,
                    ge=0.0),
        "Kd": Param(40.0, "1/s", "task damping per unit task inertia", shape=6, ge=0.0),
        "ff": Param(0.0, "1", "force set-point feed-forward (0 or 1)", ge=0.0),
        "kp_f": Param(0.0, "1", "force proportional gain", ge=0.0),
        "ki_f": Param(50.0, "1/s", "force integral gain", ge=0.0),
        "k_null": Param(5.0, "N.m.s/rad", "null-space joint damping", ge=0.0),
        "gravity": Param([0.0, 0.0, 0.0], "m/s2", "gravity to compensate", shape=3),
        "damping": Param(0.0, "1", "damped inverse near singular poses: "
                         "Lambda = (A + damping diag(A))^-1, A = J M^-1 J^T", ge=0.0),
    }
    inputs = {"q": Port("rad", size=_N, doc="joint angles"),
              "qd": Port("rad/s", size=_N, doc="joint speeds"),
              "p_ref": Port("m", size=3, doc="flange position reference (base frame)"),
              "F_ref": Port("N", size=3, doc="force set point on the environment"),
              "F_meas": Port("*", size=6, doc="measured wrench on the environment")}
    outputs = {"tau": Port("N.m", size=_N, feedthrough=("q", "qd", "p_ref", "F_ref",
                                                         "F_meas"),
                           doc="joint torques"),
               "e_F": Port("N", size=3, feedthrough=("F_ref", "F_meas"),
                           doc="force error (force-controlled directions)")}
    states = {"xi": State("N.s", size=3, doc="integral of the force error")}
    scratch = {"ws": _ws_dim(),
               "Mw": Dim("n^2", lambda p: _n(p) ** 2),
               "tmp": Dim("6 n", lambda p: 6 * _n(p)), "bw": Dim("6", lambda p: 6),
               "Jw": Dim("6 n", lambda p: 6 * _n(p)), "Yw": Dim("6 n", lambda p: 6 * _n(p)),
               "A6": Dim("36", lambda p: 36), "v6": Dim("6", lambda p: 6),
               "y6": Dim("6", lambda p: 6), "vn": Dim("2 n", lambda p: 2 * _n(p))}

    @classmethod
    def check(cls, params):
        s = np.asarray(params["selection"])
        if not np.all((s == 0.0) | (s == 1.0)):
            raise ValueError(f"selection must hold 0 (force) or 1 (position) per task "
                             f"direction, got {s.tolist()}")
        if not np.all(s[3:] == 1.0):
            # F_ref, F_meas and the force integral are forces (3 entries): a rotation
            # marked 0 would be neither position- nor moment-controlled, silently
            raise ValueError(f"selection: the rotations (entries 4-6: rx ry rz) must be 1 "
                             f"(position-controlled); this controller regulates forces "
                             f"along x y z only, not moments; got {s.tolist()}")

    derives = ("P", "R0")

    @classmethod
    def derive(cls, params):
        ch = _chain(params["model"])
        T = ch.fk(params["q0"])
        return {"P": ch.P, "R0": T[:3, :3].ravel().copy()}

    @staticmethod
    def output(t, q, qd, p_ref, F_ref, F_meas, xi, P, R0, selection, Kp, Kd, ff, kp_f, ki_f,
               k_null, gravity, damping, ws, Mw, tmp, bw, Jw, Yw, A6, v6, y6, vn, tau, e_F):
        n = q.size
        M = Mw.reshape((n, n))
        A = A6.reshape((6, 6))
        # gravity torque first (rnea leaves the frames of q in ws for the Jacobian)
        zero = vn[:n]
        tg = vn[n:]
        for i in range(n):
            zero[i] = 0.0
        for k in range(6):
            bw[k] = 0.0
        rnea(q, zero, zero, gravity, bw, P, ws, tg, bw)
        flange_jacobian(n, ws, Jw)
        b = n * _WS
        # task errors and velocity
        for k in range(3):
            v6[k] = p_ref[k] - ws[b + WS_O + k]
        orientation_error(ws, n, R0, y6)
        v6[3], v6[4], v6[5] = y6[0], y6[1], y6[2]
        for r in range(6):
            vel = 0.0
            for i in range(n):
                vel += Jw[r * n + i] * qd[i]
            v6[r] = selection[r] * (Kp[r] * v6[r] - Kd[r] * vel)       # a_m
        # Y = M^-1 J^T (n x 6), A = J Y = Lambda^-1
        mass_matrix(q, P, ws, M, tmp, bw)
        cholesky_factor(M)
        col = tmp[:n]
        sol = tmp[n:2 * n]
        for r in range(6):
            for i in range(n):
                col[i] = Jw[r * n + i]
            cholesky_subst(M, col, sol)
            for i in range(n):
                Yw[i * 6 + r] = sol[i]
        task_inertia_factor(Jw, Yw, n, A, damping, 1e-6)
        cholesky_subst(A, v6, y6)                                     # Lambda a_m
        for k in range(3):
            sel = 1.0 - selection[k]
            e = sel * (F_ref[k] - F_meas[k])
            e_F[k] = e
            y6[k] += sel * (ff * F_ref[k] + kp_f * e + ki_f * xi[k])
        for i in range(n):
            acc = tg[i]
            for r in range(6):
                acc += Jw[r * n + i] * y6[r]
            tau[i] = acc
        # null space: tau_0 - J^T Lambda J M^-1 tau_0
        for i in range(n):
            col[i] = -k_null * qd[i]
        cholesky_subst(M, col, sol)                                   # M^-1 tau_0
        for r in range(6):
            acc = 0.0
            for i in range(n):
                acc += Jw[r * n + i] * sol[i]
            v6[r] = acc
        cholesky_subst(A, v6, y6)
        for i in range(n):
            acc = col[i]
            for r in range(6):
                acc -= Jw[r * n + i] * y6[r]
            tau[i] += acc

    @staticmethod
    def derivative(t, e_F, der_xi):
        for k in range(3):
            der_xi[k] = e_F[k]


def _bind():
    from ..multibody import kernels as K
    return (K.rnea, K.flange_jacobian, K.mass_matrix, K.cholesky_factor, K.cholesky_subst,
            K.orientation_error, K.task_inertia_factor)


(rnea, flange_jacobian, mass_matrix, cholesky_factor, cholesky_subst,
 orientation_error, task_inertia_factor) = _bind()
