"""Compiled rigid-body algorithms for a serial chain of revolute joints (standard DH).

Everything is expressed in the base frame. Links are packed in ``P`` (n x 16 rows):
``d, a, alpha, m, c_x, c_y, c_z, I_xx .. I_zz`` with the COM ``c`` and the inertia about the
COM in *link* coordinates. ``ws`` is a workspace of :data:`WS_PER_LINK` ``* (n + 1)``
floats; nothing is allocated.

Conventions: joint ``i`` rotates about ``z_{i-1}`` through ``o_{i-1}`` (frame ``i-1``);
``A_i = Rz(q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``; gravity ``g`` is the acceleration of free
fall in the base frame (``[0, 0, -9.81]`` on the ground). The external wrench ``f_ext``
(force, moment about the flange origin ``o_n``, base frame) is applied *by the environment
to the arm*. The base wrench ``(f_0, n_0)`` is the force and the moment about the base
origin that the mounting applies to the arm; the arm applies the opposite to the mounting.
"""
import math

from numba import carray, cfunc

ROW = 16
WS_PER_LINK = 48
# workspace layout per link k (0 = base): R 0..8, o 9..11, w 12..14, al 15..17, ap 18..20,
# c 21..23, Iw 24..32, f 33..35, n 36..38, F 39..41, N 42..44, twist memo 45..47 (fk; the
# base's slots 45..47 are unused). The offsets by name, for code
# outside this module (``ws[k * WS_PER_LINK + WS_O + i]`` is o_k[i]):
WS_R = 0          # rotation matrix of frame k, row-major (9)
WS_O = 9          # origin o_k [m] (3)
WS_W = 12         # angular velocity w_k [rad/s] (3)
WS_ALPHA = 15     # angular acceleration [rad/s2] (3)
WS_ACC = 18       # acceleration of o_k [m/s2], with the base accelerating at -g (3)
WS_COM = 21       # centre of mass of link k [m] (3)
WS_IW = 24        # inertia about the COM in the base frame [kg.m2] (9)
WS_TWIST = 45     # fk's memo of link k-1's twist: alpha [rad], cos alpha, sin alpha (3)


def fk(q, P, ws):
    """Frame rotations and origins of every link into ``ws``; the flange is link n::

        R_i = R_{i-1} Rot_i,  o_i = o_{i-1} + R_{i-1} p_i     (R_0 = 1, o_0 = 0)

    with ``A_i = [Rot_i, p_i] = Rz(q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``.

    The twist ``alpha_i`` is constant: its cosine and sine are kept beside it in ``ws``
    (slots :data:`WS_TWIST` of link i) and computed again only when ``P`` holds another
    ``alpha_i`` than the one kept (or the memo is empty: a zeroed ``ws`` holds
    ``cos^2 + sin^2 = 0``), so a call costs the cosine and sine of the joint angles only.
    """
    n = q.size
    for j in range(9):
        ws[j] = 0.0
    ws[0] = ws[4] = ws[8] = 1.0
    ws[9] = ws[10] = ws[11] = 0.0
    for i in range(n):
        b0 = i * WS_PER_LINK
        b1 = (i + 1) * WS_PER_LINK
        th, d, a, al = q[i], P[i, 0], P[i, 1], P[i, 2]
        ct, st = math.cos(th), math.sin(th)
        m = b1 + WS_TWIST
        ca, sa = ws[m + 1], ws[m + 2]
        if not (ws[m] == al and ca * ca + sa * sa > 0.5):
            ca, sa = math.cos(al), math.sin(al)
            ws[m], ws[m + 1], ws[m + 2] = al, ca, sa
        # A = [[ct, -st ca, st sa, a ct], [st, ct ca, -ct sa, a st], [0, sa, ca, d]]
        A00, A01, A02, A03 = ct, -st * ca, st * sa, a * ct
        A10, A11, A12, A13 = st, ct * ca, -ct * sa, a * st
        A20, A21, A22, A23 = 0.0, sa, ca, d
        for r in range(3):
            R0, R1, R2 = ws[b0 + 3 * r], ws[b0 + 3 * r + 1], ws[b0 + 3 * r + 2]
            ws[b1 + 3 * r] = R0 * A00 + R1 * A10 + R2 * A20
            ws[b1 + 3 * r + 1] = R0 * A01 + R1 * A11 + R2 * A21
            ws[b1 + 3 * r + 2] = R0 * A02 + R1 * A12 + R2 * A22
            ws[b1 + 9 + r] = ws[b0 + 9 + r] + R0 * A03 + R1 * A13 + R2 * A23


