"""local_mapping and loop_closing in-process: keyframe packets in, map updates / loop corrections out."""

from __future__ import annotations

import copy

import numpy as np
import pytest

pytestmark = pytest.mark.ros

pytest.importorskip("rclpy")
msgs = pytest.importorskip("changing_slam_msgs.msg", reason="interfaces not built (tools/build_interfaces.sh)")
if not hasattr(msgs, "MapDelta"):
    pytest.skip("interfaces older than msg_defs (run tools/build_interfaces.sh)", allow_module_level=True)

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import QoSProfile  # noqa: E402

from changing_slam_msgs.msg import Keyframe as KeyframeMsg  # noqa: E402
from changing_slam_msgs.msg import LoopCorrection, MapUpdate  # noqa: E402
from changing_slam_ros.core.replication.map_replication import KeyframePacket, diff, snapshot  # noqa: E402
from changing_slam_ros.core.replication.map_replication import MapUpdate as MapUpdateData  # noqa: E402
from changing_slam_ros.nodes.local_mapping_node import LocalMappingNode  # noqa: E402
from changing_slam_ros.nodes.loop_closing_node import LoopClosingNode  # noqa: E402
from changing_slam_ros.nodes.replication_conversions import (  # noqa: E402
    packet_from_msg,
    packet_to_msg,
    update_from_msg,
    update_to_msg,
)
from helpers import REDKITCHEN, require, spin_until  # noqa: E402

Q = QoSProfile(depth=100)


@pytest.fixture(scope="module")
def kitchen_packets():
    """Keyframe packets tracking made on 7-Scenes redkitchen (first 45 frames, lossless order) and the map the
    owner built from them (ChainedGraph)."""
    from changing_slam_ros.io.dataset import open_dataset
    from changing_slam_ros.nodes.slam_backend import load_backend_config
    from changing_slam_ros.nodes.split_chains import ChainedGraph

    source = open_dataset(require(REDKITCHEN), "7scenes")
    chained = ChainedGraph.build(load_backend_config("7scenes"), loop=False, objects="off")
    packets: list[KeyframePacket] = []
    owner_call = chained.owner.on_keyframe

    def capture(packet: KeyframePacket) -> MapUpdateData:
        packets.append(copy.deepcopy(packet))
        return owner_call(packet)

    chained.owner.on_keyframe = capture  # type: ignore[method-assign]
    for i, rgbd in enumerate(source):
        if i >= 45:
            break
        chained.process(rgbd)
    return packets, chained.owner.atlas.current, chained.tracking


def test_packets_and_updates_round_trip_through_their_messages(kitchen_packets):
    packets, owner, _ = kitchen_packets
    p = packets[-1]
    back = packet_from_msg(packet_to_msg(p, "map"), "t")
    np.testing.assert_array_equal(back.keyframe.point_ids, p.keyframe.point_ids)
    np.testing.assert_array_equal(back.counters.n_visible, p.counters.n_visible)
    before = snapshot(owner)
    owner.points.positions[:5] += 0.0  # no change: an empty delta survives too
    u = MapUpdateData(7, diff(before, owner))
    again = update_from_msg(update_to_msg(u, 1, "map"), "t")
    assert again.keyframe_id == 7 and again.delta.empty


def _map_all(executor: SingleThreadedExecutor, probe: Node, node: LocalMappingNode,
             packets: list[KeyframePacket]) -> list[MapUpdate]:
    """Publish every keyframe packet on /tracking/keyframes at once from `probe`; the node's MapUpdates, asserted
    one per packet and in their order."""
    pub = probe.create_publisher(KeyframeMsg, "/tracking/keyframes", Q)
    updates: list[MapUpdate] = []
    probe.create_subscription(MapUpdate, "/local_mapping/map_updates", updates.append, Q)
    assert spin_until(executor, lambda: pub.get_subscription_count() > 0 and node.update_pub.get_subscription_count() > 0)
    for p in packets:
        pub.publish(packet_to_msg(p, "map"))
    assert spin_until(executor, lambda: len(updates) >= len(packets), 60.0)
    assert [u.keyframe_id for u in updates] == [p.keyframe.id for p in packets]
    return updates


