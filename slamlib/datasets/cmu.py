"""CMU Wean Hall: occupancy map and a real laser/odometry log.

The data of the particle-filter localization assignment of CMU 16-831
(Statistical Techniques in Robotics), shipped in ``slamlib/data/cmu_wean``
(see its ``ATTRIBUTION.md``):

* ``wean.npz``: the 800 x 800 map of 10 cm cells, re-encoded losslessly from
  ``wean.dat`` (``free_permille`` uint16: the file's values times 1000, 65535
  for its ``-1`` "unknown").
* ``robotdata1.log.gz`` (135 s, 2218 lines) and ``robotdata2.log.gz`` (240 s,
  5377 lines): ``O x y theta ts`` odometry and
  ``L x y theta xl yl thetal r1 .. r180 ts`` laser scans, in centimetres.

Map values. The assignment's notes call the values occupancy probabilities,
but in the file open corridors hold values near 1 and walls values near 0, so
they are the probability of being **free**; :func:`load_cmu_map` returns
``occupancy = 1 - value``.

Orientation. The file's first index ``i`` (line of the map block) is world
``x = (i + 1/2) 0.1 m`` and the second index ``j`` is ``y = (j + 1/2) 0.1 m``
(the ``map[x][y]`` layout of the assignment's reader). In slamlib's grid
convention (row = y, column = x) the occupancy is therefore the transposed
array. Drawn with ``origin="lower"`` this reproduces the assignment's
``wean.gif`` (long corridor along the bottom, the two square rooms top right),
and the log's laser scans, which run counter-clockwise from the robot's right,
line up with the walls in this frame (placed by odometry from
``CMU_LOG_START``) but not in its mirror image (checked in
``tests/test_cmu.py``).

References
----------
Thrun, Burgard & Fox, *Probabilistic Robotics* (2005), Ch. 8 (Monte Carlo
localization, Table 8.2) on this kind of data; Sec. 5.4 (odometry, Table 5.5).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._checks import as_index
from ..maps import OccupancyGrid
from ..angles import wrap_angle
from ..motion import odometry_from_poses
from ._text import check_time_order, fail_rows, open_text

__all__ = ["CmuLog", "load_cmu_map", "load_cmu_log", "CMU_SENSOR_OFFSET", "CMU_MAX_RANGE", "CMU_RANGE_BIAS",
           "CMU_LOG_START", "CMU_LOG_STARTS"]

#: The laser sits 25 cm ahead of the robot centre (metres).
CMU_SENSOR_OFFSET = 0.25
#: Largest reading of the log's laser (8183 cm), its "no return" value (metres).
CMU_MAX_RANGE = 81.83
#: How much further the laser sees the walls than the faces of the map's occupied cells (metres): the
#: median of measured minus ray-cast range (threshold 0.9) over the beams within 1 m of the map's, at
#: the reference tracks of ``benchmarks/mcl_success.py``: 0.21 on log 1 and 0.19 on log 2
#: (``benchmarks/mcl_study.py`` prints both, chapter 5 shows them). The beam model's expected range
#: is the ray-cast one plus this (``MCLParams.range_bias``).
CMU_RANGE_BIAS = 0.2
#: Pose (map frame, metres/radians) of the log's first scan: in the doorway of the room north of the
#: long corridor, facing south. Found by scoring the first 240 scans, placed by odometry, with the
#: likelihood field over a grid of poses; a scan-matching estimate, not ground truth.
CMU_LOG_START = (40.0, 41.5, -1.6755)
#: Start pose of each shipped log (1: ``robotdata1``, 2: ``robotdata2``), found the same way. Log 2
#: starts in the same doorway; over its first 240 scans a look-alike doorway 12 m east (52.1, 40.6)
#: scores higher, and only tracking the whole log from each candidate tells them apart: from this
#: pose every scan's end points lie on walls (median distance <= 0.15 m), from the look-alike not.
CMU_LOG_STARTS = {1: CMU_LOG_START, 2: (39.66, 41.50, -1.635)}
_LOG_FILES = {1: "robotdata1.log.gz", 2: "robotdata2.log.gz"}
_RESOLUTION = 0.1
_N_BEAMS = 180


def _data_file(name):
    from . import data_path  # the package's resolver of shipped data

    return data_path("cmu_wean", name)


def _read_map(path):
    """The ``free_permille`` array of a map file, or a ValueError naming the file."""
    import zipfile

    try:
        with np.load(path, allow_pickle=False) as f:
            if not hasattr(f, "files") or "free_permille" not in f.files:
                raise ValueError(f"{path}: not a Wean Hall map (an .npz file with an array 'free_permille')")
            raw = f["free_permille"]
    except (OSError, EOFError, zipfile.BadZipFile) as e:
        raise ValueError(f"{path}: cannot read the map file (truncated or corrupt?): {e}") from e
    except ValueError as e:
        if str(e).startswith(str(path)):
            raise
        # numpy says "Cannot load file containing pickled data ..." for any file that is not .npy/.npz
        raise ValueError(f"{path}: not an .npz map file (truncated, corrupt or another format)") from e
    if raw.dtype != np.uint16 or raw.ndim != 2 or raw.shape[0] != raw.shape[1] or raw.size == 0:
        raise ValueError(f"{path}: 'free_permille' must be a square uint16 array, got {raw.dtype} {raw.shape}")
    if np.any((raw > 1000) & (raw != 65535)):
        raise ValueError(f"{path}: 'free_permille' holds values other than 0..1000 and 65535 (unknown)")
    return raw


def load_cmu_map(path=None):
    """The Wean Hall occupancy grid in metres.

    Parameters
    ----------
    path : str or pathlib.Path, optional
        A map in the shipped ``.npz`` format (``free_permille``, see the module
        docstring); default the shipped ``wean.npz``.

    Returns
    -------
    OccupancyGrid
        ``occupancy`` of shape (800, 800): probability of being occupied,
        ``1 - value`` of the file, NaN where the file says ``-1`` (unknown);
        ``resolution`` 0.1 m; ``origin`` (0, 0). Rows are y, columns x (see
        the module docstring for the orientation).

    Raises
    ------
    ValueError
        If the file is not a readable map (the message names the file).

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 9.1 (occupancy grid maps); map of the
    CMU 16-831 assignment (``cmu16831wean``).
    """
    path = _data_file("wean.npz") if path is None else Path(path)
    raw = _read_map(path)
    free = np.where(raw == 65535, np.nan, raw / 1000.0)
    # file index [i, j] is (x, y); the grid wants [row = y, col = x]
    return OccupancyGrid(occupancy=1.0 - free.T, resolution=_RESOLUTION, origin=np.zeros(2))


@dataclass(frozen=True, eq=False)
class CmuLog:
    """The Wean Hall robot log, in metres, radians and seconds.

    Attributes
    ----------
    odom_t : ndarray, shape (T,)
        Time stamps of the odometry (``O``) lines.
    odom : ndarray, shape (T, 3)
        Odometry poses ``[x, y, theta]`` (odometry frame, not the map frame).
    laser_t : ndarray, shape (L,)
        Time stamps of the scans (``L`` lines).
    laser_pose : ndarray, shape (L, 3)
        Odometry pose of the robot centre at each scan (interpolated by the
        recorder).
    laser_sensor_pose : ndarray, shape (L, 3)
        Odometry pose of the laser at each scan (25 cm ahead of the centre).
    ranges : ndarray, shape (L, 180)
        Ranges in metres; ``CMU_MAX_RANGE`` (81.83 m) means no return.
    angles : ndarray, shape (180,)
        Beam angles relative to the heading, ``-pi/2 + k pi/180``: from the
        robot's right, counter-clockwise (right to left).
    sensor_offset : float
        0.25 m, the laser's distance ahead of the centre.
    max_range : float
        81.83 m.

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 5.4 (odometry as controls, Table 5.5),
    Sec. 6.3 (range scans).
    """

    odom_t: np.ndarray
    odom: np.ndarray
    laser_t: np.ndarray
    laser_pose: np.ndarray
    laser_sensor_pose: np.ndarray
    ranges: np.ndarray
    angles: np.ndarray
    sensor_offset: float = CMU_SENSOR_OFFSET
    max_range: float = CMU_MAX_RANGE

    @property
    def n_scans(self):
        """Number of laser scans ``L``."""
        return self.ranges.shape[0]

    def controls(self):
        """Odometry controls between consecutive scans.

        Returns
        -------
        ndarray, shape (L, 3)
            Row ``k`` is ``[rot1, trans, rot2]`` taking ``laser_pose[k-1]`` to
            ``laser_pose[k]`` (:func:`~slamlib.motion.odometry_from_poses`);
            row 0 is zero (no motion before the first scan).

        References
        ----------
        Thrun, Burgard & Fox (2005), Table 5.5 lines 2-4.
        """
        u = np.zeros((self.n_scans, 3))
        if self.n_scans > 1:
            u[1:] = odometry_from_poses(self.laser_pose[:-1], self.laser_pose[1:])
        return u

    def steps(self, start=0, stop=None):
        """Iterate over scans as ``(t, u, ranges)``.

        Parameters
        ----------
        start, stop : int
            Range of scan indices (``stop`` exclusive, default all).

        Yields
        ------
        t : float
            Time of scan ``k``.
        u : ndarray, shape (3,)
            Odometry control ``[rot1, trans, rot2]`` since scan ``k - 1``
            (zero for ``k = 0``), see :meth:`controls`.
        ranges : ndarray, shape (180,)
            The scan, in metres.

        References
        ----------
        Thrun, Burgard & Fox (2005), Table 8.2 (MCL consumes ``u_t``, ``z_t`` pairs).
        """
        L = self.n_scans
        start = as_index(start, "start", L + 1)
        stop = L if stop is None else as_index(stop, "stop", L + 1)
        u = self.controls()
        for k in range(start, stop):
            yield float(self.laser_t[k]), u[k], self.ranges[k]


def _readonly(a):
    a = np.ascontiguousarray(a, dtype=float)
    a.setflags(write=False)
    return a


def _read_lines(path):
    """The text lines of a log (plain or gzip), or a ValueError naming the file."""
    return open_text(path, corrupt="cannot decompress the log (truncated or corrupt gzip file)",
                     undecodable="not a text log").splitlines()


def _parse_records(path, lines):
    """Numbers of the O and L records with their line numbers; ValueError naming file and line."""
    recs = {"O": ([], []), "L": ([], [])}
    for n, line in enumerate(lines, start=1):
        parts = line.split()
        if not parts:
            continue
        kind = parts[0]
        if not (kind == "O" and len(parts) == 5 or kind == "L" and len(parts) == 8 + _N_BEAMS):
            raise ValueError(f"{path}: line {n} is not an 'O' (5 fields) or 'L' ({8 + _N_BEAMS} fields) record")
        try:
            values = [float(v) for v in parts[1:]]
        except ValueError:
            bad = next(v for v in parts[1:] if not _is_float(v))
            raise ValueError(f"{path}: line {n}: field {bad!r} is not a number") from None
        recs[kind][0].append(values)
        recs[kind][1].append(n)
    return recs


def _is_float(v):
    try:
        float(v)
    except ValueError:
        return False
    return True


def _check_records(path, odo, las, line_o, line_l):
    """NaN/inf, negative ranges and time running backwards, reported with the file's line number."""
    for arr, lines in ((odo, line_o), (las, line_l)):
        fail_rows(path, ~np.all(np.isfinite(arr), axis=1), lines, "NaN or infinite value")
    fail_rows(path, np.any(las[:, 6:6 + _N_BEAMS] < 0, axis=1), line_l, "negative range")
    # time stamps in file order (O and L records interleaved) must not decrease
    lines = np.concatenate([line_o, line_l])
    order = np.argsort(lines, kind="stable")
    check_time_order(path, np.concatenate([odo[:, -1], las[:, -1]])[order], lines[order], unit=" s")


