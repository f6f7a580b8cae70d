"""Speed of the localization filters, each figure against a baseline timed in this run.

Run ``python benchmarks/bench_localization.py``. It prints a table of

(a) one particle-filter step with landmark measurements (velocity-model
    sample, likelihood of 5 range-bearing measurements, systematic
    resampling) at M = 100,000 particles, in microseconds per particle,
    against the reference figure of 19.5 us per particle of a
    Python-loop-per-particle implementation, and against such a loop
    (written below, in the style of common teaching code: small NumPy arrays
    per particle, one Python iteration per particle and landmark) timed here
    at M = 2,000;
(b) ``slamlib.systematic_resample`` against a bare NumPy
    ``cumsum`` + ``searchsorted`` resampler on 100,000 weights;
(c) Monte Carlo localization with the likelihood field (10,000 particles, every
    10th of the 180 beams) over the whole CMU Wean Hall log 1, from a uniform
    start, against real time: the duration of the log divided by the time the
    filter took (target >= 10x). The beam model (ray casting pre-cached per
    cell and direction, ``MCLParams.ray_cache_angles``; same particles and
    beams) over the first 100 filter steps is printed beside it for
    comparison.

Times are medians over repeats (``time.perf_counter``). The whole run takes well
under two minutes.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

import slamlib as sl  # noqa: E402

REFERENCE_LOOP_US = 19.5  # us per particle per step of a Python-loop-per-particle filter
N_PARTICLES = 100_000
N_LOOP = 2_000
N_LANDMARKS = 5
DT = 0.1
SEED = 2024


def median_time(fn, repeats, warmup=1):
    """Median wall time of ``fn()`` over `repeats` calls, after `warmup` calls."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def scenario(n, rng):
    """Particles around a pose, 5 landmarks, their measurements and the noise models."""
    x_true = np.array([0.0, 0.0, 0.3])
    landmarks = np.array([[6.0, 1.0], [2.0, 7.0], [-5.0, 3.0], [-1.0, -6.0], [5.0, -4.0]])[:N_LANDMARKS]
    Q = np.diag([0.2**2, np.deg2rad(3.0) ** 2])
    M = np.diag([0.1**2, np.deg2rad(5.0) ** 2])
    u = np.array([1.0, 0.2])
    x_next, _, _ = sl.velocity_motion(x_true, u, DT)
    z_hat, _, _ = sl.landmark_measurement(x_next, landmarks)
    z = z_hat + rng.normal(size=z_hat.shape) * np.sqrt(np.diag(Q))
    particles = x_true + rng.normal(size=(n, 3)) * [0.3, 0.3, 0.05]
    return particles, u, z, landmarks, M, Q


# --------------------------------------------------------------------------- the Python-loop baseline
def loop_pf_step(particles, weights, u, z, landmarks, M, Q, rng):
    """One particle-filter step with one Python iteration per particle (and per landmark).

    Written the way many teaching implementations are: each particle is a small
    NumPy column vector moved by a matrix product, each likelihood a scalar
    Gaussian, resampling with Table 4.4's loop.
    """
    n = particles.shape[0]
    sv, sw = math.sqrt(M[0, 0]), math.sqrt(M[1, 1])
    sr, sb = math.sqrt(Q[0, 0]), math.sqrt(Q[1, 1])
    out = np.zeros((n, 3))
    w = np.zeros(n)
    for i in range(n):
        x = particles[i].reshape(3, 1)
        ud = np.array([[u[0] + rng.normal() * sv], [u[1] + rng.normal() * sw]])
        th = x[2, 0]
        if abs(ud[1, 0]) > 1e-9:
            r = ud[0, 0] / ud[1, 0]
            dx = np.array([[-r * math.sin(th) + r * math.sin(th + ud[1, 0] * DT)],
                           [r * math.cos(th) - r * math.cos(th + ud[1, 0] * DT)],
                           [ud[1, 0] * DT]])
        else:
            dx = np.array([[ud[0, 0] * DT * math.cos(th)], [ud[0, 0] * DT * math.sin(th)], [0.0]])
        x = x + dx
        x[2, 0] = (x[2, 0] + math.pi) % (2 * math.pi) - math.pi
        p = weights[i]
        for k in range(landmarks.shape[0]):
            ddx = landmarks[k, 0] - x[0, 0]
            ddy = landmarks[k, 1] - x[1, 0]
            dr = z[k, 0] - math.hypot(ddx, ddy)
            db = (z[k, 1] - (math.atan2(ddy, ddx) - x[2, 0]) + math.pi) % (2 * math.pi) - math.pi
            p *= math.exp(-0.5 * (dr / sr) ** 2) / (math.sqrt(2 * math.pi) * sr)
            p *= math.exp(-0.5 * (db / sb) ** 2) / (math.sqrt(2 * math.pi) * sb)
        out[i] = x[:, 0]
        w[i] = p
    w = w / w.sum()
    # low-variance resampling, Table 4.4
    idx = np.zeros(n, dtype=int)
    r0 = rng.uniform(0.0, 1.0 / n)
    c, j = w[0], 0
    for m in range(n):
        U = r0 + m / n
        while U > c and j < n - 1:
            j += 1
            c += w[j]
        idx[m] = j
    return out[idx], np.full(n, 1.0 / n)


