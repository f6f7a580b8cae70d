"""Monte Carlo localization: MCL, Augmented MCL and KLD-sampling (slamlib.mcl).

Simulated runs on a small asymmetric map check accuracy against the truth; the
CMU Wean Hall log has no ground truth, so its run is checked for consistency
with the map (scan end points on walls, the estimate in free space).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import logsumexp
from scipy.stats import chi2, norm

import slamlib as sl
from slamlib import mcl

CMU_START = (40.0, 41.5, -1.6755)  # slamlib.datasets.cmu.CMU_LOG_START
ANGLES = np.linspace(-np.pi / 2, np.pi / 2, 180, endpoint=False)
Z_MAX = 8.0


# --------------------------------------------------------------------------- a simulated world
def _grid():
    """12 m x 8 m, 10 cm cells: outer walls, two partial walls, three blocks (no symmetry)."""
    occ = np.zeros((80, 120))
    occ[0, :] = occ[-1, :] = 1.0
    occ[:, 0] = occ[:, -1] = 1.0
    occ[30:80, 40] = 1.0  # wall from the top at x = 4 m
    occ[0:45, 80] = 1.0  # wall from the bottom at x = 8 m
    occ[55:65, 10:25] = 1.0
    occ[15:22, 55:70] = 1.0
    occ[60:80, 95:100] = 1.0
    return sl.OccupancyGrid(occ, 0.1)


def _path(waypoints, n):
    wp = np.asarray(waypoints, dtype=float)
    seg = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(wp, axis=0).T))])
    s = np.linspace(0.0, seg[-1], n)
    xy = np.column_stack([np.interp(s, seg, wp[:, 0]), np.interp(s, seg, wp[:, 1])])
    d = np.gradient(xy, axis=0)
    return np.column_stack([xy, np.arctan2(d[:, 1], d[:, 0])])


ROUTE_A = [[1.5, 1.5], [3.5, 2.0], [5.0, 1.0], [7.3, 1.0], [7.3, 5.5], [10.5, 5.5], [10.5, 2.0]]
ROUTE_B = [[10.5, 1.0], [10.0, 5.2], [6.0, 5.2], [5.0, 2.5], [2.5, 2.5], [2.0, 4.5]]


def _simulate(truth, *, rng, kidnap_at=None, sigma_z=0.03, drift=0.02):
    """Scans by ray casting from the true poses (+ noise) and drifting odometry.

    At step `kidnap_at` the odometry reports no motion although the true pose jumps.
    """
    grid = _grid()
    z = sl.ray_cast(grid, truth, ANGLES, Z_MAX, sensor_offset=0.25)
    z = np.clip(z + rng.normal(0.0, sigma_z, z.shape), 0.0, Z_MAX)
    u = sl.odometry_from_poses(truth[:-1], truth[1:])
    u = u * (1.0 + drift * rng.standard_normal(u.shape))
    if kidnap_at is not None:
        u[kidnap_at - 1] = 0.0
    odom = np.empty_like(truth)
    odom[0] = [0.0, 0.0, 0.0]  # the odometry frame is not the map frame
    for k in range(1, truth.shape[0]):
        odom[k] = sl.odometry_motion(odom[k - 1], u[k - 1])
    return grid, odom, z


SIM_PARAMS = dict(n_particles=2000, z_max=Z_MAX, sigma_hit=0.2, likelihood_exponent=0.3, min_translation=0.1,
                  min_rotation=0.1, sensor_offset=0.25, occupied_threshold=0.5, free_threshold=0.2,
                  init_candidates=0, estimate_radius=0.0)  # Table 8.2's uniform start, the estimate at the mode's mean


def _error(result, truth):
    return np.hypot(*(result.mean[:, :2] - truth[result.scan_index, :2]).T)


@pytest.fixture(scope="module")
def sim():
    truth = _path(ROUTE_A, 80)
    grid, odom, z = _simulate(truth, rng=np.random.default_rng(7))
    return grid, truth, odom, z


def test_simulated_route_is_in_free_space(sim):
    grid, truth, _, _ = sim
    assert grid.is_free(truth[:, :2]).all()


@pytest.fixture(scope="module")
def global_run(sim):
    """Augmented MCL (sensor resetting) with 2000 particles from Table 8.2's uniform start, tempering 0.1.

    Plain MCL (Table 8.2) from the same start is not reliable here: over 50 simulated worlds and seeds, with
    these 2000 particles it ended about 10 m off, on a look-alike place heading the other way, in 16 runs at
    tau = 0.3 (13 of them with all the mass in that one mode) and in 9 at tau = 0.1; with 5000 in 4.
    """
    grid, truth, odom, z = sim
    aug = mcl.AugmentedParams(candidates=5000)
    params = mcl.MCLParams(**{**SIM_PARAMS, "likelihood_exponent": 0.1, "augmented": aug})
    return mcl.run_mcl(mcl.prepare_mcl(grid, params), odom, z, ANGLES, rng=np.random.default_rng(0), snapshots=2)


def test_mcl_converges_from_a_uniform_cloud(sim, global_run):
    # over 50 worlds and seeds: final error 0.056-0.083 m, spread 0.073-0.082 m, heading error <= 0.007 rad
    grid, truth, odom, z = sim
    res = global_run
    err = _error(res, truth)
    assert res.spread[0] > 2.0  # starts spread over the whole map (3.5-4.1 m measured)
    assert err[-1] < 0.3, err
    assert np.all(err[-len(err) // 4:] < 0.3), err
    assert res.spread[-1] < 0.3
    assert abs(sl.angle_diff(res.mean[-1, 2], truth[res.scan_index[-1], 2])) < 0.1
    assert len(res.snapshots) == 2 and res.snapshots[0].poses.shape == (2000, 3)


def test_beam_model_converges_too(sim):
    grid, truth, odom, z = sim
    params = mcl.MCLParams(**{**SIM_PARAMS, "n_particles": 1000, "model": "beam"})
    res = mcl.run_mcl(mcl.prepare_mcl(grid, params), odom, z, ANGLES, rng=np.random.default_rng(0))
    assert _error(res, truth)[-1] < 0.3


def test_pre_cached_ray_casting_agrees_with_exact_casting(sim):
    grid, truth, _, z = sim
    rng = np.random.default_rng(5)
    poses = np.vstack([truth[::5] + rng.normal(0, [0.1, 0.1, 0.03], (len(truth[::5]), 3)),
                       sl.sample_free_poses(grid, 200, rng=rng)])
    cached = mcl.prepare_mcl(grid, mcl.MCLParams(**{**SIM_PARAMS, "model": "beam"}))
    exact = mcl.prepare_mcl(grid, mcl.MCLParams(**{**SIM_PARAMS, "model": "beam", "ray_cache_angles": 0}))
    assert cached.rays is not None and exact.rays is None
    assert mcl.prepare_mcl(grid, mcl.MCLParams(**SIM_PARAMS)).rays is None  # the likelihood field casts nothing
    a = mcl.scan_log_likelihood(cached, poses, z[10], ANGLES)
    b = mcl.scan_log_likelihood(exact, poses, z[10], ANGLES)
    # the same ranking of places, the log-likelihoods within a few units of a scan's hundreds
    assert np.corrcoef(a, b)[0, 1] > 0.99
    assert np.median(np.abs(a - b)) < 0.05 * np.median(np.abs(b))
    with pytest.raises(ValueError, match="ray_cache_angles"):
        mcl.MCLParams(ray_cache_angles=-1)


def test_batched_likelihood_equals_looped(sim):
    grid, truth, _, z = sim
    rng = np.random.default_rng(3)
    poses = np.vstack([truth[10] + [0.05, -0.05, 0.02], sl.sample_free_poses(grid, 6, rng=rng)])
    for model_name in ("likelihood_field", "beam"):
        model = mcl.prepare_mcl(grid, mcl.MCLParams(**{**SIM_PARAMS, "model": model_name}))
        batch = mcl.scan_log_likelihood(model, poses, z[10], ANGLES)
        loop = np.array([mcl.scan_log_likelihood(model, p[None], z[10], ANGLES)[0] for p in poses])
        np.testing.assert_allclose(batch, loop, rtol=1e-12)
        assert np.argmax(batch) == 0  # the pose near the truth explains the scan best


def test_odometry_steps_merge_without_losing_motion():
    rng = np.random.default_rng(4)
    inc = np.column_stack([rng.normal(0, 0.02, 200), np.abs(rng.normal(0.03, 0.02, 200)), rng.normal(0, 0.02, 200)])
    inc[50:80] = 0.0  # the robot stands still: those scans must be skipped
    odom = np.zeros((201, 3))
    for k in range(200):
        odom[k + 1] = sl.odometry_motion(odom[k], inc[k])
    index, u = mcl.odometry_steps(odom, min_translation=0.2, min_rotation=0.2)
    assert index[0] == 0 and np.all(u[0] == 0.0) and np.all(np.diff(index) > 0)
    assert not np.any((index > 51) & (index <= 80))
    # composing the merged controls lands on the odometry of the used scans
    x = odom[0]
    for k in range(1, index.size):
        x = sl.odometry_motion(x, u[k])
        np.testing.assert_allclose(x[:2], odom[index[k], :2], atol=1e-9)
        assert abs(sl.angle_diff(x[2], odom[index[k], 2])) < 1e-9
    # every used step moved enough
    moved = np.hypot(*np.diff(odom[index, :2], axis=0).T)
    turned = np.abs(sl.angle_diff(odom[index[1:], 2], odom[index[:-1], 2]))
    assert np.all((moved >= 0.2) | (turned >= 0.2))


def test_odometry_steps_turn_in_place_keeps_the_turn_in_rot2():
    # a 30 degree turn in place with 2.5 mm of backward wheel slip, then a straight metre
    odom = np.array([[1.0, 2.0, 0.3], [1.0 - 0.0025 * np.cos(0.3), 2.0 - 0.0025 * np.sin(0.3), 0.3 + np.pi / 6],
                     [0.0, 0.0, 0.0]])
    odom[2] = sl.odometry_motion(odom[1], [0.0, 1.0, 0.0])
    index, u = mcl.odometry_steps(odom)
    np.testing.assert_array_equal(index, [0, 1, 2])
    np.testing.assert_allclose(u[1], [0.0, 0.0025, np.pi / 6], atol=1e-12)
    np.testing.assert_allclose(u[2], [0.0, 1.0, 0.0], atol=1e-12)
    # Table 5.5's increments take rot1 from the slip: two opposite turns of about 180 degrees
    raw = mcl.odometry_steps(odom, turn_in_place=0.0)[1]
    assert abs(raw[1, 0]) > 2.5 and abs(raw[1, 2]) > 2.5
    np.testing.assert_allclose(raw[2], u[2], atol=1e-12)
    # the Table 5.6 heading noise of the step is then far larger than the turn-in-place one
    alpha = np.array([0.05, 0.05, 0.05, 0.05])
    x = np.tile(odom[0], (4000, 1))
    spread = [np.std(sl.angle_diff(sl.sample_motion_model_odometry(x, c, alpha, rng=np.random.default_rng(1))[:, 2],
                                   odom[1, 2])) for c in (u[1], raw[1])]
    assert spread[1] > 5 * spread[0], spread
    with pytest.raises(ValueError, match="turn_in_place must be non-negative"):
        mcl.odometry_steps(odom, turn_in_place=-1.0)


# --------------------------------------------------------------------------- kidnapping
@pytest.fixture(scope="module")
def kidnapped():
    truth = np.vstack([_path(ROUTE_A, 80)[:40], _path(ROUTE_B, 60)])
    grid, odom, z = _simulate(truth, rng=np.random.default_rng(11), kidnap_at=40)
    return grid, truth, odom, z


def test_augmented_mcl_recovers_from_kidnapping_plain_mcl_does_not(kidnapped):
    grid, truth, odom, z = kidnapped
    model = mcl.prepare_mcl(grid, mcl.MCLParams(**SIM_PARAMS))
    # both start localized (a cloud of 0.1 m around the start): from a uniform cloud plain MCL itself settles
    # on a look-alike place in about a third of the worlds (test_mcl_converges_from_a_uniform_cloud), which is
    # not what this test is about. Over 50 worlds and seeds: augmented MCL back below 0.3 m by scan 42-49,
    # plain MCL not before scan 74 (or never), plain MCL at least 2.5 m off over scans 40-59, at most 2
    # particles injected before the kidnapping
    runs = {}
    for v in ("mcl", "augmented"):
        rng = np.random.default_rng(5)
        start = truth[0] + rng.normal(0.0, [0.1, 0.1, 0.05], (2000, 3))
        runs[v] = mcl.run_mcl(model, odom, z, ANGLES, rng=rng, variant=v, init=start)
    after = {v: r.scan_index >= 40 for v, r in runs.items()}
    err = {v: _error(r, truth) for v, r in runs.items()}

    def recovered_at(v):  # first scan from which the error stays below 0.3 m
        bad = runs[v].scan_index[after[v] & (err[v] >= 0.3)]
        return bad.max() + 1 if bad.size else 40

    for v in runs:  # both were localized before the kidnapping
        before = (runs[v].scan_index >= 25) & (runs[v].scan_index < 40)
        assert np.all(err[v][before] < 0.3), v
    aug = runs["augmented"]
    assert aug.n_injected[after["augmented"]].sum() > 0
    assert err["augmented"][-1] < 0.3
    # plain MCL has no particle near the new pose: it stays lost, or finds its way back much later
    assert recovered_at("augmented") < 60
    assert recovered_at("mcl") > recovered_at("augmented") + 10
    assert np.all(err["mcl"][(runs["mcl"].scan_index >= 40) & (runs["mcl"].scan_index < 60)] > 1.0)
    # before the kidnapping the averages agree and (almost) nothing is injected
    assert aug.n_injected[(aug.scan_index > 10) & (aug.scan_index < 40)].sum() < 0.05 * 2000


# --------------------------------------------------------------------------- KLD-sampling
def test_kld_sample_size_matches_chi_square_quantile():
    k = np.array([2, 10, 100, 1000])
    approx = mcl.kld_sample_size(k, 0.05, 0.01)
    exact = chi2.ppf(0.99, k - 1) / (2 * 0.05)
    np.testing.assert_allclose(approx, exact, rtol=0.02)
    assert mcl.kld_sample_size(1, 0.05, 0.01) == 0.0
    assert mcl.kld_sample_size(0, 0.05, 0.01) == 0.0
    assert np.all(np.diff(mcl.kld_sample_size(np.arange(2, 50), 0.05, 0.01)) > 0)


def test_kld_particle_count_drops_after_convergence(sim):
    grid, truth, odom, z = sim
    kld = mcl.KLDParams(n_min=100, n_max=5000, epsilon=0.05, delta=0.01)
    params = mcl.MCLParams(**{**SIM_PARAMS, "n_particles": 5000, "kld": kld})
    # From a cloud over the whole map, KLD-sampling keeps only a few hundred particles after the first scans and
    # settled on the look-alike place 10 m away in 17 of 50 worlds and seeds; here the cloud covers a 4 m square
    # around the start with every heading (over 2000 bins). Over 50 worlds and seeds: 5000 particles at the start,
    # 321-444 at most over the second half, final error 0.02-0.05 m.
    rng = np.random.default_rng(1)
    cloud = truth[0] + rng.uniform([-2.0, -2.0, -np.pi], [2.0, 2.0, np.pi], (5000, 3))
    res = mcl.run_mcl(mcl.prepare_mcl(grid, params), odom, z, ANGLES, rng=rng, variant="kld", init=cloud)
    assert res.n_particles[0] == 5000  # a spread-out cloud fills many bins
    late = res.n_particles[len(res) // 2:]
    assert np.all(late >= 100) and late.max() < 0.1 * 5000
    assert _error(res, truth)[-1] < 0.3


def test_kld_stops_where_the_one_at_a_time_loop_would(sim):
    # Chunks of 1 are Table 8.4's loop; the count must not depend on the chunk size.
    grid, truth, odom, z = sim
    state = mcl.mcl_initialize(mcl.prepare_mcl(grid, mcl.MCLParams(**SIM_PARAMS)), rng=np.random.default_rng(2),
                               poses=truth[5] + np.random.default_rng(2).normal(0, 0.4, (300, 3)))
    counts = []
    for chunk in (1, 7, 1000):
        params = mcl.MCLParams(**{**SIM_PARAMS, "kld": mcl.KLDParams(n_min=10, n_max=3000, chunk=chunk)})
        model = mcl.prepare_mcl(grid, params)
        rng = np.random.default_rng(9)
        # the draws of a chunked run differ from the one-at-a-time loop, so compare the rule instead
        new, info = mcl.kld_mcl_step(state, np.zeros(3), z[5], ANGLES, model, rng=rng)
        bins = np.floor(new.poses / np.asarray(params.kld.bin_size)).astype(np.int64)
        _, first = np.unique(bins, axis=0, return_index=True)
        k_after = np.cumsum(np.isin(np.arange(new.poses.shape[0]), first))
        bound = mcl.kld_sample_size(k_after, params.kld.epsilon, params.kld.delta)
        n = np.arange(1, new.poses.shape[0] + 1)
        done = (n >= bound) & (n >= params.kld.n_min)
        assert done[-1] and not np.any(done[:-1]), chunk  # stops at the first draw satisfying the rule
        counts.append(info.n_particles)
    assert min(counts) > 10


# --------------------------------------------------------------------------- weights and steps
def test_weights_stay_normalised_for_huge_log_likelihoods(sim):
    grid, truth, _, z = sim
    params = mcl.MCLParams(**{**SIM_PARAMS, "likelihood_exponent": 50.0, "resample_threshold": 0.0})
    model = mcl.prepare_mcl(grid, params)
    state = mcl.mcl_initialize(model, 500, rng=np.random.default_rng(0))
    new, info = mcl.mcl_step(state, np.zeros(3), z[0], ANGLES, model, rng=np.random.default_rng(1))
    w = new.weights
    assert np.all(np.isfinite(new.log_weights[w > 0])) and abs(w.sum() - 1.0) < 1e-12
    assert 1.0 <= info.ess < 5.0 and not info.resampled
    # every particle inside a wall: zero likelihood everywhere falls back to equal weights
    walls = np.tile([0.05, 4.0, 0.0], (50, 1))
    state = mcl.mcl_initialize(model, rng=np.random.default_rng(0), poses=walls)
    new, info = mcl.mcl_step(state, np.zeros(3), z[0], ANGLES, model, rng=np.random.default_rng(1))
    np.testing.assert_allclose(new.weights, 1.0 / 50)
    assert info.log_w_avg == -np.inf


def test_steps_do_not_modify_their_arguments(sim):
    grid, _, _, z = sim
    model = mcl.prepare_mcl(grid, mcl.MCLParams(**SIM_PARAMS))
    state = mcl.mcl_initialize(model, 300, rng=np.random.default_rng(0))
    poses, lw, scan, u = state.poses.copy(), state.log_weights.copy(), z[3].copy(), np.array([0.1, 0.2, -0.1])
    for step in (mcl.mcl_step, mcl.augmented_mcl_step, mcl.kld_mcl_step):
        step(state, u, z[3], ANGLES, model, rng=np.random.default_rng(0))
        np.testing.assert_array_equal(state.poses, poses)
        np.testing.assert_array_equal(state.log_weights, lw)
        np.testing.assert_array_equal(z[3], scan)


def test_particle_summary():
    poses = np.array([[1.0, 0.0, np.pi - 0.1], [3.0, 0.0, -np.pi + 0.1]])
    mean, spread, hs = mcl.particle_summary(poses)
    np.testing.assert_allclose(mean[:2], [2.0, 0.0])
    assert abs(abs(mean[2]) - np.pi) < 1e-9 and abs(spread - 1.0) < 1e-12 and 0.09 < hs < 0.11
    mean, spread, _ = mcl.particle_summary(poses, np.log([1.0, 3.0]))
    np.testing.assert_allclose(mean[:2], [2.5, 0.0])


def test_scan_endpoints_geometry():
    pts = mcl.scan_endpoints([1.0, 2.0, np.pi / 2], [1.0, 2.0, 9.0], [0.0, -np.pi / 2, 0.0], z_max=8.0,
                             sensor_offset=0.25)
    np.testing.assert_allclose(pts, [[1.0, 3.25], [3.0, 2.25]], atol=1e-12)


# --------------------------------------------------------------------------- bad input
def test_bad_inputs_raise(sim):
    grid, _, odom, z = sim
    model = mcl.prepare_mcl(grid, mcl.MCLParams(**SIM_PARAMS))
    state = mcl.mcl_initialize(model, 10, rng=np.random.default_rng(0))
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="model"):
        mcl.MCLParams(model="sonar")
    with pytest.raises(ValueError, match="alpha"):
        mcl.MCLParams(alpha=(0.1, -0.1, 0.1, 0.1))
    with pytest.raises(ValueError, match="n_particles"):
        mcl.MCLParams(n_particles=0)
    with pytest.raises(ValueError, match="resample_threshold"):
        mcl.MCLParams(resample_threshold=1.5)
    with pytest.raises(ValueError, match="alpha_slow"):
        mcl.AugmentedParams(alpha_slow=0.5, alpha_fast=0.1)
    with pytest.raises(ValueError, match="n_max"):
        mcl.KLDParams(n_min=100, n_max=10)
    with pytest.raises(ValueError, match="delta"):
        mcl.KLDParams(delta=1.0)
    with pytest.raises(TypeError, match="grid"):
        mcl.prepare_mcl(np.zeros((10, 10)))
    with pytest.raises(TypeError, match="params"):
        mcl.prepare_mcl(grid, {"n_particles": 10})
    with pytest.raises(TypeError, match="rng"):
        mcl.mcl_step(state, np.zeros(3), z[0], ANGLES, model, rng=0)
    with pytest.raises(ValueError, match="u"):
        mcl.mcl_step(state, np.zeros(2), z[0], ANGLES, model, rng=rng)
    with pytest.raises(ValueError, match="angles"):
        mcl.mcl_step(state, np.zeros(3), z[0], ANGLES[:-1], model, rng=rng)
    with pytest.raises(ValueError, match="ranges"):
        mcl.mcl_step(state, np.zeros(3), -z[0], ANGLES, model, rng=rng)
    with pytest.raises(TypeError, match="state"):
        mcl.mcl_step(state.poses, np.zeros(3), z[0], ANGLES, model, rng=rng)
    with pytest.raises(TypeError, match="model"):
        mcl.augmented_mcl_step(state, np.zeros(3), z[0], ANGLES, grid, rng=rng)
    with pytest.raises(ValueError, match="variant"):
        mcl.run_mcl(model, odom, z, ANGLES, rng=rng, variant="fast")
    with pytest.raises(ValueError, match="ranges"):
        mcl.run_mcl(model, odom, z[:-1], ANGLES, rng=rng)
    with pytest.raises(ValueError, match="odom_poses"):
        mcl.odometry_steps(odom[:, :2])
    with pytest.raises(ValueError, match="poses"):
        mcl.scan_log_likelihood(model, np.zeros((4, 2)), z[0], ANGLES)
    with pytest.raises(ValueError, match="k"):
        mcl.kld_sample_size(-1, 0.05, 0.01)
    with pytest.raises(ValueError, match="epsilon"):
        mcl.kld_sample_size(5, 0.0, 0.01)
    with pytest.raises(TypeError, match="bool"):
        mcl.kld_sample_size(True, 0.05, 0.01)
    with pytest.raises(TypeError, match="bool"):
        mcl.kld_sample_size(np.array([True, False]), 0.05, 0.01)
    with pytest.raises(ValueError, match="integers"):
        mcl.kld_sample_size(2.5, 0.05, 0.01)
    with pytest.raises(ValueError, match="integers"):
        mcl.kld_sample_size([2, 3.5], 0.05, 0.01)
    assert mcl.kld_sample_size(np.float64(10.0), 0.05, 0.01) == mcl.kld_sample_size(10, 0.05, 0.01)
    with pytest.raises(ValueError, match="proposal"):
        mcl.AugmentedParams(proposal="gaussian")
    with pytest.raises(ValueError, match="p_min"):
        mcl.AugmentedParams(p_min=1.0)
    with pytest.raises(ValueError, match="log_weights"):
        mcl.particle_summary(np.zeros((2, 3)), [np.nan, 0.0])


# --------------------------------------------------------------------------- the CMU Wean Hall log
@pytest.fixture(scope="module")
def wean():
    """Map, log, model with the default parameters, and a reference track.

    The log has no ground truth. The reference is MCL started in a small cloud around the
    scan-matched start pose ``CMU_LOG_START``: a filter that knows where it starts. It is
    checked against the map here; the global runs are judged against it.
    """
    from slamlib.datasets import cmu

    grid, log = cmu.load_cmu_map(), cmu.load_cmu_log()
    params = mcl.MCLParams(sensor_offset=log.sensor_offset, z_max=log.max_range)
    model = mcl.prepare_mcl(grid, params)
    rng = np.random.default_rng(99)
    init = np.asarray(cmu.CMU_LOG_START) + rng.normal(size=(2000, 3)) * [0.1, 0.1, np.deg2rad(2.0)]
    ref = mcl.run_mcl(model, log.laser_pose, log.ranges, log.angles, rng=rng, init=init, times=log.laser_t,
                      variant="mcl")
    return grid, log, params, model, ref


def _fit_to_map(model, log, result, steps):
    """Per step: median distance of the scan end points to the nearest wall, and the share within 0.2 m."""
    dist = [mcl.endpoint_distances(model, result.mean[s], log.ranges[result.scan_index[s]], log.angles) for s in steps]
    return np.array([np.median(d) for d in dist]), np.array([np.mean(d < 0.2) for d in dist])


@pytest.mark.slow
def test_cmu_reference_track_matches_the_map(wean):
    grid, log, params, model, ref = wean
    assert 150 < len(ref) < log.n_scans  # scans without motion are merged
    assert grid.is_free(ref.mean[:, :2], params.free_threshold).all()
    median, near = _fit_to_map(model, log, ref, range(len(ref)))
    assert median.max() <= 0.15, median.max()
    assert near.mean() > 0.8 and near.min() > 0.5, (near.mean(), near.min())
    assert ref.spread.max() < 0.5 and np.all(ref.heading_spread < 0.5)


@pytest.mark.slow
def test_cmu_log_global_localization_converges_in_most_runs(wean):
    """From a uniform cloud, with the library defaults, the runs find the robot.

    A run that converges on a look-alike corridor also fits the map, so runs are judged by the
    reference track: right when the estimate's median distance from it over the second half of the
    log is under 0.5 m (the criterion of ``benchmarks/mcl_success.py``, which runs many seeds per log
    and prints how many succeed). Plain MCL with 10 000 particles finds the robot in about a third of
    the seeds.
    """
    grid, log, params, model, ref = wean
    right = []
    for seed in range(6):
        res = mcl.run_mcl(model, log.laser_pose, log.ranges, log.angles, rng=np.random.default_rng(seed),
                          times=log.laser_t)
        np.testing.assert_array_equal(res.scan_index, ref.scan_index)
        assert res.spread[0] > 5.0  # global: the cloud starts over the whole building
        err = np.hypot(*(res.estimate[:, :2] - ref.mean[:, :2]).T)
        half = np.arange(len(res) // 2, len(res))
        if not np.median(err[half]) < 0.5:
            continue
        right.append(seed)
        # a run in the right place sits in free space and fits the map at the end of the log
        assert grid.is_free(res.estimate[half, :2], params.free_threshold).mean() > 0.95
        median, near = _fit_to_map(model, log, res, half[-20:])
        assert np.median(median) <= 0.15 and near.mean() > 0.7, (seed, np.median(median), near.mean())
    assert len(right) >= 4, f"only seeds {right} of 0-5 localized the robot"


@pytest.mark.slow
def test_cmu_run_settled_in_the_wrong_corridor_recovers(wean):
    """A global run of plain MCL that has settled far from the robot is abandoned by the default filter.

    Seed 1 of plain MCL (Table 8.2) from a uniform cloud, with the sharper tempering tau = 0.2 that
    settles sooner, sits 18.8 m from the reference after 40 updates with a spread of 0.24 m: sure and
    wrong. Such runs are a minority (of seeds 0-49, five end more than 10 m off with a spread under
    0.5 m: 0, 1, 5, 19 and 36), so the seed is fixed: the test needs one of them. Continued from that
    particle set, plain MCL stays wrong; the default filter (sensor resetting) leaves the wrong place
    and ends near the reference.
    """
    grid, log, params, model, ref = wean
    s0 = 39
    table_8_2 = mcl.prepare_mcl(grid, mcl.MCLParams(sensor_offset=log.sensor_offset, z_max=log.max_range,
                                                    init_candidates=0, estimate_radius=0.0,
                                                    likelihood_exponent=0.2))  # uniform start, settles sooner
    lost = mcl.run_mcl(table_8_2, log.laser_pose, log.ranges, log.angles, rng=np.random.default_rng(1), times=log.laser_t,
                       variant="mcl", max_steps=s0 + 1, snapshots=[s0])
    err0 = np.hypot(*(lost.estimate[s0, :2] - ref.mean[s0, :2]))
    assert err0 > 10.0 and lost.spread[s0] < 0.5, (err0, lost.spread[s0])
    start = ref.scan_index[s0]
    err = {}
    for variant in ("mcl", "augmented"):
        res = mcl.run_mcl(model, log.laser_pose[start:], log.ranges[start:], log.angles, rng=np.random.default_rng(2),
                          init=lost.snapshots[0], times=log.laser_t[start:], variant=variant)
        j = np.searchsorted(ref.scan_index, res.scan_index + start)
        np.testing.assert_array_equal(ref.scan_index[j], res.scan_index + start)
        err[variant] = np.hypot(*(res.estimate[:, :2] - ref.mean[j, :2]).T)
    last = slice(-30, None)  # the last 30 updates (about 20 s)
    assert np.median(err["mcl"][last]) > 2.0 and err["mcl"][-1] > 2.0, err["mcl"][last]
    # the default leaves the wrong place; on this short log it is back near the track at the end
    # (1.0 m here, not yet within 0.5 m: on the 240 s log 2 every one of 20 global runs ends within 0.5 m)
    assert err["augmented"][-1] < 1.5 and err["augmented"][-1] < 0.1 * err0, err["augmented"][last]


# --------------------------------------------------------------------------- recovery: the injected component
def test_log_space_averages_follow_table_8_3():
    """w_slow, w_fast kept in log space equal Table 8.3's recursion on the plain numbers."""
    aug = mcl.AugmentedParams(alpha_slow=0.05, alpha_fast=0.5)
    w_avg = np.exp(np.random.default_rng(0).normal(-3.0, 1.0, 30))
    state = mcl.MCLState(np.zeros((1, 3)), np.zeros(1))
    slow = fast = None
    for w in w_avg:
        ls, lf = mcl._averages(state, np.log(w), aug)
        slow = w if slow is None else slow + 0.05 * (w - slow)
        fast = w if fast is None else fast + 0.5 * (w - fast)
        np.testing.assert_allclose([np.exp(ls), np.exp(lf)], [slow, fast], rtol=1e-12)
        state = mcl.MCLState(np.zeros((1, 3)), np.zeros(1), log_w_slow=ls, log_w_fast=lf)
    # no underflow where the plain numbers would be exp(-800) = 0
    ls, lf = mcl._averages(mcl.MCLState(np.zeros((1, 3)), np.zeros(1), -800.0, -800.0), -810.0, aug)
    assert np.isfinite(ls) and lf < ls < -800.0
    assert mcl._injection_probability(ls, lf) == pytest.approx(1 - np.exp(lf - ls))


