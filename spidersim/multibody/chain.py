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


#: most links a data file may describe
MAX_LINKS = 64
#: largest |length| (d, a, com components) [m], mass [kg] and inertia entry [kg m^2] of a
#: data file: with these the mass matrix of 64 links stays below 1e25, far from overflow
#: (com 1e160 m or mass 1e300 kg overflowed it, refused as "singular ... eigenvalue nan")
MAX_LENGTH, MAX_MASS = 1e6, 1e6
MAX_INERTIA = MAX_MASS * MAX_LENGTH ** 2
LINK_KEYS = ("d", "a", "alpha", "mass", "com", "inertia")
FILE_KEYS = ("name", "gravity", "links")


def _num(v, what, file, line=None):
    """A finite number (or an expression of numbers) from a data file."""
    from ..text.expr import ExprError, evaluate
    from ..text.yamlio import found
    if isinstance(v, bool):
        raise DiagramError(f"{what}: expected a number, got {found(v)} (true/false is not a "
                           f"number)", file=file, line=line)
    try:
        x = float(evaluate(v, {})) if isinstance(v, str) else float(v)
    except (ExprError, TypeError, ValueError, OverflowError):
        raise DiagramError(f"{what}: expected a number, got {found(v)}", file=file,
                           line=line) from None
    if not np.isfinite(x):
        raise DiagramError(f"{what}: expected a finite number, got {x}", file=file, line=line)
    return x


def _vector3(v, what, file, line):
    if not isinstance(v, list) or len(v) != 3:
        from ..text.yamlio import found
        raise DiagramError(f"{what}: expected 3 numbers [x, y, z], got {found(v)}", file=file,
                           line=line)
    return [_num(x, what, file, line) for x in v]


def _bounded(x, limit, unit, what, file, line):
    """``x`` (a number or an array) with every ``|value| <= limit``, else a DiagramError
    naming the largest value, the bound and the unit the file is read in."""
    big = float(np.max(np.abs(x)))
    if big > limit:
        raise DiagramError(f"{what}: {big:g} {unit} is beyond the bound of {limit:g} {unit} "
                           f"(an arm data file is in m, kg and kg m^2)", file=file, line=line)
    return x


def _inertia(v, what, file, line):
    """Principal moments (3 numbers) or a symmetric 3 x 3 matrix [kg m^2], positive
    semi-definite with moments obeying the triangle inequality (a rigid body's)."""
    from ..text.yamlio import found
    if isinstance(v, list) and len(v) == 3 and all(isinstance(r, list) for r in v):
        if any(len(r) != 3 for r in v):
            raise DiagramError(f"{what}: a matrix must be 3 x 3", file=file, line=line)
        I = np.array([[_num(x, what, file, line) for x in r] for r in v])
        scale = max(np.abs(I).max(), 1e-300)
        if np.abs(I - I.T).max() > 1e-9 * scale:
            raise DiagramError(f"{what}: the matrix is not symmetric", file=file, line=line)
        moments = np.linalg.eigvalsh(0.5 * (I + I.T))
    elif isinstance(v, list) and len(v) == 3:
        I = np.array([_num(x, what, file, line) for x in v])
        moments, scale = I, max(np.abs(I).max(), 1e-300)
    else:
        raise DiagramError(f"{what}: expected 3 principal moments or a 3 x 3 matrix, got "
                           f"{found(v)}", file=file, line=line)
    a, b, c = sorted(float(m) for m in moments)
    if a < -1e-12 * scale or a + b < c * (1 - 1e-9):
        raise DiagramError(f"{what}: moments {[round(m, 12) for m in (a, b, c)]} are not a "
                           f"rigid body's (each must be >= 0 and at most the sum of the other "
                           f"two)", file=file, line=line)
    return I