def flange_jacobian(n, ws, J):
    """Geometric Jacobian of the flange after :func:`fk`, row-major 6 x n into ``J``:
    column i is ``[z_{i-1} x (o_n - o_{i-1}); z_{i-1}]``."""
    b = n * WS_PER_LINK
    for i in range(n):
        bi = i * WS_PER_LINK
        zx, zy, zz = ws[bi + 2], ws[bi + 5], ws[bi + 8]
        rx, ry, rz = ws[b + 9] - ws[bi + 9], ws[b + 10] - ws[bi + 10], ws[b + 11] - ws[bi + 11]
        J[i] = zy * rz - zz * ry
        J[n + i] = zz * rx - zx * rz
        J[2 * n + i] = zx * ry - zy * rx
        J[3 * n + i] = zx
        J[4 * n + i] = zy
        J[5 * n + i] = zz


def _cross(ax, ay, az, bx, by, bz):
    return ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx


def rnea(q, qd, qdd, g, f_ext, P, ws, tau, base):
    """Inverse dynamics: ``tau`` (n) and the base wrench ``base`` (6) for ``q, qd, qdd``.

    Recursive Newton-Euler in the base frame: :func:`fk` of ``q``, then
    :func:`rnea_on_frames`.
    """
    fk(q, P, ws)
    rnea_on_frames(qd, qdd, g, f_ext, P, ws, tau, base, True)


