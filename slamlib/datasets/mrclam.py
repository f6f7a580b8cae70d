"""UTIAS MRCLAM Dataset 6: real robot logs turned into a landmark-SLAM run.

Five iRobot Create robots drove for about 900 s in a 7 m x 9 m hall among 15
tubes carrying barcodes (the landmarks). Each robot logged

* its velocity commands ``(t, v, omega)`` at 67-100 Hz (``RobotN_Odometry.dat``);
* range-bearing sightings ``(t, barcode, r, phi)`` of barcodes seen by its
  monocular camera (``RobotN_Measurement.dat``): landmarks, other robots, and a
  few barcodes that belong to no subject;
* its pose from a Vicon motion-capture system (``RobotN_Groundtruth.dat``).

``Barcodes.dat`` maps subject numbers to barcodes (subjects 1-5 are robots,
6-20 landmarks) and ``Landmark_Groundtruth.dat`` holds the Vicon positions of
the landmarks. The package ships all five robots of the data set, subsetted
as ``slamlib/data/mrclam/ATTRIBUTION.md`` describes (``tools/mrclam_subset.py``
cuts the subset); :func:`load_mrclam` also reads the full original folder
(``data_dir=...``), whose files have the same format.

:func:`load_mrclam` turns one robot's log into the same kind of run the
simulator produces: fixed time steps ``dt``, one averaged control per step,
the sightings of landmarks assigned to steps with landmark indices
``0..14`` (subject ``j + 6``), and the Vicon poses at the step times as ground
truth.

References
----------
K. Y. K. Leung, Y. Halpern, T. D. Barfoot, H. H. T. Liu, "The UTIAS
Multi-Robot Cooperative Localization and Mapping Dataset", IJRR 30(8):969-974,
2011. Thrun, Burgard & Fox, *Probabilistic Robotics* (2005), Sec. 5.3 (velocity
controls) and Eq. 6.40 (range-bearing measurements).
"""

from __future__ import annotations

import io
import numbers
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._checks import as_covariance, as_scalar
from ..angles import wrap_angle
from . import data_path
from ._text import check_time_order, open_text

__all__ = ["MRCLAMRun", "load_mrclam", "MRCLAM_ROBOTS", "MRCLAM_DT", "MRCLAM_M", "MRCLAM_Q", "MRCLAM_Q_SIGHTING", "MRCLAM_GATE"]

#: Robots whose logs the package ships: all five of Dataset 6.
MRCLAM_ROBOTS = (1, 2, 3, 4, 5)
#: Subjects 1-5 are robots, 6-20 landmarks (``Barcodes.dat``).
N_ROBOTS = 5
FIRST_LANDMARK_SUBJECT = 6
N_LANDMARKS = 15

#: Time step (seconds) the book uses on this data set, and for which :data:`MRCLAM_M` is stated.
MRCLAM_DT = 0.1
#: Control noise ``M`` of ``[v, omega]`` the book uses at ``dt = MRCLAM_DT``: standard deviations of
#: 0.07 m/s and 0.10 rad/s per step, measured on robot 1 (the calibration robot; robots 2-5 are held
#: out) by :func:`slamlib.scoring.calibrate_noise`: the largest white-noise-equivalent per-step
#: deviation of the command errors against Vicon over windows of 1 s to 30 s (the errors are partly
#: correlated, so the value grows with the window). :func:`load_mrclam` scales it by
#: ``MRCLAM_DT / dt`` for other steps.
MRCLAM_M = np.diag([0.07**2, 0.10**2])
#: Measurement noise ``Q`` of ``[r, phi]`` the book uses: 0.6 m and 0.05 rad, measured on robot 1 by
#: :func:`slamlib.scoring.calibrate_noise`: the RMS sighting residuals against Vicon (0.12 m,
#: 0.019 rad) inflated by ``sqrt((1 + rho) / (1 - rho))`` for the correlation ``rho`` of consecutive
#: sightings of the same landmark (0.92 for the range, 0.77 for the bearing): a landmark's range
#: error persists while the robot keeps seeing it, so repeated sightings carry far less information
#: than independent ones would.
MRCLAM_Q = np.diag([0.6**2, 0.05**2])
#: Spread of a single sighting, ``diag(0.12^2, 0.02^2)``: robot 1's RMS residuals against Vicon without
#: the inflation of :data:`MRCLAM_Q`. Data association compares one sighting with the map, so its
#: gates should have the width of one sighting's error (``run_ekf_slam(..., Q_association=...)``).
MRCLAM_Q_SIGHTING = np.diag([0.12**2, 0.02**2])
MRCLAM_Q_SIGHTING.setflags(write=False)
#: Validation gate the filters apply to this data set by default (:attr:`MRCLAMRun.gate`): the
#: 99.999 % quantile of the chi-square distribution with 2 degrees of freedom, ``-2 ln(1e-5)``
#: (about 23.0), on the normalised innovation squared of a sighting. A few sightings are grossly
#: wrong (bearing off by about pi, range off by metres: four in robot 3's log); a tail of 1e-5
#: rejects them and, with a consistent filter, about one good sighting in 100 000.
MRCLAM_GATE = float(-2.0 * np.log(1e-5))
MRCLAM_M.setflags(write=False)
MRCLAM_Q.setflags(write=False)


