"""What was in flight across a map merge (split graph, real time): packets, counters, objects and held
provisional rows expressed in the merged map, with known answers."""

from __future__ import annotations

import numpy as np

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.dynamic.dynamic_objects import ObjectMotion, ObjectState
from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.slam.map_merging import MergeResult
from changing_slam_ros.core.map.map_point import PointStore
from changing_slam_ros.core.replication.map_replication import KeyframePacket, PointCounters
from changing_slam_ros.core.replication.merge_in_flight import MergeLog, combine_counters, move_packet
from changing_slam_ros.core.slam.provisional_points import HeldRows
from changing_slam_ros.core.geometry.se3 import make_pose

CAM = CameraIntrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)


def _rot_z(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])


def _merge(from_id: int, into_id: int, T: np.ndarray, offset: int) -> MergeResult:
    return MergeResult(from_id, into_id, T, offset, (), 0, 0, None)


def _keyframe(kf_id: int, map_id: int, T: np.ndarray, point_ids: list[int]) -> Keyframe:
    n = len(point_ids)
    kf = Keyframe(kf_id, kf_id, T.copy(), CAM, np.zeros((n, 2), np.float32), np.zeros(n, np.int8),
                  np.zeros((n, 32), np.uint8), np.ones(n, np.float32), np.array(point_ids, np.int64))
    kf.map_id = map_id
    return kf


def _counters(ids: list[int], vis: list[int], found: list[int], seen: list[int]) -> PointCounters:
    return PointCounters(*(np.array(v, np.int64) for v in (ids, vis, found, seen)))