# --------------------------------------------------------------------------- figures
def pf_figures():
    rng = np.random.default_rng(SEED)
    particles, u, z, landmarks, M, Q = scenario(N_PARTICLES, rng)
    log_w = np.full(N_PARTICLES, -math.log(N_PARTICLES))

    def vec_step():
        sl.particle_filter_step(particles, log_w, u, z, landmarks, DT, M, Q, rng=rng, resample="systematic",
                                ess_threshold=1.0)

    t_vec = median_time(vec_step, repeats=9) / N_PARTICLES * 1e6
    small, u2, z2, lm2, M2, Q2 = scenario(N_LOOP, np.random.default_rng(SEED + 1))
    w_small = np.full(N_LOOP, 1.0 / N_LOOP)
    t_loop = median_time(lambda: loop_pf_step(small, w_small, u2, z2, lm2, M2, Q2, rng), repeats=3) / N_LOOP * 1e6
    return t_vec, t_loop


def resample_figures():
    rng = np.random.default_rng(SEED)
    w = rng.random(N_PARTICLES)

    def bare():
        c = np.cumsum(w)
        c /= c[-1]
        n = w.size
        idx = np.searchsorted(c, rng.uniform(0.0, 1.0 / n) + np.arange(n) / n)
        return np.minimum(idx, n - 1)

    t_lib = median_time(lambda: sl.systematic_resample(w, rng=rng), repeats=31)
    t_bare = median_time(bare, repeats=31)
    return t_lib, t_bare


def mcl_figures():
    from slamlib.datasets import cmu

    grid, log = cmu.load_cmu_map(), cmu.load_cmu_log()
    duration = float(log.laser_t[-1] - log.laser_t[0])
    out = {}
    cpu = {}
    # the library default (Augmented MCL with sensor resetting), plain MCL (Table 8.2) with the same
    # particles as its baseline in the same run, plain MCL with twice the particles, the beam model
    cases = (("default", "likelihood_field", None, "augmented", None), ("plain", "likelihood_field", None, "mcl", None),
             ("plain20k", "likelihood_field", None, "mcl", 20_000), ("beam", "beam", 100, "mcl", None))
    for key, name, max_steps, variant, n in cases:
        params = sl.MCLParams(sensor_offset=log.sensor_offset, z_max=log.max_range, model=name)
        if n is not None:
            params = dataclasses.replace(params, n_particles=n)
        if variant == "mcl":  # Table 8.2 as printed: uniform start, the estimate at the mode's mean
            params = dataclasses.replace(params, init_candidates=0, estimate_radius=0.0)
        model = sl.prepare_mcl(grid, params)
        cpu0 = time.process_time()
        res = sl.run_mcl(model, log.laser_pose, log.ranges, log.angles, rng=np.random.default_rng(0),
                         times=log.laser_t, max_steps=max_steps, variant=variant)
        cpu[key] = time.process_time() - cpu0  # CPU time of this process: what the run costs on an idle core
        covered = float(res.t[-1] - log.laser_t[0]) if max_steps else duration
        out[key] = (params, len(res), res.runtime, covered)
    return duration, out, cpu


