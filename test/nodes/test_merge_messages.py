"""Map merges over the wire: loop_closing's MapMerge in a LoopCorrection, the map owner's merge in a MapUpdate."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("changing_slam_msgs.msg", reason="interfaces not built (tools/build_interfaces.sh)")

from changing_slam_ros.core.slam.loop_closing import MapMerge  # noqa: E402
from changing_slam_ros.core.slam.map_merging import MergeResult  # noqa: E402
from changing_slam_ros.core.replication.map_replication import LoopResult, MapUpdate, full_delta  # noqa: E402
from changing_slam_ros.core.geometry.se3 import make_pose  # noqa: E402
from changing_slam_ros.core.map.slam_map import SlamMap  # noqa: E402
from changing_slam_ros.errors import BagError  # noqa: E402
from changing_slam_ros.nodes.replication_conversions import (  # noqa: E402
    loop_result_from_msg,
    loop_result_to_msg,
    update_from_msg,
    update_to_msg,
)


def _transform(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    w = rng.normal(size=3) * 0.3
    theta = np.linalg.norm(w)
    k = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]) / theta
    R = np.eye(3) + np.sin(theta) * k + (1 - np.cos(theta)) * k @ k
    return make_pose(R, rng.normal(size=3))


def test_a_merge_verdict_crosses_the_loop_correction_message_exactly() -> None:
    T = _transform(1)
    rel = _transform(2)
    matches = np.array([[3, 7], [10, 2], [11, 40]], np.int64)
    merge = MapMerge(query_kf_id=52, match_kf_id=9, query_map_id=1, match_map_id=0, T_match_query=rel,
                     T_matchworld_queryworld=T, num_inliers=3, keypoint_matches=matches)
    msg = loop_result_to_msg(LoopResult(52, False, merge=merge), 5, "map", map_id=1)
    assert msg.merge and not msg.closed
    back = loop_result_from_msg(msg, "t")
    assert not back.closed and back.merge is not None
    g = back.merge
    assert (g.query_kf_id, g.match_kf_id, g.query_map_id, g.match_map_id, g.num_inliers) == (52, 9, 1, 0, 3)
    np.testing.assert_array_equal(g.T_matchworld_queryworld, T)  # bit for bit: the owner moves the map with it
    np.testing.assert_allclose(g.T_match_query, rel, atol=1e-12)
    np.testing.assert_array_equal(g.keypoint_matches, matches)
    # A plain "no loop" verdict has no merge.
    assert loop_result_from_msg(loop_result_to_msg(LoopResult(53, False), 6, "map", 1), "t").merge is None


def test_a_merge_update_crosses_the_map_update_message_and_bad_ones_are_rejected() -> None:
    T = _transform(3)
    r = MergeResult(from_map_id=1, into_map_id=0, T_into_from=T, point_id_offset=1234, moved_keyframes=(40, 41, 45),
                    n_points_moved=300, n_fused=17, ba=None)
    msg = update_to_msg(MapUpdate(-1, full_delta(SlamMap(0)), loop_query_kf_id=45, merge=r), 7, "map")
    back = update_from_msg(msg, "t")
    assert back.keyframe_id == -1 and back.loop_query_kf_id == 45 and back.merge is not None
    g = back.merge
    assert (g.from_map_id, g.into_map_id, g.point_id_offset, g.moved_keyframes) == (1, 0, 1234, (40, 41, 45))
    assert (g.n_points_moved, g.n_fused) == (300, 17)
    np.testing.assert_array_equal(g.T_into_from, T)
    # An ordinary update has none.
    assert update_from_msg(update_to_msg(MapUpdate(3, full_delta(SlamMap(0))), 8, "map"), "t").merge is None
    msg.merge_transform = msg.merge_transform[:12]
    with pytest.raises(BagError, match="merge_transform"):
        update_from_msg(msg, "t")
    msg.merged_from_map_id = 0
    with pytest.raises(BagError, match="into itself"):
        update_from_msg(msg, "t")


def test_a_keyframe_packet_carries_the_counter_increments_of_other_maps() -> None:
    from changing_slam_ros.core.geometry.camera import CameraIntrinsics
    from changing_slam_ros.core.map.keyframe import Keyframe
    from changing_slam_ros.core.replication.map_replication import KeyframePacket, PointCounters
    from changing_slam_ros.nodes.replication_conversions import packet_from_msg, packet_to_msg

    cam = CameraIntrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)
    kf = Keyframe(20, 20, np.eye(4), cam, np.zeros((2, 2), np.float32), np.zeros(2, np.int8),
                  np.zeros((2, 32), np.uint8), np.ones(2, np.float32), np.full(2, -1, np.int64), map_id=1)
    i64 = lambda *v: np.array(v, np.int64)  # noqa: E731
    others = {0: PointCounters(i64(4, 9, 10), i64(1, 2, 0), i64(1, 0, 0), i64(300, 301, 305)),
              2: PointCounters(i64(7), i64(3), i64(3), i64(12))}
    msg = packet_to_msg(KeyframePacket(kf, PointCounters(i64(1), i64(1), i64(1), i64(319)), other_counters=others), "map")
    back = packet_from_msg(msg, "t")
    assert sorted(back.other_counters) == [0, 2]
    for k, c in others.items():
        for f in ("ids", "n_visible", "n_found", "last_seen_frame"):
            np.testing.assert_array_equal(getattr(back.other_counters[k], f), getattr(c, f))
    assert packet_from_msg(packet_to_msg(KeyframePacket(kf), "map"), "t").other_counters == {}
    msg.other_counter_lengths = [3, 2]
    with pytest.raises(BagError, match="other_counter"):
        packet_from_msg(msg, "t")