def test_averages_can_start_at_zero_as_table_8_3_prints():
    aug = mcl.AugmentedParams(alpha_slow=0.05, alpha_fast=0.5, average_start="zero")
    state = mcl.MCLState(np.zeros((1, 3)), np.zeros(1))
    slow = fast = 0.0
    for w in (0.3, 0.2, 0.25, 0.01):
        ls, lf = mcl._averages(state, np.log(w), aug)
        slow, fast = slow + 0.05 * (w - slow), fast + 0.5 * (w - fast)
        np.testing.assert_allclose([np.exp(ls), np.exp(lf)], [slow, fast], rtol=1e-12)
        state = mcl.MCLState(np.zeros((1, 3)), np.zeros(1), log_w_slow=ls, log_w_fast=lf)
    # w_slow lags w_fast at the start: no injection until the fit drops
    assert mcl._injection_probability(*mcl._averages(mcl.MCLState(np.zeros((1, 3)), np.zeros(1)), np.log(0.3), aug)) == 0
    with pytest.raises(ValueError, match="average_start"):
        mcl.AugmentedParams(average_start="one")


def test_injected_fraction_is_bayes_rule_for_the_mixture_prior():
    # p Z_U / (p Z_U + (1 - p) w_avg)
    for p, w_avg, z_u in ((0.01, 1e-2, 1e-3), (0.3, 1e-5, 1e-3), (0.5, 1.0, 1.0)):
        expected = p * z_u / (p * z_u + (1 - p) * w_avg)
        assert mcl._injected_fraction(p, np.log(w_avg), np.log(z_u)) == pytest.approx(expected, rel=1e-12)
    assert mcl._injected_fraction(0.0, 0.0, 0.0) == 0.0
    assert mcl._injected_fraction(0.1, -np.inf, 0.0) == 1.0  # no particle explains the scan


