"""Exercise 3 solved independently of slamlib (NumPy only), as a student would."""

import numpy as np


def normalize_log_weights(log_w):
    a = log_w - np.max(log_w)
    w = np.exp(a)
    return w / w.sum()


def effective_sample_size(w):
    w = np.asarray(w, dtype=float)
    return float(w.sum() ** 2 / np.sum(w**2))


def low_variance_resample(w, *, rng):
    w = np.asarray(w, dtype=float)
    w = w / w.sum()
    M = len(w)
    r = rng.uniform(0.0, 1.0 / M)
    c = w[0]
    i = 0
    out = np.empty(M, dtype=int)
    for m in range(M):
        U = r + m / M
        while U > c and i < M - 1:
            i += 1
            c += w[i]
        out[m] = i
    return out


def landmark_likelihood(particles, z, m, Q):
    dx = m[0] - particles[:, 0]
    dy = m[1] - particles[:, 1]
    z_hat = np.stack([np.hypot(dx, dy), np.arctan2(dy, dx) - particles[:, 2]], axis=1)
    nu = z - z_hat
    nu[:, 1] = (nu[:, 1] + np.pi) % (2 * np.pi) - np.pi
    Qi = np.linalg.inv(Q)
    d = np.einsum("ki,ij,kj->k", nu, Qi, nu)
    return np.exp(-0.5 * d) / (2 * np.pi * np.sqrt(np.linalg.det(Q)))
