"""landmark_graph_from_run with a front end's associations and another motion model (chapter 12)."""

import dataclasses

import numpy as np
import pytest

import slamlib as sl
from slamlib.datasets.victoria import load_victoria_park


@pytest.fixture(scope="module")
def sim_run():
    rng = np.random.default_rng(3)
    world = sl.make_landmark_world(8, extent=12.0, min_separation=2.0, rng=rng)
    return sl.simulate_landmark_run(world, sl.loop_controls(60, v=1.0, omega=0.3), 0.2, x0=[0.0, -3.0, 0.0],
                                    M=np.diag([0.1**2, np.deg2rad(5.0) ** 2]), Q=np.diag([0.1**2, np.deg2rad(2.0) ** 2]),
                                    max_range=5.0, fov=np.pi, rng=rng)


def test_known_ids_as_associations_and_velocity_model_as_motion_give_the_default_graph(sim_run):
    base = sl.landmark_graph_from_run(sim_run)
    same = sl.landmark_graph_from_run(sim_run, associations=sim_run.ids, motion=sl.velocity_motion)
    assert base.obs_model == same.obs_model == "range_bearing"
    for name in base._fields:
        if name != "obs_model":
            np.testing.assert_allclose(np.asarray(getattr(base, name), dtype=float),
                                       np.asarray(getattr(same, name), dtype=float), atol=1e-12, err_msg=name)


def test_left_out_measurements_drop_their_edges(sim_run):
    assoc = [np.where(np.arange(len(i)) == 0, -1, i) for i in sim_run.ids]   # the first sighting of each step out
    g = sl.landmark_graph_from_run(sim_run, associations=assoc)
    n_all = sum(len(i) for i in sim_run.ids)
    n_out = sum(1 for i in sim_run.ids if len(i))
    assert g.obs_edges.shape[0] == n_all - n_out


def test_car_model_edges_compose_to_its_dead_reckoning():
    run = load_victoria_park(t_max=30.0)
    ekf = sl.run_ekf_slam(run, known=False, confirm=2, window=10, motion=run.motion)
    g = sl.landmark_graph_from_run(run, motion=run.motion, associations=ekf.associations, heading_floor=1e-3)
    x = np.zeros((run.n_steps + 1, 3))
    x[0] = run.x0
    for k in range(run.n_steps):
        x[k + 1] = run.motion(x[k], run.u[k], run.dt)[0]
    np.testing.assert_allclose(g.X0, x, atol=1e-9)
    assert g.L0.shape[0] == len(np.unique(np.concatenate([a[a >= 0] for a in ekf.associations])))
    res = sl.optimize_landmark_graph(g._replace(X0=ekf.x, L0=ekf.landmarks[g.landmark_ids]))
    assert res.chi2[-1] < res.chi2[0]


def test_a_car_standing_still_needs_a_heading_floor():
    run = load_victoria_park(t_max=5.0)
    u = run.u.copy()
    u[3] = 0.0                                   # one step standing still with straight wheels
    still = dataclasses.replace(run, u=u)
    assoc = [np.full(len(z), 0) for z in run.z]
    with pytest.raises(ValueError, match="heading_floor"):
        sl.landmark_graph_from_run(still, motion=run.motion, associations=assoc)
    g = sl.landmark_graph_from_run(still, motion=run.motion, associations=assoc, heading_floor=1e-3)
    assert np.all(np.isfinite(g.odo_Omega))


@pytest.mark.parametrize("bad, match", [
    (lambda r: r.ids[:-1], "associations and run.z"),
    (lambda r: [np.asarray(i, dtype=float) for i in r.ids], "integer array"),
    (lambda r: [np.append(i, 0) for i in r.ids], "one entry per measurement"),
    (lambda r: [np.full(len(i), -2) for i in r.ids], "landmark indices or -1"),
    (lambda r: [np.full(len(i), -1) for i in r.ids], "no landmark sighting"),
])
def test_bad_associations_are_named(sim_run, bad, match):
    with pytest.raises((ValueError, TypeError), match=match):
        sl.landmark_graph_from_run(sim_run, associations=bad(sim_run))


def test_bad_motion_and_floor_are_named(sim_run):
    with pytest.raises(TypeError, match="motion"):
        sl.landmark_graph_from_run(sim_run, motion="car")
    with pytest.raises(ValueError, match="heading_floor"):
        sl.landmark_graph_from_run(sim_run, heading_floor=-1.0)


@pytest.mark.parametrize("Q", [np.zeros((2, 2)), np.ones((2, 2)), np.diag([-1e-10, 1.0])],
                         ids=["zero", "singular", "slightly negative"])
def test_measurement_noise_must_be_positive_definite(sim_run, Q):
    # the sightings' information matrices are Q^-1: a Q the semi-definite check accepts but that has no
    # inverse (or a negative one) is named, not turned into infinite or negative information
    with pytest.raises(ValueError, match="run.Q must be positive definite"):
        sl.landmark_graph_from_run(dataclasses.replace(sim_run, Q=Q))