@dataclass(frozen=True, eq=False)
class MRCLAMRun:
    """One robot's log of MRCLAM Dataset 6 on a fixed time grid.

    The first nine fields are those of the simulator's landmark runs, so the
    SLAM run helpers take this object directly; step ``k`` applies ``u[k]``
    for ``dt`` seconds, from ``x_true[k]`` to ``x_true[k + 1]``, and then
    observes ``z[k]``.

    Attributes
    ----------
    landmarks : ndarray, shape (15, 2)
        Vicon landmark positions; row ``j`` is subject ``j + 6``.
    dt : float
        Time step, seconds.
    x0 : ndarray, shape (3,)
        Vicon pose at the start, ``x_true[0]``.
    x_true : ndarray, shape (T + 1, 3)
        Vicon poses at the step times ``t`` (linear interpolation; heading
        interpolated unwrapped, then wrapped to ``[-pi, pi)``).
    u : ndarray, shape (T, 2)
        ``[v, omega]`` commands averaged over each step (the log's commands
        held until the next record).
    z : tuple of T ndarrays, shape (K_k, 2)
        Landmark sightings ``[r, phi]`` of step ``k`` (those whose time is
        nearest to ``t[k + 1]``), in time order.
    ids : tuple of T int ndarrays, shape (K_k,)
        Landmark index ``0..14`` of each sighting.
    M : ndarray, shape (2, 2)
        Control noise covariance the filters should use (a modelling choice,
        not a property of the log; by default :data:`MRCLAM_M` scaled to
        `dt`).
    Q : ndarray, shape (2, 2)
        Measurement noise covariance of ``[r, phi]`` (:data:`MRCLAM_Q` by
        default).
    t : ndarray, shape (T + 1,)
        Step times in seconds since ``t_start``.
    robot : int
        Robot number, 1-5.
    t_start : float
        Log time (UNIX seconds) of step 0.
    landmark_std : ndarray, shape (15, 2)
        Vicon standard deviations of the landmark positions, metres.
    counts : dict
        Number of measurement records by fate: ``"landmark"`` (kept),
        ``"robot"`` (sightings of other robots, skipped), ``"unknown"``
        (barcodes of no subject, skipped) and ``"outside"`` (landmark
        sightings outside the time window, skipped).
    gate : float
        Validation gate on the normalised innovation squared that the
        filters apply by default to this real log (``run_ekf_slam``,
        ``ekf_localization_run`` read it when their ``gate`` is ``None``);
        :data:`MRCLAM_GATE` unless :func:`load_mrclam` was given another.
    """

    landmarks: np.ndarray
    dt: float
    x0: np.ndarray
    x_true: np.ndarray
    u: np.ndarray
    z: tuple
    ids: tuple
    M: np.ndarray
    Q: np.ndarray
    t: np.ndarray
    robot: int
    t_start: float
    landmark_std: np.ndarray
    counts: dict = field(default_factory=dict)
    gate: float = MRCLAM_GATE

    @property
    def n_steps(self) -> int:
        """Number of control steps ``T``."""
        return int(self.u.shape[0])

    @property
    def n_sightings(self) -> int:
        """Number of landmark sightings in the run."""
        return int(sum(len(i) for i in self.ids))


def _line_numbers(text: str) -> list[int]:
    """1-based line number of each data row (lines that are neither blank nor only a comment)."""
    return [k + 1 for k, ln in enumerate(text.splitlines()) if ln.split("#", 1)[0].strip()]


