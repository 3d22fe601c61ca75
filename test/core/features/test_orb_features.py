"""ORB extraction: budget, spread over the grid, undistortion and depth / virtual stereo lookup."""

from __future__ import annotations

import cv2
import numpy as np
from helpers import FR1_XYZ_10, require

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.features.orb_features import FeatureConfig, OrbExtractor
from changing_slam_ros.io.dataset import open_dataset


def _first_frame():
    return next(iter(open_dataset(require(FR1_XYZ_10), "tum_fr1")))


def test_keypoints_fill_the_budget_and_spread_over_the_grid() -> None:
    frame = _first_frame()
    cfg = FeatureConfig(n_features=1000)
    feats = OrbExtractor(cfg, frame.camera).extract(frame.rgb, frame.depth_m)
    assert 900 <= len(feats) <= 1000
    cols = (feats.raw_px[:, 0] * cfg.grid_cols / 640).astype(int)
    rows = (feats.raw_px[:, 1] * cfg.grid_rows / 480).astype(int)
    counts = np.bincount(rows * cfg.grid_cols + cols, minlength=cfg.grid_cols * cfg.grid_rows)
    # Plain ORB with the same budget piles corners into textured cells.
    gray = cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY)
    plain = np.array([k.pt for k in cv2.ORB_create(nfeatures=1000, edgeThreshold=19, fastThreshold=12).detect(gray, None)])
    plain_counts = np.bincount(
        (plain[:, 1] * cfg.grid_rows / 480).astype(int) * cfg.grid_cols + (plain[:, 0] * cfg.grid_cols / 640).astype(int),
        minlength=cfg.grid_cols * cfg.grid_rows,
    )
    assert counts.max() <= 0.03 * len(feats) < 0.5 * plain_counts.max()
    assert (counts > 0).mean() > (plain_counts > 0).mean() + 0.05
    assert set(np.unique(feats.octaves)) >= {0, 1, 2, 3}
    assert feats.descriptors.shape == (len(feats), 32) and feats.descriptors.dtype == np.uint8


def test_keypoints_are_undistorted_with_the_camera_model() -> None:
    frame = _first_frame()
    feats = OrbExtractor(FeatureConfig(), frame.camera).extract(frame.rgb, frame.depth_m)
    cam = frame.camera
    assert cam.has_distortion
    # Re-distorting the undistorted points gives back the detected ones.
    rays = np.column_stack([(feats.keypoints_px[:, 0] - cam.cx) / cam.fx, (feats.keypoints_px[:, 1] - cam.cy) / cam.fy, np.ones(len(feats))])
    back, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), cam.K, np.array(cam.dist))
    assert np.abs(back.reshape(-1, 2) - feats.raw_px).max() < 0.05
    assert np.abs(feats.keypoints_px - feats.raw_px).max() > 1.0  # distortion is not negligible here


def test_depth_lookup_range_and_virtual_stereo_coordinate() -> None:
    frame = _first_frame()
    cfg = FeatureConfig(min_depth_m=0.5, max_depth_m=2.0, bf_m_px=40.0)
    feats = OrbExtractor(cfg, frame.camera).extract(frame.rgb, frame.depth_m)
    has = feats.depths_m > 0
    assert has.mean() > 0.5
    assert feats.depths_m[has].min() >= 0.5 and feats.depths_m[has].max() <= 2.0
    u = np.rint(feats.raw_px[has]).astype(int)
    np.testing.assert_allclose(feats.depths_m[has], frame.depth_m[u[:, 1], u[:, 0]], rtol=1e-6)
    np.testing.assert_allclose(feats.u_right[has], feats.keypoints_px[has, 0] - 40.0 / feats.depths_m[has])
    assert (feats.u_right[~has] == -1).all()


def test_black_image_gives_no_features() -> None:
    cam = CameraIntrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)
    feats = OrbExtractor(FeatureConfig(), cam).extract(np.zeros((480, 640, 3), np.uint8), np.ones((480, 640), np.float32))
    assert len(feats) == 0
