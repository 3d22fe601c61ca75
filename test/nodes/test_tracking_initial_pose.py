"""The tracking node's /initialpose (nodes/tracking_initial_pose.py): an RViz-style PoseWithCovarianceStamped in
the map frame becomes the system's relocalisation hint, and the next frame relocalises at the place it names in a
room whose texture repeats; a pose in another frame or with a zero quaternion is refused."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytestmark = pytest.mark.ros

pytest.importorskip("rclpy")
pytest.importorskip("changing_slam_msgs.msg", reason="interfaces not built (tools/build_interfaces.sh)")

from geometry_msgs.msg import PoseWithCovarianceStamped  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from changing_slam_ros.nodes.conversions import matrix_to_pose  # noqa: E402
from changing_slam_ros.nodes.tracking_node import TrackingNode  # noqa: E402
from helpers import spin_until  # noqa: E402
from wall_scene import S, map_wall, off_by, render, truth  # noqa: E402


def initial_pose(T: np.ndarray, frame: str = "map") -> PoseWithCovarianceStamped:  # noqa: N803
    msg = PoseWithCovarianceStamped()
    msg.header.frame_id = frame
    msg.pose.pose = matrix_to_pose(T)
    cov = np.zeros(36)
    cov[0] = cov[7] = 0.25  # RViz's 2D Pose Estimate: 0.5 m in x and y, 0.26 rad in yaw
    cov[35] = 0.06853891909122467
    msg.pose.covariance = cov.tolist()
    return msg


@pytest.mark.parametrize("in_process", [True, False], ids=["in_process_backend", "split_backend"])
def test_initial_pose_message_seeds_relocalisation_at_the_place_it_names(ros_context, tmp_path, in_process):
    """In-process, and split (tracking's replica of the map local_mapping owns, loaded from the same file)."""
    map_file = map_wall(tmp_path / "map.npz")
    tracking = TrackingNode(context=ros_context, parameter_overrides=[
        Parameter("in_process_backend", value=in_process), Parameter("map_file", value=str(map_file)),
        Parameter("mode", value="localization"), Parameter("loop_closing", value=False),
    ])  # fmt: skip
    assert (tracking.split is None) == in_process
    probe = Node("probe", context=ros_context)
    pub = probe.create_publisher(PoseWithCovarianceStamped, "/initialpose", 10)
    executor = SingleThreadedExecutor(context=ros_context)
    for node in (tracking, probe):
        executor.add_node(node)
    try:
        assert spin_until(executor, lambda: pub.get_subscription_count() > 0)
        inputs = tracking.initial_pose
        bad = initial_pose(truth(0))
        q = bad.pose.pose.orientation
        q.x = q.y = q.z = q.w = 0.0
        for msg in (initial_pose(truth(0), frame="odom"), bad):
            pub.publish(msg)
        assert spin_until(executor, lambda: inputs.received == 2)
        assert inputs.applied == 0 and tracking.backend.system.tracker.pose_hint is None

        given = off_by(truth(0), 0.3, 20.0)  # near copy 0; without a hint this view is placed at copy 1
        pub.publish(initial_pose(given))
        assert spin_until(executor, lambda: inputs.applied == 1)
        hint = tracking.backend.system.tracker.pose_hint
        assert hint is not None and np.allclose(hint.T_world_cam, given, atol=1e-9)
        assert hint.radius_m == pytest.approx(1.5) and hint.angle_rad == pytest.approx(3 * math.sqrt(0.06853891909122467))

        frame = render(truth(0), 100 * S, 0)
        out = tracking.backend.system.process(frame) if in_process else tracking.split.process(frame, None)[0]
        assert out.relocalised and out.T_world_cam is not None
        assert np.linalg.norm(out.T_world_cam[:3, 3] - truth(0)[:3, 3]) < 0.03
    finally:
        executor.shutdown()
        probe.destroy_node()
        tracking.destroy_node()