def _bad_line(path, text, problem):
    """``ValueError`` naming the first data line of `text` for which ``problem(fields)`` returns a message."""
    for k, ln in enumerate(text.splitlines()):
        fields = ln.split("#", 1)[0].split()
        if fields:
            msg = problem(fields)
            if msg:
                return ValueError(f"{path}, line {k + 1}: {msg}: {ln.strip()!r}")
    return None


def _read_table(directory: Path, name: str, ncols: int) -> tuple:
    """Numeric rows of a (gzip) text file of the data set (``#`` starts a comment), and the file's path.

    Every problem is a ``ValueError`` naming the file and, where there is one, the line: a truncated
    or corrupt archive, a text field, a wrong number of columns, NaN or infinity.
    """
    path = directory / name
    if not path.exists():
        plain = directory / name.removesuffix(".gz")
        if plain.exists():
            path = plain
        else:
            raise FileNotFoundError(f"MRCLAM file {name} not found in {directory}")
    text = open_text(path)

    def fields_problem(fields):
        if len(fields) != ncols:
            return f"expected {ncols} columns, got {len(fields)}"
        for f in fields:
            try:
                float(f)
            except ValueError:
                return f"field {f!r} is not a number"
        return None

    try:
        arr = np.loadtxt(io.StringIO(text), comments="#", ndmin=2, dtype=np.float64)
    except ValueError as exc:
        raise (_bad_line(path, text, fields_problem) or ValueError(f"{path}: not a numeric table ({exc})")) from None
    if arr.shape[0] == 0:
        raise ValueError(f"{path}: no data rows")
    if arr.shape[1] != ncols:
        raise _bad_line(path, text, fields_problem) or ValueError(f"{path}: expected {ncols} columns, got {arr.shape[1]}")
    bad = ~np.all(np.isfinite(arr), axis=1)
    if np.any(bad):
        line = _line_numbers(text)[int(np.argmax(bad))]
        raise ValueError(f"{path}, line {line}: NaN or infinity: {text.splitlines()[line - 1].strip()!r}")
    return arr, path, text


def _subject_of_barcode(directory: Path) -> dict:
    """``{barcode: subject}`` from ``Barcodes.dat``; a duplicate barcode or subject is an error."""
    arr, path, text = _read_table(directory, "Barcodes.dat.gz", 2)
    lines = _line_numbers(text)
    if np.any(arr != np.rint(arr)):
        row = int(np.argmax(np.any(arr != np.rint(arr), axis=1)))
        raise ValueError(f"{path}, line {lines[row]}: subject and barcode must be integers")
    arr = arr.astype(np.int64)
    first_subject, subject_of = {}, {}
    for row, (s, b) in enumerate(arr.tolist()):
        if b in subject_of:
            raise ValueError(f"{path}, line {lines[row]}: duplicate barcode {b} (subject {s}; line "
                             f"{lines[first_subject[subject_of[b]]]} gives it to subject {subject_of[b]})")
        if s in first_subject:
            raise ValueError(f"{path}, line {lines[row]}: duplicate subject {s} (first on line {lines[first_subject[s]]})")
        first_subject[s] = row
        subject_of[b] = s
    return subject_of


def _hold_average(t_rec, values, edges):
    """Average over ``[edges[k], edges[k+1])`` of a zero-order-hold signal.

    The signal equals ``values[i]`` on ``[t_rec[i], t_rec[i+1])``, the last
    value after the last record and 0 before the first one.
    """
    # cumulative integral at the records: C[i] = int_{t_rec[0]}^{t_rec[i]} signal
    steps = np.diff(t_rec)[:, None] * values[:-1]
    C = np.vstack([np.zeros((1, values.shape[1])), np.cumsum(steps, axis=0)])
    i = np.searchsorted(t_rec, edges, side="right") - 1
    before = i < 0
    ii = np.maximum(i, 0)
    F = C[ii] + values[ii] * (edges - t_rec[ii])[:, None]
    F[before] = 0.0
    return np.diff(F, axis=0) / np.diff(edges)[:, None]


def _interp_poses(t_rec, poses, t):
    """Linear interpolation of poses, the heading unwrapped first."""
    th = np.unwrap(poses[:, 2])
    out = np.empty((t.size, 3))
    out[:, 0] = np.interp(t, t_rec, poses[:, 0])
    out[:, 1] = np.interp(t, t_rec, poses[:, 1])
    out[:, 2] = wrap_angle(np.interp(t, t_rec, th))
    return out


