"""Serial chains of revolute joints: the multibody algorithms as a library.

    from spidersim.multibody import Chain
    arm = Chain.from_yaml()                     # the SPIDER-like arm shipped with spidersim
    arm.gravity = [0, 0, -9.81]
    arm.rnea(q, qd, qdd), arm.mass_matrix(q), arm.forward_dynamics(q, qd, tau)
    arm.base_wrench(q, qd, qdd), arm.fk(q), arm.jacobian(q)

Data files (YAML): ``links`` with standard DH ``d, a, alpha`` and ``mass``, ``com`` (base
frame at q = 0 [m]) and ``inertia`` (principal moments about the COM along the base axes at
q = 0 [kg m^2], or a full 3x3 matrix); optional ``gravity``. See
``spidersim/data/spider_arm.yaml``. The computations are the compiled kernels of
:mod:`spidersim.multibody.kernels` (conventions there).
"""
from __future__ import annotations

import os

import numpy as np

from ..errors import DiagramError
from . import kernels as K

DATA = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "data")
SPIDER = os.path.join(DATA, "spider_arm.yaml")


def _num(v, what, file):
    from ..text.expr import ExprError, evaluate
    try:
        return float(evaluate(v, {})) if isinstance(v, str) else float(v)
    except (ExprError, TypeError, ValueError):
        raise DiagramError(f"{what}: expected a number, got {v!r}", file=file) from None


def dh_transform(q, d, a, alpha):
    ct, st, ca, sa = np.cos(q), np.sin(q), np.cos(alpha), np.sin(alpha)
    return np.array([[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st],
                     [0.0, sa, ca, d], [0.0, 0.0, 0.0, 1.0]])


