"""`tracking`: colour + depth + camera_info (+ detections, map updates, object states) -> camera pose.

SKELETON (issue 7): the topics, parameters, QoS, colour/depth pairing, frame conversion and the outputs'
message plumbing are real; the call into the core tracking component is one TODO line in `on_frame`, so
this node publishes no pose yet. It logs that once, loudly.

Inputs (defaults are the TUM bag names; remap with --ros-args -r):
  /camera/rgb/image_color (Image, sensor-data QoS), /camera/depth/image (Image 32FC1 m or 16UC1 mm), or with
  `compressed:=true` their /compressed CompressedImage topics (JPEG/PNG colour, PNG or compressedDepth depth),
  /camera/rgb/camera_info, /detection/detections, /local_mapping/map_updates,
  /loop_closing/loop_corrections, /object_map/object_states
Outputs: ~/pose (PoseStamped), ~/odometry, ~/path, ~/keyframes, ~/object_states (EKF), TF map->odom->camera,
  and, when `ack_topic` is set, a std_msgs/Header per processed frame for bag_player's lossless mode.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from geometry_msgs.msg import PoseStamped, TransformStamped
from nav_msgs.msg import Odometry, Path
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import QoSProfile, qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from std_msgs.msg import Header
from tf2_msgs.msg import TFMessage

from changing_slam_msgs.msg import DetectionArray, LoopCorrection, MapUpdate, ObjectStateArray
from changing_slam_msgs.msg import Keyframe as KeyframeMsg
from changing_slam_ros.core.camera import CameraIntrinsics
from changing_slam_ros.core.rgbd_frame import RgbdFrame
from changing_slam_ros.errors import SlamError
from changing_slam_ros.nodes.conversions import (
    camera_info_to_intrinsics,
    detections_from_msg,
    image_to_depth_m,
    image_to_rgb,
    make_header,
    matrix_to_pose,
    matrix_to_transform,
    stamp_to_ns,
)
from changing_slam_ros.nodes.node_runner import declare_parameters, run_node
from changing_slam_ros.nodes.stamp_sync import ApproximatePairer


class TrackingNode(Node):
    def __init__(
        self,
        image_qos: QoSProfile = qos_profile_sensor_data,
        output_qos: QoSProfile | int = 10,
        **node_kwargs: Any,
    ) -> None:
        super().__init__("tracking", **node_kwargs)
        self.params = p = declare_parameters(self, [
            ("config", "tum_fr1", "config name or YAML path (camera, tracking, dynamic sections)"),
            ("sync_slop_s", 0.02, "largest colour/depth stamp difference paired (TUM associate.py: 0.02)"),
            ("intrinsics_from", "camera_info", "'camera_info' topic or 'config' (TUM bags carry ROS defaults)"),
            ("map_frame", "map", "REP-105 map frame"),
            ("odom_frame", "odom", "REP-105 odom frame"),
            ("camera_frame", "camera", "camera optical frame of the published pose"),
            ("publish_tf", True, "publish map->odom->camera on /tf"),
            ("ack_topic", "", "std_msgs/Header per processed frame (bag_player lossless); empty = off"),
            ("stats_period_s", 10.0, "seconds between log lines with frame and drop counts"),
            ("compressed", False, "subscribe CompressedImage on <colour>/compressed and <depth>/compressed"),
        ])  # fmt: skip
        slop_ns = round(p["sync_slop_s"] * 1e9)
        self.pairer: ApproximatePairer[Any, Any] = ApproximatePairer(slop_ns)
        self.camera: CameraIntrinsics | None = None
        self.detections: dict[int, Any] = {}
        self.frames_in = 0
        self._warned: set[str] = set()

        # camera_info first: when it and an image are ready in the same spin, the executor serves it first.
        self.create_subscription(CameraInfo, "/camera/rgb/camera_info", self.on_camera_info, image_qos)
        if p["compressed"]:
            self.colour_topic, self.depth_topic = "/camera/rgb/image_color/compressed", "/camera/depth/image/compressed"
            image_type: Any = CompressedImage
        else:
            self.colour_topic, self.depth_topic = "/camera/rgb/image_color", "/camera/depth/image"
            image_type = Image
        self.create_subscription(image_type, self.colour_topic, self.on_colour, image_qos)
        self.create_subscription(image_type, self.depth_topic, self.on_depth, image_qos)
        self.create_subscription(DetectionArray, "/detection/detections", self.on_detections, 10)
        self.create_subscription(MapUpdate, "/local_mapping/map_updates", self.on_map_update, 10)
        self.create_subscription(LoopCorrection, "/loop_closing/loop_corrections", self.on_loop_correction, 10)
        self.create_subscription(ObjectStateArray, "/object_map/object_states", self.on_object_states, 10)

        self.pose_pub = self.create_publisher(PoseStamped, "~/pose", output_qos)
        self.odom_pub = self.create_publisher(Odometry, "~/odometry", output_qos)
        self.path_pub = self.create_publisher(Path, "~/path", output_qos)
        self.keyframe_pub = self.create_publisher(KeyframeMsg, "~/keyframes", QoSProfile(depth=100))
        self.object_pub = self.create_publisher(ObjectStateArray, "~/object_states", output_qos)
        self.tf_pub = self.create_publisher(TFMessage, "/tf", 100) if p["publish_tf"] else None
        self.ack_pub = self.create_publisher(Header, p["ack_topic"], 100) if p["ack_topic"] else None
        self.path = Path(header=Header(frame_id=p["map_frame"]))
        # Steady clock: the stats line keeps coming when use_sim_time is on and the bag is paused.
        self.create_timer(p["stats_period_s"], self._log_stats, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.get_logger().info("tracking: started (SKELETON: core tracking not wired yet, no poses published)")

    # -- inputs ---------------------------------------------------------------------------------
    def on_colour(self, msg: Any) -> None:
        for t_rgb, rgb_msg, _t_d, depth_msg in self.pairer.add_first(stamp_to_ns(msg.header.stamp), msg):
            self.on_frame(t_rgb, rgb_msg, depth_msg)
        self._warn_if_unpaired()

    def on_depth(self, msg: Any) -> None:
        for t_rgb, rgb_msg, _t_d, depth_msg in self.pairer.add_second(stamp_to_ns(msg.header.stamp), msg):
            self.on_frame(t_rgb, rgb_msg, depth_msg)
        self._warn_if_unpaired()

    def on_camera_info(self, msg: CameraInfo) -> None:
        try:
            self.camera = camera_info_to_intrinsics(msg, "/camera/rgb/camera_info")
        except SlamError as err:
            self.get_logger().warning(f"tracking: camera_info rejected: {err}", throttle_duration_sec=5.0)

    def on_detections(self, msg: DetectionArray) -> None:
        ds = detections_from_msg(msg)
        self.detections[ds.stamp_ns] = ds
        while len(self.detections) > 30:
            del self.detections[next(iter(self.detections))]

    def on_map_update(self, msg: MapUpdate) -> None:
        pass  # TODO(issue 7): apply to the tracker's local map replica (core tracking component).

    def on_loop_correction(self, msg: LoopCorrection) -> None:
        pass  # TODO(issue 7): correct the current pose and the local map replica.

    def on_object_states(self, msg: ObjectStateArray) -> None:
        pass  # TODO(issue 7): mark points of inactive MapObjects as not usable for tracking.

    # -- one RGB-D frame ------------------------------------------------------------------------
    def on_frame(self, stamp_ns: int, rgb_msg: Any, depth_msg: Any) -> None:
        if self.camera is None:
            self._warn_once("no_camera", "tracking: no camera_info yet; frames are skipped until one arrives")
            self._ack(rgb_msg.header)
            return
        try:
            frame = RgbdFrame(
                stamp_ns=stamp_ns,
                rgb=image_to_rgb(rgb_msg, self.colour_topic),
                depth_m=image_to_depth_m(depth_msg, self.depth_topic),
                camera=self.camera,
                index=self.frames_in,
            )
        except (SlamError, ValueError) as err:
            self.get_logger().warning(f"tracking: frame rejected: {err}", throttle_duration_sec=5.0)
            self._ack(rgb_msg.header)
            return
        self.frames_in += 1
        detections = self.detections.get(stamp_ns)
        result = None  # TODO(issue 7): result = self.tracker.track(frame, detections)  (core tracking component)
        self._warn_once("skeleton", "tracking: frames arrive and pair, but no core tracker is wired (skeleton)")
        if result is not None:
            self.publish_pose(stamp_ns, result.T_world_cam)
        del frame, detections
        self._ack(rgb_msg.header)

    # -- outputs --------------------------------------------------------------------------------
    def publish_pose(self, stamp_ns: int, T_world_cam: Any) -> None:  # noqa: N803
        """Pose, odometry, path and TF (odom = map until loop corrections separate them)."""
        p = self.params
        header = make_header(stamp_ns, p["map_frame"])
        pose = PoseStamped(header=header, pose=matrix_to_pose(T_world_cam))
        self.pose_pub.publish(pose)
        odom = Odometry(header=header, child_frame_id=p["camera_frame"])
        odom.pose.pose = pose.pose
        self.odom_pub.publish(odom)
        self.path.header.stamp = header.stamp
        self.path.poses.append(pose)
        self.path_pub.publish(self.path)
        if self.tf_pub is not None:
            import numpy as np

            map_odom = TransformStamped(header=header, child_frame_id=p["odom_frame"])
            map_odom.transform = matrix_to_transform(np.eye(4))
            odom_cam = TransformStamped(header=make_header(stamp_ns, p["odom_frame"]), child_frame_id=p["camera_frame"])
            odom_cam.transform = matrix_to_transform(T_world_cam)
            self.tf_pub.publish(TFMessage(transforms=[map_odom, odom_cam]))

    def _log_stats(self) -> None:
        s = self.pairer.stats
        if s.pairs or s.dropped_first or s.dropped_second:
            self.get_logger().info(
                f"tracking: {self.frames_in} frames, {s.pairs} colour/depth pairs, unpaired dropped: "
                f"{s.dropped_first} colour, {s.dropped_second} depth"
            )

    def _ack(self, header: Header) -> None:
        if self.ack_pub is not None:
            self.ack_pub.publish(Header(stamp=header.stamp, frame_id=self.get_name()))

    def _warn_if_unpaired(self) -> None:
        s = self.pairer.stats
        if s.dropped_first > 10 and s.pairs == 0:
            self._warn_once(
                "unpaired",
                f"tracking: colour and depth do not pair within {self.params['sync_slop_s']} s "
                f"({s.dropped_first} colour frames dropped); check the stamps or raise sync_slop_s",
            )

    def _warn_once(self, key: str, text: str) -> None:
        if key not in self._warned:
            self._warned.add(key)
            self.get_logger().warning(text)


def main(args: Sequence[str] | None = None) -> int:
    return run_node(lambda argv: TrackingNode(), args)


if __name__ == "__main__":
    raise SystemExit(main())
