"""Exercise 6 solved independently of slamlib (NumPy only), with a loop over edges and a dense solve."""

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


def build_linear_system(X, edges, Z, Omega):
    n = X.shape[0]
    H = np.zeros((3 * n, 3 * n))
    b = np.zeros(3 * n)
    for k in range(len(edges)):
        i, j = int(edges[k, 0]), int(edges[k, 1])
        e, A, B = edge_error(X[i], X[j], Z[k])
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
    H, b = build_linear_system(X, edges, Z, Omega)
    dx = np.linalg.solve(H[3:, 3:], -b[3:])
    out = X.copy()
    out[1:] += dx.reshape(-1, 3)
    out[1:, 2] = wrap(out[1:, 2])
    return out


def icp_align(P, Q):
    mp, mq = P.mean(axis=0), Q.mean(axis=0)
    C = (Q - mq).T @ (P - mp)
    U, _, Vt = np.linalg.svd(C)
    D = np.diag([1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    return R, mq - R @ mp
