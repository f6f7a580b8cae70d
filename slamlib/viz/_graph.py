"""Plots of graph SLAM: pose graphs, sparsity patterns and fill-in, convergence of chi2.

matplotlib is imported inside the functions only. Functions drawing on one axes take an
optional ``ax`` (a new figure when omitted) and return it; the panel functions make their own
figure and return its axes.
"""

from __future__ import annotations

import numpy as np

from .._checks import as_array

__all__ = ["plot_pose_graph", "plot_pose_graphs", "plot_sparsity", "plot_sparsity_panels", "plot_convergence"]

_TRUTH = "0.15"


def _axes(ax, figsize=(6.0, 6.0)):
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=figsize, layout="constrained")
    return ax


def _edges(edges, n):
    if edges is None:
        return np.zeros((0, 2), dtype=np.int64)
    e = np.asarray(edges)
    if e.dtype.kind not in "iu" or e.ndim != 2 or e.shape[1] != 2 or (e.size and (e.min() < 0 or e.max() >= n)):
        raise ValueError(f"edges must be integer index pairs of shape (E, 2) into {n} poses")
    return e


def plot_pose_graph(X, edges=None, ax=None, *, highlight=None, title=None, color="C0", label=None, closures=True):
    """Draw a pose graph: the path through consecutive poses and its loop-closure edges.

    Parameters
    ----------
    X : ndarray, shape (n, 3) or (n, 2)
        Poses (or positions).
    edges : int ndarray, shape (E, 2), optional
        Edges; those between non-consecutive poses are drawn as thin grey
        lines (loop closures).
    ax : matplotlib.axes.Axes, optional
        Axes to draw on; a new figure if omitted.
    highlight : sequence of int, optional, keyword-only
        Indices of edges to draw thick and red (e.g. a wrong loop closure).
    title : str, optional, keyword-only
    color : matplotlib colour, keyword-only
        Colour of the path.
    label : str, optional, keyword-only
        Legend label of the path.
    closures : bool, keyword-only
        Draw the loop-closure edges.

    Returns
    -------
    matplotlib.axes.Axes

    References
    ----------
    Grisetti et al., "A tutorial on graph-based SLAM" (2010), Fig. 1 (a pose graph).
    """
    from matplotlib.collections import LineCollection

    X = as_array(X, "X", ndim=2)
    if X.shape[1] not in (2, 3):
        raise ValueError(f"X must have shape (n, 3) or (n, 2), got {X.shape}")
    E = _edges(edges, X.shape[0])
    ax = _axes(ax)
    if closures and E.size:
        loop = np.abs(E[:, 0] - E[:, 1]) > 1
        segs = np.stack([X[E[loop, 0], :2], X[E[loop, 1], :2]], axis=1)
        ax.add_collection(LineCollection(segs, colors="0.6", linewidths=0.4, alpha=0.6, zorder=1,
                                         label=f"loop closures ({int(loop.sum())})"))
    ax.plot(X[:, 0], X[:, 1], color=color, lw=0.8, zorder=2, label=label)
    if highlight is not None:
        h = np.atleast_1d(np.asarray(highlight, dtype=np.int64))
        for k in h:
            i, j = E[k]
            ax.plot([X[i, 0], X[j, 0]], [X[i, 1], X[j, 1]], color="C3", lw=2.5, zorder=3)
        ax.plot([], [], color="C3", lw=2.5, label="wrong loop closure" if h.size == 1 else "highlighted edges")
    ax.plot(*X[0, :2], "o", color="k", ms=5, zorder=4)
    ax.set_aspect("equal", adjustable="datalim")
    ax.autoscale_view()
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    if title:
        ax.set_title(title)
    return ax


def plot_pose_graphs(panels, edges=None, *, highlight=None, size=4.2):
    """Several pose graphs side by side (e.g. the odometry guess and the optimum).

    Parameters
    ----------
    panels : dict
        Panel title -> poses ``(n, 3)``.
    edges : int ndarray, shape (E, 2), optional
        Edges shared by all panels.
    highlight : sequence of int, optional, keyword-only
        Edges drawn thick and red in every panel.
    size : float, keyword-only
        Width and height of a panel, inches.

    Returns
    -------
    ndarray of matplotlib.axes.Axes

    References
    ----------
    Grisetti et al. (2010), Fig. 1.
    """
    import matplotlib.pyplot as plt

    if not isinstance(panels, dict) or not panels:
        raise TypeError("panels must be a non-empty dict mapping a title to poses (n, 3)")
    fig, axes = plt.subplots(1, len(panels), figsize=(size * len(panels), size), layout="constrained", squeeze=False)
    for ax, (name, X) in zip(axes[0], panels.items()):
        plot_pose_graph(X, edges, ax=ax, highlight=highlight, title=name)
    return axes[0]


