"""The hold-out trial generator of benchmarks/mcl_holdout.py: reproducible, feasible, and unlike the study's."""

import os
import sys

import numpy as np
import pytest

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "benchmarks"))

import mcl_holdout as H  # noqa: E402
import slamlib as sl  # noqa: E402
from slamlib.datasets import cmu  # noqa: E402


@pytest.fixture(scope="module")
def world():
    return H.holdout_world()


@pytest.fixture(scope="module")
def angles():
    return np.deg2rad(np.arange(-90.0, 90.0, 1.0))


def _mismatch(**kw):
    mm = H.draw_mismatch(np.random.default_rng(0))
    mm.update(trans_scale=0.0, rot_scale=0.0, rot_drift=0.0, noise_factor=0.0, p_short=0.0, p_rand=0.0,
              p_dropout=0.0, passer_by=0.0, sigma_factor=0.0, correlated_sigma=0.0, laser_yaw=0.0)
    mm.update(kw)
    return mm


def test_trials_are_reproducible_feasible_and_long_enough(world, angles):
    a = H.make_sim_trials(world, angles, 2, 12, 5)
    b = H.make_sim_trials(world, angles, 2, 12, 5)
    c = H.make_sim_trials(world, angles, 2, 12, 6)
    assert [H.trial_digest(t) for t in a] == [H.trial_digest(t) for t in b]
    assert H.trial_digest(a[0]) != H.trial_digest(c[0])
    assert H.trial_digest(a[0]) != H.trial_digest(a[1])
    for t in a + c:
        L = t["truth"].shape[0]
        assert t["odom"].shape == (L, 3) and t["ranges"].shape == (L, angles.size) and t["times"].shape == (L,)
        assert np.all(np.diff(t["times"]) > 0)
        assert sl.odometry_steps(t["odom"])[0].size >= 12  # the filter gets the updates asked for
        discs = np.array(t["mismatch"]["discs"]).reshape(-1, 3)
        for p in t["truth"]:  # the robot never touches a wall or an obstacle
            assert H._clearance(world, discs, p[:2]) >= H.ROBOT_RADIUS - 1e-9
        assert np.all((t["ranges"] >= 0) & (t["ranges"] <= cmu.CMU_MAX_RANGE))


def test_the_control_set_drives_the_same_with_the_filter_models(world, angles):
    sim = H.make_sim_trials(world, angles, 1, 12, 7)[0]
    ctl = H.make_sim_trials(world, angles, 1, 12, 7, control=True)[0]
    np.testing.assert_array_equal(sim["truth"], ctl["truth"])
    assert not np.array_equal(sim["ranges"], ctl["ranges"]) and not np.array_equal(sim["odom"], ctl["odom"])
    z_map = sl.ray_cast(world["grid"], ctl["truth"], angles, cmu.CMU_MAX_RANGE, sensor_offset=0.25, threshold=H.OCCUPIED)
    near = z_map < 10.0
    err = (ctl["ranges"] - z_map)[near]
    hit = np.abs(err) < 1.0
    assert np.std(err[hit]) == pytest.approx(H.REF_SIGMA_HIT, rel=0.15)  # the filter's sigma_hit, no obstacles
    assert np.mean(ctl["ranges"][near] == cmu.CMU_MAX_RANGE) == pytest.approx(0.05, abs=0.02)


def test_obstacles_are_in_the_scans_but_not_in_the_map(world, angles):
    truth = np.array([[30.0, 40.3, 0.0]])  # the long corridor, looking along it
    assert H._clearance(world, np.empty((0, 3)), truth[0, :2]) > 0.3
    discs = np.array([[33.0, 40.3, 0.3]])
    obs = H._with_obstacles(world["grid"], discs)
    mm = _mismatch()
    z = H._scans(obs, truth, angles, mm, np.random.default_rng(1), cmu.CMU_MAX_RANGE, 0.25)
    z_map = sl.ray_cast(world["grid"], truth, angles, cmu.CMU_MAX_RANGE, sensor_offset=0.25, threshold=H.OCCUPIED)
    ahead = np.abs(angles) < np.deg2rad(2.0)
    assert np.all(z[0, ahead] < 3.0) and np.all(z_map[0, ahead] > 5.0)
    assert np.allclose(z[0, ~ahead & (np.abs(angles) > 0.3)], z_map[0, ~ahead & (np.abs(angles) > 0.3)])


