"""Victoria Park (Sydney): a car driving among trees, turned into a landmark-SLAM run.

A utility car drove for about 26 minutes through Victoria Park, Sydney, with a
SICK laser scanner at its front; the trunks of the trees were extracted from
the scans as point landmarks. The data set (Guivant & Nebot 2001) holds

* ``inputs.dat``: ``time [s], speed [m/s], steering angle [rad]`` at 40 Hz;
  the speed is that of an encoder on the **rear left wheel**;
* ``measurements.dat``: ``time [s], range [m], bearing [rad], trunk diameter
  [m]``, one row per tree detection, several rows per laser scan (about
  5 scans a second). The raw bearing runs over ``[0, pi]`` with ``pi / 2``
  straight ahead (the scanner's 180-degree field of view, right to left);
* ``gps.dat``: ``time [s], x [m], y [m]`` from a GPS receiver that failed at
  times: the fixes have gaps (up to a minute) and jumps;
* ``info.txt``: the car geometry ``a, b, H, L`` (see
  :func:`slamlib.ackermann_motion`).

:func:`load_victoria_park` turns the log into the kind of run the EKF SLAM and
FastSLAM drivers take (fixed time steps ``dt``, one averaged control per step,
the step's detections), with **unknown correspondences** (``ids`` are all
``-1``) and **no ground truth** but the GPS fixes, and with the bearing
converted to the book's convention, ``phi = raw - pi / 2`` (0 straight ahead,
positive to the left).

Bad input is never repaired silently: a missing, truncated or corrupt file, a
line that is not the expected numbers, a NaN or inf, time going backwards, a
non-positive range, a bearing outside ``[0, pi]`` or a negative diameter raise
a ``ValueError`` naming the file and the line.

References
----------
J. Guivant, E. Nebot, "Optimization of the simultaneous localization and
map-building algorithm for real-time implementation", IEEE Transactions on
Robotics and Automation 17(3):242-257, 2001. Thrun, Burgard & Fox,
*Probabilistic Robotics* (2005), Eq. 6.40 (range-bearing measurements).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._checks import as_array, as_covariance, as_scalar
from ..motion import AckermannModel
from ..scoring import align_se2
from . import data_path
from ._text import check_time_order, fail_rows, open_text
from .mrclam import _hold_average

__all__ = ["VictoriaRun", "load_victoria_park", "read_victoria_table", "read_car_geometry", "car_model", "victoria_gps_ate",
           "VICTORIA_DT", "VICTORIA_M", "VICTORIA_Q"]

#: Time step (seconds) of the run: two input records (40 Hz), so a detection
#: is at most 25 ms (15 cm at the car's top speed) from its step's end.
VICTORIA_DT = 0.05
#: Control noise ``M`` of ``[v_e, alpha]`` at ``dt = VICTORIA_DT``: standard
#: deviations of 0.5 m/s and 3 degrees per step (encoder slip on grass and the
#: steering sensor's offset; the order of magnitude the Victoria Park
#: literature uses, chosen before any run and not tuned). Scaled by
#: ``VICTORIA_DT / dt`` for other steps (white control errors).
VICTORIA_M = np.diag([0.5**2, np.deg2rad(3.0) ** 2])
#: Measurement noise ``Q`` of ``[r, phi]``: 0.5 m and 1 degree. The laser itself
#: is accurate to centimetres and half a degree; the error that matters is
#: where the tree detector puts the trunk's centre, of the order of the trunk
#: radius (median diameter 0.42 m, up to 1.5 m).
VICTORIA_Q = np.diag([0.5**2, np.deg2rad(1.0) ** 2])
VICTORIA_M.setflags(write=False)
VICTORIA_Q.setflags(write=False)

_FILES = {"inputs": ("inputs.dat", 3), "measurements": ("measurements.dat", 4), "gps": ("gps.dat", 3)}


@dataclass(frozen=True, eq=False)
class VictoriaRun:
    """The Victoria Park log on a fixed time grid (see :func:`load_victoria_park`).

    Step ``k`` applies ``u[k]`` for ``dt`` seconds and then observes ``z[k]``,
    like the simulator's landmark runs, so :func:`slamlib.run_ekf_slam` and
    :func:`slamlib.run_fastslam` take it (with ``known=False`` and
    ``motion=run.motion``).

    Attributes
    ----------
    landmarks : ndarray, shape (0, 2)
        No surveyed landmarks (kept for the drivers' interface).
    dt : float
        Time step, seconds.
    x0 : ndarray, shape (3,)
        Initial laser pose, ``[0, 0, 0]``: the map frame is the start.
    u : ndarray, shape (T, 2)
        ``[v_e, alpha]`` averaged over each step (each input held until the
        next record).
    z : tuple of T ndarrays, shape (K_k, 2)
        Tree detections ``[r, phi]`` of step ``k`` in the book's convention
        (``phi = raw - pi / 2``).
    ids : tuple of T int ndarrays, shape (K_k,)
        All ``-1``: the correspondences are unknown.
    diameters : tuple of T ndarrays, shape (K_k,)
        Trunk diameter of each detection, metres.
    M, Q : ndarray, shape (2, 2)
        Control and measurement noise covariances (modelling choices).
    t : ndarray, shape (T + 1,)
        Step times, seconds since ``t_start``.
    t_start : float
        Log time of step 0 (the first input record).
    gps : ndarray, shape (G, 3)
        GPS fixes ``[t, x, y]`` within the run, ``t`` since ``t_start``.
    car : dict
        Car geometry ``a, b, H, L`` (metres) as ``info.txt`` gives it
        (``a`` from the front axle, see :func:`car_model`).
    motion : AckermannModel
        The car's motion model with that geometry (:func:`car_model`).
    counts : dict
        Records by fate: ``"inputs"``, ``"detections"`` (kept),
        ``"outside"`` (detections outside the time window or beyond
        `max_range`, dropped), ``"gps"`` (fixes kept).
    """

    landmarks: np.ndarray
    dt: float
    x0: np.ndarray
    u: np.ndarray
    z: tuple
    ids: tuple
    diameters: tuple
    M: np.ndarray
    Q: np.ndarray
    t: np.ndarray
    t_start: float
    gps: np.ndarray
    car: dict
    motion: AckermannModel
    counts: dict = field(default_factory=dict)

    @property
    def n_steps(self) -> int:
        """Number of control steps ``T``."""
        return int(self.u.shape[0])

    @property
    def n_sightings(self) -> int:
        """Number of tree detections in the run."""
        return int(sum(len(i) for i in self.ids))


def _open_text(directory: Path, name: str) -> tuple[Path, str]:
    """Text of ``name`` or ``name.gz`` in `directory`; a clear error for a missing or corrupt file."""
    for path in (directory / (name + ".gz"), directory / name):
        if path.exists():
            break
    else:
        raise FileNotFoundError(f"Victoria Park file {name}(.gz) not found in {directory}")
    return path, open_text(path, corrupt="corrupt or truncated file", undecodable="corrupt or truncated file")


def read_victoria_table(path, ncols):
    """Read a numeric table of the data set, checking every line.

    Parameters
    ----------
    path : str or Path
        A ``.dat`` or ``.dat.gz`` file of whitespace-separated numbers; blank
        lines are skipped.
    ncols : int
        Numbers expected on every line.

    Returns
    -------
    rows : ndarray, shape (N, ncols)
        The numbers, float64.
    lines : ndarray of int, shape (N,)
        The 1-based line number of each row in the file (for error messages).

    Raises
    ------
    ValueError
        For a corrupt or truncated gzip file, a line without exactly `ncols`
        numbers, a NaN or inf, or no data at all; the message names the file
        and the line.
    """
    path = Path(path)
    _, text = _open_text(path.parent, path.name.removesuffix(".gz"))
    return _parse(path, text, ncols)


def _parse(path, text, ncols):
    lines = text.splitlines()
    keep = [i for i, line in enumerate(lines) if line.strip()]
    if not keep:
        raise ValueError(f"{path}: no data rows")
    try:
        rows = np.loadtxt([lines[i] for i in keep], ndmin=2, dtype=np.float64)
        ok = rows.shape[1] == ncols
    except ValueError:
        ok = False
    if not ok:  # find the first bad line, for the message
        for i in keep:
            parts = lines[i].split()
            try:
                vals = [float(p) for p in parts]
            except ValueError:
                vals = None
            if vals is None or len(vals) != ncols:
                raise ValueError(f"{path}, line {i + 1}: expected {ncols} numbers, got {lines[i].strip()[:80]!r}")
        raise ValueError(f"{path}: not a table of {ncols} numbers")  # pragma: no cover (loadtxt and float agree)
    bad = ~np.all(np.isfinite(rows), axis=1)
    if bad.any():
        i = keep[int(np.argmax(bad))]
        raise ValueError(f"{path}, line {i + 1}: NaN or inf ({lines[i].strip()[:80]!r})")
    return rows, np.asarray(keep) + 1


def read_car_geometry(path):
    """The car geometry ``a, b, H, L`` (metres) from the data set's ``info.txt``.

    Lines of the form ``a  : 0.95 m`` are read; a missing or non-positive
    value raises a ``ValueError`` naming the file.
    """
    path = Path(path)
    _, text = _open_text(path.parent, path.name.removesuffix(".gz"))
    car = {}
    for key in ("a", "b", "H", "L"):
        m = re.search(rf"^\s*{key}\s*:\s*([-+0-9.eE]+)\s*m\b", text, flags=re.MULTILINE)
        if m is None:
            raise ValueError(f"{path}: no line '{key} : <value> m' with the car geometry")
        try:
            car[key] = float(m.group(1))
        except ValueError:
            raise ValueError(f"{path}: car geometry {key} is not a number ({m.group(1)!r})") from None
        if not np.isfinite(car[key]) or (key in ("H", "L") and car[key] <= 0):
            raise ValueError(f"{path}: car geometry {key} must be a positive finite length, got {car[key]}")
    return car


def load_victoria_park(*, dt=VICTORIA_DT, t_max=None, t_min=0.0, M=None, Q=None, max_range=None, data_dir=None):
    """Load the Victoria Park log as a landmark-SLAM run with unknown correspondences.

    Parameters
    ----------
    dt : float, keyword-only
        Time step in seconds, in ``[0.025, 1]`` (default :data:`VICTORIA_DT`).
    t_max : float, optional, keyword-only
        Keep only the first `t_max` seconds (a short window for the book);
        default: the whole run (about 1549 s).
    t_min : float, keyword-only
        Start this many seconds after the first input record (default 0).
    M : ndarray, shape (2, 2), optional, keyword-only
        Control noise of ``[v_e, alpha]``; default ``VICTORIA_M * VICTORIA_DT / dt``.
    Q : ndarray, shape (2, 2), optional, keyword-only
        Measurement noise of ``[r, phi]``; default :data:`VICTORIA_Q`.
    max_range : float, optional, keyword-only
        Drop detections farther than this (metres); default: keep all.
    data_dir : str or Path, optional, keyword-only
        Folder with ``inputs.dat``, ``measurements.dat``, ``gps.dat`` (each
        possibly ``.gz``) and ``info.txt(.gz)``; default: the copy shipped
        in ``slamlib/data/victoria_park``.

    Returns
    -------
    VictoriaRun
        ``T = floor(duration / dt)`` steps from the first input record at or
        after `t_min`.

    Raises
    ------
    FileNotFoundError
        If a file is missing.
    ValueError
        For bad arguments, or bad input in a file (the message names the file
        and the line): a corrupt or truncated file, a line that is not the
        expected numbers, NaN or inf, time going backwards, a non-positive
        range, a bearing outside ``[0, pi]``, a negative diameter, a steering
        angle the car model cannot take.

    Notes
    -----
    * Controls: each ``(v_e, alpha)`` holds until the next record; ``u[k]`` is
      its average over ``[t[k], t[k+1])``.
    * Detections: a detection at time ``tau`` goes to the step whose end time
      is nearest, ``k = round((tau - t_start) / dt) - 1``, clipped to
      ``0..T-1``; the bearing becomes ``phi = raw - pi / 2``. The range is the
      detector's, unchanged.
    * GPS: the fixes inside the run, kept as they are (gaps and jumps
      included); they are the only reference.

    References
    ----------
    Guivant & Nebot (2001) (the data set and the car model).
    """
    directory = data_path("victoria_park") if data_dir is None else Path(data_dir)
    if not directory.is_dir():
        raise FileNotFoundError(f"data_dir {directory} is not a folder")
    dt = as_scalar(dt, "dt", positive=True)
    if not 0.025 <= dt <= 1.0:
        raise ValueError(f"dt must be in [0.025, 1] seconds, got {dt}")
    t_min = as_scalar(t_min, "t_min", nonnegative=True)
    if t_max is not None:
        t_max = as_scalar(t_max, "t_max", positive=True)
        if t_max < dt:
            raise ValueError(f"t_max must be at least one step dt={dt}, got {t_max}")
    if max_range is not None:
        max_range = as_scalar(max_range, "max_range", positive=True)
    M = VICTORIA_M * (VICTORIA_DT / dt) if M is None else as_covariance(M, "M", 2)
    Q = np.array(VICTORIA_Q) if Q is None else as_covariance(Q, "Q", 2)

    car = read_car_geometry(directory / "info.txt")
    tables = {}
    for key, (name, ncols) in _FILES.items():
        path, text = _open_text(directory, name)
        rows, lines = _parse(path, text, ncols)
        check_time_order(path, rows[:, 0], lines, wording="time goes backwards")
        tables[key] = (path, rows, lines)

    path, inp, lines = tables["inputs"]
    fail_rows(path, np.abs(np.tan(inp[:, 2])) * car["H"] >= car["L"], lines,
               f"steering angle beyond what the car model takes (tan(alpha) H / L >= 1, H={car['H']}, L={car['L']})")
    path, meas, lines = tables["measurements"]
    fail_rows(path, meas[:, 1] <= 0, lines, "non-positive range")
    fail_rows(path, (meas[:, 2] < 0) | (meas[:, 2] > np.pi), lines, "bearing outside [0, pi]")
    fail_rows(path, meas[:, 3] < 0, lines, "negative trunk diameter")
    gps = tables["gps"][1]

    first = int(np.searchsorted(inp[:, 0], inp[0, 0] + t_min, side="left"))
    if first >= inp.shape[0] - 1:
        raise ValueError(f"t_min={t_min} is after the last input record ({inp[-1, 0]} s)")
    t_start = float(inp[first, 0])
    duration = float(inp[-1, 0]) - t_start
    if t_max is not None:
        duration = min(duration, t_max)
    T = int(np.floor(duration / dt + 1e-9))
    if T < 1:
        raise ValueError(f"the log is shorter than one step dt={dt} after t_min={t_min}")
    t = dt * np.arange(T + 1)
    edges = t_start + t
    u = _hold_average(inp[:, 0], inp[:, 1:3], edges)

    rel = (meas[:, 0] - t_start) / dt
    keep = (meas[:, 0] >= t_start) & (rel < T + 0.5)
    if max_range is not None:
        keep &= meas[:, 1] <= max_range
    step = np.clip(np.rint(rel[keep]).astype(np.int64) - 1, 0, T - 1)
    zk = np.column_stack([meas[keep, 1], meas[keep, 2] - 0.5 * np.pi])  # phi = raw - pi/2: 0 straight ahead
    dk = meas[keep, 3]
    bounds = np.searchsorted(step, np.arange(T + 1), side="left")
    z = tuple(zk[bounds[k]:bounds[k + 1]] for k in range(T))
    diameters = tuple(dk[bounds[k]:bounds[k + 1]] for k in range(T))
    ids = tuple(np.full(bounds[k + 1] - bounds[k], -1, dtype=np.int64) for k in range(T))
    g_in = (gps[:, 0] >= t_start) & (gps[:, 0] <= edges[-1])
    gps_run = np.column_stack([gps[g_in, 0] - t_start, gps[g_in, 1:3]])
    counts = {"inputs": int(inp.shape[0]), "detections": int(keep.sum()), "outside": int((~keep).sum()),
              "gps": int(g_in.sum())}
    landmarks = np.empty((0, 2))
    for arr in (landmarks, u, t, M, Q, gps_run):
        arr.setflags(write=False)
    return VictoriaRun(landmarks=landmarks, dt=dt, x0=np.zeros(3), u=u, z=z, ids=ids, diameters=diameters, M=M, Q=Q,
                       t=t, t_start=t_start, gps=gps_run, car=car, motion=car_model(car), counts=counts)


def car_model(car):
    """The :class:`~slamlib.AckermannModel` of the car geometry of ``info.txt``.

    ``info.txt`` measures the laser's ``a`` from the **front** axle (its
    drawing, ``car.bmp``, is not shipped): the laser sits ``L + a = 3.78 m``
    ahead of the rear axle and ``b`` to the left of the centre line, the
    values of the literature on this data set (Guivant & Nebot 2001). Read
    as 0.95 m from the rear axle instead, the car's path fits the GPS four
    times worse on the first 100 s.
    """
    return AckermannModel(a=car["L"] + car["a"], b=car["b"], H=car["H"], L=car["L"])


def victoria_gps_ate(run, x_est):
    """Trajectory error against the GPS fixes, after the best rigid alignment.

    Parameters
    ----------
    run : VictoriaRun
        The run (its step times ``t`` and GPS fixes ``gps``).
    x_est : ndarray, shape (T + 1, 3)
        Estimated laser poses at the step times.

    Returns
    -------
    ate : float
        Root mean square distance (metres) between the aligned estimate and
        the fixes. It includes the GPS's own error (metres, with jumps), so
        it bounds the estimate's error from above only roughly.
    aligned : ndarray, shape (T + 1, 2)
        The estimated positions in the GPS frame.
    residuals : ndarray, shape (G,)
        Distance at each fix.
    transform : tuple (R, t)
        The rigid transform taking the estimate onto the GPS frame.

    Notes
    -----
    Every fix inside the run is compared with the estimate interpolated
    linearly at the fix's time. The alignment (Umeyama 1991, rotation and
    translation, no scale) is
    fitted on the fixes themselves; gaps in the GPS only leave those times
    out of the score.
    """
    x_est = as_array(x_est, "x_est", (run.t.shape[0], 3))
    g = run.gps
    if g.shape[0] < 2:
        raise ValueError("the run holds fewer than 2 GPS fixes: no alignment is possible")
    est_xy = np.column_stack([np.interp(g[:, 0], run.t, x_est[:, 0]), np.interp(g[:, 0], run.t, x_est[:, 1])])
    R, tr = align_se2(est_xy, g[:, 1:3])
    res = np.linalg.norm(est_xy @ R.T + tr - g[:, 1:3], axis=1)
    aligned = x_est[:, :2] @ R.T + tr
    return float(np.sqrt(np.mean(res**2))), aligned, res, (R, tr)
