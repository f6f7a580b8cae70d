"""Plots for the Gaussian-filter and particle-filter chapters.

Time series with uncertainty bands, linearisation of a Gaussian through a
nonlinear function, NEES with its chi-square band, EKF runs with covariance
ellipses, importance sampling, resampler offspring statistics, effective sample
size over time and resampling cost.

matplotlib is imported inside the functions only. Every function that draws on
one axes takes an optional ``ax`` and returns it; the multi-panel plots take
``axes`` and return the array of axes.
"""

from __future__ import annotations

import numpy as np

from .._checks import as_array, as_scalar
from . import _core
from ._core import TRUTH_COLOR, _axes

__all__ = [
    "plot_estimate_band",
    "plot_linearization",
    "plot_nees",
    "plot_ekf_run",
    "plot_linearized_motion",
    "plot_particle_snapshots",
    "plot_importance_sampling",
    "plot_offspring_counts",
    "plot_ess",
    "plot_resampling_cost",
]




def plot_estimate_band(t, mean, std, *, truth=None, measurements=None, n_std=2.0, label="estimate", color="C0",
                       linestyle="-", ax=None, title=None, ylabel=None):
    """A scalar estimate over time with its ``n_std``-sigma band.

    Parameters
    ----------
    t : ndarray, shape (T,)
        Times (or step indices).
    mean, std : ndarray, shape (T,)
        Estimated mean and standard deviation.
    truth : ndarray, shape (T,), optional
        True values, drawn as a black line.
    measurements : ndarray, shape (T,), optional
        Measurements, drawn as dots.
    n_std : float
        Half-width of the band in standard deviations.
    label : str
        Legend label of the estimate.
    color : str
        Colour of the estimate and its band.
    linestyle : str
        Line style of the estimate (the band's edges use it too).
    ax : matplotlib.axes.Axes, optional
        Axes to draw on; a new figure if omitted.
    title, ylabel : str, optional
        Axes title and y label.

    Returns
    -------
    matplotlib.axes.Axes
    """
    t = as_array(t, "t", ndim=1)
    mean = as_array(mean, "mean", t.shape)
    std = as_array(std, "std", t.shape)
    n_std = as_scalar(n_std, "n_std", positive=True)
    ax = _axes(ax, (8, 3))
    if measurements is not None:
        measurements = as_array(measurements, "measurements", t.shape, finite=False)
        ax.plot(t, measurements, ".", color="0.55", ms=4, label="measurements")
    if truth is not None:
        truth = as_array(truth, "truth", t.shape)
        ax.plot(t, truth, color=TRUTH_COLOR, lw=1.2, label="truth")
    ax.fill_between(t, mean - n_std * std, mean + n_std * std, color=color, alpha=0.15, lw=0,
                    label=rf"{label} $\pm{n_std:g}\sigma$")
    for edge in (mean - n_std * std, mean + n_std * std):
        ax.plot(t, edge, color=color, lw=0.6, ls=linestyle, alpha=0.7)
    ax.plot(t, mean, color=color, lw=1.5, ls=linestyle, label=label)
    ax.set_xlabel("t")
    if ylabel:
        ax.set_ylabel(ylabel)
    if title:
        ax.set_title(title)
    ax.legend(loc="best", fontsize="small")
    return ax


