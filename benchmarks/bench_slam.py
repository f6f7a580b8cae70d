"""Speed of EKF SLAM: the fast filter against a bare-numpy baseline and the teaching version.

Run ``python benchmarks/bench_slam.py`` (under two minutes). One EKF SLAM step
is a prediction plus 8 updates (8 landmarks in view) and ends with the
covariance up to date. Figures, all measured in this process:

* the fast :class:`slamlib.EKFSLAM` at ``N = 100`` and ``N = 400`` landmarks
  (targets: 1 ms and 5 ms per step);
* the bare-numpy floor of an update step: 8 rank-2 updates
  ``Sigma -= A @ B.T`` (``A``, ``B`` of shape ``(3+2N, 2)``) of the
  ``(3+2N) x (3+2N)`` covariance; the fast step should stay within 3x of it;
* the teaching version (contract functions, dense ``O(N^3)`` algebra);
* the size sweep: the fast step against the same floor at ``N = 10, 25, 50,
  100, 200, 400`` (goal: within 2x of the floor at every size, where the
  per-measurement Python overhead shows at small ``N``); the fast step and
  the floor are timed in alternating rounds so that both see the same load.
  ``--sweep`` prints only this table (a few seconds).

For context (not measured here): a PythonRobotics-style EKF SLAM, which builds
dense ``F_{x,j}`` and ``(I - K H) Sigma`` products, is quoted at 83 ms per step
at ``N = 100`` and 1.08 s at ``N = 400``.

Data association on a real log: an ordinary MRCLAM step (robot 2 of Dataset 6,
``dt = 0.1`` s, the loader's noise and gate) with unknown correspondences, from
the filter state Algorithm 2 has built after 300 s (association gates of one
sighting's width, ``MRCLAM_Q_SIGHTING``, as in chapter 9): a prediction, the
association of the step's sightings and the updates. Nearest neighbour
(Algorithm 2, one sighting at a time) against JCBB (all sightings of the step
jointly), over the next 3000 steps (all steps, and only those with two or more
sightings, where the joint test runs); the target is JCBB <= 3x NN.

If ``benchmarks/bench_fastslam.py`` defines ``fastslam_figures()``, its lines
are printed at the end under "FastSLAM"; then the Victoria Park case of
``benchmarks/victoria_park.py`` (EKF SLAM on the first 300 s of the real log,
the time of one scan's step against the number of landmarks, and the
bare-numpy floor at the same size).

Timings are medians over repeats (``time.perf_counter``). The fast filter
applies its pending rank-2 corrections to the dense covariance every 32
updates (4 steps here); the step time is the average over such a cycle of 4
steps, and a second row forces the dense covariance up to date after every
step. BLAS runs single-threaded (``OPENBLAS_NUM_THREADS=1`` and friends unless
set already): a filter step is a sequential workload, and the same setting
holds for the baseline.

References
----------
Course text, Algorithm 1; Thrun, Burgard & Fox, *Probabilistic Robotics*
(2005), Table 10.1 and Sec. 10.2.4 (the quadratic cost of EKF SLAM).
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import statistics
import time
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # before numpy loads BLAS

import numpy as np  # noqa: E402

import slamlib as sl  # noqa: E402

HERE = Path(__file__).resolve().parent
SEED = 20260
N_VIEW = 8
DT = 0.1
U = np.array([1.0, 0.1])
M = np.diag([0.05**2, 0.02**2])
Q = np.diag([0.1**2, np.deg2rad(2.0) ** 2])
REFERENCE_MS = {100: 83.0, 400: 1080.0}  # PythonRobotics-style EKF SLAM, quoted figures
TARGET_MS = {100: 1.0, 400: 5.0}
TARGET_RATIO = 3.0
SWEEP_SIZES = (10, 25, 50, 100, 200, 400)
SWEEP_TARGET = 2.0  # fast step / numpy floor at every size
J_VIEW = np.arange(N_VIEW)


def make_state(N, rng):
    """A filter-like state: robot at the origin, ``N`` landmarks, the first 8 within 4 m, an SPD covariance."""
    n = 3 + 2 * N
    mu = np.zeros(n)
    ang = np.linspace(-1.2, 1.2, N_VIEW)
    near = np.column_stack([3.0 * np.cos(ang), 3.0 * np.sin(ang)])
    far = rng.uniform(-50, 50, size=(N - N_VIEW, 2)) + np.array([0.0, 60.0])
    mu[3:] = np.vstack([near, far]).ravel()
    B = 0.05 * rng.standard_normal((n, 12))
    Sigma = B @ B.T + 0.01 * np.eye(n)  # correlated, well conditioned
    return mu, Sigma


def measurements(mu, rng):
    """Measurements of the 8 landmarks in view from the robot's current estimate."""
    z_hat, _, _ = sl.landmark_measurement(mu[:3], mu[3:3 + 2 * N_VIEW].reshape(N_VIEW, 2))
    return z_hat + rng.multivariate_normal(np.zeros(2), Q, size=N_VIEW)


