"""RPE of trajectories with a known constant drift gives the known values."""

from __future__ import annotations

import numpy as np
import pytest

from changing_slam_ros.core.geometry.se3 import make_pose, quat_to_rot
from changing_slam_ros.core.geometry.trajectory import Trajectory
from changing_slam_ros.errors import EvalError
from changing_slam_ros.eval.rpe import DeltaUnit, frame_pairs, rotation_angle_deg, rpe, time_pairs


def _rot_z(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _moving_gt(rng: np.random.Generator, n: int, dt: float) -> np.ndarray:
    poses = [np.eye(4)]
    for _ in range(n - 1):
        q = np.r_[rng.normal(scale=0.02, size=3), 1.0]
        step = make_pose(quat_to_rot(q / np.linalg.norm(q)), rng.normal(scale=0.03, size=3))
        poses.append(poses[-1] @ step)
    return np.array(poses)


def test_constant_drift_per_frame_gives_its_translation_and_angle_on_every_frame_pair() -> None:
    # Estimate motion = true motion followed by a constant drift D each frame:
    # P_i^-1 P_i+1 = (Q_i^-1 Q_i+1) D, hence E_i = D for every consecutive pair.
    rng = np.random.default_rng(1)
    n, dt = 120, 1.0 / 30.0
    q = _moving_gt(rng, n, dt)
    drift = make_pose(_rot_z(np.radians(0.5)) @ quat_to_rot(np.array([0.1, 0.0, 0.0, 1.0]) / np.hypot(0.1, 1.0)),
                      np.array([0.003, -0.004, 0.0]))  # 5 mm and a known angle per frame
    p = [q[0]]
    for i in range(n - 1):
        p.append(p[-1] @ np.linalg.inv(q[i]) @ q[i + 1] @ drift)
    stamps = np.arange(n) * dt
    gt = Trajectory.from_poses(stamps, q)
    est = Trajectory.from_poses(stamps, np.array(p))
    res = rpe(gt, est, delta=1, delta_unit=DeltaUnit.FRAMES)
    angle = float(rotation_angle_deg(drift[:3, :3]))
    assert len(res.pairs) == n - 1
    np.testing.assert_allclose(res.trans_errors_m, 0.005, atol=1e-9)
    np.testing.assert_allclose(res.rot_errors_deg, angle, atol=1e-7)
    assert res.trans.rmse == pytest.approx(0.005, abs=1e-9)
    assert res.trans.std == pytest.approx(0.0, abs=1e-9)
    assert res.rot.rmse == pytest.approx(angle, abs=1e-7)


def test_constant_screw_drift_accumulates_linearly_over_one_second() -> None:
    # Ground truth stands still; the estimate screws about z: 2 mm and 0.1 deg per frame at 10 Hz.
    # Over 1 s (10 frames) the drift is 20 mm and 1 deg.
    n = 50
    stamps = 100.0 + np.arange(n) * 0.1
    step = make_pose(_rot_z(np.radians(0.1)), np.array([0.0, 0.0, 0.002]))
    p = [np.eye(4)]
    for _ in range(n - 1):
        p.append(p[-1] @ step)
    gt = Trajectory.from_poses(stamps, np.tile(np.eye(4), (n, 1, 1)))
    est = Trajectory.from_poses(stamps, np.array(p))
    per_s = rpe(gt, est, delta=1.0, delta_unit=DeltaUnit.SECONDS, all_pairs=True, rel_tol=0.05)
    assert len(per_s.pairs) == n - 10
    assert (per_s.pairs[:, 1] - per_s.pairs[:, 0]).tolist() == [10] * (n - 10)
    np.testing.assert_allclose(per_s.trans_errors_m, 0.020, atol=1e-9)
    np.testing.assert_allclose(per_s.rot_errors_deg, 1.0, atol=1e-7)
    per_frame = rpe(gt, est, delta=1, delta_unit=DeltaUnit.FRAMES)
    np.testing.assert_allclose(per_frame.trans_errors_m, 0.002, atol=1e-9)
    np.testing.assert_allclose(per_frame.rot_errors_deg, 0.1, atol=1e-7)
    chained = rpe(gt, est, delta=1.0, delta_unit=DeltaUnit.SECONDS, all_pairs=False, rel_tol=0.05)
    assert chained.pairs[:, 0].tolist() == [0, 10, 20, 30]


def test_sim3_rpe_removes_a_global_scale_error() -> None:
    rng = np.random.default_rng(5)
    q = _moving_gt(rng, 80, 0.1)
    p = q.copy()
    p[:, :3, 3] *= 0.3  # monocular estimate at a third of the true scale
    stamps = np.arange(80) * 0.1
    gt = Trajectory.from_poses(stamps, q)
    est = Trajectory.from_poses(stamps, p)
    assert rpe(gt, est).trans.rmse > 0.01
    res = rpe(gt, est, sim3=True)
    assert res.alignment.scale == pytest.approx(1 / 0.3, rel=1e-9)
    assert res.trans.max == pytest.approx(0.0, abs=1e-9)


def test_frame_pairs_are_consecutive_like_evo_unless_all_pairs() -> None:
    assert frame_pairs(7, 3).tolist() == [[0, 3], [3, 6]]
    assert frame_pairs(5, 3, all_pairs=True).tolist() == [[0, 3], [1, 4]]
    assert frame_pairs(4, 1).tolist() == [[0, 1], [1, 2], [2, 3]]


def test_time_pairs_skip_gaps_outside_the_tolerance() -> None:
    stamps = np.array([0.0, 0.5, 1.0, 1.5, 4.0, 5.02, 6.5])
    pairs = time_pairs(stamps, 1.0, rel_tol=0.1, all_pairs=True)
    assert pairs.tolist() == [[0, 2], [1, 3], [4, 5]]


def test_rotation_angle_is_accurate_for_tiny_and_half_turn_rotations() -> None:
    assert float(rotation_angle_deg(_rot_z(1e-9))) == pytest.approx(np.degrees(1e-9), rel=1e-6)
    assert float(rotation_angle_deg(_rot_z(np.pi))) == pytest.approx(180.0, abs=1e-9)


def test_a_delta_longer_than_the_trajectory_raises_an_error() -> None:
    stamps = np.arange(5) * 0.1
    traj = Trajectory.from_poses(stamps, np.tile(np.eye(4), (5, 1, 1)))
    with pytest.raises(EvalError, match="found no pose pairs among 5 associated poses"):
        rpe(traj, traj, delta=1.0, delta_unit=DeltaUnit.SECONDS)
    with pytest.raises(EvalError, match="whole number"):
        rpe(traj, traj, delta=1.5, delta_unit=DeltaUnit.FRAMES)
