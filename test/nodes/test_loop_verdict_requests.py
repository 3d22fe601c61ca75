"""A restarted loop_closing answers the keyframe local_mapping awaits a verdict on (wait_for_loop_results): it
announces on /loop_closing/ready that its map is in place, local_mapping sends that keyframe's update again on
/local_mapping/verdict_requests until the verdict comes, and loop_closing decides it once."""

from __future__ import annotations

import copy

import pytest

pytestmark = pytest.mark.ros

pytest.importorskip("rclpy")
pytest.importorskip("changing_slam_msgs.msg", reason="interfaces not built (tools/build_interfaces.sh)")

from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from std_msgs.msg import Header  # noqa: E402

from changing_slam_msgs.msg import Keyframe as KeyframeMsg  # noqa: E402
from changing_slam_msgs.msg import LoopCorrection, MapUpdate  # noqa: E402
from changing_slam_ros.core.replication.map_replication import KeyframePacket, LoopResult  # noqa: E402
from changing_slam_ros.nodes.replication_conversions import (  # noqa: E402
    loop_result_to_msg,
    packet_to_msg,
    update_to_msg,
)
from helpers import REDKITCHEN, require, spin_until  # noqa: E402

Q = QoSProfile(depth=100)
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def test_a_restarted_loop_closing_decides_the_keyframes_local_mapping_asks_about_once(ros_context):
    """Restarted, the node gets a drifting room of 8 keyframes from tracking (a probe), the last one without its
    verdict, and announces itself. local_mapping's request for it (sent twice) is decided on the restored map and
    answered once; a request for a keyframe whose update the snapshot predates waits for its packet, then its
    update is applied and decided; an ordinary update of a restored keyframe gets no second verdict."""
    from core.replication.test_map_replication import drifting_room_steps

    from changing_slam_ros.core.map.slam_map import SlamMap
    from changing_slam_ros.core.replication.map_replication import full_delta
    from changing_slam_ros.nodes.loop_closing_node import LoopClosingNode
    from changing_slam_ros.nodes.map_resync import ResyncServer

    m, sent, updates, restored = SlamMap(0), {}, {}, None
    for k, _, step in drifting_room_steps(10, 48):
        sent[k], updates[k] = step(m)
        if k == 7:
            restored = copy.deepcopy(m)
    probe = Node("tracking", context=ros_context)
    server = ResyncServer(probe, lambda: [(list(restored.keyframes.values()), full_delta(restored))], "map")
    node = LoopClosingNode(context=ros_context, parameter_overrides=[Parameter("config", value=""),
                                                                     Parameter("resync_timeout_s", value=30.0)])  # fmt: skip
    ready: list[Header] = []
    answers: list[LoopCorrection] = []
    probe.create_subscription(Header, "/loop_closing/ready", ready.append, LATCHED)
    probe.create_subscription(LoopCorrection, "/loop_closing/loop_corrections", answers.append, Q)
    request_pub = probe.create_publisher(MapUpdate, "/local_mapping/verdict_requests", Q)
    kf_pub = probe.create_publisher(KeyframeMsg, "/tracking/keyframes", Q)
    up_pub = probe.create_publisher(MapUpdate, "/local_mapping/map_updates", Q)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    executor.add_node(probe)
    assert spin_until(executor, lambda: node.resync.ready and ready, 30.0)
    assert server.answered >= 1 and node.resync.restored_keyframes == 8 and ready[0].frame_id == "loop_closing"
    assert spin_until(executor, lambda: request_pub.get_subscription_count() > 0 and kf_pub.get_subscription_count() > 0
                      and up_pub.get_subscription_count() > 0 and node.correction_pub.get_subscription_count() > 0)  # fmt: skip
    for _ in range(2):  # local_mapping repeats a request until the verdict lands
        request_pub.publish(update_to_msg(updates[7], sent[7].stamp_ns, "map"))
    up_pub.publish(update_to_msg(updates[7], sent[7].stamp_ns, "map"))  # came after the snapshot too: no verdict
    assert spin_until(executor, lambda: len(answers) >= 1, 30.0)
    request_pub.publish(update_to_msg(updates[8], sent[8].stamp_ns, "map"))  # the snapshot predates this update
    spin_until(executor, lambda: False, 1.0)
    assert [a.query_keyframe_id for a in answers] == [7] and 8 in node.asked  # waits for keyframe 8's packet
    kf_pub.publish(packet_to_msg(KeyframePacket(sent[8]), "map"))
    assert spin_until(executor, lambda: len(answers) >= 2, 30.0)
    spin_until(executor, lambda: False, 1.0)
    assert [a.query_keyframe_id for a in answers] == [7, 8] and not any(a.closed for a in answers)
    assert 8 in node.side.atlas.current.keyframes and not node.side.pending and not node.asked
    s = node.stats()
    assert (s["verdict_requests"], s["verdict_requests_answered"], s["rejected"]) == (2, 2, 0), s
    executor.shutdown()
    node.destroy_node()
    probe.destroy_node()


