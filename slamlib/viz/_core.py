"""Core plotting helpers: poses, trajectories, covariance ellipses, particles,
landmarks, occupancy grids and animations.

matplotlib is imported inside the functions only. Every function draws on the
given ``ax`` (or on a new figure when ``ax`` is None, as everywhere in
``slamlib.viz``) and returns it; extra
keyword arguments go to the underlying matplotlib call.

References
----------
Thrun, Burgard & Fox, *Probabilistic Robotics* (2005): the figures of
Ch. 5 (motion samples), Ch. 7 (EKF uncertainty ellipses), Ch. 8 (particle
sets) and Ch. 9 (occupancy grids).
"""

from __future__ import annotations

import re

import numpy as np

from .._checks import as_array, as_covariance, as_scalar

__all__ = [
    "plot_pose",
    "plot_trajectory",
    "plot_covariance_ellipse",
    "plot_particles",
    "plot_landmarks",
    "plot_grid",
    "animate",
]


#: The colour of ground truth (true paths, true landmarks, true positions) in every figure.
TRUTH_COLOR = "k"


def _axes(ax, figsize=None):
    """`ax`, or the axes of a new figure when `ax` is None (the one meaning of ``ax=None`` in ``viz``)."""
    if ax is None:
        import matplotlib.pyplot as plt

        _, ax = plt.subplots(figsize=figsize, layout="constrained")
    return ax



def plot_pose(x, ax=None, *, size=None, **kw):
    """Draw a pose as a filled triangle pointing along its heading.

    Parameters
    ----------
    x : ndarray, shape (3,)
        Pose ``[x, y, theta]``.
    ax : matplotlib.axes.Axes, optional
        Axes to draw on (default: a new figure).
    size : float, keyword-only
        Length of the triangle in data units (default: 3 % of the larger
        axis span, at least 0.1).
    **kw
        Passed to ``matplotlib.patches.Polygon`` (``color``, ``alpha``, ...).

    Returns
    -------
    matplotlib.axes.Axes

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 5.2.1 (the pose ``(x, y, theta)``).
    """
    from matplotlib.patches import Polygon

    x = as_array(x, "x", (3,))
    ax = _axes(ax)
    if size is None:
        span = max(np.ptp(ax.get_xlim()), np.ptp(ax.get_ylim())) if ax.has_data() else 3.0
        size = max(0.03 * span, 0.1)
    size = as_scalar(size, "size", positive=True)
    c, s = np.cos(x[2]), np.sin(x[2])
    local = np.array([[size, 0.0], [-0.5 * size, 0.4 * size], [-0.5 * size, -0.4 * size]])
    pts = x[:2] + local @ np.array([[c, s], [-s, c]])
    kw.setdefault("color", "C3")
    kw.setdefault("zorder", 5)
    ax.add_patch(Polygon(pts, closed=True, **kw))
    ax.update_datalim(pts)
    ax.autoscale_view()
    return ax


def plot_trajectory(xs, ax=None, **kw):
    """Draw the path of a sequence of poses.

    Parameters
    ----------
    xs : ndarray, shape (T, 3) or (T, 2)
        Poses or positions.
    ax : matplotlib.axes.Axes, optional
        Axes to draw on (default: a new figure).
    **kw
        Passed to ``ax.plot`` (``color``, ``label``, ``lw``, ...).

    Returns
    -------
    matplotlib.axes.Axes

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 5.4 (paths under odometry).
    """
    xs = as_array(xs, "xs", ndim=2)
    if xs.shape[1] not in (2, 3):
        raise ValueError(f"xs must have shape (T, 3) or (T, 2), got {xs.shape}")
    ax = _axes(ax)
    kw.setdefault("lw", 1.2)
    ax.plot(xs[:, 0], xs[:, 1], **kw)
    ax.set_aspect("equal", adjustable="datalim")
    return ax


def plot_covariance_ellipse(mean, cov, n_sigma=2.0, ax=None, *, n_std=None, **kw):
    """Draw the ``n_sigma`` ellipse of a 2-D Gaussian.

    Parameters
    ----------
    mean : ndarray, shape (2,)
        Centre.
    cov : ndarray, shape (2, 2)
        Covariance (symmetric positive semi-definite).
    n_sigma : float
        Mahalanobis radius: the ellipse ``(p - mean)^T cov^-1 (p - mean) = n_sigma^2``.
    ax : matplotlib.axes.Axes, optional
        Axes to draw on (default: a new figure).
    n_std : float, keyword-only
        Alias of `n_sigma`.
    **kw
        Passed to ``matplotlib.patches.Ellipse`` (``color``, ``lw``, ``ls``, ...).

    Returns
    -------
    matplotlib.axes.Axes

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 3.2 (multivariate normal) and Sec. 7.5 (uncertainty ellipses of EKF localization).
    """
    from matplotlib.patches import Ellipse

    mean = as_array(mean, "mean", (2,))
    cov = as_covariance(cov, "cov", 2)
    k = as_scalar(n_sigma if n_std is None else n_std, "n_sigma" if n_std is None else "n_std", positive=True)
    vals, vecs = np.linalg.eigh(cov)
    vals = np.clip(vals, 0.0, None)
    angle = np.degrees(np.arctan2(vecs[1, 1], vecs[0, 1]))
    width, height = 2 * k * np.sqrt(vals[1]), 2 * k * np.sqrt(vals[0])
    ax = _axes(ax)
    color = kw.pop("color", "C0")
    kw.setdefault("edgecolor", color)
    kw.setdefault("facecolor", "none")
    ax.add_patch(Ellipse(xy=mean, width=width, height=height, angle=angle, **kw))
    r = k * np.sqrt(vals.max())
    ax.update_datalim([mean - r, mean + r])
    ax.autoscale_view()
    return ax