def plot_linearization(f, mean, std, samples, *, slope=None, bins=80, axes=None, xlabel="x", ylabel="y = f(x)"):
    """A Gaussian pushed through a nonlinear function: Monte Carlo against linearisation.

    Three panels in the layout of the book's figure: the input density (bottom
    right), the function with its tangent at the mean (top right), and the
    output (top left): a histogram of ``f(samples)``, the Gaussian with the
    samples' mean and variance, and the linearised Gaussian
    ``N(f(mean), (slope std)^2)``.

    Parameters
    ----------
    f : callable
        Vectorised scalar function ``f(x)``.
    mean, std : float
        Input Gaussian ``N(mean, std^2)``.
    samples : ndarray, shape (n,)
        Samples of the input Gaussian.
    slope : float, optional
        ``f'(mean)``; a central difference if omitted.
    bins : int
        Histogram bins.
    axes : ndarray of matplotlib.axes.Axes, shape (2, 2), optional
        Axes to draw on (the bottom-left one is hidden).
    xlabel, ylabel : str
        Names of the input and output.

    Returns
    -------
    ndarray of matplotlib.axes.Axes, shape (2, 2)
    """
    import matplotlib.pyplot as plt

    mean = as_scalar(mean, "mean")
    std = as_scalar(std, "std", positive=True)
    samples = as_array(samples, "samples", ndim=1)
    if not callable(f):
        raise TypeError("f must be a callable")
    if slope is None:
        h = 1e-6 * max(1.0, abs(mean))
        slope = (float(f(mean + h)) - float(f(mean - h))) / (2 * h)
    slope = as_scalar(slope, "slope")
    y = np.asarray(f(samples), dtype=float)
    y_lin, s_lin = float(f(mean)), abs(slope) * std
    if axes is None:
        _, axes = plt.subplots(2, 2, figsize=(8, 6), layout="constrained",
                               gridspec_kw={"width_ratios": [1, 1.6], "height_ratios": [1.6, 1]})
    axes = np.asarray(axes)
    ax_out, ax_f, ax_blank, ax_in = axes[0, 0], axes[0, 1], axes[1, 0], axes[1, 1]
    ax_blank.set_axis_off()

    xs = np.linspace(mean - 4 * std, mean + 4 * std, 400)
    ax_in.plot(xs, np.exp(-0.5 * ((xs - mean) / std) ** 2) / (std * np.sqrt(2 * np.pi)), color="C0")
    ax_in.hist(samples, bins=bins, density=True, color="C0", alpha=0.25)
    ax_in.set_xlabel(xlabel)
    ax_in.set_ylabel("density")

    ax_f.plot(xs, f(xs), color="k", lw=1.5, label="f")
    ax_f.plot(xs, y_lin + slope * (xs - mean), color="C3", ls="--", lw=1.2, label="tangent at the mean")
    ax_f.axvline(mean, color="0.6", lw=0.8)
    ax_f.set_xlabel(xlabel)
    ax_f.set_ylabel(ylabel)
    ax_f.legend(loc="best", fontsize="small")

    lo, hi = np.quantile(y, [0.0005, 0.9995])
    lo, hi = min(lo, y_lin - 4 * s_lin), max(hi, y_lin + 4 * s_lin)
    ys = np.linspace(lo, hi, 400)
    m_mc, s_mc = y.mean(), y.std()
    ax_out.hist(y, bins=bins, range=(lo, hi), density=True, orientation="horizontal", color="C0", alpha=0.25,
                label="Monte Carlo")
    ax_out.plot(np.exp(-0.5 * ((ys - m_mc) / s_mc) ** 2) / (s_mc * np.sqrt(2 * np.pi)), ys, color="C0",
                label="Gaussian of the samples")
    ax_out.plot(np.exp(-0.5 * ((ys - y_lin) / s_lin) ** 2) / (s_lin * np.sqrt(2 * np.pi)), ys, color="C3", ls="--",
                label="linearised")
    ax_out.axhline(m_mc, color="C0", lw=0.8)
    ax_out.axhline(y_lin, color="C3", lw=0.8, ls="--")
    ax_out.invert_xaxis()
    ax_out.set_ylim(lo, hi)
    ax_f.set_ylim(lo, hi)
    ax_out.set_ylabel(ylabel)
    ax_out.set_xlabel("density")
    ax_out.legend(loc="lower left", fontsize="small")
    return axes


