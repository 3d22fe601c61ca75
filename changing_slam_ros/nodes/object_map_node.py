"""`object_map`: the semantic map (Changing-SLAM §4.8) on topics and services.

The object layer (`core.object_layer.ObjectLayer`: long-term association, persistence beliefs, inactive
points) runs where the metric map is written, because it reads and flags the map's points: in `local_mapping`
(split graph; `changing-slam graph` remaps this node's input to `/local_mapping/semantic_map`) or in tracking's
in-process backend (`/tracking/semantic_map`). This node holds the latest map that node publishes, serves it,
saves and loads it, and reports what changed (`ObjectMapNode`).

Inputs: /tracking/semantic_map (MapObjectArray; remap), /local_mapping/object_candidates (MapObjectArray)
Outputs: ~/object_states (ObjectStateArray: belief, active), ~/semantic_map, ~/markers, ~/changes, ~/change_markers
Services: ~/query_objects (QueryObjects), ~/save_map (SaveMap), ~/load_map (LoadMap), ~/reset (std_srvs/Trigger),
~/report_changes (std_srvs/Trigger: the change report's JSON in `message`)
"""

from __future__ import annotations

import colorsys
import json
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from geometry_msgs.msg import Point, Pose, Quaternion, Vector3
from rclpy.node import Node
from rclpy.qos import QoSProfile
from std_msgs.msg import ColorRGBA, Header, String
from std_srvs.srv import Trigger
from visualization_msgs.msg import Marker, MarkerArray

from changing_slam_msgs.msg import MapObject, MapObjectArray, ObjectState, ObjectStateArray
from changing_slam_msgs.srv import LoadMap, QueryObjects, SaveMap
from changing_slam_ros.core.objects.change_report import ChangeReport, compare_maps
from changing_slam_ros.core.objects.object_evidence import evidence_of_semantic
from changing_slam_ros.core.objects.semantic_map import SemanticMap, SemanticObject
from changing_slam_ros.errors import SlamError
from changing_slam_ros.nodes.change_markers import change_markers
from changing_slam_ros.nodes.node_help import NodeHelp, ParamSpec, first_line
from changing_slam_ros.nodes.node_runner import declare_parameters, run_node
from changing_slam_ros.nodes.qos_profiles import LATCHED



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


def semantic_object_to_msg(o: SemanticObject) -> MapObject:
    """core SemanticObject (map frame, metres) -> MapObject message."""
    c, b, s = o.centroid_w, o.box_center_w, o.box_size_m
    return MapObject(
        id=int(o.id), class_id=int(o.class_id), class_name=o.class_name,
        centroid=Point(x=float(c[0]), y=float(c[1]), z=float(c[2])),
        box_center=Point(x=float(b[0]), y=float(b[1]), z=float(b[2])),
        box_size=Vector3(x=float(s[0]), y=float(s[1]), z=float(s[2])), belief=float(o.belief), active=bool(o.active),
        first_seen_keyframe=int(o.first_seen_keyframe), last_seen_keyframe=int(o.last_seen_keyframe),
        n_points=int(o.n_points),
    )  # fmt: skip


def semantic_object_from_msg(m: Any) -> SemanticObject:
    return SemanticObject(
        int(m.id), int(m.class_id), str(m.class_name), (m.centroid.x, m.centroid.y, m.centroid.z),
        (m.box_center.x, m.box_center.y, m.box_center.z), (m.box_size.x, m.box_size.y, m.box_size.z),
        float(m.belief), bool(m.active), int(m.n_points), int(m.first_seen_keyframe), int(m.last_seen_keyframe),
    )  # fmt: skip


def semantic_map_to_msg(smap: SemanticMap, header: Header) -> MapObjectArray:
    return MapObjectArray(header=header, objects=[semantic_object_to_msg(o) for o in smap.objects])


def _config_belief_threshold(config: str) -> float:
    from changing_slam_ros.core.objects.object_layer import object_layer_config
    from changing_slam_ros.nodes.slam_backend import load_backend_config

    cfg = load_backend_config(config)
    return float(object_layer_config(cfg.data.get("objects"), f"{cfg.where}: objects").association.belief_threshold)


OBJECT_MAP_PARAMETERS: tuple[ParamSpec, ...] = (
    ("config", "tum_fr1", "config name or YAML path (objects section: thresholds of the paper)"),
    ("map_frame", "map", "frame of the semantic map"),
    ("belief_threshold", -1.0, "BeliefThreshold: objects below are inactive (Changing-SLAM §4.7); "
                               "< 0 = the config's objects section"),
    ("map_file", "", "semantic map loaded at start, saved after every update and on SaveMap without a "
                     "path; empty = none"),
    ("map_dir", "", "folder SaveMap / LoadMap request paths must lie in (names ending .json/.yaml/.yml; "
                    "an existing file is replaced only when it is a semantic map); empty = paths refused"),
    ("changes_from", "", "semantic map file the change report compares against; empty = the map loaded "
                         "from map_file at start, else the first map received"),
)  # fmt: skip


