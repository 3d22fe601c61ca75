"""Transforms from /tf and /tf_static for a node: tf2_ros's Buffer where tf2_ros is installed (a ROS 2 install),
else a buffer of our own (`core.geometry.transform_tree.TransformTree`, tf2's rules: one parent per frame,
interpolation between samples, no extrapolation), since tf2_ros has no PyPI wheel.

    tf = make_tf_lookup(node, cache_s=10.0)
    T_odom_base = tf.lookup("odom", "base_link", stamp_ns)   # raises TransformError / ExtrapolationError

Both raise the core's `TransformError` (`ExtrapolationError` with `future=True` when the stamp is newer than the
newest sample: waiting may help), so callers handle one set of errors whichever backs them.
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np
import numpy.typing as npt
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from tf2_msgs.msg import TFMessage

from changing_slam_ros.core.geometry.se3 import make_pose, quat_to_rot
from changing_slam_ros.core.geometry.transform_tree import ExtrapolationError, TransformError, TransformTree
from changing_slam_ros.nodes.conversions import stamp_to_ns

F64 = npt.NDArray[np.float64]

# /tf_static as tf2_ros's static broadcaster offers it: every transform ever sent reaches late subscribers.
TF_STATIC_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
TF_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)


class TfLookup(Protocol):
    kind: str  # "tf2_ros" or "own"

    def lookup(self, target: str, source: str, stamp_ns: int) -> F64: ...


def transform_to_matrix(tf: Any) -> F64:
    """geometry_msgs/Transform -> 4x4 (quaternion normalised)."""
    q = np.array([tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w], np.float64)
    if not np.isfinite(q).all() or np.linalg.norm(q) < 1e-9:
        raise ValueError(f"transform rotation {q.tolist()} is not a quaternion")
    return make_pose(quat_to_rot(q), np.array([tf.translation.x, tf.translation.y, tf.translation.z], np.float64))


class OwnTfBuffer:
    """/tf and /tf_static into a `TransformTree`; warns once per frame given a second parent (two publishers of
    the same frame's parent: the TF tree conflict REP-105 rules out)."""

    kind = "own"

    def __init__(self, node: Node, cache_s: float = 10.0) -> None:
        self.node = node
        self.tree = TransformTree(cache_s)
        self.n_received = 0
        self.n_rejected = 0
        self._warned_parents: set[str] = set()
        node.create_subscription(TFMessage, "/tf", lambda m: self.add(m, static=False), TF_QOS)
        node.create_subscription(TFMessage, "/tf_static", lambda m: self.add(m, static=True), TF_STATIC_QOS)

    def add(self, msg: TFMessage, static: bool) -> None:
        for t in msg.transforms:
            try:
                self.tree.set_transform(t.header.frame_id, t.child_frame_id, stamp_to_ns(t.header.stamp),
                                        transform_to_matrix(t.transform), static=static)  # fmt: skip
            except (TransformError, ValueError) as err:
                self.n_rejected += 1
                self.node.get_logger().warning(f"{self.node.get_name()}: transform rejected: {err}",
                                               throttle_duration_sec=5.0)  # fmt: skip
                continue
            self.n_received += 1
        for child, old, new in self.tree.parent_changes:
            if child not in self._warned_parents:
                self._warned_parents.add(child)
                self.node.get_logger().warning(
                    f"{self.node.get_name()}: frame {child} was given a second parent ({old}, then {new}): two "
                    f"nodes publish it; REP-105 allows one parent per frame (odom_source tf: the robot owns odom)")
        self.tree.parent_changes.clear()

    def lookup(self, target: str, source: str, stamp_ns: int) -> F64:
        return self.tree.lookup(target, source, stamp_ns)


class Tf2RosLookup:
    """tf2_ros.Buffer + TransformListener, with tf2's exceptions turned into the core's `TransformError`s."""

    kind = "tf2_ros"

    def __init__(self, node: Node, cache_s: float = 10.0) -> None:
        import tf2_ros
        from rclpy.duration import Duration

        self._tf2 = tf2_ros
        self.buffer = tf2_ros.Buffer(cache_time=Duration(seconds=cache_s))
        self.listener = tf2_ros.TransformListener(self.buffer, node, spin_thread=False)

    def lookup(self, target: str, source: str, stamp_ns: int) -> F64:
        from rclpy.time import Time

        try:
            t = self.buffer.lookup_transform(target, source, Time(nanoseconds=stamp_ns))
        except self._tf2.ExtrapolationException as err:  # tf2 does not say which side: wait while it may come
            raise ExtrapolationError(f"{target} <- {source}: {err}", future=True) from err
        except (self._tf2.LookupException, self._tf2.ConnectivityException) as err:
            raise TransformError(f"no transform between {target} and {source}: {err}") from err
        return transform_to_matrix(t.transform)


def make_tf_lookup(node: Node, cache_s: float = 10.0, use_tf2_ros: bool = True) -> TfLookup:
    """tf2_ros's buffer when importable (and `use_tf2_ros`), else `OwnTfBuffer`."""
    if use_tf2_ros:
        try:
            import tf2_ros  # noqa: F401
        except ImportError:
            pass
        else:
            return Tf2RosLookup(node, cache_s)
    return OwnTfBuffer(node, cache_s)
