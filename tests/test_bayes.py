"""Bayes rule, the discrete Bayes filter and grid localization (slamlib.bayes)."""

from __future__ import annotations

import numpy as np
import pytest

import slamlib as sl


# --------------------------------------------------------------------------- reference constructions


def _circulant(kernel, n):
    """Transition matrix T[x, x'] = p(x | x') of the cyclic corridor, built cell by cell."""
    r = len(kernel) // 2
    T = np.zeros((n, n))
    for src in range(n):
        for k, p in enumerate(kernel):
            T[(src + k - r) % n, src] += p
    return T


def _grid_transition(kernel, free):
    """Transition matrix of the bump model of grid_predict, built cell by cell."""
    H, W = free.shape
    ry, rx = kernel.shape[0] // 2, kernel.shape[1] // 2
    T = np.zeros((H * W, H * W))
    for y in range(H):
        for x in range(W):
            src = y * W + x
            for a in range(kernel.shape[0]):
                for b in range(kernel.shape[1]):
                    nx, ny = x + b - rx, y + a - ry
                    if 0 <= nx < W and 0 <= ny < H and free[ny, nx]:
                        T[ny * W + nx, src] += kernel[a, b]
                    else:
                        T[src, src] += kernel[a, b]  # bump: stay
    return T


def _floor_plan():
    """A 14 x 20 floor plan with an inner block and a pillar (not symmetric)."""
    free = np.ones((14, 20), dtype=bool)
    free[4:10, 5:14] = False  # a block of rooms in the middle
    free[2, 16] = False  # a pillar
    return free


# --------------------------------------------------------------------------- Bayes rule


def test_bayes_rule_two_boxes():
    # fair coin picks a box; box 1: 5 red of 10, box 2: 3 red of 10; a red ball is drawn
    post = sl.bayes_rule([0.5, 0.5], [5 / 10, 3 / 10])
    np.testing.assert_allclose(post, [0.625, 0.375], rtol=0, atol=1e-15)


def test_bayes_rule_matches_formula_and_ignores_likelihood_scale():
    rng = np.random.default_rng(1)
    prior = rng.random(7)
    prior /= prior.sum()
    lik = rng.random(7)
    expected = lik * prior / np.sum(lik * prior)
    np.testing.assert_allclose(sl.bayes_rule(prior, lik), expected, rtol=1e-12)
    np.testing.assert_allclose(sl.bayes_rule(prior, 1e-200 * lik), expected, rtol=1e-12)
    assert sl.bayes_rule(prior, lik).sum() == pytest.approx(1.0, abs=1e-12)


def test_bayes_rule_works_on_grids():
    rng = np.random.default_rng(2)
    prior = rng.random((3, 4))
    prior /= prior.sum()
    lik = rng.random((3, 4))
    post = sl.bayes_rule(prior, lik)
    assert post.shape == (3, 4)
    np.testing.assert_allclose(post, lik * prior / np.sum(lik * prior), rtol=1e-12)


@pytest.mark.parametrize(
    "prior, lik, exc, word",
    [
        ([0.5, 0.6], [1.0, 1.0], ValueError, "prior"),  # does not sum to 1
        ([1.5, -0.5], [1.0, 1.0], ValueError, "prior"),  # negative
        ([0.5, 0.5], [1.0, 1.0, 1.0], ValueError, "likelihood"),  # shape
        ([0.5, 0.5], [1.0, -1.0], ValueError, "likelihood"),
        ([0.5, 0.5], [np.nan, 1.0], ValueError, "likelihood"),
        ([1.0, 0.0], [0.0, 1.0], ValueError, "impossible"),
        ("ab", [1.0, 1.0], TypeError, "prior"),
    ],
)
def test_bayes_rule_bad_inputs(prior, lik, exc, word):
    with pytest.raises(exc, match=word):
        sl.bayes_rule(prior, lik)


# --------------------------------------------------------------------------- motion kernels


def test_motion_kernel_moments_match_the_gaussian():
    # binning N(s, sigma^2) into unit cells: mean s, variance sigma^2 + 1/12 (Sheppard's correction);
    # the periodic error terms are O(exp(-2 pi^2 sigma^2)) = 1e-34 for sigma = 2
    k = sl.motion_kernel(1.3, 2.0, radius=30)
    d = np.arange(-30, 31)
    assert k.sum() == pytest.approx(1.0, abs=1e-12)
    mean = np.sum(d * k)
    assert mean == pytest.approx(1.3, abs=1e-9)
    assert np.sum((d - mean) ** 2 * k) == pytest.approx(4.0 + 1.0 / 12.0, abs=1e-9)


