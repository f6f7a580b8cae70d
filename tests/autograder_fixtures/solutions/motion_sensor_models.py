"""Exercise 1 solved independently of slamlib (NumPy and SciPy only), as a student would."""

import numpy as np
from scipy.special import ndtr


def wrap(a):
    return (np.asarray(a, dtype=float) + np.pi) % (2 * np.pi) - np.pi


def velocity_motion(x, u, dt):
    px, py, th = x
    v, w = u
    if abs(w) < 1e-6:
        c, s = np.cos(th), np.sin(th)
        x_next = np.array([px + v * dt * c, py + v * dt * s, wrap(th + w * dt)])
        G = np.array([[1.0, 0.0, -v * dt * s], [0.0, 1.0, v * dt * c], [0.0, 0.0, 1.0]])
        V = np.array([[dt * c, -v * dt**2 * s / 2], [dt * s, v * dt**2 * c / 2], [0.0, dt]])
        return x_next, G, V
    r = v / w
    th2 = th + w * dt
    x_next = np.array([px - r * np.sin(th) + r * np.sin(th2), py + r * np.cos(th) - r * np.cos(th2), wrap(th2)])
    G = np.array([[1.0, 0.0, -r * np.cos(th) + r * np.cos(th2)],
                  [0.0, 1.0, -r * np.sin(th) + r * np.sin(th2)],
                  [0.0, 0.0, 1.0]])
    V = np.array([
        [(-np.sin(th) + np.sin(th2)) / w, v * (np.sin(th) - np.sin(th2)) / w**2 + v * np.cos(th2) * dt / w],
        [(np.cos(th) - np.cos(th2)) / w, -v * (np.cos(th) - np.cos(th2)) / w**2 + v * np.sin(th2) * dt / w],
        [0.0, dt],
    ])
    return x_next, G, V


def sample_motion_model_odometry(x, u, alpha, *, rng):
    x = np.asarray(x, dtype=float)
    rot1, trans, rot2 = u
    a1, a2, a3, a4 = alpha
    M = x.shape[0]
    r1 = rot1 - rng.normal(0.0, np.sqrt(a1 * rot1**2 + a2 * trans**2), size=M)
    tr = trans - rng.normal(0.0, np.sqrt(a3 * trans**2 + a4 * (rot1**2 + rot2**2)), size=M)
    r2 = rot2 - rng.normal(0.0, np.sqrt(a1 * rot2**2 + a2 * trans**2), size=M)
    out = np.empty_like(x)
    out[:, 0] = x[:, 0] + tr * np.cos(x[:, 2] + r1)
    out[:, 1] = x[:, 1] + tr * np.sin(x[:, 2] + r1)
    out[:, 2] = wrap(x[:, 2] + r1 + r2)
    return out


def _normal(d, var):
    return np.exp(-0.5 * d**2 / var) / np.sqrt(2 * np.pi * var)


def motion_model_odometry(x_next, u, x, alpha):
    x_next = np.asarray(x_next, dtype=float)
    x = np.asarray(x, dtype=float)
    a1, a2, a3, a4 = alpha
    dx = x_next[:, 0] - x[:, 0]
    dy = x_next[:, 1] - x[:, 1]
    trans_h = np.hypot(dx, dy)
    rot1_h = wrap(np.arctan2(dy, dx) - x[:, 2])
    rot2_h = wrap(x_next[:, 2] - x[:, 2] - rot1_h)
    p1 = _normal(wrap(u[0] - rot1_h), a1 * rot1_h**2 + a2 * trans_h**2)
    p2 = _normal(u[1] - trans_h, a3 * trans_h**2 + a4 * (rot1_h**2 + rot2_h**2))
    p3 = _normal(wrap(u[2] - rot2_h), a1 * rot2_h**2 + a2 * trans_h**2)
    return p1 * p2 * p3


def landmark_measurement(x, m):
    dx, dy = m[0] - x[0], m[1] - x[1]
    q = dx**2 + dy**2
    r = np.sqrt(q)
    z_hat = np.array([r, wrap(np.arctan2(dy, dx) - x[2])])
    Hx = np.array([[-dx / r, -dy / r, 0.0], [dy / q, -dx / q, -1.0]])
    Hm = np.array([[dx / r, dy / r], [-dy / q, dx / q]])
    return z_hat, Hx, Hm


def landmark_from_measurement(x, z):
    return np.array([x[0] + z[0] * np.cos(x[2] + z[1]), x[1] + z[0] * np.sin(x[2] + z[1])])


def beam_range_finder_model(z, z_star, *, z_max, sigma_hit, lambda_short, w_hit, w_short, w_max, w_rand):
    z = np.asarray(z, dtype=float)
    z_star = np.asarray(z_star, dtype=float)
    eta = ndtr((z_max - z_star) / sigma_hit) - ndtr(-z_star / sigma_hit)
    p_hit = np.where(z <= z_max, _normal(z - z_star, sigma_hit**2) / eta, 0.0)
    p_short = np.where(z <= z_star, lambda_short * np.exp(-lambda_short * z) / (1 - np.exp(-lambda_short * z_star)), 0.0)
    p_max = np.where(z >= z_max, 1.0, 0.0)
    p_rand = np.where(z < z_max, 1.0 / z_max, 0.0)
    return w_hit * p_hit + w_short * p_short + w_max * p_max + w_rand * p_rand
