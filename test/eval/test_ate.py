"""ATE on synthetic trajectories with known errors."""

from __future__ import annotations

import numpy as np
import pytest

from changing_slam_ros.core.geometry.se3 import quat_to_rot
from changing_slam_ros.core.geometry.trajectory import Trajectory
from changing_slam_ros.errors import EvalError
from changing_slam_ros.eval.alignment import Alignment
from changing_slam_ros.eval.ate import ate


def _gt(n: int = 300, seed: int = 0) -> Trajectory:
    rng = np.random.default_rng(seed)
    stamps = 1000.0 + np.arange(n) / 30.0
    positions = np.cumsum(rng.normal(scale=0.02, size=(n, 3)), axis=0)
    quats = rng.normal(size=(n, 4))
    return Trajectory(stamps, positions, quats / np.linalg.norm(quats, axis=1, keepdims=True))


def test_without_alignment_a_constant_offset_is_the_error_of_every_pose() -> None:
    gt = _gt()
    est = Trajectory(gt.stamps_s, gt.positions + np.array([0.03, 0.0, -0.04]), gt.quats_xyzw)
    raw = ate(gt, est, align=False)
    np.testing.assert_allclose(raw.errors_m, 0.05, atol=1e-12)
    assert raw.stats.rmse == pytest.approx(0.05, abs=1e-12)
    assert raw.to_dict()["alignment"] == "none"
    assert ate(gt, est).stats.max == pytest.approx(0.0, abs=1e-12)  # SE(3) alignment removes it


def test_a_rigidly_moved_and_rescaled_estimate_has_zero_error_after_sim3_alignment() -> None:
    gt = _gt(seed=1)
    q = np.array([0.3, -0.2, 0.5, 0.8])
    moved = Alignment(R_gt_est=quat_to_rot(q / np.linalg.norm(q)), t_gt_est=np.array([5.0, -2.0, 1.0]),
                      scale=0.25).apply(gt)
    assert ate(gt, moved).stats.rmse > 0.01  # SE(3) cannot undo the scale
    res = ate(gt, moved, sim3=True)
    assert res.stats.max == pytest.approx(0.0, abs=1e-10)
    assert res.alignment.scale == pytest.approx(4.0, rel=1e-10)
    np.testing.assert_allclose(res.est_aligned.positions, gt.positions, atol=1e-10)


def test_a_single_displaced_pose_gives_the_known_error_without_alignment() -> None:
    gt = _gt(n=100)
    pos = gt.positions.copy()
    pos[40] += np.array([0.0, 0.3, 0.4])
    res = ate(gt, Trajectory(gt.stamps_s, pos, gt.quats_xyzw), align=False)
    assert res.stats.max == pytest.approx(0.5, abs=1e-12)
    assert res.stats.rmse == pytest.approx(np.sqrt(0.25 / 100), abs=1e-12)
    assert res.stats.median == 0.0
    assert res.stats.std == pytest.approx(np.std(np.r_[np.zeros(99), 0.5]), abs=1e-12)


def test_an_estimate_at_a_lower_rate_is_evaluated_on_its_own_poses_only() -> None:
    gt = _gt()
    est = gt.subset(np.arange(0, len(gt), 3))
    res = ate(gt, est)
    assert res.stats.count == len(est) == 100
    assert res.association.gt_indices.tolist() == list(range(0, 300, 3))


def test_ate_names_both_trajectories_when_too_few_poses_associate() -> None:
    gt = _gt()
    with pytest.raises(EvalError, match=r"est\.txt vs gt\.txt: alignment needs at least 3"):
        ate(gt, gt.subset(np.arange(2)), gt_name="gt.txt", est_name="est.txt")