def test_motion_kernel_default_window_and_delta():
    k = sl.motion_kernel(2.0, 0.5)
    assert k.shape == (9,)  # radius ceil(2 + 4 * 0.5) = 4
    assert np.argmax(k) == 4 + 2
    np.testing.assert_array_equal(sl.motion_kernel(-3, 0.0), np.eye(7)[0])  # delta at -3 of a radius-3 window
    np.testing.assert_array_equal(sl.motion_kernel(2.4, 0.0, radius=3), np.eye(7)[5])


def test_motion_kernel_2d_orientation_and_separability():
    k = sl.motion_kernel([2, -1], 0.0)  # dx = 2, dy = -1
    assert k.shape == (3, 5)  # rows are y (radius 1), columns x (radius 2)
    assert k[1 - 1, 2 + 2] == 1.0 and k.sum() == 1.0
    kx = sl.motion_kernel(0.5, 0.7)
    ky = sl.motion_kernel(-1.0, 0.3)
    np.testing.assert_allclose(sl.motion_kernel([0.5, -1.0], [0.7, 0.3]), np.outer(ky, kx), rtol=1e-14)


@pytest.mark.parametrize(
    "args, kwargs, exc, word",
    [
        ((1.0, -0.1), {}, ValueError, "sigma"),
        (([1.0, 2.0, 3.0], 0.1), {}, ValueError, "shift"),
        (([1.0, 2.0], [0.1, 0.2, 0.3]), {}, ValueError, "sigma"),
        ((3.0, 0.0), {"radius": 2}, ValueError, "radius"),
        ((3.0, 0.0), {"radius": 2.5}, TypeError, "radius"),
        ((np.inf, 1.0), {}, ValueError, "shift"),
    ],
)
def test_motion_kernel_bad_inputs(args, kwargs, exc, word):
    with pytest.raises(exc, match=word):
        sl.motion_kernel(*args, **kwargs)


# --------------------------------------------------------------------------- 1-D histogram filter


def test_predict_with_delta_kernel_is_a_cyclic_shift():
    rng = np.random.default_rng(3)
    bel = rng.random(12)
    bel /= bel.sum()
    for shift in (-13, -1, 0, 4, 11, 25):
        np.testing.assert_allclose(sl.histogram_predict(bel, sl.motion_kernel(shift, 0.0)), np.roll(bel, shift),
                                   rtol=0, atol=1e-15)


def test_predict_equals_transition_matrix_and_conserves_probability():
    rng = np.random.default_rng(4)
    n = 15
    bel = rng.random(n)
    bel /= bel.sum()
    for kernel in (sl.motion_kernel(2.5, 1.2), sl.motion_kernel(-4.0, 6.0)):  # the second wraps round the ring
        pred = sl.histogram_predict(bel, kernel)
        np.testing.assert_allclose(pred, _circulant(kernel, n) @ bel, rtol=1e-12, atol=1e-15)
        assert pred.sum() == pytest.approx(1.0, abs=1e-12)
        assert np.all(pred >= 0)


def test_update_with_uniform_likelihood_is_identity():
    rng = np.random.default_rng(5)
    bel = rng.random(9)
    bel /= bel.sum()
    np.testing.assert_allclose(sl.histogram_update(bel, np.full(9, 0.3)), bel, rtol=1e-14)
    lik = rng.random(9)
    np.testing.assert_allclose(sl.histogram_update(bel, lik), sl.bayes_rule(bel, lik), rtol=1e-14)


def test_histogram_filter_equals_step_by_step_loop():
    rng = np.random.default_rng(6)
    n, T = 20, 6
    bel0 = np.full(n, 1.0 / n)
    kernels = [sl.motion_kernel(u, 0.8) for u in (0, 1, 2, 1, 3, 1)]  # different lengths
    lik = rng.random((T, n))
    pred, post = sl.histogram_filter(bel0, kernels, lik)
    assert pred.shape == post.shape == (T, n)
    bel = bel0
    for t in range(T):
        bar = sl.histogram_predict(bel, kernels[t])
        bel = sl.histogram_update(bar, lik[t])
        np.testing.assert_allclose(pred[t], bar, rtol=1e-14)
        np.testing.assert_allclose(post[t], bel, rtol=1e-14)
    # one kernel for every step
    same = sl.motion_kernel(1, 0.5)
    _, post1 = sl.histogram_filter(bel0, same, lik)
    _, post2 = sl.histogram_filter(bel0, [same] * T, lik)
    np.testing.assert_allclose(post1, post2, rtol=1e-14)


