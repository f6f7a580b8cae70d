"""Exercise 6 solved independently of slamlib (NumPy only).

Each contract function has its own code (a bug planted in one must not reach the
others): ``edge_error`` with rotation matrices, ``build_linear_system`` with a loop
over edges and a dense ``H``, ``gauss_newton_step`` with its own vectorised
assembly (``np.add.at``) and a dense solve.
"""

import numpy as np


def wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def _R(a):
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


def edge_error(xi, xj, z):
    Ri, Rz = _R(xi[2]), _R(z[2])
    d = xj[:2] - xi[:2]
    dRiT = np.array([[-np.sin(xi[2]), np.cos(xi[2])], [-np.cos(xi[2]), -np.sin(xi[2])]])
    e = np.zeros(3)
    e[:2] = Rz.T @ (Ri.T @ d - z[:2])
    e[2] = wrap(xj[2] - xi[2] - z[2])
    A = np.zeros((3, 3))
    A[:2, :2] = -Rz.T @ Ri.T
    A[:2, 2] = Rz.T @ dRiT @ d
    A[2, 2] = -1.0
    B = np.zeros((3, 3))
    B[:2, :2] = Rz.T @ Ri.T
    B[2, 2] = 1.0
    return e, A, B


def _edge(xi, xj, z):
    """The same edge written with the angle sum a = theta_i + theta_z (R_z^T R_i^T = R(a)^T)."""
    a = xi[2] + z[2]
    c, s = np.cos(a), np.sin(a)
    dx, dy = xj[0] - xi[0], xj[1] - xi[1]
    cz, sz = np.cos(z[2]), np.sin(z[2])
    e = np.array([c * dx + s * dy - (cz * z[0] + sz * z[1]), -s * dx + c * dy - (-sz * z[0] + cz * z[1]),
                  (xj[2] - xi[2] - z[2] + np.pi) % (2 * np.pi) - np.pi])
    B = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    A = np.array([[-c, -s, -s * dx + c * dy], [s, -c, -c * dx - s * dy], [0.0, 0.0, -1.0]])
    return e, A, B


def build_linear_system(X, edges, Z, Omega):
    n = X.shape[0]
    H = np.zeros((3 * n, 3 * n))
    b = np.zeros(3 * n)
    for k in range(len(edges)):
        i, j = int(edges[k, 0]), int(edges[k, 1])
        e, A, B = _edge(X[i], X[j], Z[k])
        W = Omega[k]
        si, sj = slice(3 * i, 3 * i + 3), slice(3 * j, 3 * j + 3)
        H[si, si] += A.T @ W @ A
        H[si, sj] += A.T @ W @ B
        H[sj, si] += B.T @ W @ A
        H[sj, sj] += B.T @ W @ B
        b[si] += A.T @ W @ e
        b[sj] += B.T @ W @ e
    return H, b


def gauss_newton_step(X, edges, Z, Omega):
    n, E = X.shape[0], edges.shape[0]
    xi, xj = X[edges[:, 0]], X[edges[:, 1]]
    a = xi[:, 2] + Z[:, 2]
    c, s = np.cos(a), np.sin(a)
    d = xj[:, :2] - xi[:, :2]
    cz, sz = np.cos(Z[:, 2]), np.sin(Z[:, 2])
    e = np.column_stack([c * d[:, 0] + s * d[:, 1] - (cz * Z[:, 0] + sz * Z[:, 1]),
                         -s * d[:, 0] + c * d[:, 1] - (-sz * Z[:, 0] + cz * Z[:, 1]),
                         np.arctan2(np.sin(xj[:, 2] - xi[:, 2] - Z[:, 2]), np.cos(xj[:, 2] - xi[:, 2] - Z[:, 2]))])
    J = np.zeros((E, 3, 6))
    J[:, 0, :2] = np.column_stack([-c, -s])
    J[:, 1, :2] = np.column_stack([s, -c])
    J[:, 0, 2] = -s * d[:, 0] + c * d[:, 1]
    J[:, 1, 2] = -c * d[:, 0] - s * d[:, 1]
    J[:, 2, 2] = -1.0
    J[:, 0, 3:5] = np.column_stack([c, s])
    J[:, 1, 3:5] = np.column_stack([-s, c])
    J[:, 2, 5] = 1.0
    JtW = np.einsum("kri,krs->kis", J, Omega)
    blocks = np.einsum("kis,ksj->kij", JtW, J)
    grads = np.einsum("kis,ks->ki", JtW, e)
    idx = np.concatenate([3 * edges[:, :1] + np.arange(3), 3 * edges[:, 1:] + np.arange(3)], axis=1)
    H = np.zeros((3 * n, 3 * n))
    g = np.zeros(3 * n)
    np.add.at(H, (idx[:, :, None], idx[:, None, :]), blocks)
    np.add.at(g, idx, grads)
    step = np.linalg.solve(H[3:, 3:], -g[3:])
    out = X.copy()
    out[1:] += step.reshape(-1, 3)
    out[1:, 2] = np.arctan2(np.sin(out[1:, 2]), np.cos(out[1:, 2]))
    out[1:, 2] = np.where(out[1:, 2] >= np.pi, out[1:, 2] - 2 * np.pi, out[1:, 2])
    return out


def icp_align(P, Q):
    mp, mq = P.mean(axis=0), Q.mean(axis=0)
    C = (Q - mq).T @ (P - mp)
    U, _, Vt = np.linalg.svd(C)
    D = np.diag([1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    return R, mq - R @ mp
