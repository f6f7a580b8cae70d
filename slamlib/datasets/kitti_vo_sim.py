"""A simulated stereo drive shaped like the KITTI one, with known true poses, pixel noise and wrong tracks.

:func:`simulate_stereo_drive` builds a street (points on two facades and the road) along a
gently turning path, looks at it with the calibrated stereo rig of
:func:`slamlib.datasets.load_kitti_vo`, and returns the stereo measurements in the same
:class:`~slamlib.datasets.StereoVOData` record, whose ``T_wc`` are then the *true* poses.
Landmark tracks break as a feature tracker's do (each continues to the next frame with
probability ``keep``; a point seen again later is a new landmark; tracks of one frame are
dropped, as in the shipped data), pixels carry Gaussian noise, and a fraction
``outlier_rate`` of the measurements of every frame are wrong tracks: their pixels are those
of another landmark of the same frame (a wrong match keeps a plausible disparity).
"""

from __future__ import annotations

import numpy as np

from .._checks import as_count, as_probability, as_scalar, check_rng
from .kitti_vo import StereoVOData

__all__ = ["simulate_stereo_drive"]

#: The KITTI rig of the shipped drive: fx = fy, cx, cy [px], baseline [m], image size [px].
_FX, _CX, _CY, _B, _W, _H = 718.856, 607.1928, 185.2157, 0.5371657189, 1241, 376