class ObjectMapNode(Node):
    """The semantic map's node (module doc). What changed: it keeps the map it started from (`changes_from`, else
    the map loaded from `map_file`, else the first map received) and after every update publishes the change
    report against it (`core.objects.change_report`): `~/changes` (std_msgs/String, the JSON document of
    `io.change_report_file`) and `~/change_markers` (MarkerArray, `nodes.change_markers`), both transient-local;
    `~/report_changes` answers with the same JSON.

    The map received (MapObjectArray, transient-local, every object with its belief and activity) is kept in
    `self.objects` (MapObject messages) and served as `~/semantic_map` (MapObjectArray) and `~/markers`
    (MarkerArray: a box per object coloured by class, alpha by belief, a text label), both transient-local so
    late subscribers get them; `~/object_states` (belief, active); QueryObjects by class and region; SaveMap /
    LoadMap as the project's semantic-map file (`io/semantic_map_file.py`, JSON or YAML, atomic); Reset clears
    it. With `map_file` set the map is loaded from it at start (so a restarted node comes back with its last
    map) and saved to it after every update.

    Open: candidates on `/local_mapping/object_candidates` are received but not associated here (the object
    layer associates them where it runs), and a loaded map is served, not fed back into the object layer.
    """

    def __init__(self, output_qos: QoSProfile | int = 10, **node_kwargs: Any) -> None:
        super().__init__("object_map", **node_kwargs)
        self.params = declare_parameters(self, OBJECT_MAP_PARAMETERS)
        if self.params["belief_threshold"] < 0:
            self.params["belief_threshold"] = _config_belief_threshold(self.params["config"])
        self.objects: dict[int, MapObject] = {}
        self.updates_in = 0
        self.create_subscription(MapObjectArray, "/tracking/semantic_map", self.on_semantic_map, LATCHED)
        self.create_subscription(MapObjectArray, "/local_mapping/object_candidates", self.on_candidates, 10)
        self.state_pub = self.create_publisher(ObjectStateArray, "~/object_states", output_qos)
        self.map_pub = self.create_publisher(MapObjectArray, "~/semantic_map", LATCHED)
        self.marker_pub = self.create_publisher(MarkerArray, "~/markers", LATCHED)
        self.changes_pub = self.create_publisher(String, "~/changes", LATCHED)
        self.change_marker_pub = self.create_publisher(MarkerArray, "~/change_markers", LATCHED)
        self.start_map: SemanticMap | None = None
        self.create_service(Trigger, "~/report_changes", self.on_report_changes)
        self.create_service(QueryObjects, "~/query_objects", self.on_query)
        self.create_service(SaveMap, "~/save_map", self.on_save)
        self.create_service(LoadMap, "~/load_map", self.on_load)
        self.create_service(Trigger, "~/reset", self.on_reset)
        start = ""
        map_file = self.params["map_file"]
        if map_file and Path(map_file).is_file():
            try:
                self.load(map_file)
                start = f", {len(self.objects)} objects loaded from {map_file}"
            except SlamError as err:
                self.get_logger().error(f"object_map: {err}; starting empty")
        if self.params["changes_from"]:
            from changing_slam_ros.io.semantic_map_file import read_semantic_map

            try:
                self.start_map = read_semantic_map(self.params["changes_from"])
            except SlamError as err:
                self.get_logger().error(f"object_map: changes_from: {err}; comparing with the first map instead")
        elif self.objects:
            self.start_map = self.semantic_map()
        self.get_logger().info(f"object_map: started (semantic map from /tracking/semantic_map{start})")

    # -- inputs ---------------------------------------------------------------------------------
    def on_semantic_map(self, msg: MapObjectArray) -> None:
        """The object layer's current map (from local_mapping, or tracking's in-process backend)."""
        self.objects = {int(o.id): o for o in msg.objects}
        self.updates_in += 1
        if self.start_map is None:
            self.start_map = self.semantic_map()
        self.publish_map(msg.header.stamp)
        self.publish_changes(msg.header.stamp)
        if self.params["map_file"]:
            try:
                self.save(self.params["map_file"])
            except (SlamError, OSError) as err:
                self.get_logger().warning(f"object_map: autosave failed: {err}", throttle_duration_sec=10.0)

    def on_candidates(self, msg: MapObjectArray) -> None:
        self.get_logger().info(
            f"object_map: {len(msg.objects)} candidates from a separate local_mapping received; not associated "
            "(the object layer associates them where it runs)", throttle_duration_sec=30.0,
        )  # fmt: skip

    # -- outputs --------------------------------------------------------------------------------
    def publish_map(self, stamp: Any = None) -> None:
        header = Header(frame_id=self.params["map_frame"])
        header.stamp = stamp if stamp is not None else self.get_clock().now().to_msg()
        objects = sorted(self.objects.values(), key=lambda o: o.id)
        self.map_pub.publish(MapObjectArray(header=header, objects=objects))
        self.marker_pub.publish(semantic_markers(objects, header))
        states = ObjectStateArray(header=header)
        for o in objects:
            states.objects.append(ObjectState(id=o.id, class_id=o.class_id, class_name=o.class_name, position=o.centroid,
                                              belief=o.belief, active=o.active))  # fmt: skip
        self.state_pub.publish(states)

    def change_report(self) -> ChangeReport:
        """The change report from the map the node started from to the current one (empty before either)."""
        start = self.start_map.objects if self.start_map is not None else ()
        return compare_maps([evidence_of_semantic(o) for o in start],
                            [evidence_of_semantic(o) for o in self.semantic_map().objects])

    @staticmethod
    def changes_json(report: ChangeReport) -> str:
        from changing_slam_ros.io.change_report_file import change_report_to_dict

        return json.dumps(change_report_to_dict(report, "start", "current"))

    def publish_changes(self, stamp: Any = None) -> None:
        header = Header(frame_id=self.params["map_frame"])
        header.stamp = stamp if stamp is not None else self.get_clock().now().to_msg()
        report = self.change_report()
        self.changes_pub.publish(String(data=self.changes_json(report)))
        self.change_marker_pub.publish(change_markers(report, header))

    def semantic_map(self) -> SemanticMap:
        objs = tuple(semantic_object_from_msg(o) for o in sorted(self.objects.values(), key=lambda o: o.id))
        return SemanticMap(objs, float(self.params["belief_threshold"]), self.params["map_frame"])

    def save(self, path: str) -> int:
        from changing_slam_ros.io.semantic_map_file import write_semantic_map

        write_semantic_map(path, self.semantic_map())
        return len(self.objects)

    def load(self, path: str) -> int:
        from changing_slam_ros.io.semantic_map_file import read_semantic_map

        smap = read_semantic_map(path)
        self.objects = {o.id: semantic_object_to_msg(o) for o in smap.objects}
        self.publish_map()
        return len(self.objects)

    # -- services -------------------------------------------------------------------------------
    def on_query(self, request: Any, response: Any) -> Any:
        response.objects = query_objects(self.objects.values(), request, self.params["belief_threshold"])
        return response

    def _request_path(self, name: str, for_write: bool) -> str:
        """A request's path: empty = the `map_file` parameter, else a name confined to `map_dir` (io.map_dir)."""
        if not name:
            if not self.params["map_file"]:
                raise SlamError("no path given and no map_file parameter")
            return str(self.params["map_file"])
        from changing_slam_ros.io.map_dir import MapDir, is_semantic_map

        where = MapDir(self.params["map_dir"], (".json", ".yaml", ".yml"), is_semantic_map,
                       "SaveMap" if for_write else "LoadMap")  # fmt: skip
        return str(where.resolve(name, for_write))

    def on_save(self, request: Any, response: Any) -> Any:
        try:
            path = self._request_path(request.path, for_write=True)
            n = self.save(path)
            response.success, response.message = True, f"object_map: saved {n} objects to {path}"
        except (SlamError, OSError) as err:
            response.success, response.message = False, f"object_map: {err}"
            self.get_logger().warning(response.message)
        return response

    def on_load(self, request: Any, response: Any) -> Any:
        try:
            path = self._request_path(request.path, for_write=False)
            n = self.load(path)
            response.success, response.message = True, f"object_map: loaded {n} objects from {path}"
        except (SlamError, OSError) as err:
            response.success, response.message = False, f"object_map: {err}"
            self.get_logger().warning(response.message)
        return response

    def on_report_changes(self, request: Any, response: Any) -> Any:
        response.success, response.message = True, self.changes_json(self.change_report())
        return response

    def on_reset(self, request: Any, response: Any) -> Any:
        n = len(self.objects)
        self.objects.clear()
        self.publish_map()
        response.success = True
        response.message = f"object_map: cleared {n} objects"
        return response


NODE_HELP = NodeHelp("object_map", first_line(__doc__), OBJECT_MAP_PARAMETERS)


def main(args: Sequence[str] | None = None) -> int:
    return run_node(lambda argv: ObjectMapNode(), args, node_help=NODE_HELP)


if __name__ == "__main__":
    raise SystemExit(main())