def rnea_on_frames(qd, qdd, g, f_ext, P, ws, tau, base, geometry):
    """The velocity/acceleration and force passes of :func:`rnea` on the frames of
    :func:`fk` already in ``ws`` (for the ``q`` wanted): a caller that has them skips fk.

    Forward, link i (0-based, joint i about ``z_{i-1}`` through ``o_{i-1}``)::

        w_i  = w_{i-1} + qd_i z_{i-1}
        al_i = al_{i-1} + qdd_i z_{i-1} + w_{i-1} x qd_i z_{i-1}
        a_i  = a_{i-1} + al_i x r + w_i x (w_i x r),   r = o_i - o_{i-1}   (a_0 = -g)
        F_i  = m_i a_c,i  (a_c,i: the same with r = c_i - o_{i-1}),
        N_i  = I_i al_i + w_i x I_i w_i    (I_i = R_i I_link R_i^T, about the COM)

    backward: ``f_{i-1} = f_i + F_i``, moments about ``o_{i-1}``, ``tau_i = z_{i-1} . n``.
    Reads the frames' slots (:data:`WS_R`, :data:`WS_O`) and never writes them; writes
    slots 12..23 (w, al, a, COM), 24..32 (Iw; with ``geometry``) and 39..44 (F, N) of
    links 0..n. ``geometry=False`` reads the COMs and ``Iw`` (slots 21..32) as a pass at
    the same ``q`` left them instead of computing them again (they depend on ``q`` only).
    """
    n = qd.size
    # base: w = al = 0, acceleration of the origin -g (gravity as a base acceleration)
    for j in range(12, 21):
        ws[j] = 0.0
    ws[18], ws[19], ws[20] = -g[0], -g[1], -g[2]
    for i in range(n):
        bp = i * WS_PER_LINK
        b = (i + 1) * WS_PER_LINK
        zx, zy, zz = ws[bp + 2], ws[bp + 5], ws[bp + 8]            # z_{i-1}
        wpx, wpy, wpz = ws[bp + 12], ws[bp + 13], ws[bp + 14]
        wx, wy, wz = wpx + qd[i] * zx, wpy + qd[i] * zy, wpz + qd[i] * zz
        cx, cy, cz = _cross(wpx, wpy, wpz, qd[i] * zx, qd[i] * zy, qd[i] * zz)
        alx = ws[bp + 15] + qdd[i] * zx + cx
        aly = ws[bp + 16] + qdd[i] * zy + cy
        alz = ws[bp + 17] + qdd[i] * zz + cz
        ws[b + 12], ws[b + 13], ws[b + 14] = wx, wy, wz
        ws[b + 15], ws[b + 16], ws[b + 17] = alx, aly, alz
        ox, oy, oz = ws[bp + 9], ws[bp + 10], ws[bp + 11]          # o_{i-1}
        # origin acceleration of frame i
        rx, ry, rz = ws[b + 9] - ox, ws[b + 10] - oy, ws[b + 11] - oz
        t1 = _cross(alx, aly, alz, rx, ry, rz)
        w_r = _cross(wx, wy, wz, rx, ry, rz)
        t2 = _cross(wx, wy, wz, w_r[0], w_r[1], w_r[2])
        ws[b + 18] = ws[bp + 18] + t1[0] + t2[0]
        ws[b + 19] = ws[bp + 19] + t1[1] + t2[1]
        ws[b + 20] = ws[bp + 20] + t1[2] + t2[2]
        # COM in the base frame, relative to o_{i-1}
        if geometry:
            lcx, lcy, lcz = P[i, 4], P[i, 5], P[i, 6]
            gx = ws[b + 9] + ws[b] * lcx + ws[b + 1] * lcy + ws[b + 2] * lcz
            gy = ws[b + 10] + ws[b + 3] * lcx + ws[b + 4] * lcy + ws[b + 5] * lcz
            gz = ws[b + 11] + ws[b + 6] * lcx + ws[b + 7] * lcy + ws[b + 8] * lcz
            ws[b + 21], ws[b + 22], ws[b + 23] = gx, gy, gz
        else:
            gx, gy, gz = ws[b + 21], ws[b + 22], ws[b + 23]
        rcx, rcy, rcz = gx - ox, gy - oy, gz - oz
        t1 = _cross(alx, aly, alz, rcx, rcy, rcz)
        w_r = _cross(wx, wy, wz, rcx, rcy, rcz)
        t2 = _cross(wx, wy, wz, w_r[0], w_r[1], w_r[2])
        m = P[i, 3]
        acx = ws[bp + 18] + t1[0] + t2[0]
        acy = ws[bp + 19] + t1[1] + t2[1]
        acz = ws[bp + 20] + t1[2] + t2[2]
        ws[b + 39], ws[b + 40], ws[b + 41] = m * acx, m * acy, m * acz
        # inertia in the base frame: Iw = R I R^T
        if geometry:
            for r in range(3):
                for c in range(3):
                    acc = 0.0
                    for k in range(3):
                        rk = ws[b + 3 * r + k]
                        for l in range(3):
                            acc += rk * P[i, 7 + 3 * k + l] * ws[b + 3 * c + l]
                    ws[b + 24 + 3 * r + c] = acc
        Iwx = ws[b + 24] * wx + ws[b + 25] * wy + ws[b + 26] * wz
        Iwy = ws[b + 27] * wx + ws[b + 28] * wy + ws[b + 29] * wz
        Iwz = ws[b + 30] * wx + ws[b + 31] * wy + ws[b + 32] * wz
        gyr = _cross(wx, wy, wz, Iwx, Iwy, Iwz)
        ws[b + 42] = ws[b + 24] * alx + ws[b + 25] * aly + ws[b + 26] * alz + gyr[0]
        ws[b + 43] = ws[b + 27] * alx + ws[b + 28] * aly + ws[b + 29] * alz + gyr[1]
        ws[b + 44] = ws[b + 30] * alx + ws[b + 31] * aly + ws[b + 32] * alz + gyr[2]
    # backward: f, n on link i from link i-1, moments about o_{i-1}
    fx, fy, fz = -f_ext[0], -f_ext[1], -f_ext[2]
    nx_, ny_, nz_ = -f_ext[3], -f_ext[4], -f_ext[5]
    for i in range(n - 1, -1, -1):
        bp = i * WS_PER_LINK
        b = (i + 1) * WS_PER_LINK
        ox, oy, oz = ws[bp + 9], ws[bp + 10], ws[bp + 11]
        rx, ry, rz = ws[b + 9] - ox, ws[b + 10] - oy, ws[b + 11] - oz
        rcx, rcy, rcz = ws[b + 21] - ox, ws[b + 22] - oy, ws[b + 23] - oz
        Fx, Fy, Fz = ws[b + 39], ws[b + 40], ws[b + 41]
        m1 = _cross(rcx, rcy, rcz, Fx, Fy, Fz)
        m2 = _cross(rx, ry, rz, fx, fy, fz)
        nx_ = nx_ + m1[0] + m2[0] + ws[b + 42]
        ny_ = ny_ + m1[1] + m2[1] + ws[b + 43]
        nz_ = nz_ + m1[2] + m2[2] + ws[b + 44]
        fx, fy, fz = fx + Fx, fy + Fy, fz + Fz
        tau[i] = nx_ * ws[bp + 2] + ny_ * ws[bp + 5] + nz_ * ws[bp + 8]
    base[0], base[1], base[2] = fx, fy, fz
    base[3], base[4], base[5] = nx_, ny_, nz_


