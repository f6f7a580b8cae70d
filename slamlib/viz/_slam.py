"""Plots for the SLAM chapters: graphical models, maps, covariance structure, costs.

matplotlib is imported inside the functions only. Every function that draws on
one axes takes an optional ``ax`` and returns it; functions that draw several
panels take an optional ``axes`` and return the array of axes.
"""

from __future__ import annotations

import numpy as np

from .._checks import as_array
from . import _core
from ._core import TRUTH_COLOR, _axes

__all__ = [
    "plot_graphical_model",
    "plot_error_correlation",
    "plot_covariance_matrix",
    "plot_covariance_snapshots",
    "plot_slam_map",
    "plot_slam_uncertainty",
    "plot_landmark_variances",
    "plot_landmark_counts",
    "plot_step_times",
]

_EST_COLOR = "C0"



# --------------------------------------------------------------------------- graphical models
def plot_graphical_model(kind="online", *, n_poses=3, ax=None, title=None):
    """Dynamic Bayes network of SLAM with the estimated variables highlighted.

    Parameters
    ----------
    kind : {"online", "full", "both"}
        ``"online"`` highlights ``x_t`` and ``m`` (the posterior
        ``p(x_t, m | z_1:t, u_1:t)``); ``"full"`` highlights every pose and
        ``m`` (``p(x_1:t, m | z_1:t, u_1:t)``); ``"both"`` draws the two side
        by side.
    n_poses : int, keyword-only
        Poses drawn, ``x_{t-n+1} ... x_t`` (at least 2).
    ax : matplotlib.axes.Axes or array of two, optional
        Axes to draw on (two for ``"both"``); a new figure if omitted.
    title : str, optional
        Axes title (default names the posterior).

    Returns
    -------
    matplotlib.axes.Axes, or an array of two for ``"both"``

    Notes
    -----
    Observed nodes (controls ``u``, measurements ``z``) are grey, hidden
    nodes (poses ``x``, map ``m``) white; the shaded band marks what the
    posterior is over. Arrows run from causes to effects:
    ``x_{t-1}, u_t -> x_t`` (motion model) and ``x_t, m -> z_t``
    (measurement model).

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 10.1, Figs. 10.1 and 10.2.
    """
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, FancyArrowPatch, FancyBboxPatch

    if kind == "both":
        if ax is None:
            _, ax = plt.subplots(1, 2, figsize=(3.8 * n_poses + 2.0, 3.6), layout="constrained")
        ax = np.asarray(ax).ravel()
        if ax.size != 2:
            raise ValueError(f"kind='both' needs two axes, got {ax.size}")
        plot_graphical_model("online", n_poses=n_poses, ax=ax[0])
        plot_graphical_model("full", n_poses=n_poses, ax=ax[1])
        return ax
    if kind not in ("online", "full"):
        raise ValueError(f"kind must be 'online', 'full' or 'both', got {kind!r}")
    n = int(n_poses)
    if n < 2:
        raise ValueError(f"n_poses must be at least 2, got {n_poses}")
    ax = _axes(ax, (1.9 * n + 1.0, 3.6))
    r = 0.36
    dx = 1.9
    xs = np.arange(n) * dx
    y_u, y_x, y_z, y_m = 2.4, 1.2, 0.0, -1.3

    def label(k):
        off = n - 1 - k
        return "t" if off == 0 else f"t-{off}"

    def node(x, y, text, observed):
        ax.add_patch(Circle((x, y), r, facecolor="0.78" if observed else "white", edgecolor="0.1", lw=1.3,
                            zorder=3))
        ax.text(x, y, text, ha="center", va="center", fontsize=11, zorder=4)

    def arrow(p, q, start_gap=r):
        p, q = np.asarray(p, float), np.asarray(q, float)
        d = (q - p) / np.linalg.norm(q - p)  # start and end on the circles' rims
        ax.add_patch(FancyArrowPatch(p + start_gap * d, q - (r + 0.02) * d, arrowstyle="-|>", mutation_scale=13,
                                     color="0.15", lw=1.1, shrinkA=0, shrinkB=0, zorder=5))

    # what the posterior is over: a band behind the estimated nodes
    hl = dict(facecolor="#f6d98b", edgecolor="none", alpha=0.75, zorder=1)
    if kind == "online":
        ax.add_patch(FancyBboxPatch((xs[-1] - 0.55, y_x - 0.55), 1.1, 1.1, boxstyle="round,pad=0.05", **hl))
    else:
        ax.add_patch(FancyBboxPatch((xs[0] - 0.55, y_x - 0.55), xs[-1] - xs[0] + 1.1, 1.1,
                                    boxstyle="round,pad=0.05", **hl))
    x_m = xs.mean()
    ax.add_patch(FancyBboxPatch((x_m - 0.55, y_m - 0.55), 1.1, 1.1, boxstyle="round,pad=0.05", **hl))

    for k, x in enumerate(xs):
        t = label(k)
        node(x, y_u, f"$u_{{{t}}}$", True)
        node(x, y_x, f"$x_{{{t}}}$", False)
        node(x, y_z, f"$z_{{{t}}}$", True)
        arrow((x, y_u), (x, y_x))
        arrow((x, y_x), (x, y_z))
        arrow((x_m, y_m), (x, y_z))
        if k:
            arrow((xs[k - 1], y_x), (x, y_x))
    node(x_m, y_m, "$m$", False)
    ax.text(xs[0] - 1.0, y_x, r"$\cdots$", ha="center", va="center", fontsize=14)
    arrow((xs[0] - 0.75, y_x), (xs[0], y_x), start_gap=0.0)
    ax.set_xlim(xs[0] - 1.3, xs[-1] + 0.8)
    ax.set_ylim(y_m - 0.7, y_u + 0.6)
    ax.set_aspect("equal")
    ax.axis("off")
    if title is None:
        title = (r"online SLAM: $p(x_t, m \mid z_{1:t}, u_{1:t})$" if kind == "online"
                 else r"full SLAM: $p(x_{1:t}, m \mid z_{1:t}, u_{1:t})$")
    ax.set_title(title, fontsize=11)
    return ax