def test_sensor_proposal_puts_new_particles_where_the_scan_fits(sim):
    """Z_U is the mean tempered likelihood over the free space, and the draws favour the true pose."""
    grid, truth, _, z = sim
    model = mcl.prepare_mcl(grid, mcl.MCLParams(**{**SIM_PARAMS, "augmented": mcl.AugmentedParams(candidates=20_000)}))
    zz, aa = mcl._subsample(z[20], ANGLES, model.params)
    cand, log_q, log_z = mcl._sensor_component(model, zz, aa, np.random.default_rng(3))
    tll = model.params.likelihood_exponent * mcl.scan_log_likelihood(model, cand, z[20], ANGLES)
    assert log_z == pytest.approx(np.log(np.mean(np.exp(tll))), rel=1e-12)
    np.testing.assert_allclose(np.exp(log_q).sum(), 1.0)
    near = np.hypot(*(cand[:, :2] - truth[20, :2]).T) < 0.5
    near &= np.abs(sl.angle_diff(cand[:, 2], truth[20, 2])) < 0.3
    share_uniform = near.mean()
    share_drawn = np.exp(log_q)[near].sum()
    assert share_drawn > 20 * share_uniform, (share_drawn, share_uniform)
    # the true pose explains the scan far better than a random pose: Z_U << p(z | x_true)^tau
    at_truth = model.params.likelihood_exponent * mcl.scan_log_likelihood(model, truth[20][None], z[20], ANGLES)[0]
    assert at_truth > log_z + 3.0


