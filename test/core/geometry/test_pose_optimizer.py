"""Motion-only pose optimisation recovers known poses from synthetic matches with outliers."""

from __future__ import annotations

import numpy as np

from changing_slam_ros.core.geometry.pose_optimizer import (
    PinholeStereo,
    PoseObservations,
    optimize_pose,
    se3_exp_left,
)
from changing_slam_ros.core.geometry.se3 import rotation_angle_rad

CAM = PinholeStereo(fx=525.0, fy=525.0, cx=319.5, cy=239.5, bf=40.0)


def _synthetic(rng: np.random.Generator, n: int, outlier_fraction: float, stereo_fraction: float):
    T_true = se3_exp_left(np.array([0.1, -0.2, 0.05, 0.3, -0.1, 0.2]))
    pc = np.column_stack([rng.uniform(-2, 2, n), rng.uniform(-1.5, 1.5, n), rng.uniform(1, 5, n)])
    R, t = T_true[:3, :3], T_true[:3, 3]
    points_w = (pc - t) @ R  # inverse transform: pw = R^T (pc - t)
    levels = rng.integers(0, 4, n)
    sigma = 1.2**levels
    u = CAM.fx * pc[:, 0] / pc[:, 2] + CAM.cx + rng.normal(0, 1, n) * sigma
    v = CAM.fy * pc[:, 1] / pc[:, 2] + CAM.cy + rng.normal(0, 1, n) * sigma
    ur = u - CAM.bf / pc[:, 2] + rng.normal(0, 1, n) * sigma
    ur = np.where(rng.random(n) < stereo_fraction, ur, -1.0)
    n_out = int(outlier_fraction * n)
    bad = rng.choice(n, n_out, replace=False)
    u[bad] = rng.uniform(0, 640, n_out)
    v[bad] = rng.uniform(0, 480, n_out)
    obs = PoseObservations(points_w, np.column_stack([u, v]), ur, 1.0 / sigma**2)
    truth = np.zeros(n, bool)
    truth[bad] = True
    return T_true, obs, truth


def _errors(T_est: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    d = np.linalg.inv(T_true) @ T_est
    return float(np.linalg.norm(d[:3, 3])), float(np.degrees(rotation_angle_rad(d[:3, :3])))


def test_pose_is_recovered_with_30_percent_outliers_rgbd() -> None:
    rng = np.random.default_rng(1)
    T_true, obs, is_outlier = _synthetic(rng, 400, 0.3, 0.7)
    T0 = se3_exp_left(np.array([0.03, 0.02, -0.03, 0.05, 0.05, -0.04])) @ T_true
    res = optimize_pose(T0, obs, CAM)
    t_err, r_err = _errors(res.T_cam_world, T_true)
    assert t_err < 0.01 and r_err < 0.2
    # Nearly every injected outlier is flagged and nearly every true match kept.
    assert (~res.inliers[is_outlier]).mean() > 0.95
    assert res.inliers[~is_outlier].mean() > 0.85  # chi2 95 % gates drop ~5-10 %


def test_pose_is_recovered_from_monocular_matches_only() -> None:
    rng = np.random.default_rng(2)
    T_true, obs, _ = _synthetic(rng, 300, 0.3, 0.0)
    T0 = se3_exp_left(np.array([0.02, -0.02, 0.02, 0.03, -0.03, 0.03])) @ T_true
    res = optimize_pose(T0, obs, CAM)
    t_err, r_err = _errors(res.T_cam_world, T_true)
    assert t_err < 0.03 and r_err < 0.3


def test_too_few_matches_returns_no_inliers() -> None:
    obs = PoseObservations(np.ones((2, 3)), np.ones((2, 2)), -np.ones(2), np.ones(2))
    res = optimize_pose(np.eye(4), obs, CAM)
    assert res.n_inliers == 0


def test_two_iterations_per_round_reach_the_six_iteration_pose() -> None:
    """Gauss-Newton converges in two steps per round from a tracking-sized start error: the cheaper setting
    (`tracking.pose_iterations_per_round`) ends within 1e-6 m / 1e-5 deg of the default with the same inliers."""
    rng = np.random.default_rng(3)
    T_true, obs, _ = _synthetic(rng, 500, 0.2, 0.7)
    T0 = se3_exp_left(np.array([0.01, -0.01, 0.01, 0.02, 0.02, -0.02])) @ T_true
    full = optimize_pose(T0, obs, CAM)
    short = optimize_pose(T0, obs, CAM, iterations=2)
    t_diff, r_diff = _errors(short.T_cam_world, full.T_cam_world)
    assert t_diff < 1e-6 and r_diff < 1e-5
    assert np.array_equal(short.inliers, full.inliers)
    one = optimize_pose(T0, obs, CAM, iterations=1)  # one step per round is visibly short of it
    assert _errors(one.T_cam_world, full.T_cam_world)[0] > t_diff
