"""The tracking node's split backend in real time with no map owner running: provisional points keep it going."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytestmark = pytest.mark.ros

pytest.importorskip("rclpy")
pytest.importorskip("changing_slam_msgs.msg", reason="interfaces not built (tools/build_interfaces.sh)")

from geometry_msgs.msg import PoseStamped  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import QoSProfile  # noqa: E402

from changing_slam_msgs.msg import Keyframe as KeyframeMsg  # noqa: E402
from changing_slam_ros.core.geometry.trajectory import Trajectory  # noqa: E402
from changing_slam_ros.eval.ate import ate  # noqa: E402
from changing_slam_ros.io.dataset import open_dataset  # noqa: E402
from changing_slam_ros.nodes import conversions as cv  # noqa: E402
from changing_slam_ros.nodes.tracking_node import TrackingNode  # noqa: E402
from helpers import REPO, lossless_player, require, spin_until  # noqa: E402


@pytest.mark.parametrize("provisional", [True, False])
def test_split_tracking_without_a_map_owner_tracks_every_frame_only_with_provisional_points(
        ros_context, tmp_path, provisional):  # fmt: skip
    """fr1 bag (9 frames), split backend, real time (no wait for map updates), and no local_mapping: with
    provisional points every frame gets a pose within 1 cm of ground truth; without, only the first (the new
    map then waits for points that never come). The keyframe packet names no provisional point."""
    bag = require(REPO / "bags" / "tum_fr1_xyz_first10.mcap")
    out = tmp_path / "out"
    tracking = TrackingNode(context=ros_context, parameter_overrides=[
        Parameter("config", value="tum_fr1"), Parameter("ack_topic", value="/bag_player/ack"),
        Parameter("provisional_points", value=provisional), Parameter("output_dir", value=str(out)),
        Parameter("loop_closing", value=False), Parameter("objects", value="off"),
    ])  # fmt: skip
    player = lossless_player(ros_context, bag)
    probe = Node("probe", context=ros_context)
    poses: list[PoseStamped] = []
    keyframes: list[KeyframeMsg] = []
    probe.create_subscription(PoseStamped, "/tracking/pose", poses.append, 100)
    probe.create_subscription(KeyframeMsg, "/tracking/keyframes", keyframes.append, QoSProfile(depth=100))
    executor = SingleThreadedExecutor(context=ros_context)
    for node in (tracking, probe, player):
        executor.add_node(node)
    result = player.play(executor)
    assert result.completed
    spin_until(executor, lambda: len(poses) >= (9 if provisional else 1) and keyframes, 5.0)
    assert tracking.split is not None and (tracking.split.provisional is not None) == provisional
    if provisional:
        assert len(poses) == 9
        gt = open_dataset(bag, "tum_fr1").groundtruth
        stamps = np.array([cv.stamp_to_ns(p.header.stamp) * 1e-9 for p in poses])
        est = Trajectory.from_poses(stamps, np.array([cv.pose_to_matrix(p.pose) for p in poses]))
        assert ate(gt, est).stats.rmse < 0.01
        assert tracking.split.provisional.n_created > 300
    else:
        assert len(poses) == 1
    assert keyframes and keyframes[0].id == 0
    assert max(keyframes[0].point_ids, default=-1) == -1  # a new map's first keyframe: the owner makes its points
    executor.shutdown()
    tracking.destroy_node()
    stats = json.loads((out / "tracking_stats.json").read_text())
    assert stats["frames_skipped_waiting_for_map"] == (0 if provisional else 8)
    assert (stats["provisional_points_created"] is not None) == provisional
    player.destroy_node()
    probe.destroy_node()