def plot_nees(nees, dof, *, p=0.95, t=None, label=None, color="C0", show_runs=True, ax=None, title=None):
    """Average NEES over Monte-Carlo runs against its chi-square band.

    Parameters
    ----------
    nees : ndarray, shape (N, T)
        NEES of ``N`` independent runs at ``T`` time steps (e.g.
        :func:`slamlib.metrics.nees`).
    dof : int
        State dimension (degrees of freedom of each NEES).
    p : float
        Probability mass of the band (:func:`slamlib.metrics.nees_band`).
    t : ndarray, shape (T,), optional
        Time axis; step indices if omitted.
    label : str, optional
        Legend label of the average.
    color : str
        Colour of the average.
    show_runs : bool
        Also draw the single runs, faintly.
    ax : matplotlib.axes.Axes, optional
        Axes to draw on; a new figure if omitted.
    title : str, optional
        Axes title.

    Returns
    -------
    matplotlib.axes.Axes
    """
    from ..metrics import nees_band

    nees = as_array(nees, "nees", ndim=2)
    n_runs, T = nees.shape
    t = np.arange(T) if t is None else as_array(t, "t", (T,))
    lo, hi = nees_band(dof, n_runs, p)
    ax = _axes(ax, (8, 3))
    if show_runs:
        ax.plot(t, nees.T, color=color, lw=0.4, alpha=0.15)
    avg = nees.mean(axis=0)
    inside = np.mean((avg >= lo) & (avg <= hi))
    ax.plot(t, avg, color=color, lw=1.6, label=(label or "average NEES") + f" ({inside:.0%} inside)")
    ax.axhspan(lo, hi, color="C2", alpha=0.15, lw=0, label=f"{p:.0%} band, {n_runs} runs")
    ax.axhline(dof, color="C2", lw=1.0, ls="--", label=f"expected value {dof}")
    top = max(hi * 1.6, float(np.quantile(avg, 0.98)) * 1.2)
    ax.set_ylim(0, top)
    ax.set_xlabel("t")
    ax.set_ylabel("NEES")
    if title:
        ax.set_title(title)
    ax.legend(loc="upper right", fontsize="small")
    return ax


def plot_ekf_run(run, mu, Sigma, *, every=10, n_std=2.0, ids=None, z=None, dead_reckoning=None, ax=None,
                 title=None, legend=True):
    """An EKF localization run: landmarks, true and estimated paths, covariance ellipses.

    Parameters
    ----------
    run : LandmarkRun
        The simulated run (:func:`slamlib.sim.simulate_landmark_run`).
    mu : ndarray, shape (T+1, 3)
        Estimated poses.
    Sigma : ndarray, shape (T+1, 3, 3)
        Their covariances; the position block is drawn every `every` steps.
    every : int
        Spacing of the ellipses.
    n_std : float
        Ellipses at ``n_std`` standard deviations.
    ids : sequence of int ndarrays, optional
        Correspondences chosen by the filter at each step; with `z`, rays from
        the estimated pose to the measured points are drawn every `every`
        steps, grey for gated measurements (``-1``).
    z : sequence of ndarrays, shape (K_t, 2), optional
        Measurements the filter received (defaults to ``run.z``).
    dead_reckoning : tuple (mu, Sigma), optional
        Prediction-only estimates to draw for comparison.
    ax : matplotlib.axes.Axes, optional
        Axes to draw on; a new figure if omitted.
    title : str, optional
        Axes title.
    legend : bool
        Draw a legend.

    Returns
    -------
    matplotlib.axes.Axes
    """
    mu = as_array(mu, "mu", (None, 3))
    Sigma = as_array(Sigma, "Sigma", (mu.shape[0], 3, 3))
    ax = _axes(ax, (6.5, 6.5))
    steps = np.arange(0, mu.shape[0], max(int(every), 1))
    _core.plot_landmarks(run.landmarks, ax=ax)
    if dead_reckoning is not None:
        dr_mu = as_array(dead_reckoning[0], "dead_reckoning[0]", mu.shape)
        dr_S = as_array(dead_reckoning[1], "dead_reckoning[1]", Sigma.shape)
        ax.plot(dr_mu[:, 0], dr_mu[:, 1], color="C1", lw=1.0, ls=":", label="dead reckoning")
        for k in steps:
            _core.plot_covariance_ellipse(dr_mu[k, :2], dr_S[k, :2, :2], n_std=n_std, ax=ax, color="C1", lw=0.8)
    ax.plot(run.x_true[:, 0], run.x_true[:, 1], color=TRUTH_COLOR, lw=1.2, label="true path")
    ax.plot(mu[:, 0], mu[:, 1], color="C0", lw=1.2, ls="--", label="EKF mean")
    for k in steps:
        _core.plot_covariance_ellipse(mu[k, :2], Sigma[k, :2, :2], n_std=n_std, ax=ax, color="C0", lw=1.0)
    ax.plot([], [], color="C0", lw=1.0, label=rf"${n_std:g}\sigma$ position ellipse")
    if ids is not None:
        zs = run.z if z is None else z
        for k in steps[steps > 0]:
            zk = np.asarray(zs[k - 1]).reshape(-1, 2)
            x = mu[k]
            ends = x[:2] + zk[:, :1] * np.column_stack([np.cos(x[2] + zk[:, 1]), np.sin(x[2] + zk[:, 1])])
            for e, j in zip(ends, np.asarray(ids[k - 1])):
                ax.plot([x[0], e[0]], [x[1], e[1]], color="C2" if j >= 0 else "0.6", lw=0.6,
                        ls="-" if j >= 0 else ":")
        ax.plot([], [], color="C2", lw=0.6, label="associated measurement")
        ax.plot([], [], color="0.6", lw=0.6, ls=":", label="gated measurement")
    _core.plot_pose(mu[-1], ax=ax, color="C0")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    if title:
        ax.set_title(title)
    if legend:
        ax.legend(loc="upper right", fontsize="small")
    return ax


