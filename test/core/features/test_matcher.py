"""Descriptor matching on real frames with ground-truth poses."""

from __future__ import annotations

import numpy as np
from helpers import FR1_XYZ_10, require

from changing_slam_ros.core.features.frame import Frame
from changing_slam_ros.core.features.matcher import ProjectionQuery, hamming, match_brute_force, search_by_projection
from changing_slam_ros.core.features.orb_features import FeatureConfig, OrbExtractor
from changing_slam_ros.core.geometry.se3 import invert, transform_points
from changing_slam_ros.io.dataset import open_dataset

CFG = FeatureConfig()


def _pair(i: int = 0, j: int = 6):
    frames = list(open_dataset(require(FR1_XYZ_10), "tum_fr1"))
    ex = OrbExtractor(CFG, frames[0].camera)
    a, b = frames[i], frames[j]
    return a, b, ex.extract(a.rgb, a.depth_m), ex.extract(b.rgb, b.depth_m)


def test_hamming_matches_bit_count() -> None:
    rng = np.random.default_rng(0)
    a = rng.integers(0, 256, (5, 32), dtype=np.uint8)
    b = rng.integers(0, 256, (5, 32), dtype=np.uint8)
    expected = [sum(bin(x ^ y).count("1") for x, y in zip(ra, rb)) for ra, rb in zip(a, b)]
    np.testing.assert_array_equal(hamming(a, b), expected)
    assert hamming(a[0], a[0]) == 0


def test_projection_search_finds_correct_matches_with_the_true_pose() -> None:
    a, b, fa, fb = _pair()
    has = np.flatnonzero(fa.depths_m > 0)
    # Map points from frame a's depth, in the world frame of the ground truth.
    pw = transform_points(a.T_world_cam_gt, a.camera.backproject(fa.keypoints_px[has], fa.depths_m[has]))
    centre = a.T_world_cam_gt[:3, 3]
    dist = np.linalg.norm(pw - centre, axis=1)
    scales = CFG.level_scales()
    query = ProjectionQuery(pw, fa.descriptors[has], has.astype(np.int64), (pw - centre) / dist[:, None],
                            dist * scales[fa.octaves[has]] / scales[-1], dist * scales[fa.octaves[has]])
    frame_b = Frame(b.stamp_ns, 1, b.camera, fb)
    T_cw = invert(b.T_world_cam_gt)
    res = search_by_projection(frame_b, T_cw, query, 8.0, scales, bf_m_px=CFG.bf_m_px)
    assert len(res.kp_indices) > 250
    assert len(np.unique(res.kp_indices)) == len(res.kp_indices)  # one point per keypoint
    proj = b.camera.project(transform_points(T_cw, pw[res.rows]))
    err = np.linalg.norm(proj - fb.keypoints_px[res.kp_indices], axis=1)
    assert np.median(err) < 2.0 and (err < 5.0).mean() > 0.9


def test_projection_search_with_a_wrong_pose_finds_little() -> None:
    a, b, fa, fb = _pair()
    has = np.flatnonzero(fa.depths_m > 0)
    pw = transform_points(a.T_world_cam_gt, a.camera.backproject(fa.keypoints_px[has], fa.depths_m[has]))
    centre = a.T_world_cam_gt[:3, 3]
    dist = np.linalg.norm(pw - centre, axis=1)
    query = ProjectionQuery(pw, fa.descriptors[has], has.astype(np.int64), (pw - centre) / dist[:, None], dist / 4, dist * 4)
    T_cw = invert(b.T_world_cam_gt)
    T_cw[:3, 3] += np.array([0.15, 0.0, 0.0])  # 15 cm off
    res = search_by_projection(Frame(b.stamp_ns, 1, b.camera, fb), T_cw, query, 4.0, CFG.level_scales(), bf_m_px=CFG.bf_m_px)
    assert len(res.kp_indices) < 60


def test_brute_force_matches_are_mostly_geometrically_right() -> None:
    a, b, fa, fb = _pair()
    ia, ib = match_brute_force(fa.descriptors, fb.descriptors, ratio=0.75)
    assert len(ia) > 200 and len(np.unique(ib)) == len(ib)
    ok = fa.depths_m[ia] > 0
    pw = transform_points(a.T_world_cam_gt, a.camera.backproject(fa.keypoints_px[ia[ok]], fa.depths_m[ia[ok]]))
    proj = b.camera.project(transform_points(invert(b.T_world_cam_gt), pw))
    err = np.linalg.norm(proj - fb.keypoints_px[ib[ok]], axis=1)
    assert (err < 5.0).mean() > 0.85
