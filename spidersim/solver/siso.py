"""The minimal pole-zero form of one input/output pair of a state-space model.

The figures of merit of a pair (DC gain, bandwidth, crossovers, margins) belong to its
transfer function ``G(s) = C (sI - A)^-1 B + D``. A linearized diagram carries modes that
the pair cannot move or cannot see (another subsystem of the file, an angle behind a speed
loop): eigenvalues of ``A`` that are not poles of ``G``. They are removed here without
forming polynomial coefficients: expanding ``G`` into a numerator and a denominator loses
the zeros (and with them the DC gain and the bandwidth) of a model whose poles spread over
a few decades, as a current loop at 1e4 rad/s beside a mechanism at 10 rad/s does.

1. **Structurally**: only the states reachable from the input (through the nonzero entries
   of ``B`` and ``A``) that also reach the output (through ``A`` and ``C``) are kept. A
   finite-difference linearization gives exact zeros where a variable does not depend on
   another, so unconnected parts of the diagram drop out exactly.
2. **Numerically**: the poles are the eigenvalues of the remaining ``A``, the zeros the
   finite generalized eigenvalues of the Rosenbrock pencil ``([A B; C D], [I 0; 0 0])``
   (QZ, as ``control.zeros`` computes them without slycot). A zero within
   :func:`cancel_tolerance` of a pole cancels it: a mode that is uncontrollable or
   unobservable without a structural reason.
3. The gain ``k`` of ``G(s) = k prod(s - z_i) / prod(s - p_i)`` is fitted a decade above
   every eigenvalue, from ``G`` evaluated on the state space by a linear solve.

The response at ``s = jw`` is then a product of factors: its logarithm and its phase are sums,
so nothing overflows and the phase is continuous in ``w`` (crossings of -180 deg are found
without unwrapping). Frequencies are in rad/s.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: relative part of the distance within which a zero cancels a pole
CANCEL_REL = 1e-6


def origin_tolerance(scale):
    """Magnitude below which a pole or zero is at the origin: twice ``sqrt(eps scale)``,
    how far a double eigenvalue at the origin (a rigid-body mode: an angle and its speed)
    moves under round-off in a matrix of size ``scale``. Absolute: a slow pole (0.05 rad/s
    beside a current loop at 1e5 rad/s) is a pole, not an integrator."""
    return 2.0 * math.sqrt(np.finfo(float).eps * scale)


def cancel_tolerance(p, z, scale):
    """``|p - z|`` below which zero ``z`` cancels pole ``p``: ``CANCEL_REL max(|p|, |z|)``
    plus :func:`origin_tolerance` (two roots at the origin to round-off)."""
    return CANCEL_REL * max(abs(p), abs(z)) + origin_tolerance(scale)


def structural_part(A, B, C):
    """Indices of the states reachable from ``B`` through ``A`` that reach ``C`` through
    ``A`` (sorted)."""
    dep = A != 0.0                       # dep[i, j]: x_i' depends on x_j
    reach = set(np.flatnonzero(B.ravel() != 0.0).tolist())
    stack = list(reach)
    while stack:
        j = stack.pop()
        for i in np.flatnonzero(dep[:, j]).tolist():
            if i not in reach:
                reach.add(i)
                stack.append(i)
    seen = set(np.flatnonzero(C.ravel() != 0.0).tolist())
    stack = list(seen)
    while stack:
        i = stack.pop()
        for j in np.flatnonzero(dep[i, :]).tolist():
            if j not in seen:
                seen.add(j)
                stack.append(j)
    return sorted(reach & seen)


def pencil_zeros(A, B, C, D, limit):
    """Finite zeros of the SISO system: generalized eigenvalues of the Rosenbrock pencil
    of magnitude below ``limit`` (the infinite ones of a strictly proper system come out of
    QZ as zero ``beta`` or as huge values)."""
    from scipy.linalg import eig
    n = len(A)
    M = np.block([[A, B], [C, D]])
    N = np.zeros_like(M)
    N[:n, :n] = np.eye(n)
    (alpha, beta) = eig(M, N, left=False, right=False, homogeneous_eigvals=True)
    out = []
    for a, b in zip(alpha, beta):
        if b != 0 and abs(a) < limit * abs(b):
            out.append(complex(a / b))
    return np.array(out, dtype=complex)


def _cancel(poles, zeros, scale):
    """Remove each zero with its nearest pole when they are within
    :func:`cancel_tolerance`; return the remaining ``(poles, zeros)``."""
    poles = list(poles)
    kept = []
    for z in sorted(zeros, key=abs):
        if poles:
            k = int(np.argmin([abs(p - z) for p in poles]))
            if abs(poles[k] - z) <= cancel_tolerance(poles[k], z, scale):
                poles.pop(k)
                continue
        kept.append(z)
    return np.array(poles, dtype=complex), np.array(kept, dtype=complex)


def _response(A, B, C, D, s):
    """``G(s)`` of the state space by one linear solve."""
    n = len(A)
    if n == 0:
        return complex(D[0, 0])
    x = np.linalg.solve(s * np.eye(n) - A, B[:, 0].astype(complex))
    return complex(C[0] @ x + D[0, 0])


def _fit_frequency(eigs, zeros):
    """A frequency [rad/s] for fitting the gain: a decade above every eigenvalue of ``A``
    (``sI - A`` is then well conditioned, whatever modes were cancelled), moved up when a
    zero lies on it."""
    w = 10.0 * max([abs(e) for e in eigs] + [1.0])
    while any(abs(1j * w - z) < 1e-3 * w for z in zeros):
        w *= 1.37
    return w


def _dc_from_ss(A, B, C, D):
    """``D - C A^-1 B`` when ``A`` is well conditioned (no mode near the origin), else
    None."""
    if len(A) == 0:
        return float(D[0, 0])
    if np.linalg.cond(A) > 1e10:
        return None
    return float(D[0, 0] - C[0] @ np.linalg.solve(A, B[:, 0]))


def _angles(s, roots):
    """``arg(s - r)`` for ``s = jw`` (a column) and each root, continuous in ``w``: a
    right-half-plane root's factor passes the negative real axis at ``w = Im r``, where
    ``np.angle`` jumps by 2 pi; written as ``pi + arg(r - s)`` there it does not."""
    w = s.imag
    re, im = roots.real[None, :], roots.imag[None, :]
    left = np.arctan2(w - im, -re)
    right = math.pi + np.arctan2(im - w, re)
    return np.where(re > 0, right, left)


@dataclass(frozen=True)
class Zpk:
    """``G(s) = k prod(s - zeros) / prod(s - poles)``, minimal (see the module docstring)."""
    zeros: np.ndarray
    poles: np.ndarray
    k: float
    scale: float
    dc: float | None = None      # G(0) from the state space when A is well conditioned

    @classmethod
    def from_ss(cls, sys):
        """The minimal form of a SISO ``control.StateSpace`` (or anything with ``A``, ``B``,
        ``C``, ``D``)."""
        A, B, C, D = (np.atleast_2d(np.asarray(getattr(sys, m), dtype=float))
                      for m in "ABCD")
        if A.size == 0:
            return cls(np.zeros(0, complex), np.zeros(0, complex), float(D[0, 0]), 1.0)
        scale = max(1.0, float(np.max(np.abs(A))))
        keep = structural_part(A, B, C)
        A, B, C = A[np.ix_(keep, keep)], B[keep, :], C[:, keep]
        if len(keep):
            # diagonal similarity: the companion form of a transfer function has entries of
            # 1 beside 1e7; balanced, the eigenvalue and pencil problems lose far less
            from scipy.linalg import matrix_balance
            A, T = matrix_balance(A, permute=False)
            t = np.diag(T)
            B, C = B / t[:, None], C * t[None, :]
        eigs = np.linalg.eigvals(A) if len(keep) else np.zeros(0, complex)
        zeros = (pencil_zeros(A, B, C, D, 1e10 * scale) if len(keep)
                 else np.zeros(0, complex))
        poles, zeros = _cancel(eigs, zeros, scale)
        w0 = _fit_frequency(eigs, zeros)
        s0 = 1j * w0
        g0 = _response(A, B, C, D, s0)
        k = g0 * np.prod(s0 - poles) / np.prod(s0 - zeros)
        return cls(zeros, poles, float(k.real), scale, _dc_from_ss(A, B, C, D))

    def has_integrator(self):
        """Whether a pole sits at the origin (to round-off, :func:`origin_tolerance`)."""
        return bool(np.any(np.abs(self.poles) < origin_tolerance(self.scale)))

    def dc_gain(self):
        """``G(0)``: inf with a free integrator, 0 with a zero at the origin; else
        ``D - C A^-1 B`` of the reduced state space when ``A`` is well conditioned (it does
        not depend on how accurately the zeros came out), else from the factors."""
        if self.has_integrator():
            return math.inf
        if self.k == 0.0 or np.any(np.abs(self.zeros) < origin_tolerance(self.scale)):
            return 0.0
        if self.dc is not None:
            return self.dc
        return float((self.k * np.prod(-self.zeros) / np.prod(-self.poles)).real)

    def log_mag_phase(self, w):
        """``(ln|G(jw)|, phase of G(jw) [rad])`` for an array of ``w``; the phase is
        continuous in ``w`` (a sum of the factors' angles)."""
        s = 1j * np.atleast_1d(np.asarray(w, dtype=float))[:, None]
        fz, fp = s - self.zeros[None, :], s - self.poles[None, :]
        with np.errstate(divide="ignore"):
            logm = (math.log(abs(self.k)) if self.k != 0 else -math.inf) + (
                np.sum(np.log(np.abs(fz)), axis=1) - np.sum(np.log(np.abs(fp)), axis=1))
        phase = (math.pi if self.k < 0 else 0.0) + (np.sum(_angles(s, self.zeros), axis=1)
                                                    - np.sum(_angles(s, self.poles), axis=1))
        return logm, phase

    def magnitude(self, w):
        """``|G(jw)|`` for an array of ``w``."""
        return np.exp(self.log_mag_phase(w)[0])

    def grid(self, n=4000, decades=4.0):
        """Frequencies [rad/s] for searching crossings: a logarithmic grid ``decades`` beyond
        the poles' and zeros' magnitudes, with the magnitude of every pole and zero and points
        at its half-power width on either side (a lightly damped pair's phase turns within
        that width)."""
        roots = [r for r in list(self.poles) + list(self.zeros) if abs(r) > 0]
        mags = [abs(r) for r in roots] or [1.0]
        # where |k| / w^r = 1 (r the relative degree): a gain crossover far beyond the
        # roots (a loop gain of 1e5 on an integrator crosses at 1e5 rad/s)
        r = len(self.poles) - len(self.zeros)
        if r > 0 and self.k != 0:
            mags.append(abs(self.k) ** (1.0 / r))
        lo, hi = min(mags) / 10 ** decades, max(mags) * 10 ** decades
        pts = [np.logspace(math.log10(lo), math.log10(hi), n)]
        for r in roots:
            width = max(abs(r.real), 1e-9 * abs(r))
            pts.append(np.array([abs(r) - width, abs(r), abs(r) + width,
                                 abs(r) - 0.1 * width, abs(r) + 0.1 * width]))
        w = np.unique(np.concatenate(pts))
        return w[(w >= lo) & (w <= hi)]


def _roots_of(f, w, values, target):
    """Frequencies where the continuous ``f(w)`` crosses ``target`` between grid points
    ``w`` (``values = f(w)``), refined by Brent's method."""
    from scipy.optimize import brentq
    d = values - target
    d[np.abs(d) < 1e-9] = 0.0       # on the target to round-off (1/s^2: -180 deg at all w)
    out = []
    for a, b in _sign_changes(d):
        out.append(float(brentq(lambda v: f(v) - target, w[a], w[b],
                                xtol=1e-14 * w[b], rtol=4 * np.finfo(float).eps)))
    return sorted(out)


def _sign_changes(d):
    """Index pairs ``(a, b)``, ``a < b``, of grid values of opposite signs with only zeros
    between them: a crossing between two points, or on a point (or a run of points) taken
    as zero. The grid holds every pole and zero magnitude, where a symmetric design
    crosses exactly (``2 (s + 1)^2 / s^3`` at 1 rad/s: that crossing was missed); a run
    of zeros with the same sign on both sides, or none, only touches (``1/s^2``)."""
    nz = np.flatnonzero(d != 0.0)
    s = np.sign(d[nz])
    return [(int(nz[k]), int(nz[k + 1])) for k in np.flatnonzero(s[:-1] * s[1:] < 0)]


def margins(zpk):
    """``(gain margin, phase margin [deg], phase crossover, gain crossover [rad/s])`` of the
    loop transfer ``L = zpk`` (negative feedback), as ``control.margin`` defines them: among
    several crossings the gain margin closest to 1 (in log) and the phase margin smallest
    in magnitude; ``inf`` and ``nan`` where there is no crossing."""
    w = zpk.grid()
    logm, phase = zpk.log_mag_phase(w)
    # phase crossovers: (phase + pi) / 2pi through an integer
    turns = (phase + math.pi) / (2 * math.pi)
    wpc = []
    for m in range(int(np.floor(np.min(turns))), int(np.ceil(np.max(turns))) + 1):
        wpc += _roots_of(lambda v: (zpk.log_mag_phase(v)[1][0] + math.pi) / (2 * math.pi),
                         w, turns, float(m))
    wgc = _roots_of(lambda v: zpk.log_mag_phase(v)[0][0], w, logm, 0.0)
    gains = [(v, math.exp(-zpk.log_mag_phase(v)[0][0])) for v in wpc]
    dc = zpk.dc_gain()
    if len(zpk.poles) and np.isfinite(dc) and dc < 0:
        gains.append((0.0, 1.0 / abs(dc)))       # -180 deg at w = 0
    gm, w_gm = math.inf, math.nan
    for v, g in gains:
        if abs(math.log(g)) < abs(math.log(gm)) or math.isinf(gm):
            gm, w_gm = g, v
    pm, w_pm = math.inf, math.nan
    for v in wgc:
        ph = math.degrees(zpk.log_mag_phase(v)[1][0])
        p = (ph + 180.0 + 180.0) % 360.0 - 180.0
        if abs(p) < abs(pm):
            pm, w_pm = p, v
    return gm, pm, w_gm, w_pm