def plot_linearized_motion(samples, mean, cov, *, start=None, n_std=2.0, ax=None, title=None):
    """Monte-Carlo poses after a motion against the EKF's linearised prediction.

    Parameters
    ----------
    samples : ndarray, shape (n, 3)
        Poses sampled from the initial belief and moved through the motion model.
    mean : ndarray, shape (3,)
        EKF predicted mean.
    cov : ndarray, shape (3, 3)
        EKF predicted covariance; its position block is drawn as an ellipse.
    start : ndarray, shape (3,), optional
        Initial mean pose, drawn as an arrow.
    n_std : float
        Ellipses at ``n_std`` standard deviations.
    ax : matplotlib.axes.Axes, optional
        Axes to draw on; a new figure if omitted.
    title : str, optional
        Axes title.

    Returns
    -------
    matplotlib.axes.Axes
    """
    samples = as_array(samples, "samples", (None, 3))
    mean = as_array(mean, "mean", (3,))
    cov = as_array(cov, "cov", (3, 3))
    ax = _axes(ax, (6.5, 5))
    ax.plot(samples[:, 0], samples[:, 1], ".", color="C0", ms=2, alpha=0.25, label="Monte-Carlo samples")
    mc_mean = samples[:, :2].mean(axis=0)
    mc_cov = np.cov(samples[:, :2].T)
    _core.plot_covariance_ellipse(mc_mean, mc_cov, n_std=n_std, ax=ax, color="C0", lw=1.2, ls=":")
    ax.plot(*mc_mean, "x", color="C0", ms=9, mew=2, label="samples' mean and covariance")
    _core.plot_covariance_ellipse(mean[:2], cov[:2, :2], n_std=n_std, ax=ax, color="C3", lw=1.5)
    ax.plot(*mean[:2], "o", color="C3", ms=6, label="EKF prediction")
    if start is not None:
        _core.plot_pose(as_array(start, "start", (3,)), ax=ax, color="k")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    if title:
        ax.set_title(title)
    ax.legend(loc="best", fontsize="small")
    return ax


