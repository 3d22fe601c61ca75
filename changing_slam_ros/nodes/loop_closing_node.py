"""`loop_closing`: keyframes (+ map updates, object states) -> loop corrections.

SKELETON (issue 7): topics, parameters, QoS, the keyframe conversion and the LoopCorrection message are
real; the call into the core component (`core.loop_closing.LoopCloser`: place recognition, geometric
verification, gtsam pose graph) is one TODO line in `on_keyframe`. It says so at start.
Until the core can replicate map updates between processes, this work runs inside the tracking node
(`in_process_backend`, nodes/slam_backend.py) and `changing-slam graph` does not start this node.

Inputs: /tracking/keyframes, /local_mapping/map_updates, /object_map/object_states
Output: ~/loop_corrections (LoopCorrection, reliable)
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from rclpy.node import Node
from rclpy.qos import QoSProfile

from changing_slam_msgs.msg import Keyframe as KeyframeMsg
from changing_slam_msgs.msg import MapUpdate, ObjectStateArray
from changing_slam_ros.errors import SlamError
from changing_slam_ros.nodes.conversions import keyframe_from_msg, loop_correction_to_msg
from changing_slam_ros.nodes.node_runner import declare_parameters, run_node
from changing_slam_msgs.msg import LoopCorrection as LoopCorrectionMsg

KEYFRAME_QOS = QoSProfile(depth=100)


class LoopClosingNode(Node):
    def __init__(self, keyframe_qos: QoSProfile = KEYFRAME_QOS, **node_kwargs: Any) -> None:
        super().__init__("loop_closing", **node_kwargs)
        self.params = declare_parameters(self, [
            ("config", "tum_fr1", "config name or YAML path (loop section: verification, pose graph)"),
            ("map_frame", "map", "frame of the corrected poses"),
        ])  # fmt: skip
        self.keyframes_in = 0
        self.create_subscription(KeyframeMsg, "/tracking/keyframes", self.on_keyframe, keyframe_qos)
        self.create_subscription(MapUpdate, "/local_mapping/map_updates", self.on_map_update, keyframe_qos)
        self.create_subscription(ObjectStateArray, "/object_map/object_states", self.on_object_states, 10)
        self.correction_pub = self.create_publisher(LoopCorrectionMsg, "~/loop_corrections", keyframe_qos)
        self.get_logger().info("loop_closing: started (SKELETON: core loop closing not wired, no loops closed)")

    def on_keyframe(self, msg: KeyframeMsg) -> None:
        try:
            kf = keyframe_from_msg(msg, "/tracking/keyframes")
        except (SlamError, ValueError) as err:
            self.get_logger().warning(f"loop_closing: keyframe rejected: {err}", throttle_duration_sec=5.0)
            return
        self.keyframes_in += 1
        correction = None  # TODO(issue 7): correction = self.loop_closer.process(kf, ...)  (core LoopCloser)
        if correction is not None:
            self.correction_pub.publish(loop_correction_to_msg(correction, kf.stamp_ns, self.params["map_frame"]))

    def on_map_update(self, msg: MapUpdate) -> None:
        pass  # TODO(issue 7): update keyframe poses in the keyframe database / pose graph.

    def on_object_states(self, msg: ObjectStateArray) -> None:
        pass  # TODO(issue 7): exclude inactive points' descriptors from place recognition.


def main(args: Sequence[str] | None = None) -> int:
    return run_node(lambda argv: LoopClosingNode(), args)


if __name__ == "__main__":
    raise SystemExit(main())
