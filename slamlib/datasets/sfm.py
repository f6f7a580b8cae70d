"""Structure-from-motion data: SIFT keypoints of photographs, Bundler reconstructions, BAL problems.

Files in ``slamlib/data/sfm`` (see its ``ATTRIBUTION.md``): two photographs of the
Villa del Balbianello with their SIFT keypoints (Lowe's ``.key`` format), the
Bundler reconstruction ``Balbianello.out`` of five such photographs, and the
BAL problem ``dubrovnik-3-7-pre.txt``.

Both Bundler and BAL use a camera looking down its *negative* z axis with y up and
pixels centred on the image (``p = R X + t``, ``[x, y] = -f r(p) p_xy / p_z``,
``r = 1 + k1 |p|^2 + k2 |p|^4``). The loaders convert to the book's convention
(:mod:`slamlib.camera`): camera-to-world poses ``T_wc``, z forward, y down, pixels
``uv = [x, -y]`` with ``K = diag(f, f, 1)``, and remove the radial distortion from
the observations, so that the problem is a plain pinhole bundle adjustment.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from . import data_path
from ..lie import _so3_exp
from ._text import open_text

__all__ = ["SiftKeys", "load_balbianello_keys", "load_balbianello_image", "SfmProblem", "load_bundler",
           "load_bal", "load_balbianello", "load_dubrovnik"]

#: Size (width, height) of the Balbianello photographs in pixels.
BALBIANELLO_SIZE = (640, 427)


class SiftKeys(NamedTuple):
    """SIFT keypoints of one photograph.

    Attributes
    ----------
    uv : ndarray, shape (N, 2)
        Keypoint positions in pixels ``[column, row]``.
    descriptors : ndarray, shape (N, 128)
        SIFT descriptors (integers 0-255 stored as float64).
    scale, orientation : ndarray, shape (N,)
    K : ndarray, shape (3, 3)
        The camera's calibration (focal length of Bundler's reconstruction, principal
        point at the image centre ``((w - 1) / 2, (h - 1) / 2)``, where Bundler's
        observations line up with the keypoints).
    """

    uv: np.ndarray
    descriptors: np.ndarray
    scale: np.ndarray
    orientation: np.ndarray
    K: np.ndarray


def _read_keys(path):
    tok = np.array(open_text(path).split(), dtype=np.float64)
    n, d = int(tok[0]), int(tok[1])
    body = tok[2:].reshape(n, 4 + d)
    return body


def load_balbianello_keys(image):
    """SIFT keypoints of Balbianello photograph ``image`` (1 or 2), with its calibration."""
    if image not in (1, 2):
        raise ValueError(f"image must be 1 or 2 (the photographs shipped), got {image!r}")
    body = _read_keys(data_path("sfm", f"BalbianelloMedium-{image}.key.gz"))
    f = load_balbianello(undistort=False).K[image - 1, 0, 0]
    w, h = BALBIANELLO_SIZE
    K = np.array([[f, 0.0, (w - 1) / 2], [0.0, f, (h - 1) / 2], [0.0, 0.0, 1.0]])
    return SiftKeys(body[:, [1, 0]].copy(), body[:, 4:].copy(), body[:, 2].copy(), body[:, 3].copy(), K)


def load_balbianello_image(image):
    """Balbianello photograph ``image`` (1 or 2) as an RGB array ``(427, 640, 3)`` of ``uint8``.

    The JPEG files are stored gzipped (the repository keeps every data file compressed);
    they are decoded with Pillow, which matplotlib already requires.
    """
    import gzip
    import io

    from PIL import Image

    if image not in (1, 2):
        raise ValueError(f"image must be 1 or 2 (the photographs shipped), got {image!r}")
    raw = gzip.decompress(data_path("sfm", f"BalbianelloMedium-{image}.jpg.gz").read_bytes())
    return np.asarray(Image.open(io.BytesIO(raw)).convert("RGB"))


class SfmProblem(NamedTuple):
    """A bundle-adjustment problem in the book's camera convention.

    Attributes
    ----------
    T_wc : ndarray, shape (C, 4, 4)
        Camera poses (camera-to-world), the file's estimate.
    K : ndarray, shape (C, 3, 3)
        Calibration of each camera, ``diag(f, f, 1)`` (pixels centred on the image).
    points : ndarray, shape (P, 3)
        World points, the file's estimate.
    cam, point : ndarray of int, shape (O,)
        Camera and point of each observation.
    uv : ndarray, shape (O, 2)
        Observed pixels (x right, y down, centred), radial distortion removed when
        loaded with ``undistort=True``.
    distortion : ndarray, shape (C, 2)
        The file's ``k1, k2`` of each camera.
    key : ndarray of int, shape (O,)
        The keypoint index the file gives for each observation (Bundler's own
        numbering, not the order of the shipped ``.key`` files; -1 for BAL).
    """

    T_wc: np.ndarray
    K: np.ndarray
    points: np.ndarray
    cam: np.ndarray
    point: np.ndarray
    uv: np.ndarray
    distortion: np.ndarray
    key: np.ndarray


def _from_file_cameras(R_b, t_b, f, k, points, cam, point, xy, key, undistort):
    """Convert Bundler/BAL cameras (world-to-camera, -z forward, y up) to the book's convention."""
    D = np.array([1.0, -1.0, -1.0])
    R_cw = D[:, None] * R_b
    t_cw = D * t_b
    T = np.zeros((len(f), 4, 4))
    T[:, :3, :3] = np.swapaxes(R_cw, 1, 2)
    T[:, :3, 3] = -np.einsum("cji,cj->ci", R_cw, t_cw)
    T[:, 3, 3] = 1.0
    K = np.zeros((len(f), 3, 3))
    K[:, 0, 0] = K[:, 1, 1] = f
    K[:, 2, 2] = 1.0
    uv = xy * np.array([1.0, -1.0])
    if undistort:
        # solve |p_d| = r(|p|) |p| for the undistorted normalised radius by fixed-point iteration
        fc, k1, k2 = f[cam], k[cam, 0], k[cam, 1]
        rd = np.linalg.norm(uv, axis=1) / fc
        r = rd.copy()
        for _ in range(50):
            r = rd / (1.0 + k1 * r**2 + k2 * r**4)
        uv = uv / (1.0 + k1 * r**2 + k2 * r**4)[:, None]
    return SfmProblem(T, K, points, cam, point, uv, k, key)


