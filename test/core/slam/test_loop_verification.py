"""Geometric verification: known relative poses recovered from real RGB-D frames; other places rejected."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import FR1_XYZ_10, REDKITCHEN, require

from changing_slam_ros.core.slam.geometric_verification import kabsch, verify
from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.features.orb_features import FeatureConfig, OrbExtractor
from changing_slam_ros.core.geometry.se3 import invert, make_pose, rotation_angle_rad
from changing_slam_ros.io.dataset import open_dataset


def keyframes_from(folder, config_name: str, indices: list[int]) -> list[Keyframe]:
    """Keyframes (features + depth, ground-truth pose) of the given frames of a TUM-layout folder."""
    source = open_dataset(folder, config_name)
    extractor = OrbExtractor(FeatureConfig(), source.camera)
    out = []
    for i in indices:
        frame = source.frame(i)
        f = extractor.extract(frame.rgb, frame.depth_m)
        out.append(
            Keyframe(
                id=frame.index, stamp_ns=frame.stamp_ns, T_world_cam=frame.T_world_cam_gt, camera=source.camera,
                keypoints_px=f.keypoints_px.astype(np.float32), octaves=f.octaves.astype(np.int8),
                descriptors=f.descriptors, depths_m=f.depths_m.astype(np.float32),
                point_ids=np.full(len(f), -1, np.int64),
            )
        )
    return out


def pose_error(T_est: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """Translation (m) and rotation (deg) of T_true^-1 T_est."""
    e = invert(T_true) @ T_est
    return float(np.linalg.norm(e[:3, 3])), float(np.degrees(rotation_angle_rad(e[:3, :3])))


@pytest.fixture(scope="module")
def fr1() -> list[Keyframe]:
    return keyframes_from(require(FR1_XYZ_10), "tum_fr1", [0, 3, 8])


def test_kabsch_recovers_an_exact_rigid_motion():
    rng = np.random.default_rng(0)
    p_b = rng.uniform(-1, 1, (20, 3))
    r = make_pose(np.linalg.qr(rng.normal(size=(3, 3)))[0], np.array([0.3, -0.2, 1.0]))
    if np.linalg.det(r[:3, :3]) < 0:
        r[:3, :3] *= -1
    p_a = p_b @ r[:3, :3].T + r[:3, 3]
    np.testing.assert_allclose(kabsch(p_a, p_b), r, atol=1e-10)


def test_verification_recovers_the_ground_truth_motion_between_real_fr1_frames(fr1):
    a, b3, b8 = fr1
    for b in (b3, b8):
        v = verify(a, b)
        assert v is not None
        truth = invert(a.T_world_cam) @ b.T_world_cam
        t_err, r_err = pose_error(v.T_a_b, truth)
        print(f"fr1 0->{b.id}: {v.num_inliers} inliers, rmse {v.rmse_px:.2f} px, error {100 * t_err:.2f} cm "
              f"{r_err:.2f} deg (motion {100 * np.linalg.norm(truth[:3, 3]):.1f} cm)")
        assert v.num_inliers > 200
        assert v.rmse_px < 2.5
        # fr1 motion-capture truth vs colour frames carries ~0.5 deg / few mm of its own error
        assert t_err < 0.01 and r_err < 1.5


def test_verification_of_a_frame_with_a_moved_copy_of_itself_is_exact(fr1):
    a = fr1[0]
    # the copy: the same features seen from a camera moved by a known T_a_b (points re-projected, depth recomputed)
    T_a_b = make_pose(_rot_xyz(0.05, -0.1, 0.03), np.array([0.08, -0.02, 0.05]))
    valid = a.depths_m > 0
    pts_a = a.camera.backproject(a.keypoints_px[valid].astype(np.float64), a.depths_m[valid].astype(np.float64))
    pts_b = (pts_a - T_a_b[:3, 3]) @ T_a_b[:3, :3]
    uv = a.camera.project(pts_b)
    inside = (uv[:, 0] > 0) & (uv[:, 0] < 640) & (uv[:, 1] > 0) & (uv[:, 1] < 480) & (pts_b[:, 2] > 0.1)
    rng = np.random.default_rng(5)
    b = Keyframe(
        id=99, stamp_ns=0, T_world_cam=np.eye(4), camera=a.camera,
        keypoints_px=(uv[inside] + rng.normal(0, 0.3, (inside.sum(), 2))).astype(np.float32),
        octaves=a.octaves[valid][inside], descriptors=a.descriptors[valid][inside],
        depths_m=pts_b[inside, 2].astype(np.float32), point_ids=np.full(int(inside.sum()), -1, np.int64),
    )
    v = verify(a, b)
    assert v is not None and v.num_inliers > 0.8 * len(b)
    t_err, r_err = pose_error(v.T_a_b, T_a_b)
    assert t_err < 0.002 and r_err < 0.1


def test_a_frame_of_another_place_is_rejected(fr1):
    kitchen = keyframes_from(require(REDKITCHEN), "7scenes", [0, 600])
    for a in fr1:
        for b in kitchen:
            assert verify(a, b) is None
            assert verify(b, a) is None


def test_masked_keypoints_take_no_part(fr1):
    a, b = fr1[0], fr1[1]
    mask_b = np.zeros(len(b), bool)
    mask_b[:40] = True  # only 40 keypoints allowed: too few for a loop
    assert verify(a, b, mask_b=mask_b) is None
    v = verify(a, b, mask_b=np.arange(len(b)) % 2 == 0)
    assert v is not None and np.all(v.matches[:, 1] % 2 == 0)


def _rot_xyz(rx: float, ry: float, rz: float) -> np.ndarray:
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    r_x = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    r_y = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    r_z = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return r_z @ r_y @ r_x
