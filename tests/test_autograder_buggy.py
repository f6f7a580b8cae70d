"""Realistic bugs lose points on the buggy function, and only there.

Each variant is an independent solution (``autograder_fixtures/solutions``) with
one textual change inside one contract function.
"""

from __future__ import annotations

import sys
from functools import lru_cache
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent / "autograder_fixtures"))

from agtest import variant  # noqa: E402

from autograder.engine import grade  # noqa: E402
from autograder.exercises import EXERCISES, get_exercise  # noqa: E402

_R1 = "    r1 = rot1 - rng.normal(0.0, np.sqrt(a1 * rot1**2 + a2 * trans**2), size=M)\n"
_TR = "    tr = trans - rng.normal(0.0, np.sqrt(a3 * trans**2 + a4 * (rot1**2 + rot2**2)), size=M)\n"
_R2 = "    r2 = rot2 - rng.normal(0.0, np.sqrt(a1 * rot2**2 + a2 * trans**2), size=M)\n"
#: Right marginals, wrong joint law: every noise is a multiple of one draw (F5 of the 31st attack report) ...
_ODO_SHARED_DRAW = [
    (_R1, "    e = rng.standard_normal(M)\n    r1 = rot1 - np.sqrt(a1 * rot1**2 + a2 * trans**2) * e\n"),
    (_TR, "    tr = trans - np.sqrt(a3 * trans**2 + a4 * (rot1**2 + rot2**2)) * e\n"),
    (_R2, "    r2 = rot2 - np.sqrt(a1 * rot2**2 + a2 * trans**2) * e\n")]
#: ... or only the two rotations share one (a copy-paste slip).
_ODO_ROT2_REUSES_ROT1 = [
    (_R1, "    e1 = rng.standard_normal(M)\n    r1 = rot1 - np.sqrt(a1 * rot1**2 + a2 * trans**2) * e1\n"),
    (_R2, "    r2 = rot2 - np.sqrt(a1 * rot2**2 + a2 * trans**2) * e1\n")]

#: Right marginals, independent noises within a pose, but one pose's draws reused for another: as is, or negated
#: (antithetic pairs); the hidden "each pose moves with its own noise" test finds such a pair.
_PAIRED = ("    e = rng.standard_normal(((M + 1) // 2, 3))\n    e = np.concatenate([e, {}e])[:M]\n"
           "    r1 = rot1 - np.sqrt(a1 * rot1**2 + a2 * trans**2) * e[:, 0]\n")
_ODO_PAIRS = [(_R1, _PAIRED.format("")),
              (_TR, "    tr = trans - np.sqrt(a3 * trans**2 + a4 * (rot1**2 + rot2**2)) * e[:, 1]\n"),
              (_R2, "    r2 = rot2 - np.sqrt(a1 * rot2**2 + a2 * trans**2) * e[:, 2]\n")]
_ODO_ANTITHETIC = [(_R1, _PAIRED.format("-"))] + _ODO_PAIRS[1:]