def add_reactions(n, ws, tau_r, tau, base):
    """Add the drives' reaction torques to the result of :func:`rnea` (frames in ``ws``).

    Drive ``i`` (stator, gear housing) sits on link ``i-1`` (the base for joint 1) and its
    rotor spins about ``z_{i-1}``. Beyond the joint torque ``tau_i`` it passes to link
    ``i``, it applies the moment ``tau_r[i] z_{i-1}`` to link ``i-1``, with
    ``tau_r = -J_m dw_m/dt`` (see :class:`spidersim.blocks.arm.Arm`). These are external
    moments on the links, so by the backward recursion the moment link ``i-1`` applies to
    link ``i`` loses the sum of the reactions on links ``i..n-1`` and the base moment all of
    them (the force is unchanged)::

        tau_j  -=  z_{j-1} . sum_{i > j} tau_r[i] z_{i-1}     (1-based joints)
        n_0    -=  sum_{i >= 1} tau_r[i] z_{i-1}

    so that ``rnea(...) + add_reactions`` is the inverse dynamics of the arm loaded by the
    reactions: ``M qdd + b = tau + Q_r`` with ``Q_r,j = z_{j-1} . sum_{i > j} tau_r[i]
    z_{i-1}``, the generalized force of those moments. O(n), nothing allocated.
    """
    sx = sy = sz = 0.0
    for j in range(n - 1, -1, -1):
        b = j * WS_PER_LINK
        zx, zy, zz = ws[b + 2], ws[b + 5], ws[b + 8]                 # z_{j-1}
        tau[j] -= zx * sx + zy * sy + zz * sz
        sx += tau_r[j] * zx
        sy += tau_r[j] * zy
        sz += tau_r[j] * zz
    base[3] -= sx
    base[4] -= sy
    base[5] -= sz