def test_local_mapping_node_maps_real_keyframes_and_its_map_equals_the_owner(ros_context, kitchen_packets, tmp_path):
    packets, owner, _ = kitchen_packets
    assert len(packets) >= 4
    # All packets are published at once, so in real time every BA would give way to the next keyframe
    # (ba_yields_to_keyframes): off here, the node must equal the owner.
    node = LocalMappingNode(context=ros_context, parameter_overrides=[
        Parameter("config", value="7scenes"), Parameter("objects", value="off"),
        Parameter("diagnostics_period_s", value=0.2), Parameter("resync_timeout_s", value=0.0),
        Parameter("ba_yields_to_keyframes", value=False), Parameter("map_dir", value=str(tmp_path))])  # fmt: skip
    probe = Node("probe", context=ros_context)
    diags: list[DiagnosticArray] = []
    probe.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    executor.add_node(probe)
    updates = _map_all(executor, probe, node, packets)
    later = update_from_msg(updates[-1], "t")
    assert len(later.delta.points) > 0 and len(later.delta.keyframes) >= 2  # new points; BA moved neighbours
    assert len(updates[-1].keyframe_poses) == len(later.delta.keyframes)  # the summary fields are filled
    m = node.owner.atlas.current
    assert sorted(m.keyframes) == sorted(owner.keyframes)
    for k, kf in owner.keyframes.items():
        np.testing.assert_allclose(m.keyframes[k].T_world_cam, kf.T_world_cam, atol=1e-9, rtol=0)
    n = owner.points.size
    np.testing.assert_allclose(m.points.column_arrays()["positions"], owner.points.column_arrays()["positions"], atol=1e-9, rtol=0)
    def reported() -> dict[str, str]:
        ours = [s for d in diags for s in d.status if s.name == "local_mapping"]
        return {kv.key: kv.value for kv in ours[-1].values} if ours else {}

    assert spin_until(executor, lambda: reported().get("keyframes_mapped") == str(len(packets)), 5.0)
    assert float(reported()["keyframe_ms_median"]) > 0 and reported()["keyframes_rejected"] == "0"
    # ~/save_map writes the owned map in the map-file format; loaded back it is the owner's map.
    from changing_slam_msgs.srv import SaveMap
    from changing_slam_ros.io.map_file import load_map

    client = probe.create_client(SaveMap, "/local_mapping/save_map")
    assert spin_until(executor, client.service_is_ready, 10.0)
    refused = client.call_async(SaveMap.Request(path=""))  # no path and no map_out parameter
    assert spin_until(executor, refused.done, 10.0) and not refused.result().success
    future = client.call_async(SaveMap.Request(path=str(tmp_path / "saved" / "map.npz")))
    assert spin_until(executor, future.done, 30.0) and future.result().success, future.result().message
    loaded = load_map(tmp_path / "saved" / "map.npz").atlas.current
    assert sorted(loaded.keyframes) == sorted(owner.keyframes)
    np.testing.assert_array_equal(loaded.points.column_arrays()["positions"], m.points.column_arrays()["positions"])
    executor.shutdown()
    node.destroy_node()
    probe.destroy_node()


def test_keyframes_still_queued_at_shutdown_are_mapped_and_saved_when_publishing_fails(ros_context, kitchen_packets,
                                                                                        tmp_path):
    """SIGINT shuts the context down before `destroy_node` runs `finish`: the keyframes still queued are mapped, and
    their updates fail to publish ("publisher's context is invalid"). Seen in CI: local_mapping died there and
    never saved map.npz. Now each is mapped, the failure logged, and the map saved with every keyframe."""
    from rclpy._rclpy_pybind11 import RCLError

    from changing_slam_ros.io.map_file import load_map

    packets, owner, _ = kitchen_packets
    node = LocalMappingNode(context=ros_context, parameter_overrides=[
        Parameter("config", value="7scenes"), Parameter("objects", value="off"), Parameter("resync_timeout_s", value=0.0),
        Parameter("ba_yields_to_keyframes", value=False), Parameter("map_out", value=str(tmp_path / "map.npz"))])  # fmt: skip
    sent: list[int] = []

    def publish_after_shutdown(msg):  # noqa: ANN001, ANN202
        if len(sent) >= 2:
            raise RCLError("Failed to publish: publisher's context is invalid")
        sent.append(msg.keyframe_id)

    node.update_pub.publish = publish_after_shutdown
    node.queue.extend(copy.deepcopy(p) for p in packets)
    node.destroy_node()
    assert sent == [p.keyframe.id for p in packets[:2]]
    saved = load_map(tmp_path / "map.npz").atlas.current
    assert sorted(saved.keyframes) == sorted(owner.keyframes)
    for k, kf in owner.keyframes.items():
        np.testing.assert_allclose(saved.keyframes[k].T_world_cam, kf.T_world_cam, atol=1e-9, rtol=0)