def test_histogram_bad_inputs():
    bel = np.full(5, 0.2)
    with pytest.raises(ValueError, match="kernel"):
        sl.histogram_predict(bel, [0.5, 0.5])  # even length
    with pytest.raises(ValueError, match="kernel"):
        sl.histogram_predict(bel, [0.2, 0.2, 0.2])  # does not sum to 1
    with pytest.raises(ValueError, match="belief"):
        sl.histogram_predict(np.full((5, 1), 0.2), [1.0])
    with pytest.raises(ValueError, match="belief"):
        sl.histogram_update(np.full(5, 0.3), np.ones(5))
    with pytest.raises(ValueError, match="likelihood"):
        sl.histogram_update(bel, np.ones(4))
    with pytest.raises(ValueError, match="kernels"):
        sl.histogram_filter(bel, [[1.0]] * 2, np.ones((3, 5)))
    with pytest.raises(ValueError, match="likelihoods"):
        sl.histogram_filter(bel, [1.0], np.ones((3, 4)))


def test_functions_do_not_modify_their_arguments():
    rng = np.random.default_rng(7)
    bel = rng.random(10)
    bel /= bel.sum()
    kernel = sl.motion_kernel(1.0, 0.7)
    lik = rng.random(10)
    copies = [a.copy() for a in (bel, kernel, lik)]
    sl.histogram_predict(bel, kernel)
    sl.histogram_update(bel, lik)
    sl.bayes_rule(bel, lik)
    sl.histogram_filter(bel, kernel, lik[None])
    for a, c in zip((bel, kernel, lik), copies):
        np.testing.assert_array_equal(a, c)
    free = _floor_plan()
    grid = free / free.sum()
    k2 = sl.motion_kernel([1.0, 0.0], 0.6)
    g_copy, k2_copy, f_copy = grid.copy(), k2.copy(), free.copy()
    sl.grid_predict(grid, k2, free=free)
    sl.grid_wall_distances(free)
    np.testing.assert_array_equal(grid, g_copy)
    np.testing.assert_array_equal(k2, k2_copy)
    np.testing.assert_array_equal(free, f_copy)


# --------------------------------------------------------------------------- the corridor


def test_corridor_doors_and_door_likelihood():
    doors = sl.corridor_doors(10, [1, 8], door_width=3)
    np.testing.assert_array_equal(np.flatnonzero(doors), [0, 1, 2, 3, 8, 9])  # the second door wraps
    lik = sl.door_likelihood(doors, True, p_hit=0.8, p_false=0.1)
    np.testing.assert_allclose(lik, np.where(doors, 0.8, 0.1), rtol=0)
    both = sl.door_likelihood(doors, [True, False], p_hit=0.8, p_false=0.1)
    assert both.shape == (2, 10)
    np.testing.assert_allclose(both.sum(axis=0), 1.0, rtol=1e-15)  # p(door | x) + p(wall | x) = 1
    with pytest.raises(ValueError, match="door_cells"):
        sl.corridor_doors(10, [10])
    with pytest.raises(ValueError, match="p_hit"):
        sl.door_likelihood(doors, True, p_hit=1.5, p_false=0.1)
    with pytest.raises(ValueError, match="z"):
        sl.door_likelihood(doors, 2, p_hit=0.8, p_false=0.1)
    with pytest.raises(ValueError, match="doors"):
        sl.door_likelihood([0, 2, 1], True, p_hit=0.8, p_false=0.1)