class Chain:
    """A serial chain; ``P`` is the packed (n x 16) link table of the kernels."""

    def __init__(self, dh, masses, coms_base, inertias_base, gravity=(0, 0, 0), name="chain"):
        dh = np.asarray(dh, dtype=float)
        n = len(dh)
        self.n = n
        self.name = name
        self.gravity = gravity
        P = np.zeros((n, K.ROW))
        T = np.eye(4)
        for i in range(n):
            d, a, alpha = dh[i]
            T = T @ dh_transform(0.0, d, a, alpha)
            R, o = T[:3, :3], T[:3, 3]
            I_b = np.asarray(inertias_base[i], dtype=float)
            I_b = np.diag(I_b) if I_b.ndim == 1 else I_b
            P[i, 0:3] = d, a, alpha
            P[i, 3] = masses[i]
            P[i, 4:7] = R.T @ (np.asarray(coms_base[i], dtype=float) - o)
            P[i, 7:16] = (R.T @ I_b @ R).ravel()
        self.P = P
        self._ws = np.zeros(K.WS_PER_LINK * (n + 1))
        self._M = np.zeros((n, n))
        self._tmp = np.zeros(6 * n)
        self._base = np.zeros(6)

    @property
    def gravity(self):
        """Gravity acceleration in base axes [m/s^2] (a float array of 3)."""
        return self._gravity

    @gravity.setter
    def gravity(self, g):
        g = np.asarray(g, dtype=float).reshape(-1)
        if g.shape != (3,) or not np.all(np.isfinite(g)):
            raise ValueError(f"gravity must be 3 finite numbers [m/s^2], got {g.tolist()}")
        self._gravity = g

    @classmethod
    def from_yaml(cls, path=None):
        """Load a chain data file (default: the SPIDER-like arm)."""
        from ..text.yamlio import read_file
        path = path or SPIDER
        if not os.path.isfile(path):
            raise DiagramError(f"arm data file not found: {path}")
        data = read_file(path)
        links = data.get("links") if isinstance(data, dict) else None
        if not isinstance(links, list) or not links:
            raise DiagramError("an arm data file needs a non-empty 'links' list", file=path)
        dh, m, c, I = [], [], [], []
        for k, L in enumerate(links):
            for key in ("d", "a", "alpha", "mass", "com", "inertia"):
                if key not in L:
                    raise DiagramError(f"links[{k}] lacks '{key}'", file=path,
                                       line=getattr(L, "line", None))
            dh.append([_num(L[key], f"links[{k}].{key}", path) for key in ("d", "a", "alpha")])
            m.append(_num(L["mass"], f"links[{k}].mass", path))
            c.append([_num(v, f"links[{k}].com", path) for v in L["com"]])
            I.append(np.array([[_num(v, f"links[{k}].inertia", path) for v in
                                (row if isinstance(row, list) else [row])]
                               for row in L["inertia"]]).squeeze())
        g = [_num(v, "gravity", path) for v in data.get("gravity", [0, 0, 0])]
        return cls(dh, m, c, I, g, name=str(data.get("name", "chain")))

    # ---------------------------------------------------------------- kinematics
    def fk(self, q):
        """Flange pose (4x4 homogeneous transform in the base frame)."""
        q = np.asarray(q, dtype=float)
        K.fk(q, self.P, self._ws)
        b = self.n * K.WS_PER_LINK
        T = np.eye(4)
        T[:3, :3] = self._ws[b:b + 9].reshape(3, 3)
        T[:3, 3] = self._ws[b + K.WS_O:b + K.WS_O + 3]
        return T

    def frames(self, q):
        """Origins of frames 0..n (n+1 x 3): the stick figure."""
        K.fk(np.asarray(q, dtype=float), self.P, self._ws)
        return np.array([self._ws[k * K.WS_PER_LINK + 9:k * K.WS_PER_LINK + 12]
                         for k in range(self.n + 1)])

    def jacobian(self, q):
        """Geometric Jacobian (6 x n) of the flange: [linear; angular] velocity."""
        o = self.frames(q)
        J = np.zeros((6, self.n))
        for i in range(self.n):
            b = i * K.WS_PER_LINK
            z = self._ws[b:b + 9].reshape(3, 3)[:, 2]
            J[:3, i] = np.cross(z, o[-1] - o[i])
            J[3:, i] = z
        return J

    # ---------------------------------------------------------------- dynamics
    def rnea(self, q, qd, qdd, f_ext=None, tau_r=None):
        """Joint torques for the motion (inverse dynamics), gravity included.

        ``tau_r`` (n, optional): the drives' reaction torques, drive i's applied to link
        i-1 about joint i's axis (``-J_m dw_m/dt``; see :func:`kernels.add_reactions`).
        """
        tau = np.zeros(self.n)
        K.rnea(np.asarray(q, float), np.asarray(qd, float), np.asarray(qdd, float),
               self.gravity, np.zeros(6) if f_ext is None else np.asarray(f_ext, float),
               self.P, self._ws, tau, self._base)
        if tau_r is not None:
            K.add_reactions(self.n, self._ws, np.asarray(tau_r, float), tau, self._base)
        return tau

    def base_wrench(self, q, qd, qdd, f_ext=None, tau_r=None):
        """(force, moment about the base origin) the mounting applies to the arm."""
        self.rnea(q, qd, qdd, f_ext, tau_r)
        return self._base[:3].copy(), self._base[3:].copy()

    def mass_matrix(self, q):
        K.mass_matrix(np.asarray(q, float), self.P, self._ws, self._M, self._tmp, self._base)
        return self._M.copy()

    def forward_dynamics(self, q, qd, tau, f_ext=None, tau_r=None):
        """Joint accelerations for the torques ``tau`` (and reactions ``tau_r``, see
        :meth:`rnea`)."""
        qdd = np.zeros(self.n)
        K.forward_dynamics(np.asarray(q, float), np.asarray(qd, float),
                           np.asarray(tau, float), self.gravity,
                           np.zeros(6) if f_ext is None else np.asarray(f_ext, float),
                           np.zeros(0) if tau_r is None else np.asarray(tau_r, float),
                           self.P, self._ws, self._M, self._tmp, self._base, qdd,
                           np.empty(0))
        return qdd

    def momentum(self, q, qd):
        """(linear momentum, angular momentum about the base origin) of the arm."""
        K.rnea(np.asarray(q, float), np.asarray(qd, float), np.zeros(self.n),
               np.zeros(3), np.zeros(6), self.P, self._ws, np.zeros(self.n), self._base)
        p, L = np.zeros(3), np.zeros(3)
        for i in range(self.n):
            b = (i + 1) * K.WS_PER_LINK
            m = self.P[i, 3]
            c = self._ws[b + K.WS_COM:b + K.WS_COM + 3]
            w = self._ws[b + K.WS_W:b + K.WS_W + 3]
            v = self._point_velocity(q, qd, i, c)      # COM velocity, J_i(c) qd
            Iw = self._ws[b + K.WS_IW:b + K.WS_IW + 9].reshape(3, 3)
            p += m * v
            L += m * np.cross(c, v) + Iw @ w
        return p, L

    def _point_velocity(self, q, qd, i, point):
        K.fk(np.asarray(q, float), self.P, self._ws)
        v = np.zeros(3)
        for k in range(i + 1):
            b = k * K.WS_PER_LINK
            z = self._ws[b:b + 9].reshape(3, 3)[:, 2]
            v += qd[k] * np.cross(z, point - self._ws[b + K.WS_O:b + K.WS_O + 3])
        return v

    def kinetic_energy(self, q, qd):
        M = self.mass_matrix(q)
        return 0.5 * float(np.asarray(qd) @ M @ np.asarray(qd))
