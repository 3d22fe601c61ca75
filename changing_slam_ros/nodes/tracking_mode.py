"""The tracking node's mapping / localisation switch (`ModeControl`): parameter `mode` (at start and with
`ros2 param set /tracking mode localization`) and service `~/set_mode` (std_srvs/SetBool: data true =
localization, false = mapping), both into `SlamSystem.set_mode` (`core/slam/localization.py`).

In localisation tracking makes no keyframes, so local_mapping and loop_closing (split backend) receive nothing
and the map they own stays as it is. `~/objects_seen` (MapObjectArray) lists the loaded map's objects present at
their mapped place, each time that set changes; the latched `~/semantic_map` is the loaded map's (beliefs are
not updated while localising).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.qos import QoSProfile
from std_srvs.srv import SetBool

from changing_slam_msgs.msg import MapObjectArray
from changing_slam_ros.core.objects.map_object import ObjectMapConfig
from changing_slam_ros.core.objects.semantic_map import build_semantic_map
from changing_slam_ros.core.slam.localization import Mode
from changing_slam_ros.errors import ConfigError
from changing_slam_ros.nodes.conversions import make_header


class ModeControl:
    """Holds the node's mode and applies it to the current system (`system()`: the backend may be replaced)."""

    def __init__(self, node: Node, mode: str, system: Callable[[], Any], objects_config: ObjectMapConfig | None,
                 map_frame: str, qos: QoSProfile | int = 10) -> None:  # fmt: skip
        self.node = node
        self.mode = Mode.parse(mode)
        self.system = system
        self.objects_config = objects_config or ObjectMapConfig()
        self.map_frame = map_frame
        self.seen_pub = node.create_publisher(MapObjectArray, "~/objects_seen", qos)
        self._last_seen: tuple[int, ...] | None = None
        self.switches = 0
        node.create_service(SetBool, "~/set_mode", self.on_set_mode)
        node.add_on_set_parameters_callback(self.on_parameters)

    def apply(self, mode: Mode) -> tuple[bool, str]:
        """Switch the system; (False, why) when it cannot (localisation without a map)."""
        system = self.system()
        if system is None:
            return False, "no SLAM backend (slam:=false)"
        try:
            system.set_mode(mode)
        except ConfigError as err:
            return False, str(err)
        if mode is not self.mode:
            self.switches += 1
            self.node.get_logger().info(f"tracking: mode {self.mode.value} -> {mode.value}")
        self.mode = mode
        self._last_seen = None
        return True, f"mode {mode.value}"

    def on_set_mode(self, request: SetBool.Request, response: SetBool.Response) -> SetBool.Response:
        response.success, response.message = self.apply(Mode.LOCALIZATION if request.data else Mode.MAPPING)
        return response

    def on_parameters(self, params: list[Any]) -> SetParametersResult:
        for p in params:
            if p.name != "mode":
                continue
            try:
                mode = Mode.parse(str(p.value))
            except ConfigError as err:
                return SetParametersResult(successful=False, reason=str(err))
            ok, why = self.apply(mode)
            if not ok:
                return SetParametersResult(successful=False, reason=why)
        return SetParametersResult(successful=True)

    def after_frame(self, stamp_ns: int, out: Any) -> None:
        """Localisation: publish the objects present at their place when that set changed."""
        if self.mode is not Mode.LOCALIZATION or out.T_world_cam is None:
            return
        seen = tuple(out.objects_seen)
        if seen == self._last_seen:
            return
        self._last_seen = seen
        system = self.system()
        present = [o for o in system.map_objects(system.atlas.current.id) if o.id in set(seen)]
        smap = build_semantic_map(present, self.objects_config, include_inactive=True, min_belief=0.0)
        self.seen_pub.publish(MapObjectArray(header=make_header(stamp_ns, self.map_frame),
                                             objects=_objects_msg(smap)))  # fmt: skip

    def diagnostic_values(self) -> dict[str, Any]:
        return {"mode": self.mode.value, "objects_present": -1 if self._last_seen is None else len(self._last_seen)}


def _objects_msg(smap: Any) -> list[Any]:
    from changing_slam_ros.nodes.object_map_node import semantic_object_to_msg

    return [semantic_object_to_msg(o) for o in smap.objects]
