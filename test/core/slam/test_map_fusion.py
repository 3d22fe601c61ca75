"""Fusion of duplicated map points between keyframes."""

from __future__ import annotations

import numpy as np

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.slam.map_fusion import fuse_into, refresh_points
from changing_slam_ros.core.geometry.se3 import make_pose
from changing_slam_ros.core.map.slam_map import SlamMap

CAM = CameraIntrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)
SCALES = np.array([1.2**i for i in range(8)])


def _keyframe(kf_id: int, T: np.ndarray, pts_w: np.ndarray, desc: np.ndarray, point_ids: np.ndarray) -> Keyframe:
    pc = (pts_w - T[:3, 3]) @ T[:3, :3]
    uv = CAM.project(pc)
    n = len(pts_w)
    return Keyframe(kf_id, kf_id, T, CAM, uv.astype(np.float32), np.zeros(n, np.int8), desc,
                    pc[:, 2].astype(np.float32), point_ids.astype(np.int64))


def test_duplicates_are_merged_and_observations_added() -> None:
    rng = np.random.default_rng(5)
    n = 150
    pts = np.column_stack([rng.uniform(-1.5, 1.5, n), rng.uniform(-1, 1, n), rng.uniform(2, 4, n)])
    desc = rng.integers(0, 256, (n, 32), dtype=np.uint8)
    T0, T1 = np.eye(4), make_pose(np.eye(3), np.array([0.1, 0.0, 0.0]))
    m = SlamMap(0)
    a = m.points.add(pts, desc, 0, np.arange(n), T0[:3, 3], np.zeros(n, np.int64), SCALES)
    m.add_keyframe(_keyframe(0, T0, pts, desc, a))
    # Keyframe 1 re-created the first 100 points from its own depth (duplicates); 50 keypoints unmatched.
    b = m.points.add(pts[:100] + 0.002, desc[:100], 1, np.arange(100), T1[:3, 3], np.zeros(100, np.int64), SCALES)
    m.add_keyframe(_keyframe(1, T1, pts, desc, np.concatenate([b, np.full(50, -1)])))
    added, merged = fuse_into(m, m.keyframes[1], a, SCALES, 40.0)
    assert merged >= 95 and added >= 45
    kf1 = m.keyframes[1]
    # Every keypoint of keyframe 1 now holds the same point as keyframe 0 at that index.
    same = kf1.point_ids == m.keyframes[0].point_ids
    assert same.mean() >= 0.9
    # Of each duplicated pair exactly one point survives, and it is seen by both keyframes.
    assert (m.points.bad[a[:100]] ^ m.points.bad[b]).mean() >= 0.9
    kept = kf1.point_ids[same]
    assert not m.points.bad[kept].any()
    assert all(set(m.points.observations[int(p)]) == {0, 1} for p in kept)
    refresh_points(m, kept, SCALES)
    assert np.all(np.abs(np.linalg.norm(m.points.normals[kept], axis=1) - 1) < 1e-9)