# --------------------------------------------------------------------------- correlation demo
def plot_error_correlation(robot_err, landmark_err, *, ax=None, title=None, labels=("robot", "landmark")):
    """Scatter of robot errors against the errors of a landmark mapped from the robot.

    Parameters
    ----------
    robot_err : ndarray, shape (K,)
        One error component of the robot (e.g. its x error) over `K` trials.
    landmark_err : ndarray, shape (K,)
        The same component of the landmark estimate's error.
    ax : matplotlib.axes.Axes, optional
        Axes to draw on; a new figure if omitted.
    title : str, optional
        Axes title (default: the sample correlation coefficient).
    labels : tuple of str
        Names for the two axes.

    Returns
    -------
    matplotlib.axes.Axes

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 10.2.1 (why EKF SLAM keeps the
    robot-landmark correlations).
    """
    a = as_array(robot_err, "robot_err", ndim=1)
    b = as_array(landmark_err, "landmark_err", a.shape)
    ax = _axes(ax, (4.4, 4.2))
    ax.scatter(a, b, s=7, alpha=0.45, color=_EST_COLOR, lw=0)
    lim = 1.05 * max(np.abs(a).max(), np.abs(b).max())
    ax.plot([-lim, lim], [-lim, lim], color="0.5", lw=0.8, ls="--", label="equal errors")
    ax.set_xlim(-lim, lim)
    ax.set_ylim(-lim, lim)
    ax.set_aspect("equal")
    ax.set_xlabel(f"{labels[0]} error [m]")
    ax.set_ylabel(f"{labels[1]} error [m]")
    rho = float(np.corrcoef(a, b)[0, 1])
    ax.set_title(title if title is not None else f"correlation {rho:.2f}")
    ax.legend(loc="upper left", fontsize=8)
    return ax


# --------------------------------------------------------------------------- covariance structure
def _correlation(Sigma):
    d = np.sqrt(np.clip(np.diag(Sigma), 0.0, None))
    d = np.where(d > 0, d, 1.0)
    return Sigma / np.outer(d, d)