def simulate_stereo_drive(*, rng, n_frames=77, step=0.9, noise_px=0.5, outlier_rate=0.05, keep=0.6,
                          max_turn=0.02, max_depth=100.0, density=52.0):
    """A seeded stereo drive with known truth, for testing visual odometry beyond one log.

    Parameters
    ----------
    rng : numpy.random.Generator, keyword-only
        All draws: the path's turn rates, the street's points, track breaks, noise, wrong tracks.
    n_frames : int, keyword-only
        Frames, at least 2.
    step : float, keyword-only
        Distance between frames [m] (positive).
    noise_px : float, keyword-only
        Standard deviation of the pixel noise of ``uL``, ``uR`` and ``v`` [px] (non-negative).
    outlier_rate : float, keyword-only
        Fraction of each frame's measurements that are wrong tracks, in [0, 1).
    keep : float, keyword-only
        Probability that a track continues to the next frame where its point is seen.
    max_turn : float, keyword-only
        Largest heading change between frames [rad] (non-negative); the turn rate is a smooth random walk.
    max_depth : float, keyword-only
        Points farther than this from the camera are not seen [m]; one at depth ``Z`` beyond
        15 m is found in a frame with probability ``15 / Z``.
    density : float, keyword-only
        Points per metre of street.

    Returns
    -------
    StereoVOData
        ``T_wc`` are the true camera-to-world poses (camera z forward, y down; the first is the identity).
    """
    check_rng(rng)
    F = as_count(n_frames, "n_frames", minimum=2)
    step = as_scalar(step, "step", positive=True)
    noise = as_scalar(noise_px, "noise_px", nonnegative=True)
    rate = as_probability(outlier_rate, "outlier_rate")
    if rate >= 1:
        raise ValueError(f"outlier_rate must be smaller than 1, got {rate}")
    keep = as_probability(keep, "keep")
    max_turn = as_scalar(max_turn, "max_turn", nonnegative=True)
    max_depth = as_scalar(max_depth, "max_depth", positive=True)
    density = as_scalar(density, "density", positive=True)
    K = np.array([[_FX, 0.0, _CX], [0.0, _FX, _CY], [0.0, 0.0, 1.0]])
    # the path: heading psi about the camera's y axis (down), a smooth random turn rate
    turn = np.clip(np.cumsum(rng.normal(0.0, 0.25 * max_turn, F)), -max_turn, max_turn)
    psi = np.concatenate([[0.0], np.cumsum(turn[1:])])
    c, s = np.cos(psi), np.sin(psi)
    pos = np.zeros((F, 3))
    pos[1:, 0] = np.cumsum(step * s[:-1])
    pos[1:, 2] = np.cumsum(step * c[:-1])
    T = np.zeros((F, 4, 4))
    T[:, 0, 0], T[:, 0, 2], T[:, 2, 0], T[:, 2, 2] = c, s, -s, c
    T[:, 1, 1] = T[:, 3, 3] = 1.0
    T[:, :3, 3] = pos
    # the street: facades 4-14 m to each side (heights 1.6 m below to 8 m above the camera) and the road
    length = step * (F - 1) + max_depth + 10.0
    n = int(density * length)
    arc = rng.uniform(-10.0, length, n)
    frac = np.clip(arc / step, 0, F - 1)
    k0 = np.minimum(frac.astype(np.int64), F - 2)
    w = (frac - k0)[:, None]
    centre = (1 - w) * pos[k0] + w * pos[k0 + 1] + np.outer(np.maximum(arc, 0) - np.clip(arc, 0, step * (F - 1)),
                                                           [0.0, 0.0, 1.0])
    ang = (1 - w[:, 0]) * psi[k0] + w[:, 0] * psi[k0 + 1]
    normal = np.column_stack([np.cos(ang), np.zeros(n), -np.sin(ang)])
    road = rng.random(n) < 0.25
    side = np.where(rng.random(n) < 0.5, -1.0, 1.0)
    lateral = np.where(road, rng.uniform(-8.0, 8.0, n), side * rng.uniform(4.0, 14.0, n))
    height = np.where(road, 1.65, rng.uniform(-8.0, 1.6, n))
    X = centre + lateral[:, None] * normal
    X[:, 1] = height
    # what each frame sees
    R_cw = np.transpose(T[:, :3, :3], (0, 2, 1))
    Pc = np.einsum("fij,nj->fni", R_cw, X) - np.einsum("fij,fj->fi", R_cw, pos)[:, None, :]
    Z = Pc[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uL = _FX * Pc[..., 0] / Z + _CX
        uR = _FX * (Pc[..., 0] - _B) / Z + _CX
        v = _FX * Pc[..., 1] / Z + _CY
    seen = (Z > 2.0) & (Z < max_depth) & (uR >= 0) & (uL < _W) & (v >= 0) & (v < _H)
    seen &= rng.random(Z.shape) * np.maximum(Z, 1.0) < 15.0  # a feature far away is found less often
    # tracks: a new landmark where a point is first seen, reappears, or its track breaks
    seen_t = seen.T  # (N, F)
    prev = np.zeros_like(seen_t)
    prev[:, 1:] = seen_t[:, :-1]
    start = seen_t & (~prev | (rng.random(seen_t.shape) >= keep))
    track = np.cumsum(start.ravel()).reshape(seen_t.shape) - 1
    pt, fr = np.nonzero(seen_t)  # sorted by point, then frame
    lm = track[pt, fr]
    counts = np.bincount(lm)
    ok = counts[lm] >= 2
    pt, fr, lm = pt[ok], fr[ok], np.unique(lm[ok], return_inverse=True)[1]
    order = np.lexsort((lm, fr))
    pt, fr, lm = pt[order], fr[order], lm[order]
    m = len(fr)
    dv = noise * rng.standard_normal(m)
    meas = np.column_stack([uL[fr, pt] + noise * rng.standard_normal(m), uR[fr, pt] + noise * rng.standard_normal(m),
                            v[fr, pt] + dv])
    # wrong tracks: the pixels of another measurement of the same frame
    starts = np.searchsorted(fr, np.arange(F + 1))
    bad = np.nonzero(rng.random(m) < rate)[0]
    lo, hi = starts[fr[bad]], starts[fr[bad] + 1]
    other = lo + (rng.random(bad.size) * (hi - lo)).astype(np.int64)
    meas[bad] = meas[other]
    meas[:, 1] = np.minimum(meas[:, 1], meas[:, 0] - 0.05)  # noise never flips a disparity's sign
    return StereoVOData(K, _B, T, fr.astype(np.int64), lm.astype(np.int64), meas[:, 0], meas[:, 1], meas[:, 2])