def test_scan_noise_is_not_the_filter_mixture(world, angles):
    truth = np.tile([30.0, 40.3, 0.0], (200, 1))
    z_map = sl.ray_cast(world["grid"], truth, angles, cmu.CMU_MAX_RANGE, sensor_offset=0.25, threshold=H.OCCUPIED)
    mm = _mismatch(sigma_factor=2.0, p_dropout=0.08)
    z = H._scans(world["grid"], truth, angles, mm, np.random.default_rng(2), cmu.CMU_MAX_RANGE, 0.25)
    hit = (z < cmu.CMU_MAX_RANGE) & (z_map < cmu.CMU_MAX_RANGE)
    assert np.std((z - z_map)[hit]) == pytest.approx(2.0 * H.REF_SIGMA_HIT, rel=0.1)  # twice the filter's sigma_hit
    dropped = (z == cmu.CMU_MAX_RANGE) & (z_map < cmu.CMU_MAX_RANGE)
    assert 0.04 < dropped.mean() < 0.15
    run = dropped[:, 1:] & dropped[:, :-1]
    assert run.sum() > 0.5 * dropped.sum()  # dropouts come in runs of beams, not one at a time


def test_odometry_has_systematic_error_and_noise_per_distance(world):
    line = np.column_stack([np.arange(0.0, 10.0, 0.05), np.zeros(200), np.zeros(200)])
    odom = H._odometry(line, _mismatch(trans_scale=0.04, rot_drift=np.deg2rad(1.0)), np.random.default_rng(3))
    rel = sl.odometry_from_poses(odom[:-1], odom[1:])
    assert rel[:, 1].sum() == pytest.approx(1.04 * 9.95, rel=1e-6)
    assert sl.wrap_angle(odom[-1, 2] - odom[0, 2]) == pytest.approx(np.deg2rad(1.0) * 9.95, rel=1e-6)
    # the noise is a random walk: the same variance over 4 m whether the scans are 0.05 m or 0.2 m apart
    finals = {}
    for step in (0.05, 0.2):
        xs = np.arange(0.0, 4.0 + 1e-9, step)
        path = np.column_stack([xs, np.zeros_like(xs), np.zeros_like(xs)])
        rng = np.random.default_rng(4)
        mm = _mismatch(noise_factor=2.0)
        finals[step] = np.array([H._odometry(path, mm, rng)[-1] - H._odometry(path, _mismatch(), rng)[-1]
                                 for _ in range(300)])
    var = {s: np.var(f[:, 0]) for s, f in finals.items()}
    assert var[0.05] == pytest.approx(var[0.2], rel=0.35)
    # ... and 2x the filter's variance over each 0.2 m update: a3 * trans^2 per update, 20 updates
    assert var[0.2] == pytest.approx(2.0 * H.REF_ALPHA[2] * 0.2 ** 2 * 20, rel=0.35)


def test_log_starts_avoid_the_study_and_fit_the_logs():
    refs = {1: dict(scan_index=np.arange(208) * 3), 2: dict(scan_index=np.arange(437) * 5)}
    keys = H.log_starts(refs, 5, H.BASE_SEED)
    assert len(keys) == 10 and {k[0] for k in keys} == {1, 2}
    for n, j, shift, h in keys:
        L = len(refs[n]["scan_index"])
        assert j not in H.study_offsets(L)
        assert 1 <= shift < refs[n]["scan_index"][j + 1] - refs[n]["scan_index"][j]
        assert j + h < L - 1
    assert {k[3] for k in keys} >= {20, 120} and H.STUDY_UPDATES not in {k[3] for k in keys}


def test_the_study_seed_is_refused():
    with pytest.raises(SystemExit, match="study"):
        H.main(["--seed", str(H.STUDY_SEED), "--trials", "1"])


def test_the_reference_tracks_models_do_not_follow_the_library_defaults():
    """The truth the defaults are judged against is fixed in mcl_success.REF_MODELS, not read from MCLParams()."""
    import mcl_success

    fields = set(sl.MCLParams.__dataclass_fields__)
    assert set(mcl_success.REF_MODELS) <= fields
    # the models of the measurement and the motion are pinned; the update spacing is deliberately not
    assert {"model", "likelihood_exponent", "sigma_hit", "beam_step", "alpha"} <= set(mcl_success.REF_MODELS)
    assert not {"min_translation", "min_rotation"} & set(mcl_success.REF_MODELS)
    sl.MCLParams(**mcl_success.REF_MODELS)  # a valid parameter set