def median_ms(fn, repeats):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times)


CYCLE = 4  # steps per refresh of the dense covariance (32 pending updates / 8 per step)


def bench_fast(N, rng, repeats, *, refresh_every_step=False):
    """Median ms per step; by default the mean over cycles of CYCLE steps (one dense refresh each)."""
    mu, Sigma = make_state(N, rng)
    filt = sl.EKFSLAM.from_state(mu, Sigma)
    n_steps = CYCLE if not refresh_every_step else 1
    zs = [measurements(mu, rng) for _ in range((repeats + 2) * n_steps)]
    it = iter(zs)

    def steps():
        for _ in range(n_steps):
            filt.step(U, DT, M, next(it), J_VIEW, Q)  # predict + 8 updates
        filt.Sigma  # noqa: B018  (the covariance is up to date at the end)

    for _ in range(2):  # warm-up
        steps()
    return median_ms(steps, repeats) / n_steps


def bench_plain(N, rng, repeats):
    mu, Sigma = make_state(N, rng)
    zs = [measurements(mu, rng) for _ in range(repeats + 1)]
    it = iter(zs)
    state = [mu, Sigma]

    def step():
        m, S = sl.ekf_slam_predict(state[0], state[1], U, DT, M)
        for j, z in enumerate(next(it)):
            m, S = sl.ekf_slam_update(m, S, z, j, Q)
        state[:] = [m, S]

    step()  # warm-up
    return median_ms(step, repeats)


def bench_numpy(N, rng, repeats):
    n = 3 + 2 * N
    Sigma = np.eye(n)
    AB = [(1e-4 * rng.standard_normal((n, 2)), 1e-4 * rng.standard_normal((n, 2))) for _ in range(N_VIEW)]

    def step():
        for A, B in AB:
            Sigma.__isub__(A @ B.T)  # Sigma -= A @ B.T

    step()
    return median_ms(step, repeats)


def bench_sweep(N, rng, rounds):
    """Median ms of the fast step (mean over a cycle of CYCLE steps) and of the floor, timed in alternating rounds."""
    mu, Sigma = make_state(N, rng)
    filt = sl.EKFSLAM.from_state(mu, Sigma)
    zs = iter([measurements(mu, rng) for _ in range((rounds + 2) * CYCLE)])
    n = 3 + 2 * N
    S = np.eye(n)
    AB = [(1e-4 * rng.standard_normal((n, 2)), 1e-4 * rng.standard_normal((n, 2))) for _ in range(N_VIEW)]

    def steps():
        for _ in range(CYCLE):
            filt.step(U, DT, M, next(zs), J_VIEW, Q)  # predict + 8 updates
        filt.Sigma  # noqa: B018  (the covariance is up to date at the end)

    def floor():
        for A, B in AB:
            S.__isub__(A @ B.T)  # Sigma -= A @ B.T

    def timed(fn):
        t0 = time.perf_counter()
        fn()
        return time.perf_counter() - t0

    for _ in range(2):  # warm-up
        steps()
        floor()
    fast, base = [], []
    for _ in range(rounds):
        fast.append(timed(steps) / CYCLE)
        base.append(timed(floor))
    return 1e3 * statistics.median(fast), 1e3 * statistics.median(base)


