"""Object tracking by object-level BA (Dai et al. 2021, eqs. 7 and 11) on a synthetic RGB-D sequence."""

from __future__ import annotations

import numpy as np
import pytest

from changing_slam_ros.core.backend.object_ba import (
    ObjectBAConfig,
    ObjectObservations,
    align_points,
    full_object_ba,
    motion_only_object_ba,
)
from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.movers.object_tracking import (
    FrameObjectMeasurements,
    MovingObject,
    ObjectTracker,
    ObjectTrackingConfig,
    objects_from_segmentation,
)
from changing_slam_ros.core.movers.point_correlation import CorrelationWindow, SegmentationResult
from changing_slam_ros.core.geometry.se3 import invert, make_pose, rotation_angle_rad, transform_points
from changing_slam_ros.errors import ConfigError

CAMERA = CameraIntrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)


def _rot(axis: list[float], angle_rad: float) -> np.ndarray:
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle_rad) * k + (1 - np.cos(angle_rad)) * k @ k


def _measure(
    rng: np.random.Generator, points_world: np.ndarray, T_world_cam: np.ndarray, outlier_rate: float
) -> tuple[np.ndarray, np.ndarray]:
    """Noisy RGB-D back-projections (N, 3) of world points and a visibility mask (N,)."""
    cam = transform_points(invert(T_world_cam), points_world)
    uv = CAMERA.project(cam) + rng.normal(0.0, 1.0, (len(cam), 2))
    depth = cam[:, 2] + rng.normal(0.0, 1.425e-3 * cam[:, 2] ** 2)
    bad = rng.random(len(cam)) < outlier_rate
    depth[bad] += rng.choice([-1.0, 1.0], bad.sum()) * rng.uniform(0.1, 0.3, bad.sum())
    uv[bad] += rng.normal(0.0, 15.0, (bad.sum(), 2))
    visible = (uv[:, 0] >= 0) & (uv[:, 0] < 640) & (uv[:, 1] >= 0) & (uv[:, 1] < 480) & (depth > 0.3)
    return CAMERA.backproject(uv, depth), visible


def object_sequence(n_frames: int, seed: int, outlier_rate: float = 0.05):
    """A textured 0.4 x 0.3 x 0.2 m box on a curved 6-DoF path seen by a moving camera at 30 Hz.

    Returns true object-to-world poses (K, 4, 4) whose frame is the box centre at frame 0, camera poses
    (K, 4, 4), per-frame measurements and the true points in the object frame (P, 3).
    """
    rng = np.random.default_rng(seed)
    half = np.array([0.2, 0.15, 0.1])
    n_points = 80
    pts = rng.uniform(-1.0, 1.0, (n_points, 3))
    face = rng.integers(0, 3, n_points)
    pts[np.arange(n_points), face] = rng.choice([-1.0, 1.0], n_points)
    points_obj = pts * half
    t = np.arange(n_frames) / 30.0
    T_world_obj = np.stack(
        [make_pose(_rot([0.2, 1.0, 0.3], 0.8 * s), np.array([0.3 * np.sin(1.5 * s), 0.05 * s, 1.6 + 0.2 * s])) for s in t]
    )
    T_world_cam = np.stack([make_pose(_rot([0.0, 1.0, 0.1], 0.1 * s), np.array([0.2 * s, 0.0, 0.05 * s])) for s in t])
    frames = []
    for k in range(n_frames):
        meas, visible = _measure(rng, transform_points(T_world_obj[k], points_obj), T_world_cam[k], outlier_rate)
        ids = np.flatnonzero(visible)
        frames.append(FrameObjectMeasurements(int(k * 33_333_333), T_world_cam[k], ids.astype(np.int64), meas[visible]))
    return T_world_obj, T_world_cam, frames, points_obj


def _errors(obj: MovingObject, T_true: np.ndarray, frames: list[FrameObjectMeasurements]) -> tuple[float, float]:
    """RMSE of the object origin (m) and max rotation error (rad) over the tracked frames.

    The estimated object frame is the centre of the noisy points measured at creation, the true one the
    true centre; the fixed offset between the two is removed with the first pose, as in ATE alignment.
    """
    stamps = {f.stamp_ns: k for k, f in enumerate(frames)}
    offset = invert(T_true[0]) @ obj.poses[frames[0].stamp_ns]
    err_t, err_r = [], []
    for stamp, pose in obj.poses.items():
        truth = T_true[stamps[stamp]] @ offset
        err_t.append(np.linalg.norm(pose[:3, 3] - truth[:3, 3]))
        err_r.append(rotation_angle_rad(pose[:3, :3].T @ truth[:3, :3]))
    return float(np.sqrt(np.mean(np.square(err_t)))), float(np.max(err_r))