def test_a_keyframe_received_again_is_dropped_not_mapped_twice(ros_context, kitchen_packets, tmp_path):
    """Tracking re-sends the keyframes it has no map update for after a resync; one that local_mapping had mapped
    (or still queues) arrived twice in a CI run of the lossless graph, was mapped again at shutdown and its points
    were added a second time (the saved map's keypoint -> point ids all offset by 796). A packet of a keyframe
    mapped or queued already is dropped and counted."""
    from changing_slam_ros.io.map_file import load_map

    packets, owner, _ = kitchen_packets
    node = LocalMappingNode(context=ros_context, parameter_overrides=[
        Parameter("config", value="7scenes"), Parameter("objects", value="off"), Parameter("resync_timeout_s", value=0.0),
        Parameter("ba_yields_to_keyframes", value=False), Parameter("map_out", value=str(tmp_path / "map.npz"))])  # fmt: skip
    node._enqueue(packet_to_msg(packets[0], "map"))
    node.map_keyframe(node.queue.popleft())  # mapped
    node._enqueue(packet_to_msg(packets[0], "map"))  # again, after it was mapped
    for p in packets[1:]:
        node._enqueue(packet_to_msg(p, "map"))
    node._enqueue(packet_to_msg(packets[1], "map"))  # again, while the first copy waits in the queue
    assert node.keyframes_duplicate == 2 and [q.keyframe.id for q in node.queue] == [p.keyframe.id for p in packets[1:]]
    node.destroy_node()  # maps the queue, saves the map
    saved = load_map(tmp_path / "map.npz").atlas.current
    assert sorted(saved.keyframes) == sorted(owner.keyframes) and saved.points.size == owner.points.size
    for k, kf in owner.keyframes.items():
        np.testing.assert_array_equal(saved.keyframes[k].point_ids, kf.point_ids)