def plot_covariance_matrix(Sigma, *, correlation=True, absolute=False, ax=None, title=None, colorbar=True):
    """Image of an EKF SLAM covariance or correlation matrix.

    Parameters
    ----------
    Sigma : ndarray, shape (3+2N, 3+2N)
        Covariance of ``[x, y, theta, m0x, m0y, ...]``.
    correlation : bool, keyword-only
        Show correlation coefficients ``Sigma_ij / sqrt(Sigma_ii Sigma_jj)``
        (default) instead of raw covariances.
    absolute : bool, keyword-only
        Show magnitudes (``|rho|`` on a white-to-dark scale) instead of signed
        values.
    ax : matplotlib.axes.Axes, optional
        Axes to draw on; a new figure if omitted.
    title : str, optional
        Axes title.
    colorbar : bool, keyword-only
        Draw a colour bar.

    Returns
    -------
    matplotlib.axes.Axes

    Notes
    -----
    Thin lines separate the robot block (first three rows and columns) from
    the landmark blocks (two rows and columns each).

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 10.2.4 and Fig. 10.5 (the correlation
    matrix of EKF SLAM filling in).
    """
    Sigma = as_array(Sigma, "Sigma", ndim=2)
    n = Sigma.shape[0]
    if Sigma.shape != (n, n) or n < 3 or (n - 3) % 2:
        raise ValueError(f"Sigma must have shape (3+2N, 3+2N), got {Sigma.shape}")
    A = _correlation(Sigma) if correlation else Sigma
    ax = _axes(ax, (4.6, 4.0))
    if absolute:
        img = ax.imshow(np.abs(A), cmap="Greys", vmin=0, vmax=1 if correlation else None, interpolation="nearest")
    else:
        v = 1.0 if correlation else float(np.abs(A).max()) or 1.0
        img = ax.imshow(A, cmap="RdBu_r", vmin=-v, vmax=v, interpolation="nearest")
    ax.hlines(2.5, -0.5, n - 0.5, color="0.3", lw=0.9)  # robot | landmarks
    ax.vlines(2.5, -0.5, n - 0.5, color="0.3", lw=0.9)
    if n > 5:
        b = np.arange(5, n, 2) - 0.5  # between landmarks
        ax.hlines(b, -0.5, n - 0.5, color="0.5", lw=0.25)
        ax.vlines(b, -0.5, n - 0.5, color="0.5", lw=0.25)
    N = (n - 3) // 2
    step = max(1, N // 8)
    ticks = [1] + [3 + 2 * k + 0.5 for k in range(0, N, step)]
    names = ["robot"] + [f"$m_{{{k}}}$" for k in range(0, N, step)]
    ax.set_xticks(ticks, names, fontsize=7, rotation=90)
    ax.set_yticks(ticks, names, fontsize=7)
    if colorbar:
        ax.figure.colorbar(img, ax=ax, shrink=0.8,
                           label=("|correlation|" if absolute else "correlation") if correlation else "covariance")
    if title:
        ax.set_title(title, fontsize=10)
    return ax


def plot_covariance_snapshots(snapshots, *, times=None, dt=None, absolute=True, axes=None):
    """Correlation matrices of EKF SLAM at several times, side by side.

    Parameters
    ----------
    snapshots : dict
        ``{t: (mu, Sigma, ids)}`` as in
        :attr:`~slamlib.ekf_slam.EKFSLAMResult.snapshots`.
    times : sequence of int, optional
        Which steps to show (default: all, sorted).
    dt : float, optional
        Step duration; titles then give the time in seconds.
    absolute : bool, keyword-only
        Show ``|rho|`` (default) or signed correlations.
    axes : array of matplotlib.axes.Axes, optional
        One axes per time; a new figure if omitted.

    Returns
    -------
    ndarray of matplotlib.axes.Axes

    References
    ----------
    Thrun, Burgard & Fox (2005), Fig. 10.5.
    """
    import matplotlib.pyplot as plt

    if not isinstance(snapshots, dict) or not snapshots:
        raise ValueError("snapshots must be a non-empty dict {t: (mu, Sigma, ids)}")
    times = sorted(snapshots) if times is None else list(times)
    missing = [t for t in times if t not in snapshots]
    if missing:
        raise ValueError(f"times not in snapshots: {missing}")
    if axes is None:
        _, axes = plt.subplots(1, len(times), figsize=(3.1 * len(times), 3.2), layout="constrained")
    axes = np.atleast_1d(axes)
    if axes.size != len(times):
        raise ValueError(f"axes must hold {len(times)} axes, got {axes.size}")
    for ax, t in zip(axes, times):
        _, Sigma, _ = snapshots[t]
        N = (np.asarray(Sigma).shape[0] - 3) // 2
        when = f"t = {t * dt:.0f} s" if dt is not None else f"step {t}"
        plot_covariance_matrix(Sigma, absolute=absolute, ax=ax, colorbar=False, title=f"{when}, {N} landmarks")
    return axes


# --------------------------------------------------------------------------- maps and uncertainty
def plot_slam_map(result, run=None, *, n_std=2.0, every=0, ax=None, title=None, legend=True):
    """Map estimated by EKF SLAM: landmark ellipses, estimated and true paths.

    Parameters
    ----------
    result : EKFSLAMResult
        From :func:`~slamlib.ekf_slam.run_ekf_slam`.
    run : LandmarkRun, optional
        Ground truth (true landmarks and path) to compare with.
    n_std : float, keyword-only
        Ellipses enclose `n_std` standard deviations.
    every : int, keyword-only
        Also draw the robot's position ellipse every `every` steps (0: only
        the last).
    ax : matplotlib.axes.Axes, optional
        Axes to draw on; a new figure if omitted.
    title : str, optional
        Axes title.
    legend : bool, keyword-only
        Draw a legend.

    Returns
    -------
    matplotlib.axes.Axes

    Notes
    -----
    Landmarks created by clutter (``landmark_ids == -1``) are drawn in grey.

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 10.2, Fig. 10.3.
    """
    ax = _axes(ax, (6.0, 6.0))
    if run is not None:
        _core.plot_landmarks(run.landmarks, ax=ax, label="true landmarks", s=70)
        ax.plot(run.x_true[:, 0], run.x_true[:, 1], color=TRUTH_COLOR, lw=1.2, label="true path")
    x = np.asarray(result.x)
    ax.plot(x[:, 0], x[:, 1], color=_EST_COLOR, lw=1.2, ls="--", label="estimated path")
    if every:
        for k in range(every, x.shape[0], int(every)):
            _core.plot_covariance_ellipse(x[k, :2], result.Sigma_x[k, :2, :2], n_std=n_std, ax=ax,
                                          color=_EST_COLOR, lw=0.6)
    _core.plot_covariance_ellipse(x[-1, :2], result.Sigma_x[-1, :2, :2], n_std=n_std, ax=ax, color=_EST_COLOR,
                                  lw=1.0)
    _core.plot_pose(x[-1], ax=ax, color=_EST_COLOR)
    ids = np.asarray(result.landmark_ids)
    for m, P, i in zip(result.landmarks, result.landmark_cov, ids):
        color = "C2" if i >= 0 else "0.55"
        _core.plot_covariance_ellipse(m, P, n_std=n_std, ax=ax, color=color, lw=1.0)
    real = ids >= 0
    ax.scatter(result.landmarks[real, 0], result.landmarks[real, 1], s=14, color="C2", zorder=4,
               label=rf"landmark estimate, ${n_std:g}\sigma$")
    if np.any(~real):
        ax.scatter(result.landmarks[~real, 0], result.landmarks[~real, 1], s=10, color="0.55", marker="s", zorder=4,
                   label="landmark made from clutter")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    if title:
        ax.set_title(title)
    if legend:
        ax.legend(loc="upper right", fontsize=8, framealpha=0.85)
    return ax


def plot_slam_uncertainty(results, *, labels=None, dt=1.0, marks=None, ax=None, title=None):
    """Robot position standard deviation over time (one line per result).

    Parameters
    ----------
    results : EKFSLAMResult or sequence of them
        From :func:`~slamlib.ekf_slam.run_ekf_slam`.
    labels : sequence of str, optional
        Legend entries.
    dt : float, keyword-only
        Step duration (seconds) for the time axis.
    marks : dict, optional
        ``{label: t}`` steps to mark with a vertical line (e.g. loop closure).
    ax : matplotlib.axes.Axes, optional
        Axes to draw on; a new figure if omitted.
    title : str, optional
        Axes title.

    Returns
    -------
    matplotlib.axes.Axes

    Notes
    -----
    Plots ``sqrt(Var x + Var y)`` of the robot (solid) and the mean over the
    mapped landmarks of ``sqrt(Var m_x + Var m_y)`` (dashed).

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 10.2.4 (loop closure).
    """
    if hasattr(results, "Sigma_x"):
        results = [results]
    ax = _axes(ax, (7.0, 3.2))
    for k, res in enumerate(results):
        t = np.arange(res.x.shape[0]) * dt
        color = f"C{k}"
        lab = labels[k] if labels is not None else None
        robot = np.sqrt(res.Sigma_x[:, 0, 0] + res.Sigma_x[:, 1, 1])
        ax.plot(t, robot, color=color, lw=1.4, label=f"robot{'' if lab is None else ', ' + lab}")
        var = res.landmark_var
        has = np.any(~np.isnan(var), axis=1)
        lm = np.full(var.shape[0], np.nan)
        lm[has] = np.nanmean(np.sqrt(var[has]), axis=1)
        ax.plot(t, lm, color=color, lw=1.2, ls="--", label=f"landmarks (mean){'' if lab is None else ', ' + lab}")
    for name, step in (marks or {}).items():
        ax.axvline(step * dt, color="0.4", lw=0.9, ls=":")
        ax.text(step * dt, ax.get_ylim()[1], f" {name}", va="top", ha="left", fontsize=8, color="0.3")
    ax.set_xlabel("time [s]" if dt != 1.0 else "step")
    ax.set_ylabel("position std [m]")
    ax.legend(fontsize=8)
    if title:
        ax.set_title(title)
    return ax


def plot_landmark_variances(result, *, dt=1.0, ax=None, title=None):
    """Each landmark's position standard deviation from its first sighting on.

    Parameters
    ----------
    result : EKFSLAMResult
        From :func:`~slamlib.ekf_slam.run_ekf_slam`.
    dt : float, keyword-only
        Step duration (seconds).
    ax : matplotlib.axes.Axes, optional
        Axes to draw on; a new figure if omitted.
    title : str, optional
        Axes title.

    Returns
    -------
    matplotlib.axes.Axes

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 10.2.4 (landmark uncertainty only
    decreases and is bounded below by the robot's uncertainty at first sight).
    """
    ax = _axes(ax, (7.0, 3.2))
    var = np.asarray(result.landmark_var)
    t = np.arange(var.shape[0]) * dt
    for k in range(var.shape[1]):
        ax.plot(t, np.sqrt(var[:, k]), lw=1.0, color=f"C{k % 10}")
    ax.set_yscale("log")
    ax.set_xlabel("time [s]" if dt != 1.0 else "step")
    ax.set_ylabel(r"landmark std $\sqrt{\mathrm{Var}\,m_x + \mathrm{Var}\,m_y}$ [m]")
    if title:
        ax.set_title(title)
    return ax


def plot_landmark_counts(results, labels, *, true_count=None, dt=1.0, ax=None, title=None):
    """Number of landmarks in the map over time, for several runs.

    Parameters
    ----------
    results : sequence of EKFSLAMResult
        From :func:`~slamlib.ekf_slam.run_ekf_slam`.
    labels : sequence of str
        Legend entries.
    true_count : ndarray of int, shape (T+1,), optional
        True number of distinct landmarks seen so far, drawn as a step line.
    dt : float, keyword-only
        Step duration (seconds).
    ax : matplotlib.axes.Axes, optional
        Axes to draw on; a new figure if omitted.
    title : str, optional
        Axes title.

    Returns
    -------
    matplotlib.axes.Axes

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 10.3.3 (spurious landmarks and the
    provisional landmark list).
    """
    ax = _axes(ax, (7.0, 3.2))
    for k, (res, lab) in enumerate(zip(results, labels)):
        n = np.asarray(res.n_landmarks)
        ax.step(np.arange(n.size) * dt, n, where="post", color=f"C{k}", lw=1.4, label=lab)
    if true_count is not None:
        c = np.asarray(true_count)
        ax.step(np.arange(c.size) * dt, c, where="post", color=TRUTH_COLOR, lw=1.0, ls=":", label="true landmarks seen")
    ax.set_xlabel("time [s]" if dt != 1.0 else "step")
    ax.set_ylabel("landmarks in the map")
    ax.legend(fontsize=8)
    if title:
        ax.set_title(title)
    return ax


def plot_step_times(sizes, times, *, guides=None, ax=None, title=None):
    """Time per EKF SLAM step against the number of landmarks, log-log.

    Parameters
    ----------
    sizes : ndarray, shape (K,)
        Numbers of landmarks ``N``.
    times : dict
        ``{label: ndarray of shape (K,)}`` seconds per step (NaN where not
        measured).
    guides : dict, optional
        ``{power: label}``: a grey guide line ``propto N^power`` through the
        last measured point of series `label`.
    ax : matplotlib.axes.Axes, optional
        Axes to draw on; a new figure if omitted.
    title : str, optional
        Axes title.

    Returns
    -------
    matplotlib.axes.Axes

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 10.2.4 (the quadratic update cost).
    """
    sizes = as_array(sizes, "sizes", ndim=1)
    ax = _axes(ax, (5.6, 3.8))
    series = {}
    for k, (lab, sec) in enumerate(times.items()):
        sec = as_array(sec, f"times[{lab!r}]", sizes.shape, finite=False)
        ok = np.isfinite(sec)
        series[lab] = (sec, ok)
        ax.loglog(sizes[ok], 1e3 * sec[ok], marker="o", color=f"C{k}", lw=1.4, label=lab)
    for (power, lab), ls in zip((guides or {}).items(), ("--", ":", "-.")):
        if lab not in series:
            raise ValueError(f"guides names series {lab!r}, not in times")
        sec, ok = series[lab]
        last = np.flatnonzero(ok)[-1]
        ax.loglog(sizes, 1e3 * sec[last] * (sizes / sizes[last]) ** power, color="0.55", lw=0.9, ls=ls,
                  label=rf"$\propto N^{{{power}}}$")
    ax.set_xlabel("landmarks N")
    ax.set_ylabel("time per step [ms]")
    ax.legend(fontsize=8)
    if title:
        ax.set_title(title)
    return ax
