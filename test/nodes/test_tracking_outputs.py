"""nodes/tracking_outputs.py: the per-frame pose outputs keep the whole path but build odometry, path and TF
messages only for subscribers."""

from __future__ import annotations

import numpy as np
import pytest

pytestmark = pytest.mark.ros

pytest.importorskip("rclpy")

from nav_msgs.msg import Odometry, Path as PathMsg  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402

from changing_slam_ros.core.geometry.se3 import make_pose  # noqa: E402
from changing_slam_ros.nodes.qos_events import QuietQosEvents  # noqa: E402
from changing_slam_ros.nodes.tracking_outputs import PoseOutputs  # noqa: E402
from helpers import spin_until  # noqa: E402


class Quiet(QuietQosEvents, Node):
    pass


def test_the_path_keeps_every_pose_and_goes_out_only_to_subscribers(ros_context) -> None:
    node = Quiet("tracking", context=ros_context)
    out = PoseOutputs(node, 10, "map", "camera")
    assert len(list(node.waitables)) == 0  # no QoS-event handlers on these publishers (nodes/qos_events.py)
    poses = [make_pose(np.eye(3), np.array([0.1 * k, 0.0, 0.0])) for k in range(4)]
    for k in range(3):  # nobody listens: the path grows, nothing is built for odometry, path or TF
        out.publish(1_000_000_000 + k, poses[k])
    assert len(out.path.poses) == 3
    probe = Node("probe", context=ros_context)
    paths: list[PathMsg] = []
    odoms: list[Odometry] = []
    probe.create_subscription(PathMsg, "/tracking/path", paths.append, 10)
    probe.create_subscription(Odometry, "/tracking/odometry", odoms.append, 10)
    executor = SingleThreadedExecutor(context=ros_context)
    for n in (node, probe):
        executor.add_node(n)
    assert spin_until(executor, lambda: out.path_pub.get_subscription_count() > 0
                      and out.odom_pub.get_subscription_count() > 0)  # fmt: skip
    out.publish(1_000_000_003, poses[3])
    assert spin_until(executor, lambda: paths and odoms, 5.0)
    assert len(paths[-1].poses) == 4 and paths[-1].poses[3].pose.position.x == pytest.approx(0.3)
    assert odoms[-1].child_frame_id == "camera" and odoms[-1].header.frame_id == "map"
    out.replace_path([2.0], [poses[1]])  # after a loop closure: the optimised trajectory so far
    assert len(out.path.poses) == 1 and out.path.poses[0].header.stamp.sec == 2
    executor.shutdown()
    probe.destroy_node()
    node.destroy_node()


def test_a_bounded_path_thins_evenly_and_keeps_the_newest_pose(ros_context) -> None:
    node = Quiet("tracking_bounded", context=ros_context)
    out = PoseOutputs(node, 10, "map", "camera", path_max_poses=10)
    for k in range(101):  # nobody listens; the path is bounded all the same
        out.publish(1_000_000_000 + k, make_pose(np.eye(3), np.array([0.01 * k, 0.0, 0.0])))
        assert len(out.path.poses) <= 10
    xs = np.array([p.pose.position.x for p in out.path.poses])
    assert xs[0] == 0.0 and xs[-1] == pytest.approx(1.0)  # the start of the way and the newest pose
    steps = np.diff(xs)
    assert len(xs) >= 6 and np.allclose(steps[:-1], steps[0]) and 0 < steps[-1] <= steps[0] + 1e-9  # even spacing
    out.replace_path(np.arange(50.0), [make_pose(np.eye(3), np.array([float(k), 0.0, 0.0])) for k in range(50)])
    xs = [p.pose.position.x for p in out.path.poses]
    assert 5 <= len(xs) <= 10 and xs[0] == 0.0 and xs[-1] == 49.0
    fed = PoseOutputs(node, 10, "map", "camera", path_max_poses=10)  # the same poses one by one: the same path
    for k in range(50):
        fed.publish(k * 1_000_000_000, make_pose(np.eye(3), np.array([float(k), 0.0, 0.0])))
    assert [p.pose.position.x for p in fed.path.poses] == xs
    with pytest.raises(Exception, match="path_max_poses"):
        PoseOutputs(node, 10, "map", "camera", path_max_poses=1)
    node.destroy_node()
