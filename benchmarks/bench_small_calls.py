"""Speed of one small Kalman/EKF call, against filterpy and a bare-NumPy limit timed in this run.

Run ``python benchmarks/bench_small_calls.py`` (needs the ``bench`` extra:
``pip install -e .[bench]`` for filterpy). On a 3-state problem (pose
``[x, y, theta]``, a 2-d measurement) it times, per call,

* ``sl.kf_predict`` / ``sl.kf_update`` against ``filterpy.kalman.predict`` /
  ``filterpy.kalman.update`` and against the same algebra written as bare NumPy
  expressions without any input check;
* ``sl.ekf_predict`` / ``sl.ekf_update`` (velocity motion model, range-bearing
  measurement of a known landmark) against filterpy's
  ``ExtendedKalmanFilter.predict`` / ``.update`` (the motion model, its
  Jacobians and the measurement model supplied as the same bare NumPy code)
  and against the bare expression of Table 7.2 itself;

and prints microseconds per call and the ratios ``slamlib / filterpy`` (target
<= 2) and ``slamlib / bare`` (target <= 3). The slamlib calls include their
input validation. A second table times ``kf_predict`` and ``kf_update`` at 2 to 6
states (2 measurements, correlated covariances) against filterpy, with the goal
``slamlib / filterpy <= 2`` at every size; as in a running filter, ``P`` changes
from call to call (the contestants cycle through 37 covariances) while ``F``,
``Q``, ``H`` and ``R`` stay. A second table times the batched calls (10,000 filters in
one call) in microseconds per filter, so a faster small path can be seen not to
slow the large one.

The three contestants of a row are timed in turn, block by block (200 calls,
a few milliseconds: short enough to fall between the neighbours' time slices on
a loaded machine), for 80 rounds, and each keeps its best block
(``time.perf_counter``; the minimum, as ``timeit`` advises, because on a
shared machine the slower blocks measure the neighbours); the whole run takes
about half a minute.
"""

from __future__ import annotations

import argparse
import itertools
import math
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

import slamlib as sl  # noqa: E402

try:
    import filterpy.kalman as fk
except ImportError:  # pragma: no cover - the bench extra is optional
    fk = None

SEED = 7
DT = 0.1
N_BATCH = 10_000


def per_call(fn, *, block=2000, repeats=7):
    """Minimum over `repeats` of the mean time of one call of ``fn()`` over a block, in us."""
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(block):
            fn()
        times.append((time.perf_counter() - t0) / block)
    return 1e6 * min(times)


# --------------------------------------------------------------------------- the problem
rng = np.random.default_rng(SEED)
A = rng.normal(size=(3, 3))
P = A @ A.T + 3.0 * np.eye(3)
x = np.array([1.0, 2.0, 0.3])
F = np.eye(3) + 0.1 * rng.normal(size=(3, 3))
Qk = np.diag([0.01, 0.02, 0.003])
H = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.5]])
Rk = np.diag([0.2, 0.3])
zk = np.array([1.1, 2.2])

mu = np.array([1.0, 2.0, 0.3])
Sigma = np.diag([0.05, 0.04, 0.01])
u = np.array([1.0, 0.2])
M = np.diag([0.1**2, np.deg2rad(5.0) ** 2])
Q = np.diag([0.2**2, np.deg2rad(3.0) ** 2])
m = np.array([6.0, 4.0])
z = np.array([5.9, 0.35])


# --------------------------------------------------------------------------- bare NumPy: the limit
def bare_kf_predict(x, P, F, Q):
    # x_bar = F x, P_bar = F P F^T + Q, symmetrised as slamlib does
    P_bar = F @ P @ F.T + Q
    return F @ x, 0.5 * (P_bar + P_bar.T)


def bare_kf_update(x, P, z, H, R):
    PHt = P @ H.T
    S = H @ PHt + R
    K = np.linalg.solve(S, PHt.T).T
    x_new = x + K @ (z - H @ x)
    P_new = P - K @ H @ P
    return x_new, 0.5 * (P_new + P_new.T)


def bare_motion(mu, u, dt):
    """Exact arc (Table 5.3) with its Jacobians G and V (Table 7.2 lines 3-4), omega != 0."""
    th = mu[2]
    v, w = u[0], u[1]
    r = v / w
    th2 = th + w * dt
    s, c, s2, c2 = math.sin(th), math.cos(th), math.sin(th2), math.cos(th2)
    x_next = np.array([mu[0] - r * s + r * s2, mu[1] + r * c - r * c2, (th2 + math.pi) % (2 * math.pi) - math.pi])
    G = np.array([[1.0, 0.0, -r * c + r * c2], [0.0, 1.0, -r * s + r * s2], [0.0, 0.0, 1.0]])
    V = np.array([
        [(-s + s2) / w, v * (s - s2) / w**2 + r * c2 * dt],
        [(c - c2) / w, -v * (c - c2) / w**2 + r * s2 * dt],
        [0.0, dt],
    ])
    return x_next, G, V


