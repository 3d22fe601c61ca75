"""Read the semantic map from Python: which objects are in the room now, and where.

    python examples/semantic_map_listener.py            # while the graph (or ros2 launch) runs

Subscribes to `/object_map/semantic_map` (changing_slam_msgs/MapObjectArray, transient-local: the latest map
arrives at once, also when this node starts after the map was published) and asks `/object_map/query_objects`
for the chairs within 2 m of the map origin. Copy it as the start of your own node.
"""

from __future__ import annotations

from geometry_msgs.msg import Point
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from changing_slam_msgs.msg import MapObjectArray
from changing_slam_msgs.srv import QueryObjects

CHAIR = 56  # COCO class id, 0-based
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


class SemanticMapListener(Node):
    def __init__(self, **node_kwargs) -> None:  # noqa: ANN003
        super().__init__("semantic_map_listener", **node_kwargs)
        self.latest: MapObjectArray | None = None
        self.create_subscription(MapObjectArray, "/object_map/semantic_map", self.on_map, LATCHED)
        self.query = self.create_client(QueryObjects, "/object_map/query_objects")

    def on_map(self, msg: MapObjectArray) -> None:
        """Every object the map holds; `active` ones are believed to be where the map says (belief >= threshold)."""
        self.latest = msg
        for obj in msg.objects:
            if obj.active:
                c = obj.box_center
                self.get_logger().info(f"{obj.class_name} #{obj.id} at ({c.x:.2f}, {c.y:.2f}, {c.z:.2f}) m in "
                                       f"{msg.header.frame_id}, belief {obj.belief:.2f}")

    def chairs_near_origin(self):  # noqa: ANN201 - a Future of QueryObjects.Response
        """Ask object_map for the active chairs whose centre lies within 2 m of the map origin (a box query)."""
        request = QueryObjects.Request(class_ids=[CHAIR], use_region=True, region_min=Point(x=-2.0, y=-2.0, z=-2.0),
                                       region_max=Point(x=2.0, y=2.0, z=2.0))
        return self.query.call_async(request)


def main() -> None:
    import rclpy
    from rclpy.executors import ExternalShutdownException

    rclpy.init()
    node = SemanticMapListener()
    try:
        if node.query.wait_for_service(timeout_sec=5.0):
            future = node.chairs_near_origin()
            rclpy.spin_until_future_complete(node, future, timeout_sec=5.0)
            if future.done():
                node.get_logger().info(f"chairs within 2 m: {[o.id for o in future.result().objects]}")
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