def _track_sequence(optimise: bool, seed: int = 0) -> tuple[MovingObject, np.ndarray, list[FrameObjectMeasurements]]:
    T_true, _, frames, _ = object_sequence(30, seed)
    first = frames[0]
    tracker = ObjectTracker(CAMERA, ObjectTrackingConfig())
    obj = MovingObject.create(7, first.point_ids, transform_points(first.T_world_cam, first.points_cam), first.stamp_ns, first)
    for frame in frames[1:]:
        result = tracker.track(obj, frame)
        assert result.tracked
        if optimise and result.is_keypose:
            tracker.optimise(obj)
    return obj, T_true, frames


def test_tracking_with_object_ba_recovers_the_object_trajectory_within_1_cm() -> None:
    obj, T_true, frames = _track_sequence(optimise=True)
    rmse_m, max_rot_rad = _errors(obj, T_true, frames)
    assert len(obj.poses) == 30
    assert rmse_m < 0.01, rmse_m
    assert max_rot_rad < np.radians(1.5), np.degrees(max_rot_rad)
    assert len(obj.keyposes) >= 4


def test_full_object_ba_refines_the_shape_measured_in_one_frame() -> None:
    T_true, _, frames, points_true = object_sequence(30, seed=1)
    first = frames[0]
    obj = MovingObject.create(1, first.point_ids, transform_points(first.T_world_cam, first.points_cam), first.stamp_ns, first)
    tracker = ObjectTracker(CAMERA, ObjectTrackingConfig())
    for frame in frames[1:]:
        tracker.track(obj, frame)
    shape_before = _shape_error(obj, T_true[0], points_true)
    tracker.optimise(obj)
    shape_after = _shape_error(obj, T_true[0], points_true)
    # One frame of depth noise plus outliers (median ~5 mm at 1.6 m) against several keyposes fused.
    assert shape_after < 0.6 * shape_before, (shape_before, shape_after)
    assert shape_after < 0.004


def _shape_error(obj: MovingObject, T_true_0: np.ndarray, points_true: np.ndarray) -> float:
    """Median distance (m) of the object's points to the truth after aligning the two frames."""
    world_true = transform_points(T_true_0, points_true[obj.point_ids])
    T = align_points(obj.points_obj, world_true)
    return float(np.median(np.linalg.norm(transform_points(T, obj.points_obj) - world_true, axis=1)))


def test_motion_only_ba_rejects_outliers_and_converges_from_a_wrong_guess() -> None:
    T_true, _, frames, points_true = object_sequence(2, seed=2, outlier_rate=0.1)
    frame = frames[1]
    obs = ObjectObservations(frame.stamp_ns, frame.T_world_cam, frame.point_ids, frame.points_cam)
    guess = T_true[1] @ make_pose(_rot([1.0, 0.0, 0.0], 0.1), np.array([0.05, -0.03, 0.04]))
    result = motion_only_object_ba(points_true, obs, guess, CAMERA, ObjectBAConfig())
    assert np.linalg.norm(result.T_world_obj[:3, 3] - T_true[1][:3, 3]) < 0.003
    # From 5.7 deg and 7 cm off to within one frame of noise (a 0.4 m box at 1.6 m: ~0.5 deg).
    assert rotation_angle_rad(result.T_world_obj[:3, :3].T @ T_true[1][:3, :3]) < np.radians(1.0)
    assert 0.8 < result.inliers.mean() < 0.97


def test_full_object_ba_holds_the_reference_keypose_as_gauge() -> None:
    T_true, _, frames, points_true = object_sequence(4, seed=3, outlier_rate=0.0)
    kps = [ObjectObservations(f.stamp_ns, f.T_world_cam, f.point_ids, f.points_cam) for f in frames]
    rng = np.random.default_rng(0)
    init = T_true.copy()
    init[1:, :3, 3] += rng.normal(0.0, 0.02, (3, 3))
    result = full_object_ba(points_true + rng.normal(0.0, 0.01, points_true.shape), kps, init, CAMERA, ObjectBAConfig())
    np.testing.assert_allclose(result.T_world_obj[0], T_true[0], atol=1e-6)
    assert np.max(np.linalg.norm(result.T_world_obj[1:, :3, 3] - T_true[1:, :3, 3], axis=1)) < 0.003