VARIANTS = [
    # ---------------------------------------------------------------- exercise 1
    ("motion_sensor_models", "velocity_motion", "sign error in the Jacobian G",
     [("[[1.0, 0.0, -r * np.cos(th) + r * np.cos(th2)],", "[[1.0, 0.0, r * np.cos(th) - r * np.cos(th2)],")]),
    ("motion_sensor_models", "velocity_motion", "heading not wrapped",
     [("py + r * np.cos(th) - r * np.cos(th2), wrap(th2)])", "py + r * np.cos(th) - r * np.cos(th2), th2])")]),
    ("motion_sensor_models", "sample_motion_model_odometry", "standard deviation used as the variance",
     [("rng.normal(0.0, np.sqrt(a1 * rot1**2 + a2 * trans**2), size=M)",
       "rng.normal(0.0, a1 * rot1**2 + a2 * trans**2, size=M)")]),
    ("motion_sensor_models", "sample_motion_model_odometry", "one standard normal shared by the three noises",
     _ODO_SHARED_DRAW),
    ("motion_sensor_models", "sample_motion_model_odometry", "the rot2 noise reuses the rot1 noise's draw",
     _ODO_ROT2_REUSES_ROT1),
    ("motion_sensor_models", "sample_motion_model_odometry", "one pose's noises reused for another", _ODO_PAIRS),
    ("motion_sensor_models", "sample_motion_model_odometry", "antithetic pairs of poses", _ODO_ANTITHETIC),
    ("motion_sensor_models", "motion_model_odometry", "variances evaluated at the control, not the hypothesis",
     [("p1 = _normal(wrap(u[0] - rot1_h), a1 * rot1_h**2 + a2 * trans_h**2)",
       "p1 = _normal(wrap(u[0] - rot1_h), a1 * u[0]**2 + a2 * u[1]**2)")]),
    ("motion_sensor_models", "landmark_measurement", "sign error in the bearing row of Hx",
     [("Hx = np.array([[-dx / r, -dy / r, 0.0], [dy / q, -dx / q, -1.0]])",
       "Hx = np.array([[-dx / r, -dy / r, 0.0], [-dy / q, dx / q, -1.0]])")]),
    ("motion_sensor_models", "landmark_from_measurement", "robot heading forgotten",
     [("np.array([x[0] + z[0] * np.cos(x[2] + z[1]), x[1] + z[0] * np.sin(x[2] + z[1])])",
       "np.array([x[0] + z[0] * np.cos(z[1]), x[1] + z[0] * np.sin(z[1])])")]),
    ("motion_sensor_models", "beam_range_finder_model", "truncated normal not renormalised",
     [("_normal(z - z_star, sigma_hit**2) / eta", "_normal(z - z_star, sigma_hit**2)")]),
    # ---------------------------------------------------------------- exercise 2
    ("ekf_localization", "ekf_predict", "Jacobian G at the predicted mean (wrong linearisation point)",
     [("    mu_bar, G, V = _motion(mu, u, dt)\n", "    mu_bar, _, V = _motion(mu, u, dt)\n    _, G, _ = _motion(mu_bar, u, dt)\n")]),
    ("ekf_localization", "ekf_predict", "control noise M added without V",
     [("return mu_bar, G @ Sigma @ G.T + V @ M @ V.T", "return mu_bar, G @ Sigma @ G.T + np.pad(M, ((0, 1), (0, 1)))")]),
    ("ekf_localization", "ekf_update", "Q^-1 instead of S^-1 in the gain",
     [("K = Sigma_bar @ H.T @ np.linalg.inv(S)", "K = Sigma_bar @ H.T @ np.linalg.inv(Q)")]),
    ("ekf_localization", "ekf_update", "bearing innovation not wrapped",
     [("    nu[1] = wrap(nu[1])\n    mu = mu_bar + K @ nu", "    mu = mu_bar + K @ nu")]),
    ("ekf_localization", "associate_ml", "maximum likelihood (det S) instead of nearest neighbour",
     [("d = nu @ np.linalg.solve(S, nu)", "d = nu @ np.linalg.solve(S, nu) + np.log(np.linalg.det(S))")]),
    ("ekf_localization", "associate_ml", "a distance equal to the gate rejected",
     [("return best if best_d <= gate else -1", "return best if best_d < gate else -1")]),
    # ---------------------------------------------------------------- exercise 3
    ("particle_filter", "normalize_log_weights", "no shift by the maximum (overflow)",
     [("a = log_w - np.max(log_w)", "a = log_w")]),
    ("particle_filter", "effective_sample_size", "1 / sum(w^2) for unnormalised weights",
     [("return float(w.sum() ** 2 / np.sum(w**2))", "return float(1.0 / np.sum(w**2))")]),
    ("particle_filter", "low_variance_resample", "off-by-one pointer r + (m + 1) / M",
     [("U = r + m / M", "U = r + (m + 1) / M")]),
    ("particle_filter", "landmark_likelihood", "bearing difference not wrapped",
     [("    nu[:, 1] = (nu[:, 1] + np.pi) % (2 * np.pi) - np.pi\n", "")]),
    ("particle_filter", "landmark_likelihood", "normalising constant missing",
     [("return np.exp(-0.5 * d) / (2 * np.pi * np.sqrt(np.linalg.det(Q)))", "return np.exp(-0.5 * d)")]),
    # ---------------------------------------------------------------- exercise 4
    ("ekf_slam", "ekf_slam_predict", "cross-covariances not propagated (robot block only)",
     [("    Sigma_bar = G @ Sigma @ G.T + F.T @ (V @ M @ V.T) @ F\n",
       "    Sigma_bar = Sigma.copy()\n    Sigma_bar[:3, :3] = Gx @ Sigma[:3, :3] @ Gx.T + V @ M @ V.T\n")]),
    ("ekf_slam", "ekf_slam_measurement", "sign error in the landmark columns of H",
     [("h = np.array([[-dx / r, -dy / r, 0, dx / r, dy / r], [dy / q, -dx / q, -1, -dy / q, dx / q]])",
       "h = np.array([[-dx / r, -dy / r, 0, -dx / r, -dy / r], [dy / q, -dx / q, -1, dy / q, -dx / q]])")]),
    ("ekf_slam", "ekf_slam_init_landmark", "robot heading forgotten",
     [("out[a] = mu[0] + z[0] * np.cos(z[1] + mu[2])", "out[a] = mu[0] + z[0] * np.cos(z[1])"),
      ("out[a + 1] = mu[1] + z[0] * np.sin(z[1] + mu[2])", "out[a + 1] = mu[1] + z[0] * np.sin(z[1])")]),
    ("ekf_slam", "ekf_slam_update", "Q^-1 instead of S^-1 in the gain",
     [("K = Sigma_bar @ H.T @ np.linalg.inv(S)", "K = Sigma_bar @ H.T @ np.linalg.inv(Q)")]),
    ("ekf_slam", "ekf_slam_associate", "off-by-one: slot n_seen considered",
     [("for k in range(n_seen):", "for k in range(min(n_seen + 1, (len(mu_bar) - 3) // 2)):")]),
    # ---------------------------------------------------------------- exercise 5
    ("fastslam", "fastslam_update_landmark", "weight with Q instead of S (the course text's erratum)",
     [("w[k] = np.exp(-0.5 * nu @ np.linalg.solve(S, nu)) / (2 * np.pi * np.sqrt(np.linalg.det(S)))",
       "w[k] = np.exp(-0.5 * nu @ np.linalg.solve(Q, nu)) / (2 * np.pi * np.sqrt(np.linalg.det(Q)))")]),
    ("fastslam", "fastslam_update_landmark", "bearing innovation not wrapped",
     [("        nu[1] = wrap(nu[1])\n        mu_new[k]", "        mu_new[k]")]),
    ("fastslam", "fastslam_init_landmark", "H instead of H^-1",
     [("Hi = np.linalg.inv(H)", "Hi = H")]),
    ("fastslam", "fastslam_init_landmark", "missing transpose: H^-1 Q H^-1",
     [("Sigma[k] = Hi @ Q @ Hi.T", "Sigma[k] = Hi @ Q @ Hi")]),
    # ---------------------------------------------------------------- exercise 6
    ("graph_slam", "edge_error", "heading error not wrapped",
     [("e[2] = wrap(xj[2] - xi[2] - z[2])", "e[2] = xj[2] - xi[2] - z[2]")]),
    ("graph_slam", "edge_error", "A's rotation column without R_z^T",
     [("A[:2, 2] = Rz.T @ dRiT @ d", "A[:2, 2] = dRiT @ d")]),
    ("graph_slam", "build_linear_system", "an off-diagonal block assigned instead of added (repeated edges lost)",
     [("H[si, sj] += A.T @ W @ B", "H[si, sj] = A.T @ W @ B")]),
    ("graph_slam", "gauss_newton_step", "sign error: H dx = b",
     [("step = np.linalg.solve(H[3:, 3:], -g[3:])", "step = np.linalg.solve(H[3:, 3:], g[3:])")]),
    ("graph_slam", "gauss_newton_step", "headings not wrapped",
     [("    out[1:, 2] = np.arctan2(np.sin(out[1:, 2]), np.cos(out[1:, 2]))\n", "")]),
    ("graph_slam", "icp_align", "reflection case not corrected",
     [("D = np.diag([1.0, np.sign(np.linalg.det(U @ Vt))])", "D = np.eye(2)")]),
    ("graph_slam", "icp_align", "translation from the centroids the wrong way round",
     [("return R, mq - R @ mp", "return R, mp - R @ mq")]),
    # ---------------------------------------------------------------- exercise 7
    ("bundle_adjustment", "so3_exp", "Rodrigues with sin(a) for sin(a)/a (the axis not normalised)",
     [("A = np.sin(a) / a", "A = np.sin(a)")]),
    ("bundle_adjustment", "so3_log", "the quaternion's half angle returned as the angle",
     [("angle = 2.0 * np.arctan2(s, qw)", "angle = np.arctan2(s, qw)")]),
    ("bundle_adjustment", "project", "J_point with R for R^T",
     [("Jx[k] = D @ R.T", "Jx[k] = D @ R")]),
    ("bundle_adjustment", "project", "rotation block of J_pose with the wrong sign",
     [("Jp[k, :, 3:] = D @ _hat(np.array([X, Y, Z]))", "Jp[k, :, 3:] = -D @ _hat(np.array([X, Y, Z]))")]),
    ("bundle_adjustment", "triangulate", "T_wc used as the world-to-camera transform",
     [("Ps.append(K @ np.hstack([R.T, (-R.T @ t)[:, None]]))", "Ps.append(K @ np.hstack([R, t[:, None]]))")]),
    ("bundle_adjustment", "eight_point", "Hartley normalisation not undone (E = F)",
     [("E = T2.T @ F @ T1", "E = F")]),
    ("bundle_adjustment", "schur_complement", "the reduced right-hand side with the wrong sign",
     [("s -= W @ b[sl_]", "s += W @ b[sl_]")]),
    ("bundle_adjustment", "back_substitute", "the minus sign of -H_pp^-1 (...) dropped",
     [("out[3 * j:3 * j + 3] = -inv[j] @ (b[sl_] + H[sl_, :m] @ dx_cameras)",
       "out[3 * j:3 * j + 3] = inv[j] @ (b[sl_] + H[sl_, :m] @ dx_cameras)")]),
]