def plot_particle_snapshots(run, snapshots, *, estimate=None, ax=None, title=None):
    """Particle sets at a few time steps of a simulated run.

    Parameters
    ----------
    run : LandmarkRun
        The simulated run (:func:`slamlib.sim.simulate_landmark_run`).
    snapshots : dict of int to ndarray, shape (n, 3)
        Particles after the given step (0 is the initial set).
    estimate : ndarray, shape (T+1, 3), optional
        The filter's mean poses, drawn dashed.
    ax : matplotlib.axes.Axes, optional
        Axes to draw on; a new figure if omitted.
    title : str, optional
        Axes title.

    Returns
    -------
    matplotlib.axes.Axes
    """
    ax = _axes(ax, (6.5, 6.5))
    _core.plot_landmarks(run.landmarks, ax=ax)
    ax.plot(run.x_true[:, 0], run.x_true[:, 1], color=TRUTH_COLOR, lw=1.2, label="true path")
    if estimate is not None:
        est = as_array(estimate, "estimate", (None, 3))
        ax.plot(est[:, 0], est[:, 1], color="C3", lw=1.2, ls="--", label="particle-filter mean")
    for k, (step, parts) in enumerate(sorted(snapshots.items())):
        parts = as_array(parts, f"snapshots[{step}]", (None, 3))
        _core.plot_particles(parts, ax=ax, color=f"C{k % 10}")
        x = run.x_true[step]
        ax.annotate(f"t={step}", (x[0], x[1]), textcoords="offset points", xytext=(6, 6), fontsize="small")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    if title:
        ax.set_title(title)
    ax.legend(loc="upper right", fontsize="small")
    return ax


def plot_importance_sampling(x, target, proposal, samples, weights, *, ax=None, title=None):
    """Importance sampling in 1-D: target, proposal, samples and their weights.

    Parameters
    ----------
    x : ndarray, shape (n,)
        Grid on which the densities are given.
    target, proposal : ndarray, shape (n,)
        Target density ``f`` and proposal density ``g`` on `x`.
    samples : ndarray, shape (M,)
        Samples drawn from the proposal.
    weights : ndarray, shape (M,)
        Their normalised importance weights ``w ~ f / g``.
    ax : matplotlib.axes.Axes, optional
        Axes to draw on; a new figure if omitted.
    title : str, optional
        Axes title.

    Returns
    -------
    matplotlib.axes.Axes
    """
    x = as_array(x, "x", ndim=1)
    target = as_array(target, "target", x.shape)
    proposal = as_array(proposal, "proposal", x.shape)
    samples = as_array(samples, "samples", ndim=1)
    weights = as_array(weights, "weights", samples.shape)
    ax = _axes(ax, (8, 3.2))
    ax.plot(x, target, color="C3", lw=1.8, label="target $f$")
    ax.plot(x, proposal, color="C0", lw=1.5, ls="--", label="proposal $g$")
    ax.plot(samples, np.zeros_like(samples), "|", color="C0", ms=10, alpha=0.4, label="samples of $g$")
    ax2 = ax.twinx()
    ax2.vlines(samples, 0, weights, color="C2", lw=0.8, alpha=0.8)
    ax2.set_ylim(0, weights.max() * 1.15)
    ax2.set_ylabel("weight $w = f / g$ (normalised)", color="C2")
    ax.plot([], [], color="C2", lw=0.8, label="importance weights")
    ax.set_xlabel("x")
    ax.set_ylabel("density")
    ax.set_ylim(bottom=0)
    if title:
        ax.set_title(title)
    ax.legend(loc="upper left", fontsize="small")
    return ax


def plot_offspring_counts(w, counts, *, axes=None):
    """How the resamplers distribute offspring: mean and spread of the counts.

    Parameters
    ----------
    w : ndarray, shape (M,)
        Normalised weights that were resampled.
    counts : dict of str to ndarray, shape (R, M)
        For each resampler, the offspring counts of the ``M`` particles in
        ``R`` independent resamplings.
    axes : ndarray of matplotlib.axes.Axes, shape (2,), optional
        Axes to draw on.

    Returns
    -------
    ndarray of matplotlib.axes.Axes, shape (2,)
        Left: mean count against ``M w`` (every unbiased scheme lies on the
        diagonal). Right: standard deviation of each particle's count, with
        the multinomial ``sqrt(M w (1 - w))`` and the smallest possible spread
        ``sqrt(f (1 - f))``, ``f = frac(M w)``.
    """
    import matplotlib.pyplot as plt

    w = as_array(w, "w", ndim=1)
    M = w.size
    if axes is None:
        _, axes = plt.subplots(1, 2, figsize=(10, 3.6), layout="constrained")
    axes = np.asarray(axes)
    mw = M * w
    order = np.argsort(mw)
    markers = "osD^v<>"
    for k, (name, c) in enumerate(counts.items()):
        c = as_array(c, f"counts[{name!r}]", (None, M))
        axes[0].plot(mw, c.mean(axis=0), markers[k % len(markers)], ms=4, alpha=0.8, label=name, color=f"C{k}")
        axes[1].plot(mw[order], c.std(axis=0)[order], marker=markers[k % len(markers)], ms=3, lw=0.8, label=name,
                     color=f"C{k}")
    top = mw.max() * 1.05
    axes[0].plot([0, top], [0, top], color="k", lw=0.8, label="$M w$")
    axes[0].set_xlabel("expected count $M w_i$")
    axes[0].set_ylabel("mean offspring count")
    axes[0].legend(fontsize="small")
    frac = mw - np.floor(mw)
    axes[1].plot(mw[order], np.sqrt(mw * (1 - w))[order], color="k", lw=1.0, ls="--",
                 label=r"multinomial $\sqrt{M w (1-w)}$")
    axes[1].plot(mw[order], np.sqrt(frac * (1 - frac))[order], color="0.5", lw=1.0, ls=":",
                 label=r"floor/ceil bound $\sqrt{f(1-f)}$")
    axes[1].set_xlabel("expected count $M w_i$")
    axes[1].set_ylabel("std of the offspring count")
    axes[1].legend(fontsize="small", loc="upper left")
    return axes