def load_bundler(path, *, undistort=True):
    """Read a Bundler ``.out`` file (v0.3) as an :class:`SfmProblem`.

    References
    ----------
    N. Snavely, *Bundler v0.4 user's manual* (the ``bundle.out`` format).
    """
    lines = [ln for ln in open_text(path).splitlines() if not ln.startswith("#")]
    n_cam, n_pt = (int(v) for v in lines[0].split())
    cams = np.array(" ".join(lines[1:1 + 5 * n_cam]).split(), dtype=np.float64).reshape(n_cam, 15)
    pts, cam, point, key, xy = [], [], [], [], []
    pos = 1 + 5 * n_cam
    for j in range(n_pt):
        pts.append([float(v) for v in lines[pos].split()])
        view = lines[pos + 2].split()
        m = int(view[0])
        v = np.array(view[1:1 + 4 * m], dtype=np.float64).reshape(m, 4)
        cam.append(v[:, 0].astype(np.int64))
        key.append(v[:, 1].astype(np.int64))
        xy.append(v[:, 2:])
        point.append(np.full(m, j, dtype=np.int64))
        pos += 3
    f, k = cams[:, 0], cams[:, 1:3]
    R_b = cams[:, 3:12].reshape(n_cam, 3, 3)
    t_b = cams[:, 12:15]
    return _from_file_cameras(R_b, t_b, f, k, np.array(pts), np.concatenate(cam), np.concatenate(point),
                              np.concatenate(xy), np.concatenate(key), undistort)


def load_bal(path, *, undistort=True):
    """Read a BAL problem file ("Bundle Adjustment in the Large") as an :class:`SfmProblem`.

    References
    ----------
    S. Agarwal, N. Snavely, S. M. Seitz, R. Szeliski, "Bundle adjustment in the large", ECCV 2010.
    """
    tok = open_text(path).split()
    n_cam, n_pt, n_obs = (int(v) for v in tok[:3])
    obs = np.array(tok[3:3 + 4 * n_obs], dtype=np.float64).reshape(n_obs, 4)
    rest = np.array(tok[3 + 4 * n_obs:], dtype=np.float64)
    cams = rest[:9 * n_cam].reshape(n_cam, 9)
    pts = rest[9 * n_cam:9 * n_cam + 3 * n_pt].reshape(n_pt, 3)
    return _from_file_cameras(_so3_exp(cams[:, :3]), cams[:, 3:6], cams[:, 6], cams[:, 7:9], pts,
                              obs[:, 0].astype(np.int64), obs[:, 1].astype(np.int64), obs[:, 2:],
                              np.full(n_obs, -1, dtype=np.int64), undistort)


def load_balbianello(*, undistort=True):
    """Bundler's reconstruction of five photographs of the Villa del Balbianello (5 cameras, 544 points)."""
    return load_bundler(data_path("sfm", "Balbianello.out.gz"), undistort=undistort)


def load_dubrovnik(*, undistort=True):
    """The BAL problem ``dubrovnik-3-7-pre`` (3 cameras, 7 points, 19 observations)."""
    return load_bal(data_path("sfm", "dubrovnik-3-7-pre.txt.gz"), undistort=undistort)