def plot_particles(particles, weights=None, ax=None, *, arrows=False, **kw):
    """Scatter a particle set, sized by weight if given.

    Parameters
    ----------
    particles : ndarray, shape (M, 3) or (M, 2)
        Particle poses (or positions).
    weights : ndarray, shape (M,), optional
        Non-negative weights; marker areas are proportional to them.
    ax : matplotlib.axes.Axes, optional
        Axes to draw on (default: a new figure).
    arrows : bool, keyword-only
        Also draw short heading ticks (``(M, 3)`` particles only).
    **kw
        Passed to ``ax.scatter`` (``color``, ``alpha``, ``s``, ``label``, ...).

    Returns
    -------
    matplotlib.axes.Axes

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 4.3 and Sec. 8.3 (particle sets).
    """
    p = as_array(particles, "particles", ndim=2)
    if p.shape[1] not in (2, 3):
        raise ValueError(f"particles must have shape (M, 3) or (M, 2), got {p.shape}")
    M = p.shape[0]
    ax = _axes(ax)
    if weights is not None:
        w = as_array(weights, "weights", (M,))
        if np.any(w < 0):
            raise ValueError("weights must be non-negative")
        total = w.sum()
        sizes = 3.0 + 30.0 * (w / total * M if total > 0 else np.ones(M)) / max(1.0, np.sqrt(M) / 4)
        kw.setdefault("s", sizes)
    else:
        kw.setdefault("s", 4.0 if M > 200 else 10.0)
    kw.setdefault("color", "C0")
    kw.setdefault("alpha", 0.5 if M > 200 else 0.8)
    kw.setdefault("linewidths", 0)
    ax.scatter(p[:, 0], p[:, 1], **kw)
    if arrows and p.shape[1] == 3:
        span = max(np.ptp(p[:, 0]), np.ptp(p[:, 1]), 1.0)
        ln = 0.02 * span
        ax.quiver(p[:, 0], p[:, 1], ln * np.cos(p[:, 2]), ln * np.sin(p[:, 2]), angles="xy", scale_units="xy",
                  scale=1.0, color=kw["color"], alpha=kw["alpha"], width=0.002)
    ax.set_aspect("equal", adjustable="datalim")
    return ax


def plot_landmarks(landmarks, ax=None, labels=False, **kw):
    """Mark landmarks with stars, optionally numbered.

    Parameters
    ----------
    landmarks : ndarray, shape (N, 2)
        Landmark positions.
    ax : matplotlib.axes.Axes, optional
        Axes to draw on (default: a new figure).
    labels : bool
        Write each landmark's index (0-based) beside it.
    **kw
        Passed to ``ax.scatter``.

    Returns
    -------
    matplotlib.axes.Axes

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 6.2 (feature-based maps).
    """
    lm = as_array(landmarks, "landmarks", (None, 2))
    ax = _axes(ax)
    kw.setdefault("marker", "*")
    kw.setdefault("s", 90)
    kw.setdefault("color", "k")
    kw.setdefault("zorder", 4)
    kw.setdefault("label", "landmarks")
    ax.scatter(lm[:, 0], lm[:, 1], **kw)
    if labels:
        for j, (mx, my) in enumerate(lm):
            ax.annotate(str(j), (mx, my), textcoords="offset points", xytext=(5, 5), fontsize=8)
    ax.set_aspect("equal", adjustable="datalim")
    return ax


def plot_grid(grid, ax=None, *, unknown_color="#c8d8e8", **kw):
    """Show an occupancy grid (white free, black occupied) in world coordinates.

    Parameters
    ----------
    grid : OccupancyGrid
        The map; drawn with ``origin="lower"`` and the grid's ``extent`` so
        that x runs right and y up.
    ax : matplotlib.axes.Axes, optional
        Axes to draw on (default: a new figure).
    unknown_color : color, keyword-only
        Colour of unknown (NaN) cells.
    **kw
        Passed to ``ax.imshow``.

    Returns
    -------
    matplotlib.axes.Axes

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 9.1 (occupancy grid maps).
    """
    import matplotlib as mpl

    from ..maps import OccupancyGrid

    if not isinstance(grid, OccupancyGrid):
        raise TypeError(f"grid must be an OccupancyGrid, got {type(grid).__name__}")
    ax = _axes(ax)
    cmap = mpl.colormaps["gray_r"].with_extremes(bad=unknown_color)
    kw.setdefault("cmap", cmap)
    kw.setdefault("vmin", 0.0)
    kw.setdefault("vmax", 1.0)
    kw.setdefault("interpolation", "nearest")
    ax.imshow(np.ma.masked_invalid(grid.occupancy), origin="lower", extent=grid.extent, **kw)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal")
    return ax


