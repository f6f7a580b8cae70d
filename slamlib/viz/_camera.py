"""Plots of two-view geometry: matches between photographs, epipolar lines, reconstructed points."""

from __future__ import annotations

import numpy as np

from ._core import TRUTH_COLOR, _axes

__all__ = ["plot_matches", "plot_epipolar_lines", "plot_reconstruction", "plot_matrix_pattern", "plot_reprojection_errors",
           "plot_camera_paths"]


def _side_by_side(img1, img2):
    h = max(img1.shape[0], img2.shape[0])
    pad = [np.pad(im, ((0, h - im.shape[0]), (0, 0)) + ((0, 0),) * (im.ndim - 2)) for im in (img1, img2)]
    return np.concatenate(pad, axis=1), img1.shape[1]


def plot_matches(img1, img2, uv1, uv2, inliers=None, ax=None, *, max_lines=400):
    """Two photographs side by side with lines joining matched pixels (inliers green, outliers red)."""
    ax = _axes(ax, figsize=(10.0, 3.6))
    both, w = _side_by_side(img1, img2)
    ax.imshow(both)
    inl = np.ones(len(uv1), dtype=bool) if inliers is None else np.asarray(inliers, dtype=bool)
    idx = np.flatnonzero(np.ones(len(uv1), dtype=bool))[:max_lines]
    for k in idx:
        ax.plot([uv1[k, 0], uv2[k, 0] + w], [uv1[k, 1], uv2[k, 1]], "-", lw=0.6,
                color="tab:green" if inl[k] else "tab:red", alpha=0.8)
    ax.set_axis_off()
    return ax


def plot_epipolar_lines(img2, lines_px, uv2, ax=None):
    """Epipolar lines ``a u + b v + c = 0`` (pixels, rows of `lines_px`) on photograph 2 and the matched pixels."""
    ax = _axes(ax, figsize=(5.5, 3.8))
    ax.imshow(img2)
    w = img2.shape[1]
    u = np.array([0.0, w - 1.0])
    for (a, b, c), p in zip(lines_px, uv2):
        ax.plot(u, -(a * u + c) / b, "-", lw=0.8, color="tab:cyan")
        ax.plot(*p, "o", ms=3, color="tab:orange")
    ax.set_xlim(0, w - 1)
    ax.set_ylim(img2.shape[0] - 1, 0)
    ax.set_axis_off()
    return ax


def plot_reconstruction(points, T_wcs, ax=None, *, size=0.3):
    """Points and cameras seen from above (x right, z forward of the first camera)."""
    ax = _axes(ax, figsize=(5.0, 4.5))
    ax.plot(points[:, 0], points[:, 2], ".", ms=2, color="0.3")
    for T in T_wcs:
        c, z = T[:3, 3], T[:3, 2]
        ax.plot(c[0], c[2], "^", color="tab:blue", ms=8)
        ax.plot([c[0], c[0] + size * z[0]], [c[2], c[2] + size * z[2]], "-", color="tab:blue")
    ax.set_xlabel("x [first camera's units]")
    ax.set_ylabel("z (depth)")
    ax.set_aspect("equal", adjustable="datalim")
    return ax


def plot_matrix_pattern(H, ax=None, *, split=None, title=None):
    """The non-zero pattern of a matrix (``spy``), with a line after the first `split` rows and columns."""
    ax = _axes(ax, figsize=(4.2, 4.2))
    ax.spy(np.abs(np.asarray(H)) > 0, markersize=0.3, color="0.2")
    if split is not None:
        ax.axhline(split - 0.5, color="tab:red", lw=0.8)
        ax.axvline(split - 0.5, color="tab:red", lw=0.8)
    if title:
        ax.set_title(title)
    ax.set_xticks([])
    ax.set_yticks([])
    return ax


def plot_reprojection_errors(errors, labels, ax=None, *, bins=40, max_px=None):
    """Histograms of reprojection error norms (pixels), one per array in `errors`."""
    ax = _axes(ax, figsize=(5.5, 3.2))
    top = max_px if max_px is not None else max(float(np.percentile(e, 99)) for e in errors)
    for e, lab in zip(errors, labels):
        ax.hist(np.clip(e, 0, top), bins=bins, range=(0, top), histtype="step", lw=1.5, label=lab)
    ax.set_xlabel("reprojection error [px]")
    ax.set_ylabel("observations")
    ax.legend()
    return ax


def plot_camera_paths(paths, labels, ax=None, *, colors=None):
    """Camera positions seen from above (x and z of the world), one line per trajectory ``(F, 4, 4)``.

    The first trajectory is the reference, drawn in the truth colour unless `colors` says otherwise.
    """
    ax = _axes(ax, figsize=(5.5, 4.0))
    colors = colors or [TRUTH_COLOR] + [None] * (len(paths) - 1)
    for T, lab, col in zip(paths, labels, colors):
        ax.plot(T[:, 0, 3], T[:, 2, 3], "-", lw=1.5, label=lab, color=col)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("z [m] (forward at the start)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend()
    return ax
