"""Exercise 5 solved independently of slamlib (NumPy only), with a loop over particles."""

import numpy as np


def wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def _h(x, m):
    dx, dy = m[0] - x[0], m[1] - x[1]
    q = dx * dx + dy * dy
    r = np.sqrt(q)
    return np.array([r, wrap(np.arctan2(dy, dx) - x[2])]), np.array([[dx / r, dy / r], [-dy / q, dx / q]])


def fastslam_init_landmark(x, z, Q):
    M = x.shape[0]
    mu = np.empty((M, 2))
    Sigma = np.empty((M, 2, 2))
    for k in range(M):
        mu[k] = x[k, :2] + z[0] * np.array([np.cos(x[k, 2] + z[1]), np.sin(x[k, 2] + z[1])])
        _, H = _h(x[k], mu[k])
        Hi = np.linalg.inv(H)
        Sigma[k] = Hi @ Q @ Hi.T
    return mu, Sigma


def fastslam_update_landmark(x, mu, Sigma, z, Q):
    M = x.shape[0]
    mu_new = np.empty((M, 2))
    Sigma_new = np.empty((M, 2, 2))
    w = np.empty(M)
    for k in range(M):
        z_hat, H = _h(x[k], mu[k])
        S = H @ Sigma[k] @ H.T + Q
        K = Sigma[k] @ H.T @ np.linalg.inv(S)
        nu = z - z_hat
        nu[1] = wrap(nu[1])
        mu_new[k] = mu[k] + K @ nu
        P = (np.eye(2) - K @ H) @ Sigma[k]
        Sigma_new[k] = (P + P.T) / 2
        w[k] = np.exp(-0.5 * nu @ np.linalg.solve(S, nu)) / (2 * np.pi * np.sqrt(np.linalg.det(S)))
    return mu_new, Sigma_new, w