def mass_matrix(q, P, ws, M, tmp, base):
    """Joint-space inertia ``M(q)`` by the composite-rigid-body algorithm (Walker & Orin's
    method 3, in the base frame); also leaves :func:`fk` of ``q`` in ``ws``, and the links'
    COMs and inertias about them in the base frame (``R I R^T``, slots :data:`WS_COM`,
    :data:`WS_IW`) as :func:`rnea_on_frames` computes them (the inertia exactly symmetric),
    and zeroes ``base`` (6). ``tmp`` is not used (kept for the callers' signature).

    With ``qd = 0`` and no gravity, a unit acceleration of joint ``j`` moves links
    ``j..n-1`` (1-based: the links after joint ``j``) as one rigid body, the *composite*
    ``C_j`` (mass ``m_j``, centre ``c_j``, inertia ``I_j`` about ``c_j``), turning about the
    axis ``z_{j-1}`` through ``o_{j-1}``. The wrench that does it, about ``o_{j-1}``::

        F_j = m_j  z_{j-1} x (c_j - o_{j-1})
        N_j = I_j z_{j-1} + (c_j - o_{j-1}) x F_j

    passes unchanged through the joints before ``j`` (their links do not accelerate), so
    ``M_ij = M_ji = z_{i-1} . (N_j + (o_{j-1} - o_{i-1}) x F_j)`` for ``i <= j``. The
    composites are built from the tip: ``m_j = m_link + m_(j+1)``, ``c_j`` the mass-weighted
    centre, ``I_j`` the two inertias moved to ``c_j`` (parallel axes:
    ``I + m (|d|^2 1 - d d^T)``). O(n^2); the RNEA-column reference it replaced took n
    passes of inverse dynamics (``tests/multibody``: equal to round-off).
    """
    n = q.size
    fk(q, P, ws)
    for k in range(6):
        base[k] = 0.0
    # composite of links k..n-1 into ws slots 33..45 of link k+1: mass, centre (3), inertia
    # about the centre (9, base frame); the RNEA rewrites these slots later
    mc = 0.0
    ccx = ccy = ccz = 0.0
    I00 = I01 = I02 = I11 = I12 = I22 = 0.0
    for k in range(n - 1, -1, -1):
        b = (k + 1) * WS_PER_LINK
        m = P[k, 3]
        lcx, lcy, lcz = P[k, 4], P[k, 5], P[k, 6]
        gx = ws[b + 9] + ws[b] * lcx + ws[b + 1] * lcy + ws[b + 2] * lcz
        gy = ws[b + 10] + ws[b + 3] * lcx + ws[b + 4] * lcy + ws[b + 5] * lcz
        gz = ws[b + 11] + ws[b + 6] * lcx + ws[b + 7] * lcy + ws[b + 8] * lcz
        # link inertia about its COM in the base frame: R I R^T (symmetric: 6 entries)
        L00 = L01 = L02 = L11 = L12 = L22 = 0.0
        for r in range(3):
            for c in range(r, 3):
                acc = 0.0
                for a in range(3):
                    ra = ws[b + 3 * r + a]
                    for e in range(3):
                        acc += ra * P[k, 7 + 3 * a + e] * ws[b + 3 * c + e]
                if r == 0 and c == 0:
                    L00 = acc
                elif r == 0 and c == 1:
                    L01 = acc
                elif r == 0:
                    L02 = acc
                elif c == 1:
                    L11 = acc
                elif r == 1:
                    L12 = acc
                else:
                    L22 = acc
        mt = mc + m
        if mt > 0.0:
            nx = (m * gx + mc * ccx) / mt
            ny = (m * gy + mc * ccy) / mt
            nz = (m * gz + mc * ccz) / mt
        else:
            nx, ny, nz = gx, gy, gz
        # parallel axes: the link from gx.., the outer composite from ccx.. to the new centre
        dx, dy, dz = gx - nx, gy - ny, gz - nz
        ex, ey, ez = ccx - nx, ccy - ny, ccz - nz
        d2, e2 = dx * dx + dy * dy + dz * dz, ex * ex + ey * ey + ez * ez
        I00 = L00 + I00 + m * (d2 - dx * dx) + mc * (e2 - ex * ex)
        I11 = L11 + I11 + m * (d2 - dy * dy) + mc * (e2 - ey * ey)
        I22 = L22 + I22 + m * (d2 - dz * dz) + mc * (e2 - ez * ez)
        I01 = L01 + I01 - m * dx * dy - mc * ex * ey
        I02 = L02 + I02 - m * dx * dz - mc * ex * ez
        I12 = L12 + I12 - m * dy * dz - mc * ey * ez
        mc, ccx, ccy, ccz = mt, nx, ny, nz
        # the link's COM and inertia in the base frame, as the RNEA keeps them
        ws[b + 21], ws[b + 22], ws[b + 23] = gx, gy, gz
        ws[b + 24], ws[b + 25], ws[b + 26] = L00, L01, L02
        ws[b + 27], ws[b + 28], ws[b + 29] = L01, L11, L12
        ws[b + 30], ws[b + 31], ws[b + 32] = L02, L12, L22
        ws[b + 33] = mc
        ws[b + 34], ws[b + 35], ws[b + 36] = ccx, ccy, ccz
        ws[b + 37], ws[b + 38], ws[b + 39] = I00, I01, I02
        ws[b + 40], ws[b + 41], ws[b + 42] = I11, I12, I22
    for j in range(n):
        bj = j * WS_PER_LINK                      # frame j-1 (0-based joint j turns about z_j)
        b = (j + 1) * WS_PER_LINK                 # the composite's slots
        zx, zy, zz = ws[bj + 2], ws[bj + 5], ws[bj + 8]
        ox, oy, oz = ws[bj + 9], ws[bj + 10], ws[bj + 11]
        m = ws[b + 33]
        rx, ry, rz = ws[b + 34] - ox, ws[b + 35] - oy, ws[b + 36] - oz
        F = _cross(zx, zy, zz, rx, ry, rz)
        Fx, Fy, Fz = m * F[0], m * F[1], m * F[2]
        c0 = _cross(rx, ry, rz, Fx, Fy, Fz)
        Nx = ws[b + 37] * zx + ws[b + 38] * zy + ws[b + 39] * zz + c0[0]
        Ny = ws[b + 38] * zx + ws[b + 40] * zy + ws[b + 41] * zz + c0[1]
        Nz = ws[b + 39] * zx + ws[b + 41] * zy + ws[b + 42] * zz + c0[2]
        for i in range(j + 1):
            bi = i * WS_PER_LINK
            px, py, pz = ox - ws[bi + 9], oy - ws[bi + 10], oz - ws[bi + 11]
            c1 = _cross(px, py, pz, Fx, Fy, Fz)
            v = (ws[bi + 2] * (Nx + c1[0]) + ws[bi + 5] * (Ny + c1[1])
                 + ws[bi + 8] * (Nz + c1[2]))
            M[i, j] = v
            M[j, i] = v


