"""Should an object have been seen? In view, behind a wall, out of the frustum, out of range, no depth."""

from __future__ import annotations

import numpy as np
import pytest

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.objects.map_object import ObjectMapConfig
from changing_slam_ros.core.objects.object_visibility import (
    Visibility, check_visibility, depth_from_keypoints, min_projected_area, window_depth_m,
)

CAM = CameraIntrinsics(160, 120, 131.25, 131.25, 79.5, 59.5)
CFG = ObjectMapConfig(margin_px=10.0, min_range_m=0.3, max_range_m=4.0, occlusion_tolerance_m=0.2)
I4 = np.eye(4)  # camera at the origin looking down +z (optical frame = world)


def _wall(depth: float) -> np.ndarray:
    return np.full((CAM.height, CAM.width), depth, np.float32)


def test_object_in_view_in_front_of_the_wall_behind_it_is_visible() -> None:
    # the object's front surface (2.3 m) is measured; its centroid is at 2.5 m, half-extent 0.25 m
    depth = _wall(4.0)
    depth[50:70, 70:90] = 2.3
    chk = check_visibility(np.array([0.0, 0.0, 2.5]), I4, CAM, depth, CFG, box_size_m=np.array([0.5, 0.5, 0.5]))
    assert chk.visibility is Visibility.VISIBLE and chk.expected
    assert chk.pixel_uv == pytest.approx((79.5, 59.5))
    assert chk.measured_depth_m == pytest.approx(2.3)
    # removed object: the wall behind is measured (farther than the centroid): still expected -> a miss
    assert check_visibility(np.array([0.0, 0.0, 2.5]), I4, CAM, _wall(4.0), CFG).expected


def test_object_behind_a_wall_is_occluded() -> None:
    chk = check_visibility(np.array([0.0, 0.0, 3.0]), I4, CAM, _wall(1.5), CFG, box_size_m=np.array([0.6, 0.6, 0.6]))
    assert chk.visibility is Visibility.OCCLUDED and not chk.expected
    # tolerance: a surface 0.45 m in front of the centroid with half-extent 0.3 + 0.2 is not an occluder
    assert check_visibility(np.array([0.0, 0.0, 3.0]), I4, CAM, _wall(2.55), CFG, box_size_m=np.array([0.6, 0.6, 0.6])).expected


def test_object_outside_the_frustum_or_the_margin_or_behind_the_camera_is_not_expected() -> None:
    depth = _wall(5.0)
    # x = 1.0 m at 2 m: u = 79.5 + 131.25 / 2 = 145.1 <= 159 - 10 (inside); x = 1.2 m: u = 158.25 (in the margin)
    assert check_visibility(np.array([1.0, 0.0, 2.0]), I4, CAM, depth, CFG).expected
    assert check_visibility(np.array([1.2, 0.0, 2.0]), I4, CAM, depth, CFG).visibility is Visibility.OUT_OF_IMAGE
    assert check_visibility(np.array([0.0, 3.0, 2.0]), I4, CAM, depth, CFG).visibility is Visibility.OUT_OF_IMAGE
    assert check_visibility(np.array([0.0, 0.0, -2.0]), I4, CAM, depth, CFG).visibility is Visibility.BEHIND_CAMERA


def test_object_out_of_range_is_not_expected() -> None:
    assert check_visibility(np.array([0.0, 0.0, 4.5]), I4, CAM, _wall(6.0), CFG).visibility is Visibility.OUT_OF_RANGE
    assert check_visibility(np.array([0.0, 0.0, 0.2]), I4, CAM, _wall(6.0), CFG).visibility is Visibility.OUT_OF_RANGE


def test_camera_pose_is_applied_and_missing_depth_means_unknown() -> None:
    # camera at (0, 0, -2) in the world, turned 180 deg about y: it looks down -z; object at world (0, 0, -4.5)
    T = np.eye(4)
    T[:3, :3] = np.diag([-1.0, 1.0, -1.0])
    T[:3, 3] = [0.0, 0.0, -2.0]
    chk = check_visibility(np.array([0.0, 0.0, -4.5]), T, CAM, _wall(3.0), CFG)
    assert chk.expected and chk.centroid_depth_m == pytest.approx(2.5)
    assert not check_visibility(np.array([0.0, 0.0, 1.0]), T, CAM, _wall(3.0), CFG).expected  # behind it
    chk = check_visibility(np.array([0.0, 0.0, -4.5]), T, CAM, _wall(0.0), CFG)
    assert chk.visibility is Visibility.NO_DEPTH
    assert check_visibility(np.array([0.0, 0.0, -4.5]), T, CAM, None, CFG).expected  # no depth image: frustum only


