"""Lossless split backend: tracking holds frames until local_mapping and loop_closing are matched.

A keyframe published before its subscriptions matched is lost for good (volatile QoS), and the
acknowledgement held for its map update would then wait out `map_update_timeout_s`. Here the peers are
stand-ins on a probe node: without them the first frame is not tracked; once they are matched it is; and
with no peers at all tracking goes on after `peers_wait_s`.
"""

from __future__ import annotations

import time

import pytest

pytestmark = pytest.mark.ros

pytest.importorskip("rclpy")
pytest.importorskip("changing_slam_msgs.msg", reason="interfaces not built (tools/build_interfaces.sh)")

from geometry_msgs.msg import PoseStamped  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import Image  # noqa: E402

from changing_slam_msgs.msg import Keyframe as KeyframeMsg  # noqa: E402
from changing_slam_msgs.msg import LoopCorrection, MapUpdate  # noqa: E402
from changing_slam_ros.io.dataset import open_dataset  # noqa: E402
from changing_slam_ros.nodes.conversions import depth_to_image, rgb_to_image  # noqa: E402
from changing_slam_ros.nodes.tracking_node import TrackingNode  # noqa: E402
from helpers import FR1_XYZ_10, require, spin_until  # noqa: E402


def _graph(ros_context, peers_wait_s: float, resend_s: float = 5.0):  # noqa: ANN001, ANN202
    tracking = TrackingNode(context=ros_context, parameter_overrides=[
        Parameter("config", value="tum_fr1"), Parameter("intrinsics_from", value="config"),
        Parameter("wait_for_map_updates", value=True), Parameter("peers_wait_s", value=peers_wait_s),
        Parameter("diagnostics_period_s", value=0.0), Parameter("debug_image", value=False),
        Parameter("map_update_resend_s", value=resend_s),
    ])  # fmt: skip
    probe = Node("probe", context=ros_context)
    poses: list[PoseStamped] = []
    probe.create_subscription(PoseStamped, "/tracking/pose", poses.append, 10)
    qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
    pubs = (probe.create_publisher(Image, "/camera/rgb/image_color", qos),
            probe.create_publisher(Image, "/camera/depth/image", qos))  # fmt: skip
    executor = SingleThreadedExecutor(context=ros_context)
    for n in (tracking, probe):
        executor.add_node(n)
    assert spin_until(executor, lambda: all(p.get_subscription_count() > 0 for p in pubs), 10.0)
    frame = next(iter(open_dataset(require(FR1_XYZ_10), "tum_fr1")))
    pubs[0].publish(rgb_to_image(frame.rgb, frame.stamp_ns, "camera"))
    pubs[1].publish(depth_to_image(frame.depth_m, frame.stamp_ns, "camera"))
    return tracking, probe, executor, poses


def test_the_first_frame_waits_for_the_peers_and_goes_once_they_match(ros_context):
    tracking, probe, executor, poses = _graph(ros_context, peers_wait_s=60.0)
    spin_until(executor, lambda: bool(poses), 1.5)
    assert poses == [] and len(tracking.queue) == 1  # held: nobody would get its keyframe
    keyframes: list[KeyframeMsg] = []
    for _ in range(2):  # local_mapping's and loop_closing's subscriptions
        probe.create_subscription(KeyframeMsg, "/tracking/keyframes", keyframes.append, QoSProfile(depth=100))
    probe.create_publisher(MapUpdate, "/local_mapping/map_updates", 10)
    probe.create_publisher(LoopCorrection, "/loop_closing/loop_corrections", 10)
    assert spin_until(executor, lambda: bool(poses) and bool(keyframes), 10.0)
    assert keyframes[0].id == 0  # the first keyframe reached the matched subscriptions


def test_without_peers_tracking_goes_on_after_the_wait(ros_context):
    tracking, _probe, executor, poses = _graph(ros_context, peers_wait_s=1.0)
    t0 = time.monotonic()
    assert spin_until(executor, lambda: bool(poses), 10.0)
    assert time.monotonic() - t0 > 0.9  # not before the wait ran out


def test_after_a_restart_a_keyframe_without_its_map_update_is_sent_again(ros_context):
    # a restarted local_mapping can miss the keyframe tracking sends after its snapshot: while the held ack waits,
    # the keyframe goes out again every map_update_resend_s (the receivers drop one they have); without a
    # restart it is sent once
    tracking, probe, executor, _poses = _graph(ros_context, peers_wait_s=60.0, resend_s=0.3)
    keyframes: list[KeyframeMsg] = []
    for _ in range(2):
        probe.create_subscription(KeyframeMsg, "/tracking/keyframes", keyframes.append, QoSProfile(depth=100))
    probe.create_publisher(MapUpdate, "/local_mapping/map_updates", 10)
    probe.create_publisher(LoopCorrection, "/loop_closing/loop_corrections", 10)
    assert spin_until(executor, lambda: len(keyframes) >= 2, 10.0)  # sent to both subscriptions
    spin_until(executor, lambda: len(keyframes) > 2, 1.0)
    assert len(keyframes) == 2 and tracking.keyframes_resent == 0  # no restart: no resend
    tracking._resend_unmapped("local_mapping")  # as after the snapshot answer to a restarted local_mapping
    assert spin_until(executor, lambda: len(keyframes) >= 8, 10.0)  # the resend, then 2 more, each to both
    assert {k.id for k in keyframes} == {0} and tracking.keyframes_resent >= 2
    assert tracking.map_update_waits_timed_out == 0