def load_mrclam(robot=1, *, dt=MRCLAM_DT, t_max=None, M=None, Q=None, gate=MRCLAM_GATE, data_dir=None):
    """Load one robot of MRCLAM Dataset 6 as a landmark-SLAM run.

    Parameters
    ----------
    robot : int
        Robot number, 1-5 (the package ships all five, :data:`MRCLAM_ROBOTS`).
    dt : float, keyword-only
        Time step in seconds, in ``[0.005, 1]`` (default :data:`MRCLAM_DT`).
    t_max : float, optional, keyword-only
        Keep only the first `t_max` seconds (positive); default: the whole log.
    M : ndarray, shape (2, 2), optional, keyword-only
        Control noise covariance stored in the run. Default:
        ``MRCLAM_M * MRCLAM_DT / dt``: control errors modelled as white noise,
        whose average over a step has a variance inversely proportional to
        the step's length.
    Q : ndarray, shape (2, 2), optional, keyword-only
        Measurement noise covariance stored in the run (default
        :data:`MRCLAM_Q`).
    gate : float, keyword-only
        Validation gate stored in the run (:attr:`MRCLAMRun.gate`), non-negative;
        ``numpy.inf`` turns gating off for the filters that read it.
    data_dir : str or Path, optional, keyword-only
        Folder holding ``Barcodes.dat(.gz)``, ``Landmark_Groundtruth.dat(.gz)``
        and ``RobotN_{Odometry,Measurement,Groundtruth}.dat(.gz)``; default:
        the copy shipped in ``slamlib/data/mrclam``.

    Returns
    -------
    MRCLAMRun
        ``T = floor(duration / dt)`` steps starting at the later of the first
        odometry record and the first Vicon pose, and ending no later than the
        last of either (or after `t_max` seconds). Fields: ``landmarks (15, 2)``,
        ``dt``, ``x0 (3,)``, ``x_true (T+1, 3)``, ``u (T, 2)``, ``z`` (T arrays
        ``(K_k, 2)``), ``ids`` (T int arrays ``(K_k,)``), ``M``, ``Q``,
        ``t (T+1,)`` and metadata (see :class:`MRCLAMRun`).

    Raises
    ------
    ValueError
        For a robot number outside 1-5, a non-positive or too large `dt`, a
        `t_max` shorter than one step, or a bad file. A bad file is never
        repaired silently: the message names the file and, where there is
        one, the line, for a truncated or corrupt gzip archive, a text field
        or a wrong number of columns, NaN or infinity, times that run
        backwards (equal times are allowed), a non-positive range or a
        non-integer barcode in a sighting, and a barcode or subject listed
        twice in ``Barcodes.dat`` (which would silently move sightings to
        another landmark).
    FileNotFoundError
        If a file of the data set is missing.

    Notes
    -----
    * Controls: each command ``(v, omega)`` holds until the next record; ``u[k]``
      is its average over ``[t[k], t[k+1])``.
    * Sightings: a record at time ``tau`` goes to step ``k = round((tau - t[0]) / dt) - 1``
      (the step whose end time is nearest), clipped to ``0..T-1``; records
      outside ``[t[0], t[T] + dt / 2)`` are dropped. Barcodes of robots and
      barcodes of no subject are skipped (``counts`` says how many).
    * Ground truth: the Vicon poses, interpolated linearly at ``t``.

    References
    ----------
    Leung et al., IJRR 30(8):969-974 (2011) (the data set); Thrun, Burgard &
    Fox (2005), Sec. 5.3 (velocity controls ``[v, omega]``) and Eq. 6.40
    (range-bearing sightings).
    """
    if isinstance(robot, bool) or not isinstance(robot, (numbers.Integral, np.integer)):
        raise TypeError(f"robot must be an integer 1-{N_ROBOTS}, got {type(robot).__name__}")
    robot = int(robot)
    if not 1 <= robot <= N_ROBOTS:
        raise ValueError(f"robot must be in 1..{N_ROBOTS}, got {robot}")
    if data_dir is None:
        directory = data_path("mrclam")
    else:
        directory = Path(data_dir)
        if not directory.is_dir():
            raise FileNotFoundError(f"data_dir {directory} is not a folder")
    dt = as_scalar(dt, "dt", positive=True)
    if not 0.005 <= dt <= 1.0:
        raise ValueError(f"dt must be in [0.005, 1] seconds, got {dt}")
    if t_max is not None:
        t_max = as_scalar(t_max, "t_max", positive=True)
        if t_max < dt:
            raise ValueError(f"t_max must be at least one step dt={dt}, got {t_max}")
    # white control errors: the variance of a step's average falls like 1 / dt
    M = MRCLAM_M * (MRCLAM_DT / dt) if M is None else as_covariance(M, "M", 2)
    Q = np.array(MRCLAM_Q) if Q is None else as_covariance(Q, "Q", 2)
    gate = as_scalar(gate, "gate", nonnegative=True, finite=False)

    # --- subjects and landmarks
    subject_of = _subject_of_barcode(directory)
    lm, lm_path, _ = _read_table(directory, "Landmark_Groundtruth.dat.gz", 5)
    subjects = lm[:, 0].astype(np.int64)
    expected = np.arange(FIRST_LANDMARK_SUBJECT, FIRST_LANDMARK_SUBJECT + N_LANDMARKS)
    if not np.array_equal(np.sort(subjects), expected):
        raise ValueError(f"{lm_path}: expected subjects {expected[0]}..{expected[-1]} once each, got {subjects}")
    if np.any(lm[:, 3:5] < 0):
        raise ValueError(f"{lm_path}: negative standard deviation")
    order = np.argsort(subjects)
    landmarks = lm[order, 1:3].copy()
    landmark_std = lm[order, 3:5].copy()

    # --- the robot's logs, each in time order
    # (times must not decrease; equal times are allowed: a later record overrides)
    logs = []
    for name, ncols in (("Odometry", 3), ("Groundtruth", 4), ("Measurement", 4)):
        arr, path, text = _read_table(directory, f"Robot{robot}_{name}.dat.gz", ncols)
        check_time_order(path, arr[:, 0], _line_numbers(text))
        logs.append((arr, path, text))
    (odo, _, _), (gt, _, _), (meas, meas_path, meas_text) = logs
    bad = (meas[:, 2] <= 0) | (meas[:, 1] != np.rint(meas[:, 1]))
    if np.any(bad):
        row = int(np.argmax(bad))
        line = _line_numbers(meas_text)[row]
        what = "non-positive range" if meas[row, 2] <= 0 else "barcode is not an integer"
        raise ValueError(f"{meas_path}, line {line}: {what}: {meas_text.splitlines()[line - 1].strip()!r}")

    t_start = max(odo[0, 0], gt[0, 0])
    t_end = min(odo[-1, 0], gt[-1, 0])
    duration = t_end - t_start
    if t_max is not None:
        duration = min(duration, t_max)
    T = int(np.floor(duration / dt + 1e-9))
    if T < 1:
        raise ValueError(f"robot {robot}: the log is shorter than one step dt={dt}")
    t = dt * np.arange(T + 1)
    edges = t_start + t

    u = _hold_average(odo[:, 0], odo[:, 1:3], edges)
    x_true = _interp_poses(gt[:, 0], gt[:, 1:4], edges)

    # --- sightings: barcode -> subject -> landmark index
    codes = np.rint(meas[:, 1]).astype(np.int64)
    subj = np.array([subject_of.get(int(c), -1) for c in codes], dtype=np.int64)
    is_landmark = subj >= FIRST_LANDMARK_SUBJECT
    is_robot = (subj >= 1) & (subj <= N_ROBOTS)
    rel = (meas[:, 0] - t_start) / dt
    inside = (meas[:, 0] >= t_start) & (rel < T + 0.5)
    keep = is_landmark & inside
    step = np.clip(np.rint(rel[keep]).astype(np.int64) - 1, 0, T - 1)
    zk = np.column_stack([meas[keep, 2], wrap_angle(meas[keep, 3])])
    idk = subj[keep] - FIRST_LANDMARK_SUBJECT
    bounds = np.searchsorted(step, np.arange(T + 1), side="left")
    z = tuple(zk[bounds[k]:bounds[k + 1]] for k in range(T))
    ids = tuple(idk[bounds[k]:bounds[k + 1]] for k in range(T))
    counts = {
        "landmark": int(keep.sum()),
        "robot": int(is_robot.sum()),
        "unknown": int((subj < 0).sum()),
        "outside": int((is_landmark & ~inside).sum()),
    }
    for arr in (landmarks, landmark_std, x_true, u, t, M, Q):
        arr.setflags(write=False)
    return MRCLAMRun(landmarks=landmarks, dt=dt, x0=x_true[0].copy(), x_true=x_true, u=u, z=z, ids=ids,
                     M=M, Q=Q, t=t, robot=robot, t_start=float(t_start), landmark_std=landmark_std,
                     counts=counts, gate=gate)
