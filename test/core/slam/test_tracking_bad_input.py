"""Bad input: tracking reports LOST (or refuses to start), nothing crashes, and it recovers."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from helpers import FR1_XYZ_10, REDKITCHEN, require

from changing_slam_ros.core.features.rgbd_frame import RgbdFrame
from changing_slam_ros.core.system import SlamSystem, SystemConfig
from changing_slam_ros.core.slam.tracking import TrackingState
from changing_slam_ros.core.slam.tracking_config import TrackingConfig
from changing_slam_ros.errors import ConfigError
from changing_slam_ros.eval.ate import ate
from changing_slam_ros.io.dataset import open_dataset


def _frames(path=FR1_XYZ_10, config="tum_fr1") -> list[RgbdFrame]:
    return list(open_dataset(require(path), config))


def _black(frame: RgbdFrame, stamp_ns: int) -> RgbdFrame:
    return dataclasses.replace(frame, rgb=np.zeros_like(frame.rgb), stamp_ns=stamp_ns)


def test_all_black_frame_is_lost_then_relocalised() -> None:
    frames = _frames()
    system = SlamSystem()
    for f in frames[:4]:
        assert system.process(f).state == TrackingState.OK
    out = system.process(_black(frames[4], frames[4].stamp_ns - 1_000_000))
    assert out.state == TrackingState.LOST and out.T_world_cam is None and out.n_keypoints == 0
    after = [system.process(f) for f in frames[4:]]
    assert all(o.state == TrackingState.OK for o in after)
    assert len(system.atlas.maps) == 1  # relocalised into the same map, no new one
    # Every good frame has a pose and the trajectory is still accurate.
    gt = open_dataset(FR1_XYZ_10, "tum_fr1").groundtruth
    final = system.final_trajectory()
    assert len(final) == len(frames)
    assert ate(gt, final).stats.rmse <= 0.01


def test_depth_all_zero_cannot_start_a_map_and_later_frames_do() -> None:
    frames = _frames()
    no_depth = dataclasses.replace(frames[0], depth_m=np.zeros_like(frames[0].depth_m))
    system = SlamSystem()
    out = system.process(no_depth)
    assert out.state == TrackingState.NOT_INITIALISED and out.keyframe is None
    outs = [system.process(f) for f in frames[1:]]
    assert outs[0].state == TrackingState.OK and outs[0].keyframe is not None
    assert all(o.state == TrackingState.OK for o in outs)


def test_depth_all_zero_mid_sequence_tracks_monocularly_without_mapping() -> None:
    frames = _frames()
    system = SlamSystem()
    for f in frames[:5]:
        system.process(f)
    n_points = system.atlas.current.points.size
    out = system.process(dataclasses.replace(frames[5], depth_m=np.zeros_like(frames[5].depth_m)))
    # Map points are still found (monocular residuals) or the frame is reported lost; never a crash.
    assert out.state in (TrackingState.OK, TrackingState.LOST)
    if out.keyframe is not None:
        assert system.atlas.current.points.size == n_points  # no depth: no new points
    outs = [system.process(f) for f in frames[6:]]
    assert all(o.state == TrackingState.OK for o in outs)
    gt = open_dataset(FR1_XYZ_10, "tum_fr1").groundtruth
    assert ate(gt, system.final_trajectory()).stats.rmse <= 0.01


def test_jump_in_time_drops_the_motion_model_and_keeps_tracking() -> None:
    frames = _frames()
    system = SlamSystem()
    for f in frames[:3]:
        system.process(f)
    assert system.tracker.velocity is not None
    jump = 60 * 10**9  # a minute later (a paused recording), same place
    outs = [system.process(dataclasses.replace(f, stamp_ns=f.stamp_ns + jump)) for f in frames[3:]]
    assert all(o.state == TrackingState.OK for o in outs)
    # A backwards stamp is a gap too: no motion model, no crash.
    back = system.process(dataclasses.replace(frames[-1], stamp_ns=frames[0].stamp_ns))
    assert back.state == TrackingState.OK
    poses = np.array([o.T_world_cam for o in outs])
    gt = [f.T_world_cam_gt for f in frames[3:]]
    first_gt = frames[0].T_world_cam_gt
    rel_gt = np.array([np.linalg.inv(first_gt) @ g for g in gt])
    assert np.abs(poses[:, :3, 3] - rel_gt[:, :3, 3]).max() < 0.02


def test_lost_for_long_in_another_place_starts_a_new_map() -> None:
    frames = _frames()
    kitchen = _frames(REDKITCHEN, "7scenes")[:6]
    cfg = SystemConfig(tracking=dataclasses.replace(SystemConfig().tracking, lost_frames_new_map=2))
    system = SlamSystem(cfg)
    for f in frames[:4]:
        system.process(f)
    t0 = frames[3].stamp_ns
    outs = []
    for i, f in enumerate(kitchen):
        # A different place (another dataset): relocalisation fails, then a new map starts there.
        outs.append(system.process(dataclasses.replace(f, stamp_ns=t0 + (i + 1) * 33_000_000)))
    assert outs[0].state == TrackingState.LOST
    assert len(system.atlas.maps) == 2
    assert all(o.state == TrackingState.OK for o in outs[2:])
    assert system.atlas.current.id == 1 and len(system.atlas.maps[0].keyframes) >= 1


def test_pose_optimisation_counts_below_one_are_config_errors() -> None:
    with pytest.raises(ConfigError, match="tracking.pose_iterations_per_round"):
        TrackingConfig(pose_iterations_per_round=0)
    with pytest.raises(ConfigError, match="tracking.motion_pose_rounds"):
        TrackingConfig(motion_pose_rounds=0)