def test_augmented_step_keeps_weights_when_it_injects_without_resampling(sim):
    grid, truth, _, z = sim
    aug = mcl.AugmentedParams(p_min=0.5, candidates=2000)
    model = mcl.prepare_mcl(grid, mcl.MCLParams(**{**SIM_PARAMS, "resample_threshold": 0.0, "augmented": aug}))
    rng = np.random.default_rng(4)
    wrong = mcl.mcl_initialize(model, rng=rng, poses=np.tile([10.5, 6.5, 0.0], (500, 1)) + rng.normal(0, 0.05, (500, 3)))
    new, info = mcl.augmented_mcl_step(wrong, np.zeros(3), z[20], ANGLES, model, rng=rng)
    assert not info.resampled and info.n_injected > 0
    np.testing.assert_allclose(np.exp(logsumexp(new.log_weights)), 1.0)
    moved = np.any(new.poses != wrong.poses, axis=1)
    assert np.count_nonzero(moved) == info.n_injected
    # the belief is wrong: the new particles, near where the scan fits, take most of the weight
    assert new.weights[moved].sum() > 0.5
    # a belief at the true pose keeps nearly all of it
    right = mcl.mcl_initialize(model, rng=rng, poses=truth[20] + rng.normal(0, 0.05, (500, 3)))
    new, info = mcl.augmented_mcl_step(right, np.zeros(3), z[20], ANGLES, model, rng=rng)
    assert info.n_injected < 0.05 * 500


def test_estimate_is_the_heaviest_cluster():
    rng = np.random.default_rng(5)
    a = np.array([2.0, 3.0, 0.5]) + rng.normal(0, 0.1, (600, 3))
    b = np.array([14.0, 3.0, -2.0]) + rng.normal(0, 0.1, (400, 3))
    poses = np.vstack([a, b])
    lw = np.full(1000, -np.log(1000))
    mean, _, _, est, mass, n_modes = mcl._summary(poses, lw)[:6]
    assert abs(mean[0] - 6.8) < 0.2  # the mean lies between the clusters
    np.testing.assert_allclose(est[:2], a[:, :2].mean(axis=0), atol=1e-9)
    assert abs(sl.angle_diff(est[2], 0.5)) < 0.05
    # the estimate reports its ambiguity: the heaviest mode holds 60 %, and there are two modes
    assert mass == pytest.approx(0.6) and n_modes == 2
    # weight, not the number of particles, decides
    lw2 = np.log(np.r_[np.full(600, 0.2 / 600), np.full(400, 0.8 / 400)])
    est2, mass2 = mcl._summary(poses, lw2)[3:5]
    np.testing.assert_allclose(est2[:2], b[:, :2].mean(axis=0), atol=1e-9)
    assert mass2 == pytest.approx(0.8)


