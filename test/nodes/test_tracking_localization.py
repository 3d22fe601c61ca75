"""The tracking node in localisation mode (nodes/tracking_mode.py), in-process on the bundled fr1 bag against the
map an offline run made of it: poses, no keyframes, the loaded map unchanged, objects reported present, and the
mode switched by ~/set_mode and by the parameter."""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.ros

pytest.importorskip("rclpy")
pytest.importorskip("changing_slam_msgs.msg", reason="interfaces not built (tools/build_interfaces.sh)")

from geometry_msgs.msg import PoseStamped  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import QoSProfile  # noqa: E402
from std_srvs.srv import SetBool  # noqa: E402

from changing_slam_msgs.msg import Keyframe as KeyframeMsg  # noqa: E402
from changing_slam_msgs.msg import MapObjectArray  # noqa: E402
from changing_slam_ros.cli import main as cli_main  # noqa: E402
from changing_slam_ros.core.slam.localization import Mode  # noqa: E402
from changing_slam_ros.io.map_file import load_map, map_arrays, npz_bytes  # noqa: E402
from changing_slam_ros.nodes.tracking_node import TrackingNode  # noqa: E402
from helpers import REPO, lossless_player, require, spin_until  # noqa: E402


def call(executor, client, request):  # noqa: ANN001, ANN201
    assert client.wait_for_service(timeout_sec=5.0)
    future = client.call_async(request)
    assert spin_until(executor, future.done, 10.0)
    return future.result()


def test_localisation_tracks_in_the_loaded_map_without_changing_it_and_reports_the_objects(ros_context, tmp_path):
    bag = require(REPO / "bags" / "tum_fr1_xyz_first10.mcap")
    assert cli_main(["run", str(bag), "--out", str(tmp_path / "map"), "--config", "tum_fr1", "--quiet",
                     "--no-plot"]) == 0  # fmt: skip
    map_file = tmp_path / "map" / "map.npz"
    tracking = TrackingNode(context=ros_context, parameter_overrides=[
        Parameter("config", value="tum_fr1"), Parameter("ack_topic", value="/bag_player/ack"),
        Parameter("in_process_backend", value=True), Parameter("map_file", value=str(map_file)),
        Parameter("mode", value="localization"),
    ])  # fmt: skip
    player = lossless_player(ros_context, bag)
    probe = Node("probe", context=ros_context)
    poses: list[PoseStamped] = []
    keyframes: list[KeyframeMsg] = []
    seen: list[MapObjectArray] = []
    probe.create_subscription(PoseStamped, "/tracking/pose", poses.append, 100)
    probe.create_subscription(KeyframeMsg, "/tracking/keyframes", keyframes.append, QoSProfile(depth=100))
    probe.create_subscription(MapObjectArray, "/tracking/objects_seen", seen.append, 100)
    client = probe.create_client(SetBool, "/tracking/set_mode")
    executor = SingleThreadedExecutor(context=ros_context)
    for node in (tracking, probe, player):
        executor.add_node(node)
    assert spin_until(executor, lambda: tracking.mode_control.seen_pub.get_subscription_count() > 0)
    result = player.play(executor)
    assert result.completed and result.ack_timeouts == 0
    spin_until(executor, lambda: len(poses) >= 9 and len(seen) >= 1, 5.0)
    system = tracking.backend.system
    assert len(poses) == 9 and keyframes == [] and system.mode is Mode.LOCALIZATION
    n_kf = system.tracker.next_kf_id  # keyframes, points and graph as in the file
    assert npz_bytes(map_arrays(system.atlas, None, n_kf)) == npz_bytes(map_arrays(load_map(map_file).atlas, None, n_kf))
    # The mapping run's 6 objects (the chair seen cut by the image border only), present at their place from the
    # first frame on (one message: the set held).
    assert len(seen) == 1 and sorted(o.class_id for o in seen[0].objects) == [41, 56, 62, 63, 66, 73]
    assert tracking.diagnostic_values()["mode"] == "localization"
    # Back to mapping by the service, to localisation by the parameter.
    assert call(executor, client, SetBool.Request(data=False)).success and system.mode is Mode.MAPPING
    assert not system.tracker.localization
    assert tracking.set_parameters([Parameter("mode", value="localization")])[0].successful
    assert system.mode is Mode.LOCALIZATION and tracking.mode_control.switches == 2
    bad = tracking.set_parameters([Parameter("mode", value="slam")])[0]
    assert not bad.successful and "mode 'slam' unknown" in bad.reason
    executor.shutdown()
    for node in (tracking, probe, player):
        node.destroy_node()


def test_localisation_without_a_map_is_refused_by_the_service(ros_context):
    tracking = TrackingNode(context=ros_context, parameter_overrides=[
        Parameter("config", value="tum_fr1"), Parameter("in_process_backend", value=True),
    ])  # fmt: skip
    probe = Node("probe", context=ros_context)
    client = probe.create_client(SetBool, "/tracking/set_mode")
    executor = SingleThreadedExecutor(context=ros_context)
    for node in (tracking, probe):
        executor.add_node(node)
    answer = call(executor, client, SetBool.Request(data=True))
    assert not answer.success and "localization mode needs a map" in answer.message
    assert tracking.backend.system.mode is Mode.MAPPING
    executor.shutdown()
    tracking.destroy_node()
    probe.destroy_node()
