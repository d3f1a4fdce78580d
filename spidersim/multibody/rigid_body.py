"""Compiled helpers for a free rigid body (the Arm's payload): attitude, Euler's equations,
and a body merged into a link.

Attitude: a quaternion ``Q = [w, x, y, z]`` (scalar first) of the body axes in the base
frame: a vector with body coordinates ``u_b`` has base coordinates ``u = R(Q) u_b``. The
kinematics ``dQ/dt = 1/2 Q (x) [0, w_b]`` (``w_b``: angular velocity in body axes) keeps
``|Q|`` constant in exact arithmetic; the integrator's drift of ``|Q|`` is harmless because
``R`` is always formed from ``Q / |Q|`` (and the norm never feeds back into the motion).

Euler's equations about the COM in principal axes (moments ``I_1, I_2, I_3``), torque free::

    I_1 dw_1/dt = (I_2 - I_3) w_2 w_3     (and cyclic)

A zero principal moment (a point mass, a thin rod) leaves that component constant.
"""
import math

from .kernels import jit_kernel


def quat_to_rot(Q, R):
    """Rotation matrix (row-major 9) of the quaternion ``Q`` (normalised here)."""
    s = math.sqrt(Q[0] * Q[0] + Q[1] * Q[1] + Q[2] * Q[2] + Q[3] * Q[3])
    w, x, y, z = Q[0] / s, Q[1] / s, Q[2] / s, Q[3] / s
    R[0] = 1.0 - 2.0 * (y * y + z * z)
    R[1] = 2.0 * (x * y - w * z)
    R[2] = 2.0 * (x * z + w * y)
    R[3] = 2.0 * (x * y + w * z)
    R[4] = 1.0 - 2.0 * (x * x + z * z)
    R[5] = 2.0 * (y * z - w * x)
    R[6] = 2.0 * (x * z - w * y)
    R[7] = 2.0 * (y * z + w * x)
    R[8] = 1.0 - 2.0 * (x * x + y * y)


def rot_to_quat(R, Q):
    """Unit quaternion (``w >= 0``) of the rotation matrix ``R`` (row-major 9); Shepperd's
    method (the largest of ``w, x, y, z`` is found first, no loss near 180 degrees)."""
    tr = R[0] + R[4] + R[8]
    if tr >= R[0] and tr >= R[4] and tr >= R[8]:
        w = 0.5 * math.sqrt(1.0 + tr)
        f = 0.25 / w
        x, y, z = (R[7] - R[5]) * f, (R[2] - R[6]) * f, (R[3] - R[1]) * f
    elif R[0] >= R[4] and R[0] >= R[8]:
        x = 0.5 * math.sqrt(1.0 + R[0] - R[4] - R[8])
        f = 0.25 / x
        w, y, z = (R[7] - R[5]) * f, (R[1] + R[3]) * f, (R[2] + R[6]) * f
    elif R[4] >= R[8]:
        y = 0.5 * math.sqrt(1.0 + R[4] - R[0] - R[8])
        f = 0.25 / y
        w, x, z = (R[2] - R[6]) * f, (R[1] + R[3]) * f, (R[5] + R[7]) * f
    else:
        z = 0.5 * math.sqrt(1.0 + R[8] - R[0] - R[4])
        f = 0.25 / z
        w, x, y = (R[3] - R[1]) * f, (R[2] + R[6]) * f, (R[5] + R[7]) * f
    sg = -1.0 if w < 0.0 else 1.0
    Q[0], Q[1], Q[2], Q[3] = sg * w, sg * x, sg * y, sg * z


def free_body_rates(Q, w_b, inertia, dQ, dw_b):
    """``dQ/dt = 1/2 Q (x) [0, w_b]`` and Euler's torque-free equations (module docstring)."""
    w, x, y, z = Q[0], Q[1], Q[2], Q[3]
    p, q, r = w_b[0], w_b[1], w_b[2]
    dQ[0] = 0.5 * (-x * p - y * q - z * r)
    dQ[1] = 0.5 * (w * p + y * r - z * q)
    dQ[2] = 0.5 * (w * q + z * p - x * r)
    dQ[3] = 0.5 * (w * r + x * q - y * p)
    I1, I2, I3 = inertia[0], inertia[1], inertia[2]
    dw_b[0] = (I2 - I3) * q * r / I1 if I1 > 0.0 else 0.0
    dw_b[1] = (I3 - I1) * r * p / I2 if I2 > 0.0 else 0.0
    dw_b[2] = (I1 - I2) * p * q / I3 if I3 > 0.0 else 0.0


def merge_into_link(row, mass, com, inertia, R_rel, out):
    """Link row ``out`` (16: ``d, a, alpha, m, c, I`` of the kernels' link table) of link
    ``row`` with a body rigidly attached: ``mass`` [kg], its COM ``com`` (3) and principal
    ``inertia`` (3) along the axes ``R_rel`` (row-major 9), both in the link frame::

        m = m_0 + m_p,  c = (m_0 c_0 + m_p c_p) / m,
        I = I_0 + m_0 (|d_0|^2 E - d_0 d_0^T) + R_rel diag(I_p) R_rel^T
              + m_p (|d_p|^2 E - d_p d_p^T),      d_k = c_k - c   (parallel axes)
    """
    for k in range(16):
        out[k] = row[k]
    m0 = row[3]
    m = m0 + mass
    if m <= 0.0:
        return
    cx = (m0 * row[4] + mass * com[0]) / m
    cy = (m0 * row[5] + mass * com[1]) / m
    cz = (m0 * row[6] + mass * com[2]) / m
    d0x, d0y, d0z = row[4] - cx, row[5] - cy, row[6] - cz
    dpx, dpy, dpz = com[0] - cx, com[1] - cy, com[2] - cz
    s0 = d0x * d0x + d0y * d0y + d0z * d0z
    sp = dpx * dpx + dpy * dpy + dpz * dpz
    out[3] = m
    out[4], out[5], out[6] = cx, cy, cz
    for a in range(3):
        d0a = d0x if a == 0 else (d0y if a == 1 else d0z)
        dpa = dpx if a == 0 else (dpy if a == 1 else dpz)
        for b in range(3):
            d0b = d0x if b == 0 else (d0y if b == 1 else d0z)
            dpb = dpx if b == 0 else (dpy if b == 1 else dpz)
            e = 1.0 if a == b else 0.0
            Ib = 0.0
            for k in range(3):
                Ib += R_rel[3 * a + k] * inertia[k] * R_rel[3 * b + k]
            out[7 + 3 * a + b] = (row[7 + 3 * a + b] + m0 * (s0 * e - d0a * d0b) + Ib
                                  + mass * (sp * e - dpa * dpb))




quat_to_rot = jit_kernel(quat_to_rot)
rot_to_quat = jit_kernel(rot_to_quat)
free_body_rates = jit_kernel(free_body_rates)
merge_into_link = jit_kernel(merge_into_link)