def test_window_depth_is_the_median_of_valid_readings() -> None:
    d = np.zeros((5, 5), np.float32)
    d[1:4, 1:4] = [[1.0, 0.0, 2.0], [np.nan, 3.0, 0.0], [4.0, 5.0, 0.0]]
    assert window_depth_m(d, 2.0, 2.0, 1) == pytest.approx(3.0)  # median of 1, 2, 3, 4, 5
    assert window_depth_m(d, 0.0, 4.0, 0) == 0.0


def test_sparse_depth_from_keypoints_gives_the_occlusion_test_keypoint_depths() -> None:
    kp = np.array([[79.5, 59.5], [81.0, 60.0], [10.0, 10.0], [150.0, 100.0]])
    depth = depth_from_keypoints(kp, np.array([3.0, 1.2, 2.0, 0.0]), CAM, radius_px=3)
    assert depth[60, 80] == pytest.approx(1.2)  # overlapping squares: the nearest wins
    assert depth[59, 77] == pytest.approx(3.0) and depth[10, 10] == pytest.approx(2.0)
    assert depth[100, 150] == 0.0 and depth[40, 120] == 0.0  # no depth / no keypoint
    # an object 2.5 m away behind the 1.2 m keypoint is occluded; with no keypoint near it, unknown
    assert check_visibility(np.array([0.0, 0.0, 2.5]), I4, CAM, depth, CFG).visibility is Visibility.OCCLUDED
    assert check_visibility(np.array([0.6, -0.1, 2.5]), I4, CAM, depth, CFG).visibility is Visibility.NO_DEPTH


def test_object_too_small_to_be_detected_is_not_expected_and_the_limit_scales_with_the_image() -> None:
    # a cup 0.05 x 0.08 x 0.1 m; the default limit is 5.2e-4 of the image: 9.98 px at 160x120, 159.7 px at 640x480
    cup = np.array([0.05, 0.08, 0.1])
    cam640 = CameraIntrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)
    cfg640 = ObjectMapConfig(margin_px=40.0, min_range_m=0.3, max_range_m=4.0, occlusion_tolerance_m=0.2)
    for z, expected in ((2.6, True), (3.7, True), (3.8, False)):
        # 160x120: (131.25 / z)^2 * 0.008 = 20.4, 10.07, 9.54 px; 640x480: (525 / z)^2 * 0.008 = 326, 161.1, 152.7 px
        small = check_visibility(np.array([0.0, 0.0, z]), I4, CAM, _wall(4.5), CFG, box_size_m=cup)
        large = check_visibility(np.array([0.0, 0.0, z]), I4, cam640, np.full((480, 640), 4.5, np.float32), cfg640,
                                 box_size_m=cup)
        assert small.expected is expected and large.expected is expected, z
        if not expected:
            assert small.visibility is Visibility.TOO_SMALL and large.visibility is Visibility.TOO_SMALL
    # an absolute floor (a detector with a fixed pixel minimum): 100 px at 160x120
    floor = ObjectMapConfig(margin_px=10.0, min_projected_area_px=100.0)
    # (131.25 / 2.6)^2 * 0.008 = 20.4 px < 100 px; at 1.2 m: 95.7 px; at 1.1 m: 113.9 px
    far = check_visibility(np.array([0.0, 0.0, 2.6]), I4, CAM, _wall(4.0), floor, box_size_m=cup)
    assert far.visibility is Visibility.TOO_SMALL and not far.expected
    assert not check_visibility(np.array([0.0, 0.0, 1.2]), I4, CAM, _wall(4.0), floor, box_size_m=cup).expected
    assert check_visibility(np.array([0.0, 0.0, 1.1]), I4, CAM, _wall(4.0), floor, box_size_m=cup).expected
    assert min_projected_area(floor, CAM) == 100.0
    assert min_projected_area(ObjectMapConfig(), cam640) == pytest.approx(159.744)