def plot_ess(ess, n_particles, *, resampled=None, threshold=None, label=None, color="C0", ax=None, title=None):
    """Effective sample size over time, with the resampling steps marked.

    Parameters
    ----------
    ess : ndarray, shape (T,)
        Effective sample size at each step (before resampling).
    n_particles : int
        Number of particles ``M`` (upper limit of the ESS).
    resampled : ndarray of bool, shape (T,), optional
        Steps at which the filter resampled, marked by ticks.
    threshold : float, optional
        Resampling threshold as a fraction of ``M``, drawn as a line.
    label : str, optional
        Legend label.
    color : str
        Line colour.
    ax : matplotlib.axes.Axes, optional
        Axes to draw on; a new figure if omitted.
    title : str, optional
        Axes title.

    Returns
    -------
    matplotlib.axes.Axes
    """
    ess = as_array(ess, "ess", ndim=1)
    n = as_scalar(n_particles, "n_particles", positive=True)
    ax = _axes(ax, (8, 3))
    t = np.arange(1, ess.size + 1)
    ax.plot(t, ess, color=color, lw=1.5, marker=".", ms=4, label=label)
    if resampled is not None:
        resampled = np.asarray(resampled, dtype=bool)
        ax.plot(t[resampled], ess[resampled], "v", color=color, ms=6, mfc="none")
    if threshold is not None:
        ax.axhline(as_scalar(threshold, "threshold") * n, color="0.5", ls=":", lw=1.0)
    ax.axhline(n, color="0.5", lw=0.8)
    ax.set_yscale("log")
    ax.set_ylim(0.8, n * 1.3)
    ax.set_xlabel("t")
    ax.set_ylabel("effective sample size")
    if title:
        ax.set_title(title)
    if label:
        ax.legend(loc="lower left", fontsize="small")
    return ax


def plot_resampling_cost(sizes, seconds, *, ax=None, title=None):
    """Run time of resamplers against the number of particles (log-log).

    Parameters
    ----------
    sizes : ndarray, shape (n,)
        Numbers of particles ``M``.
    seconds : dict of str to ndarray, shape (n,)
        Measured time per resampling for each method.
    ax : matplotlib.axes.Axes, optional
        Axes to draw on; a new figure if omitted.
    title : str, optional
        Axes title.

    Returns
    -------
    matplotlib.axes.Axes
    """
    sizes = as_array(sizes, "sizes", ndim=1)
    ax = _axes(ax, (6, 3.6))
    for k, (name, s) in enumerate(seconds.items()):
        s = as_array(s, f"seconds[{name!r}]", sizes.shape)
        ax.loglog(sizes, s * 1e6 / sizes, marker="o", ms=4, color=f"C{k}", label=name)
    ax.set_xlabel("number of particles $M$")
    ax.set_ylabel("time per particle [µs]")
    if title:
        ax.set_title(title)
    ax.legend(fontsize="small")
    return ax
