"""Stereo measurements along the start of KITTI odometry sequence 00, with the shipped camera poses.

Files in ``slamlib/data/kitti_vo`` (see its ``ATTRIBUTION.md``; KITTI-derived, CC BY-NC-SA 3.0):
the rectified stereo calibration ``fx fy s cx cy b``, the left camera's poses (camera-to-world,
z forward) of 77 frames, and 52 544 stereo measurements ``(frame, landmark, uL, uR, v)`` of 15 638
tracked landmarks (pixels of the left and right images; the rectified pair shares ``v``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from . import data_path
from .._checks import as_count, as_index, check_type
from ._text import open_text

__all__ = ["StereoVOData", "load_kitti_vo", "stereo_vo_segment"]


class StereoVOData(NamedTuple):
    """The stereo visual-odometry data.

    Attributes
    ----------
    K : ndarray, shape (3, 3)
        Calibration of the left camera (the right one is the same, ``baseline`` to its right).
    baseline : float
        Stereo baseline [m].
    T_wc : ndarray, shape (F, 4, 4)
        The shipped poses of the left camera (camera-to-world), the reference trajectory.
    frame, landmark : ndarray of int, shape (M,)
    uL, uR, v : ndarray, shape (M,)
        Stereo measurements, sorted by frame then landmark.
    """

    K: np.ndarray
    baseline: float
    T_wc: np.ndarray
    frame: np.ndarray
    landmark: np.ndarray
    uL: np.ndarray
    uR: np.ndarray
    v: np.ndarray


def load_kitti_vo():
    """Load the stereo measurements, calibration and poses of the KITTI drive (77 frames, ~54 m)."""
    fx, fy, _, cx, cy, b = (float(v) for v in open_text(data_path("kitti_vo", "calibration_00s.txt.gz")).split())
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    poses = np.array(open_text(data_path("kitti_vo", "camera_poses_00s.txt.gz")).split(), dtype=np.float64)
    poses = poses.reshape(-1, 17)
    T = poses[np.argsort(poses[:, 0]), 1:].reshape(-1, 4, 4)
    rows = [ln for ln in open_text(data_path("kitti_vo", "stereo_00s.txt.gz")).splitlines() if not ln.startswith("#")]
    m = np.array(" ".join(rows).split(), dtype=np.float64).reshape(-1, 5)
    m = m[np.lexsort((m[:, 1], m[:, 0]))]
    return StereoVOData(K, b, T, m[:, 0].astype(np.int64), m[:, 1].astype(np.int64), m[:, 2], m[:, 3], m[:, 4])


def stereo_vo_segment(data, start, stop):
    """Frames ``start .. stop - 1`` of a stereo drive as a drive of their own (frames renumbered from 0).

    Parameters
    ----------
    data : StereoVOData
    start, stop : int
        ``0 <= start < stop - 1 < F``: at least two frames.

    Returns
    -------
    StereoVOData
        The measurements of those frames and their reference poses ``data.T_wc[start:stop]``.
    """
    check_type(data, StereoVOData, "data", "from load_kitti_vo or simulate_stereo_drive")
    F = len(data.T_wc)
    start = as_index(start, "start", F - 1)
    stop = as_count(stop, "stop", minimum=start + 2, maximum=F)
    sel = (data.frame >= start) & (data.frame < stop)
    return StereoVOData(data.K, data.baseline, data.T_wc[start:stop], data.frame[sel] - start, data.landmark[sel],
                        data.uL[sel], data.uR[sel], data.v[sel])