@pytest.fixture(scope="module")
def two_packets():
    """The first two keyframe packets tracking makes on 7-Scenes redkitchen (lossless order)."""
    from changing_slam_ros.io.dataset import open_dataset
    from changing_slam_ros.nodes.slam_backend import load_backend_config
    from changing_slam_ros.nodes.split_chains import ChainedGraph

    source = open_dataset(require(REDKITCHEN), "7scenes")
    chained = ChainedGraph.build(load_backend_config("7scenes"), loop=False, objects="off")
    packets: list[KeyframePacket] = []
    owner_call = chained.owner.on_keyframe

    def capture(packet: KeyframePacket):  # noqa: ANN202
        packets.append(copy.deepcopy(packet))
        return owner_call(packet)

    chained.owner.on_keyframe = capture  # type: ignore[method-assign]
    for i, rgbd in enumerate(source):
        if len(packets) >= 2 or i >= 45:
            break
        chained.process(rgbd)
    assert len(packets) >= 2
    return packets[:2]


def test_local_mapping_asks_a_loop_closing_that_announces_itself_for_the_verdict_it_awaits(ros_context, two_packets):
    """wait_for_loop_results: the second keyframe waits for the verdict on the first. A loop_closing announcing
    itself (latched, as a restarted one does) gets the first keyframe's update again, once a second until the
    verdict comes; then the second keyframe is mapped and the requests stop."""
    from changing_slam_ros.nodes.local_mapping_node import LocalMappingNode

    node = LocalMappingNode(context=ros_context, parameter_overrides=[
        Parameter("config", value="7scenes"), Parameter("objects", value="off"), Parameter("resync_timeout_s", value=0.0),
        Parameter("wait_for_loop_results", value=True)])  # fmt: skip
    probe = Node("probe", context=ros_context)
    kf_pub = probe.create_publisher(KeyframeMsg, "/tracking/keyframes", Q)
    verdict_pub = probe.create_publisher(LoopCorrection, "/loop_closing/loop_corrections", Q)
    ready_pub = probe.create_publisher(Header, "/loop_closing/ready", LATCHED)
    updates: list[MapUpdate] = []
    requests: list[MapUpdate] = []
    probe.create_subscription(MapUpdate, "/local_mapping/map_updates", updates.append, Q)
    probe.create_subscription(MapUpdate, "/local_mapping/verdict_requests", requests.append, Q)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    executor.add_node(probe)
    assert spin_until(executor, lambda: kf_pub.get_subscription_count() > 0 and verdict_pub.get_subscription_count() > 0
                      and node.update_pub.get_subscription_count() > 0
                      and node.verdict_request_pub.get_subscription_count() > 0)  # fmt: skip
    first, second = (p.keyframe.id for p in two_packets)
    for p in two_packets:
        kf_pub.publish(packet_to_msg(p, "map"))
    assert spin_until(executor, lambda: len(updates) >= 1 and len(node.queue) == 1, 30.0)
    assert node.awaiting_loop_for == first and not requests
    ready_pub.publish(Header(frame_id="loop_closing"))
    assert spin_until(executor, lambda: len(requests) >= 2, 10.0)  # the first at once, then a second later
    assert {r.keyframe_id for r in requests} == {first} and requests[0].delta == updates[0].delta
    verdict_pub.publish(loop_result_to_msg(LoopResult(first, False), two_packets[0].keyframe.stamp_ns, "map", 0))
    assert spin_until(executor, lambda: len(updates) >= 2, 30.0)
    n = len(requests)
    spin_until(executor, lambda: False, 1.5)
    assert [u.keyframe_id for u in updates] == [first, second] and node.awaiting_loop_for == second
    assert len(requests) == n and node.stats()["verdict_requests"] == n  # stopped at the verdict
    executor.shutdown()
    node.destroy_node()
    probe.destroy_node()