def cholesky_factor(A):
    """Cholesky factor of symmetric positive definite ``A`` in place (lower triangle ``L``,
    ``A = L L^T``); NaN on the diagonal if ``A`` is not positive definite."""
    n = A.shape[0]
    for j in range(n):
        s = A[j, j]
        for k in range(j):
            s -= A[j, k] * A[j, k]
        d = math.sqrt(s) if s > 0.0 else math.nan
        A[j, j] = d
        for i in range(j + 1, n):
            s = A[i, j]
            for k in range(j):
                s -= A[i, k] * A[j, k]
            A[i, j] = s / d


def cholesky_subst(L, b, x):
    """Solve ``L L^T x = b`` with the factor of :func:`cholesky_factor` (``L`` unchanged)."""
    n = b.size
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= L[i, k] * x[k]
        x[i] = s / L[i, i]
    for i in range(n - 1, -1, -1):
        s = x[i]
        for k in range(i + 1, n):
            s -= L[k, i] * x[k]
        x[i] = s / L[i, i]


def task_inertia_factor(J, Y, n, A, damping, fallback):
    """Cholesky factor (in place, in ``A``) of the inverse operational-space inertia
    ``A = J M^-1 J^T`` with its diagonal scaled by ``1 + damping``; ``J`` is 6 x n
    row-major, ``Y = M^-1 J^T`` (n x 6 row-major). Where that is not positive definite (a
    singular pose: J lost rank, rows of J may vanish) it is formed again with
    ``fallback tr(A) / 6`` added to the diagonal (damped least squares). Returns the
    diagonal term added (0 when the first factorisation succeeded)."""
    extra = 0.0
    for attempt in range(2):
        tr = 0.0
        for r in range(6):
            for c in range(6):
                acc = 0.0
                for i in range(n):
                    acc += J[r * n + i] * Y[i * 6 + c]
                A[r, c] = acc
            tr += A[r, r]
        if attempt == 1:
            extra = fallback * tr / 6.0
        for r in range(6):
            A[r, r] = A[r, r] * (1.0 + damping) + extra
        cholesky_factor(A)
        ok = True
        for r in range(6):
            if not A[r, r] > 0.0:
                ok = False
        if ok:
            break
    return extra


def cholesky_solve(M, b, x):
    """Solve ``M x = b`` for symmetric positive definite ``M`` (factored in place)."""
    cholesky_factor(M)
    cholesky_subst(M, b, x)


def orientation_error(ws, n, R_ref, e):
    """``e = 1/2 sum_i r_i x r_ref,i`` (3): the rotation error of the flange frame (columns
    ``r_i`` of its rotation, from :func:`fk` in ``ws``) to ``R_ref`` (row-major), base
    frame; for small errors the rotation vector from the flange to the reference."""
    b = n * WS_PER_LINK
    ex = ey = ez = 0.0
    for c in range(3):
        ax, ay, az = ws[b + c], ws[b + 3 + c], ws[b + 6 + c]
        dx, dy, dz = R_ref[c], R_ref[3 + c], R_ref[6 + c]
        ex += 0.5 * (ay * dz - az * dy)
        ey += 0.5 * (az * dx - ax * dz)
        ez += 0.5 * (ax * dy - ay * dx)
    e[0], e[1], e[2] = ex, ey, ez


def relative_rotation(Rc, R, out):
    """``out = R_c^T R`` for 3 x 3 rotations, all row-major (9 floats): ``R`` seen from
    the frame ``R_c``."""
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for r in range(3):
                acc += Rc[3 * r + i] * R[3 * r + j]
            out[3 * i + j] = acc


