"""Pose graphs in the g2o text format, and the two benchmark graphs the package ships.

A g2o file lists one record per line:

* ``VERTEX_SE2 id x y theta``: a pose (its initial estimate);
* ``EDGE_SE2 i j dx dy dtheta I11 I12 I13 I22 I23 I33``: pose ``j`` measured
  from pose ``i``, with the upper triangle of its ``3 x 3`` information matrix.

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

__all__ = ["PoseGraph", "load_g2o", "load_intel", "load_m3500"]


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
    """

    X: np.ndarray
    edges: np.ndarray
    Z: np.ndarray
    Omega: np.ndarray
    vertex_ids: np.ndarray
    source: str

    @property
    def n_poses(self) -> int:
        """Number of poses ``n``."""
        return int(self.X.shape[0])

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


def load_g2o(path):
    """Read a 2-D pose graph (``VERTEX_SE2`` and ``EDGE_SE2`` records) from a g2o file.

    Parameters
    ----------
    path : str or Path
        A g2o text file, plain or gzip-compressed (detected from its content).

    Returns
    -------
    PoseGraph
        ``X (n, 3)``, ``edges (E, 2)`` (row indices), ``Z (E, 3)``,
        ``Omega (E, 3, 3)``, ``vertex_ids (n,)``, ``source``.

    Raises
    ------
    FileNotFoundError
        If `path` does not exist.
    ValueError
        Naming the file and line: an unknown record type, a wrong number of
        fields, a field that is not a number (or an id that is not an integer),
        NaN or inf, a vertex defined twice, an edge to an undefined vertex, an
        edge from a vertex to itself, an information matrix that is not
        positive definite; or a file without vertices.

    Notes
    -----
    The information matrix of an edge is given by its upper triangle in row
    order, ``I11 I12 I13 I22 I23 I33``, and mirrored. Headings are kept as
    written (the optimisers wrap them).

    References
    ----------
    Kuemmerle et al., "g2o: A general framework for graph optimization", ICRA 2011.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"g2o file {path} not found")
    vid, vpose, vline = [], [], []
    eij, eline, emeas, einfo = [], [], [], []
    for lineno, raw in enumerate(_lines(path), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        tok = line.split()
        tag = tok[0]
        if tag == "VERTEX_SE2":
            if len(tok) != 5:
                raise ValueError(f"{path}:{lineno}: VERTEX_SE2 needs 4 fields (id x y theta), got {len(tok) - 1}")
            vals = _numbers(path, lineno, tok[1:], "ifff")
            vid.append(vals[0])
            vpose.append(vals[1:])
            vline.append(lineno)
        elif tag == "EDGE_SE2":
            if len(tok) != 12:
                raise ValueError(f"{path}:{lineno}: EDGE_SE2 needs 11 fields (i j dx dy dtheta I11 I12 I13 I22 I23 I33), "
                                 f"got {len(tok) - 1}")
            vals = _numbers(path, lineno, tok[1:], "iifffffffff")
            eij.append(vals[:2])
            emeas.append(vals[2:5])
            einfo.append(vals[5:])
            eline.append(lineno)
        else:
            raise ValueError(f"{path}:{lineno}: unsupported record {tag!r} (only VERTEX_SE2 and EDGE_SE2 are read)")
    if not vid:
        raise ValueError(f"{path}: no VERTEX_SE2 record")
    ids = np.array(vid, dtype=np.int64)
    order = np.argsort(ids, kind="stable")
    sorted_ids = ids[order]
    dup = np.flatnonzero(np.diff(sorted_ids) == 0)
    if dup.size:
        a, b = sorted(vline[k] for k in order[dup[0]:dup[0] + 2])
        raise ValueError(f"{path}:{b}: vertex {sorted_ids[dup[0]]} is defined twice (first on line {a})")
    X = np.array(vpose, dtype=np.float64)[order]
    eij = np.array(eij, dtype=np.int64).reshape(-1, 2)
    pos = np.searchsorted(sorted_ids, eij)
    pos_c = np.minimum(pos, sorted_ids.size - 1)
    known = sorted_ids[pos_c] == eij
    bad = np.flatnonzero(~known.all(axis=1))
    if bad.size:
        k = bad[0]
        which = eij[k, 0] if not known[k, 0] else eij[k, 1]
        raise ValueError(f"{path}:{eline[k]}: EDGE_SE2 {eij[k, 0]} {eij[k, 1]} refers to vertex {which}, "
                         "which no VERTEX_SE2 record defines")
    loop = np.flatnonzero(eij[:, 0] == eij[:, 1])
    if loop.size:
        raise ValueError(f"{path}:{eline[loop[0]]}: EDGE_SE2 joins vertex {eij[loop[0], 0]} to itself")
    info = np.array(einfo, dtype=np.float64).reshape(-1, 6)
    iu = np.array([0, 0, 0, 1, 1, 2]), np.array([0, 1, 2, 1, 2, 2])
    Omega = np.zeros((info.shape[0], 3, 3))
    Omega[:, iu[0], iu[1]] = info
    Omega[:, iu[1], iu[0]] = info
    if info.shape[0]:
        eig = np.linalg.eigvalsh(Omega)
        notpd = np.flatnonzero(eig[:, 0] <= 1e-15 * np.maximum(eig[:, -1], 0.0))
        if notpd.size:
            k = notpd[0]
            raise ValueError(f"{path}:{eline[k]}: the information matrix of EDGE_SE2 {eij[k, 0]} {eij[k, 1]} is not "
                             f"positive definite (smallest eigenvalue {eig[k, 0]:.3g})")
    return PoseGraph(X=X, edges=pos, Z=np.array(emeas, dtype=np.float64).reshape(-1, 3), Omega=Omega,
                     vertex_ids=sorted_ids, source=str(path))


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
