"""The nodes in-process: topics, conversions, acks, services (tracking with `slam:=false`: plumbing only;
its SLAM backend is tested in test_tracking_node.py)."""

from __future__ import annotations


import numpy as np
import pytest

pytestmark = pytest.mark.ros

pytest.importorskip("rclpy")
pytest.importorskip("changing_slam_msgs.msg", reason="interfaces not built (tools/build_interfaces.sh)")

from geometry_msgs.msg import Point, PoseStamped, Vector3  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from std_msgs.msg import Header  # noqa: E402
from tf2_msgs.msg import TFMessage  # noqa: E402
from visualization_msgs.msg import MarkerArray  # noqa: E402

from changing_slam_msgs.msg import Keyframe as KeyframeMsg, MapObject  # noqa: E402
from changing_slam_msgs.srv import QueryObjects, SaveMap  # noqa: E402
from changing_slam_ros.core.geometry.camera import CameraIntrinsics  # noqa: E402
from changing_slam_ros.core.map.keyframe import Keyframe  # noqa: E402
from changing_slam_ros.nodes import conversions as cv  # noqa: E402
from changing_slam_ros.nodes.bag_player_node import BagPlayerNode  # noqa: E402
from changing_slam_ros.nodes.local_mapping_node import LocalMappingNode  # noqa: E402
from changing_slam_ros.nodes.loop_closing_node import LoopClosingNode  # noqa: E402
from changing_slam_ros.nodes.object_map_node import ObjectMapNode  # noqa: E402
from changing_slam_ros.nodes.tracking_node import TrackingNode  # noqa: E402
from helpers import spin_until  # noqa: E402


def test_tracking_pairs_every_bag_frame_and_acks_it_for_a_lossless_bag_player(ros_context, tmp_path, fr1_bag_writer):
    bag = fr1_bag_writer(tmp_path / "bag", n=10, scale=4)
    tracking = TrackingNode(context=ros_context, parameter_overrides=[
        Parameter("ack_topic", value="/bag_player/ack"), Parameter("slam", value=False)])  # fmt: skip
    player = BagPlayerNode(context=ros_context, parameter_overrides=[
        Parameter("bag", value=str(bag.path)), Parameter("rate", value=5.0), Parameter("lossless", value=True),
        Parameter("ack_topics", value=["/camera/rgb/image_color"]),
        Parameter("wait_subscribers_timeout_s", value=10.0), Parameter("ack_timeout_s", value=1.0),
    ])  # fmt: skip
    acks: list[int] = []
    probe = Node("probe", context=ros_context)
    probe.create_subscription(Header, "/bag_player/ack", lambda m: acks.append(cv.stamp_to_ns(m.stamp)), 100)
    executor = SingleThreadedExecutor(context=ros_context)
    for node in (tracking, player, probe):
        executor.add_node(node)
    # the probe must hear the first ack: an ack published before discovery matched it would be lost
    assert spin_until(executor, lambda: tracking.ack_pub.get_subscription_count() >= 2, 10.0)
    result = player.play(executor)
    spin_until(executor, lambda: len(acks) >= len(bag.rgb_stamps_ns), 2.0)
    # Each colour frame's depth frame was recorded 15-20 ms after it: acknowledging a colour frame needs the
    # depth frame published after it (one frame in flight), and nothing times out.
    assert all(0 < d - c < 20_000_000 for c, d in zip(bag.rgb_stamps_ns, bag.depth_stamps_ns))
    assert result.completed and result.ack_timeouts == 0
    # Every colour frame paired with a depth frame, converted to an RgbdFrame and acknowledged.
    assert tracking.frames_in == len(bag.rgb_stamps_ns) == 9
    assert tracking.camera is not None and tracking.camera.width == 160
    assert sorted(set(acks))[: tracking.frames_in] == bag.rgb_stamps_ns[: tracking.frames_in]
    executor.shutdown()
    for node in (tracking, player, probe):
        node.destroy_node()


def test_tracking_publishes_pose_and_rep105_tf_from_a_camera_to_world_matrix(ros_context):
    tracking = TrackingNode(context=ros_context, parameter_overrides=[Parameter("slam", value=False)])
    probe = Node("probe", context=ros_context)
    poses: list[PoseStamped] = []
    tfs: list[TFMessage] = []
    probe.create_subscription(PoseStamped, "/tracking/pose", poses.append, 10)
    probe.create_subscription(TFMessage, "/tf", tfs.append, 10)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(tracking)
    executor.add_node(probe)
    spin_until(executor, lambda: tracking.poses_out.pose_pub.get_subscription_count() > 0 and tracking.frames_out.tf_pub.get_subscription_count() > 0)
    T = np.eye(4)
    T[:3, 3] = [1.0, -2.0, 0.5]
    tracking.publish_pose(1305031102_175304000, T)
    assert spin_until(executor, lambda: poses and tfs)
    assert poses[0].header.frame_id == "map" and poses[0].pose.position.y == -2.0
    frames = [(t.header.frame_id, t.child_frame_id) for t in tfs[0].transforms]
    assert frames == [("map", "odom"), ("odom", "camera")]
    assert tfs[0].transforms[1].transform.translation.x == 1.0
    executor.shutdown()
    tracking.destroy_node()
    probe.destroy_node()


def _keyframe_msg(n: int = 50) -> KeyframeMsg:
    rng = np.random.default_rng(1)
    kf = Keyframe(
        id=3, stamp_ns=10, T_world_cam=np.eye(4), camera=CameraIntrinsics(640, 480, 525.0, 525.0, 319.5, 239.5),
        keypoints_px=rng.uniform(0, 480, (n, 2)).astype(np.float32), octaves=np.zeros(n, np.int8),
        descriptors=rng.integers(0, 256, (n, 32)).astype(np.uint8), depths_m=np.ones(n, np.float32),
        point_ids=np.full(n, -1, np.int64),  # a first keyframe: no map points yet
    )  # fmt: skip
    return cv.keyframe_to_msg(kf, "map")


