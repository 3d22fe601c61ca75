"""core/geometry/rep105.py: map -> odom takes every jump, odom -> base stays continuous; covariance from inliers."""

from __future__ import annotations

import numpy as np
import pytest

from changing_slam_ros.core.geometry.rep105 import (
    OdomSource,
    PoseCovarianceModel,
    Rep105State,
    base_motion,
    base_pose,
)
from changing_slam_ros.core.geometry.se3 import invert, make_pose
from changing_slam_ros.errors import ConfigError


def rot_z(deg: float) -> np.ndarray:
    a = np.deg2rad(deg)
    return np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])


def at(x: float, y: float = 0.0, yaw_deg: float = 0.0) -> np.ndarray:
    return make_pose(rot_z(yaw_deg), np.array([x, y, 0.0]))


def test_visual_odometry_follows_the_pose_until_the_map_moves_then_the_jump_goes_into_map_to_odom() -> None:
    s = Rep105State()
    np.testing.assert_allclose(s.visual(at(1.0), map_moved=False), at(1.0))
    np.testing.assert_allclose(s.visual(at(1.1), map_moved=False), at(1.1), atol=1e-12)
    np.testing.assert_allclose(s.T_map_odom, np.eye(4))
    # A loop correction moves this frame's pose 0.3 m along y and 10 deg; the tracker measured 0.1 m along x.
    corrected = at(1.2, 0.3, 10.0)
    odom_base = s.visual(corrected, map_moved=True, T_prev_cur_base=at(0.1))
    np.testing.assert_allclose(odom_base, at(1.2), atol=1e-12)  # continuous: no jump in odom -> base
    np.testing.assert_allclose(s.T_map_odom @ odom_base, corrected, atol=1e-12)  # map -> base is the SLAM pose
    np.testing.assert_allclose(s.T_map_odom[:3, 3], corrected[:3, 3] - rot_z(10.0) @ [1.2, 0.0, 0.0], atol=1e-12)
    assert s.jumps == 1
    # Afterwards the odometry moves with the pose again, through the new map -> odom.
    nxt = corrected @ at(0.1)
    np.testing.assert_allclose(s.visual(nxt, map_moved=False), at(1.3), atol=1e-12)


def test_relocalisation_without_measured_motion_holds_odometry_where_it_was() -> None:
    s = Rep105State()
    s.visual(at(2.0), map_moved=False)
    odom_base = s.visual(at(5.0, 1.0, 90.0), map_moved=True)
    np.testing.assert_allclose(odom_base, at(2.0), atol=1e-12)
    np.testing.assert_allclose(s.T_map_odom, at(5.0, 1.0, 90.0) @ invert(at(2.0)), atol=1e-12)
    np.testing.assert_allclose(s.T_map_odom[:3, 3], [5.0, -1.0, 0.0], atol=1e-12)


def test_external_odometry_gives_map_to_odom_from_the_base_pose_and_the_camera_mounting() -> None:
    T_base_cam = make_pose(rot_z(-90.0), np.array([0.25, 0.0, 0.4]))
    T_map_cam = at(3.0, 1.0, 0.0)
    T_map_base = base_pose(T_map_cam, T_base_cam)
    np.testing.assert_allclose(T_map_base @ T_base_cam, T_map_cam, atol=1e-12)
    np.testing.assert_allclose(T_map_base[:3, 3], [3.0 + 0.0, 1.0 - 0.25, -0.4], atol=1e-12)
    s = Rep105State()
    T_odom_base = at(2.9, 0.6, 80.0)  # wheel odometry, drifted
    T_map_odom = s.from_odometry(T_map_base, T_odom_base)
    np.testing.assert_allclose(T_map_odom @ T_odom_base @ T_base_cam, T_map_cam, atol=1e-12)
    # A camera moving 0.1 m along its own x axis moves the base 0.1 m along the base's -y (camera x = base -y).
    np.testing.assert_allclose(base_motion(at(0.1), T_base_cam)[:3, 3], [0.0, -0.1, 0.0], atol=1e-12)


def test_covariance_falls_as_one_over_the_inliers() -> None:
    model = PoseCovarianceModel(sigma_m=0.01, sigma_rad=0.02, ref_inliers=100)
    c = model.covariance(400)
    assert c.shape == (6, 6) and np.count_nonzero(c) == 6
    assert c[0, 0] == pytest.approx(2.5e-5) and c[2, 2] == pytest.approx(2.5e-5) and c[5, 5] == pytest.approx(1e-4)
    assert model.covariance(0)[0, 0] == pytest.approx(1e-2)  # no inliers: counted as one


def test_odom_source_names_the_choices_on_a_typo() -> None:
    assert OdomSource.parse("tf") is OdomSource.TF
    with pytest.raises(ConfigError, match="odom_source 'wheel' unknown; expected visual or tf"):
        OdomSource.parse("wheel")
