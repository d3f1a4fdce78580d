"""Plain-numpy reference for the payload tests: kinematics, mass matrix and momenta of a
standard-DH serial chain from its link table alone (no compiled kernel), and free rigid
bodies. Written independently of spidersim.multibody.kernels.

Link table ``P`` (n x 16): ``d, a, alpha, m, c (3), I (9)`` with the COM and the inertia
about it in link coordinates; ``A_i = Rz(q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``; joint i turns
about z_{i-1} through o_{i-1}.
"""
import numpy as np


def skew(r):
    return np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])


def frames(P, q):
    """[(R_k, o_k)] for k = 0..n."""
    out = [(np.eye(3), np.zeros(3))]
    T = np.eye(4)
    for i in range(len(P)):
        d, a, al = P[i, :3]
        ct, st, ca, sa = np.cos(q[i]), np.sin(q[i]), np.cos(al), np.sin(al)
        A = np.array([[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st],
                      [0.0, sa, ca, d], [0.0, 0.0, 0.0, 1.0]])
        T = T @ A
        out.append((T[:3, :3].copy(), T[:3, 3].copy()))
    return out


def point_jacobian(P, q, k, p):
    """6 x n Jacobian [linear; angular] of point ``p`` (base frame) fixed to link k (1..n)."""
    F = frames(P, q)
    J = np.zeros((6, len(P)))
    for j in range(k):
        z, o = F[j][0][:, 2], F[j][1]
        J[:3, j] = np.cross(z, p - o)
        J[3:, j] = z
    return J


def link_bodies(P, q):
    """Per link: (mass, COM in the base frame, inertia about it in the base frame, k)."""
    F = frames(P, q)
    out = []
    for i in range(len(P)):
        R, o = F[i + 1]
        c = o + R @ P[i, 4:7]
        out.append((P[i, 3], c, R @ P[i, 7:16].reshape(3, 3) @ R.T, i + 1))
    return out


def mass_matrix(P, q):
    M = np.zeros((len(P), len(P)))
    for m, c, I, k in link_bodies(P, q):
        J = point_jacobian(P, q, k, c)
        M += m * J[:3].T @ J[:3] + J[3:].T @ I @ J[3:]
    return M


def arm_momentum(P, q, qd):
    """(linear momentum, angular momentum about the base origin) of the links."""
    p, L = np.zeros(3), np.zeros(3)
    for m, c, I, k in link_bodies(P, q):
        J = point_jacobian(P, q, k, c)
        v, w = J[:3] @ qd, J[3:] @ qd
        p += m * v
        L += m * np.cross(c, v) + I @ w
    return p, L


def body_momentum(m, I_body, R, x, v, w):
    """(p, L about the base origin) of a rigid body: mass m, principal inertia I_body,
    axes R, COM x, COM velocity v, angular velocity w (base frame)."""
    Iw = R @ np.diag(I_body) @ R.T
    return m * v, m * np.cross(x, v) + Iw @ w


def rotation(axis_angle):
    """Rotation matrix of a rotation vector (Rodrigues)."""
    th = np.linalg.norm(axis_angle)
    if th == 0:
        return np.eye(3)
    K = skew(axis_angle / th)
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K
