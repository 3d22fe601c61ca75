"""The tracking node's REP-105 transforms (`Rep105Outputs`): map -> odom always, odom -> base_frame only when
the odometry is visual (`odom_source: visual`); with `odom_source: tf` the robot publishes odom -> base_frame
and map -> odom is computed against its odometry at each image's stamp. The frame math is in
`core/geometry/rep105.py`; this module looks transforms up, waits for late odometry and publishes.

Odometry for an image usually arrives after the image (the base publishes at its own rate): a frame whose
stamp is newer than the newest odom -> base_frame sample waits up to `tf_timeout_s` (checked every 10 ms on a
steady timer, without blocking the executor); after that it is dropped with a warning that says how far the
odometry lags, and the last map -> odom goes on being published. While tracking is lost the last map -> odom is
published at each frame's stamp, and no pose is published until tracking relocalises.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from geometry_msgs.msg import TransformStamped
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from tf2_msgs.msg import TFMessage

from changing_slam_ros.core.geometry.rep105 import OdomSource, Rep105State, base_motion, base_pose
from changing_slam_ros.core.geometry.se3 import invert, rotation_angle_rad
from changing_slam_ros.core.geometry.transform_tree import ExtrapolationError, TransformError
from changing_slam_ros.nodes.conversions import make_header, matrix_to_transform
from changing_slam_ros.nodes.tf_buffer import TfLookup, make_tf_lookup

F64 = npt.NDArray[np.float64]


@dataclass
class _Waiting:
    """A tracked frame whose odometry (odom_source tf) has not arrived yet."""

    stamp_ns: int
    T_map_base: F64
    deadline_s: float  # time.monotonic()


class Rep105Outputs:
    """TF for one tracking node; `on_tracked` per posed frame, `on_lost` per frame tracking could not pose."""

    def __init__(self, node: Node, p: dict[str, Any], tf_lookup: TfLookup | None = None) -> None:
        self.node = node
        self.source = OdomSource.parse(p["odom_source"])
        self.map_frame, self.odom_frame, self.camera_frame = p["map_frame"], p["odom_frame"], p["camera_frame"]
        self.base_frame: str = p["base_frame"] or p["camera_frame"]
        self.timeout_s = float(p["tf_timeout_s"])
        self.tf_pub = node.create_publisher(TFMessage, "/tf", 100) if p["publish_tf"] else None
        needs_tf = self.source is OdomSource.TF or self.base_frame != self.camera_frame
        self.tf = tf_lookup if tf_lookup is not None else (make_tf_lookup(node, p["tf_cache_s"]) if needs_tf else None)
        self.T_base_cam: F64 | None = np.eye(4) if self.base_frame == self.camera_frame else None
        self.state = Rep105State()
        self.has_map_odom = False  # a map -> odom has been computed (before: nothing to hold while lost)
        self.tracking = "NOT_INITIALISED"  # OK, LOST, or RELOCALISED (the first pose after LOST)
        self.n_lost_frames = 0
        self.n_relocalised = 0  # LOST -> a pose again
        self.odom_timeouts = 0  # frames whose odometry never came within tf_timeout_s
        self.odom_missing = 0  # frames with no odometry path at all (no odom -> base_frame on /tf)
        self._map_moved = False
        self._map_placed = False  # `place_map` has decided the frame of the map
        self._waiting: deque[_Waiting] = deque()
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._timer = node.create_timer(0.01, self._retry, clock=steady, autostart=False)

    # -- per frame ------------------------------------------------------------------------------
    def map_moved(self) -> None:
        """The map moved under the robot (a loop correction, a merge): the next pose's jump is the map's."""
        self._map_moved = True

    def on_tracked(self, stamp_ns: int, T_map_cam: F64, map_moved: bool,  # noqa: N803
                   T_prev_cur_cam: F64 | None) -> tuple[F64, str]:  # fmt: skip
        """A posed frame: publishes its transforms and returns the pose to publish with its child frame
        (the base's when its mounting is known, else the camera's). `map_moved`: the pose is not continuous with
        the last one; `T_prev_cur_cam`: the camera's motion since the last frame when tracking measured it."""
        moved = map_moved or self._map_moved or self.tracking == "LOST"
        self._map_moved = False
        self._set_state("RELOCALISED" if self.tracking == "LOST" else "OK", stamp_ns)
        T_base_cam = self.base_cam()  # noqa: N806
        if T_base_cam is None:
            return T_map_cam, self.camera_frame
        T_map_base = base_pose(T_map_cam, T_base_cam)  # noqa: N806
        if self.source is OdomSource.VISUAL:
            before = self.state.T_map_odom.copy()
            step = None if T_prev_cur_cam is None else base_motion(T_prev_cur_cam, T_base_cam)
            T_odom_base = self.state.visual(T_map_base, moved, step)  # noqa: N806
            self.has_map_odom = True
            if moved:
                self._log_jump(before, self.state.T_map_odom, stamp_ns)
            self._send(stamp_ns, [(self.map_frame, self.odom_frame, self.state.T_map_odom),
                                  (self.odom_frame, self.base_frame, T_odom_base)])  # fmt: skip
        else:
            self._waiting.append(_Waiting(stamp_ns, T_map_base, time.monotonic() + self.timeout_s))
            self._retry()
        return T_map_base, self.base_frame

    def on_lost(self, stamp_ns: int) -> None:
        """A frame without a pose: the last map -> odom goes on (odom_source tf: the robot's odometry carries
        the pose); odom -> base_frame from vision stops until tracking relocalises."""
        self.n_lost_frames += 1
        self._set_state("LOST", stamp_ns)
        if self.has_map_odom and not self._waiting:
            self._send(stamp_ns, [(self.map_frame, self.odom_frame, self.state.T_map_odom)])

    def place_map(self, system: Any) -> None:
        """Before a map's first keyframe (none loaded): with a `base_frame` whose mounting is known, the map is
        built in the base's frame at the start (`SlamSystem.set_first_pose`), so `map` is z-up when the base
        stands level (REP-105) and `~/grid` lies in its x-y plane as Nav2 reads it. Without a base frame, or
        while the mounting is unknown, the map is the first camera's optical frame (z forward, y down), or level on
        the floor in view with `tracking.level_from_floor` (`SlamSystem`)."""
        if self._map_placed or system is None:
            return
        self._map_placed = True
        if system.atlas.n_keyframes:  # a loaded map keeps its frame
            return
        has_base = self.base_frame != self.camera_frame
        T_base_cam = self.base_cam() if has_base else None  # noqa: N806
        if T_base_cam is None:
            missing = (f"no {self.base_frame} -> {self.camera_frame} mounting when the map started" if has_base
                       else "no base_frame")
            if system.config.tracking.level_from_floor:
                self.node.get_logger().info(f"tracking: {missing}; {self.map_frame} starts level on the floor in the "
                                            f"first depth image that shows one (tracking.level_from_floor)")  # fmt: skip
            elif has_base:
                self.node.get_logger().warning(f"tracking: {self.map_frame} is the first camera's optical frame (not "
                                               f"z-up): {missing}")  # fmt: skip
            return
        system.set_first_pose(T_base_cam)
        self.node.get_logger().info(f"tracking: {self.map_frame} is {self.base_frame} at the first frame")

    def base_cam(self) -> F64 | None:
        """T_base_cam from /tf_static (the robot's URDF), looked up once it is there; None (warned) before."""
        if self.T_base_cam is None and self.tf is not None:
            try:
                self.T_base_cam = self.tf.lookup(self.base_frame, self.camera_frame, 0)
                self.node.get_logger().info(f"tracking: camera mounting {self.base_frame} -> {self.camera_frame}: "
                                            f"t = {np.round(self.T_base_cam[:3, 3], 4).tolist()} m")  # fmt: skip
            except TransformError as err:
                self.node.get_logger().warning(
                    f"tracking: no {self.base_frame} -> {self.camera_frame} transform yet ({err}); publish it on "
                    f"/tf_static (robot_state_publisher); until then poses are the camera's and no TF goes out",
                    throttle_duration_sec=5.0)  # fmt: skip
        return self.T_base_cam

    def diagnostic_values(self) -> dict[str, Any]:
        return {"tracking_state": self.tracking, "relocalisations": self.n_relocalised,
                "odom_source": self.source.value, "lost_frames": self.n_lost_frames,
                "map_odom_jumps": self.state.jumps, "odom_lookups_timed_out": self.odom_timeouts}  # fmt: skip

    # -- odom_source tf -------------------------------------------------------------------------
    def _retry(self) -> None:
        """Frames waiting for odometry, oldest first: each gets map -> odom once odom -> base_frame at its stamp
        is in the buffer, or is given up at its deadline (warned; the last map -> odom is sent instead)."""
        assert self.tf is not None
        while self._waiting:
            w = self._waiting[0]
            try:
                T_odom_base = self.tf.lookup(self.odom_frame, self.base_frame, w.stamp_ns)  # noqa: N806
            except ExtrapolationError as err:
                if err.future and time.monotonic() < w.deadline_s:
                    break  # the odometry for this stamp may still come
                self._give_up(w, f"no odometry within tf_timeout_s {self.timeout_s} s: {err}", timed_out=True)
                continue
            except TransformError as err:
                self._give_up(w, str(err), timed_out=False)
                continue
            self._waiting.popleft()
            self.state.from_odometry(w.T_map_base, T_odom_base)
            self.has_map_odom = True
            self._send(w.stamp_ns, [(self.map_frame, self.odom_frame, self.state.T_map_odom)])
        if self._waiting:
            self._timer.reset()
        else:
            self._timer.cancel()

    def _give_up(self, w: _Waiting, why: str, timed_out: bool) -> None:
        self._waiting.popleft()
        if timed_out:
            self.odom_timeouts += 1
        else:
            self.odom_missing += 1
        self.node.get_logger().warning(
            f"tracking: map -> {self.odom_frame} not updated at {w.stamp_ns * 1e-9:.3f} s ({why}); the last one "
            f"is kept", throttle_duration_sec=5.0)  # fmt: skip
        if self.has_map_odom:
            self._send(w.stamp_ns, [(self.map_frame, self.odom_frame, self.state.T_map_odom)])

    # -- helpers --------------------------------------------------------------------------------
    def _set_state(self, state: str, stamp_ns: int) -> None:
        if state == self.tracking:
            return
        if state == "LOST":
            self.node.get_logger().warning(f"tracking: LOST at {stamp_ns * 1e-9:.3f} s; no pose until "
                                           f"relocalisation, map -> {self.odom_frame} held")  # fmt: skip
        elif state == "RELOCALISED":
            self.n_relocalised += 1
            self.node.get_logger().info(f"tracking: relocalised at {stamp_ns * 1e-9:.3f} s")
        self.tracking = state

    def _log_jump(self, before: F64, after: F64, stamp_ns: int) -> None:
        d = invert(before) @ after
        self.node.get_logger().info(
            f"tracking: map moved at {stamp_ns * 1e-9:.3f} s: map -> {self.odom_frame} changed by "
            f"{np.linalg.norm(d[:3, 3]) * 100:.1f} cm, {np.rad2deg(rotation_angle_rad(d[:3, :3])):.1f} deg")

    def _send(self, stamp_ns: int, edges: list[tuple[str, str, F64]]) -> None:
        if self.tf_pub is None or self.tf_pub.get_subscription_count() == 0:
            return
        out = []
        for parent, child, T in edges:  # noqa: N806
            t = TransformStamped(header=make_header(stamp_ns, parent), child_frame_id=child)
            t.transform = matrix_to_transform(T)
            out.append(t)
        self.tf_pub.publish(TFMessage(transforms=out))