def sweep_rows(rng):
    rows = []
    for N in SWEEP_SIZES:
        fast, base = bench_sweep(N, rng, max(50, 20000 // N))
        ratio = fast / base
        rows.append((f"  fast / numpy 8 x rank-2, N={N} (step {fast * 1e3:.0f} us)", f"{ratio:.2f}x",
                     f"{base * 1e3:.1f} us (numpy)", "", f"<= {SWEEP_TARGET:g}x",
                     "PASS" if ratio <= SWEEP_TARGET else "MISS"))
    return rows


def print_table(rows):
    header = ("figure", "value", "baseline", "ratio", "target", "result")
    widths = [max(len(r[i]) for r in rows + [header]) for i in range(len(header))]
    for r in [header] + rows:
        print("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip())


JCBB_TARGET = 3.0


def bench_association(repeats=5):
    """Median ms per MRCLAM step with NN and with JCBB association, from the same filter state."""
    from slamlib.datasets.mrclam import MRCLAM_Q_SIGHTING, load_mrclam

    run = load_mrclam(2)
    t0, n = 3000, 3000
    Qa = np.array(MRCLAM_Q_SIGHTING)  # association gates of one sighting's width, as in chapter 9
    prefix = sl.run_ekf_slam(run, known=False, snapshots=(t0,), Q_association=Qa)
    mu, Sigma, _ = prefix.snapshots[t0]
    base = sl.EKFSLAM.from_state(mu, Sigma)
    alpha, alpha_j, gate, Q_run, M_run = sl.DEFAULT_ALPHA, sl.JCBB_ALPHA, run.gate, np.array(run.Q), np.array(run.M)
    steps = [(run.u[t], np.asarray(run.z[t])) for t in range(t0, t0 + n)]
    multi = [k for k, (_, z) in enumerate(steps) if len(z) >= 2]

    def nn_step(f, u, Z):
        f._predict(u, run.dt, M_run)
        for z in Z:
            j = f._associate(z, Qa, alpha)
            if j == f.n_landmarks:
                j = f._add_landmark(z)
            f._update(z, j, Q_run, gate)

    def jcbb_step(f, u, Z):
        f._predict(u, run.dt, M_run)
        pairing = f._jcbb(Z, Qa, alpha_j) if len(Z) > 1 else np.full(len(Z), sl.JCBB_NEW)
        for z, j in zip(Z, pairing.tolist()):
            if j == sl.JCBB_UNPAIRED:
                continue
            if j == sl.JCBB_NEW:
                j = f._associate(z, Qa, alpha)
            if j == f.n_landmarks:
                j = f._add_landmark(z)
            f._update(z, j, Q_run, gate)

    def timed(step_fn, which):
        # every step starts from the state the NN filter reached, so both methods see the same states
        states, f = [], base.copy()
        for u, Z in steps:
            states.append(f.copy())
            nn_step(f, u, Z)
        per = []
        for _ in range(repeats):
            t = np.empty(len(which))
            for i, k in enumerate(which):
                g = states[k].copy()
                u, Z = steps[k]
                t1 = time.perf_counter()
                step_fn(g, u, Z)
                t[i] = time.perf_counter() - t1
            per.append(t.mean())
        return 1e3 * statistics.median(per)

    every = list(range(len(steps)))
    return {"all": (timed(nn_step, every), timed(jcbb_step, every)),
            "multi": (timed(nn_step, multi), timed(jcbb_step, multi)),
            "n_multi": len(multi), "n": len(steps), "n_landmarks": base.n_landmarks}


def fastslam_lines():
    path = HERE / "bench_fastslam.py"
    if not path.is_file():
        return None
    spec = importlib.util.spec_from_file_location("bench_fastslam", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    if not hasattr(mod, "fastslam_figures"):
        return None
    return [str(line) for line in mod.fastslam_figures()]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sweep", action="store_true", help="only the size sweep (fast step / floor at N = 10..400)")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(SEED)
    rows = []
    t_start = time.perf_counter()
    threads = os.environ.get("OPENBLAS_NUM_THREADS")
    if args.sweep:
        print(f"EKF SLAM size sweep: one step = predict + 8 updates, median over alternating rounds "
              f"(OPENBLAS_NUM_THREADS={threads})")
        print_table(sweep_rows(rng))
        print(f"(measured in {time.perf_counter() - t_start:.1f} s)")
        return
    for N, reps, plain_reps in ((100, 400, 10), (400, 160, 3)):
        fast = bench_fast(N, rng, reps // CYCLE)
        forced = bench_fast(N, rng, reps, refresh_every_step=True)
        base = bench_numpy(N, rng, reps)
        plain = bench_plain(N, rng, plain_reps)
        ratio = fast / base
        rows.append((f"EKF SLAM step, N={N} [ms]", f"{fast:.3f}", f"{base:.3f} (numpy)", f"{ratio:.2f}",
                     f"<= {TARGET_MS[N]:g} ms", "PASS" if fast <= TARGET_MS[N] else "MISS"))
        rows.append((f"  fast / numpy 8 x rank-2, N={N}", f"{ratio:.2f}x", "", "", f"<= {TARGET_RATIO:g}x",
                     "PASS" if ratio <= TARGET_RATIO else "MISS"))
        rows.append((f"  dense Sigma refreshed every step, N={N} [ms]", f"{forced:.3f}", f"{base:.3f} (numpy)",
                     f"{forced / base:.2f}", f"<= {TARGET_MS[N]:g} ms", "PASS" if forced <= TARGET_MS[N] else "MISS"))
        rows.append((f"  teaching version, N={N} [ms]", f"{plain:.1f}", f"{fast:.3f} (fast)", f"{plain / fast:.0f}",
                     "-", "-"))
        rows.append((f"  PythonRobotics-style, N={N} [ms] (quoted)", f"{REFERENCE_MS[N]:g}", f"{fast:.3f} (fast)",
                     f"{REFERENCE_MS[N] / fast:.0f}", "-", "-"))
    assoc = bench_association()
    for key, label in (("all", f"all {assoc['n']} steps"), ("multi", f"{assoc['n_multi']} steps with >= 2 sightings")):
        nn, jc = assoc[key]
        rows.append((f"MRCLAM step, JCBB vs NN, {label} [ms]", f"{jc:.3f}", f"{nn:.3f} (NN)", f"{jc / nn:.2f}",
                     f"<= {JCBB_TARGET:g}x", "PASS" if jc / nn <= JCBB_TARGET else "MISS"))
    header = ("figure", "value", "baseline", "ratio", "target", "result")
    widths = [max(len(r[i]) for r in rows + [header]) for i in range(len(header))]
    threads = os.environ.get("OPENBLAS_NUM_THREADS")
    print(f"EKF SLAM: one step = predict + 8 updates, median over repeats (OPENBLAS_NUM_THREADS={threads})")
    for r in [header] + rows:
        print("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip())
    print(f"(measured in {time.perf_counter() - t_start:.1f} s)")
    lines = fastslam_lines()
    if lines is not None:
        print()
        print("FastSLAM")
        for line in lines:
            print(line)
    lines = victoria_lines()
    if lines is not None:
        print()
        print("Victoria Park (real log, the map grows to hundreds of landmarks)")
        for line in lines:
            print(line)


def victoria_lines():
    """Lines of ``benchmarks/victoria_park.py``'s ``victoria_figures()``, if that script is there."""
    path = HERE / "victoria_park.py"
    if not path.is_file():
        return None
    spec = importlib.util.spec_from_file_location("victoria_park", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return [str(line) for line in mod.victoria_figures()] if hasattr(mod, "victoria_figures") else None


if __name__ == "__main__":
    main()