@lru_cache(maxsize=None)
def _full(exercise):
    return get_exercise(exercise)


def test_at_least_four_variants_per_exercise():
    counts = {}
    for ex, *_ in VARIANTS:
        counts[ex] = counts.get(ex, 0) + 1
    assert set(counts) == set(EXERCISES)  # every registered exercise, so a new one cannot be left out
    assert min(counts.values()) >= 4


@pytest.mark.slow
@pytest.mark.parametrize("exercise, function, bug, replacements", VARIANTS,
                         ids=[f"{v[1]}: {v[2]}" for v in VARIANTS])
def test_buggy_variant_loses_points_only_on_its_function(exercise, function, bug, replacements, tmp_path):
    path = variant(exercise, replacements, tmp_path / f"{exercise}.py")
    result = grade(path, exercise)
    scores = result.by_function()
    ex = _full(exercise)
    for fn in ex.functions:
        got, top = scores[fn]
        if fn == function:
            assert got < top, f"{bug}: {fn} kept all its points\n{result.text_report()}"
        else:
            assert got == top, f"{bug}: {fn} lost points\n{result.text_report()}"
    failed = [t for t in result.tests if t.status == "failed"]
    assert all("Hint:" in t.output and "grader could not complete" not in t.output for t in failed)


@pytest.mark.slow
@pytest.mark.parametrize("replacements", [_ODO_SHARED_DRAW, _ODO_ROT2_REUSES_ROT1], ids=["shared draw", "rot2 = rot1"])
def test_correlated_odometry_noises_fail_the_independence_test(replacements, tmp_path):
    """Noises with the right marginals but drawn from one standard normal fail "three independent noises per pose"."""
    result = grade(variant("motion_sensor_models", replacements, tmp_path / "msm.py"), "motion_sensor_models")
    odo = {t.name: t for t in result.tests if t.function == "sample_motion_model_odometry"}
    failed = {name for name, t in odo.items() if t.status == "failed"}
    name = "sample_motion_model_odometry: three independent noises per pose"
    # one draw for all three puts a pose's noises on a curve, where two of 20 000 poses come within 1e-7 of each
    # other (or of each other's negatives): the hidden "own noise" test may fail too, and rightly
    also = {"sample_motion_model_odometry: each pose moves with its own noise"} if replacements is _ODO_SHARED_DRAW \
        else set()
    assert name in failed and failed <= {name} | also, result.text_report()
    out = odo[name].output
    assert "are correlated: correlation" in out and "expected |correlation| <= 0.05" in out, out


@pytest.mark.slow
@pytest.mark.parametrize("replacements", [_ODO_PAIRS, _ODO_ANTITHETIC], ids=["reused", "antithetic"])
def test_noise_reused_across_poses_fails_the_own_noise_test(replacements, tmp_path):
    """Both scored 20/20: every marginal and the three noises of a pose are right; a pair of poses shares a draw."""
    result = grade(variant("motion_sensor_models", replacements, tmp_path / "msm.py"), "motion_sensor_models")
    odo = {t.name: t for t in result.tests if t.function == "sample_motion_model_odometry"}
    name = "sample_motion_model_odometry: each pose moves with its own noise"
    assert {n for n, t in odo.items() if t.status == "failed"} == {name}, result.text_report()
    assert "moved with the same noises" in odo[name].output, odo[name].output