@pytest.mark.parametrize("node_class", [LocalMappingNode, LoopClosingNode])
def test_mapping_and_loop_nodes_take_keyframes_and_reject_malformed_ones(ros_context, node_class):
    node = node_class(context=ros_context, parameter_overrides=[Parameter("resync_timeout_s", value=0.0)])
    probe = Node("probe", context=ros_context)
    pub = probe.create_publisher(KeyframeMsg, "/tracking/keyframes", QoSProfile(depth=100))
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    executor.add_node(probe)
    assert spin_until(executor, lambda: pub.get_subscription_count() > 0)
    bad = _keyframe_msg()
    bad.octaves = bad.octaves[:10]  # 10 octaves for 50 keypoints
    pub.publish(bad)
    pub.publish(_keyframe_msg())
    assert spin_until(executor, lambda: node.keyframes_in >= 1)
    spin_until(executor, lambda: False, 0.3)
    assert node.keyframes_in == 1  # the malformed one was rejected with a warning, the node lives on
    unknown = _keyframe_msg()
    unknown.id = 4
    unknown.point_ids = np.arange(50, dtype=np.int64) + 10_000  # points no map has: rejected, not a crash
    pub.publish(unknown)
    spin_until(executor, lambda: False, 0.3)
    rejected = node.keyframes_rejected if node_class is LocalMappingNode else node.rejected
    assert rejected == 2  # the malformed message and the keyframe naming unknown points
    executor.shutdown()
    node.destroy_node()
    probe.destroy_node()


def _object(i: int, class_id: int, name: str, x: float, belief: float) -> MapObject:
    return MapObject(
        id=i, class_id=class_id, class_name=name, centroid=Point(x=x, y=0.0, z=1.0), box_center=Point(x=x, z=1.0),
        box_size=Vector3(x=0.5, y=0.5, z=0.9), belief=belief, active=belief >= 0.5, n_points=40,
    )  # fmt: skip


def test_object_map_answers_queries_latches_the_semantic_map_and_resets(ros_context):
    node = ObjectMapNode(context=ros_context)
    node.objects = {1: _object(1, 56, "chair", 0.0, 0.9), 2: _object(2, 56, "chair", 3.0, 0.2),
                    3: _object(3, 62, "tv", 1.0, 0.8)}  # fmt: skip
    node.publish_map()
    probe = Node("probe", context=ros_context)
    markers: list[MarkerArray] = []
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    probe.create_subscription(MarkerArray, "/object_map/markers", markers.append, latched)  # a late subscriber
    query = probe.create_client(QueryObjects, "/object_map/query_objects")
    save = probe.create_client(SaveMap, "/object_map/save_map")
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    executor.add_node(probe)
    assert spin_until(executor, lambda: markers)
    boxes = [m for m in markers[0].markers if m.ns == "objects"]
    assert sorted(m.id for m in boxes) == [1, 2, 3]
    assert min(m.color.a for m in boxes) == pytest.approx(0.2)  # alpha = belief
    assert any(m.text == "tv #3 0.80" for m in markers[0].markers)

    def call(client, request):  # noqa: ANN001, ANN202
        assert spin_until(executor, client.service_is_ready)
        future = client.call_async(request)
        assert spin_until(executor, future.done)
        return future.result()

    chairs = call(query, QueryObjects.Request(class_ids=[56]))
    assert [o.id for o in chairs.objects] == [1]  # chair 2 is inactive (belief 0.2 < 0.5)
    all_chairs = call(query, QueryObjects.Request(class_ids=[56], include_inactive=True))
    assert [o.id for o in all_chairs.objects] == [1, 2]
    region = QueryObjects.Request(use_region=True, region_min=Point(x=0.5, y=-1.0, z=0.0),
                                  region_max=Point(x=2.0, y=1.0, z=2.0))  # fmt: skip
    assert [o.id for o in call(query, region).objects] == [3]
    saved = call(save, SaveMap.Request(path=""))  # no path and no map_file parameter
    assert not saved.success and "no path" in saved.message
    executor.shutdown()
    node.destroy_node()
    probe.destroy_node()


def test_tracking_takes_compressed_colour_and_depth_from_the_bundled_sim_bag(ros_context):
    from helpers import REPO, require

    path = require(REPO / "bags" / "sim_walking_changing.mcap")
    colour = "/camera/rgb/image_color/compressed"
    tracking = TrackingNode(context=ros_context, parameter_overrides=[
        Parameter("ack_topic", value="/bag_player/ack"), Parameter("compressed", value=True),
        Parameter("slam", value=False)])  # fmt: skip
    player = BagPlayerNode(context=ros_context, parameter_overrides=[
        Parameter("bag", value=str(path)), Parameter("rate", value=4.0), Parameter("start_offset_s", value=13.0),
        Parameter("lossless", value=True), Parameter("ack_topics", value=[colour]),
    ])  # fmt: skip
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(tracking)
    executor.add_node(player)
    result = player.play(executor)
    n_colour = result.per_topic[colour]
    assert result.completed and n_colour >= 20 and result.ack_timeouts == 0
    assert tracking.frames_in == n_colour  # every JPEG colour frame paired with its PNG depth frame and decoded
    assert tracking.camera is not None and (tracking.camera.width, tracking.camera.height) == (320, 240)  # sim camera
    executor.shutdown()
    tracking.destroy_node()
    player.destroy_node()