def plot_sparsity(M, ax=None, *, title=None, resolution=600, tol=0.0):
    """Draw the non-zero pattern of a matrix, with the count in the title.

    Parameters
    ----------
    M : scipy.sparse matrix or ndarray, shape (N, N)
        The matrix.
    ax : matplotlib.axes.Axes, optional
        Axes to draw on; a new figure if omitted.
    title : str, optional, keyword-only
        Title; the number of non-zeros is appended.
    resolution : int, keyword-only
        Matrices with more rows than this are drawn binned to this many pixels
        a side, a bin dark if any of its entries is non-zero.
    tol : float, keyword-only
        Entries with ``|m_ij| <= tol * max |m|`` count as zero (for dense matrices).

    Returns
    -------
    matplotlib.axes.Axes

    References
    ----------
    T. A. Davis, *Direct Methods for Sparse Linear Systems* (2006), Ch. 1 (sparsity patterns).
    """
    import scipy.sparse as sp

    ax = _axes(ax, figsize=(4.5, 4.5))
    if sp.issparse(M):
        C = sp.coo_matrix(M)
        keep = np.abs(C.data) > tol * (np.abs(C.data).max() if C.nnz else 0.0)
        r, c, N = C.row[keep], C.col[keep], C.shape[0]
    else:
        A = as_array(M, "M", ndim=2)
        r, c = np.nonzero(np.abs(A) > tol * np.abs(A).max())
        N = A.shape[0]
    # one pixel per entry up to 600 x 600; larger matrices are binned, a bin dark if any entry in it is
    B = max(1, min(N, int(resolution)))
    img = np.zeros((B, B), dtype=bool)
    img[r * B // N, c * B // N] = True
    ax.imshow(img, cmap="Greys", vmin=0, vmax=1, interpolation="nearest", extent=(-0.5, N - 0.5, N - 0.5, -0.5))
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    pct = 100.0 * r.size / float(N * N)
    share = f"{pct:.0f} %" if pct >= 10 else f"{pct:.2g} %"
    ax.set_title(f"{title + ': ' if title else ''}{r.size:,} non-zeros ({share})", fontsize=9)
    return ax


def plot_sparsity_panels(matrices, *, size=3.6, tol=0.0, resolution=600):
    """Sparsity patterns side by side (e.g. ``H`` and its factor in two orders).

    Parameters
    ----------
    matrices : dict
        Panel title -> matrix (sparse or dense).
    size : float, keyword-only
        Width and height of a panel, inches.
    tol : float, keyword-only
        As in :func:`plot_sparsity`.
    resolution : int, keyword-only
        As in :func:`plot_sparsity`.

    Returns
    -------
    ndarray of matplotlib.axes.Axes

    References
    ----------
    Davis (2006), Ch. 4 and 7 (fill-in and fill-reducing orderings).
    """
    import matplotlib.pyplot as plt

    if not isinstance(matrices, dict) or not matrices:
        raise TypeError("matrices must be a non-empty dict mapping a title to a matrix")
    fig, axes = plt.subplots(1, len(matrices), figsize=(size * len(matrices), size + 0.3), layout="constrained",
                             squeeze=False)
    for ax, (name, M) in zip(axes[0], matrices.items()):
        plot_sparsity(M, ax=ax, title=name, tol=tol, resolution=resolution)
    return axes[0]


def plot_convergence(curves, ax=None, *, title=None, ylabel=r"$\chi^2$"):
    """chi2 (or cost) per iteration for several optimisers, log scale.

    Parameters
    ----------
    curves : dict
        Label -> values per iteration (the initial value first), e.g.
        ``PoseGraphResult.chi2``.
    ax : matplotlib.axes.Axes, optional
        Axes to draw on; a new figure if omitted.
    title : str, optional, keyword-only
    ylabel : str, keyword-only

    Returns
    -------
    matplotlib.axes.Axes

    References
    ----------
    Madsen, Nielsen & Tingleff, *Methods for non-linear least squares problems* (2004), Sec. 3.
    """
    if not isinstance(curves, dict) or not curves:
        raise TypeError("curves must be a non-empty dict mapping a label to values per iteration")
    ax = _axes(ax, figsize=(6.0, 3.8))
    markers = "os^vD<>"
    for k, (name, v) in enumerate(curves.items()):
        v = as_array(v, f"curves[{name!r}]", ndim=1)
        ax.semilogy(np.arange(v.size), v, marker=markers[k % len(markers)], ms=4, lw=1.2, label=name)
    ax.set_xlabel("iteration")
    ax.set_ylabel(ylabel)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    if title:
        ax.set_title(title)
    return ax