#: Glyphs for the buttons of matplotlib's animation controls, which otherwise are Font Awesome
#: icons whose stylesheet comes from a CDN: the book must read offline.
_BUTTON_GLYPHS = {  # characters common fonts have (DejaVu, Liberation, the system UI fonts)
    "fa fa-minus": "\u2212",  # slower
    "fa fa-fast-backward": "\u21e4",  # first frame: leftwards arrow to bar
    "fa fa-step-backward": "\u2039",  # previous frame
    "fa fa-play fa-flip-horizontal": "\u25c0",  # play backwards
    "fa fa-pause": "\u25ae\u25ae",  # pause
    "fa fa-play": "\u25b6",  # play
    "fa fa-step-forward": "\u203a",  # next frame
    "fa fa-fast-forward": "\u21e5",  # last frame: rightwards arrow to bar
    "fa fa-plus": "+",  # faster
}


def _offline_controls(html):
    """Drop the CDN stylesheet of ``to_jshtml`` and draw its buttons with Unicode glyphs."""
    html = re.sub(r'<link rel="stylesheet"\s+href="https?://[^"]*font-awesome[^"]*">\s*', "", html)

    def glyph(match):
        cls = match.group(1)
        if cls not in _BUTTON_GLYPHS:
            raise RuntimeError(f"unknown animation button icon {cls!r}: update slamlib.viz._core._BUTTON_GLYPHS")
        return f'<span class="anim-glyph" aria-hidden="true">{_BUTTON_GLYPHS[cls]}</span>'

    return re.sub(r'<i class="(fa [^"]*)"></i>', glyph, html)


def _accessible_controls(html, alt):
    """Give the frame its text alternative and the frame slider its label (axe-core's image-alt and
    label rules)."""
    import html as _html

    html, n_img = re.subn(r'<img id="(_anim_img\w+)">', lambda m: f'<img id="{m.group(1)}" alt="{_html.escape(alt)}">',
                          html)
    html, n_slider = re.subn(r'<input id="(_anim_slider\w+)" type="range"',
                             r'<input id="\1" type="range" aria-label="Frame"', html)
    if n_img != 1 or n_slider != 1:
        raise RuntimeError("matplotlib's to_jshtml markup changed: update slamlib.viz._core._accessible_controls")
    return html


def animate(fig, update, frames, *, alt, interval=100, embed_limit_mb=30.0, dpi=None):
    """Render a matplotlib animation to self-contained HTML for the static book.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        Figure the animation draws on; it is closed afterwards so that the
        notebook does not also show it as a static image.
    update : callable
        ``update(frame)`` redraws the figure for one frame.
    frames : int or iterable
        Number of frames, or the frame values passed to `update`. Keep it
        small (tens of frames): every frame is embedded as an image.
    alt : str, keyword-only
        What the animation shows, in words: the text alternative of its
        frames for readers who cannot see them.
    interval : float, keyword-only
        Milliseconds between frames.
    embed_limit_mb : float, keyword-only
        Value of ``rcParams["animation.embed_limit"]`` during rendering (MB).
    dpi : float, keyword-only
        Resolution of the embedded frames (default: the figure's, capped at 80).

    Returns
    -------
    IPython.display.HTML
        ``FuncAnimation(...).to_jshtml()``: frames plus play/step controls,
        whose buttons are drawn with Unicode glyphs instead of matplotlib's
        Font Awesome icons (a stylesheet from a CDN), so that the page needs
        no network.

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 8.3 (filters shown as sequences of
    snapshots; here as an animation).
    """
    import matplotlib as mpl
    import matplotlib.pyplot as plt
    from IPython.display import HTML
    from matplotlib.animation import FuncAnimation

    if not callable(update):
        raise TypeError(f"update must be callable, got {type(update).__name__}")
    if not isinstance(alt, str) or not alt.strip():
        raise ValueError(f"alt must be a non-empty description of the animation, got {alt!r}")
    interval = as_scalar(interval, "interval", positive=True)
    embed_limit_mb = as_scalar(embed_limit_mb, "embed_limit_mb", positive=True)
    if dpi is None:
        dpi = min(float(fig.dpi), 80.0)
    dpi = as_scalar(dpi, "dpi", positive=True)
    old_dpi = fig.dpi
    try:
        with mpl.rc_context({"animation.embed_limit": embed_limit_mb}):
            fig.set_dpi(dpi)
            anim = FuncAnimation(fig, update, frames=frames, interval=interval, blit=False)
            html = anim.to_jshtml(default_mode="once")
    finally:
        fig.set_dpi(old_dpi)
        plt.close(fig)
    return HTML(_accessible_controls(_offline_controls(html), alt))