def test_local_ba_gives_way_to_waiting_keyframes_in_real_time(ros_context, kitchen_packets):
    """Real time (ba_yields_to_keyframes, the default without wait_for_loop_results): keyframes flooding in
    while local BA runs end it early (taken off the subscription between solver iterations and mapped next, in
    order); every keyframe is still mapped and the map stays close to the owner's (BA cut short, not skipped
    throughout: the last keyframe, with nothing behind it, gets its full BA)."""
    packets, owner, _ = kitchen_packets
    node = LocalMappingNode(context=ros_context, parameter_overrides=[
        Parameter("config", value="7scenes"), Parameter("objects", value="off"),
        Parameter("resync_timeout_s", value=0.0)])  # fmt: skip
    assert node.owner.mapper.ba_stop is not None
    probe = Node("probe", context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    executor.add_node(probe)
    _map_all(executor, probe, node, packets)
    stats = node.stats()
    assert 1 <= stats["ba_stopped_early"] < len(packets) and stats["keyframes_mapped"] == len(packets)
    assert node._drain_timer.is_canceled()  # nothing queued: no 10 Hz wake-ups
    m = node.owner.atlas.current
    assert sorted(m.keyframes) == sorted(owner.keyframes)
    moved = max(np.linalg.norm(m.keyframes[k].T_world_cam[:3, 3] - kf.T_world_cam[:3, 3]) for k, kf in owner.keyframes.items())
    assert moved < 0.05, f"keyframes {moved * 100:.1f} cm from the owner's"
    executor.shutdown()
    node.destroy_node()
    probe.destroy_node()
    lossless = LocalMappingNode(context=ros_context, parameter_overrides=[
        Parameter("config", value="7scenes"), Parameter("objects", value="off"),
        Parameter("wait_for_loop_results", value=True)])  # fmt: skip
    assert lossless.owner.mapper.ba_stop is None  # the lossless graph repeats the offline work exactly
    lossless.destroy_node()


def test_loop_closing_node_closes_the_loop_of_a_drifting_room(ros_context):
    """Synthetic room with ground truth (test/core/slam/test_loop_closing.py): a drifting owner maps a turn and a
    quarter; fed its keyframe packets and map updates, the node answers every keyframe and closes the loop
    between the start and a turn later, with the correction's delta for the owner."""
    from core.replication.test_map_replication import drifting_room_steps

    from changing_slam_ros.core.map.slam_map import SlamMap

    node = LoopClosingNode(context=ros_context, parameter_overrides=[Parameter("config", value=""),
                                                                     Parameter("resync_timeout_s", value=0.0)])
    probe = Node("probe", context=ros_context)
    kf_pub = probe.create_publisher(KeyframeMsg, "/tracking/keyframes", Q)
    up_pub = probe.create_publisher(MapUpdate, "/local_mapping/map_updates", Q)
    answers: list[LoopCorrection] = []
    probe.create_subscription(LoopCorrection, "/loop_closing/loop_corrections", answers.append, Q)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    executor.add_node(probe)
    assert spin_until(executor, lambda: kf_pub.get_subscription_count() > 0 and up_pub.get_subscription_count() > 0
                      and node.correction_pub.get_subscription_count() > 0)  # fmt: skip
    m, n_kf, n_per_turn = SlamMap(0), 58, 48
    for k, _, step in drifting_room_steps(n_kf, n_per_turn):
        sent, update = step(m)
        kf_pub.publish(packet_to_msg(KeyframePacket(sent), "map"))
        up_pub.publish(update_to_msg(update, sent.stamp_ns, "map"))
        assert spin_until(executor, lambda k=k: len(answers) >= k + 1, 30.0)
    closed = [a for a in answers if a.closed]
    assert [a.query_keyframe_id for a in answers] == list(range(n_kf))
    assert closed, "no loop closed"
    first = closed[0]
    assert first.match_keyframe_id < 5 and first.query_keyframe_id >= n_per_turn - 3
    assert len(first.fused_point_pairs) // 2 > 100 and len(first.delta.kf_ids) > 40
    executor.shutdown()
    node.destroy_node()
    probe.destroy_node()


def test_a_restarted_local_mapping_node_gets_its_map_back_from_tracking(ros_context, kitchen_packets):
    """local_mapping dies and starts empty: it asks, tracking (here a probe with the split tracking side's
    replica) answers with its keyframes and the full map, and the node's map equals the owner's again."""
    from changing_slam_ros.nodes.map_resync import ResyncServer

    _, owner, tracking_side = kitchen_packets
    probe = Node("tracking", context=ros_context)
    server = ResyncServer(probe, tracking_side.snapshot, "map")
    node = LocalMappingNode(context=ros_context, parameter_overrides=[
        Parameter("config", value="7scenes"), Parameter("objects", value="off"),
        Parameter("resync_timeout_s", value=30.0)])  # fmt: skip
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    executor.add_node(probe)
    assert not node.resync.ready
    assert spin_until(executor, lambda: node.resync.ready, 30.0)
    assert server.answered >= 1 and node.resync.restored_keyframes == len(owner.keyframes)
    m = node.owner.atlas.current
    assert sorted(m.keyframes) == sorted(owner.keyframes) and m.points.size == owner.points.size
    for k, kf in owner.keyframes.items():
        np.testing.assert_allclose(m.keyframes[k].T_world_cam, kf.T_world_cam, atol=1e-9, rtol=0)
        np.testing.assert_array_equal(m.keyframes[k].point_ids, kf.point_ids)
        assert m.covisibility[k] == owner.covisibility[k]
    n = owner.points.size
    np.testing.assert_allclose(m.points.column_arrays()["positions"], owner.points.column_arrays()["positions"], atol=1e-9, rtol=0)
    np.testing.assert_array_equal(m.points.column_arrays()["bad"], owner.points.column_arrays()["bad"])
    executor.shutdown()
    node.destroy_node()
    probe.destroy_node()


def test_a_local_mapping_node_started_with_tracking_asks_for_no_map(ros_context):
    """`resync:=false` (the graph's first start): the node is ready at once and sends no snapshot request, so
    tracking never answers one with a keyframe local_mapping should map itself."""
    from std_msgs.msg import Header

    from changing_slam_ros.nodes.map_resync import REQUEST_TOPIC

    probe = Node("tracking", context=ros_context)
    requests: list[str] = []
    probe.create_subscription(Header, REQUEST_TOPIC, lambda m: requests.append(m.frame_id), 10)
    node = LocalMappingNode(context=ros_context, parameter_overrides=[
        Parameter("config", value="7scenes"), Parameter("objects", value="off"), Parameter("resync", value=False),
        Parameter("resync_timeout_s", value=30.0)])  # fmt: skip
    assert node.resync.ready
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    executor.add_node(probe)
    spin_until(executor, lambda: bool(requests), 2.5)  # the default asks at once and every second
    assert requests == [] and node.resync.restored_keyframes == 0
    executor.shutdown()
    node.destroy_node()
    probe.destroy_node()
