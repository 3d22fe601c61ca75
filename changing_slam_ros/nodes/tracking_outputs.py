"""What the tracking node publishes per frame besides keyframe packets and TF (`nodes/tracking_tf.py`): pose,
odometry and path (`PoseOutputs`), the class-agnostic movers (`MoverOutputs`) and the debug image (`debug_image`).

Per-frame outputs that nobody reads cost CPU on every frame (the path message grows by one pose per frame), so
odometry, path and the debug image are built only while something subscribes; all are volatile, so no
late subscriber misses one. The pose itself always goes out (the graph's and the tests' main output).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry, Path as PathMsg
from rclpy.node import Node
from rclpy.qos import QoSProfile
from sensor_msgs.msg import Image
from std_msgs.msg import Header
from visualization_msgs.msg import MarkerArray

from changing_slam_msgs.msg import MovingObjectArray
from changing_slam_ros.core.features.rgbd_frame import RgbdFrame
from changing_slam_ros.errors import ConfigError
from changing_slam_ros.nodes.conversions import (
    make_header,
    matrix_to_pose,
    moving_object_markers,
    moving_objects_to_msg,
    rgb_to_image,
)

# RGB colours of the debug image per KeypointClass (static, movable, dynamic, unused).
CLASS_RGB = {0: (0, 220, 0), 1: (0, 120, 255), 2: (255, 0, 0), 3: (160, 160, 160)}


class PoseOutputs:
    """~/pose, ~/odometry (with covariance) and ~/path (the online poses so far), for the base frame when its
    mounting is known (else the camera). TF is `tracking_tf.Rep105Outputs`.

    `path_max_poses` > 0 bounds the path: it holds every `stride`-th pose (by count since the start) and the
    newest, and when that would be more than the bound the stride doubles. So the whole way travelled stays drawn
    at an even spacing, and a long run's path message (sent whole each frame to a subscriber) and memory stay
    bounded; 0 keeps every pose."""

    def __init__(self, node: Node, qos: QoSProfile | int, map_frame: str, child_frame: str,
                 path_max_poses: int = 0) -> None:  # fmt: skip
        if path_max_poses < 0 or path_max_poses == 1:
            raise ConfigError(f"tracking: path_max_poses must be 0 (every pose) or >= 2, got {path_max_poses}")
        self.path_max_poses = int(path_max_poses)
        self.map_frame, self.child_frame = map_frame, child_frame
        self.pose_pub = node.create_publisher(PoseStamped, "~/pose", qos)
        self.odom_pub = node.create_publisher(Odometry, "~/odometry", qos)
        self.path_pub = node.create_publisher(PathMsg, "~/path", qos)
        self.path = PathMsg(header=Header(frame_id=map_frame))
        self._path_index: list[int] = []  # each path pose's count since the start
        self._stride = 1
        self._count = 0  # poses so far

    def publish(self, stamp_ns: int, T_map_pose: Any, child_frame: str | None = None,  # noqa: N803
                covariance: Any = None) -> None:  # fmt: skip
        """One pose of `child_frame` (default: the one given at construction) in the map; `covariance` (6, 6)
        in ROS order (x, y, z, rotations), m^2 and rad^2, goes into the odometry message."""
        header = make_header(stamp_ns, self.map_frame)
        pose = PoseStamped(header=header, pose=matrix_to_pose(T_map_pose))
        self.pose_pub.publish(pose)
        if self.odom_pub.get_subscription_count() > 0:
            odom = Odometry(header=header, child_frame_id=child_frame or self.child_frame)
            odom.pose.pose = pose.pose
            if covariance is not None:
                odom.pose.covariance = np.asarray(covariance, np.float64).ravel()
            self.odom_pub.publish(odom)
        self.path.header.stamp = header.stamp
        self._add_to_path(pose)
        if self.path_pub.get_subscription_count() > 0:
            self.path_pub.publish(self.path)

    def replace_path(self, stamps_s: Any, poses: Any) -> None:
        """The path becomes these poses (after a loop closure: the optimised trajectory so far; [] after a load).
        With a bound, only the poses it keeps are built: those on the smallest stride it allows, and the newest."""
        stamps_s, poses = list(stamps_s), list(poses)
        n = len(poses)
        if len(stamps_s) != n:
            raise ValueError(f"replace_path: {len(stamps_s)} stamps for {n} poses")
        stride = 1
        while self.path_max_poses > 0 and _kept_count(n, stride) > self.path_max_poses:
            stride *= 2
        index = [i for i in range(n) if i % stride == 0 or i == n - 1]
        self.path.poses = [PoseStamped(header=make_header(round(stamps_s[i] * 1e9), self.map_frame),
                                       pose=matrix_to_pose(poses[i])) for i in index]  # fmt: skip
        self._path_index = index if self.path_max_poses > 0 else []
        self._stride, self._count = stride, n

    def _add_to_path(self, pose: PoseStamped) -> None:
        """Append `pose`; the previous newest goes unless it falls on the stride; the stride doubles past the bound."""
        index, self._count = self._count, self._count + 1
        if self.path_max_poses <= 0:
            self.path.poses.append(pose)
            return
        if self._path_index and self._path_index[-1] % self._stride:
            self.path.poses.pop()
            self._path_index.pop()
        self.path.poses.append(pose)
        self._path_index.append(index)
        while len(self.path.poses) > self.path_max_poses:
            self._stride *= 2
            keep = [k for k, i in enumerate(self._path_index) if i % self._stride == 0 or k == len(self._path_index) - 1]
            self.path.poses = [self.path.poses[k] for k in keep]
            self._path_index = [self._path_index[k] for k in keep]


def _kept_count(n: int, stride: int) -> int:
    """Poses a path of `n` keeps at `stride`: every stride-th from the first, and the newest."""
    return 0 if n == 0 else (n - 1) // stride + 1 + (1 if (n - 1) % stride else 0)


class MoverOutputs:
    """~/moving_objects (MovingObjectArray) and ~/moving_object_markers (MarkerArray), at most every `period_s`."""

    def __init__(self, node: Node, qos: QoSProfile | int, map_frame: str, period_s: float) -> None:
        self.map_frame, self.period_s = map_frame, period_s
        self.movers_pub = node.create_publisher(MovingObjectArray, "~/moving_objects", qos)
        self.markers_pub = node.create_publisher(MarkerArray, "~/moving_object_markers", qos)
        self.sent_s = -float("inf")
        self.published = 0

    def due(self) -> bool:
        return time.monotonic() - self.sent_s >= self.period_s

    def publish(self, movers: Any, stamp_ns: int) -> None:
        """Every mover tracked in at least the config's `min_track_frames` frames, with its trajectory so far
        (nothing is sent before there is one)."""
        objects = [o for o in movers.objects() if len(o.poses) >= movers.config.min_track_frames]
        if not objects:
            return
        self.sent_s = time.monotonic()
        tracks = [o.to_track() for o in objects]
        header = make_header(stamp_ns, self.map_frame)
        self.movers_pub.publish(moving_objects_to_msg(tracks, {o.object_id: o.points_obj for o in objects}, header))
        self.markers_pub.publish(moving_object_markers(tracks, header))
        self.published += 1


def debug_image(frame: RgbdFrame, last_frame: Any, dynamic: Any, detections: Any, frame_id: str) -> Image:
    """Colour image with the keypoints tracking used (`last_frame`'s, coloured by the dynamic stage's class when
    it kept exactly those, else green) and the detection boxes (red)."""
    import cv2

    img = np.ascontiguousarray(frame.rgb.copy())
    if dynamic is not None and last_frame is not None and len(last_frame.features) == int(dynamic.keep.sum()):
        classes = dynamic.kp_classes[dynamic.keep]
        for (u, v), c in zip(last_frame.features.keypoints_px, classes, strict=True):
            cv2.circle(img, (int(u), int(v)), 2, CLASS_RGB.get(int(c), (255, 255, 255)), -1)
    elif last_frame is not None:
        for u, v in last_frame.features.keypoints_px:
            cv2.circle(img, (int(u), int(v)), 2, CLASS_RGB[0], -1)
    for d in () if detections is None else detections.detections:
        x0, y0, x1, y1 = (int(round(v)) for v in d.box_xyxy)
        cv2.rectangle(img, (x0, y0), (x1, y1), (255, 0, 0), 1)
    return rgb_to_image(img, frame.stamp_ns, frame_id)
