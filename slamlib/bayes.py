"""Bayes rule and discrete (histogram) Bayes filters.

The first algorithms of the course: Bayes rule on a finite state space, the
discrete Bayes filter on a one-dimensional cyclic corridor with doors, and grid
localization on a two-dimensional occupancy grid (Thrun, Burgard & Fox,
*Probabilistic Robotics*, 2005: Table 2.1, Table 4.1, Secs. 4.1 and 8.2).

Conventions
-----------
* A belief is a float64 array of probabilities (non-negative, summing to 1)
  over the cells of the state space: shape ``(n,)`` for the corridor, ``(H, W)``
  for a grid.
* A grid is indexed ``[row, column] = [y, x]``: cell ``(i, j)`` has centre
  ``x = j``, ``y = i`` in cell units, so row 0 is the bottom of a plot drawn with
  ``origin="lower"``. Vectors of cell coordinates and displacements are written
  ``(x, y)``, as everywhere else in the course.
* A motion kernel is ``p(displacement)`` on a window of cells centred on zero
  displacement: ``kernel[k]`` (1-D, odd length ``2 r + 1``) is the probability of
  moving ``k - r`` cells; ``kernel[a, b]`` (2-D, odd sizes ``2 r_y + 1`` by
  ``2 r_x + 1``) the probability of moving ``dx = b - r_x``, ``dy = a - r_y``.
* Boundaries: the corridor is a ring (moving forward from cell ``n - 1`` enters
  cell 0). On a grid a move that would end off the map or in an occupied cell
  leaves the robot where it was (it bumps), so no probability is lost.
"""

from __future__ import annotations

import numpy as np
from scipy import signal, special

from ._checks import as_array, as_index, as_kernel, as_mask, as_probabilities, as_probability, as_scalar, check_rng

__all__ = [
    "bayes_rule",
    "motion_kernel",
    "histogram_predict",
    "histogram_update",
    "histogram_filter",
    "corridor_doors",
    "door_likelihood",
    "simulate_corridor",
    "grid_predict",
    "grid_wall_distances",
    "grid_range_likelihood",
    "simulate_grid",
]

def _posterior(prior, likelihood):
    """``eta * likelihood * prior`` for checked arrays of the same shape."""
    peak = likelihood.max()
    if peak > 0:
        # a constant factor cancels in eta; rescaling keeps tiny likelihoods from underflowing
        likelihood = likelihood / peak
    unnormalised = likelihood * prior
    total = unnormalised.sum()
    if not total > 0:
        raise ValueError("the likelihood is zero wherever the prior is positive: "
                         "this measurement is impossible under the prior, so no posterior exists")
    return unnormalised / total  # eta = 1 / sum(p(z | x) p(x))


# --------------------------------------------------------------------------- Bayes rule


def bayes_rule(prior, likelihood):
    """Posterior of a discrete state after one observation, by Bayes rule.

    ``p(x | z) = eta p(z | x) p(x)`` with ``eta = 1 / sum_x p(z | x) p(x)``.

    Parameters
    ----------
    prior : ndarray, shape (n,) or any shape
        ``p(x)`` over the states (the cells of the array); non-negative, sums to 1.
    likelihood : ndarray, same shape as `prior`
        ``p(z | x)`` of the observed ``z`` for every state ``x``; non-negative.
        Only ratios matter: any constant factor cancels in ``eta``.

    Returns
    -------
    ndarray, same shape as `prior`
        The posterior ``p(x | z)``, summing to 1.

    Raises
    ------
    ValueError
        If the shapes differ, an input is negative or not finite, `prior` does
        not sum to 1, or ``p(z | x) p(x) = 0`` everywhere (an impossible
        observation).

    References
    ----------
    Thrun, Burgard & Fox, *Probabilistic Robotics*, Eqs. 2.13-2.15.

    Examples
    --------
    Two boxes, picked by a fair coin; box 1 holds 5 red and 5 white balls,
    box 2 holds 3 red and 7 white. A red ball is drawn:

    >>> bayes_rule([0.5, 0.5], [5 / 10, 3 / 10])
    array([0.625, 0.375])
    """
    prior = as_probabilities(prior, "prior", ndim=range(1, 33), sums_to_one=True)
    likelihood = as_array(likelihood, "likelihood", prior.shape, nonnegative=True, ref="prior")
    return _posterior(prior, likelihood)