def test_trajectory_and_point_lookup_of_a_moving_object() -> None:
    pts = np.array([[0.0, 0, 1], [0.2, 0, 1], [0, 0.2, 1], [0, 0, 1.2]])
    obj = MovingObject.create(3, np.array([10, 11, 12, 13]), pts, 1_000_000_000)
    np.testing.assert_allclose(obj.points_obj.mean(axis=0), 0.0, atol=1e-12)
    obj.poses[2_000_000_000] = make_pose(np.eye(3), pts.mean(axis=0) + [0.1, 0, 0])
    traj = obj.trajectory()
    np.testing.assert_allclose(traj.stamps_s, [1.0, 2.0])
    np.testing.assert_allclose(traj.positions[1] - traj.positions[0], [0.1, 0, 0])
    np.testing.assert_array_equal(obj.index_of(np.array([12, 99, 10])), [2, -1, 0])
    np.testing.assert_allclose(obj.points_world(2_000_000_000), pts + [0.1, 0, 0])


def test_tracking_config_rejects_a_window_without_room_for_the_reference() -> None:
    with pytest.raises(ConfigError, match="window_keyposes"):
        ObjectTrackingConfig(window_keyposes=1)


def test_objects_from_segmentation_creates_one_object_per_target_in_the_newest_frame() -> None:
    rng = np.random.default_rng(4)
    points_cam = rng.uniform([-0.5, -0.5, 1.0], [0.5, 0.5, 2.0], (2, 14, 3))
    points_cam[1, 12] = np.nan  # target 2 loses a point in the newest frame
    T_world_cam = np.stack([np.eye(4), make_pose(np.eye(3), np.array([0.1, 0.0, 0.0]))])
    window = CorrelationWindow(np.arange(100, 114), points_cam, T_world_cam, CAMERA)
    labels = np.array([0] * 4 + [1] * 6 + [2] * 4)
    result = SegmentationResult(window.point_ids, labels, np.zeros((14, 3)), np.empty((0, 2), np.int64), np.empty(0, bool), np.empty(0))
    objects = objects_from_segmentation(result, window, 5_000, first_id=7, min_points=4)
    assert [o.object_id for o in objects] == [7]  # target 2 has only 3 points measured in the newest frame
    obj = objects[0]
    np.testing.assert_array_equal(obj.point_ids, np.arange(104, 110))
    world = transform_points(T_world_cam[1], points_cam[1, 4:10])
    np.testing.assert_allclose(obj.poses[5_000][:3, 3], world.mean(axis=0))
    np.testing.assert_allclose(obj.points_world(5_000), world)
    assert len(obj.keyposes) == 1 and obj.keyposes[0].stamp_ns == 5_000


def test_configs_load_from_yaml_sections() -> None:
    from changing_slam_ros.config import section
    from changing_slam_ros.core.movers.object_merging import MergeConfig
    from changing_slam_ros.core.movers.point_correlation import SegmentationConfig

    seg = section(SegmentationConfig, {"inconsistent_inlier_fraction": 0.5, "static_volume": "view_cone"}, "t.yaml: seg")
    assert seg.inconsistent_inlier_fraction == 0.5 and seg.static_volume == "view_cone"
    tracking = section(ObjectTrackingConfig, {"window_keyposes": 5, "ba": {"sigma_px": 2}}, "t.yaml: objects")
    assert tracking.window_keyposes == 5 and tracking.ba.sigma_px == 2.0
    assert section(MergeConfig, {"overlap_tolerance": 0.2}, "t.yaml: merge").overlap_tolerance == 0.2
    with pytest.raises(ConfigError, match="huber"):
        section(SegmentationConfig, {"huber": 1.0}, "t.yaml: seg")
    with pytest.raises(ConfigError, match="static_volume"):
        section(SegmentationConfig, {"static_volume": "sphere"}, "t.yaml: seg")


def _tracked(config: ObjectTrackingConfig, seed: int = 0, n_frames: int = 30) -> tuple[MovingObject, np.ndarray, list[FrameObjectMeasurements], int]:
    """The synthetic box tracked with eq. 7 every frame and eq. 11 when due; also the number of eq. 11 runs."""
    T_true, _, frames, _ = object_sequence(n_frames, seed)
    first = frames[0]
    tracker = ObjectTracker(CAMERA, config)
    obj = MovingObject.create(7, first.point_ids, transform_points(first.T_world_cam, first.points_cam), first.stamp_ns, first)
    runs = 0
    for frame in frames[1:]:
        result = tracker.track(obj, frame)
        assert result.tracked
        if result.is_keypose and tracker.optimise_due(obj):
            tracker.optimise(obj)
            runs += 1
    return obj, T_true, frames, runs


