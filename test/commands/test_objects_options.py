"""The run helpers of the object layer: loop error against ground truth, alignment of objects, the object map in the map file."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from changing_slam_ros.commands.objects_options import LoopRecord, loop_error, object_layer_setup
from changing_slam_ros.eval.object_alignment import aligned_objects, trajectory_alignment
from changing_slam_ros.core.objects.map_object import MapObject
from changing_slam_ros.core.objects.object_layer import ObjectLayer
from changing_slam_ros.core.geometry.se3 import make_pose
from changing_slam_ros.core.map.slam_map import Atlas
from changing_slam_ros.core.geometry.trajectory import Trajectory
from changing_slam_ros.io.map_file import load_map, save_map


def _rot_z(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])


def _gt() -> Trajectory:
    stamps = np.arange(10) * 0.1
    poses = np.array([make_pose(_rot_z(10.0 * k), np.array([0.2 * k, 0.1 * k * k, 0.0])) for k in range(10)])
    return Trajectory.from_poses(stamps, poses)


def test_loop_error_is_the_relative_pose_error_of_the_two_keyframes() -> None:
    gt = _gt()
    poses = gt.poses()
    exact = np.linalg.inv(poses[2]) @ poses[8]
    rec = LoopRecord(int(0.8e9), int(0.2e9), exact)
    t_m, r_deg = loop_error(gt, rec)  # type: ignore[misc]
    assert t_m < 1e-9 and r_deg < 1e-6
    off = exact @ make_pose(_rot_z(6.0), np.array([0.0, 0.12, 0.0]))
    t_m, r_deg = loop_error(gt, LoopRecord(int(0.8e9), int(0.2e9), off))  # type: ignore[misc]
    assert abs(t_m - 0.12) < 1e-9 and abs(r_deg - 6.0) < 1e-6
    assert loop_error(gt, LoopRecord(int(5e9), int(0.2e9), exact)) is None  # no ground truth at that stamp


def test_objects_are_moved_into_the_ground_truth_frame_with_the_trajectory_alignment() -> None:
    gt = _gt()
    T_est_gt = make_pose(_rot_z(35.0), np.array([1.0, -2.0, 0.5]))  # the estimate's frame differs from ground truth
    est = Trajectory.from_poses(gt.stamps_s, np.array([T_est_gt @ p for p in gt.poses()]))
    T = trajectory_alignment(gt, est)
    assert T is not None
    np.testing.assert_allclose(T @ T_est_gt, np.eye(4), atol=1e-9)
    pts_gt = np.array([[1.0, 1.0, 0.2], [1.2, 1.0, 0.2], [1.0, 1.3, 0.9]])
    pts_est = pts_gt @ T_est_gt[:3, :3].T + T_est_gt[:3, 3]
    obj = MapObject(3, 56, (0, 0, 1, 1), (0, 0, 1, 1), 0, 0, point_ids=np.arange(3), points_w=pts_est)
    (moved,) = aligned_objects([obj], T)
    np.testing.assert_allclose(moved.centroid_w, pts_gt.mean(axis=0), atol=1e-9)
    np.testing.assert_allclose(moved.box_size_m, [0.2, 0.3, 0.7], atol=1e-9)
    np.testing.assert_allclose(obj.points_w, pts_est)  # the original is untouched


def test_object_map_is_saved_in_the_map_file(tmp_path: Path) -> None:
    layer = object_layer_setup(argparse.Namespace(objects=None), {"objects": {"belief_threshold": 0.7}}, "test")
    assert layer.enabled and layer.config.association.belief_threshold == 0.7
    assert not object_layer_setup(argparse.Namespace(objects=False), {}, "test").enabled
    obj = MapObject(4, 62, (1, 2, 30, 40), (3, 4, 33, 44), 2, 9, belief=0.83, active=True,
                    point_ids=np.array([5, -2, -3]), points_w=np.array([[0.0, 1, 2], [0.1, 1, 2], [0.0, 1.2, 2]]))
    layer.association(0).add_object(obj)
    path = tmp_path / "map.npz"
    save_map(path, Atlas(), layer)
    loaded = load_map(path)
    (back,) = loaded.objects[0].objects
    assert (back.id, back.class_id, back.belief, back.active, back.last_seen_keyframe) == (4, 62, 0.83, True, 9)
    np.testing.assert_array_equal(back.point_ids, obj.point_ids)
    np.testing.assert_allclose(back.centroid_w, obj.centroid_w)
    assert set(loaded.objects) == {0}
    assert isinstance(ObjectLayer().map_ids, list)


def _square_loop(height_error_m: float) -> tuple[Trajectory, Trajectory]:
    """A ground robot on a 0.8 m square at 0.5 m, optical axis level (world z up), 90 deg per side; the estimate
    has exact orientations and a height error growing linearly across the square (+-height_error_m)."""
    level = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # optical z -> world x, y -> -z
    corners = np.array([[0.0, 0.0], [0.8, 0.0], [0.8, 0.8], [0.0, 0.8]])
    dirs = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
    poses = np.array([make_pose(_rot_z(90.0 * (k // 20)) @ level,
                                np.r_[corners[k // 20] + 0.8 * (k % 20) / 20 * dirs[k // 20], 0.5]) for k in range(80)])
    est = poses.copy()
    est[:, 2, 3] += height_error_m * (est[:, 0, 3] - 0.4) / 0.4
    stamps = np.arange(80) * 0.1
    return Trajectory.from_poses(stamps, poses), Trajectory.from_poses(stamps, est)


def test_object_alignment_weighs_camera_orientation_so_height_noise_does_not_tilt_the_map() -> None:
    """Positions alone leave the tilt of a planar path free: +-2 cm of height error across a 0.8 m square tilts
    the map 2.9 deg and moves an object 2.6 m ahead of the path 13 cm; with the camera axes in the fit (orientations
    are exact here) the tilt is 0.7 deg and the object moves 3 cm."""
    gt, est = _square_loop(0.02)
    obj = np.array([3.0, 0.4, 0.5, 1.0])
    T_pos = trajectory_alignment(gt, est, lever_m=0.0)
    T_pose = trajectory_alignment(gt, est)
    assert T_pos is not None and T_pose is not None
    tilt_pos = np.degrees(np.arccos(np.clip((np.trace(T_pos[:3, :3]) - 1) / 2, -1, 1)))
    tilt_pose = np.degrees(np.arccos(np.clip((np.trace(T_pose[:3, :3]) - 1) / 2, -1, 1)))
    assert tilt_pos > 2.5 and tilt_pose < 1.0
    assert np.linalg.norm((T_pos @ obj)[:3] - obj[:3]) > 0.10
    assert np.linalg.norm((T_pose @ obj)[:3] - obj[:3]) < 0.05
    gt0, est0 = _square_loop(0.0)  # an exact estimate is aligned exactly either way
    for lever in (0.0, 1.0):
        T = trajectory_alignment(gt0, est0, lever_m=lever)
        assert T is not None
        np.testing.assert_allclose(T, np.eye(4), atol=1e-9)
