"""Relocalisation: against a keyframe when many of the frame's matches are wrong; refused when the camera could not
have moved there."""

from __future__ import annotations

import dataclasses

import numpy as np
from helpers import FR1_XYZ_10, require

from changing_slam_ros.core.features.frame import Frame
from changing_slam_ros.core.features.orb_features import Features
from changing_slam_ros.core.slam.motion_gate import MotionGateConfig
from changing_slam_ros.core.slam.tracking import TrackingState
from changing_slam_ros.core.slam.tracking_config import TrackingConfig
from changing_slam_ros.core.system import SlamSystem, SystemConfig
from changing_slam_ros.io.dataset import open_dataset


def _features(system: SlamSystem, frame) -> Features:
    return system._extractor_for(frame.camera).extract(frame.rgb, frame.depth_m)


def _with_decoys(feats: Features, system: SlamSystem, n: int) -> Features:
    """`feats` plus `n` decoys: points of the first keyframe, each with its own descriptor at the pixel and depth
    of another point. A decoy matches its point exactly, at a place the pose cannot explain."""
    kf = system.atlas.current.keyframes[min(system.atlas.current.keyframes)]
    rng = np.random.default_rng(3)
    rows = rng.choice(np.flatnonzero(kf.point_ids >= 0), n, replace=False)
    at = rng.permutation(rows)
    px = kf.keypoints_px[at].astype(np.float64)
    d = kf.depths_m[at].astype(np.float64)
    u_right = np.where(d > 0, px[:, 0] - system.config.features.bf_m_px / np.maximum(d, 1e-6), -1.0)
    decoys = Features(px, px.copy(), kf.octaves[rows].astype(np.int64), np.zeros(n), np.ones(n),
                      kf.descriptors[rows].copy(), d, u_right)
    return Features(*(np.concatenate([getattr(p, f.name) for p in (feats, decoys)]) for f in dataclasses.fields(Features)))


N_DECOYS = 350  # about as many as the frame's true matches: PnP still finds the pose


def test_relocalisation_finds_the_pose_when_most_matches_are_decoys() -> None:
    frames = list(open_dataset(require(FR1_XYZ_10), "tum_fr1"))
    reference = SlamSystem()
    poses = [reference.process(f).T_world_cam for f in frames]
    system = SlamSystem()
    for f in frames[:6]:
        assert system.process(f).state == TrackingState.OK
    tracker = system.tracker
    tracker.state = TrackingState.LOST
    target = frames[8]
    feats = _with_decoys(_features(system, target), system, N_DECOYS)
    frame = Frame(target.stamp_ns, 8, target.camera, feats)
    res = tracker.track(frame)
    assert res.relocalised and res.state == TrackingState.OK
    assert np.linalg.norm(res.T_world_cam[:3, 3] - poses[8][:3, 3]) < 0.02


def test_a_relocalisation_further_than_the_camera_could_move_is_refused() -> None:
    frames = list(open_dataset(require(FR1_XYZ_10), "tum_fr1"))
    for check, relocalises in ((True, False), (False, True)):
        config = SystemConfig(tracking=TrackingConfig(motion_gate=MotionGateConfig(relocalisation=check)))
        system = SlamSystem(config)
        for f in frames[:6]:
            assert system.process(f).state == TrackingState.OK
        tracker = system.tracker
        tracker.state = TrackingState.LOST
        # The last accepted pose 1 m off, 0.1 s before the frame: 10 m/s to where relocalisation finds it.
        tracker.last_good_pose = tracker.last_good_pose @ np.array(
            [[1.0, 0, 0, 1.0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]])
        target = frames[8]
        tracker.last_good_stamp_ns = target.stamp_ns - 100_000_000
        frame = Frame(target.stamp_ns, 8, target.camera, _features(system, target))
        res = tracker.track(frame)
        assert res.relocalised == relocalises and (res.state == TrackingState.OK) == relocalises
