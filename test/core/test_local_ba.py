"""Local bundle adjustment (gtsam) on a synthetic map with known ground truth."""

from __future__ import annotations

import numpy as np

from changing_slam_ros.core.backend.local_ba import LocalBAConfig, local_bundle_adjust
from changing_slam_ros.core.camera import CameraIntrinsics
from changing_slam_ros.core.keyframe import Keyframe
from changing_slam_ros.core.pose_optimizer import se3_exp_left
from changing_slam_ros.core.se3 import invert, make_pose, rotation_angle_rad
from changing_slam_ros.core.slam_map import SlamMap

CAM = CameraIntrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)
BF = 40.0


def _build_map(rng: np.random.Generator, pose_noise: float, point_noise_m: float):
    """Five keyframes moving sideways past 400 points; returns (map, true poses, true points)."""
    pts_true = np.column_stack([rng.uniform(-2, 2, 400), rng.uniform(-1.5, 1.5, 400), rng.uniform(2, 5, 400)])
    poses_true = [make_pose(np.eye(3), np.array([0.1 * k, 0.02 * k, 0.0])) for k in range(5)]
    m = SlamMap(0)
    m.points.add(
        pts_true + rng.normal(0, point_noise_m, pts_true.shape), np.zeros((400, 32), np.uint8), 0,
        np.arange(400), np.zeros(3), np.zeros(400, np.int64), np.array([1.2**i for i in range(8)]),
    )
    for k, T in enumerate(poses_true):
        pc = (pts_true - T[:3, 3]) @ T[:3, :3]
        uv = CAM.project(pc) + rng.normal(0, 0.5, (400, 2))
        depth = pc[:, 2].astype(np.float32)
        depth[::3] = 0.0  # a third monocular
        T_est = T if k < 2 else se3_exp_left(rng.normal(0, pose_noise, 6)) @ T
        kf = Keyframe(k, k, T_est, CAM, uv.astype(np.float32), np.zeros(400, np.int8),
                      np.zeros((400, 32), np.uint8), depth, np.arange(400, dtype=np.int64))
        m.add_keyframe(kf)
    for k in range(5):
        m.update_connections(k)
    return m, poses_true, pts_true


def _pose_errors(m: SlamMap, poses_true: list[np.ndarray]) -> tuple[float, float]:
    t, r = [], []
    for k, T in enumerate(poses_true):
        d = invert(T) @ m.keyframes[k].T_world_cam
        t.append(np.linalg.norm(d[:3, 3]))
        r.append(np.degrees(rotation_angle_rad(d[:3, :3])))
    return max(t), max(r)


def test_local_ba_lowers_reprojection_error_and_recovers_perturbed_poses() -> None:
    rng = np.random.default_rng(3)
    m, poses_true, pts_true = _build_map(rng, pose_noise=0.02, point_noise_m=0.02)
    t_before, _ = _pose_errors(m, poses_true)
    res = local_bundle_adjust(m, 4, LocalBAConfig(n_window=10, iterations=15, bf_m_px=BF))
    t_after, r_after = _pose_errors(m, poses_true)
    assert res.n_fixed >= 1  # the gauge is fixed by at least one keyframe
    assert res.rms_after_px < 0.5 * res.rms_before_px
    assert res.rms_after_px < 1.5
    assert t_before > 0.02 and t_after < 0.005 and r_after < 0.1
    err_pts = np.linalg.norm(m.points.positions[:400] - pts_true, axis=1)
    assert np.median(err_pts) < 0.04  # depth is weak at 2-5 m with a 7.6 cm virtual baseline


def test_local_ba_erases_gross_outlier_observations() -> None:
    rng = np.random.default_rng(4)
    m, poses_true, _ = _build_map(rng, pose_noise=0.005, point_noise_m=0.005)
    kf = m.keyframes[3]
    kf.keypoints_px[:20] += 40.0  # 20 wrong matches
    res = local_bundle_adjust(m, 4, LocalBAConfig(n_window=10, iterations=15, bf_m_px=BF))
    assert res.n_outliers_removed >= 20
    assert (kf.point_ids[:20] == -1).all()
    assert (kf.point_ids[20:] >= 0).mean() > 0.95
    t_after, _ = _pose_errors(m, poses_true)
    assert t_after < 0.005
