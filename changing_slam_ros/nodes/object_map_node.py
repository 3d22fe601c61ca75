"""`object_map`: object candidates + keyframe poses -> object beliefs and the semantic map (Changing-SLAM §4.6-4.8).

SKELETON (issue 7) around a real message layer: the semantic map it holds (`self.objects`, MapObject messages)
is published as `~/semantic_map` (MapObjectArray) and `~/markers` (MarkerArray: a box per object coloured by
class, alpha by belief, a text label), both transient-local so late subscribers get them; the QueryObjects
service filters it by class and region; Reset clears it. What fills it, the core long-term association and
persistence filter, is one TODO line in `on_candidates`; SaveMap / LoadMap answer success=false until the
core map file exists. It says so at start.

Inputs: /local_mapping/object_candidates (MapObjectArray), /local_mapping/map_updates (keyframe poses)
Outputs: ~/object_states (ObjectStateArray: belief, active), ~/semantic_map, ~/markers
Services: ~/query_objects (QueryObjects), ~/save_map (SaveMap), ~/load_map (LoadMap), ~/reset (std_srvs/Trigger)
"""

from __future__ import annotations

import colorsys
from collections.abc import Iterable, Sequence
from typing import Any

from geometry_msgs.msg import Point, Pose, Quaternion, Vector3
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import ColorRGBA, Header
from std_srvs.srv import Trigger
from visualization_msgs.msg import Marker, MarkerArray

from changing_slam_msgs.msg import MapObject, MapObjectArray, MapUpdate, ObjectStateArray
from changing_slam_msgs.srv import LoadMap, QueryObjects, SaveMap
from changing_slam_ros.nodes.node_runner import declare_parameters, run_node

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def query_objects(objects: Iterable[Any], request: Any, belief_threshold: float) -> list[Any]:
    """Objects matching a QueryObjects request: class filter (empty = all), optional box region, activity."""
    wanted = set(request.class_ids)
    out = []
    for obj in objects:
        if wanted and obj.class_id not in wanted:
            continue
        if not request.include_inactive and (not obj.active or obj.belief < belief_threshold):
            continue
        if request.use_region:
            c, lo, hi = obj.centroid, request.region_min, request.region_max
            if not (lo.x <= c.x <= hi.x and lo.y <= c.y <= hi.y and lo.z <= c.z <= hi.z):
                continue
        out.append(obj)
    return out


def class_colour(class_id: int, alpha: float) -> ColorRGBA:
    """A stable colour per COCO class (golden-ratio hue walk), with the given alpha."""
    hue = (class_id * 0.618033988749895) % 1.0 if class_id >= 0 else 0.0
    r, g, b = colorsys.hsv_to_rgb(hue, 0.8 if class_id >= 0 else 0.0, 0.95)
    return ColorRGBA(r=r, g=g, b=b, a=float(alpha))


def semantic_markers(objects: Sequence[Any], header: Header, min_alpha: float = 0.15) -> MarkerArray:
    """MarkerArray for RViz/Foxglove: DELETEALL, then per object a CUBE (3D box) and a TEXT label."""
    out = MarkerArray(markers=[Marker(header=header, action=Marker.DELETEALL)])
    for obj in objects:
        alpha = max(min_alpha, min(1.0, float(obj.belief)))
        box = Marker(header=header, ns="objects", id=int(obj.id), type=Marker.CUBE, action=Marker.ADD)
        box.pose = Pose(position=obj.box_center, orientation=Quaternion(w=1.0))
        box.scale = Vector3(x=max(obj.box_size.x, 0.01), y=max(obj.box_size.y, 0.01), z=max(obj.box_size.z, 0.01))
        box.color = class_colour(int(obj.class_id), alpha)
        text = Marker(header=header, ns="labels", id=int(obj.id), type=Marker.TEXT_VIEW_FACING, action=Marker.ADD)
        c = obj.box_center
        text.pose = Pose(position=Point(x=c.x, y=c.y, z=c.z + 0.5 * obj.box_size.z + 0.1), orientation=Quaternion(w=1.0))
        text.scale = Vector3(z=0.12)
        text.color = ColorRGBA(r=1.0, g=1.0, b=1.0, a=1.0)
        text.text = f"{obj.class_name} #{obj.id} {obj.belief:.2f}"
        out.markers += [box, text]
    return out


