"""The tracking node's `/initialpose` (geometry_msgs/PoseWithCovarianceStamped, as RViz's "2D Pose Estimate" and
Nav2 publish it): the base pose in the map frame becomes a relocalisation hint (`core/slam/initial_pose.py`).

The pose is the base's (`base_frame`; the camera's when it is empty) and is moved to the camera with the static
`base_frame -> camera_frame` transform. The hint's tolerance is 3 sigma of the message's covariance, at least
`initial_pose_radius_m` and `initial_pose_angle_deg`. A message in another frame than `map_frame`, with a zero
quaternion, or before a map is loaded is refused with a warning (the tracker goes on as it was).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt
from geometry_msgs.msg import PoseWithCovarianceStamped
from rclpy.node import Node

from changing_slam_ros.core.slam.initial_pose import PoseHint, hint_from_covariance
from changing_slam_ros.errors import ConfigError
from changing_slam_ros.nodes.conversions import pose_to_matrix

F64 = npt.NDArray[np.float64]


class InitialPoseInput:
    """Subscribes `/initialpose`; each valid message goes to `system().set_pose_hint`."""

    def __init__(self, node: Node, system: Callable[[], Any], base_cam: Callable[[], F64 | None], map_frame: str,
                 min_radius_m: float, min_angle_deg: float) -> None:  # fmt: skip
        if not (min_radius_m > 0 and 0 < min_angle_deg <= 180):
            raise ConfigError(f"tracking: initial_pose_radius_m must be > 0 and initial_pose_angle_deg in (0, 180], "
                              f"got {min_radius_m} and {min_angle_deg}")  # fmt: skip
        self.node = node
        self.system = system
        self.base_cam = base_cam
        self.map_frame = map_frame
        self.min_radius_m = float(min_radius_m)
        self.min_angle_rad = math.radians(min_angle_deg)
        self.received = 0
        self.applied = 0
        self.last_hint: PoseHint | None = None
        node.create_subscription(PoseWithCovarianceStamped, "/initialpose", self.on_initial_pose, 10)

    def on_initial_pose(self, msg: PoseWithCovarianceStamped) -> None:
        self.received += 1
        ok, why = self.apply(msg)
        if ok:
            self.node.get_logger().info(f"tracking: initial pose: {why}")
        else:
            self.node.get_logger().warning(f"tracking: initial pose ignored: {why}")

    def apply(self, msg: PoseWithCovarianceStamped) -> tuple[bool, str]:
        """Set the hint from `msg`; (False, why) when it cannot be used."""
        system = self.system()
        if system is None:
            return False, "no SLAM backend (slam:=false)"
        frame = msg.header.frame_id.lstrip("/")
        if frame and frame != self.map_frame:
            return False, f"it is in frame '{frame}'; give it in the map frame '{self.map_frame}'"
        try:
            T_map_base = pose_to_matrix(msg.pose.pose)  # noqa: N806
        except ValueError as err:
            return False, str(err)
        T_base_cam = self.base_cam()  # noqa: N806
        if T_base_cam is None:
            return False, "the base -> camera transform is not known yet (/tf_static)"
        try:
            hint = hint_from_covariance(T_map_base @ T_base_cam, np.asarray(msg.pose.covariance, dtype=np.float64),
                                        self.min_radius_m, self.min_angle_rad)  # fmt: skip
            system.set_pose_hint(hint)
        except ConfigError as err:
            return False, str(err)
        self.applied += 1
        self.last_hint = hint
        x, y, z = (round(float(v), 3) for v in hint.T_world_cam[:3, 3])
        return True, (f"relocalising within {hint.radius_m:.2f} m and {math.degrees(hint.angle_rad):.0f} deg of "
                      f"the camera at ({x}, {y}, {z}) m in {self.map_frame}")  # fmt: skip
