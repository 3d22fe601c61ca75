"""Map bookkeeping: observations, covisibility, spanning tree through culled keyframes, inactive points."""

from __future__ import annotations

import numpy as np
from helpers import FR1_XYZ_10, require

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.geometry.pose_optimizer import se3_exp_left
from changing_slam_ros.core.map.slam_map import SlamMap
from changing_slam_ros.core.system import SlamSystem
from changing_slam_ros.core.slam.tracking import TrackingState
from changing_slam_ros.io.dataset import open_dataset

CAM = CameraIntrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)


def _kf(kf_id: int, point_ids: np.ndarray, T: np.ndarray) -> Keyframe:
    n = len(point_ids)
    return Keyframe(kf_id, kf_id, T, CAM, np.zeros((n, 2), np.float32), np.zeros(n, np.int8),
                    np.zeros((n, 32), np.uint8), np.ones(n, np.float32), point_ids.astype(np.int64))


def _map_with_three_keyframes() -> tuple[SlamMap, list[np.ndarray]]:
    m = SlamMap(0)
    m.points.add(np.zeros((100, 3)), np.zeros((100, 32), np.uint8), 0, np.arange(100), np.zeros(3),
                 np.zeros(100, np.int64), np.array([1.2**i for i in range(8)]))
    poses = [se3_exp_left(np.array([0, 0.1 * k, 0, 0.2 * k, 0, 0])) for k in range(3)]
    m.add_keyframe(_kf(0, np.arange(100), poses[0]))
    m.add_keyframe(_kf(1, np.concatenate([np.arange(60), np.full(40, -1)]), poses[1]))
    m.add_keyframe(_kf(2, np.concatenate([np.arange(20, 60), np.full(60, -1)]), poses[2]))
    for k in range(3):
        m.update_connections(k)
    return m, poses


def test_covisibility_weights_are_shared_point_counts() -> None:
    m, _ = _map_with_three_keyframes()
    assert m.covisibility[0] == {1: 60, 2: 40}
    assert m.covisibility[2] == {0: 40, 1: 40}
    assert m.covisible(0) == [1, 2]
    assert m.parent[1] == 0 and m.parent[2] in (0, 1)
    assert len(m.points.observations[30]) == 3


def test_culled_keyframe_keeps_its_pose_through_the_spanning_tree() -> None:
    m, poses = _map_with_three_keyframes()
    m.parent[2] = 1
    m.children[1].add(2)
    assert m.remove_keyframe(1)
    assert 1 not in m.keyframes and 1 not in m.covisibility.get(0, {})
    np.testing.assert_allclose(m.pose_of(1), poses[1], atol=1e-12)
    # Moving the parent moves the culled keyframe with it (a loop correction would do this).
    shift = se3_exp_left(np.array([0, 0, 0.05, 0.1, 0, 0]))
    m.keyframes[0].T_world_cam = shift @ m.keyframes[0].T_world_cam
    np.testing.assert_allclose(m.pose_of(1), shift @ poses[1], atol=1e-12)
    assert m.parent[2] == 0  # re-attached to the grandparent
    assert 1 not in m.points.observations[10]


def test_origin_keyframe_is_never_culled() -> None:
    m, _ = _map_with_three_keyframes()
    assert not m.remove_keyframe(0)
    assert 0 in m.keyframes


def test_erasing_the_last_observation_makes_a_point_bad() -> None:
    m, _ = _map_with_three_keyframes()
    m.erase_observation(0, 80)  # point 80 is seen by keyframe 0 only
    assert m.points.bad[80] and not m.points.usable()[80]
    assert m.keyframes[0].point_ids[80] == -1


def test_inactive_points_are_skipped_by_tracking() -> None:
    frames = list(open_dataset(require(FR1_XYZ_10), "tum_fr1"))
    system = SlamSystem()
    for f in frames[:3]:
        assert system.process(f).state == TrackingState.OK
    pts = system.atlas.current.points
    pts.active[: pts.size] = False  # e.g. everything belongs to objects that left the scene
    out = system.process(frames[3])
    assert out.state == TrackingState.LOST
    assert system.atlas.current.local_point_ids(list(system.atlas.current.keyframes)).size == 0
    pts.active[: pts.size] = True
    assert all(system.process(f).state == TrackingState.OK for f in frames[4:])
