"""Input generators and checks shared by the exercises' test cases."""

from __future__ import annotations

import numpy as np

from ..context import Out, wrap

__all__ = ["random_pose", "random_cov", "fd_jacobian", "OUT_POSE", "spd", "check_fd"]

OUT_POSE = Out("x_next", (3,))


def random_pose(rng, extent=5.0, heading=None):
    """A pose ``[x, y, theta]`` with position in ``[-extent, extent]^2``."""
    th = rng.uniform(-np.pi, np.pi) if heading is None else heading
    return np.array([rng.uniform(-extent, extent), rng.uniform(-extent, extent), th])


def spd(rng, n, scale=1.0, cond=20.0):
    """A random symmetric positive-definite ``(n, n)`` matrix with a bounded condition number."""
    A = rng.standard_normal((n, n))
    Qm, _ = np.linalg.qr(A)
    eig = scale * np.exp(rng.uniform(0.0, np.log(cond), size=n)) / cond
    S = (Qm * eig) @ Qm.T
    return 0.5 * (S + S.T)


def random_cov(rng, n, scale=1.0):
    return spd(rng, n, scale)


def fd_jacobian(f, x0, h=1e-6, angle_out=None):
    """Central finite differences of ``f`` (a vector function) at ``x0``.

    ``angle_out``: output indices that are angles; their differences are wrapped.
    """
    x0 = np.asarray(x0, dtype=float)
    cols = []
    for i in range(x0.size):
        e = np.zeros_like(x0)
        e[i] = h
        d = np.asarray(f(x0 + e), dtype=float) - np.asarray(f(x0 - e), dtype=float)
        if angle_out is not None:
            d = d.copy()
            d[list(angle_out)] = wrap(d[list(angle_out)])
        cols.append(d / (2 * h))
    return np.stack(cols, axis=-1)


def check_fd(ctx, name, analytic, numeric, *, atol=1e-5, rtol=1e-4):
    """Compare an analytic Jacobian with finite differences (message says so)."""
    ctx.close(name, analytic, numeric, atol=atol, rtol=rtol,
              note="(compared with central finite differences of your own function's value)")
