"""Umeyama alignment recovers a known SE(3) / Sim(3) transform exactly on synthetic data."""

from __future__ import annotations

import numpy as np
import pytest

from changing_slam_ros.core.geometry.se3 import quat_to_rot
from changing_slam_ros.core.geometry.trajectory import Trajectory
from changing_slam_ros.errors import EvalError
from changing_slam_ros.eval.alignment import Alignment, align_trajectories, umeyama


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    return quat_to_rot(q / np.linalg.norm(q))


def _random_trajectory(rng: np.random.Generator, n: int = 200) -> Trajectory:
    stamps = np.arange(n) * 0.033
    positions = np.cumsum(rng.normal(scale=0.05, size=(n, 3)), axis=0)
    quats = rng.normal(size=(n, 4))
    return Trajectory(stamps, positions, quats / np.linalg.norm(quats, axis=1, keepdims=True))


@pytest.mark.parametrize("seed", range(5))
def test_se3_alignment_recovers_a_random_rigid_transform(seed: int) -> None:
    rng = np.random.default_rng(seed)
    gt = _random_trajectory(rng)
    truth = Alignment(R_gt_est=_random_rotation(rng), t_gt_est=rng.normal(scale=3.0, size=3))
    # est = truth^-1 applied to gt, so aligning est must give back `truth`.
    inverse = Alignment(R_gt_est=truth.R_gt_est.T, t_gt_est=-truth.R_gt_est.T @ truth.t_gt_est)
    est = inverse.apply(gt)
    found = align_trajectories(gt, est, with_scale=False)
    np.testing.assert_allclose(found.R_gt_est, truth.R_gt_est, atol=1e-10)
    np.testing.assert_allclose(found.t_gt_est, truth.t_gt_est, atol=1e-10)
    assert found.scale == 1.0
    aligned = found.apply(est)
    np.testing.assert_allclose(aligned.positions, gt.positions, atol=1e-10)
    np.testing.assert_allclose(aligned.poses()[:, :3, :3], gt.poses()[:, :3, :3], atol=1e-10)


@pytest.mark.parametrize("scale", [0.137, 1.0, 4.2])
def test_sim3_alignment_recovers_a_random_similarity_and_its_scale(scale: float) -> None:
    rng = np.random.default_rng(42)
    gt = _random_trajectory(rng)
    rot = _random_rotation(rng)
    trans = rng.normal(size=3)
    est_positions = ((gt.positions - trans) @ rot) / scale  # x = R^T (y - t) / s
    found = umeyama(est_positions, gt.positions, with_scale=True)
    assert found.scale == pytest.approx(scale, rel=1e-12)
    np.testing.assert_allclose(found.R_gt_est, rot, atol=1e-10)
    np.testing.assert_allclose(found.t_gt_est, trans, atol=1e-10)
    np.testing.assert_allclose(found.apply_points(est_positions), gt.positions, atol=1e-10)
    np.testing.assert_allclose(found.T_gt_est[:3, :3], scale * rot, atol=1e-10)


def test_alignment_of_a_mirrored_point_set_is_still_a_proper_rotation() -> None:
    rng = np.random.default_rng(7)
    y = rng.normal(size=(50, 3))
    x = y * np.array([1.0, 1.0, -1.0])  # a reflection: the best orthogonal map has det -1
    found = umeyama(x, y)
    assert np.linalg.det(found.R_gt_est) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(found.R_gt_est @ found.R_gt_est.T, np.eye(3), atol=1e-12)


def test_se3_alignment_minimises_the_error_with_noise() -> None:
    rng = np.random.default_rng(3)
    y = rng.normal(size=(300, 3))
    x = y + rng.normal(scale=0.01, size=y.shape)
    found = umeyama(x, y)
    best = np.sum((found.apply_points(x) - y) ** 2)
    for _ in range(20):  # any perturbed transform is worse
        d = Alignment(R_gt_est=quat_to_rot(np.r_[rng.normal(scale=1e-3, size=3), 1.0]) @ found.R_gt_est,
                      t_gt_est=found.t_gt_est + rng.normal(scale=1e-3, size=3))
        assert np.sum((d.apply_points(x) - y) ** 2) > best


def test_alignment_rejects_fewer_than_three_points_and_coincident_points() -> None:
    with pytest.raises(EvalError, match="at least 3 associated poses, got 2"):
        umeyama(np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(EvalError, match="all estimated positions coincide"):
        umeyama(np.ones((5, 3)), np.random.default_rng(0).normal(size=(5, 3)))