def test_particle_modes_lists_every_mode_with_its_mass():
    rng = np.random.default_rng(2)
    centres = np.array([[2.0, 3.0, 0.5], [14.0, 3.0, -2.0], [8.0, 9.0, 1.0]])
    poses = np.vstack([c + rng.normal(0, 0.1, (n, 3)) for c, n in zip(centres, (500, 300, 200))])
    got, mass = sl.particle_modes(poses)
    np.testing.assert_allclose(mass, [0.5, 0.3, 0.2])
    np.testing.assert_allclose(got[:, :2], centres[:, :2], atol=0.02)
    got, mass = sl.particle_modes(poses, np.log(np.r_[np.full(500, 0.1 / 500), np.full(300, 0.895 / 300),
                                                      np.full(200, 0.005 / 200)]))
    np.testing.assert_allclose(mass, [0.895, 0.1])  # the third, under 1 %, is not a mode
    assert sl.particle_modes(poses, max_modes=1)[1].shape == (1,)
    with pytest.raises(ValueError, match="max_modes"):
        sl.particle_modes(poses, max_modes=0)


def test_a_uniform_cloud_is_not_a_confident_mode(sim):
    grid, *_ = sim
    poses = sl.sample_free_poses(grid, 5000, rng=np.random.default_rng(0))
    _, _, _, _, mass, n_modes = mcl._summary(poses, np.full(5000, -np.log(5000)))[:6]
    assert mass < 0.2 and n_modes == 8  # spread over the map: no mode holds much


def test_estimate_hysteresis_keeps_the_previous_mode_until_another_clearly_wins():
    rng = np.random.default_rng(5)
    a = np.array([2.0, 3.0, 0.5]) + rng.normal(0, 0.1, (500, 3))
    b = np.array([14.0, 3.0, -2.0]) + rng.normal(0, 0.1, (500, 3))
    poses = np.vstack([a, b])
    for share_b, h, expect in ((0.6, 1.0, b), (0.6, 2.0, a), (0.7, 2.0, b)):
        lw = np.log(np.r_[np.full(500, (1 - share_b) / 500), np.full(500, share_b / 500)])
        est = mcl._summary(poses, lw, previous=np.array([2.0, 3.0, 0.5]), hysteresis=h)[3]
        np.testing.assert_allclose(est[:2], expect[:, :2].mean(axis=0), atol=1e-9)
    with pytest.raises(ValueError, match="estimate_hysteresis"):
        mcl.MCLParams(estimate_hysteresis=0.5)


def test_run_mcl_reports_its_ambiguity(sim, global_run):
    _, truth, _, _ = sim
    res = global_run
    mass, n_modes = res.ambiguity()
    assert mass.shape == n_modes.shape == (len(res),)
    # the start: spread over several modes (over 50 worlds and seeds, 8 modes, the heaviest with 0.10-0.51)
    assert mass[0] < 0.9 and n_modes[0] > 1
    # converged on the truth: one mode (mass 1.0 in all 50). The mass is the particles' belief, not a calibrated
    # probability: a run can also be sure of a look-alike for a while (updates 3-20 of one of 13 seeds checked)
    # until sensor resetting brings the right place back
    assert mass[-1] > 0.95 and n_modes[-1] == 1
    assert np.hypot(*(res.estimate[-1, :2] - truth[res.scan_index[-1], :2])) < 0.3


# --------------------------------------------------------------------------- mode-preserving resampling
def _two_modes(rng, m_heavy=900, m_light=100, light=1e-5):
    poses = np.r_[rng.normal([0.0, 0.0, 0.0], 0.2, (m_heavy, 3)), rng.normal([20.0, 5.0, 1.0], 0.2, (m_light, 3))]
    w = np.r_[rng.uniform(0.5, 1.5, m_heavy), light * rng.uniform(0.5, 1.5, m_light)]
    return poses, w / w.sum()


def test_mode_preserving_resampling_with_one_mode_is_low_variance_resampling():
    rng = np.random.default_rng(3)
    poses = rng.normal([5.0, 5.0, 0.0], 0.3, (500, 3))
    w = rng.uniform(0.1, 1.0, 500)
    w /= w.sum()
    idx, log_w = mcl._mode_preserving_resample(poses, w, np.random.default_rng(7), 100, 1e-6)
    r = np.random.default_rng(7).uniform(0.0, 1.0 / 500)
    np.testing.assert_array_equal(idx, sl.particle._low_variance_indices(w, r, w.size))
    np.testing.assert_allclose(log_w, -np.log(500))


def test_mode_preserving_resampling_keeps_a_light_mode_with_its_mass():
    poses, w = _two_modes(np.random.default_rng(4))
    light = w[900:].sum()
    plain = sl.low_variance_resample(w, rng=np.random.default_rng(0))
    assert not np.any(plain >= 900)  # plain resampling drops the light mode
    idx, log_w = mcl._mode_preserving_resample(poses, w, np.random.default_rng(0), 50, 1e-8)
    assert idx.shape == (1000,) and np.sum(idx >= 900) == 50
    wn = np.exp(log_w)
    np.testing.assert_allclose(wn.sum(), 1.0)
    np.testing.assert_allclose(wn[idx >= 900].sum(), light, rtol=1e-12)  # the mode keeps its mass exactly
    np.testing.assert_allclose(wn[idx >= 900], light / 50, rtol=1e-12)  # shared equally
    # a mode whose mass is below the floor is resampled as usual (here: dropped)
    idx2, log_w2 = mcl._mode_preserving_resample(poses, w, np.random.default_rng(0), 50, 1e-3)
    assert not np.any(idx2 >= 900)
    np.testing.assert_allclose(log_w2, -np.log(1000))


def test_mode_preserving_resampling_is_unbiased():
    """The expected weight each particle receives equals its weight (what makes it a resampler)."""
    rng = np.random.default_rng(5)
    poses, w = _two_modes(rng, 300, 60, light=1e-3)
    poses = np.r_[poses, rng.normal([-15.0, 3.0, 0.0], 0.2, (40, 3))]  # a third mode
    w = np.r_[w, np.full(40, 2e-4)]
    w /= w.sum()
    total = np.zeros(w.size)
    n = 2000
    for _ in range(n):
        idx, log_w = mcl._mode_preserving_resample(poses, w, rng, 20, 1e-6)
        np.add.at(total, idx, np.exp(log_w))
    np.testing.assert_allclose(total / n, w, atol=4 * np.sqrt(w.max() / 20 / n) + 1e-6)