def histogram_update(belief, likelihood):
    """Measurement update (correction) of the discrete Bayes filter.

    ``bel(x) = eta p(z | x) bel_bar(x)`` for every cell ``x``: Bayes rule with the
    predicted belief as the prior.

    Parameters
    ----------
    belief : ndarray, shape (n,) or (H, W)
        Predicted belief ``bel_bar`` over the cells; non-negative, sums to 1.
    likelihood : ndarray, same shape as `belief`
        ``p(z | x)`` of the measurement for every cell (e.g. from
        :func:`door_likelihood` or :func:`grid_range_likelihood`); non-negative.

    Returns
    -------
    ndarray, same shape as `belief`
        The corrected belief ``bel``, summing to 1. A uniform likelihood leaves the
        belief unchanged.

    Raises
    ------
    ValueError
        As :func:`bayes_rule`, naming `belief` and `likelihood`.

    References
    ----------
    Thrun, Burgard & Fox, *Probabilistic Robotics*, Table 4.1 line 4; Table 2.1 line 4.
    """
    belief = as_probabilities(belief, "belief", ndim=range(1, 33), sums_to_one=True)
    likelihood = as_array(likelihood, "likelihood", belief.shape, nonnegative=True, ref="belief")
    # bel(x_t) = eta p(z_t | x_t) bel_bar(x_t)  (Table 4.1 line 4)
    return _posterior(belief, likelihood)


# --------------------------------------------------------------------------- motion


def motion_kernel(shift, sigma, *, radius=None):
    """Discretised Gaussian motion kernel ``p(displacement)`` on a grid of cells.

    The displacement is ``shift + noise`` with ``noise ~ N(0, sigma^2)`` per axis;
    each cell of the kernel holds the probability that this continuous
    displacement falls into that cell (``[d - 1/2, d + 1/2)``), renormalised over
    the window. With ``sigma = 0`` the kernel is a delta at ``round(shift)``
    (halves round to even).

    Parameters
    ----------
    shift : float or ndarray, shape (2,)
        Commanded displacement in cells: a scalar for a 1-D corridor, ``(dx, dy)``
        for a grid.
    sigma : float or ndarray, shape (2,)
        Standard deviation of the displacement noise in cells (per axis for a
        grid), ``>= 0``.
    radius : int or ndarray of int, shape (2,), optional
        Half-width ``r`` of the window (per axis ``(r_x, r_y)`` for a grid); the
        kernel has ``2 r + 1`` cells. Default: ``ceil(|shift| + 4 sigma)``, which
        holds all but about 6e-5 of the mass.

    Returns
    -------
    kernel : ndarray, shape (2 r + 1,) or (2 r_y + 1, 2 r_x + 1)
        ``kernel[k]`` is the probability of moving ``k - r`` cells; for a grid
        ``kernel[a, b]`` that of moving ``dx = b - r_x``, ``dy = a - r_y`` (rows are
        ``y``, as in a grid belief). Sums to 1.

    Raises
    ------
    ValueError
        If `sigma` is negative, `radius` is too small to hold ``round(shift)``,
        or the shapes disagree.

    References
    ----------
    Thrun, Burgard & Fox, *Probabilistic Robotics*, Sec. 4.1 (the motion model of a
    histogram filter as a probability per cell).
    """
    shift_arr = as_array(shift, "shift", ndim=(0, 1), bools=False)
    if shift_arr.ndim == 1 and shift_arr.shape != (2,):
        raise ValueError(f"shift must be a scalar (corridor) or have shape (2,) (grid), got {shift_arr.shape}")
    dim = shift_arr.size
    shifts = np.atleast_1d(shift_arr)
    sig = as_array(sigma, "sigma", ndim=(0, 1), bools=False)
    if sig.ndim == 1 and sig.shape != (dim,):
        raise ValueError(f"sigma must be a scalar or have shape ({dim},) like shift, got {sig.shape}")
    sig = np.broadcast_to(sig, (dim,))
    if np.any(sig < 0):
        raise ValueError(f"sigma must be non-negative, got {sig}")
    if radius is None:
        radii = np.ceil(np.abs(shifts) + 4.0 * sig).astype(int)
    else:
        r = np.atleast_1d(np.asarray(radius))
        if r.dtype.kind not in "iu" or r.ndim != 1 or r.size not in (1, dim):
            raise TypeError(f"radius must be a non-negative integer or {dim} of them, got {radius!r}")
        radii = np.broadcast_to(r, (dim,)).astype(int)
        if np.any(radii < 0):
            raise ValueError(f"radius must be non-negative, got {radius!r}")
        if np.any(np.abs(np.rint(shifts)) > radii):
            raise ValueError(f"radius {radius!r} is too small for shift {shift!r}: the window must hold round(shift)")
    axes = []
    for s, sd, r in zip(shifts, sig, radii):
        d = np.arange(-r, r + 1, dtype=float)
        if sd == 0:
            k = (d == np.rint(s)).astype(float)
        else:
            # mass of N(s, sd^2) on the cell [d - 1/2, d + 1/2)
            k = special.ndtr((d + 0.5 - s) / sd) - special.ndtr((d - 0.5 - s) / sd)
        total = k.sum()
        if not total > 0:
            raise ValueError(f"radius {radius!r} is too small for shift {shift!r}: the window holds no probability")
        axes.append(k / total)
    if dim == 1:
        return axes[0]
    kx, ky = axes
    return np.outer(ky, kx)  # rows are y, columns x; the axes are independent


