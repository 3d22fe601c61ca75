"""object_map in-process: mirrors the semantic map tracking publishes, saves / loads it, comes back with it."""

from __future__ import annotations

import json

import pytest

pytestmark = pytest.mark.ros

pytest.importorskip("rclpy")
pytest.importorskip("changing_slam_msgs.msg", reason="interfaces not built (tools/build_interfaces.sh)")

from geometry_msgs.msg import Point, Vector3  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from std_msgs.msg import Header  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from changing_slam_msgs.msg import MapObject, MapObjectArray, ObjectStateArray  # noqa: E402
from changing_slam_msgs.srv import LoadMap, QueryObjects, SaveMap  # noqa: E402
from changing_slam_ros.nodes.object_map_node import ObjectMapNode  # noqa: E402
from changing_slam_ros.nodes.qos_profiles import LATCHED  # noqa: E402
from helpers import spin_until  # noqa: E402


def _obj(i: int, class_id: int, name: str, x: float, belief: float) -> MapObject:
    return MapObject(id=i, class_id=class_id, class_name=name, centroid=Point(x=x, y=0.5, z=1.0),
                     box_center=Point(x=x, y=0.5, z=1.0), box_size=Vector3(x=0.4, y=0.6, z=0.8), belief=belief,
                     active=belief >= 0.6, first_seen_keyframe=2, last_seen_keyframe=9, n_points=35)  # fmt: skip


def test_object_map_mirrors_tracking_saves_loads_and_restarts_from_its_map_file(ros_context, tmp_path):
    map_file = tmp_path / "objects.json"
    node = ObjectMapNode(context=ros_context, parameter_overrides=[Parameter("map_file", value=str(map_file)),
                                                                   Parameter("map_dir", value=str(tmp_path))])
    assert node.params["belief_threshold"] == 0.6  # tum_fr1 config's objects section
    probe = Node("probe", context=ros_context)
    tracking_map = probe.create_publisher(MapObjectArray, "/tracking/semantic_map", LATCHED)
    states: list[ObjectStateArray] = []
    probe.create_subscription(ObjectStateArray, "/object_map/object_states", states.append, 10)
    clients = {name: probe.create_client(kind, f"/object_map/{name}")
               for name, kind in (("query_objects", QueryObjects), ("save_map", SaveMap), ("load_map", LoadMap),
                                  ("reset", Trigger))}  # fmt: skip
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    executor.add_node(probe)

    def call(name, request):  # noqa: ANN001, ANN202
        assert spin_until(executor, clients[name].service_is_ready)
        future = clients[name].call_async(request)
        assert spin_until(executor, future.done)
        return future.result()

    tracking_map.publish(MapObjectArray(header=Header(frame_id="map"), objects=[
        _obj(4, 56, "chair", 1.0, 0.9), _obj(7, 41, "cup", 2.0, 0.3)]))  # fmt: skip
    assert spin_until(executor, lambda: node.updates_in == 1 and states)
    assert [(o.id, o.active) for o in states[-1].objects] == [(4, True), (7, False)]
    # Saved after the update (the restart file), in the project's semantic-map format.
    doc = json.loads(map_file.read_text())
    assert [(o["id"], o["class_name"], o["belief"]) for o in doc["objects"]] == [(4, "chair", pytest.approx(0.9)), (7, "cup", pytest.approx(0.3))]
    assert [o.id for o in call("query_objects", QueryObjects.Request()).objects] == [4]  # cup below 0.6
    other = tmp_path / "saved.yaml"
    assert call("save_map", SaveMap.Request(path=str(other))).success and other.is_file()
    assert call("reset", Trigger.Request()).success and node.objects == {}
    loaded = call("load_map", LoadMap.Request(path=str(other)))
    assert loaded.success and "2 objects" in loaded.message
    got = call("query_objects", QueryObjects.Request(include_inactive=True)).objects
    assert [(o.id, o.class_id, round(o.box_size.z, 3), o.first_seen_keyframe) for o in got] == [(4, 56, 0.8, 2), (7, 41, 0.8, 2)]
    bad = call("load_map", LoadMap.Request(path=str(tmp_path / "missing.json")))
    assert not bad.success and "missing.json" in bad.message  # the error names the file
    executor.shutdown()
    node.destroy_node()

    # A restarted node (the graph runner restarts one that died) starts from its map file.
    again = ObjectMapNode(context=ros_context, parameter_overrides=[Parameter("map_file", value=str(map_file))])
    assert sorted(again.objects) == [4, 7] and again.objects[4].class_name == "chair"
    again.destroy_node()
    probe.destroy_node()


def test_object_map_reports_what_changed_since_the_map_it_started_from(ros_context, tmp_path):
    from std_msgs.msg import String
    from visualization_msgs.msg import Marker, MarkerArray

    from changing_slam_ros.core.objects.semantic_map import SemanticMap
    from changing_slam_ros.io.semantic_map_file import write_semantic_map
    from changing_slam_ros.nodes.object_map_node import semantic_object_from_msg

    start = tmp_path / "start.json"  # the earlier session: a chair at x = 1, a cup at x = 2
    write_semantic_map(start, SemanticMap(tuple(semantic_object_from_msg(o) for o in (
        _obj(4, 56, "chair", 1.0, 0.9), _obj(7, 41, "cup", 2.0, 0.7))), 0.6))
    node = ObjectMapNode(context=ros_context, parameter_overrides=[Parameter("map_file", value=str(start))])
    assert node.start_map is not None and len(node.start_map.objects) == 2
    probe = Node("probe_changes", context=ros_context)
    tracking_map = probe.create_publisher(MapObjectArray, "/tracking/semantic_map", LATCHED)
    got: list[String] = []
    markers: list[MarkerArray] = []
    probe.create_subscription(String, "/object_map/changes", got.append, LATCHED)
    probe.create_subscription(MarkerArray, "/object_map/change_markers", markers.append, LATCHED)
    client = probe.create_client(Trigger, "/object_map/report_changes")
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    executor.add_node(probe)
    # now: the chair missed at x = 1 (belief 0.2) and seen at x = 3.5 (a new object), the cup gone, a new tv
    tracking_map.publish(MapObjectArray(header=Header(frame_id="map"), objects=[
        _obj(4, 56, "chair", 1.0, 0.2), _obj(7, 41, "cup", 2.0, 0.2), _obj(9, 56, "chair", 3.5, 0.5),
        _obj(10, 62, "tv", -2.0, 0.5)]))  # fmt: skip
    assert spin_until(executor, lambda: node.updates_in == 1 and got and markers)
    doc = json.loads(got[-1].data)
    assert doc["counts"] == {"moved": 1, "removed": 1, "added": 1, "replaced": 0, "unchanged": 0}
    moved = next(c for c in doc["changes"] if c["kind"] == "moved")
    assert (moved["before"]["id"], moved["after"]["id"], moved["distance_m"]) == (4, 9, pytest.approx(2.5))
    arrows = [m for m in markers[-1].markers if m.type == Marker.ARROW and m.action == Marker.ADD]
    assert len(arrows) == 1 and (arrows[0].points[0].x, arrows[0].points[1].x) == (1.0, 3.5)
    assert spin_until(executor, client.service_is_ready)
    future = client.call_async(Trigger.Request())
    assert spin_until(executor, future.done)
    assert json.loads(future.result().message)["counts"] == doc["counts"]
    executor.shutdown()
    node.destroy_node()
    probe.destroy_node()