def impact_projection(n, qd, c, M, J, Jc, Y, A, r, x):
    """Plastic impact on the engaged directions of a 6-D flange constraint, in place::

        qd+ = qd- - M^-1 J_c^T (J_c M^-1 J_c^T)^-1 J_c qd-

    ``c`` is ``[s_0..s_5, R_c]``: ``s_k > 0.5`` marks an engaged direction (0-2: translation
    along, 3-5: rotation about the contact axis k mod 3, the column k mod 3 of the contact
    rotation ``R_c``, row-major, base frame). Row k of ``J_c`` is ``x_k^T J_v`` or
    ``x_k^T J_w`` (``J``: the flange Jacobian, 6 x n row-major, base frame), so ``J_c qd+ =
    0``: the flange velocity along every engaged direction vanishes. ``M`` is factored in
    place; ``Jc``, ``Y`` (6 n), ``A`` (36), ``r``, ``x`` (6) are scratch. The projection is
    the least kinetic-energy change that removes the constrained velocity (energy is lost,
    never gained). Redundant rows (a singular pose) leave ``A`` singular: NaN results.
    """
    m = 0
    for k in range(6):
        if c[k] > 0.5:
            col = k % 3
            blk = 0 if k < 3 else 3
            for i in range(n):
                acc = 0.0
                for rr in range(3):
                    acc += c[6 + 3 * rr + col] * J[(blk + rr) * n + i]
                Jc[m * n + i] = acc
            m += 1
    if m == 0:
        return
    cholesky_factor(M)
    for j in range(m):
        cholesky_subst(M, Jc[j * n:(j + 1) * n], Y[j * n:(j + 1) * n])   # M^-1 J_c^T
    Am = A[:m * m].reshape((m, m))
    for a in range(m):
        acc = 0.0
        for i in range(n):
            acc += Jc[a * n + i] * qd[i]
        r[a] = acc                                                      # J_c qd-
        for b in range(m):
            acc = 0.0
            for i in range(n):
                acc += Jc[a * n + i] * Y[b * n + i]
            Am[a, b] = acc
    cholesky_solve(Am, r[:m], x[:m])
    for i in range(n):
        acc = 0.0
        for j in range(m):
            acc += Y[j * n + i] * x[j]
        qd[i] -= acc


def forward_dynamics(q, qd, tau, g, f_ext, tau_r, P, ws, M, tmp, base, qdd, key):
    """``qdd`` from ``M(q) qdd = tau - b(q, qd) + Q_r`` (``b``: RNEA with ``qdd = 0``;
    ``Q_r``: the generalized force of the drives' reaction torques ``tau_r``, see
    :func:`add_reactions`; ``tau_r`` all zero, or empty, skips them), then the base wrench
    of the resulting motion, reactions included, into ``base``. Forward kinematics runs
    once (in ``mass_matrix``, or on its own when the factor is reused), and both RNEA
    passes (:func:`rnea_on_frames`) use its frames and the links' COMs and base-frame
    inertias ``mass_matrix`` (or, after a reuse, the first pass) left in ``ws``. The frames,
    motion and forces left in ``ws`` are those :func:`rnea` of ``q, qd, qdd`` leaves.

    ``key`` (``n + 2`` floats, or empty: no reuse) lets a caller that evaluates the same
    ``q`` several times (an algebraic loop through ``f_ext``: Newton iterations) reuse the
    Cholesky factor of ``M`` kept in ``M``: it holds ``q``, a checksum of ``P`` and a valid
    flag. Whoever writes ``M`` for another purpose sets ``key[n + 1] = 0``.
    """
    n = q.size
    zero = tmp[3 * n:4 * n]
    bias = tmp[4 * n:5 * n]
    rhs = tmp[5 * n:6 * n]
    for k in range(n):
        zero[k] = 0.0
    keep = key.size == n + 2
    reuse = False
    check = 0.0
    if keep:
        for i in range(P.shape[0]):
            for j in range(P.shape[1]):
                check += P[i, j] * (1.0 + i * P.shape[1] + j)
        reuse = key[n + 1] == 1.0 and key[n] == check
        for k in range(n):
            if key[k] != q[k]:
                reuse = False
    if not reuse:
        _mass_matrix_linked(q, P, ws, M, tmp, base)   # linked: see _c_kernels
        cholesky_factor(M)
        if keep:
            for k in range(n):
                key[k] = q[k]
            key[n] = check
            key[n + 1] = 1.0
    else:
        # the factor is q's, but ws may hold the frames of another q (an event, a caller
        # sharing ws): forward kinematics again; mass_matrix left them in ws otherwise
        fk(q, P, ws)
    react = False
    if tau_r.size == n:
        for k in range(n):
            if tau_r[k] != 0.0:
                react = True
    # one fk per call: the passes read the frames and never write them (nor read
    # mass_matrix's composites, slots 33..42); COMs and Iw are mass_matrix's, or, when the
    # factor is reused, the first pass computes them for the second
    rnea_on_frames(qd, zero, g, f_ext, P, ws, bias, base, reuse)
    if react:
        add_reactions(n, ws, tau_r, bias, base)
    for k in range(n):
        rhs[k] = tau[k] - bias[k]
    cholesky_subst(M, rhs, qdd)
    rnea_on_frames(qd, qdd, g, f_ext, P, ws, bias, base, False)
    if react:
        add_reactions(n, ws, tau_r, bias, base)


