"""Bad inputs to every public function of the base modules fail loudly, naming the argument.

Each entry of ``SPECS`` is one public function with a valid call and, for each
argument, the kinds of bad value it must refuse. Hypothesis picks an argument
and a corruption of it (a NaN or inf at a drawn position, a string, ``None``, a
bool, a wrong trailing dimension, an asymmetric or indefinite covariance, a
negative count, one row too few against another argument, ...) and the call
must raise ``ValueError`` or ``TypeError`` whose message names the argument.
``test_every_public_function_has_a_spec`` walks ``__all__`` of these modules,
so a new public function without an entry here fails.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import slamlib as sl

MODULES = ("angles", "bayes", "maps", "motion", "sensors", "metrics", "sim", "particle", "gaussian")

#: Public names that are not functions taking user input: result containers and tables.
NOT_CALLED = {
    "RESAMPLERS": "a dict of the resamplers, each tested below",
    "PFStepInfo": "a result record filled by the filter steps",
    "PFRunResult": "a result record filled by run_particle_filter",
    "EKFRunResult": "a result record filled by the EKF drivers",
    "LandmarkRun": "a result record filled by simulate_landmark_run",
    "LikelihoodField": "built by likelihood_field, whose inputs are tested",
    "RangeTable": "built by range_table, whose inputs are tested; RangeTable.ranges in tests/test_sensors.py",
}

FUZZ = settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow], derandomize=True)

# --------------------------------------------------------------------------- valid inputs
RNG_SEED = 3
P3 = np.array([[0.05, 0.01, 0.0], [0.01, 0.04, 0.002], [0.0, 0.002, 0.01]])
M2 = np.diag([0.01, 0.003])
Q2 = np.diag([0.04, 0.003])
POSE = np.array([1.0, 2.0, 0.3])
POSES = np.array([[1.0, 2.0, 0.3], [1.1, 1.9, 0.2], [0.9, 2.2, -0.1], [1.2, 2.1, 0.4]])
LANDMARKS = np.array([[6.0, 4.0], [2.0, 7.0], [-3.0, 1.0]])
Z1 = np.array([5.9, 0.35])
ZS = np.array([[5.9, 0.35], [5.2, 1.2]])
GRID = sl.OccupancyGrid(np.pad(np.zeros((8, 10)), 1, constant_values=1.0), 0.5)
FIELD = sl.likelihood_field(GRID)
FREE = np.ones((6, 7), dtype=bool)
FREE[2, 3] = False
BEL = np.full(10, 0.1)
BEAM = dict(z_max=10.0, sigma_hit=0.2, lambda_short=0.1, w_hit=0.7, w_short=0.1, w_max=0.1, w_rand=0.1)
RUN = sl.simulate_landmark_run(LANDMARKS, np.tile([1.0, 0.1], (5, 1)), 0.1, x0=POSE, M=M2, Q=Q2,
                               rng=np.random.default_rng(RNG_SEED))
LOGW = np.log(np.array([0.1, 0.2, 0.3, 0.4]))
W = np.array([0.1, 0.2, 0.3, 0.4])


class Arg:
    """How one argument may be corrupted; `rows` names a group whose first axes must agree."""

    def __init__(self, kind, *, rows=None, expect=None, neg=False, none_ok=False, vector_ok=False):
        self.kind, self.rows, self.expect, self.neg = kind, rows, expect, neg
        self.none_ok, self.vector_ok = none_ok, vector_ok


def spec(fn, args, kwargs=None, bad=None):
    return {"fn": fn, "args": dict(args), "kwargs": dict(kwargs or {}), "bad": bad}


A = Arg
# kinds: "arr" (float array, fixed trailing shape), "rowsarr" (2-D, any number of columns), "free" (1-D float
# array, any length), "any" (float array of
# any shape), "cov"/"pd" (PSD / PD covariance), "scalar", "prob" (scalar in [0, 1]), "count" (int >= 0),
# "rng", "fn" (callable), "logw", "w" (weights), "dist" (probability vector), "mask", "obj" (a library object)
SPECS = {
    # angles
    "wrap_angle": spec(sl.wrap_angle, {"a": np.array([0.1, 4.0])}, bad={"a": A("any")}),
    "angle_diff": spec(sl.angle_diff, {"a": np.array([0.1, 4.0, -1.0]), "b": np.array([0.2, -3.0, 2.0])},
                       bad={"a": A("any", rows="ab"), "b": A("any", rows="ab")}),
    "circular_mean": spec(sl.circular_mean, {"angles": np.array([0.1, 0.4, 3.0])}, {"weights": np.array([1.0, 2.0, 0.5])},
                          bad={"angles": A("free", rows="w"), "weights": A("w", rows="w", none_ok=True)}),
    # bayes
    "bayes_rule": spec(sl.bayes_rule, {"prior": BEL, "likelihood": np.linspace(0.1, 1.0, 10)},
                       bad={"prior": A("dist", rows="p"), "likelihood": A("free", rows="p", neg=True)}),
    "motion_kernel": spec(sl.motion_kernel, {"shift": 1.5, "sigma": 0.7}, {"radius": 5},
                          bad={"shift": A("scalar", vector_ok=True), "sigma": A("scalar", neg=True, vector_ok=True),
                               "radius": A("count", none_ok=True)}),
    "histogram_predict": spec(sl.histogram_predict, {"belief": BEL, "kernel": np.array([0.25, 0.5, 0.25])},
                              bad={"belief": A("dist"), "kernel": A("dist")}),
    "histogram_update": spec(sl.histogram_update, {"belief": BEL, "likelihood": np.linspace(0.1, 1.0, 10)},
                             bad={"belief": A("dist", rows="p"), "likelihood": A("free", rows="p", neg=True)}),
    "histogram_filter": spec(sl.histogram_filter, {"belief": BEL, "kernels": np.array([0.25, 0.5, 0.25]),
                                                   "likelihoods": np.full((3, 10), 0.5)},
                             bad={"belief": A("dist"), "kernels": A("dist"), "likelihoods": A("arr", neg=True)}),
    "corridor_doors": spec(sl.corridor_doors, {"n_cells": 20, "door_cells": [2, 9]}, {"door_width": 2},
                           bad={"n_cells": A("count"), "door_width": A("count")}),
    "door_likelihood": spec(sl.door_likelihood, {"doors": np.arange(10) % 3 == 0, "z": True},
                            {"p_hit": 0.8, "p_false": 0.1},
                            bad={"doors": A("mask"), "p_hit": A("prob"), "p_false": A("prob")}),
    "simulate_corridor": spec(sl.simulate_corridor, {"doors": np.arange(10) % 3 == 0, "x0": 2, "moves": [1, 2, 1]},
                              {"sigma": 0.5, "p_hit": 0.8, "p_false": 0.1, "rng": np.random.default_rng(1)},
                              bad={"doors": A("mask"), "x0": A("count"), "sigma": A("scalar", neg=True),
                                   "p_hit": A("prob"), "p_false": A("prob"), "rng": A("rng")}),
    "grid_predict": spec(sl.grid_predict, {"belief": FREE / FREE.sum(), "kernel": np.full((3, 3), 1 / 9)},
                         {"free": FREE}, bad={"belief": A("dist"), "kernel": A("dist"), "free": A("mask", none_ok=True)}),
    "grid_wall_distances": spec(sl.grid_wall_distances, {"free": FREE}, {"max_range": 5.0},
                                bad={"free": A("mask"), "max_range": A("scalar", neg=True, none_ok=True)}),
    "grid_range_likelihood": spec(sl.grid_range_likelihood, {"expected": np.ones((6, 7, 4)), "z": np.ones(4)},
                                  {"sigma": 0.5},
                                  bad={"expected": A("arr"), "z": A("free"), "sigma": A("scalar", neg=True)}),
    "simulate_grid": spec(sl.simulate_grid, {"free": FREE, "start": [1, 1], "moves": [[0, 1], [1, 0]]},
                          {"sigma": 0.3, "range_sigma": 0.2, "rng": np.random.default_rng(1)},
                          bad={"free": A("mask"), "sigma": A("scalar", neg=True, vector_ok=True),
                               "range_sigma": A("scalar", neg=True), "rng": A("rng")}),
    # maps
    "OccupancyGrid": spec(sl.OccupancyGrid, {"occupancy": np.zeros((4, 5)), "resolution": 0.5},
                          bad={"resolution": A("scalar", neg=True)}),
    "sample_free_poses": spec(sl.sample_free_poses, {"grid": GRID, "n": 5}, {"rng": np.random.default_rng(1)},
                              bad={"grid": A("obj"), "n": A("count"), "rng": A("rng")}),
    "make_landmark_world": spec(sl.make_landmark_world, {"n": 4}, {"rng": np.random.default_rng(1)},
                                bad={"n": A("count"), "rng": A("rng"), "extent": A("scalar", neg=True)}),
    # motion
    "velocity_motion": spec(sl.velocity_motion, {"x": POSES, "u": np.tile([1.0, 0.2], (4, 1)), "dt": 0.1},
                            bad={"x": A("arr", rows="m"), "u": A("arr", rows="m"), "dt": A("scalar", neg=True)}),
    "ackermann_motion": spec(sl.ackermann_motion, {"x": POSES, "u": np.tile([2.0, 0.1], (4, 1)), "dt": 0.1},
                             {"a": 3.78, "b": 0.5, "H": 0.76, "L": 2.83},
                             bad={"x": A("arr", rows="m"), "u": A("arr", rows="m"), "dt": A("scalar", neg=True),
                                  "a": A("scalar"), "b": A("scalar"), "H": A("scalar", neg=True),
                                  "L": A("scalar", neg=True)}),
    "AckermannModel": spec(sl.AckermannModel, {"a": 3.78, "b": 0.5, "H": 0.76, "L": 2.83},
                           bad={"a": A("scalar"), "b": A("scalar"), "H": A("scalar", neg=True),
                                "L": A("scalar", neg=True)}),
    "velocity_noise_cov": spec(sl.velocity_noise_cov, {"u": np.array([1.0, 0.2]), "alpha": np.full(4, 0.1)},
                               bad={"u": A("arr"), "alpha": A("arr", neg=True)}),
    "sample_motion_model_velocity": spec(
        sl.sample_motion_model_velocity, {"x": POSES, "u": np.tile([1.0, 0.2], (4, 1)), "dt": 0.1,
                                          "alpha": np.full(6, 0.1)}, {"rng": np.random.default_rng(1)},
        bad={"x": A("arr", rows="m"), "u": A("arr", rows="m"), "dt": A("scalar", neg=True),
             "alpha": A("arr", neg=True), "rng": A("rng")}),
    "motion_model_velocity": spec(
        sl.motion_model_velocity, {"x_next": POSES + 0.05, "u": np.array([1.0, 0.2]), "x": POSES, "dt": 0.1,
                                   "alpha": np.full(6, 0.1)},
        bad={"x_next": A("arr", rows="m"), "u": A("arr"), "x": A("arr", rows="m"), "dt": A("scalar", neg=True),
             "alpha": A("arr", neg=True)}),
    "odometry_from_poses": spec(sl.odometry_from_poses, {"x_prev": POSES, "x_next": POSES + 0.1},
                                bad={"x_prev": A("arr", rows="m"), "x_next": A("arr", rows="m")}),
    "odometry_motion": spec(sl.odometry_motion, {"x": POSES, "u": np.tile([0.1, 1.0, 0.1], (4, 1))},
                            bad={"x": A("arr", rows="m"), "u": A("arr", rows="m")}),
    "sample_motion_model_odometry": spec(
        sl.sample_motion_model_odometry, {"x": POSES, "u": np.array([0.1, 1.0, 0.1]), "alpha": np.full(4, 0.1)},
        {"rng": np.random.default_rng(1)},
        bad={"x": A("arr"), "u": A("arr"), "alpha": A("arr", neg=True), "rng": A("rng")}),
    "motion_model_odometry": spec(
        sl.motion_model_odometry, {"x_next": POSES + 0.1, "u": np.array([0.1, 1.0, 0.1]), "x": POSES,
                                   "alpha": np.full(4, 0.1)},
        bad={"x_next": A("arr", rows="m"), "u": A("arr"), "x": A("arr", rows="m"), "alpha": A("arr", neg=True)}),
    "dead_reckoning": spec(sl.dead_reckoning, {"x0": POSE, "u": np.tile([1.0, 0.1], (5, 1)), "dt": 0.1},
                           bad={"x0": A("arr"), "u": A("arr"), "dt": A("scalar", neg=True)}),
    # sensors
    "landmark_measurement": spec(sl.landmark_measurement, {"x": POSES[:3], "m": LANDMARKS},
                                 bad={"x": A("arr", rows="m"), "m": A("arr", rows="m")}),
    "landmark_from_measurement": spec(sl.landmark_from_measurement, {"x": POSES[:3], "z": np.vstack([ZS, [4.0, -0.5]])},
                                      bad={"x": A("arr", rows="m"), "z": A("arr", rows="m")}),
    "beam_range_finder_model": spec(sl.beam_range_finder_model, {"z": np.array([1.0, 2.0, 3.0]),
                                                                 "z_star": np.array([1.1, 2.0, 2.5])}, BEAM,
                                    bad={"z": A("free", rows="z"), "z_star": A("free", rows="z"),
                                         "sigma_hit": A("scalar", neg=True), "w_hit": A("scalar", neg=True)}),
    "beam_range_finder_log_likelihood": spec(
        sl.beam_range_finder_log_likelihood, {"z": np.array([1.0, 2.0, 3.0]), "z_star": np.array([1.1, 2.0, 2.5])},
        BEAM, bad={"z": A("free", rows="z"), "z_star": A("free", rows="z"), "z_max": A("scalar", neg=True)}),
    "ray_cast": spec(sl.ray_cast, {"grid": GRID, "poses": np.array([[2.0, 2.0, 0.1]]),
                                   "angles": np.array([0.0, 1.0]), "max_range": 5.0},
                     bad={"grid": A("obj"), "poses": A("arr"), "angles": A("free"),
                          "max_range": A("scalar", neg=True)}),
    "range_table": spec(sl.range_table, {"grid": GRID},
                        {"max_range": 5.0, "n_angles": 36, "region": np.ones(GRID.shape, dtype=bool)},
                        bad={"grid": A("obj"), "max_range": A("scalar", neg=True), "n_angles": A("count"),
                             "region": A("mask", none_ok=True)}),
    "likelihood_field": spec(sl.likelihood_field, {"grid": GRID}, {"max_dist": 2.0},
                             bad={"grid": A("obj"), "max_dist": A("scalar", neg=True)}),
    "likelihood_field_log_likelihood": spec(
        sl.likelihood_field_log_likelihood, {"field": FIELD, "poses": np.array([[2.0, 2.0, 0.1]]),
                                             "ranges": np.array([1.0, 2.0]), "angles": np.array([0.0, 1.0])},
        {"z_max": 8.0, "sigma_hit": 0.2, "w_hit": 0.9, "w_rand": 0.1},
        bad={"field": A("obj"), "poses": A("arr"), "ranges": A("free", rows="r", neg=True),
             "angles": A("free", rows="r"), "sigma_hit": A("scalar", neg=True)}),
    # metrics
    "pose_error": spec(sl.pose_error, {"est": POSES, "true": POSES + 0.1},
                       bad={"est": A("arr", rows="m"), "true": A("arr", rows="m")}),
    "ate_rmse": spec(sl.ate_rmse, {"est": POSES, "true": POSES + 0.1},
                     bad={"est": A("arr", rows="m"), "true": A("arr", rows="m")}),
    "heading_rmse": spec(sl.heading_rmse, {"est": POSES, "true": POSES + 0.1},
                         bad={"est": A("arr", rows="m"), "true": A("arr", rows="m")}),
    "landmark_rmse": spec(sl.landmark_rmse, {"est": LANDMARKS, "true": LANDMARKS + 0.1},
                          bad={"est": A("arr", rows="m"), "true": A("arr", rows="m")}),
    "nees": spec(sl.nees, {"err": np.tile([0.1, -0.1, 0.02], (2, 1)), "P": np.stack([P3, 2 * P3])},
                 bad={"err": A("arr"), "P": A("pd")}),
    "nees_band": spec(sl.nees_band, {"dof": 3, "n_runs": 20}, {"p": 0.95},
                      bad={"dof": A("count"), "n_runs": A("count"), "p": A("prob")}),
    # sim
    "simulate_landmark_run": spec(sl.simulate_landmark_run, {"landmarks": LANDMARKS,
                                                             "u": np.tile([1.0, 0.1], (5, 1)), "dt": 0.1},
                                  {"x0": POSE, "M": M2, "Q": Q2, "rng": np.random.default_rng(1)},
                                  bad={"landmarks": A("arr"), "u": A("arr"), "dt": A("scalar", neg=True),
                                       "x0": A("arr"), "M": A("cov"), "Q": A("cov"), "rng": A("rng")}),
    "add_clutter": spec(sl.add_clutter, {"run": RUN, "rate": 0.5}, {"rng": np.random.default_rng(2), "max_range": 5.0},
                        bad={"run": A("obj"), "rate": A("scalar", neg=True), "rng": A("rng"),
                             "max_range": A("scalar", neg=True, none_ok=True)}),
    "loop_controls": spec(sl.loop_controls, {"n_steps": 10}, {"v": 1.0, "omega": 0.1},
                          bad={"n_steps": A("count"), "v": A("scalar"), "omega": A("scalar")}),
    "figure_eight_controls": spec(sl.figure_eight_controls, {"n_steps": 10}, {"v": 1.0, "omega": 0.1},
                                  bad={"n_steps": A("count"), "v": A("scalar"), "omega": A("scalar")}),
    # particle
    "ParticleSet": spec(sl.ParticleSet, {"poses": POSES, "log_weights": LOGW},
                        bad={"poses": A("rowsarr", rows="m"), "log_weights": A("logw", rows="m")}),
    "normalize_log_weights": spec(sl.normalize_log_weights, {"log_w": LOGW}, bad={"log_w": A("logw")}),
    "effective_sample_size": spec(sl.effective_sample_size, {"w": W}, bad={"w": A("w")}),
    **{name: spec(getattr(sl, name), {"w": W}, {"rng": np.random.default_rng(1)}, bad={"w": A("w"), "rng": A("rng")})
       for name in ("low_variance_resample", "systematic_resample", "stratified_resample", "multinomial_resample",
                    "residual_resample")},
    "landmark_likelihood": spec(sl.landmark_likelihood, {"particles": POSES, "z": Z1, "m": LANDMARKS[0], "Q": Q2},
                                bad={"particles": A("arr"), "z": A("arr"), "m": A("arr"), "Q": A("pd")}),
    "bootstrap_filter_step": spec(
        sl.bootstrap_filter_step, {"particles": POSES, "log_w": LOGW, "propagate": lambda p, rng: p + 0.01,
                                   "log_likelihood": lambda p: -p[:, 0] ** 2},
        {"rng": np.random.default_rng(1)},
        bad={"particles": A("rowsarr", rows="m"), "log_w": A("logw", rows="m"), "propagate": A("fn"),
             "log_likelihood": A("fn"), "rng": A("rng"), "ess_threshold": A("prob")}),
    "particle_filter_step": spec(
        sl.particle_filter_step, {"particles": POSES, "log_w": LOGW, "u": np.array([1.0, 0.1]), "z": ZS,
                                  "m": LANDMARKS[:2], "dt": 0.1, "M": M2, "Q": Q2},
        {"rng": np.random.default_rng(1)},
        bad={"particles": A("arr", rows="p"), "log_w": A("logw", rows="p"), "u": A("arr"), "z": A("arr", rows="z"),
             "m": A("arr", rows="z"), "dt": A("scalar", neg=True), "M": A("cov"), "Q": A("pd"), "rng": A("rng"),
             "landmark_likelihood": A("fn"), "normalize_log_weights": A("fn"), "effective_sample_size": A("fn")}),
    "run_particle_filter": spec(
        sl.run_particle_filter, {"run": RUN, "particles": POSES}, {"rng": np.random.default_rng(1), "log_w": LOGW},
        bad={"run": A("obj"), "particles": A("arr", rows="p"), "log_w": A("logw", rows="p", none_ok=True),
             "rng": A("rng"), "M": A("cov", none_ok=True), "Q": A("pd", none_ok=True), "ess_threshold": A("prob"),
             "landmark_likelihood": A("fn"), "normalize_log_weights": A("fn"), "effective_sample_size": A("fn"),
             "on_step": A("fn")}),
    "particle_gaussian": spec(sl.particle_gaussian, {"particles": POSES, "log_weights": LOGW}, {"angles": (2,)},
                              bad={"particles": A("rowsarr", rows="m"),
                                   "log_weights": A("logw", rows="m", none_ok=True)}),
    # gaussian
    "Gaussian": spec(sl.Gaussian, {"mean": POSE, "cov": P3}, bad={"mean": A("arr"), "cov": A("arr")}),
    "kf_predict": spec(sl.kf_predict, {"x": POSES, "P": np.stack([P3] * 4), "F": np.eye(3), "Q": P3},
                       bad={"x": A("arr", rows="m"), "P": A("cov", rows="m"), "F": A("arr"), "Q": A("cov")}),
    "kf_update": spec(sl.kf_update, {"x": POSES, "P": np.stack([P3] * 4), "z": np.ones((4, 2)),
                                     "H": np.eye(2, 3), "R": Q2},
                      bad={"x": A("arr", rows="m"), "P": A("cov", rows="m"), "z": A("arr", rows="m"), "H": A("arr"),
                           "R": A("pd")}),
    "ekf_predict": spec(sl.ekf_predict, {"mu": POSES, "Sigma": np.stack([P3] * 4), "u": np.array([1.0, 0.2]),
                                         "dt": 0.1, "M": M2},
                        bad={"mu": A("arr", rows="m"), "Sigma": A("cov", rows="m"), "u": A("arr"),
                             "dt": A("scalar", neg=True), "M": A("cov")}),
    "ekf_update": spec(sl.ekf_update, {"mu_bar": POSES, "Sigma_bar": np.stack([P3] * 4), "z": np.tile(Z1, (4, 1)),
                                       "m": LANDMARKS[0], "Q": Q2},
                       bad={"mu_bar": A("arr", rows="m"), "Sigma_bar": A("cov", rows="m"), "z": A("arr", rows="m"),
                            "m": A("arr"), "Q": A("pd")}),
    "landmark_mahalanobis": spec(sl.landmark_mahalanobis, {"mu_bar": POSE, "Sigma_bar": P3, "z": Z1,
                                                           "landmarks": LANDMARKS, "Q": Q2},
                                 bad={"mu_bar": A("arr"), "Sigma_bar": A("cov"), "z": A("arr"),
                                      "landmarks": A("arr"), "Q": A("pd")}),
    "associate_ml": spec(sl.associate_ml, {"mu_bar": POSE, "Sigma_bar": P3, "z": Z1, "landmarks": LANDMARKS,
                                           "Q": Q2, "gate": 9.2},
                         bad={"mu_bar": A("arr"), "Sigma_bar": A("cov"), "z": A("arr"), "landmarks": A("arr"),
                              "Q": A("pd"), "gate": A("scalar", neg=True)}),
    "ekf_localization_known": spec(
        sl.ekf_localization_known, {"mu": POSE, "Sigma": P3, "u": np.array([1.0, 0.2]), "z": ZS,
                                    "ids": np.array([0, 1]), "landmarks": LANDMARKS, "dt": 0.1, "M": M2, "Q": Q2},
        bad={"mu": A("arr"), "Sigma": A("cov"), "u": A("arr"), "z": A("arr", rows="z"), "landmarks": A("arr"),
             "dt": A("scalar", neg=True), "M": A("cov"), "Q": A("pd"), "ids": A("ids", rows="z")}),
    "ekf_localization_unknown": spec(
        sl.ekf_localization_unknown, {"mu": POSE, "Sigma": P3, "u": np.array([1.0, 0.2]), "z": ZS,
                                      "landmarks": LANDMARKS, "dt": 0.1, "M": M2, "Q": Q2}, {"gate": 9.2},
        bad={"mu": A("arr"), "Sigma": A("cov"), "u": A("arr"), "z": A("arr"), "landmarks": A("arr"),
             "dt": A("scalar", neg=True), "M": A("cov"), "Q": A("pd"), "gate": A("scalar", neg=True)}),
    "ekf_localization_run": spec(sl.ekf_localization_run, {"run": RUN}, {"mu0": POSE, "Sigma0": P3},
                                 bad={"mu0": A("arr", none_ok=True), "Sigma0": A("cov", none_ok=True),
                                      "M": A("cov", none_ok=True), "Q": A("pd", none_ok=True),
                                      "gate": A("scalar", neg=True, none_ok=True), "ekf_predict": A("fn"),
                                      "ekf_update": A("fn"), "on_step": A("fn")}),
    "ekf_localization_batch": spec(sl.ekf_localization_batch, {"runs": [RUN, RUN]}, {"mu0": POSE, "Sigma0": P3},
                                   bad={"mu0": A("arr", none_ok=True), "Sigma0": A("cov", none_ok=True),
                                        "M": A("cov", none_ok=True), "Q": A("pd", none_ok=True)}),
}

# --------------------------------------------------------------------------- corruptions


def _default(name, sp):
    for source in (sp["args"], sp["kwargs"]):
        if name in source:
            return source[name]
    if sp["bad"][name].kind == "fn":
        return None  # an optional function (None: the library's own)
    return {"extent": 10.0, "M": M2, "Q": Q2, "gate": 9.2, "ess_threshold": 0.5}[name]


def _corruptions(arg, value, data):
    """Bad values for an argument of kind `arg.kind` whose valid value is `value`."""
    out = {"string": "abc"} if arg.none_ok else {"string": "abc", "None": None}
    kind = arg.kind
    if kind in ("arr", "rowsarr", "free", "any", "cov", "pd", "dist", "w", "logw", "mask"):
        a = np.array(value, dtype=float)
        if a.size:
            i = data.draw(st.integers(0, a.size - 1), label="position")
            if kind != "logw":
                for label, v in (("nan", np.nan), ("inf", data.draw(st.sampled_from([np.inf, -np.inf])))):
                    b = a.copy().ravel()
                    b[i] = v
                    out[label] = b.reshape(a.shape)
            else:
                out["nan"] = np.where(np.arange(a.size) == i, np.nan, a)
                out["+inf"] = np.where(np.arange(a.size) == i, np.inf, a)
                out["all -inf"] = np.full(a.shape, -np.inf)
        out["strings"] = np.array(["a"] * max(a.size, 1)).reshape(a.shape or (1,))
        if kind in ("arr", "cov", "pd", "dist") and a.ndim >= 2 or kind == "arr":
            out["trailing dimension"] = np.concatenate([a, a[..., :1]], axis=-1)
        if kind in ("free", "w", "logw", "dist") and a.ndim == 1:
            out["two dimensions"] = a[:, None] * np.ones(2)
        if kind == "rowsarr":
            out["one dimension"] = a.ravel()
        if kind in ("cov", "pd"):
            asym = a.copy()
            asym[..., 0, 1] += 0.5 + abs(asym[..., 0, 1])
            out["asymmetric"] = asym
            out["indefinite"] = a - 2.0 * np.max(np.linalg.eigvalsh(a)) * np.eye(a.shape[-1])
        if kind == "pd":
            out["singular"] = np.zeros_like(a)
        if (kind in ("w", "dist") or arg.neg) and a.size:
            neg = a.copy().ravel()
            neg[i] = -1.0
            out["negative"] = neg.reshape(a.shape)
        if kind == "w":
            out["all zero"] = np.zeros_like(a)
        if kind == "dist":
            out["not summing to 1"] = 2.0 * a
        if kind == "mask":
            out["not 0/1"] = np.where(np.arange(a.size).reshape(a.shape) == i, 2.0, a)
    elif kind == "ids":
        a = np.asarray(value)
        out.update({"floats": a.astype(float) + 0.5, "negative": a - 10, "too large": a + 1000})
    elif kind in ("scalar", "prob"):
        out.update({"nan": np.nan, "bool": True})
        if not arg.vector_ok:
            out["array"] = np.array([1.0, 2.0])
        if kind == "prob":
            out.update({"above 1": 1.5, "negative": -0.1})
        if arg.neg:
            out["negative"] = -1.0
    elif kind == "count":
        out.update({"negative": -1, "float": 2.5, "bool": True})
    elif kind == "rng":
        out = {"int": 0, "None": None, "RandomState": np.random.RandomState(0)}
    elif kind == "fn":
        out = {"int": 1, "string": "abc"}
    elif kind == "obj":
        out = {"string": "abc", "None": None, "int": 1}
    return out


def _rows_cut(value, kind):
    a = np.asarray(value)[:-1]
    return a / a.sum() if kind == "dist" else a  # a distribution stays one


def _call(sp, name=None, bad=None):
    args, kwargs = dict(sp["args"]), dict(sp["kwargs"])
    if name is not None:
        (args if name in args else kwargs)[name] = bad
    return sp["fn"](*args.values(), **kwargs)


@pytest.mark.parametrize("fname", sorted(SPECS))
def test_valid_call_succeeds(fname):
    _call(SPECS[fname])  # the baseline of every corruption below is a valid call


@pytest.mark.parametrize("fname", sorted(SPECS))
@FUZZ
@given(data=st.data())
def test_bad_input_is_refused_naming_the_argument(fname, data):
    sp = SPECS[fname]
    name = data.draw(st.sampled_from(sorted(sp["bad"])), label="argument")
    arg = sp["bad"][name]
    value = _default(name, sp)
    options = _corruptions(arg, value, data)
    group = [n for n, a in sp["bad"].items() if arg.rows and a.rows == arg.rows]
    if len(group) > 1 and np.ndim(value) >= 1 and len(value) > 1:
        options["one row too few"] = _rows_cut(value, arg.kind)
    label = data.draw(st.sampled_from(sorted(options)), label="corruption")
    with pytest.raises((ValueError, TypeError)) as info:
        _call(sp, name, options[label])
    want = arg.expect or name
    msg = str(info.value)
    assert want in msg, f"{fname}({name}={label}): message does not name {want!r}: {msg}"
    if label == "one row too few":  # a mismatch names both sides
        others = [n for n in group if n != name]
        assert any(re.search(rf"\b{n}\b", msg) for n in others), f"{fname}({name}): message names only {name}: {msg}"


def test_every_public_function_has_a_spec():
    missing = []
    for mod in MODULES:
        for name in getattr(sl, mod).__all__:
            if name not in SPECS and name not in NOT_CALLED:
                missing.append(f"{mod}.{name}")
    assert not missing, f"public functions without a bad-input spec in tests/test_bad_inputs.py: {missing}"
