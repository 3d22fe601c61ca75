"""`local_mapping`: keyframes (+ loop corrections, object states) -> map updates and object candidates.

SKELETON (issue 7): topics, parameters, QoS and the keyframe conversion are real; the call into the core
local-mapping component (`core.local_mapping.LocalMapper`, which owns the metric map as ORB-SLAM3's Atlas
does) is one TODO line in `on_keyframe`, so no map updates are published yet. It says so at start.
Until the core can replicate map updates between processes, this work runs inside the tracking node
(`in_process_backend`, nodes/slam_backend.py) and `changing-slam graph` does not start this node.

Inputs: /tracking/keyframes (reliable, deep queue: keyframes must not be lost), /loop_closing/loop_corrections,
  /object_map/object_states
Outputs: ~/map_updates (MapUpdate), ~/object_candidates (MapObjectArray), ~/map_cloud (PointCloud2, throttled)
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from rclpy.node import Node
from rclpy.qos import QoSProfile
from sensor_msgs.msg import PointCloud2

from changing_slam_msgs.msg import Keyframe as KeyframeMsg
from changing_slam_msgs.msg import LoopCorrection, MapObjectArray, MapUpdate, ObjectStateArray
from changing_slam_ros.errors import SlamError
from changing_slam_ros.nodes.conversions import keyframe_from_msg
from changing_slam_ros.nodes.node_runner import declare_parameters, run_node

KEYFRAME_QOS = QoSProfile(depth=100)  # reliable, volatile: every keyframe counts


class LocalMappingNode(Node):
    def __init__(self, keyframe_qos: QoSProfile = KEYFRAME_QOS, output_qos: QoSProfile | int = 10,
                 **node_kwargs: Any) -> None:  # fmt: skip
        super().__init__("local_mapping", **node_kwargs)
        self.params = declare_parameters(self, [
            ("config", "tum_fr1", "config name or YAML path (mapping, local BA, objects sections)"),
            ("map_frame", "map", "frame of the published map"),
            ("map_cloud_period_s", 1.0, "shortest time between two map_cloud messages"),
        ])  # fmt: skip
        self.keyframes_in = 0
        self.create_subscription(KeyframeMsg, "/tracking/keyframes", self.on_keyframe, keyframe_qos)
        self.create_subscription(LoopCorrection, "/loop_closing/loop_corrections", self.on_loop_correction, 10)
        self.create_subscription(ObjectStateArray, "/object_map/object_states", self.on_object_states, 10)
        self.update_pub = self.create_publisher(MapUpdate, "~/map_updates", keyframe_qos)
        self.candidate_pub = self.create_publisher(MapObjectArray, "~/object_candidates", output_qos)
        self.cloud_pub = self.create_publisher(PointCloud2, "~/map_cloud", output_qos)
        self.get_logger().info("local_mapping: started (SKELETON: core local mapping not wired, no map updates)")

    def on_keyframe(self, msg: KeyframeMsg) -> None:
        try:
            kf = keyframe_from_msg(msg, "/tracking/keyframes")
        except (SlamError, ValueError) as err:
            self.get_logger().warning(f"local_mapping: keyframe rejected: {err}", throttle_duration_sec=5.0)
            return
        self.keyframes_in += 1
        update = None  # TODO(issue 7): update = self.mapper.process(kf)  (core LocalMapper -> MapUpdate)
        if update is not None:
            self.update_pub.publish(update)
        self.get_logger().info(
            f"local_mapping: keyframe {kf.id} ({len(kf)} keypoints) received; not mapped (skeleton)",
            throttle_duration_sec=10.0,
        )

    def on_loop_correction(self, msg: LoopCorrection) -> None:
        pass  # TODO(issue 7): apply the corrected keyframe poses and points to the map.

    def on_object_states(self, msg: ObjectStateArray) -> None:
        pass  # TODO(issue 7): deactivate points of MapObjects below BeliefThreshold (Changing-SLAM §4.7).


def main(args: Sequence[str] | None = None) -> int:
    return run_node(lambda argv: LocalMappingNode(), args)


if __name__ == "__main__":
    raise SystemExit(main())