def jit_kernel(fn):
    """``fn`` compiled by numba for the hot path: cached machine code, numpy's error model
    (a division by zero gives inf/nan, reported by name, instead of an exception). Shared by
    the multibody kernels and the blocks built on them."""
    import numba
    return numba.njit(cache=True, error_model="numpy")(fn)


# the kernels call each other: rebind every name to its compiled version (numba resolves
# the globals when a function is first compiled)
_cross = jit_kernel(_cross)
fk = jit_kernel(fk)
flange_jacobian = jit_kernel(flange_jacobian)
rnea_on_frames = jit_kernel(rnea_on_frames)
rnea = jit_kernel(rnea)
add_reactions = jit_kernel(add_reactions)
mass_matrix = jit_kernel(mass_matrix)
cholesky_factor = jit_kernel(cholesky_factor)
cholesky_subst = jit_kernel(cholesky_subst)
cholesky_solve = jit_kernel(cholesky_solve)
task_inertia_factor = jit_kernel(task_inertia_factor)
orientation_error = jit_kernel(orientation_error)
impact_projection = jit_kernel(impact_projection)
relative_rotation = jit_kernel(relative_rotation)
forward_dynamics = jit_kernel(forward_dynamics)
_mass_matrix_linked = mass_matrix   # the jitted kernel, before _c_kernels rebinds the name


# The arm's event kernels (and what they share with the Chain and the force control) are
# called through C symbols (see .native): compiled once here, they are no longer linked into,
# and optimised again with, every caller. Each wrapper takes the data pointer and the shape
# of every array (.native.c_signature). forward_dynamics is exported too (a new diagram's
# compile 1 s shorter, spider.yaml 2-4 % slower: see .native); flange_jacobian, small,
# stays linked; forward_dynamics calls the linked mass_matrix (_mass_matrix_linked).
def _c_kernels():
    from .native import c_signature, exported

    def c_kernel(kinds):
        return cfunc(c_signature(kinds), cache=True, nogil=True, error_model="numpy")

    @c_kernel("211")
    def cholesky_solve_c(M, r_M, c_M, b, n_b, x, n_x):
        cholesky_solve(carray(M, (r_M, c_M)), carray(b, n_b), carray(x, n_x))

    @c_kernel("121211")
    def mass_matrix_c(q, n_q, P, r_P, c_P, ws, n_ws, M, r_M, c_M, tmp, n_tmp, base, n_base):
        mass_matrix(carray(q, n_q), carray(P, (r_P, c_P)), carray(ws, n_ws),
                    carray(M, (r_M, c_M)), carray(tmp, n_tmp), carray(base, n_base))

    @c_kernel("i112111111")
    def impact_projection_c(n, qd, n_qd, c, n_c, M, r_M, c_M, J, n_J, Jc, n_Jc, Y, n_Y, A,
                            n_A, r, n_r, x, n_x):
        impact_projection(n, carray(qd, n_qd), carray(c, n_c), carray(M, (r_M, c_M)),
                          carray(J, n_J), carray(Jc, n_Jc), carray(Y, n_Y), carray(A, n_A),
                          carray(r, n_r), carray(x, n_x))

    @c_kernel("1111112121111")
    def forward_dynamics_c(q, n_q, qd, n_qd, tau, n_tau, g, n_g, f_ext, n_f, tau_r, n_r, P,
                           r_P, c_P, ws, n_ws, M, r_M, c_M, tmp, n_tmp, base, n_base, qdd,
                           n_qdd, key, n_key):
        forward_dynamics(carray(q, n_q), carray(qd, n_qd), carray(tau, n_tau), carray(g, n_g),
                         carray(f_ext, n_f), carray(tau_r, n_r), carray(P, (r_P, c_P)),
                         carray(ws, n_ws), carray(M, (r_M, c_M)), carray(tmp, n_tmp),
                         carray(base, n_base), carray(qdd, n_qdd), carray(key, n_key))

    return (exported(cholesky_solve, cholesky_solve_c, "211"),
            exported(mass_matrix, mass_matrix_c, "121211"),
            exported(impact_projection, impact_projection_c, "i112111111"),
            exported(forward_dynamics, forward_dynamics_c, "1111112121111"))


cholesky_solve, mass_matrix, impact_projection, forward_dynamics = _c_kernels()