def main(argv=None):
    argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter).parse_args(argv)
    t_start = time.perf_counter()
    t_vec, t_loop = pf_figures()
    t_lib, t_bare = resample_figures()
    rows = [
        # figure, value, baseline, ratio, target, pass
        (f"(a) PF step, M={N_PARTICLES:,}, {N_LANDMARKS} landmarks [us/particle]", f"{t_vec:.3f}",
         f"{REFERENCE_LOOP_US} (reference loop)", f"{REFERENCE_LOOP_US / t_vec:.1f}x", "<= 1 us, >= 20x",
         t_vec <= 1.0 and REFERENCE_LOOP_US / t_vec >= 20),
        (f"(a) PF step vs Python loop (M={N_LOOP:,}) measured now", f"{t_vec:.3f}",
         f"{t_loop:.2f} (loop, us/particle)", f"{t_loop / t_vec:.1f}x", ">= 20x", t_loop / t_vec >= 20),
        (f"(b) systematic_resample, M={N_PARTICLES:,} [ms]", f"{t_lib * 1e3:.3f}",
         f"{t_bare * 1e3:.3f} (cumsum+searchsorted)", f"{t_lib / t_bare:.2f}x", "<= 2x", t_lib / t_bare <= 2.0),
    ]
    head = ("figure", "value", "baseline", "ratio", "target", "")
    widths = [max(len(str(r[i])) for r in rows + [head]) for i in range(5)]
    print("Localization benchmarks (median of repeats, time.perf_counter)")
    print("  ".join(h.ljust(wd) for h, wd in zip(head, widths)))
    print("  ".join("-" * wd for wd in widths) + "  ----")
    for r in rows:
        print("  ".join(str(c).ljust(wd) for c, wd in zip(r[:5], widths)) + "  " + ("PASS" if r[5] else "MISS"))
    factor = t_loop / REFERENCE_LOOP_US
    print(f"\nThe Python loop ran at {t_loop:.1f} us/particle here, {factor:.2f}x the reference figure: on the "
          f"reference machine the vectorised step would take about {t_vec / factor:.2f} us/particle.")
    duration, mcl, cpu = mcl_figures()
    p, steps, runtime, covered = mcl["default"]
    n_beams = len(range(0, 180, p.beam_step))
    factor = duration / runtime
    _, _, t_plain, _ = mcl["plain"]
    _, _, t_20k, _ = mcl["plain20k"]
    print(f"\n(c) MCL with the library defaults (Augmented MCL, sensor resetting, M={p.n_particles:,}, "
          f"{p.augmented.candidates:,} candidates, start from the first scan with {p.init_candidates:,} candidates), "
          f"likelihood field, {n_beams} of 180 beams, CMU Wean Hall log 1 "
          f"({duration:.0f} s, {steps} filter steps):")
    print(f"    {runtime:.2f} s for the whole log = {factor:.0f}x real time (baseline: the log's own duration); "
          f"target >= 10x  {'PASS' if factor >= 10 else 'MISS'}; by the process's CPU time "
          f"{duration / cpu['default']:.0f}x (what an idle core would give)")
    print(f"    plain MCL (Table 8.2), same particles, same run: {t_plain:.2f} s = {duration / t_plain:.0f}x real time; "
          f"the default costs {runtime / t_plain:.2f}x plain MCL and {runtime / t_20k:.2f}x plain MCL with 20 000 "
          f"particles ({t_20k:.2f} s)")
    p, steps, runtime, covered = mcl["beam"]
    print(f"    beam model (pre-cached ray casting), plain MCL, same particles and beams, first {steps} steps "
          f"({covered:.0f} s of log): "
          f"{runtime:.2f} s = {covered / runtime:.1f}x real time")
    print(f"\n(total {time.perf_counter() - t_start:.1f} s)")


if __name__ == "__main__":
    main()