def test_simulate_corridor_follows_its_model():
    n = 30
    doors = sl.corridor_doors(n, [3, 12, 20], door_width=2)
    T = 20000
    x, z = sl.simulate_corridor(doors, 0, np.full(T, 2.0), sigma=0.8, p_hit=0.7, p_false=0.2,
                                rng=np.random.default_rng(8))
    assert x.shape == z.shape == (T,) and x.dtype.kind == "i" and z.dtype == bool
    # readings: door seen with probability p_hit at doors, p_false elsewhere (4-sigma binomial bounds)
    for mask, p in ((doors[x], 0.7), (~doors[x], 0.2)):
        m = mask.sum()
        assert abs(z[mask].mean() - p) < 4 * np.sqrt(p * (1 - p) / m)
    # displacements follow the kernel (total variation distance of the empirical histogram)
    steps = np.diff(np.concatenate([[0], x])) % n
    kernel = sl.motion_kernel(2.0, 0.8)
    r = kernel.size // 2
    empirical = np.array([np.mean(steps == (k - r) % n) for k in range(kernel.size)])
    assert 0.5 * np.abs(empirical - kernel).sum() < 0.02


def test_corridor_filter_localizes_the_robot():
    n, sigma = 60, 0.3
    doors = sl.corridor_doors(n, [3, 9, 24, 42], door_width=3)  # irregular gaps: 3, 12, 15, 18 cells
    near = []
    for seed in range(10):
        rng = np.random.default_rng(100 + seed)
        x, z = sl.simulate_corridor(doors, int(rng.integers(n)), np.full(100, 1.0), sigma=sigma, p_hit=0.9,
                                    p_false=0.05, rng=rng)
        lik = sl.door_likelihood(doors, z, p_hit=0.9, p_false=0.05)
        _, post = sl.histogram_filter(np.full(n, 1.0 / n), sl.motion_kernel(1.0, sigma), lik)
        # ignorance at the start: the posterior after one reading is spread over many cells
        assert post[0].max() < 0.1
        offset = (np.arange(n) - x[-1] + n // 2) % n - n // 2  # signed cyclic distance to the robot
        near.append(post[-1, np.abs(offset) <= 3].sum())
    assert min(near) > 0.8, f"belief within 3 cells of the robot after 100 steps: {np.round(near, 3)}"
    assert np.median(near) > 0.95


def test_simulate_corridor_bad_inputs():
    doors = sl.corridor_doors(10, [2])
    with pytest.raises(TypeError, match="rng"):
        sl.simulate_corridor(doors, 0, [1.0], sigma=0.5, p_hit=0.9, p_false=0.1, rng=3)
    with pytest.raises(ValueError, match="x0"):
        sl.simulate_corridor(doors, 10, [1.0], sigma=0.5, p_hit=0.9, p_false=0.1, rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="sigma"):
        sl.simulate_corridor(doors, 0, [1.0], sigma=-1.0, p_hit=0.9, p_false=0.1, rng=np.random.default_rng(0))


# --------------------------------------------------------------------------- 2-D grid localization


def test_grid_predict_with_delta_kernel_is_a_shift_in_open_space():
    rng = np.random.default_rng(9)
    bel = np.zeros((12, 15))
    bel[3:7, 4:9] = rng.random((4, 5))  # well inside the map
    bel /= bel.sum()
    pred = sl.grid_predict(bel, sl.motion_kernel([2, -1], 0.0))  # dx = 2 columns, dy = -1 row
    np.testing.assert_allclose(pred, np.roll(bel, (-1, 2), axis=(0, 1)), rtol=0, atol=1e-15)


def test_grid_predict_equals_bump_transition_matrix():
    free = np.ones((5, 6), dtype=bool)
    free[2, 1:4] = False
    free[0, 5] = False
    rng = np.random.default_rng(10)
    bel = rng.random(free.shape) * free
    bel /= bel.sum()
    for kernel in (sl.motion_kernel([1.0, 0.5], [0.7, 0.4]), sl.motion_kernel([-2, 1], 0.0)):
        pred = sl.grid_predict(bel, kernel, free=free)
        expected = (_grid_transition(kernel, free) @ bel.ravel()).reshape(free.shape)
        np.testing.assert_allclose(pred, expected, rtol=1e-12, atol=1e-15)
        assert pred.sum() == pytest.approx(1.0, abs=1e-12)
        assert np.all(pred[~free] == 0)


def test_grid_predict_bumps_into_walls():
    free = np.ones((3, 4), dtype=bool)
    free[:, 3] = False
    bel = np.zeros((3, 4))
    bel[1, 2] = 1.0  # next to the wall on its east side
    np.testing.assert_array_equal(sl.grid_predict(bel, sl.motion_kernel([1, 0], 0.0), free=free), bel)


def test_grid_predict_bad_inputs():
    free = _floor_plan()
    bel = np.full(free.shape, 1.0 / free.size)  # puts mass inside walls
    with pytest.raises(ValueError, match="occupied"):
        sl.grid_predict(bel, sl.motion_kernel([1, 0], 0.5), free=free)
    with pytest.raises(ValueError, match="free"):
        sl.grid_predict(free / free.sum(), sl.motion_kernel([1, 0], 0.5), free=free[:, :-1])
    with pytest.raises(ValueError, match="kernel"):
        sl.grid_predict(free / free.sum(), np.full((2, 2), 0.25), free=free)
    with pytest.raises(ValueError, match="free"):
        sl.grid_predict(free / free.sum(), sl.motion_kernel([1, 0], 0.5), free=free * 2.0)


def test_grid_wall_distances_against_brute_force():
    rng = np.random.default_rng(11)
    free = rng.random((7, 9)) > 0.3
    d = sl.grid_wall_distances(free)
    H, W = free.shape
    for y in range(H):
        for x in range(W):
            if not free[y, x]:
                np.testing.assert_array_equal(d[y, x], 0.0)
                continue
            for k, (dx, dy) in enumerate([(1, 0), (0, 1), (-1, 0), (0, -1)]):
                s = 1
                while 0 <= x + s * dx < W and 0 <= y + s * dy < H and free[y + s * dy, x + s * dx]:
                    s += 1
                assert d[y, x, k] == s, (y, x, k)
    np.testing.assert_array_equal(sl.grid_wall_distances(free, max_range=2.5), np.minimum(d, 2.5))
    with pytest.raises(ValueError, match="max_range"):
        sl.grid_wall_distances(free, max_range=0.0)


def test_grid_range_likelihood_is_a_scaled_gaussian_product():
    rng = np.random.default_rng(12)
    expected = rng.random((4, 5, 4)) * 10
    z = rng.random(4) * 10
    lik = sl.grid_range_likelihood(expected, z, sigma=1.5)
    dens = np.prod(np.exp(-0.5 * ((z - expected) / 1.5) ** 2) / (1.5 * np.sqrt(2 * np.pi)), axis=-1)
    assert lik.max() == pytest.approx(1.0, abs=1e-15)
    np.testing.assert_allclose(lik, dens / dens.max(), rtol=1e-12)
    # far-off readings do not underflow to an all-zero likelihood
    assert sl.grid_range_likelihood(expected, z + 1e3, sigma=0.1).max() == 1.0
    with pytest.raises(ValueError, match="z"):
        sl.grid_range_likelihood(expected, z[:3], sigma=1.0)
    with pytest.raises(ValueError, match="sigma"):
        sl.grid_range_likelihood(expected, z, sigma=0.0)


def test_simulate_grid_noise_free_follows_commands():
    free = _floor_plan()
    moves = np.array([[1, 0]] * 4 + [[0, 1]] * 3)
    cells, z = sl.simulate_grid(free, [1, 1], moves, sigma=0.0, range_sigma=0.0, rng=np.random.default_rng(0))
    np.testing.assert_array_equal(cells, [[2, 1], [3, 1], [4, 1], [5, 1], [5, 2], [5, 3], [5, 3]])  # bumps at the end
    d = sl.grid_wall_distances(free)
    np.testing.assert_array_equal(z, d[cells[:, 1], cells[:, 0]])


def test_simulate_grid_matches_grid_predict():
    # one-step Monte Carlo of the simulator against the predicted belief from a known cell by a wall
    free = _floor_plan()
    start = (4, 6)  # x = 4, y = 6: the block of rooms starts at x = 5
    kernel = sl.motion_kernel([1.0, 0.5], 0.8)
    bel = np.zeros(free.shape)
    bel[start[1], start[0]] = 1.0
    pred = sl.grid_predict(bel, kernel, free=free)
    rng = np.random.default_rng(13)
    counts = np.zeros(free.shape)
    N = 4000
    for _ in range(N):
        cells, _ = sl.simulate_grid(free, start, [[1.0, 0.5]], sigma=0.8, range_sigma=0.0, rng=rng)
        counts[cells[0, 1], cells[0, 0]] += 1
    assert 0.5 * np.abs(counts / N - pred).sum() < 0.04
    assert pred[start[1], start[0]] > 0.3  # bumping into the block keeps much of the mass in place


def test_grid_filter_localizes_the_robot():
    free = _floor_plan()
    d = sl.grid_wall_distances(free)
    moves = np.array([[1, 0]] * 12 + [[0, 1]] * 6 + [[-1, 0]] * 6, dtype=float)
    for seed in range(3):
        rng = np.random.default_rng(200 + seed)
        cells, z = sl.simulate_grid(free, [1, 1], moves, sigma=0.4, range_sigma=0.5, rng=rng)
        bel = free / free.sum()
        for u, zt in zip(moves, z):
            bel = sl.grid_predict(bel, sl.motion_kernel(u, 0.4), free=free)
            bel = sl.histogram_update(bel, sl.grid_range_likelihood(d, zt, sigma=0.5))
        x, y = cells[-1]
        near = bel[max(y - 1, 0):y + 2, max(x - 1, 0):x + 2].sum()
        assert near > 0.9, f"seed {seed}: only {near:.3f} of the belief within one cell of the robot"


def test_simulate_grid_bad_inputs():
    free = _floor_plan()
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="start"):
        sl.simulate_grid(free, [6, 6], [[1, 0]], sigma=0.1, range_sigma=0.1, rng=rng)  # inside the block
    with pytest.raises(ValueError, match="moves"):
        sl.simulate_grid(free, [1, 1], [1, 0], sigma=0.1, range_sigma=0.1, rng=rng)
    with pytest.raises(TypeError, match="rng"):
        sl.simulate_grid(free, [1, 1], [[1, 0]], sigma=0.1, range_sigma=0.1, rng=None)