def histogram_predict(belief, kernel):
    """Prediction step of the discrete Bayes filter on a cyclic 1-D corridor.

    ``bel_bar(x) = sum_x' p(x | u, x') bel(x')`` with a shift-invariant motion model
    ``p(x | u, x') = kernel[x - x' + r]``: a circular convolution of the belief
    with the motion kernel.

    Parameters
    ----------
    belief : ndarray, shape (n,)
        ``bel(x_{t-1})`` over the ``n`` cells; non-negative, sums to 1.
    kernel : ndarray, shape (2 r + 1,)
        ``p(displacement)``: ``kernel[k]`` is the probability of moving ``k - r``
        cells (see :func:`motion_kernel`); non-negative, sums to 1, odd length
        (it may be longer than the corridor).

    Returns
    -------
    ndarray, shape (n,)
        ``bel_bar(x_t)``, summing to 1. A delta kernel shifts the belief
        (``np.roll``); any kernel conserves probability.

    Notes
    -----
    Boundary convention: the corridor is a ring, so probability that moves past
    cell ``n - 1`` re-enters at cell 0 (and backwards from cell 0 to ``n - 1``).

    References
    ----------
    Thrun, Burgard & Fox, *Probabilistic Robotics*, Table 4.1 line 3; Table 2.1 line 3.
    """
    belief = as_probabilities(belief, "belief", ndim=1, sums_to_one=True)
    kernel = as_kernel(kernel, "kernel", ndim=1)
    return _histogram_predict(belief, kernel)


def _histogram_predict(belief, kernel):
    """Unchecked core of :func:`histogram_predict`."""
    r = kernel.size // 2
    bel_bar = np.zeros_like(belief)
    for k in np.flatnonzero(kernel):
        # bel_bar(x_t) = sum_{x_{t-1}} p(x_t | u_t, x_{t-1}) bel(x_{t-1})  (Table 4.1 line 3):
        # np.roll(belief, d)[x] = belief[x - d] is where the mass moving d cells comes from
        bel_bar += kernel[k] * np.roll(belief, k - r)
    return bel_bar


