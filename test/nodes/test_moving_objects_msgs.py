"""Moving objects (class-agnostic movers) as messages and in the graph's outputs.mcap (fast, no nodes)."""

from __future__ import annotations

import numpy as np
import pytest

pytestmark = pytest.mark.ros

pytest.importorskip("rclpy")
pytest.importorskip("changing_slam_msgs.msg", reason="interfaces not built (tools/build_interfaces.sh)")

from visualization_msgs.msg import Marker  # noqa: E402

from changing_slam_ros.core.movers.object_tracking import MovingObjectTrack  # noqa: E402
from changing_slam_ros.core.geometry.se3 import make_pose  # noqa: E402
from changing_slam_ros.nodes import conversions as cv  # noqa: E402

S = 1_000_000_000


def _track(object_id: int, n: int, start_ns: int = 5 * S) -> MovingObjectTrack:
    """An object moving 2 cm per frame along x while turning about z, 30 Hz."""
    from scipy.spatial.transform import Rotation

    poses = np.stack([make_pose(Rotation.from_euler("z", 0.05 * k).as_matrix(), np.array([0.02 * k, 1.0, -0.5]))
                      for k in range(n)])  # fmt: skip
    stamps = start_ns + np.arange(n, dtype=np.int64) * (S // 30)
    return MovingObjectTrack(object_id, -1, stamps, poses, 7)


def test_moving_objects_round_trip_through_their_message_and_markers_follow_the_trajectory():
    tracks = [_track(3, 12), _track(8, 1, 6 * S)]
    points = {3: np.arange(21, dtype=np.float64).reshape(7, 3) * 0.01}
    msg = cv.moving_objects_to_msg(tracks, points, cv.make_header(7 * S, "map"))
    assert [o.id for o in msg.objects] == [3, 8]
    assert cv.stamp_to_ns(msg.objects[0].header.stamp) == tracks[0].last_stamp_ns
    back = cv.moving_objects_from_msg(msg)
    t3, p3 = back[0]
    np.testing.assert_array_equal(t3.stamps_ns, tracks[0].stamps_ns)
    np.testing.assert_allclose(t3.T_world_obj, tracks[0].T_world_obj, atol=1e-9)
    np.testing.assert_allclose(p3, points[3], atol=1e-6)  # float32 on the wire
    assert back[1][1].shape == (0, 3) and back[1][0].class_id == -1
    np.testing.assert_allclose(cv.pose_to_matrix(msg.objects[0].pose), tracks[0].T_world_obj[-1], atol=1e-9)

    markers = cv.moving_object_markers(tracks, cv.make_header(7 * S, "map")).markers
    assert markers[0].action == Marker.DELETEALL
    strips = [m for m in markers if m.type == Marker.LINE_STRIP]
    assert [m.id for m in strips] == [3]  # a single pose draws no line
    assert [round(p.x, 6) for p in strips[0].points] == [round(0.02 * k, 6) for k in range(12)]
    spheres = {m.id: m for m in markers if m.type == Marker.SPHERE}
    assert set(spheres) == {3, 8} and spheres[3].pose.position.x == pytest.approx(0.22)
    assert strips[0].color != spheres[8].color


def test_a_bad_point_array_is_rejected():
    msg = cv.moving_objects_to_msg([_track(1, 3)], {}, cv.make_header(0, "map"))
    msg.objects[0].points = [0.0, 1.0]
    with pytest.raises(ValueError, match="moving object 1: 2 point values"):
        cv.moving_objects_from_msg(msg)


def test_the_graph_writes_moving_objects_json_into_outputs_mcap(tmp_path):
    from rosbags.highlevel import AnyReader

    from changing_slam_ros.commands.graph_outputs import write_mover_topics
    from changing_slam_ros.io.mcap_writer import RgbdMcapWriter
    from changing_slam_ros.io.moving_objects_file import write_moving_objects
    from changing_slam_ros.io.msg_types import typestore_with_project_types

    tracks = [_track(3, 12), _track(8, 2, 6 * S)]
    write_moving_objects(tmp_path, tracks)
    with RgbdMcapWriter(tmp_path / "outputs.mcap") as writer:
        assert write_mover_topics(writer, tmp_path) == 2
    with AnyReader([tmp_path / "outputs.mcap"], default_typestore=typestore_with_project_types()) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        assert counts == {"/moving_objects/object_3/pose": 12, "/moving_objects/object_8/pose": 2,
                          "/tracking/moving_objects": 1, "/tracking/moving_object_markers": 1}  # fmt: skip
        conns = [c for c in reader.connections if c.topic in ("/moving_objects/object_3/pose", "/tracking/moving_objects")]
        msgs = {c.topic: [] for c in conns}
        for con, log_ns, raw in reader.messages(conns):
            msgs[con.topic].append((log_ns, reader.deserialize(raw, con.msgtype)))
    poses = msgs["/moving_objects/object_3/pose"]
    # TUM files keep microseconds: the stamps come back within one.
    np.testing.assert_allclose([ns for ns, _ in poses], tracks[0].stamps_ns, atol=1000, rtol=0)
    assert poses[-1][1].header.frame_id == "map" and poses[-1][1].pose.position.x == pytest.approx(0.22)
    (log_ns, arr), = msgs["/tracking/moving_objects"]
    assert abs(log_ns - tracks[1].last_stamp_ns) <= 1000 and [len(o.trajectory.poses) for o in arr.objects] == [12, 2]


def test_without_moving_objects_json_nothing_is_written(tmp_path):
    from changing_slam_ros.commands.graph_outputs import write_mover_topics
    from changing_slam_ros.io.mcap_writer import RgbdMcapWriter

    with RgbdMcapWriter(tmp_path / "outputs.mcap") as writer:
        assert write_mover_topics(writer, tmp_path) == 0
