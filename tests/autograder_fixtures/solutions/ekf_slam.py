"""Exercise 4 solved independently of slamlib (NumPy only), as a student would."""

import numpy as np


def wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def _motion(x, u, dt):
    px, py, th = x
    v, w = u
    if abs(w) < 1e-6:
        c, s = np.cos(th), np.sin(th)
        x_next = np.array([px + v * dt * c, py + v * dt * s, wrap(th + w * dt)])
        G = np.array([[1, 0, -v * dt * s], [0, 1, v * dt * c], [0, 0, 1.0]])
        V = np.array([[dt * c, -v * dt**2 * s / 2], [dt * s, v * dt**2 * c / 2], [0, dt]])
        return x_next, G, V
    r = v / w
    t2 = th + w * dt
    x_next = np.array([px - r * np.sin(th) + r * np.sin(t2), py + r * np.cos(th) - r * np.cos(t2), wrap(t2)])
    G = np.array([[1, 0, -r * np.cos(th) + r * np.cos(t2)], [0, 1, -r * np.sin(th) + r * np.sin(t2)], [0, 0, 1.0]])
    V = np.array([[(-np.sin(th) + np.sin(t2)) / w, v * (np.sin(th) - np.sin(t2)) / w**2 + v * np.cos(t2) * dt / w],
                  [(np.cos(th) - np.cos(t2)) / w, -v * (np.cos(th) - np.cos(t2)) / w**2 + v * np.sin(t2) * dt / w],
                  [0, dt]])
    return x_next, G, V


def ekf_slam_predict(mu, Sigma, u, dt, M):
    n = len(mu)
    x_next, Gx, V = _motion(mu[:3], u, dt)
    mu_bar = mu.copy()
    mu_bar[:3] = x_next
    F = np.zeros((3, n))
    F[:, :3] = np.eye(3)
    G = np.eye(n) + F.T @ (Gx - np.eye(3)) @ F
    Sigma_bar = G @ Sigma @ G.T + F.T @ (V @ M @ V.T) @ F
    return mu_bar, Sigma_bar


def _meas(mu, j):
    """Expected measurement and full-state Jacobian (private helper of update and association)."""
    n = len(mu)
    a = 3 + 2 * j
    dx, dy = mu[a] - mu[0], mu[a + 1] - mu[1]
    q = dx * dx + dy * dy
    r = np.sqrt(q)
    H = np.zeros((2, n))
    H[:, :3] = [[-dx / r, -dy / r, 0], [dy / q, -dx / q, -1]]
    H[:, a:a + 2] = [[dx / r, dy / r], [-dy / q, dx / q]]
    return np.array([r, wrap(np.arctan2(dy, dx) - mu[2])]), H


def ekf_slam_measurement(mu, j):
    n = len(mu)
    a = 3 + 2 * j
    dx, dy = mu[a] - mu[0], mu[a + 1] - mu[1]
    q = dx * dx + dy * dy
    r = np.sqrt(q)
    z_hat = np.array([r, wrap(np.arctan2(dy, dx) - mu[2])])
    h = np.array([[-dx / r, -dy / r, 0, dx / r, dy / r], [dy / q, -dx / q, -1, -dy / q, dx / q]])
    F = np.zeros((5, n))
    F[:3, :3] = np.eye(3)
    F[3, a] = F[4, a + 1] = 1.0
    return z_hat, h @ F


def ekf_slam_init_landmark(mu, z, j):
    out = mu.copy()
    a = 3 + 2 * j
    out[a] = mu[0] + z[0] * np.cos(z[1] + mu[2])
    out[a + 1] = mu[1] + z[0] * np.sin(z[1] + mu[2])
    return out


def ekf_slam_update(mu_bar, Sigma_bar, z, j, Q):
    z_hat, H = _meas(mu_bar, j)
    S = H @ Sigma_bar @ H.T + Q
    K = Sigma_bar @ H.T @ np.linalg.inv(S)
    nu = z - z_hat
    nu[1] = wrap(nu[1])
    mu = mu_bar + K @ nu
    mu[2] = wrap(mu[2])
    Sigma = (np.eye(len(mu)) - K @ H) @ Sigma_bar
    return mu, (Sigma + Sigma.T) / 2


def ekf_slam_associate(mu_bar, Sigma_bar, z, n_seen, Q, alpha):
    d = []
    for k in range(n_seen):
        z_hat, H = _meas(mu_bar, k)
        S = H @ Sigma_bar @ H.T + Q
        nu = z - z_hat
        nu[1] = wrap(nu[1])
        d.append(nu @ np.linalg.solve(S, nu))
    if n_seen == 0 or min(d) > alpha:
        return n_seen
    return int(np.argmin(d))