def histogram_filter(belief, kernels, likelihoods):
    """Run the discrete Bayes filter over a sequence of controls and measurements.

    At every step ``t``: predict with ``kernels[t]`` (:func:`histogram_predict`),
    then correct with ``likelihoods[t]`` (:func:`histogram_update`).

    Parameters
    ----------
    belief : ndarray, shape (n,)
        Initial belief ``bel(x_0)``; non-negative, sums to 1.
    kernels : ndarray, shape (L,), or sequence of T ndarrays of shape (L_t,)
        The motion kernel of each step, or one kernel used at every step. Use
        ``[1.0]`` for a step without motion.
    likelihoods : ndarray, shape (T, n)
        ``p(z_t | x)`` for every step and cell.

    Returns
    -------
    predicted : ndarray, shape (T, n)
        ``bel_bar(x_t)`` after each prediction.
    posterior : ndarray, shape (T, n)
        ``bel(x_t)`` after each correction.

    Raises
    ------
    ValueError
        If the number of kernels differs from the number of measurements, or any
        input is invalid (see the step functions).

    References
    ----------
    Thrun, Burgard & Fox, *Probabilistic Robotics*, Table 4.1 (discrete Bayes filter).
    """
    bel = as_probabilities(belief, "belief", ndim=1, sums_to_one=True)
    likelihoods = as_array(likelihoods, "likelihoods", (None, bel.size), nonnegative=True, ref="belief")
    steps = likelihoods.shape[0]
    if kernels is None or isinstance(kernels, (str, bytes)) or not hasattr(kernels, "__len__"):
        raise TypeError(f"kernels must be one kernel (L,) or a sequence of kernels, got {type(kernels).__name__}")
    try:
        single = np.asarray(kernels, dtype=float).ndim == 1
    except (ValueError, TypeError):  # kernels of different lengths
        single = False
    if single:
        kernels = [as_kernel(kernels, "kernels", ndim=1)] * steps
    else:
        kernels = [as_kernel(k, f"kernels[{t}]", ndim=1) for t, k in enumerate(kernels)]
    if len(kernels) != steps:
        raise ValueError(f"kernels must hold one kernel per step: got {len(kernels)} kernels "
                         f"for {steps} rows of likelihoods")
    predicted = np.empty((steps, bel.size))
    posterior = np.empty((steps, bel.size))
    for t in range(steps):
        predicted[t] = _histogram_predict(bel, kernels[t])  # Table 4.1 line 3
        bel = posterior[t] = _posterior(predicted[t], likelihoods[t])  # Table 4.1 line 4
    return predicted, posterior


# --------------------------------------------------------------------------- the corridor world


def corridor_doors(n_cells, door_cells, *, door_width=1):
    """Map of a cyclic corridor: which cells lie in front of a door.

    Parameters
    ----------
    n_cells : int
        Number of cells ``n`` of the corridor (``>= 1``).
    door_cells : ndarray of int, shape (D,)
        First cell of each door, in ``[0, n)``.
    door_width : int, optional
        Cells each door spans: door ``d`` covers cells ``door_cells[d]`` to
        ``door_cells[d] + door_width - 1`` (wrapping around the ring).

    Returns
    -------
    doors : ndarray of bool, shape (n,)
        ``True`` where the robot stands in front of a door.

    References
    ----------
    Thrun, Burgard & Fox, *Probabilistic Robotics*, Fig. 1.1 (the corridor with
    three doors) and Sec. 4.1.
    """
    n = as_index(n_cells, "n_cells", lower=1)
    width = as_index(door_width, "door_width", n + 1, lower=1)
    cells = as_array(door_cells, "door_cells", ndim=1)
    if np.any(cells != np.round(cells)) or np.any(cells < 0) or np.any(cells >= n):
        raise ValueError(f"door_cells must be integer cell indices in [0, {n}), got {np.asarray(door_cells)}")
    doors = np.zeros(n, dtype=bool)
    covered = (cells.astype(int)[:, None] + np.arange(width)[None, :]) % n
    doors[covered.ravel()] = True
    return doors


def door_likelihood(doors, z, *, p_hit, p_false):
    """Likelihood ``p(z | x)`` of a binary door detector for every corridor cell.

    ``p(z = door | x) = p_hit`` in front of a door and ``p_false`` elsewhere;
    ``p(z = wall | x) = 1 - p(z = door | x)``.

    Parameters
    ----------
    doors : ndarray of bool, shape (n,)
        Door map (:func:`corridor_doors`).
    z : bool or ndarray of bool, shape (T,)
        The reading(s): ``True`` (or 1) means "I see a door".
    p_hit : float
        ``p(z = door | door at x)``, the detection rate, in ``[0, 1]``.
    p_false : float
        ``p(z = door | no door at x)``, the false-alarm rate, in ``[0, 1]``.

    Returns
    -------
    ndarray, shape (n,) or (T, n)
        ``p(z | x)`` per cell (per reading).

    References
    ----------
    Thrun, Burgard & Fox, *Probabilistic Robotics*, Sec. 2.4.2 (the door sensor
    example) and Sec. 4.1.
    """
    doors = as_mask(doors, "doors", ndim=1)
    zs = as_array(z, "z", ndim=(0, 1))
    if not np.all((zs == 0) | (zs == 1)):
        raise ValueError("z must hold booleans (True = door seen) or 0/1")
    p_hit = as_probability(p_hit, "p_hit")
    p_false = as_probability(p_false, "p_false")
    p_door = np.where(doors, p_hit, p_false)  # p(z = door | x)
    seen = zs.astype(bool)[..., None]
    return np.where(seen, p_door, 1.0 - p_door)


