"""Pose graphs in the g2o text format, and the two benchmark graphs the package ships.

A g2o file lists one record per line:

* ``VERTEX_SE2 id x y theta``: a pose (its initial estimate);
* ``EDGE_SE2 i j dx dy dtheta I11 I12 I13 I22 I23 I33``: pose ``j`` measured
  from pose ``i``, with the upper triangle of its ``3 x 3`` information matrix;
* ``VERTEX_XY id x y``: a point landmark (its initial estimate);
* ``EDGE_SE2_XY i j x y I11 I12 I22`` (or ``LANDMARK2``, the same fields): landmark
  ``j`` seen from pose ``i`` at ``(x, y)`` in the pose's frame, with the upper
  triangle of its ``2 x 2`` information matrix.

Blank lines and lines starting with ``#`` are skipped. Any other record, a
wrong number of fields, a number that does not parse or is not finite, a
repeated vertex, an edge to a vertex the file does not define, an edge from a
pose to itself, or an information matrix that is not positive definite is an
error naming the file and the line. Nothing is dropped silently.

Shipped graphs (``slamlib/data/pose_graphs``, attribution beside them):
:func:`load_intel` (Intel Research Lab, Seattle: a real robot, 1728 poses,
2512 edges) and :func:`load_m3500` (Manhattan world, simulated, 3500 poses,
5453 edges).

References
----------
R. Kuemmerle, G. Grisetti, H. Strasdat, K. Konolige, W. Burgard, "g2o: A
general framework for graph optimization", ICRA 2011 (the file format). E.
Olson, J. Leonard, S. Teller, "Fast iterative alignment of pose graphs with
poor initial estimates", ICRA 2006 (the Manhattan data set). A. Howard, N. Roy,
The Robotics Data Set Repository (Radish), 2003 (the Intel Research Lab log).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import NamedTuple

import numpy as np

from . import data_path
from ._text import open_text

__all__ = ["PoseGraph", "PoseGraph3D", "City10000", "load_g2o", "load_g2o3d", "load_intel", "load_m3500", "load_sphere2500",
           "load_city10000"]


class PoseGraph(NamedTuple):
    """A pose graph read from a g2o file.

    Attributes
    ----------
    X : ndarray, shape (n, 3)
        The vertices' poses ``[x, y, theta]`` (the file's initial estimate), in
        the order of their ids.
    edges : int ndarray, shape (E, 2)
        Index pairs ``(i, j)`` into `X` (rows, not the file's ids).
    Z : ndarray, shape (E, 3)
        Relative-pose measurements ``[dx, dy, dtheta]``: pose ``j`` seen from pose ``i``.
    Omega : ndarray, shape (E, 3, 3)
        Information matrices (symmetric positive definite).
    vertex_ids : int ndarray, shape (n,)
        The file's id of each row of `X` (sorted).
    source : str
        The file the graph was read from.
    equivalences : int ndarray, shape (K, 2), or None
        Row pairs of TORO's ``EQUIV`` records (not constraints), None when there are none.
    landmarks : ndarray, shape (K, 2), or None
        Point landmarks (``VERTEX_XY``, or for a landmark without one the position of its first
        sighting, ``t_i + R_i z``), in the order of their ids; None when the file has no landmark.
    landmark_ids : int ndarray, shape (K,), or None
        The file's id of each row of `landmarks` (sorted).
    obs_edges : int ndarray, shape (S, 2), or None
        ``(pose row, landmark row)`` of each sighting (``EDGE_SE2_XY`` / ``LANDMARK2``).
    obs_Z : ndarray, shape (S, 2), or None
        The landmark's position ``[x, y]`` in the pose's frame.
    obs_Omega : ndarray, shape (S, 2, 2), or None
        Their information matrices.
    """

    X: np.ndarray
    edges: np.ndarray
    Z: np.ndarray
    Omega: np.ndarray
    vertex_ids: np.ndarray
    source: str
    equivalences: np.ndarray | None = None
    landmarks: np.ndarray | None = None
    landmark_ids: np.ndarray | None = None
    obs_edges: np.ndarray | None = None
    obs_Z: np.ndarray | None = None
    obs_Omega: np.ndarray | None = None

    @property
    def n_poses(self) -> int:
        """Number of poses ``n``."""
        return int(self.X.shape[0])

    @property
    def n_edges(self) -> int:
        """Number of edges ``E``."""
        return int(self.edges.shape[0])

    @property
    def n_landmarks(self) -> int:
        """Number of landmarks ``K`` (0 for a pose graph)."""
        return 0 if self.landmarks is None else int(self.landmarks.shape[0])

    def landmark_graph(self):
        """The graph as a :class:`slamlib.graph_slam.LandmarkGraph` with ``obs_model="point"``.

        Poses start at `X`, landmarks at `landmarks`; solve it with
        :func:`slamlib.graph_slam.optimize_landmark_graph`.

        Raises
        ------
        ValueError
            If the file had no landmark.
        """
        from ..graph_slam import LandmarkGraph

        if self.landmarks is None:
            raise ValueError(f"{self.source} has no landmark (no EDGE_SE2_XY or LANDMARK2 record)")
        return LandmarkGraph(X0=self.X, L0=self.landmarks, odo_edges=self.edges, odo_Z=self.Z, odo_Omega=self.Omega,
                             obs_edges=self.obs_edges, obs_Z=self.obs_Z, obs_Omega=self.obs_Omega,
                             landmark_ids=self.landmark_ids, obs_model="point")


class PoseGraph3D(NamedTuple):
    """A 3-D pose graph read by :func:`load_g2o3d`.

    Attributes
    ----------
    T : ndarray, shape (n, 4, 4)
        Poses (the file's vertices, or the odometry guess for a file of edges only), in the
        order of their ids.
    edges : int ndarray, shape (E, 2)
        Row pairs ``(i, j)``.
    Z : ndarray, shape (E, 4, 4)
        Relative-pose measurements: pose ``j`` seen from pose ``i``.
    Omega : ndarray, shape (E, 6, 6)
        Information matrices over ``[translation, rotation]``.
    vertex_ids : int ndarray, shape (n,)
        The file's id of each row (sorted).
    source : str
        The file the graph was read from.
    """

    T: np.ndarray
    edges: np.ndarray
    Z: np.ndarray
    Omega: np.ndarray
    vertex_ids: np.ndarray
    source: str

    @property
    def n_poses(self) -> int:
        """Number of poses ``n``."""
        return int(self.T.shape[0])

    @property
    def n_edges(self) -> int:
        """Number of edges ``E``."""
        return int(self.edges.shape[0])


def _lines(path: Path):
    with open(path, "rb") as fh:
        gz = fh.read(2) == b"\x1f\x8b"
    what = f"cannot be read as {'gzip-compressed ' if gz else ''}text"
    return open_text(path, encoding="utf-8", compressed=gz, corrupt=what, undecodable=what).splitlines()


def _numbers(path, lineno, tokens, kinds):
    out = []
    for tok, kind in zip(tokens, kinds):
        try:
            val = int(tok) if kind == "i" else float(tok)
        except ValueError:
            want = "an integer id" if kind == "i" else "a number"
            raise ValueError(f"{path}:{lineno}: {tok!r} is not {want}") from None
        if kind == "f" and not math.isfinite(val):
            raise ValueError(f"{path}:{lineno}: {tok!r} is not finite")
        out.append(val)
    return out


#: Records read, by tag: (kind, dimension, fields after the tag, field kinds).
_RECORDS = {
    "VERTEX_SE2": ("vertex", 2, "id x y theta", "ifff"),
    "VERTEX2": ("vertex", 2, "id x y theta", "ifff"),
    "EDGE_SE2": ("edge", 2, "i j dx dy dtheta I11 I12 I13 I22 I23 I33", "ii" + "f" * 9),
    "EDGE2": ("edge", 2, "i j dx dy dtheta I11 I12 I22 I33 I13 I23", "ii" + "f" * 9),
    "EQUIV": ("equiv", 2, "i j", "ii"),
    "VERTEX_XY": ("point", 2, "id x y", "iff"),
    "EDGE_SE2_XY": ("sighting", 2, "i j x y I11 I12 I22", "ii" + "f" * 5),
    "LANDMARK2": ("sighting", 2, "i j x y I11 I12 I22", "ii" + "f" * 5),
    "VERTEX_SE3:QUAT": ("vertex", 3, "id x y z qx qy qz qw", "i" + "f" * 7),
    "VERTEX3": ("vertex", 3, "id x y z roll pitch yaw", "i" + "f" * 6),
    "EDGE_SE3:QUAT": ("edge", 3, "i j x y z qx qy qz qw I11 .. I66 (21 upper-triangle entries)", "ii" + "f" * 28),
    "EDGE3": ("edge", 3, "i j x y z roll pitch yaw I11 .. I66 (21 upper-triangle entries)", "ii" + "f" * 27),
}
#: Upper-triangle positions of a 3 x 3 information matrix in g2o's order and in TORO's.
_UT3_G2O = (np.array([0, 0, 0, 1, 1, 2]), np.array([0, 1, 2, 1, 2, 2]))
_UT3_TORO = (np.array([0, 0, 1, 2, 0, 1]), np.array([0, 1, 1, 2, 2, 2]))


def _parse(path, dim):
    """The records of a pose-graph file of dimension `dim` (2 or 3), checked line by line."""
    vid, vval, vline, vtag = [], [], [], []
    eij, eval_, eline, etag = [], [], [], []
    equiv, points, sightings = [], [], []
    for lineno, raw in enumerate(_lines(path), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        tok = line.split()
        tag = tok[0]
        spec = _RECORDS.get(tag)
        if spec is None or spec[1] != dim:
            known = " ".join(t for t, sp in _RECORDS.items() if sp[1] == dim)
            raise ValueError(f"{path}:{lineno}: unsupported record {tag!r} (a {dim}-D pose graph reads {known})")
        kind, _, fields, kinds = spec
        if len(tok) - 1 != len(kinds):
            raise ValueError(f"{path}:{lineno}: {tag} needs {len(kinds)} fields ({fields}), got {len(tok) - 1}")
        vals = _numbers(path, lineno, tok[1:], kinds)
        if kind == "vertex":
            vid.append(vals[0])
            vval.append(vals[1:])
            vline.append(lineno)
            vtag.append(tag)
        elif kind == "edge":
            eij.append(vals[:2])
            eval_.append(vals[2:])
            eline.append(lineno)
            etag.append(tag)
        elif kind == "equiv":
            equiv.append((vals[0], vals[1], lineno))
        elif kind == "point":
            points.append((vals[0], vals[1:], lineno))
        else:
            sightings.append((vals[0], vals[1], vals[2:], lineno, tag))
    return vid, vval, vline, vtag, eij, eval_, eline, etag, equiv, points, sightings


def _vertex_rows(path, vid, vline, eij, eline, etag, *, need_vertices, vertex_name):
    """Sorted vertex ids and each edge's row pair; ids come from the edges when the file has no vertices."""
    eij = np.array(eij, dtype=np.int64).reshape(-1, 2)
    if not vid:
        if need_vertices or not eij.size:
            raise ValueError(f"{path}: no {vertex_name} record")
        sorted_ids = np.unique(eij)
        order = None
    else:
        ids = np.array(vid, dtype=np.int64)
        order = np.argsort(ids, kind="stable")
        sorted_ids = ids[order]
        dup = np.flatnonzero(np.diff(sorted_ids) == 0)
        if dup.size:
            a, b = sorted(vline[k] for k in order[dup[0]:dup[0] + 2])
            raise ValueError(f"{path}:{b}: vertex {sorted_ids[dup[0]]} is defined twice (first on line {a})")
    pos = np.searchsorted(sorted_ids, eij)
    pos_c = np.minimum(pos, sorted_ids.size - 1)
    known = sorted_ids[pos_c] == eij
    bad = np.flatnonzero(~known.all(axis=1))
    if bad.size:
        k = bad[0]
        which = eij[k, 0] if not known[k, 0] else eij[k, 1]
        raise ValueError(f"{path}:{eline[k]}: {etag[k]} {eij[k, 0]} {eij[k, 1]} refers to vertex {which}, "
                         f"which no {vertex_name} record defines")
    loop = np.flatnonzero(eij[:, 0] == eij[:, 1])
    if loop.size:
        raise ValueError(f"{path}:{eline[loop[0]]}: {etag[loop[0]]} joins vertex {eij[loop[0], 0]} to itself")
    return sorted_ids, order, pos, eij


def _first_not_pd(Omega):
    if not Omega.shape[0]:
        return None, None
    eig = np.linalg.eigvalsh(Omega)
    notpd = np.flatnonzero(eig[:, 0] <= 1e-15 * np.maximum(eig[:, -1], 0.0))
    return (notpd[0], eig[notpd[0], 0]) if notpd.size else (None, None)


def _check_information(path, Omega, eij, eline, etag):
    k, lam = _first_not_pd(Omega)
    if k is not None:
        raise ValueError(f"{path}:{eline[k]}: the information matrix of {etag[k]} {eij[k, 0]} {eij[k, 1]} is not "
                         f"positive definite (smallest eigenvalue {lam:.3g})")


def _info3(info, layout):
    Omega = np.zeros((info.shape[0], 3, 3))
    Omega[:, layout[0], layout[1]] = info
    Omega[:, layout[1], layout[0]] = info
    return Omega


def load_g2o(path):
    """Read a 2-D pose graph from a g2o or TORO text file.

    Records: g2o's ``VERTEX_SE2 id x y theta`` and
    ``EDGE_SE2 i j dx dy dtheta I11 I12 I13 I22 I23 I33``, and TORO's ``VERTEX2`` (the same
    fields) and ``EDGE2 i j dx dy dtheta I11 I12 I22 I33 I13 I23`` (TORO's order of the
    information entries) and ``EQUIV i j``; point landmarks: g2o's ``VERTEX_XY id x y`` and
    ``EDGE_SE2_XY i j x y I11 I12 I22`` (landmark ``j`` at ``(x, y)`` in the frame of pose ``i``,
    information by its upper triangle), also tagged ``LANDMARK2`` (``victoriaPark``). Blank lines
    and ``#`` comments are skipped.

    Parameters
    ----------
    path : str or Path
        A text file, plain or gzip-compressed (detected from its content).

    Returns
    -------
    PoseGraph
        ``X (n, 3)``, ``edges (E, 2)`` (row indices), ``Z (E, 3)``,
        ``Omega (E, 3, 3)``, ``vertex_ids (n,)``, ``source``, and ``equivalences (K, 2)``
        (rows of TORO's ``EQUIV`` pairs; None when the file has none); with landmarks also
        ``landmarks (K, 2)``, ``landmark_ids (K,)``, ``obs_edges (S, 2)`` (pose row, landmark
        row), ``obs_Z (S, 2)``, ``obs_Omega (S, 2, 2)`` (None without), and
        :meth:`PoseGraph.landmark_graph` gives the problem
        :func:`slamlib.graph_slam.optimize_landmark_graph` solves.

    Raises
    ------
    FileNotFoundError
        If `path` does not exist.
    ValueError
        Naming the file and line: an unknown record type (3-D records included), a wrong
        number of fields, a field that is not a number (or an id that is not an integer),
        NaN or inf, a vertex defined twice, an edge to an undefined vertex, an edge from a
        vertex to itself, an information matrix that is not positive definite; a landmark
        id that is also a pose's, a sighting from an undefined pose or (when the file has
        ``VERTEX_XY`` records) of an undefined landmark; or a file without vertices or edges.
        A file of edges only (``w20000``) gets the odometry guess
        (:func:`slamlib.graph_slam.pose_graph_initial_guess`) as ``X`` and must be connected.

    Notes
    -----
    The information matrix of an edge is given by its upper triangle and mirrored. Some
    files tagged ``EDGE2`` (``w20000``) store it in g2o's order: when TORO's order makes
    some matrix of a file indefinite and g2o's order makes all of them positive definite,
    the file is read in g2o's order (the rule GTSAM's reader applies line by line). TORO's
    ``EQUIV i j`` records (two vertices that are one place) are returned in
    ``equivalences`` and not made into constraints (GTSAM's reader skips them too).
    Headings are kept as written (the optimisers wrap them). Poses and landmarks share the
    file's ids; a landmark without ``VERTEX_XY`` starts at its first sighting, ``t_i + R_i z``
    from pose ``i``'s initial estimate.

    References
    ----------
    Kuemmerle et al., "g2o: A general framework for graph optimization", ICRA 2011;
    G. Grisetti, C. Stachniss, W. Burgard, "Nonlinear constraint network optimization for
    efficient map learning", IEEE T-ITS 10(3), 2009 (TORO and its file format).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"g2o file {path} not found")
    vid, vval, vline, vtag, eij, evals, eline, etag, equiv, points, sightings = _parse(path, 2)
    sorted_ids, order, pos, eij = _vertex_rows(path, vid, vline, eij, eline, etag, need_vertices=False,
                                               vertex_name="VERTEX_SE2")
    ev = np.array(evals, dtype=np.float64).reshape(-1, 9)
    toro = np.array([t == "EDGE2" for t in etag], dtype=bool)
    Omega = _info3(ev[:, 3:], _UT3_G2O)
    if toro.any():
        as_toro = _info3(ev[toro, 3:], _UT3_TORO)
        if _first_not_pd(as_toro)[0] is None or _first_not_pd(Omega[toro])[0] is not None:
            Omega[toro] = as_toro
    _check_information(path, Omega, eij, eline, etag)
    eq = None
    if equiv:
        eq_ids = np.array([e[:2] for e in equiv], dtype=np.int64)
        eq = np.searchsorted(sorted_ids, eq_ids)
        ok = (eq < sorted_ids.size) & (sorted_ids[np.minimum(eq, sorted_ids.size - 1)] == eq_ids)
        bad = np.flatnonzero(~ok.all(axis=1))
        if bad.size:
            raise ValueError(f"{path}:{equiv[bad[0]][2]}: EQUIV {eq_ids[bad[0], 0]} {eq_ids[bad[0], 1]} refers to a "
                             "vertex no VERTEX record defines")
    if vid:
        X = np.array(vval, dtype=np.float64)[order]
    else:
        from ..graph_slam import pose_graph_initial_guess

        X = pose_graph_initial_guess(sorted_ids.size, pos, ev[:, :3])
    lm = _landmarks(path, sorted_ids, X, points, sightings) if points or sightings else {}
    return PoseGraph(X=X, edges=pos, Z=ev[:, :3].copy(), Omega=Omega, vertex_ids=sorted_ids, source=str(path),
                     equivalences=eq, **lm)


def _landmarks(path, pose_ids, X, points, sightings):
    """The landmark fields of :class:`PoseGraph` from ``VERTEX_XY`` and sighting records, checked."""
    pose_set = set(pose_ids.tolist())
    first = {}
    for lid, _, lineno in points:
        if lid in pose_set:
            raise ValueError(f"{path}:{lineno}: VERTEX_XY {lid} has the id of a pose")
        if lid in first:
            raise ValueError(f"{path}:{lineno}: landmark {lid} is defined twice (first on line {first[lid]})")
        first[lid] = lineno
    for i, j, _, lineno, tag in sightings:
        if i not in pose_set:
            raise ValueError(f"{path}:{lineno}: {tag} {i} {j} refers to pose {i}, which no VERTEX_SE2 or EDGE_SE2 "
                             "record defines")
        if j in pose_set:
            raise ValueError(f"{path}:{lineno}: {tag} {i} {j} refers to landmark {j}, which is a pose")
        if points and j not in first:
            raise ValueError(f"{path}:{lineno}: {tag} {i} {j} refers to landmark {j}, which no VERTEX_XY record "
                             "defines")
    ids = np.array(sorted(set(first) | {s[1] for s in sightings}), dtype=np.int64)
    S = len(sightings)
    obs = np.zeros((S, 2), dtype=np.int64)
    if S:
        obs[:, 0] = np.searchsorted(pose_ids, [s[0] for s in sightings])
        obs[:, 1] = np.searchsorted(ids, [s[1] for s in sightings])
    vals = np.array([s[2] for s in sightings], dtype=np.float64).reshape(S, 5)
    Z = vals[:, :2].copy()
    Omega = np.empty((S, 2, 2))
    Omega[:, 0, 0], Omega[:, 0, 1], Omega[:, 1, 0], Omega[:, 1, 1] = vals[:, 2], vals[:, 3], vals[:, 3], vals[:, 4]
    _check_information(path, Omega, np.array([s[:2] for s in sightings], dtype=np.int64).reshape(S, 2),
                       [s[3] for s in sightings], [s[4] for s in sightings])
    L = np.full((ids.size, 2), np.nan)
    if points:
        L[np.searchsorted(ids, [p[0] for p in points])] = [p[1] for p in points]
    else:
        # no VERTEX_XY: each landmark starts where its first sighting puts it, t_i + R_i z
        rows, k = np.unique(obs[:, 1], return_index=True)
        x = X[obs[k, 0]]
        c, s = np.cos(x[:, 2]), np.sin(x[:, 2])
        L[rows, 0] = x[:, 0] + c * Z[k, 0] - s * Z[k, 1]
        L[rows, 1] = x[:, 1] + s * Z[k, 0] + c * Z[k, 1]
    return dict(landmarks=L, landmark_ids=ids, obs_edges=obs, obs_Z=Z, obs_Omega=Omega)


def load_g2o3d(path):
    """Read a 3-D pose graph from a g2o or TORO text file.

    Records: g2o's ``VERTEX_SE3:QUAT id x y z qx qy qz qw`` and
    ``EDGE_SE3:QUAT i j x y z qx qy qz qw`` followed by the 21 upper-triangle entries of the
    ``6 x 6`` information matrix (row by row), and TORO's ``VERTEX3 id x y z roll pitch yaw``
    and ``EDGE3 i j x y z roll pitch yaw`` with the same 21 entries; a rotation from angles is
    ``R_z(yaw) R_y(pitch) R_x(roll)``. The information matrices are over
    ``[translation, rotation]``.

    Parameters
    ----------
    path : str or Path
        A text file, plain or gzip-compressed (detected from its content).

    Returns
    -------
    PoseGraph3D
        ``T (n, 4, 4)``: the vertices' poses, or, for a file of edges only (TORO's
        ``sphere2500``), the odometry guess composed from the edges
        (:func:`slamlib.graph_slam3d.pose_graph3d_initial_guess`, first pose at the identity);
        ``edges (E, 2)``, ``Z (E, 4, 4)``, ``Omega (E, 6, 6)``, ``vertex_ids (n,)``, ``source``.

    Raises
    ------
    FileNotFoundError, ValueError
        As :func:`load_g2o` (file and line named); also for a zero quaternion. A file of
        edges only must be connected.

    References
    ----------
    Kuemmerle et al. (2011); Grisetti, Stachniss & Burgard (2009) (TORO); L. Carlone, R.
    Tron, K. Daniilidis, F. Dellaert, "Initialization techniques for 3D SLAM", ICRA 2015.
    """
    from ..graph_slam3d import pose_graph3d_initial_guess
    from ..lie import _euler_to_so3, _quat_to_so3, _se3

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"g2o file {path} not found")
    vid, vval, vline, vtag, eij, evals, eline, etag, *_ = _parse(path, 3)

    def poses(vals, tags, lines):
        out = np.zeros((len(vals), 4, 4))
        if not vals:
            return out
        quat = np.array([t.endswith(":QUAT") for t in tags], dtype=bool)
        v = [np.asarray(x[:7 if q else 6], dtype=np.float64) for x, q in zip(vals, quat)]
        if quat.any():
            q = np.array([x[3:7] for x, is_q in zip(v, quat) if is_q])
            zero = np.flatnonzero(np.linalg.norm(q, axis=1) < 1e-12)
            if zero.size:
                k = np.flatnonzero(quat)[zero[0]]
                raise ValueError(f"{path}:{lines[k]}: {tags[k]} has a zero quaternion")
            out[quat] = _se3(_quat_to_so3(q), np.array([x[:3] for x, is_q in zip(v, quat) if is_q]))
        if (~quat).any():
            rpy = np.array([x[3:6] for x, is_q in zip(v, quat) if not is_q])
            out[~quat] = _se3(_euler_to_so3(rpy), np.array([x[:3] for x, is_q in zip(v, quat) if not is_q]))
        return out

    sorted_ids, order, pos, eij = _vertex_rows(path, vid, vline, eij, eline, etag, need_vertices=False,
                                               vertex_name="VERTEX_SE3:QUAT or VERTEX3")
    Z = poses([e[:7] for e in evals], etag, eline)
    info = np.array([e[7:] if t.endswith(":QUAT") else e[6:] for e, t in zip(evals, etag)],
                    dtype=np.float64).reshape(-1, 21)
    iu = np.triu_indices(6)
    Omega = np.zeros((info.shape[0], 6, 6))
    Omega[:, iu[0], iu[1]] = info
    Omega[:, iu[1], iu[0]] = info
    _check_information(path, Omega, eij, eline, etag)
    if vid:
        T = poses(vval, vtag, vline)[order]
    else:
        T = pose_graph3d_initial_guess(sorted_ids.size, pos, Z)
    return PoseGraph3D(T=T, edges=pos, Z=Z, Omega=Omega, vertex_ids=sorted_ids, source=str(path))


def load_intel():
    """The Intel Research Lab pose graph (real robot, 1728 poses, 2512 edges).

    Returns
    -------
    PoseGraph
        Read by :func:`load_g2o` from ``slamlib/data/pose_graphs/intel.g2o.gz``;
        ``X`` is the odometry initial guess of the file.

    References
    ----------
    Howard & Roy, Radish (2003); Kuemmerle et al. (2011) (g2o format).
    """
    return load_g2o(data_path("pose_graphs", "intel.g2o.gz"))


def load_m3500():
    """The Manhattan M3500 pose graph (simulated, 3500 poses, 5453 edges).

    Returns
    -------
    PoseGraph
        Read by :func:`load_g2o` from ``slamlib/data/pose_graphs/M3500.g2o.gz``;
        ``X`` is the odometry initial guess of the file.

    References
    ----------
    Olson, Leonard & Teller, ICRA 2006; Kuemmerle et al. (2011) (g2o format).
    """
    return load_g2o(data_path("pose_graphs", "M3500.g2o.gz"))


def load_sphere2500():
    """The sphere2500 3-D pose graph (simulated, 2500 poses, 4949 edges) and its true poses.

    Returns
    -------
    graph : PoseGraph3D
        Read by :func:`load_g2o3d` from ``slamlib/data/pose_graphs/sphere2500.txt.gz`` (TORO
        ``EDGE3`` records only); ``T`` is the odometry guess, first pose at the identity.
    truth : ndarray, shape (2500, 4, 4)
        The true poses: the noise-free edges of ``sphere2500_groundtruth.txt.gz`` composed along
        the same tree (first pose at the identity, as in `graph`).

    References
    ----------
    Kaess, Ranganathan & Dellaert (2008); Carlone, Tron, Daniilidis & Dellaert, ICRA 2015.
    """
    graph = load_g2o3d(data_path("pose_graphs", "sphere2500.txt.gz"))
    truth = load_g2o3d(data_path("pose_graphs", "sphere2500_groundtruth.txt.gz"))
    if not np.array_equal(truth.edges, graph.edges):
        raise ValueError("sphere2500: the ground-truth file's edges differ from the graph's")
    return graph, truth.T


class City10000(NamedTuple):
    """The City10000 data set in arrival order (:func:`load_city10000`).

    Attributes
    ----------
    graph : PoseGraph
        All measurements as a pose graph (``X`` the odometry guess, first pose at the origin), the
        first hypothesis of each line, information ``diag(30^2, 30^2, 100^2)`` for every edge (the
        odometry noise of GTSAM's City10000 examples: sigmas 1/30 m, 1/30 m, 1/100 rad).
    truth : ndarray, shape (n, 3)
        The reference poses, or None when not loaded.
    n_hypotheses : int ndarray, shape (E,)
        How many alternative measurements each line carried (1 or 2).
    """

    graph: PoseGraph
    truth: np.ndarray | None
    n_hypotheses: np.ndarray


#: Noise of every City10000 measurement (GTSAM's City10000 examples): sigmas of x, y, theta.
CITY10000_SIGMAS = (1.0 / 30.0, 1.0 / 30.0, 1.0 / 100.0)


def load_city10000(path=None, truth_path=None):
    """Read City10000 (the iSAM format: ``EDGE2 i 1 j 0 k x y theta [x y theta ...]``), in arrival order.

    Each line is one measurement of pose ``j`` from pose ``i`` with ``k`` hypotheses; the first
    hypothesis is used. Odometry lines (``j = i + 1``) introduce the poses in order; the rest are
    loop closures. The edges keep the file's order, so a prefix of them is the graph as it stood
    when a pose arrived (the incremental setting).

    Parameters
    ----------
    path, truth_path : str or Path, optional
        The measurement file and the reference poses (``x y theta`` per line); default the
        shipped ``T1_city10000_04.txt.gz`` and ``ISAM2_GT_city10000.txt.gz``. With `path` given and
        `truth_path` None, no truth is read.

    Returns
    -------
    City10000

    Raises
    ------
    FileNotFoundError, ValueError
        A malformed line (file and line named), a pose that appears before the odometry that
        introduces it, or a truth file whose length differs from the number of poses.

    References
    ----------
    Kaess, Ranganathan & Dellaert (2008) (iSAM, the City10000 simulation); Hsiao & Kaess, ICRA 2019.
    """
    if path is None:
        path = data_path("pose_graphs", "T1_city10000_04.txt.gz")
        truth_path = data_path("pose_graphs", "ISAM2_GT_city10000.txt.gz")
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"City10000 file {path} not found")
    eij, Z, nh, lines = [], [], [], []
    for lineno, raw in enumerate(_lines(path), start=1):
        tok = raw.split()
        if not tok or tok[0].startswith("#"):
            continue
        if tok[0] != "EDGE2" or len(tok) < 9:
            raise ValueError(f"{path}:{lineno}: expected 'EDGE2 i 1 j 0 k x y theta ...', got {raw.strip()[:60]!r}")
        i, _, j, _, k = _numbers(path, lineno, tok[1:6], "iiiii")
        if k < 1 or len(tok) != 6 + 3 * k:
            raise ValueError(f"{path}:{lineno}: {k} hypotheses need {6 + 3 * k} fields, got {len(tok)}")
        z = _numbers(path, lineno, tok[6:9], "fff")
        eij.append((i, j))
        Z.append(z)
        nh.append(k)
        lines.append(lineno)
    if not eij:
        raise ValueError(f"{path}: no EDGE2 line")
    edges = np.array(eij, dtype=np.int64)
    n = int(edges.max()) + 1
    # a pose is introduced by the odometry line (n - 1 -> n); no line may use a pose before that
    seen = np.maximum.accumulate(np.where(edges[:, 1] == edges[:, 0] + 1, edges[:, 1], 0))
    bad = np.flatnonzero(edges.max(axis=1) > seen)
    if bad.size:
        k = bad[0]
        raise ValueError(f"{path}:{lines[k]}: pose {edges[k].max()} is used before the odometry that introduces it")
    loop = np.flatnonzero(edges[:, 0] == edges[:, 1])
    if loop.size:
        raise ValueError(f"{path}:{lines[loop[0]]}: an edge joins pose {edges[loop[0], 0]} to itself")
    Z = np.array(Z, dtype=np.float64)
    Omega = np.broadcast_to(np.diag(1.0 / np.square(CITY10000_SIGMAS)), (len(edges), 3, 3)).copy()
    from ..graph_slam import pose_graph_initial_guess

    X = pose_graph_initial_guess(n, edges, Z)
    graph = PoseGraph(X=X, edges=edges, Z=Z, Omega=Omega, vertex_ids=np.arange(n), source=str(path))
    truth = None
    if truth_path is not None:
        rows = [r.split() for r in _lines(Path(truth_path)) if r.strip()]
        if len(rows) != n or any(len(r) != 3 for r in rows):
            raise ValueError(f"{truth_path}: expected {n} lines of 'x y theta', got {len(rows)}")
        truth = np.array(rows, dtype=np.float64)
    return City10000(graph=graph, truth=truth, n_hypotheses=np.array(nh, dtype=np.int64))
