"""Frames published as an RGB-D camera driver publishes them, for feeding the live graph without a bag.

A driver stamps each frame with the wall clock as it goes out, publishes colour (rgb8), depth (16UC1 millimetres)
and camera_info with sensor-data QoS (best effort, keep last 5), at its own rate whether anyone keeps up or not.
`CameraFeed` does that on a node of the caller's: `ready()` says whether a subscriber has matched each topic
(`tracking` subscribed), `play()` sends frames at a rate, spinning the caller's executor between them so its
subscriptions (poses, TF) are served.
"""

from __future__ import annotations

import time
from collections.abc import Iterable

import numpy as np
import numpy.typing as npt
from rclpy.executors import Executor
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.io.dataset_config import TopicSet
from changing_slam_ros.nodes.conversions import depth_to_image, intrinsics_to_camera_info, rgb_to_image

FRAME_ID = "camera_color_optical_frame"  # realsense2_camera's colour optical frame


class CameraFeed:
    """Publishers of one camera's colour, depth and camera_info topics (`topics`) on `node`."""

    def __init__(self, node: Node, topics: TopicSet, camera: CameraIntrinsics, frame_id: str = FRAME_ID) -> None:
        self.camera = camera
        self.frame_id = frame_id
        self.rgb = node.create_publisher(Image, topics.rgb, qos_profile_sensor_data)
        self.depth = node.create_publisher(Image, topics.depth, qos_profile_sensor_data)
        self.info = node.create_publisher(CameraInfo, topics.camera_info, qos_profile_sensor_data)

    def ready(self) -> bool:
        """True once every topic has a subscriber."""
        return all(p.get_subscription_count() > 0 for p in (self.rgb, self.depth, self.info))

    def publish(self, rgb: npt.NDArray[np.uint8], depth_m: npt.NDArray[np.float32]) -> int:
        """One frame, stamped now (wall clock); returns the stamp in nanoseconds."""
        stamp = time.time_ns()
        self.info.publish(intrinsics_to_camera_info(self.camera, stamp, self.frame_id))
        self.rgb.publish(rgb_to_image(rgb, stamp, self.frame_id))
        self.depth.publish(depth_to_image(depth_m, stamp, self.frame_id, encoding="16UC1"))
        return stamp

    def play(self, executor: Executor, frames: Iterable[tuple[npt.NDArray[np.uint8], npt.NDArray[np.float32]]],
             rate_hz: float) -> tuple[list[int], float]:
        """Publish (colour, depth in metres) frames every 1 / `rate_hz` s, spinning `executor` while waiting;
        returns the stamps sent and the seconds it took."""
        period_ns = round(1e9 / rate_hz)
        sent: list[int] = []
        t_next = t_start = time.monotonic_ns()
        for rgb, depth_m in frames:
            while time.monotonic_ns() < t_next:
                executor.spin_once(timeout_sec=max(0.0, (t_next - time.monotonic_ns()) * 1e-9))
            t_next += period_ns
            sent.append(self.publish(rgb, depth_m))
        return sent, (time.monotonic_ns() - t_start) * 1e-9
