"""Class-agnostic mover tracking (`core/movers/mover_tracking.py`) on a constructed scene: static walls and one
rigid box carried past a still camera, keypoints with unique descriptors, Kinect-like depth noise."""

from __future__ import annotations

import numpy as np
import pytest

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.movers.mover_tracking import FeatureTracks, MoverConfig, MoverTracker
from changing_slam_ros.core.features.orb_features import Features
from changing_slam_ros.core.geometry.se3 import invert, make_pose, transform_points
from changing_slam_ros.errors import ConfigError

CAMERA = CameraIntrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)


def _rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _features(uv: np.ndarray, depth: np.ndarray, desc: np.ndarray) -> Features:
    n = len(uv)
    return Features(uv, uv.copy(), np.zeros(n, np.int64), np.zeros(n), np.ones(n), desc, depth, np.full(n, -1.0))


def _scene(rng: np.random.Generator, n_frames: int, speed_m_per_frame: float):  # type: ignore[no-untyped-def]
    """Per frame: (Features, truth on the box (N,), T_world_obj of the box); the camera is the world frame."""
    walls = np.column_stack([rng.uniform(-2.0, 2.0, 700), rng.uniform(-1.5, 1.5, 700), rng.uniform(3.5, 4.0, 700)])
    box = rng.uniform(-0.12, 0.12, (150, 3))
    face = rng.integers(0, 3, 150)
    box[np.arange(150), face] = rng.choice([-0.12, 0.12], 150)
    desc = rng.integers(0, 256, (850, 32), dtype=np.uint8)
    frames = []
    for k in range(n_frames):
        T_obj = make_pose(_rot_z(0.01 * k), np.array([-0.6 + speed_m_per_frame * k, 0.0, 1.5]))
        world = np.vstack([walls, transform_points(T_obj, box)])
        depth = world[:, 2] + rng.normal(0.0, 1.425e-3 * world[:, 2] ** 2)
        uv = CAMERA.project(world) + rng.normal(0.0, 0.5, (len(world), 2))
        on_box = np.r_[np.zeros(700, bool), np.ones(150, bool)]
        order = rng.permutation(len(world))  # keypoint order changes every frame
        frames.append((_features(uv[order], depth[order], desc[order]), on_box[order], T_obj))
    return frames


def test_feature_tracks_keep_ids_across_frames_and_start_new_ones() -> None:
    rng = np.random.default_rng(0)
    desc = rng.integers(0, 256, (50, 32), dtype=np.uint8)
    uv = rng.uniform(0, 600, (50, 2))
    tracks = FeatureTracks(MoverConfig())
    first = tracks.associate(uv, desc, np.ones(50))
    order = rng.permutation(50)
    second = tracks.associate(uv[order] + 2.0, desc[order], np.ones(50))
    assert np.array_equal(second, first[order])
    fresh = rng.integers(0, 256, (5, 32), dtype=np.uint8)
    third = tracks.associate(np.vstack([uv[:3], uv[:5]]), np.vstack([desc[:3], fresh]), np.r_[np.ones(3), np.ones(4), 0.0])
    assert np.array_equal(third[:3], first[:3])
    assert np.all(third[3:7] >= 50) and third[7] == -1  # new tracks; no depth and no match: none


def test_a_carried_box_is_flagged_tracked_as_one_object_within_1_cm() -> None:
    rng = np.random.default_rng(1)
    frames = _scene(rng, 45, speed_m_per_frame=0.01)  # 0.3 m/s at 30 Hz
    movers = MoverTracker(MoverConfig(enabled=True, min_track_frames=5))
    tp = fp = fn = 0
    truth: dict[int, np.ndarray] = {}
    for k, (feats, on_box, T_obj) in enumerate(frames):
        stamp = int(k * 1e9 / 30)
        truth[stamp] = T_obj
        moving = movers.before_tracking(stamp, feats, CAMERA)
        movers.after_tracking(np.eye(4))
        if k >= 20:
            tp, fp, fn = tp + int(np.sum(moving & on_box)), fp + int(np.sum(moving & ~on_box)), fn + int(np.sum(on_box & ~moving))
    assert tp / (tp + fp) > 0.99 and tp / (tp + fn) > 0.9
    tracks = movers.tracks()
    assert len(tracks) == 1  # merged by eq. 12, one box gives one trajectory
    track = tracks[0]
    assert track.class_id == -1 and len(track.stamps_ns) >= 30
    first = track.first_stamp_ns
    offset = invert(truth[first]) @ track.T_world_obj[0]
    err = [np.linalg.norm(T[:3, 3] - (truth[s] @ offset)[:3, 3]) for s, T in zip(track.stamps_ns, track.T_world_obj)]
    assert np.sqrt(np.mean(np.square(err))) < 0.01


def test_a_static_scene_gives_no_moving_objects() -> None:
    rng = np.random.default_rng(2)
    frames = _scene(rng, 30, speed_m_per_frame=0.0)
    movers = MoverTracker(MoverConfig(enabled=True, min_track_frames=1))
    flagged = 0
    for k, (feats, _, _) in enumerate(frames):
        flagged += int(movers.before_tracking(int(k * 1e9 / 30), feats, CAMERA).sum())
        movers.after_tracking(np.eye(4))
    assert flagged == 0 and movers.tracks() == []


def test_a_failed_frame_is_skipped_and_config_is_checked() -> None:
    rng = np.random.default_rng(3)
    (feats, _, _), = _scene(rng, 1, 0.0)
    movers = MoverTracker(MoverConfig(enabled=True))
    movers.before_tracking(0, feats, CAMERA)
    movers.after_tracking(None)
    assert movers.objects() == []
    with pytest.raises(ConfigError, match="window_frames"):
        MoverConfig(window_frames=1)
    with pytest.raises(ConfigError, match="match_ratio"):
        MoverConfig(match_ratio=0.0)


def test_an_idle_stage_segments_less_often_and_still_finds_the_box() -> None:
    static = _scene(np.random.default_rng(2), 30, speed_m_per_frame=0.0)
    windows = {}
    for idle in (0, 4):
        movers = MoverTracker(MoverConfig(enabled=True, idle_segment_every_frames=idle))
        for k, (feats, _, _) in enumerate(static):
            assert not movers.before_tracking(int(k * 1e9 / 30), feats, CAMERA).any()
            movers.after_tracking(np.eye(4))
        windows[idle] = len(movers.segmentation_ms)
    assert windows[4] <= windows[0] // 2 + 1 and windows[4] >= 5, windows
    carried = _scene(np.random.default_rng(1), 45, speed_m_per_frame=0.01)
    movers = MoverTracker(MoverConfig(enabled=True, min_track_frames=5, idle_segment_every_frames=4))
    tp = fp = fn = 0
    for k, (feats, on_box, _) in enumerate(carried):
        moving = movers.before_tracking(int(k * 1e9 / 30), feats, CAMERA)
        movers.after_tracking(np.eye(4))
        if k >= 20:
            tp, fp, fn = tp + int(np.sum(moving & on_box)), fp + int(np.sum(moving & ~on_box)), fn + int(np.sum(on_box & ~moving))
    assert tp / (tp + fp) > 0.99 and tp / (tp + fn) > 0.9
    assert len(movers.tracks()) == 1
    with pytest.raises(ConfigError, match="idle_segment_every_frames"):
        MoverConfig(idle_segment_every_frames=-1)
