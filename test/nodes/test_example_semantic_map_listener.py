"""examples/semantic_map_listener.py against a live object_map node: it receives the map and its query answers."""

from __future__ import annotations

import importlib.util

import pytest

pytestmark = pytest.mark.ros

pytest.importorskip("rclpy")
pytest.importorskip("changing_slam_msgs.msg", reason="interfaces not built (tools/build_interfaces.sh)")

from geometry_msgs.msg import Point, Vector3  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from std_msgs.msg import Header  # noqa: E402

from changing_slam_msgs.msg import MapObject, MapObjectArray  # noqa: E402
from changing_slam_ros.nodes.object_map_node import ObjectMapNode  # noqa: E402
from changing_slam_ros.nodes.qos_profiles import LATCHED  # noqa: E402
from helpers import REPO, spin_until  # noqa: E402


def _listener_module():  # noqa: ANN202
    spec = importlib.util.spec_from_file_location("semantic_map_listener", REPO / "examples" / "semantic_map_listener.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _obj(i: int, class_id: int, name: str, x: float, belief: float) -> MapObject:
    return MapObject(id=i, class_id=class_id, class_name=name, centroid=Point(x=x, y=0.5, z=0.4),
                     box_center=Point(x=x, y=0.5, z=0.4), box_size=Vector3(x=0.5, y=0.5, z=0.9), belief=belief,
                     active=belief >= 0.6, first_seen_keyframe=1, last_seen_keyframe=5, n_points=40)  # fmt: skip


def test_the_example_listener_gets_the_map_and_the_chairs_near_the_origin(ros_context, tmp_path):
    node = ObjectMapNode(context=ros_context, parameter_overrides=[Parameter("map_file", value=str(tmp_path / "m.json"))])
    listener = _listener_module().SemanticMapListener(context=ros_context)
    probe = Node("probe", context=ros_context)
    tracking_map = probe.create_publisher(MapObjectArray, "/tracking/semantic_map", LATCHED)
    executor = SingleThreadedExecutor(context=ros_context)
    for n in (node, listener, probe):
        executor.add_node(n)
    tracking_map.publish(MapObjectArray(header=Header(frame_id="map"), objects=[
        _obj(1, 56, "chair", 1.0, 0.9), _obj(2, 56, "chair", 3.5, 0.9), _obj(3, 56, "chair", -0.5, 0.2),
        _obj(4, 62, "tv", 0.5, 0.9)]))  # fmt: skip
    assert spin_until(executor, lambda: listener.latest is not None and len(listener.latest.objects) == 4)
    assert spin_until(executor, listener.query.service_is_ready)
    future = listener.chairs_near_origin()
    assert spin_until(executor, future.done)
    # chair 2 is 3.5 m away, chair 3 is below the belief threshold, 4 is a tv
    assert [o.id for o in future.result().objects] == [1]
    executor.shutdown()
    for n in (listener, probe, node):
        n.destroy_node()