def load_cmu_log(path=None, *, log=1):
    """Parse a CMU 16-831 robot log into metres, radians and seconds.

    Parameters
    ----------
    path : str or pathlib.Path, optional
        A log file (plain text or ``.gz``); default the shipped log `log`.
    log : {1, 2}, keyword-only
        Which shipped log to read when `path` is omitted: 1 is
        ``robotdata1.log.gz`` (135 s; 1505 odometry lines, 713 scans), 2 is
        ``robotdata2.log.gz`` (240 s; 3126 odometry lines, 2251 scans).

    Returns
    -------
    CmuLog
        Odometry and scans, read-only arrays.

    Raises
    ------
    ValueError
        The message names the file and, where there is one, the line: a file
        that cannot be decompressed or is not text; a line that is neither a
        5-field ``O`` nor a 188-field ``L`` record; a field that is not a
        number; NaN or infinite values; a negative range; a time stamp smaller
        than the one before it (in file order); a file without scans.

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 5.4 (odometry), Sec. 6.3 (range
    finders); log of the CMU 16-831 assignment (``cmu16831wean``).
    """
    if path is None:
        if isinstance(log, bool) or log not in _LOG_FILES:
            raise ValueError(f"log must be one of {sorted(_LOG_FILES)}, got {log!r}")
        path = _data_file(_LOG_FILES[log])
    else:
        path = Path(path)
    recs = _parse_records(path, _read_lines(path))
    odo = np.array(recs["O"][0], dtype=float).reshape(-1, 4)
    las = np.array(recs["L"][0], dtype=float).reshape(-1, 7 + _N_BEAMS)
    line_o = np.array(recs["O"][1], dtype=np.intp)
    line_l = np.array(recs["L"][1], dtype=np.intp)
    if las.shape[0] == 0:
        raise ValueError(f"{path}: no 'L' (laser scan) record")
    _check_records(path, odo, las, line_o, line_l)
    cm = 0.01
    odom = odo[:, :3] * [cm, cm, 1.0]
    laser_pose = las[:, 0:3] * [cm, cm, 1.0]
    sensor_pose = las[:, 3:6] * [cm, cm, 1.0]
    for pose in (odom, laser_pose, sensor_pose):
        pose[:, 2] = wrap_angle(pose[:, 2])
    angles = -np.pi / 2 + np.arange(_N_BEAMS) * (np.pi / _N_BEAMS)
    return CmuLog(
        odom_t=_readonly(odo[:, 3]), odom=_readonly(odom), laser_t=_readonly(las[:, -1]),
        laser_pose=_readonly(laser_pose), laser_sensor_pose=_readonly(sensor_pose),
        ranges=_readonly(las[:, 6:6 + _N_BEAMS] * cm), angles=_readonly(angles),
    )
