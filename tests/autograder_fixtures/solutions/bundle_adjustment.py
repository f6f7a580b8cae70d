"""Exercise 7 solved independently of slamlib (NumPy only).

Each contract function has its own code: ``so3_exp`` by the Taylor series near 0,
``so3_log`` through the quaternion of ``R`` (Shepperd's method), ``project`` and
``triangulate`` with explicit loops over points, ``eight_point`` with a Kronecker
design matrix, the Schur complement with a loop over the point blocks.
"""

import numpy as np


def _hat(w):
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def so3_exp(w):
    w = np.asarray(w, dtype=float)
    a = np.linalg.norm(w)
    W = _hat(w)
    if a < 1e-4:
        A = 1.0 - a * a / 6.0 + a**4 / 120.0
        B = 0.5 - a * a / 24.0 + a**4 / 720.0
    else:
        A = np.sin(a) / a
        B = (1.0 - np.cos(a)) / (a * a)
    return np.eye(3) + A * W + B * W @ W


def so3_log(R):
    R = np.asarray(R, dtype=float)
    # quaternion (Shepperd): the largest of 4 candidates under the square root
    tr = np.trace(R)
    cands = [tr, R[0, 0], R[1, 1], R[2, 2]]
    k = int(np.argmax(cands))
    if k == 0:
        qw = 0.5 * np.sqrt(1.0 + tr)
        q = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / (4.0 * qw)
    else:
        i = k - 1
        j, l = (i + 1) % 3, (i + 2) % 3
        q = np.zeros(3)
        q[i] = 0.5 * np.sqrt(1.0 + R[i, i] - R[j, j] - R[l, l])
        q[j] = (R[j, i] + R[i, j]) / (4.0 * q[i])
        q[l] = (R[l, i] + R[i, l]) / (4.0 * q[i])
        qw = (R[l, j] - R[j, l]) / (4.0 * q[i])
    if qw < 0:
        q, qw = -q, -qw
    s = np.linalg.norm(q)
    if s == 0.0:
        return np.zeros(3)
    angle = 2.0 * np.arctan2(s, qw)
    return angle * q / s


def project(K, T_wc, P):
    R, t = T_wc[:3, :3], T_wc[:3, 3]
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    n = len(P)
    uv, Jp, Jx = np.zeros((n, 2)), np.zeros((n, 2, 6)), np.zeros((n, 2, 3))
    for k in range(n):
        X, Y, Z = R.T @ (P[k] - t)
        uv[k] = [fx * X / Z + cx, fy * Y / Z + cy]
        D = np.array([[fx / Z, 0.0, -fx * X / Z**2], [0.0, fy / Z, -fy * Y / Z**2]])
        Jp[k, :, :3] = -D
        Jp[k, :, 3:] = D @ _hat(np.array([X, Y, Z]))
        Jx[k] = D @ R.T
    return uv, Jp, Jx


def triangulate(K, T_wc1, T_wc2, uv1, uv2):
    Ps = []
    for T in (T_wc1, T_wc2):
        R, t = T[:3, :3], T[:3, 3]
        Ps.append(K @ np.hstack([R.T, (-R.T @ t)[:, None]]))
    out = np.zeros((len(uv1), 3))
    for k in range(len(uv1)):
        A = []
        for Pm, (u, v) in zip(Ps, (uv1[k], uv2[k])):
            A.append(u * Pm[2] - Pm[0])
            A.append(v * Pm[2] - Pm[1])
        X = np.linalg.svd(np.array(A))[2][-1]
        out[k] = X[:3] / X[3]
    return out


def _norm_T(x):
    c = x.mean(axis=0)
    s = np.sqrt(2.0) / np.mean(np.sqrt(((x - c) ** 2).sum(axis=1)))
    return np.array([[s, 0, -s * c[0]], [0, s, -s * c[1]], [0, 0, 1.0]])


def eight_point(x1, x2):
    T1, T2 = _norm_T(x1), _norm_T(x2)
    h1 = np.hstack([x1, np.ones((len(x1), 1))]) @ T1.T
    h2 = np.hstack([x2, np.ones((len(x2), 1))]) @ T2.T
    A = np.array([np.kron(b, a) for a, b in zip(h1, h2)])
    F = np.linalg.svd(A)[2][-1].reshape(3, 3)
    E = T2.T @ F @ T1
    U, _, Vt = np.linalg.svd(E)
    return U @ np.diag([1.0, 1.0, 0.0]) @ Vt


def _blocks(H, n_cameras):
    m = 6 * n_cameras
    n_pt = (H.shape[0] - m) // 3
    inv = [np.linalg.inv(H[m + 3 * j:m + 3 * j + 3, m + 3 * j:m + 3 * j + 3]) for j in range(n_pt)]
    return m, n_pt, inv


def schur_complement(H, b, n_cameras):
    m, n_pt, inv = _blocks(H, n_cameras)
    S = H[:m, :m].copy()
    s = b[:m].copy()
    for j in range(n_pt):
        sl_ = slice(m + 3 * j, m + 3 * j + 3)
        W = H[:m, sl_] @ inv[j]
        S -= W @ H[sl_, :m]
        s -= W @ b[sl_]
    return S, s


def back_substitute(H, b, n_cameras, dx_cameras):
    m, n_pt, inv = _blocks(H, n_cameras)
    out = np.zeros(3 * n_pt)
    for j in range(n_pt):
        sl_ = slice(m + 3 * j, m + 3 * j + 3)
        out[3 * j:3 * j + 3] = -inv[j] @ (b[sl_] + H[sl_, :m] @ dx_cameras)
    return out