def bare_ekf_predict(mu, Sigma, u, dt, M):
    x_next, G, V = bare_motion(mu, u, dt)
    S = G @ Sigma @ G.T + V @ M @ V.T
    return x_next, 0.5 * (S + S.T)


def bare_measure(mu, m):
    dx, dy = m[0] - mu[0], m[1] - mu[1]
    q = dx * dx + dy * dy
    r = math.sqrt(q)
    z_hat = np.array([r, math.atan2(dy, dx) - mu[2]])
    H = np.array([[-dx / r, -dy / r, 0.0], [dy / q, -dx / q, -1.0]])
    return z_hat, H


def bare_ekf_update(mu, Sigma, z, m, Q):
    z_hat, H = bare_measure(mu, m)
    nu = z - z_hat
    nu[1] = (nu[1] + math.pi) % (2 * math.pi) - math.pi
    SHt = Sigma @ H.T
    S = H @ SHt + Q
    K = np.linalg.solve(S, SHt.T).T
    mu_new = mu + K @ nu
    mu_new[2] = (mu_new[2] + math.pi) % (2 * math.pi) - math.pi
    P = Sigma - K @ H @ Sigma
    return mu_new, 0.5 * (P + P.T)


# --------------------------------------------------------------------------- filterpy
def filterpy_ekf():
    """filterpy's ExtendedKalmanFilter with the velocity model plugged in (its usual subclassing)."""

    class VelocityEKF(fk.ExtendedKalmanFilter):
        def predict_x(self, u):
            self.x, self.F, V = bare_motion(self.x, u, DT)
            self.Q = V @ M @ V.T

    ekf = VelocityEKF(dim_x=3, dim_z=2)
    ekf.x = mu.copy()
    ekf.P = Sigma.copy()
    ekf.R = Q
    return ekf


def residual(a, b):
    d = a - b
    d[1] = (d[1] + math.pi) % (2 * math.pi) - math.pi
    return d


def rows_small():
    ekf_p = filterpy_ekf() if fk else None
    ekf_u = filterpy_ekf() if fk else None

    def fp_update():
        ekf_u.x = mu  # every call updates the same prior
        ekf_u.P = Sigma
        ekf_u.update(z, lambda s, lm: bare_measure(s, lm)[1], lambda s, lm: bare_measure(s, lm)[0],
                     args=(m,), hx_args=(m,), residual=residual)

    cases = [
        ("kf_predict", lambda: sl.kf_predict(x, P, F, Qk), (lambda: fk.predict(x, P, F, Qk)) if fk else None,
         lambda: bare_kf_predict(x, P, F, Qk)),
        ("kf_update", lambda: sl.kf_update(x, P, zk, H, Rk), (lambda: fk.update(x, P, zk, Rk, H)) if fk else None,
         lambda: bare_kf_update(x, P, zk, H, Rk)),
        ("ekf_predict", lambda: sl.ekf_predict(mu, Sigma, u, DT, M), (lambda: ekf_p.predict(u)) if fk else None,
         lambda: bare_ekf_predict(mu, Sigma, u, DT, M)),
        ("ekf_update", lambda: sl.ekf_update(mu, Sigma, z, m, Q), fp_update if fk else None,
         lambda: bare_ekf_update(mu, Sigma, z, m, Q)),
    ]
    rows = []
    for name, *fns in cases:
        t = interleaved([fn for fn in fns if fn is not None])
        if fns[1] is None:
            t.insert(1, float("nan"))
        rows.append((name, *t))
    return rows


SIZES = (2, 3, 4, 5, 6)
GOAL_FILTERPY = 2.0  # at every size: slamlib / filterpy <= 2
N_RING = 37  # distinct covariances P the calls of one row cycle through


def linear_problem(n, k=2, seed=SEED):
    """A linear-Gaussian filter with `n` states and `k` measurements (covariances with correlations)."""
    r = np.random.default_rng(seed + n)
    A = r.normal(size=(n, n))
    P = A @ A.T + n * np.eye(n)
    F = np.eye(n) + 0.1 * r.normal(size=(n, n))
    G = r.normal(size=(n, n))
    Qn = 0.01 * (G @ G.T + np.eye(n))
    H = np.eye(k, n) + 0.1 * r.normal(size=(k, n))
    R = np.diag(r.uniform(0.1, 0.3, size=k))
    return r.normal(size=n), P, F, Qn, H, R, r.normal(size=k)