def _link(k, L, path, list_line=None):
    """One entry of ``links``: ``(dh, mass, com, inertia)``, each checked (errors at the
    entry's line, or the list's for an entry that is not a mapping)."""
    from ..text.yamlio import found
    line = getattr(L, "line", None) or list_line
    if not isinstance(L, dict):
        raise DiagramError(f"links[{k}] must be a mapping {{d, a, alpha, mass, com, "
                           f"inertia}}, got {found(L)}", file=path, line=line)
    bad = sorted(str(key) for key in L if key not in LINK_KEYS)
    if bad:
        raise DiagramError(f"links[{k}]: unknown key(s) {', '.join(bad)}; keys are "
                           f"{', '.join(LINK_KEYS)}", file=path, line=line)
    for key in LINK_KEYS:
        if key not in L:
            raise DiagramError(f"links[{k}] lacks '{key}'", file=path, line=line)
    dh = [_num(L[key], f"links[{k}].{key}", path, line) for key in ("d", "a", "alpha")]
    for key, x in zip(("d", "a"), dh):
        _bounded(x, MAX_LENGTH, "m", f"links[{k}].{key}", path, line)
    m = _num(L["mass"], f"links[{k}].mass", path, line)
    if m < 0.0:
        raise DiagramError(f"links[{k}].mass: expected a mass >= 0 kg, got {m}", file=path,
                           line=line)
    _bounded(m, MAX_MASS, "kg", f"links[{k}].mass", path, line)
    c = _vector3(L["com"], f"links[{k}].com", path, line)
    _bounded(c, MAX_LENGTH, "m", f"links[{k}].com", path, line)
    I = _inertia(L["inertia"], f"links[{k}].inertia", path, line)
    return dh, m, c, _bounded(I, MAX_INERTIA, "kg m^2", f"links[{k}].inertia", path, line)


def _sizes(dh, masses, coms, inertias):
    """The largest length, mass and inertia of a chain's links, each named by its key:
    ``links[1].com 1e+160 m, links[0].mass 1 kg, links[0].inertia 0.1 kg m^2``."""
    kinds = (("m", [(f"links[{i}].{key}", dh[i][j]) for i in range(len(dh))
                    for j, key in ((0, "d"), (1, "a"))]
              + [(f"links[{i}].com", c) for i, c in enumerate(coms)]),
             ("kg", [(f"links[{i}].mass", m) for i, m in enumerate(masses)]),
             ("kg m^2", [(f"links[{i}].inertia", I) for i, I in enumerate(inertias)]))
    out = []
    for unit, entries in kinds:
        key, big = max(((k, float(np.max(np.abs(np.asarray(v, dtype=float)))))
                        for k, v in entries), key=lambda e: e[1])
        out.append(f"{key} {big:g} {unit}")
    return ", ".join(out)


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
        self._given = (dh, masses, coms_base, inertias_base)     # for error messages
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
        from ..text.yamlio import read_file, refuse_unreadable
        path = path or SPIDER
        refuse_unreadable(path, "arm data file")
        if not os.path.isfile(path):
            raise DiagramError(f"arm data file not found: {path}")
        data = read_file(path)
        if not isinstance(data, dict):
            raise DiagramError("an arm data file is a mapping with 'links' (and optionally "
                               "'name', 'gravity')", file=path)
        bad = sorted(str(key) for key in data if key not in FILE_KEYS)
        if bad:
            raise DiagramError(f"unknown key(s) {', '.join(bad)}; keys are "
                               f"{', '.join(FILE_KEYS)}", file=path,
                               line=data.line_of(bad[0]) if hasattr(data, "line_of") else None)
        links = data.get("links")
        if not isinstance(links, list) or not links:
            raise DiagramError("an arm data file needs a non-empty 'links' list", file=path)
        if len(links) > MAX_LINKS:
            raise DiagramError(f"'links' has {len(links)} entries, at most {MAX_LINKS} allowed",
                               file=path)
        dh, m, c, I = zip(*(_link(k, L, path, getattr(links, "line", None))
                            for k, L in enumerate(links)))
        line = data.line_of("gravity") if hasattr(data, "line_of") else None
        g = _vector3(data.get("gravity", [0, 0, 0]), "gravity", path, line)
        name = data.get("name", "chain")
        if not isinstance(name, str):
            raise DiagramError("'name' must be a text", file=path)
        chain = cls(dh, m, c, I, g, name=name)
        chain._check_inertia(path)
        return chain

    def _check_inertia(self, path):
        """The mass matrix at q = 0 must be finite (no overflow: a chain built in Python has
        no bounds on its values, see :data:`MAX_LENGTH`) and positive definite: every joint
        moves some inertia (a chain whose last links are massless points is refused here,
        not by a NaN in the middle of a run)."""
        M = self.mass_matrix(np.zeros(self.n))
        if not np.all(np.isfinite(M)):
            raise DiagramError(f"the chain's joint-space mass matrix at q = 0 is not finite "
                               f"(it overflowed): a mass, length or inertia is too large; the "
                               f"largest are {_sizes(*self._given)}", file=path)
        smallest = np.linalg.eigvalsh(0.5 * (M + M.T)).min()
        if not smallest > 1e-12 * max(np.abs(M).max(), 1e-300):
            raise DiagramError(f"the chain's joint-space mass matrix is singular at q = 0 "
                               f"(smallest eigenvalue {smallest:.3g} kg m^2): some joint moves "
                               f"no inertia", file=path)

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