def test_mode_preserving_resampling_caps_the_minimum_shares_at_half_the_set():
    rng = np.random.default_rng(6)
    centres = np.column_stack([np.arange(30) * 10.0, np.zeros(30), np.zeros(30)])  # 30 separate modes
    poses = np.repeat(centres, 20, axis=0) + rng.normal(0.0, 0.1, (600, 3))
    w = np.repeat(np.geomspace(1.0, 1e-3, 30), 20)
    w /= w.sum()
    idx, log_w = mcl._mode_preserving_resample(poses, w, rng, 50, 1e-9)
    kept = np.unique(idx // 20)
    assert kept.size == 600 // (2 * 50)  # the six heaviest modes, with at least 50 particles each
    np.testing.assert_array_equal(kept, np.arange(6))
    assert np.all(np.bincount(idx // 20, minlength=6)[:6] >= 50)
    np.testing.assert_allclose(np.exp(log_w).sum(), 1.0)


def test_mode_particles_is_checked():
    with pytest.raises(ValueError, match="mode_particles"):
        mcl.MCLParams(mode_particles=-1)
    with pytest.raises(ValueError, match="mode_floor"):
        mcl.MCLParams(mode_floor=1.5)


@pytest.mark.slow
def test_wean_log_2_the_right_mode_survives_scans_that_favour_a_look_alike():
    """On Wean Hall log 2, ten scans in a row fit a look-alike place 13 m away better than the right one.

    With the sharper tempering tau = 0.2 (the default 0.1 keeps thousands of particles at the right
    place through this stretch even with plain resampling), the filter starts in the right place (a small cloud around the reference track of
    ``benchmarks/mcl_success.py`` at update 290, scan 1475). Over updates 300-311 the scans fit the
    map worse there than at a look-alike place that sensor resetting brings in. Plain resampling then
    leaves the right place with a handful of particles or none; mode-preserving resampling (the
    default) keeps its 100, and the filter is back on the reference track at update 350 (scan 1766).
    The poses are the reference track's.
    """
    from slamlib.datasets import cmu

    grid, log = cmu.load_cmu_map(), cmu.load_cmu_log(log=2)
    a, b = 1475, 1766
    start = np.array([48.308, 39.083, -0.024])
    checks = {18: (52.105, 38.580), 20: (52.509, 38.511), 22: (52.902, 38.582)}  # update - 290: reference position
    end = np.array([55.322, 38.971])
    near = {}
    for mp in (0, 100):
        model = mcl.prepare_mcl(grid, mcl.MCLParams(sensor_offset=log.sensor_offset, z_max=log.max_range,
                                                    mode_particles=mp, likelihood_exponent=0.2))
        rng = np.random.default_rng(0)
        init = start + rng.normal(size=(10_000, 3)) * [0.1, 0.1, 0.03]
        res = mcl.run_mcl(model, log.laser_pose[a:b + 1], log.ranges[a:b + 1], log.angles, rng=rng, init=init,
                          snapshots=list(checks))
        assert res.scan_index[-1] == b - a and len(res) == 61  # the same updates as the reference
        near[mp] = [int(np.sum(np.hypot(*(snap.poses[:, :2] - checks[k]).T) < 1.0))
                    for k, snap in zip(res.snapshot_steps, res.snapshots)]
        if mp:
            assert np.hypot(*(res.estimate[-1, :2] - end)) < 0.5, res.estimate[-1]
    assert min(near[100]) >= 100, near
    assert min(near[0]) < 20, near


# --------------------------------------------------------------------------- the study harness (benchmarks/mcl_study.py)
def _study_module():
    import importlib.util
    from pathlib import Path

    bench = Path(__file__).resolve().parents[1] / "benchmarks"
    import sys

    sys.path.insert(0, str(bench))
    if "mcl_study" in sys.modules:
        return sys.modules["mcl_study"]
    spec = importlib.util.spec_from_file_location("mcl_study", bench / "mcl_study.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["mcl_study"] = mod  # the study's process pool pickles its functions by module name
    spec.loader.exec_module(mod)
    return mod


def test_study_wilson_interval_matches_known_values():
    study = _study_module()
    np.testing.assert_allclose(study.wilson(5, 10), (0.2366, 0.7634), atol=1e-4)
    np.testing.assert_allclose(study.wilson(0, 10), (0.0, 0.2775), atol=1e-4)
    np.testing.assert_allclose(study.wilson(20, 20), (0.8389, 1.0), atol=1e-4)


def _study_world():
    """The study's module, the Wean Hall map, the study's parameters, likelihood field and roadmap, 180 beams."""
    from slamlib.datasets import cmu

    study = _study_module()
    grid = cmu.load_cmu_map()
    params = study.make_params({})
    field = sl.likelihood_field(grid, max_dist=params.max_dist, threshold=params.occupied_threshold)
    roadmap = study._roadmap(grid, field, params.free_threshold)
    return study, grid, params, field, roadmap, np.linspace(-np.pi / 2, np.pi / 2, 180, endpoint=False)


def test_study_simulated_trial_is_collision_free_and_noisy_as_the_models_say():
    from slamlib.datasets import cmu

    study, grid, params, field, roadmap, angles = _study_world()
    trial = study.simulate_trial(grid, field, roadmap, params, angles, 40, np.random.default_rng(0))
    truth = trial["truth"]
    assert truth.shape == (40, 3) and trial["ranges"].shape == (40, 180)
    assert grid.is_free(truth[:, :2], params.free_threshold).all() and field.distance_at(truth[:, :2]).min() >= 0.25
    step = np.hypot(*np.diff(truth[:, :2], axis=0).T)
    np.testing.assert_allclose(step, study.SIM_STEP, atol=0.02)
    # odometry: the true increments plus the motion model's noise (not the truth itself, not far from it)
    u_true = sl.odometry_from_poses(truth[:-1], truth[1:])
    u_odom = sl.odometry_from_poses(trial["odom"][:-1], trial["odom"][1:])
    d_trans = u_odom[:, 1] - u_true[:, 1]
    assert 0 < np.std(d_trans) < 3 * np.sqrt(params.alpha[2]) * study.SIM_STEP
    # scans: most beams within 3 sigma_hit of the beam model's expected range, the ray-cast one moved
    # range_bias beyond the map's faces (where the robot's laser sees the walls)
    assert params.range_bias == cmu.CMU_RANGE_BIAS > 0
    z_star = sl.ray_cast(grid, truth, angles, params.z_max, sensor_offset=params.sensor_offset,
                         threshold=params.occupied_threshold)
    hit = np.abs(trial["ranges"] - (z_star + params.range_bias)) < 3 * params.sigma_hit
    assert 0.8 < hit.mean() < 0.97
    near = np.abs(trial["ranges"] - z_star) < 1.0
    assert abs(np.median((trial["ranges"] - z_star)[near]) - params.range_bias) < 0.05


def test_the_studies_simulate_with_the_calibrations_both_logs_measure():
    # cmu.CMU_RANGE_BIAS is the measured median range excess (measured minus ray-cast range at the reference
    # tracks), and the simulator draws the odometry error with SIM_ODOMETRY_STD of the motion model's standard
    # deviation, at least what both logs measure; both study files record the measurements and the values used
    import json
    from pathlib import Path

    from slamlib.datasets import cmu

    study = _study_module()
    data = Path(__file__).resolve().parents[1] / "chapters" / "data"
    for name in ("mcl_study.json", "mcl_study_long.json"):
        settings = json.loads((data / name).read_text())["settings"]
        checks = settings["model_checks"]
        assert settings["range_bias"] == cmu.CMU_RANGE_BIAS
        excess = checks["log_range_excess"]
        assert sorted(excess) == ["1", "2"]
        # each log's measurement agrees with the other's, and with the constant, to 0.03 m
        assert abs(excess["1"] - excess["2"]) < 0.03
        assert all(abs(v - cmu.CMU_RANGE_BIAS) < 0.03 for v in excess.values())
        assert settings["sim_odometry_std"] == study.SIM_ODOMETRY_STD
        ratios = checks["odometry_error_ratio"]
        assert sorted(ratios) == ["1", "2"]
        assert all(0.1 < v <= study.SIM_ODOMETRY_STD for r in ratios.values() for v in r.values())


@pytest.mark.parametrize("scale", [1.0, 1 / 3])
def test_study_odometry_error_ratio_recovers_the_noise_it_was_drawn_with(scale):
    # odometry drawn from the motion model with alpha * scale**2 around a known track: the ratio is ~scale
    study = _study_module()
    rng = np.random.default_rng(3)
    alpha = np.array(sl.MCLParams().alpha)
    n = 4000
    truth = np.zeros((n, 3))
    for k in range(1, n):  # a wandering track, 0.2 m per update, turning now and then
        truth[k] = sl.odometry_motion(truth[k - 1], [rng.normal(0, 0.2), rng.uniform(0.1, 0.3), rng.normal(0, 0.2)])
    u = sl.odometry_from_poses(truth[:-1], truth[1:])
    odom = np.zeros_like(truth)
    for k in range(1, n):
        odom[k] = sl.sample_motion_model_odometry(odom[k - 1], u[k - 1], alpha * scale**2, rng=rng)

    class Log:
        laser_pose = odom

    class Ref:
        scan_index = np.arange(n)
        mean = truth

    got = study.odometry_error_ratio(Log, Ref, alpha)
    assert set(got) == {"translation", "heading"}
    np.testing.assert_allclose([got["translation"], got["heading"]], scale, rtol=0.1)


def test_study_simulator_draws_hits_around_the_biased_range():
    # no noise but the hit term, and a tiny sigma: the simulated ranges are the ray-cast ones plus the bias
    from slamlib.datasets import cmu

    study = _study_module()
    grid = cmu.load_cmu_map()
    field = sl.likelihood_field(grid, max_dist=2.0, threshold=0.9)
    angles = np.linspace(-np.pi / 2, np.pi / 2, 36)
    for bias in (0.0, 0.3):
        params = study.make_params({"w_short": 0.0, "w_max": 0.0, "w_rand": 0.0, "sigma_hit": 1e-6,
                                    "range_bias": bias})
        roadmap = study._roadmap(grid, field, params.free_threshold)
        trial = study.simulate_trial(grid, field, roadmap, params, angles, 5, np.random.default_rng(1))
        z_star = sl.ray_cast(grid, trial["truth"], angles, params.z_max, sensor_offset=params.sensor_offset,
                             threshold=params.occupied_threshold)
        np.testing.assert_allclose(trial["ranges"], np.minimum(z_star + bias, params.z_max), atol=1e-4)


def test_range_bias_moves_the_beam_models_expected_range_and_leaves_the_field_alone():
    # MCLParams.range_bias: the beam model's z* is the ray-cast range plus the bias (max-range beams stay
    # at z_max); the likelihood field ignores it
    occ = np.zeros((60, 60))
    occ[:, 50:] = 1.0  # a wall at x = 5 m
    grid = sl.OccupancyGrid(occ, 0.1)
    angles = np.array([-3.0, 0.0, 0.2])  # the first beam looks away from the wall: max range
    poses = np.array([[2.0, 3.0, 0.0], [2.5, 3.0, 0.1]])
    ranges = np.array([10.0, 3.2, 3.1])
    kw = dict(z_max=10.0, sensor_offset=0.0, beam_step=1, ray_cache_angles=0)
    for bias in (0.0, 0.25, -0.1):
        model = sl.prepare_mcl(grid, sl.MCLParams(model="beam", range_bias=bias, **kw))
        p = model.params
        z_star = sl.ray_cast(grid, poses, angles, p.z_max, threshold=p.occupied_threshold)
        assert z_star[0, 0] == p.z_max
        expected = np.where(z_star < p.z_max, z_star + bias, z_star)
        # summed over the beams, per pose
        want = sl.beam_range_finder_log_likelihood(ranges, expected, z_max=p.z_max, sigma_hit=p.sigma_hit,
                                                   lambda_short=p.lambda_short, w_hit=p.w_hit, w_short=p.w_short,
                                                   w_max=p.w_max, w_rand=p.w_rand)
        np.testing.assert_allclose(sl.scan_log_likelihood(model, poses, ranges, angles), want)
    field = [sl.scan_log_likelihood(sl.prepare_mcl(grid, sl.MCLParams(range_bias=b, **kw)), poses, ranges, angles)
             for b in (0.0, 0.25)]
    np.testing.assert_array_equal(field[0], field[1])
    # the bias is a model parameter: it changes the beam model's answer
    a, b = (sl.scan_log_likelihood(sl.prepare_mcl(grid, sl.MCLParams(model="beam", range_bias=v, **kw)),
                                   poses, ranges, angles) for v in (0.0, 0.25))
    assert not np.allclose(a, b)


@pytest.mark.parametrize("value", [np.nan, np.inf, "0.2", None])
def test_range_bias_refuses_what_is_not_a_finite_number(value):
    with pytest.raises((TypeError, ValueError), match="range_bias"):
        sl.MCLParams(range_bias=value)


def test_study_truth_between_updates_follows_the_odometry():
    study = _study_module()

    class Ref:
        scan_index = np.array([0, 3])
        mean = np.array([[1.0, 2.0, 0.5], [5.0, 5.0, 1.0]])

    odom = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.2, 0.0, 0.1], [0.3, 0.0, 0.1], [0.5, 0.0, 0.1]])
    got = study.truth_at(Ref, odom, np.array([0, 2, 3, 4]))
    np.testing.assert_allclose(got[0], Ref.mean[0])
    np.testing.assert_allclose(got[2], Ref.mean[1])
    np.testing.assert_allclose(got[1], sl.odometry_motion(Ref.mean[0], sl.odometry_from_poses(odom[0], odom[2])))
    np.testing.assert_allclose(got[3], sl.odometry_motion(Ref.mean[1], sl.odometry_from_poses(odom[3], odom[4])))


def _alias_drive(n_updates=40, seed=3):
    import dataclasses

    study, grid, params, field, roadmap, angles = _study_world()
    exact = dataclasses.replace(params, alpha=(0.0, 0.0, 0.0, 0.0))  # odometry = the true motion
    trial = study.simulate_trial(grid, field, roadmap, exact, angles, n_updates, np.random.default_rng(seed))
    return study, sl.prepare_mcl(grid, params), trial, angles


def test_study_alias_evidence_weighs_the_wrong_track_against_the_truth():
    # alias_evidence: the final estimate carried back through the odometry, against the truth, summed tempered
    # log-likelihood ratio of the scans at each track's best fit nearby: about 0 for a run that ends at the truth
    # (alias_null, the measure's own spread), clearly negative for a place the scans do not fit (the simulator's
    # map is the filter's); the verdict counts only what lies beyond the spread
    study, model, trial, angles = _alias_drive()
    truth, odom = trial["truth"], trial["odom"]
    idx = np.arange(len(truth))
    null = study.alias_null(model, odom, trial["ranges"], angles, len(truth), lambda i: truth[i])
    assert null == study.alias_evidence(model, odom, trial["ranges"], angles, idx, truth[-1], truth)
    assert abs(null) < 1.0
    e = study.alias_evidence(model, odom, trial["ranges"], angles, idx, truth[-1] + [0.0, 0.0, np.pi], truth)
    assert np.isfinite(e) and e < -1.0  # the last pose turned around
    band = abs(null)
    assert study.alias_verdict(e, band) == "truth" and study.alias_verdict(-e, band) == "wrong place"
    assert study.alias_verdict(band / 2, band) == study.alias_verdict(-band, band) == "tie"
    assert study.alias_verdict(None, band) is None


def test_study_alias_track_follows_the_scans_through_the_odometrys_drift():
    # carried back through an odometry that turns 0.3 degrees too far at every update, the track drifts a metre off
    # over 40 updates; kept on the scans (within ALIAS_STEP per update), it stays near the true track
    study, model, trial, angles = _alias_drive()
    truth = trial["truth"]
    u = sl.odometry_from_poses(truth[:-1], truth[1:])
    u[:, 0] += np.deg2rad(0.3)
    odom = np.array([truth[0]] * len(truth))
    for t in range(1, len(truth)):
        odom[t] = sl.odometry_motion(odom[t - 1], u[t - 1])
    idx = np.arange(len(truth))
    carried = sl.odometry_motion(np.repeat(truth[-1][None], len(idx), 0),
                                 sl.odometry_from_poses(np.repeat(odom[-1][None], len(idx), 0), odom))
    kept = study.alias_track(model, odom, trial["ranges"], angles, idx, truth[-1])
    assert np.hypot(*(carried[:, :2] - truth[:, :2]).T).max() > 0.8  # the odometry alone drifts off
    assert np.hypot(*(kept[:, :2] - truth[:, :2]).T).max() < 0.5
    np.testing.assert_allclose(kept[-1], truth[-1])


def test_study_weighs_every_configuration_by_the_defaults_sensor_model():
    # alias_evidence is on one scale for every configuration (the one its band is measured on): the defaults'
    # sensor model and exponent, with the run's laser constants
    study, grid, *_ = _study_world()
    study._WORK.setdefault("grid", grid)
    for over in ({"likelihood_exponent": 0.2}, {"model": "beam"}, {"beam_skip_share": 0.05}):
        params = study.make_params(over, 0.3, 50.0)
        assert study._yardstick(params).params == study.make_params({}, 0.3, 50.0) != params


@pytest.mark.slow
def test_study_ceilings_start_at_the_truth_and_are_never_chosen(tmp_path):
    # the ceiling (the defaults started around the true pose) is run like a configuration, but it is an
    # oracle: it is not screened as a mechanism and cross-validation never picks it, even where it wins
    import json

    study = _study_module()
    out = tmp_path / "study.json"
    study.main(["--sim-trials", "3", "--offsets", "1", "--updates", "8", "--screen-sim", "3", "--screen-offsets", "1",
                "--configs", "defaults", *study.TRUTH_STARTS, "--screen", "all", "--cache", str(tmp_path / "runs"),
                "--json", str(out)])
    d = json.loads(out.read_text())
    assert study.TRUTH_START in study.TRUTH_STARTS and study.BEAM_SKIP_TRUTH in study.TRUTH_STARTS
    for oracle in study.TRUTH_STARTS:
        assert oracle in d["table"] and oracle not in d["screen"]
        assert all(cv["chosen"] != oracle for cv in d["cross_validation"].values())
        started = [r for r in d["runs"] if r["config"] == oracle]
        assert len(started) == 5 and all(r["final_error"] < 0.5 for r in started)  # started at the truth, it stays
    # a run that ends on a wrong place is weighed against the truth, and the tables count both
    assert all((r["alias_evidence"] is None) == (r["final_error"] <= study.RADIUS) for r in d["runs"])
    for c, sets in d["table"].items():
        for s, t in sets.items():
            runs = [r for r in d["runs"] if r["config"] == c and r["set"] == s]
            assert t["wrong_at_end"] == sum(r["final_error"] > study.RADIUS for r in runs)
            band = d["settings"]["model_checks"]["alias_band"][s]
            assert band == max(abs(v) for v in d["settings"]["model_checks"]["alias_null"][s])
            assert t["alias_wrong_place"] == sum(r["alias_evidence"] is not None and r["alias_evidence"] > band
                                                 for r in runs)
            assert t["wrong_at_end"] == t["alias_wrong_place"] + t["alias_tie"] + t["alias_truth"]
    assert "plain MCL" in d["screen"] and study.BEAM_SKIP in d["screen"]  # the mechanism is screened
    assert d["table"][study.TRUTH_START]["sim"]["strict"] > d["table"]["defaults"]["sim"]["strict"]


# --------------------------------------------------------------------------- scan-guided start, estimate, confidence
def _near(poses, pose, r=0.5, dth=np.deg2rad(15.0)):
    return (np.hypot(*(poses[:, :2] - pose[:2]).T) < r) & (np.abs(sl.angle_diff(poses[:, 2], pose[2])) < dth)


def test_scan_guided_start_puts_many_more_particles_near_the_truth(sim):
    grid, truth, _, z = sim
    params = mcl.MCLParams(**{**SIM_PARAMS, "n_particles": 500, "init_candidates": 50_000})
    model = mcl.prepare_mcl(grid, params)
    guided = mcl.mcl_initialize(model, rng=np.random.default_rng(0), scan=(z[0], ANGLES))
    uniform = mcl.mcl_initialize(model, rng=np.random.default_rng(0))
    assert guided.poses.shape == (500, 3)
    assert _near(guided.poses, truth[0]).sum() >= 10 * max(_near(uniform.poses, truth[0]).sum(), 1)
    # without candidates the scan is ignored: the uniform start
    off = mcl.prepare_mcl(grid, mcl.MCLParams(**{**SIM_PARAMS, "n_particles": 500, "init_candidates": 0}))
    again = mcl.mcl_initialize(off, rng=np.random.default_rng(0), scan=(z[0], ANGLES))
    np.testing.assert_array_equal(again.poses, uniform.poses)


def test_scan_guided_start_is_an_importance_sample_of_the_uniform_prior(sim):
    """The start's weights undo its proposal: the first update with the same scan leaves equal weights."""
    grid, _, _, z = sim
    params = mcl.MCLParams(**{**SIM_PARAMS, "n_particles": 400, "init_candidates": 20_000, "resample_threshold": 0.0})
    model = mcl.prepare_mcl(grid, params)
    state = mcl.mcl_initialize(model, rng=np.random.default_rng(1), scan=(z[0], ANGLES))
    assert np.ptp(state.log_weights) > 1.0  # importance weights, not equal
    after, info = mcl.mcl_step(state, np.zeros(3), z[0], ANGLES, model, rng=np.random.default_rng(2))
    np.testing.assert_allclose(after.log_weights, -np.log(400), atol=1e-9)
    assert info.ess == pytest.approx(400.0)


def test_confidence_is_the_mass_within_half_a_metre_of_the_estimate():
    rng = np.random.default_rng(0)
    # one mode stretched along 2.8 m of corridor: it holds all the mass, but little of it is near any one point
    line = np.column_stack([rng.uniform(0.0, 2.8, 2000), rng.normal(0.0, 0.05, 2000), np.zeros(2000)])
    info = mcl._summary(line, np.full(2000, -np.log(2000)), radius=0.5)
    assert info[5] == 1 and info[4] > 0.99  # one mode with all the mass
    assert info[6] < 0.45  # ... yet the estimate is within 0.5 m with probability ~1/3
    tight = np.column_stack([rng.normal(1.0, 0.1, 2000), rng.normal(0.0, 0.1, 2000), np.zeros(2000)])
    assert mcl._summary(tight, np.full(2000, -np.log(2000)))[6] > 0.99


def test_estimate_radius_moves_the_estimate_to_the_densest_place_of_the_mode():
    rng = np.random.default_rng(0)
    core = np.column_stack([rng.normal(0.0, 0.1, 1500), rng.normal(0.0, 0.1, 1500), np.zeros(1500)])
    tail = np.column_stack([rng.uniform(0.3, 1.4, 1500), rng.normal(0.0, 0.1, 1500), np.zeros(1500)])
    poses = np.vstack([core, tail])
    lw = np.full(3000, -np.log(3000))
    at_mean = mcl._summary(poses, lw, radius=0.0)
    at_core = mcl._summary(poses, lw, radius=0.5)
    assert abs(at_mean[3][0]) > 0.3  # the mode's mean is pulled into the tail
    assert abs(at_core[3][0]) < 0.2  # the densest place is the core


def test_run_mcl_reports_confidence_and_rejects_bad_new_parameters(sim):
    grid, _, odom, z = sim
    model = mcl.prepare_mcl(grid, mcl.MCLParams(**{**SIM_PARAMS, "n_particles": 300, "init_candidates": 3000}))
    res = mcl.run_mcl(model, odom, z, ANGLES, rng=np.random.default_rng(0), max_steps=5)
    assert res.confidence.shape == (len(res),) and np.all((res.confidence >= 0) & (res.confidence <= 1))
    with pytest.raises(ValueError, match="init_candidates"):
        mcl.MCLParams(init_candidates=-1)
    with pytest.raises(ValueError, match="estimate_radius"):
        mcl.MCLParams(estimate_radius=-0.5)


# --------------------------------------------------------------------------- beam skipping
def _door_scene(sim, skip):
    """A belief around the true pose at step 10 and its scan with one used beam made 1.5 m longer (an open door).

    Returns the model, the particles, the scan and the door beam's index among the used beams: the first
    beam whose longer reading ends at least 1.5 m from every wall for every particle.
    """
    grid, truth, _, z = sim
    model = mcl.prepare_mcl(grid, mcl.MCLParams(**{**SIM_PARAMS, "beam_skip_share": skip}))
    p = model.params
    rng = np.random.default_rng(3)
    poses = truth[10] + rng.normal(0.0, [0.05, 0.05, 0.02], (400, 3))
    zz, aa = mcl._subsample(z[10], ANGLES, p)
    far = mcl._field_terms(model, poses, zz + 1.5, aa, per_beam=True)
    floor = np.log(p.w_hit * norm.pdf(1.5, scale=p.sigma_hit) + p.w_rand / p.z_max)
    j = int(np.flatnonzero(np.all(far <= floor, axis=0) & (zz + 1.5 < p.z_max))[0])
    scan = z[10].copy()
    scan[j * p.beam_step] += 1.5
    return model, poses, scan, j


def test_beam_skipping_leaves_out_the_beam_no_part_of_the_belief_explains(sim):
    model, poses, scan, j = _door_scene(sim, 0.05)
    p = model.params
    z, a = mcl._subsample(scan, ANGLES, p)
    terms = mcl._field_terms(model, poses, z, a, per_beam=True)
    lw = np.full(len(poses), -np.log(len(poses)))
    np.testing.assert_array_equal(np.flatnonzero(~mcl._kept_beams(p, lw, terms, z)), [j])
    # a tenth of the belief where the long reading ends at a wall explains it: kept
    explained = np.zeros(len(poses), dtype=bool)
    explained[:40] = True
    t2 = terms.copy()
    t2[explained, j] = terms.max()
    assert mcl._kept_beams(p, lw, t2, z).all()
    # ... but not if those particles hold less than beam_skip_share of the mass
    lw2 = np.where(explained, np.log(0.01 / 40), np.log(0.99 / 360))
    np.testing.assert_array_equal(np.flatnonzero(~mcl._kept_beams(p, lw2, t2, z)), [j])
    # with skipping off, nothing is left out
    off = mcl.MCLParams(**{**SIM_PARAMS, "beam_skip_share": 0.0})
    assert mcl._kept_beams(off, lw, terms, z).all()


def test_a_step_with_a_skipped_beam_is_the_step_without_that_beam(sim):
    model, poses, scan, j = _door_scene(sim, 0.05)
    off = mcl.prepare_mcl(model.grid, mcl.MCLParams(**{**SIM_PARAMS, "beam_skip_share": 0.0}))
    state = mcl.MCLState(poses=poses, log_weights=np.full(len(poses), -np.log(len(poses))))
    u = np.array([0.0, 0.05, 0.0])
    without = scan.copy()
    without[j * model.params.beam_step] = model.params.z_max  # a max-range reading: the likelihood field ignores it
    for step in (mcl.mcl_step, mcl.augmented_mcl_step, mcl.kld_mcl_step):
        a, ia = step(state, u, scan, ANGLES, model, rng=np.random.default_rng(1))
        b, ib = step(state, u, without, ANGLES, off, rng=np.random.default_rng(1))
        np.testing.assert_array_equal(a.poses, b.poses)
        np.testing.assert_allclose(a.log_weights, b.log_weights, rtol=0, atol=1e-12)
        assert ia.log_w_avg == pytest.approx(ib.log_w_avg, abs=1e-12)
        _, ic = step(state, u, scan, ANGLES, off, rng=np.random.default_rng(1))
        # unskipped, the door reading lowers the belief's fit (and so raises sensor resetting's share)
        assert ic.log_w_avg < ia.log_w_avg - 0.3


def test_beam_skipping_keeps_every_beam_when_the_scan_contradicts_the_belief(sim):
    """Most beams unexplained: the belief is wrong (a kidnapping), not the map; nothing is skipped."""
    model = _door_scene(sim, 0.05)[0]
    _, truth, _, z = sim
    assert np.hypot(*(truth[60, :2] - truth[10, :2])) > 5.0
    rng = np.random.default_rng(4)
    wrong = truth[60] + rng.normal(0.0, [0.05, 0.05, 0.02], (400, 3))  # the belief 5 m or more from the scan's pose
    zz, aa = mcl._subsample(z[10], ANGLES, model.params)
    terms = mcl._field_terms(model, wrong, zz, aa, per_beam=True)
    lw = np.full(len(wrong), -np.log(len(wrong)))
    p = model.params
    strict = mcl.MCLParams(**{**SIM_PARAMS, "beam_skip_share": 0.05, "beam_skip_limit": 1.0})
    n_out = np.count_nonzero(~mcl._kept_beams(strict, lw, terms, zz))
    assert n_out > p.beam_skip_limit * np.count_nonzero(zz < p.z_max)  # more than half would go ...
    assert mcl._kept_beams(p, lw, terms, zz).all()  # ... so none does


def test_beam_skipping_parameters_are_checked():
    for kw, match in (({"beam_skip_share": 1.5}, "beam_skip_share"), ({"beam_skip_share": -0.1}, "beam_skip_share"),
                      ({"beam_skip_limit": 2.0}, "beam_skip_limit"), ({"beam_skip_distance": 0.0}, "beam_skip_distance"),
                      ({"beam_skip_share": 0.05, "model": "beam"}, "likelihood field")):
        with pytest.raises(ValueError, match=match):
            mcl.MCLParams(**kw)
    mcl.MCLParams(model="beam")  # the default, off, goes with either model


def test_wean_log_2_beam_skipping_keeps_the_right_place_where_the_map_disagrees():
    """From the truth at the start of Wean Hall log 2, beam skipping stays on the reference track for 95 updates.

    From about update 43 the robot passes openings that the map shows closed: one or two of the 18 beams the
    filter uses end more than a metre past the mapped wall for several scans, and a place some 10 m away with the opposite heading
    explains them. Without beam skipping, sensor resetting brings that place in and it takes part of the
    mass (over seeds 0-19: 8-63%, a third or more in 14 of 20, and the estimate jumped to it at one of the
    checks in 9 of 20); with it, those beams are left out while no part of the belief explains them, and
    the right place keeps the mass (it lost at most 0.6%).
    """
    from slamlib.datasets import cmu

    grid, log = cmu.load_cmu_map(), cmu.load_cmu_log(log=2)
    start = np.array([39.7016, 41.5186, -1.6342])  # the reference track of benchmarks/mcl_success.py at scan 0
    checks = {49: (30.31, 41.21), 70: (25.91, 41.55), 94: (20.76, 42.17)}  # update: reference position
    skip = 0.05  # the study's "beam skipping" configuration (off by default)
    lowest, err = {}, {}
    for share in (0.0, skip):
        model = mcl.prepare_mcl(grid, mcl.MCLParams(sensor_offset=log.sensor_offset, z_max=log.max_range,
                                                    beam_skip_share=share))
        rng = np.random.default_rng(2)
        init = mcl.MCLState(poses=start + rng.normal(0.0, [0.1, 0.1, 0.035], (10_000, 3)),
                            log_weights=np.full(10_000, -np.log(10_000)))
        res = mcl.run_mcl(model, log.laser_pose, log.ranges, log.angles, rng=rng, init=init, times=log.laser_t,
                          max_steps=95)
        lowest[share] = float(res.mode_mass[40:60].min())
        err[share] = [float(np.hypot(*(res.estimate[k, :2] - xy))) for k, xy in checks.items()]
    # lowest mass of the main mode over updates 40-59, seeds 0-19: 0.994-0.999 with skipping, 0.37-0.92
    # without; the bound 0.98 lies between them (a log-normal fitted to each side puts the chance of a
    # seed on the wrong side of it at about 1e-5 with skipping and 1e-4 without)
    assert lowest[skip] > 0.98 and max(err[skip]) < 0.5, (lowest, err)  # estimate errors 0.04 m or less
    assert lowest[0.0] < 0.98, lowest  # without skipping the look-alike takes 2% of the mass or more