def test_an_object_keeps_the_reference_and_the_newest_window_of_keyposes() -> None:
    obj, T_true, frames, _ = _tracked(ObjectTrackingConfig(window_keyposes=4, keypose_translation_m=0.01))
    assert len(obj.keyposes) == 4
    assert obj.keyposes[0].stamp_ns == frames[0].stamp_ns  # the reference (gauge) keypose
    assert [kp.stamp_ns for kp in obj.keyposes[1:]] == sorted(kp.stamp_ns for kp in obj.keyposes[1:])
    rmse_m, _ = _errors(obj, T_true, frames)
    assert rmse_m < 0.01, rmse_m


def test_full_ba_at_every_third_keypose_keeps_the_trajectory_within_1_cm() -> None:
    every, _, _, n_every = _tracked(ObjectTrackingConfig(optimise_every_keyposes=1))
    third, T_true, frames, n_third = _tracked(ObjectTrackingConfig(optimise_every_keyposes=3))
    assert n_third <= n_every // 3 + 1, (n_third, n_every)
    rmse_every, _ = _errors(every, T_true, frames)
    rmse_third, rot_third = _errors(third, T_true, frames)
    assert rmse_third < 0.01 and rot_third < np.radians(1.5), (rmse_every, rmse_third, np.degrees(rot_third))


def test_bound_model_keeps_the_reference_and_the_most_observed_points() -> None:
    rng = np.random.default_rng(5)
    ids = np.arange(200, 300)
    obj = MovingObject(1, ids.copy(), rng.normal(0.0, 0.1, (100, 3)))
    T = np.eye(4)

    def keypose(stamp: int, index: np.ndarray) -> ObjectObservations:
        return ObjectObservations(stamp, T, index.astype(np.int64), obj.points_obj[index] + [0.0, 0.0, 1.5])

    ref = np.arange(0, 10)  # the reference keypose sees points 0..9 once
    often = np.arange(50, 80)  # seen in three later keyposes
    obj.keyposes = [keypose(0, ref), keypose(1, often), keypose(2, np.r_[often, 95]), keypose(3, often)]
    obj.bound_model(45)
    assert len(obj.point_ids) == 45
    kept = set(obj.point_ids.tolist())
    assert set((ids[ref]).tolist()) <= kept and set(ids[often].tolist()) <= kept and 200 + 95 in kept
    # Ties among the points seen once or never: the newest (highest index) are kept.
    assert 200 + 99 in kept and 200 + 10 not in kept
    # Keyposes still point at the same map points and measurements.
    for kp, before in zip(obj.keyposes, [ref, often, np.r_[often, 95], often]):
        np.testing.assert_array_equal(obj.point_ids[kp.point_index], ids[before])
    obj.bound_model(0)  # 0: no bound
    assert len(obj.point_ids) == 45


def test_tracking_config_rejects_a_bad_cadence_or_bound() -> None:
    with pytest.raises(ConfigError, match="optimise_every_keyposes"):
        ObjectTrackingConfig(optimise_every_keyposes=0)
    with pytest.raises(ConfigError, match="max_model_points"):
        ObjectTrackingConfig(max_model_points=-1)


def test_dropping_keyposes_outside_the_window_leaves_a_merged_window_unchanged() -> None:
    from copy import deepcopy

    from changing_slam_ros.core.movers.object_merging import fuse_into

    rng = np.random.default_rng(6)

    def with_keyposes(object_id: int, ids: np.ndarray, stamps: list[int]) -> MovingObject:
        obj = MovingObject(object_id, ids, rng.normal(0.0, 0.1, (len(ids), 3)))
        for s in stamps:
            obj.poses[s] = make_pose(np.eye(3), rng.normal(0.0, 0.1, 3))
            index = np.sort(rng.choice(len(ids), 12, replace=False)).astype(np.int64)
            obj.keyposes.append(ObjectObservations(s, np.eye(4), index, rng.normal(0.0, 1.0, (12, 3))))
        return obj

    window = 8
    host = with_keyposes(1, np.arange(0, 60), list(range(0, 400, 10)))  # 40 keyposes, every 10
    other = with_keyposes(2, np.arange(40, 100), [*range(5, 400, 20), 230, 390])  # interleaved, two shared stamps
    other.keyposes.sort(key=lambda kp: kp.stamp_ns)
    full = fuse_into(host, other, 390)
    host_p, other_p = deepcopy(host), deepcopy(other)
    host_p.keep_keyposes(window)
    other_p.keep_keyposes(window)
    assert len(host_p.keyposes) == window and len(other_p.keyposes) == window
    pruned = fuse_into(host_p, other_p, 390)

    def ba_window(obj: MovingObject) -> list[tuple[int, list[int]]]:
        kps = [obj.keyposes[0]] + obj.keyposes[1:][-(window - 1) :]
        return [(kp.stamp_ns, obj.point_ids[kp.point_index].tolist()) for kp in kps]

    assert ba_window(pruned) == ba_window(full)