# --------------------------------------------------------------------------- plots


def test_plot_functions_draw_what_they_are_given():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    doors = sl.corridor_doors(20, [2, 11], door_width=2)
    bel = np.full(20, 0.05)
    ax = sl.viz.plot_belief_1d(bel, doors=doors, true_x=4, predicted=bel, legend=True)
    assert ax.get_xlim() == (-0.5, 19.5)
    axes = sl.viz.plot_belief_sequence(np.tile(bel, (3, 1)), doors=doors, true_x=[1, 2, 3], titles=list("abc"))
    assert len(axes) == 3 and axes[2].get_title(loc="left") == "c"
    free = _floor_plan()
    grid = free / free.sum()
    assert len(sl.viz.plot_belief_2d_sequence(np.stack([grid] * 4), free=free, true_xy=[[1, 1]] * 4, ncols=3)) == 4
    ax = sl.viz.plot_belief_2d(grid, free=free, true_xy=[1, 1], path=[[1, 1], [2, 1]], colorbar=True)
    assert ax.get_xlim() == (-0.5, 19.5)
    ax = sl.viz.plot_beam_model(4.0, z_max=8.0, sigma_hit=0.3, lambda_short=0.5, w_hit=0.7, w_short=0.1,
                                w_max=0.05, w_rand=0.15)
    assert len(ax.get_lines()) >= 4
    ax = sl.viz.plot_range_histogram(np.array([0.5, 1.0, 8.0, 8.0]), max_range=8.0)
    assert ax.patches[-1].get_height() == pytest.approx(0.5)  # half the readings are "no return"
    samples = sl.sample_motion_model_odometry(np.zeros((50, 3)), [0.1, 1.0, 0.1], [0.01] * 4,
                                              rng=np.random.default_rng(0))
    axes = sl.viz.plot_motion_samples([samples, samples], start=np.zeros(3), end=[1.0, 0.1, 0.2],
                                      densities=[np.ones((4, 4)), None], extent=(0, 2, -1, 1))
    assert len(axes) == 2
    axes = sl.viz.plot_likelihood_panels([np.ones((5, 5))], (0, 1, 0, 1), landmarks=[[[0.5, 0.5]]],
                                         pose=[0.2, 0.2, 0.0])
    assert axes[0].get_xlim() == (0, 1)
    occ = np.zeros((30, 40))
    occ[0, :] = occ[:, 0] = 1.0
    m = sl.OccupancyGrid(occ, 0.1)
    axes = sl.viz.plot_map_and_field(m, sl.likelihood_field(m, max_dist=1.0), sigma_hit=0.2, xlim=(0, 4))
    assert axes[1].get_xlim() == (0, 4)
    with pytest.raises(ValueError, match="belief"):
        sl.viz.plot_belief_1d(np.ones((2, 2)))
    plt.close("all")