def test_a_packet_of_the_merged_away_map_is_expressed_in_the_merged_one() -> None:
    T = make_pose(_rot_z(30.0), np.array([1.0, -2.0, 0.5]))
    pose = make_pose(_rot_z(-10.0), np.array([0.3, 0.1, 0.0]))
    kf = _keyframe(7, 1, pose, [0, -1, 4, 12])
    obj = ObjectState(3, 1, (0.0, 0.0, 1.0, 1.0), np.array([1.0, 2.0, 3.0]), np.array([0.5, 0.0, 0.0]), 0.5,
                      ObjectMotion(0), 4, False, np.diag([1.0, 2.0, 3.0, 4.0, 5.0, 6.0]))  # fmt: skip
    packet = KeyframePacket(kf, _counters([0, 4], [1, 2], [1, 1], [5, 6]), None, (obj,))
    packet.other_counters = {0: _counters([3, 100], [1, 1], [0, 1], [2, 4])}  # map 0, the one merged into
    assert move_packet(packet, _merge(1, 0, T, 100))
    assert kf.map_id == 0
    np.testing.assert_allclose(kf.T_world_cam, T @ pose, atol=1e-12)
    np.testing.assert_array_equal(kf.point_ids, [100, -1, 104, 112])
    # Its own counters (now map 0's ids 100 and 104) and those tracking filed under map 0 are one set.
    c = packet.counters
    np.testing.assert_array_equal(c.ids, [3, 100, 104])
    np.testing.assert_array_equal(c.n_visible, [1, 2, 2])
    np.testing.assert_array_equal(c.n_found, [0, 2, 1])
    np.testing.assert_array_equal(c.last_seen_frame, [2, 5, 6])
    assert packet.other_counters == {}
    moved = packet.objects[0]
    np.testing.assert_allclose(moved.position_world, T[:3, :3] @ [1.0, 2.0, 3.0] + T[:3, 3], atol=1e-12)
    np.testing.assert_allclose(moved.velocity_world, T[:3, :3] @ [0.5, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(np.linalg.eigvalsh(moved.covariance), [1, 2, 3, 4, 5, 6], atol=1e-12)  # rotated only


def test_a_packet_of_another_map_keeps_its_keyframe_and_renames_its_counters_of_the_merged_away_map() -> None:
    kf = _keyframe(9, 2, np.eye(4), [0, 1])
    packet = KeyframePacket(kf, _counters([0], [1], [1], [9]))
    packet.other_counters = {1: _counters([2, 5], [1, 1], [1, 0], [3, 3]), 0: _counters([40], [2], [2], [1])}
    assert not move_packet(packet, _merge(1, 0, np.eye(4), 50))
    assert kf.map_id == 2
    np.testing.assert_array_equal(kf.point_ids, [0, 1])
    assert list(packet.other_counters) == [0]
    np.testing.assert_array_equal(packet.other_counters[0].ids, [40, 52, 55])
    np.testing.assert_array_equal(packet.counters.ids, [0])


def test_combine_counters_adds_increments_of_one_point_and_keeps_its_later_frame() -> None:
    c = combine_counters(_counters([5, 1], [1, 2], [0, 1], [10, 3]), _counters([5], [3], [2], [8]))
    np.testing.assert_array_equal(c.ids, [1, 5])
    np.testing.assert_array_equal(c.n_visible, [2, 4])
    np.testing.assert_array_equal(c.n_found, [1, 2])
    np.testing.assert_array_equal(c.last_seen_frame, [3, 10])
    assert len(combine_counters(PointCounters(), PointCounters()).ids) == 0


def test_merge_log_moves_a_packet_through_two_merges_in_turn() -> None:
    """Map 2 went into map 1 (offset 10), later map 1 into map 0 (offset 100): a packet of map 2 lands in map 0
    with both transforms composed and both offsets added."""
    T21 = make_pose(_rot_z(20.0), np.array([0.0, 1.0, 0.0]))
    T10 = make_pose(_rot_z(-45.0), np.array([2.0, 0.0, 1.0]))
    log = MergeLog()
    log.record(_merge(2, 1, T21, 10))
    log.record(_merge(1, 0, T10, 100))
    kf = _keyframe(4, 2, np.eye(4), [3, -1])
    packet = KeyframePacket(kf, _counters([3], [1], [1], [1]))
    assert log.resolve(packet) and log.n_moved == 1
    assert kf.map_id == 0
    np.testing.assert_allclose(kf.T_world_cam, T10 @ T21, atol=1e-12)
    np.testing.assert_array_equal(kf.point_ids, [113, -1])
    np.testing.assert_array_equal(packet.counters.ids, [113])
    other = KeyframePacket(_keyframe(5, 0, np.eye(4), [1]))
    assert not log.resolve(other) and log.n_moved == 1  # made after both merges: untouched
    np.testing.assert_array_equal(other.keyframe.point_ids, [1])


def _held(map_id: int, first: int, positions: np.ndarray, creators: list[int]) -> HeldRows:
    n = len(positions)
    cols = {name: np.zeros((n,) + shape, dtype) for name, shape, dtype in PointStore.column_specs()}
    cols["positions"] = positions.astype(np.float64)
    cols["normals"] = np.tile([0.0, 0.0, 1.0], (n, 1))
    cols["first_kf"] = np.array(creators, cols["first_kf"].dtype)
    return HeldRows(map_id, first, cols, [{k: j} for j, k in enumerate(creators)], np.array(creators, np.int64),
                    np.arange(n, dtype=np.int64), np.arange(n, dtype=np.int64))  # fmt: skip


def test_held_provisional_rows_move_into_the_merged_frame_and_join_after_the_merged_maps_rows() -> None:
    T = make_pose(_rot_z(90.0), np.array([1.0, 0.0, 0.0]))
    a = _held(0, 50, np.array([[0.0, 0.0, 2.0]]), [3])
    b = _held(1, 20, np.array([[1.0, 0.0, 2.0], [0.0, 1.0, 2.0]]), [7, 8])
    moved = b.moved(T, 0)
    assert moved.map_id == 0 and b.map_id == 1
    np.testing.assert_allclose(moved.columns["positions"], [[1.0, 1.0, 2.0], [0.0, 0.0, 2.0]], atol=1e-12)
    np.testing.assert_allclose(moved.columns["normals"], [[0.0, 0.0, 1.0]] * 2, atol=1e-12)
    np.testing.assert_allclose(b.columns["positions"][0], [1.0, 0.0, 2.0])  # the original is not changed
    j = HeldRows.join(a, moved)
    assert len(j) == 3 and j.first == 50 and j.map_id == 0
    np.testing.assert_array_equal(j.creators(), [3, 7, 8])
    np.testing.assert_array_equal(j.ref_rows, [0, 1, 2])
    assert HeldRows.join(None, moved) is moved and HeldRows.join(a, None) is a