class ObjectMapNode(Node):
    def __init__(self, output_qos: QoSProfile | int = 10, **node_kwargs: Any) -> None:
        super().__init__("object_map", **node_kwargs)
        self.params = declare_parameters(self, [
            ("config", "tum_fr1", "config name or YAML path (objects section: thresholds of the paper)"),
            ("map_frame", "map", "frame of the semantic map"),
            ("belief_threshold", 0.5, "BeliefThreshold: objects below are inactive (Changing-SLAM §4.7)"),
            ("map_file", "", "map loaded at start and saved on SaveMap without a path; empty = none"),
        ])  # fmt: skip
        self.objects: dict[int, MapObject] = {}
        self.create_subscription(MapObjectArray, "/local_mapping/object_candidates", self.on_candidates, 10)
        self.create_subscription(MapUpdate, "/local_mapping/map_updates", self.on_map_update, 10)
        self.state_pub = self.create_publisher(ObjectStateArray, "~/object_states", output_qos)
        self.map_pub = self.create_publisher(MapObjectArray, "~/semantic_map", LATCHED)
        self.marker_pub = self.create_publisher(MarkerArray, "~/markers", LATCHED)
        self.create_service(QueryObjects, "~/query_objects", self.on_query)
        self.create_service(SaveMap, "~/save_map", self.on_save)
        self.create_service(LoadMap, "~/load_map", self.on_load)
        self.create_service(Trigger, "~/reset", self.on_reset)
        self.get_logger().info("object_map: started (SKELETON: core object layer not wired; map stays empty)")

    # -- inputs ---------------------------------------------------------------------------------
    def on_candidates(self, msg: MapObjectArray) -> None:
        # TODO(issue 7): self.objects = self.object_layer.update(candidates, keyframe poses)  (core §4.6-4.7)
        self.get_logger().info(
            f"object_map: {len(msg.objects)} candidates received; not associated (skeleton)", throttle_duration_sec=10.0
        )

    def on_map_update(self, msg: MapUpdate) -> None:
        pass  # TODO(issue 7): keyframe poses for the visibility test of the persistence filter.

    # -- outputs --------------------------------------------------------------------------------
    def publish_map(self, stamp: Any = None) -> None:
        header = Header(frame_id=self.params["map_frame"])
        header.stamp = stamp if stamp is not None else self.get_clock().now().to_msg()
        objects = sorted(self.objects.values(), key=lambda o: o.id)
        self.map_pub.publish(MapObjectArray(header=header, objects=objects))
        self.marker_pub.publish(semantic_markers(objects, header))

    # -- services -------------------------------------------------------------------------------
    def on_query(self, request: Any, response: Any) -> Any:
        response.objects = query_objects(self.objects.values(), request, self.params["belief_threshold"])
        return response

    def on_save(self, request: Any, response: Any) -> Any:
        response.success = False
        response.message = "object_map: saving is not implemented yet (core map file, issue 6)"
        return response

    def on_load(self, request: Any, response: Any) -> Any:
        response.success = False
        response.message = "object_map: loading is not implemented yet (core map file, issue 6)"
        return response

    def on_reset(self, request: Any, response: Any) -> Any:
        n = len(self.objects)
        self.objects.clear()
        self.publish_map()
        response.success = True
        response.message = f"object_map: cleared {n} objects"
        return response


def main(args: Sequence[str] | None = None) -> int:
    return run_node(lambda argv: ObjectMapNode(), args)


if __name__ == "__main__":
    raise SystemExit(main())
