"""core/geometry/transform_tree.py: composition along the tree, interpolation between samples, no extrapolation."""

from __future__ import annotations

import numpy as np
import pytest

from changing_slam_ros.core.geometry.se3 import make_pose, rotation_angle_rad
from changing_slam_ros.core.geometry.transform_tree import (
    ExtrapolationError,
    TransformError,
    TransformTree,
    interpolate_pose,
)


def rot_z(deg: float) -> np.ndarray:
    a = np.deg2rad(deg)
    return np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])


S = 1_000_000_000  # one second in ns


def test_interpolation_is_linear_in_translation_and_slerp_in_rotation() -> None:
    a = make_pose(np.eye(3), np.array([0.0, 0.0, 0.0]))
    b = make_pose(rot_z(90.0), np.array([1.0, 2.0, -4.0]))
    mid = interpolate_pose(a, b, 0.25)
    np.testing.assert_allclose(mid[:3, 3], [0.25, 0.5, -1.0], atol=1e-12)
    np.testing.assert_allclose(mid[:3, :3], rot_z(22.5), atol=1e-12)
    np.testing.assert_allclose(interpolate_pose(a, b, 1.0), b, atol=1e-12)


def test_lookup_composes_the_path_through_the_common_ancestor_at_the_stamp() -> None:
    tree = TransformTree()
    # odom -> base_link moves 1 m/s along x and turns 90 deg/s; base_link -> camera is static (URDF).
    tree.set_transform("odom", "base_link", 10 * S, make_pose(np.eye(3), np.array([0.0, 0.0, 0.0])))
    tree.set_transform("odom", "base_link", 11 * S, make_pose(rot_z(90.0), np.array([1.0, 0.0, 0.0])))
    T_base_cam = make_pose(np.eye(3), np.array([0.2, 0.0, 0.5]))
    tree.set_transform("base_link", "camera", 0, T_base_cam, static=True)
    tree.set_transform("odom", "wheel", 10 * S, make_pose(np.eye(3), np.array([0.0, 1.0, 0.0])))
    tree.set_transform("odom", "wheel", 11 * S, make_pose(np.eye(3), np.array([0.0, 1.0, 0.0])))
    T = tree.lookup("odom", "camera", 10 * S + S // 2)
    # Halfway: base at x = 0.5 turned 45 deg; the camera 0.2 m ahead of it along the turned x axis.
    c = np.cos(np.pi / 4)
    np.testing.assert_allclose(T[:3, 3], [0.5 + 0.2 * c, 0.2 * c, 0.5], atol=1e-12)
    assert np.rad2deg(rotation_angle_rad(T[:3, :3])) == pytest.approx(45.0, abs=1e-9)
    # Between two children of odom: camera seen from the wheel at 11 s.
    T_wheel_cam = tree.lookup("wheel", "camera", 11 * S)
    np.testing.assert_allclose(T_wheel_cam[:3, 3], [1.0, -1.0 + 0.2, 0.5], atol=1e-12)
    assert tree.lookup("camera", "camera", 5) is not None and tree.parent("camera") == "base_link"


def test_lookup_refuses_to_extrapolate_and_says_how_far() -> None:
    tree = TransformTree()
    tree.set_transform("odom", "base_link", 10 * S, np.eye(4))
    tree.set_transform("odom", "base_link", 11 * S, np.eye(4))
    with pytest.raises(ExtrapolationError, match=r"odom -> base_link: asked at 11.050 s, newest sample 11.000 s "
                                                 r"\(50.0 ms later\)") as err:  # fmt: skip
        tree.lookup("odom", "base_link", 11 * S + 50_000_000)
    assert err.value.future
    with pytest.raises(ExtrapolationError, match="oldest kept sample 10.000 s") as err:
        tree.lookup("odom", "base_link", 9 * S)
    assert not err.value.future
    with pytest.raises(TransformError, match="no transform between map and base_link: their trees have roots map "
                                             "and odom"):  # fmt: skip
        tree.lookup("map", "base_link", 10 * S)


def test_old_samples_leave_the_cache_and_a_second_parent_is_recorded() -> None:
    tree = TransformTree(cache_s=2.0)
    for k in range(6):
        tree.set_transform("odom", "base_link", k * S, make_pose(np.eye(3), np.array([float(k), 0.0, 0.0])))
    with pytest.raises(ExtrapolationError, match="oldest kept sample 3.000 s"):
        tree.lookup("odom", "base_link", 2 * S)
    assert tree.lookup("odom", "base_link", 0)[0, 3] == 5.0  # 0: the newest sample
    tree.set_transform("map", "base_link", 6 * S, np.eye(4))  # a second publisher of base_link's parent
    assert tree.parent_changes == [("base_link", "odom", "map")]