def simulate_corridor(doors, x0, moves, *, sigma, p_hit, p_false, rng):
    """Simulate a robot driving round the cyclic corridor with a door detector.

    At step ``t`` the robot moves ``moves[t]`` cells plus noise, drawn from
    ``motion_kernel(moves[t], sigma)`` (the same model the filter uses), then
    reads its door detector with the probabilities of :func:`door_likelihood`.

    Parameters
    ----------
    doors : ndarray of bool, shape (n,)
        Door map (:func:`corridor_doors`).
    x0 : int
        Cell the robot starts in (before the first move).
    moves : ndarray, shape (T,)
        Commanded displacement of each step in cells (``0`` to stand still).
    sigma : float
        Motion noise standard deviation in cells, ``>= 0``.
    p_hit, p_false : float
        Detector probabilities as in :func:`door_likelihood`.
    rng : numpy.random.Generator
        Source of randomness. Each step draws one displacement
        (``rng.choice`` with the kernel's probabilities), then one
        ``rng.random()`` for the reading.

    Returns
    -------
    x : ndarray of int, shape (T,)
        True cell after each step's move.
    z : ndarray of bool, shape (T,)
        The reading taken there (``True`` = door seen).

    References
    ----------
    Thrun, Burgard & Fox, *Probabilistic Robotics*, Sec. 4.1 (the corridor example).
    """
    doors = as_mask(doors, "doors", ndim=1)
    n = doors.size
    pos = as_index(x0, "x0", n)
    moves = as_array(moves, "moves", ndim=1)
    sigma = as_scalar(sigma, "sigma", nonnegative=True)
    p_hit = as_probability(p_hit, "p_hit")
    p_false = as_probability(p_false, "p_false")
    rng = check_rng(rng)
    xs = np.empty(moves.size, dtype=int)
    zs = np.empty(moves.size, dtype=bool)
    for t, u in enumerate(moves):
        kernel = motion_kernel(u, sigma)
        pos = (pos + int(rng.choice(kernel.size, p=kernel)) - kernel.size // 2) % n
        xs[t] = pos
        zs[t] = rng.random() < (p_hit if doors[pos] else p_false)
    return xs, zs


# --------------------------------------------------------------------------- 2-D grid localization


def grid_predict(belief, kernel, *, free=None):
    """Prediction step of grid localization on a bounded 2-D occupancy grid.

    Motion model: the robot draws a displacement from `kernel`; if the target
    cell is off the map or occupied, it stays where it was (it bumps). Hence::

        p(x | u, x') = kernel[x - x'] free(x) + [x = x'] (1 - c(x')),
        c(x') = sum_d kernel[d] free(x' + d),

    where ``c(x')`` is the probability that a move from ``x'`` ends on a free
    cell. Summing over ``x'`` gives the predicted belief::

        bel_bar = free * (kernel conv bel) + (1 - c) * bel.

    Parameters
    ----------
    belief : ndarray, shape (H, W)
        ``bel(x_{t-1})`` over the cells (rows ``y``, columns ``x``); non-negative,
        sums to 1, zero on occupied cells.
    kernel : ndarray, shape (2 r_y + 1, 2 r_x + 1)
        ``p(displacement)`` (:func:`motion_kernel` with a 2-D shift): rows are
        ``dy``, columns ``dx``, centred on zero displacement; sums to 1.
    free : ndarray of bool, shape (H, W), optional
        ``True`` on free cells. Default: every cell is free (only the map edge
        blocks).

    Returns
    -------
    ndarray, shape (H, W)
        ``bel_bar(x_t)``, summing to 1 and zero on occupied cells. With a delta
        kernel and no obstacle in the way this is a shift of the belief.

    Raises
    ------
    ValueError
        If `belief` puts probability on an occupied cell, or the shapes or
        values are invalid.

    References
    ----------
    Thrun, Burgard & Fox, *Probabilistic Robotics*, Table 8.1 line 3 (grid
    localization) and Table 4.1 line 3; Sec. 8.2.
    """
    belief = as_probabilities(belief, "belief", ndim=2, sums_to_one=True)
    kernel = as_kernel(kernel, "kernel", ndim=2)
    if free is None:
        free = np.ones(belief.shape, dtype=bool)
    else:
        free = as_mask(free, "free", shape=belief.shape, ref="belief")
    if np.any(belief[~free] > 0):
        raise ValueError("belief puts probability on occupied cells of free; the robot cannot be inside a wall")
    free_f = free.astype(float)
    # c(x') = sum_d kernel[d] free(x' + d): the chance a move from x' lands on a free cell
    # (cells beyond the map edge count as blocked: zero padding)
    reach = signal.correlate(free_f, kernel, mode="same", method="direct")
    moved = signal.convolve(belief, kernel, mode="same", method="direct")
    # bel_bar(x_t) = sum_{x_{t-1}} p(x_t | u_t, x_{t-1}) bel(x_{t-1})  (Table 8.1 line 3)
    bel_bar = free_f * moved + np.clip(1.0 - reach, 0.0, 1.0) * belief
    return np.clip(bel_bar, 0.0, None)


def _steps_to_block(blocked, axis):
    """Steps from each cell along ``+axis`` to the first blocked cell (the edge blocks)."""
    b = np.moveaxis(blocked, axis, -1)
    n = b.shape[-1]
    idx = np.arange(n)
    nxt = np.where(b, idx, n)  # index of a blocked cell, or the virtual wall at n
    nxt = np.minimum.accumulate(nxt[..., ::-1], axis=-1)[..., ::-1]
    return np.moveaxis(nxt - idx, -1, axis)


def grid_wall_distances(free, *, max_range=None):
    """Expected readings of four axis-aligned range sensors in every grid cell.

    The toy range finder of the grid-localization example measures, in cells,
    how far the first occupied cell (or the map edge) lies to the east (``+x``),
    north (``+y``), west (``-x``) and south (``-y``): the number of steps from
    the robot's cell to that cell, so a wall right next to the robot reads 1.

    Parameters
    ----------
    free : ndarray of bool, shape (H, W)
        ``True`` on free cells (rows ``y``, columns ``x``).
    max_range : float, optional
        Largest reading of the sensor (``> 0``): longer distances read
        ``max_range``. Default: no limit.

    Returns
    -------
    ndarray, shape (H, W, 4)
        Distances ``[east, north, west, south]`` in cells, at most `max_range`;
        0 on occupied cells.

    References
    ----------
    Thrun, Burgard & Fox, *Probabilistic Robotics*, Sec. 6.3 (expected range
    ``z*`` by ray casting), reduced to four axis-aligned beams.
    """
    free = as_mask(free, "free", ndim=2)
    blocked = ~free
    east = _steps_to_block(blocked, 1)
    north = _steps_to_block(blocked, 0)
    west = _steps_to_block(blocked[:, ::-1], 1)[:, ::-1]
    south = _steps_to_block(blocked[::-1, :], 0)[::-1, :]
    out = np.stack([east, north, west, south], axis=-1).astype(float)
    if max_range is not None:
        out = np.minimum(out, as_scalar(max_range, "max_range", positive=True))
    out[blocked] = 0.0
    return out


def grid_range_likelihood(expected, z, *, sigma):
    """Likelihood grid ``p(z | x)`` of independent Gaussian range beams.

    ``p(z | x) = prod_k N(z_k; z*_k(x), sigma^2)``, the beams being independent
    given the pose (Eq. 6.2) and each a Gaussian around its expected reading.

    Parameters
    ----------
    expected : ndarray, shape (H, W, K)
        Expected readings ``z*`` of ``K`` beams in every cell
        (e.g. :func:`grid_wall_distances`).
    z : ndarray, shape (K,)
        The measured ranges.
    sigma : float
        Standard deviation of each beam, ``> 0``, in the units of `z`.

    Returns
    -------
    ndarray, shape (H, W)
        ``p(z | x)`` up to a constant factor: computed in log space and scaled so
        that its largest value is 1, so it never underflows to all zeros. Bayes
        rule (:func:`histogram_update`) does not depend on that factor.

    References
    ----------
    Thrun, Burgard & Fox, *Probabilistic Robotics*, Eq. 6.2 and Eq. 6.4 (the hit
    component of the beam model).
    """
    expected = as_array(expected, "expected", ndim=3)
    z = as_array(z, "z", (expected.shape[-1],), ref="expected")
    sigma = as_scalar(sigma, "sigma", positive=True)
    # log p(z | x) = sum_k log N(z_k; z*_k, sigma^2), up to a constant  (Eq. 6.2)
    log_lik = -0.5 * np.sum(((z - expected) / sigma) ** 2, axis=-1)
    return np.exp(log_lik - log_lik.max())


def simulate_grid(free, start, moves, *, sigma, range_sigma, rng, max_range=None):
    """Simulate a robot moving on a grid and reading its four range beams.

    Each step draws a displacement from ``motion_kernel(moves[t], sigma)``; a
    move that would end off the map or in an occupied cell leaves the robot where
    it was (the motion model of :func:`grid_predict`). The robot then reads
    ``grid_wall_distances(free, max_range=max_range)`` at its cell plus
    Gaussian noise.

    Parameters
    ----------
    free : ndarray of bool, shape (H, W)
        ``True`` on free cells (rows ``y``, columns ``x``).
    start : ndarray of int, shape (2,)
        Free cell ``(x, y)`` where the robot starts (before the first move).
    moves : ndarray, shape (T, 2)
        Commanded displacement ``(dx, dy)`` of each step in cells.
    sigma : float or ndarray, shape (2,)
        Motion noise standard deviation in cells (per axis ``(x, y)``), ``>= 0``.
    range_sigma : float
        Standard deviation of each range reading in cells, ``>= 0``.
    rng : numpy.random.Generator
        Source of randomness. Each step draws one displacement (``rng.choice``
        with the kernel's probabilities), then four ``rng.normal`` readings.
    max_range : float, optional
        Largest expected reading, as in :func:`grid_wall_distances`.

    Returns
    -------
    cells : ndarray of int, shape (T, 2)
        True cell ``(x, y)`` after each step's move.
    z : ndarray, shape (T, 4)
        The readings ``[east, north, west, south]`` taken there, in cells.

    References
    ----------
    Thrun, Burgard & Fox, *Probabilistic Robotics*, Sec. 8.2 (grid localization).
    """
    free = as_mask(free, "free", ndim=2)
    H, W = free.shape
    start = as_array(start, "start", (2,))
    if np.any(start != np.round(start)):
        raise ValueError(f"start must hold integer cell coordinates (x, y), got {start}")
    x, y = int(start[0]), int(start[1])
    if not (0 <= x < W and 0 <= y < H) or not free[y, x]:
        raise ValueError(f"start {start} must be a free cell (x, y) inside the {W} x {H} map")
    moves = as_array(moves, "moves", (None, 2))
    range_sigma = as_scalar(range_sigma, "range_sigma", nonnegative=True)
    rng = check_rng(rng)
    expected = grid_wall_distances(free, max_range=max_range)
    cells = np.empty((moves.shape[0], 2), dtype=int)
    zs = np.empty((moves.shape[0], 4))
    for t, u in enumerate(moves):
        kernel = motion_kernel(u, sigma)
        a, b = np.unravel_index(int(rng.choice(kernel.size, p=kernel.ravel())), kernel.shape)
        nx, ny = x + int(b) - kernel.shape[1] // 2, y + int(a) - kernel.shape[0] // 2
        if 0 <= nx < W and 0 <= ny < H and free[ny, nx]:
            x, y = nx, ny  # otherwise the robot bumps and stays
        cells[t] = (x, y)
        zs[t] = expected[y, x] + range_sigma * rng.normal(size=4)
    return cells, zs