def rows_sizes():
    """``kf_predict`` and ``kf_update`` at 2 to 6 states: slamlib, filterpy and bare NumPy, us per call."""
    rows = []
    for n in SIZES:
        xn, Pn, Fn, Qn, Hn, Rn, zn = linear_problem(n)
        # P changes from call to call, as in a running filter (F, Q, H and R stay): every call checks a new P
        ring = itertools.cycle([Pn + 0.01 * i * np.eye(n) for i in range(N_RING)])
        nx = ring.__next__
        for name, fns in (
            ("kf_predict", [lambda: sl.kf_predict(xn, nx(), Fn, Qn),
                            (lambda: fk.predict(xn, nx(), Fn, Qn)) if fk else None,
                            lambda: bare_kf_predict(xn, nx(), Fn, Qn)]),
            ("kf_update", [lambda: sl.kf_update(xn, nx(), zn, Hn, Rn),
                           (lambda: fk.update(xn, nx(), zn, Rn, Hn)) if fk else None,
                           lambda: bare_kf_update(xn, nx(), zn, Hn, Rn)]),
        ):
            t = interleaved([fn for fn in fns if fn is not None])
            if fns[1] is None:
                t.insert(1, float("nan"))
            rows.append((name, n, *t))
    return rows


def interleaved(fns, *, block=200, rounds=80):
    """Best mean time per call (us) of each of `fns`, timed in turn block by block, so that a
    change in the machine's load hits all of them alike."""
    for fn in fns:
        fn()
    best = [float("inf")] * len(fns)
    for _ in range(rounds):
        for i, fn in enumerate(fns):
            t0 = time.perf_counter()
            for _ in range(block):
                fn()
            best[i] = min(best[i], (time.perf_counter() - t0) / block)
    return [1e6 * b for b in best]


def rows_batched():
    r = np.random.default_rng(SEED)
    N = N_BATCH
    xs = x + 0.1 * r.normal(size=(N, 3))
    Ps = np.broadcast_to(P, (N, 3, 3)).copy()
    zs = zk + 0.1 * r.normal(size=(N, 2))
    mus = mu + 0.1 * r.normal(size=(N, 3))
    Sigmas = np.broadcast_to(Sigma, (N, 3, 3)).copy()
    us = u + 0.01 * r.normal(size=(N, 2))
    zz = z + 0.01 * r.normal(size=(N, 2))
    cases = [
        ("kf_predict", lambda: sl.kf_predict(xs, Ps, F, Qk)),
        ("kf_update", lambda: sl.kf_update(xs, Ps, zs, H, Rk)),
        ("ekf_predict", lambda: sl.ekf_predict(mus, Sigmas, us, DT, M)),
        ("ekf_update", lambda: sl.ekf_update(mus, Sigmas, zz, m, Q)),
    ]
    return [(name, per_call(fn, block=5, repeats=7) / N) for name, fn in cases]


def goal_verdict(ratios, measured):
    """The largest ratio and whether every one meets the goal; never "met" for a ratio not measured (NaN)."""
    if not measured:
        return "not measured (filterpy is not installed: pip install -e .[bench])"
    worst = float(np.max(ratios))  # NaN if any is NaN
    return f"{worst:.2f} ({'met' if all(r <= GOAL_FILTERPY for r in ratios) else 'MISSED'})"


def main(argv=None):
    argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter).parse_args(argv)
    print(f"one call on a 3-state problem (us per call; best of 80 interleaved blocks of 200 calls); filterpy "
          f"{'installed' if fk else 'NOT installed (pip install -e .[bench])'}")
    print(f"{'call':<12} {'slamlib':>9} {'filterpy':>9} {'bare':>9} {'sl/filterpy':>12} {'sl/bare':>8}")
    for name, s, f, b in rows_small():
        print(f"{name:<12} {s:9.2f} {f:9.2f} {b:9.2f} {s / f:12.2f} {s / b:8.2f}")
    print(f"\nthe linear Kalman filter at {SIZES[0]} to {SIZES[-1]} states (2 measurements; goal at every size: "
          f"slamlib / filterpy <= {GOAL_FILTERPY:g})")
    print(f"{'call':<12} {'n':>2} {'slamlib':>9} {'filterpy':>9} {'bare':>9} {'sl/filterpy':>12} {'sl/bare':>8}")
    ratios = []
    for name, n, s, f, b in rows_sizes():
        ratios.append(s / f)
        print(f"{name:<12} {n:2d} {s:9.2f} {f:9.2f} {b:9.2f} {s / f:12.2f} {s / b:8.2f}")
    print(f"largest slamlib / filterpy: {goal_verdict(ratios, fk is not None)}")
    print(f"\nbatched: {N_BATCH} filters in one call (us per filter)")
    for name, t in rows_batched():
        print(f"{name:<12} {t:9.3f}")


if __name__ == "__main__":
    main()
