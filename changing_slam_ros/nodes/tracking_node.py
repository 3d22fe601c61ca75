"""`tracking`: colour + depth + camera_info (+ detections) -> camera pose, path, TF, keyframes, semantic map.

    python -m changing_slam_ros.nodes.tracking_node --ros-args -p config:=tum_fr1 -p output_dir:=/tmp/out

Two backends. `in_process_backend:=false` (the split graph): features, dynamic filter and tracking run
here against a replica of the map; each new keyframe goes out as a keyframe packet (~/keyframes) to
`local_mapping` (which owns the map) and `loop_closing`; their MapUpdates (/local_mapping/map_updates) are
applied to the replica as they arrive and the last frame is re-anchored on its moved reference keyframe
(`nodes/split_backend.py`, `core/replication/map_replication.py`). With `wait_for_map_updates:=true` (lossless graph) a
keyframe frame is acknowledged to the bag player only once local_mapping's update and loop_closing's verdict
for it (and, after a loop, local_mapping's update applying it) are in, so the graph replays the offline order.
In real time (`provisional_points`, on unless `wait_for_map_updates`) a new keyframe's depth keypoints become
provisional points in the replica at once (`core/slam/provisional_points.py`), so tracking goes on at full rate
while local_mapping maps the keyframe; the owner's update replaces them.
`in_process_backend:=true`: the whole `core.system.SlamSystem` (tracking -> local mapping -> object layer ->
loop closing) runs in this process (deterministic, `nodes/slam_backend.py`), and this node publishes the
semantic map itself. `slam:=false`: frames are paired, converted and acknowledged only (plumbing tests).

Per RGB-D pair (approximate-time, `sync_slop_s`): the frame waits for the detections stamped with its colour stamp for
at most `detections_wait_s` (only when the dynamic filter uses detections and a detection stream is there, or
`detections_required:=true`) or until it is clear that none will come (the detector announced on /detection/skipped
that it will not detect that image, its rate cap, or it published detections of a later image), then goes through the
system with them (or with the newest earlier ones carried forward, or none: the object EKFs then predict).
`frame_policy:=latest` (real time; `nodes/frame_queue.py`): when several paired frames wait, the newest ready one (its
detections in, or its wait over) is tracked and the older ones whose wait is over are dropped
(`frames_dropped_stale`), so no queue builds up behind a slow frame; with `reliable_images` and `image_queue_depth:=1`
the middleware keeps only the newest image too. `detections_skip_late:=true`: while the last `detections_late_window`
detections all came later than `detections_wait_s` (a detector slower than the wait), frames are tracked at once
instead of waiting in vain (`frames_not_waited_for_late_detections`); the wait resumes when detections come in time
again.
A frame tracked without its own detections takes the newest earlier person boxes carried forward
(`core.late_detections`, `detections_carry_*`: grown with their age; with `detections_carry_flow` first moved by
their image motion since the detections' image, from a ring of the recent frames' grey and depth images).
Intrinsics come from camera_info or from the config's camera (`intrinsics_from`; `auto` follows the config's
`dataset.bag_intrinsics_from`, since TUM bags carry the uncalibrated ROS defaults). `map_file`: multi-session
(`SlamSystem.start_from_map`; see `nodes/split_backend.py`). LoadMap mid-run (local_mapping's ~/load_map, split
backend): on the owner's load marker the replica starts afresh from the marker's map file, as with `map_file`
(relocalising in the loaded map first; the path restarts in its frame; the trajectory so far is written as
trajectory_online_before_load_<n>.txt), a marker goes out on ~/keyframes, and map updates and loop verdicts
made before their sender loaded are dropped (`nodes/map_load.py`).

With `dynamic.movers` on in the config: ~/moving_objects (MovingObjectArray) and ~/moving_object_markers
(MarkerArray), every `moving_objects_period_s` and at the end; moving_objects.json on shutdown.

Inputs (defaults are the TUM bag names; remap with --ros-args -r):
  /camera/rgb/image_color (Image, sensor-data QoS), /camera/depth/image (Image 32FC1 m or 16UC1 mm), or with
  `compressed:=true` their /compressed CompressedImage topics (JPEG/PNG colour, PNG or compressedDepth depth),
  /camera/rgb/camera_info, /detection/detections, /detection/skipped, /local_mapping/map_updates,
  /loop_closing/loop_corrections, /object_map/object_states
Outputs (`nodes/tracking_outputs.py`; odometry, path, TF and debug image only while subscribed): ~/pose
  (PoseStamped, map frame), ~/odometry, ~/path (the online poses; rebuilt from the optimised
  trajectory after a loop closure), ~/keyframes, ~/semantic_map (MapObjectArray, transient-local, after each
  keyframe the object layer worked on), ~/debug_image (keypoints used for tracking, coloured by class, and the
  frame's detection boxes), TF map->odom (identity: no separate odometry yet) and odom->camera (REP-105,
  `publish_tf`), and, when `ack_topic` is set, a std_msgs/Header per processed frame (frame_id: this node's
  name) and per accepted camera_info (frame_id: the camera_info topic) for bag_player's lossless mode.
On shutdown (SIGINT/SIGTERM, or `destroy_node`) with `output_dir` set: trajectory.txt (final, after all
optimisation), trajectory_online.txt, keyframes.txt (TUM), semantic_map.json and tracking_stats.json (frames,
drops, image-to-pose latency: colour message received -> pose published, steady clock), written atomically.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from rclpy._rclpy_pybind11 import RCLError  # a publish after the context shut down
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from std_msgs.msg import Header

from changing_slam_msgs.msg import DetectionArray, LoopCorrection, MapObjectArray, MapUpdate
from changing_slam_msgs.msg import ObjectStateArray
from changing_slam_msgs.msg import Keyframe as KeyframeMsg
from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.features.rgbd_frame import RgbdFrame
from changing_slam_ros.core.slam.tracking import TrackingState
from changing_slam_ros.errors import SlamError
from changing_slam_ros.nodes.conversions import (
    camera_info_to_intrinsics,
    detections_from_msg,
    image_to_depth_m,
    image_to_rgb,
    keyframe_to_msg,
    make_header,
    stamp_to_ns,
)
from changing_slam_ros.nodes.frame_queue import FrameQueue, PendingFrame
from changing_slam_ros.nodes.map_load import LoadEpochs, LoadMarker, keyframe_marker, marker_of
from changing_slam_ros.nodes.node_runner import declare_parameters, run_node
from changing_slam_ros.nodes.qos_events import QuietQosEvents
from changing_slam_ros.nodes.stamp_sync import ApproximatePairer
from changing_slam_ros.nodes.tracking_outputs import MoverOutputs, PoseOutputs, debug_image
from changing_slam_ros.nodes.tracking_params import TRACKING_PARAMETERS

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def _keep_newest(by_stamp: dict[int, Any], n: int) -> None:
    """Drop the oldest entries (insertion order) of a per-stamp dict until at most `n` are left."""
    while len(by_stamp) > n:
        del by_stamp[next(iter(by_stamp))]


class TrackingNode(QuietQosEvents, Node):
    def __init__(
        self,
        image_qos: QoSProfile = qos_profile_sensor_data,
        output_qos: QoSProfile | int = 10,
        **node_kwargs: Any,
    ) -> None:
        super().__init__("tracking", **node_kwargs)
        self.params = p = declare_parameters(self, list(TRACKING_PARAMETERS))
        if p["reliable_images"]:
            image_qos = QoSProfile(depth=max(1, p["image_queue_depth"]), reliability=ReliabilityPolicy.RELIABLE)
        slop_ns = round(p["sync_slop_s"] * 1e9)
        self.pairer: ApproximatePairer[Any, Any] = ApproximatePairer(slop_ns)
        self.camera: CameraIntrinsics | None = None  # from camera_info, as received
        self.detections: dict[int, Any] = {}
        self.frames_in = 0  # frames converted to RgbdFrame
        self.colour_in = 0  # colour messages received
        self.frames_rejected = 0
        self.frames_without_detections = 0
        self.latency_ms: list[float] = []
        self.process_ms: list[float] = []
        self.process_cpu_ms: list[float] = []  # process CPU time per processed frame (load-independent)
        self.detection_delay_ms: list[float] = []  # colour received -> its detections received
        self.published_poses = 0
        self.frames_dropped_stale = 0  # frame_policy latest: paired frames skipped for a newer one
        self.frames_not_waited = 0  # detections_skip_late: frames tracked at once as detections came late
        self._recent_delays_ms: deque[float] = deque(maxlen=max(1, p["detections_late_window"]))
        self._processed_received_s: dict[int, float] = {}  # stamp -> colour received, of frames already tracked
        self._warned: set[str] = set()
        self._received_s: dict[int, float] = {}
        self._skipped: dict[int, None] = {}  # stamps the detector announced it will not detect (insertion order)
        self.detections_skipped_in = 0
        self._last_detected_ns: int | None = None  # stamp of the last detections received
        # frames waiting for their detections: ready once those are settled (`_detections_settled`) or at the deadline
        self.queue = FrameQueue(p["frame_policy"], self._detections_settled)
        self._detections_seen = False
        self._acked_early: set[int] = set()  # frames acked while held for the first camera_info
        self._newest_detections: Any | None = None  # the newest DetectionSet received (carried to later frames)
        self._previous_detections: Any | None = None  # the one before it (the carried boxes' velocities)
        from changing_slam_ros.core.dynamic.late_detections import CarryConfig, RecentImages

        self._carry = CarryConfig(p["detections_carry_max_age_s"], p["detections_carry_grow_widths_per_s"],
                                  tuple(int(c) for c in p["detections_carry_class_ids"]),
                                  extrapolate=p["detections_carry_extrapolate"], flow=p["detections_carry_flow"],
                                  flow_grow_widths_per_s=p["detections_carry_flow_grow_widths_per_s"],
                                  flow_hull=p["detections_carry_flow_hull"])  # fmt: skip
        # detections_carry_flow: grey + depth of the recent frames, by stamp (the carried boxes' image motion)
        self._recent_images = RecentImages(p["detections_carry_max_age_s"], p["detections_carry_flow_max_stamp_gap_s"])
        self.carry_cpu_ms: list[float] = []  # CPU of carrying boxes forward (with flow: measuring their motion)
        self.frames_with_carried_detections = 0
        self._finished = False

        self.backend: Any = None
        self.split: Any = None  # split_backend.TrackingSide when the map comes from local_mapping
        self.config_camera: CameraIntrinsics | None = None
        self.updates_applied = 0
        self.updates_rejected = 0
        self.detections_in = 0
        self.update_latency_ms: list[float] = []  # keyframe published -> its map update applied
        self._awaiting: dict[str, Any] | None = None  # wait_for_map_updates: what the held ack waits for
        self._kf_sent_s: dict[int, float] = {}
        self._relays_seen: set[int] = set()
        self.epochs = LoadEpochs.of("updates", "loops")  # local_mapping's ~/load_map (see nodes/map_load.py)
        self._before_load: list[Any] = []  # online trajectories of the maps replaced by a LoadMap
        self.loads = 0
        self._cfg: Any = None
        intrinsics_from = p["intrinsics_from"]
        if p["slam"]:
            from changing_slam_ros.nodes.slam_backend import build_backend, config_camera, intrinsics_source, load_backend_config

            self._cfg = cfg = load_backend_config(p["config"])
            if p["in_process_backend"]:
                self.backend = build_backend(cfg, loop=p["loop_closing"], dynamic=p["dynamic"], objects=p["objects"])
            else:
                from changing_slam_ros.nodes.split_backend import TrackingSide

                provisional = bool(p["provisional_points"] and not p["wait_for_map_updates"])
                self.split = TrackingSide.build(cfg, loop=p["loop_closing"], dynamic=p["dynamic"], objects=p["objects"],
                                                provisional=provisional)  # fmt: skip
                self.backend = self.split.backend
                from changing_slam_ros.nodes.map_resync import ResyncServer

                # lambdas: a LoadMap replaces self.split
                self.resync = ResyncServer(self, lambda: self.split.snapshot(), p["map_frame"], self._resend_unmapped)
            if p["map_file"]:
                self._start_from_map(cfg, p["map_file"])
            if intrinsics_from == "auto":
                intrinsics_from = intrinsics_source(cfg)
            if intrinsics_from == "config":
                self.config_camera = config_camera(cfg)
        if intrinsics_from not in ("camera_info", "config", "auto"):
            raise SlamError(f"tracking: parameter intrinsics_from: '{intrinsics_from}' unknown; expected auto, camera_info or config")
        self.intrinsics_from = "config" if self.config_camera is not None else "camera_info"

        # camera_info first: when it and an image are ready in the same spin, the executor serves it first.
        # The sensor inputs keep rclpy's QoS-event warnings (a driver offering incompatible QoS); the other
        # publishers and subscriptions have none (nodes/qos_events.py: cheaper spins).
        warn = SubscriptionEventCallbacks
        self._camera_info_sub = self.create_subscription(CameraInfo, "/camera/rgb/camera_info", self.on_camera_info,
                                                         image_qos, event_callbacks=warn())  # fmt: skip
        if p["compressed"]:
            self.colour_topic, self.depth_topic = "/camera/rgb/image_color/compressed", "/camera/depth/image/compressed"
            image_type: Any = CompressedImage
        else:
            self.colour_topic, self.depth_topic = "/camera/rgb/image_color", "/camera/depth/image"
            image_type = Image
        self.create_subscription(image_type, self.colour_topic, self.on_colour, image_qos, event_callbacks=warn())
        self.create_subscription(image_type, self.depth_topic, self.on_depth, image_qos, event_callbacks=warn())
        self.create_subscription(DetectionArray, "/detection/detections", self.on_detections, 10)
        self.create_subscription(Header, "/detection/skipped", self.on_detections_skipped, 10)
        self.create_subscription(MapUpdate, "/local_mapping/map_updates", self.on_map_update, 10)
        self.create_subscription(LoopCorrection, "/loop_closing/loop_corrections", self.on_loop_correction, 10)
        self.create_subscription(ObjectStateArray, "/object_map/object_states", self.on_object_states, 10)

        self.poses_out = PoseOutputs(self, output_qos, p["map_frame"], p["odom_frame"], p["camera_frame"],
                                     p["publish_tf"])  # pose, odometry, path, TF  # fmt: skip
        self.keyframe_pub = self.create_publisher(KeyframeMsg, "~/keyframes", QoSProfile(depth=100))
        self.object_pub = self.create_publisher(ObjectStateArray, "~/object_states", output_qos)
        self.semantic_pub = self.create_publisher(MapObjectArray, "~/semantic_map", LATCHED)
        self.debug_pub = self.create_publisher(Image, "~/debug_image", 2) if p["debug_image"] else None
        self.movers = None if self.backend is None or self.backend.dynamic is None else self.backend.dynamic.movers
        # class-agnostic movers (Dai et al.): tracked here, with camera tracking
        self.movers_out = None if self.movers is None else MoverOutputs(self, output_qos, p["map_frame"],
                                                                        p["moving_objects_period_s"])  # fmt: skip
        self._movers_stamp_ns = 0
        self.ack_pub = self.create_publisher(Header, p["ack_topic"], 100) if p["ack_topic"] else None
        # Steady clock: the stats line and the detection deadlines keep going when use_sim_time is on and the
        # bag is paused.
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(p["stats_period_s"], self._log_stats, clock=steady)
        # Woken at the earliest deadline something waits for (a frame's detections, a held ack), else idle:
        # a spin costs ~0.5-1 ms of CPU, so a fixed 100 Hz poll cost more than a frame's decoding.
        self._drain_timer = self.create_timer(3600.0, self._drain, clock=steady, autostart=False)
        from changing_slam_ros.nodes.diagnostics import NodeDiagnostics

        self.diagnostics = NodeDiagnostics(self, p["diagnostics_period_s"], warn_if=_warn_if)
        self.diagnostics.set_source(self.diagnostic_values)
        if self.backend is None:
            mode = "pairing only (slam:=false, no poses)"
        elif self.split is not None:
            mode = "split backend (map from local_mapping, loops from loop_closing)"
        else:
            mode = "in-process backend (tracking + local mapping + objects + loop closing here)"
        self.get_logger().info(f"tracking: started, {mode}, intrinsics from {self.intrinsics_from}")

    def _start_from_map(self, cfg: Any, map_file: str) -> None:
        """Multi-session (as `changing-slam run --map-in`): the loaded Atlas becomes the map (split: the replica
        and the relocalisation index, with the saved objects' point flags as local_mapping sets them)."""
        from changing_slam_ros.io.map_file import load_map

        loaded = load_map(map_file)
        if self.split is not None:
            from changing_slam_ros.nodes.split_backend import object_layer_for

            self.split.start_from_map(loaded, object_layer_for(cfg, self.params["objects"]))
        else:
            self.backend.system.start_from_map(loaded.atlas, loaded.next_keyframe_id, loaded.objects)
        atlas = self.backend.system.atlas
        self.get_logger().info(f"tracking: {atlas.n_keyframes} keyframes in {len(atlas.maps)} maps loaded from "
                               f"{map_file}; relocalising in map {atlas.current.id} first")  # fmt: skip

    # -- inputs ---------------------------------------------------------------------------------
    def on_colour(self, msg: Any) -> None:
        self.colour_in += 1
        stamp_ns = stamp_to_ns(msg.header.stamp)
        self._received_s[stamp_ns] = time.monotonic()
        _keep_newest(self._received_s, 200)
        for t_rgb, rgb_msg, _t_d, depth_msg in self.pairer.add_first(stamp_ns, msg):
            self.on_frame(t_rgb, rgb_msg, depth_msg)
        self._warn_if_unpaired()

    def on_depth(self, msg: Any) -> None:
        for t_rgb, rgb_msg, _t_d, depth_msg in self.pairer.add_second(stamp_to_ns(msg.header.stamp), msg):
            self.on_frame(t_rgb, rgb_msg, depth_msg)
        self._warn_if_unpaired()

    def on_camera_info(self, msg: CameraInfo) -> None:
        first = self.camera is None
        try:
            self.camera = camera_info_to_intrinsics(msg, "/camera/rgb/camera_info")
        except SlamError as err:
            self.get_logger().warning(f"tracking: camera_info rejected: {err}", throttle_duration_sec=5.0)
            return
        if self.ack_pub is not None:  # lossless: confirms delivery to a player that re-sends until confirmed
            self.ack_pub.publish(Header(stamp=msg.header.stamp, frame_id=self._camera_info_sub.topic_name))
        if first and len(self.queue):
            self._drain()  # frames held for it (lossless)

    def on_detections(self, msg: DetectionArray) -> None:
        ds = detections_from_msg(msg)
        self._detections_seen = True
        self.detections_in += 1
        received = (self._received_s.get(ds.stamp_ns) or self._processed_received_s.get(ds.stamp_ns)
                    or self.queue.received_s(ds.stamp_ns))  # fmt: skip
        if received is not None:  # also for frames tracked already: how late detections come
            delay_ms = (time.monotonic() - received) * 1e3
            self.detection_delay_ms.append(delay_ms)
            self._recent_delays_ms.append(delay_ms)
        self.detections[ds.stamp_ns] = ds
        self._last_detected_ns = ds.stamp_ns
        if self._newest_detections is None or ds.stamp_ns > self._newest_detections.stamp_ns:
            self._previous_detections, self._newest_detections = self._newest_detections, ds
        _keep_newest(self.detections, 30)
        if self.backend is not None and self.backend.system.refinement is not None:
            # tracking.deferred_refinement: the frames tracked before these detections came get their final pose
            # refined (core.deferred_refinement); the published poses stay
            self.backend.system.refine_with_detections(ds)
        self._drain()

    def _detections_settled(self, stamp_ns: int) -> bool:
        """A frame's detections are in, or none will come: the detector announced it skips the image, or it has
        published detections of a later image (it works through images in order and never goes back)."""
        last = self._last_detected_ns
        return stamp_ns in self.detections or stamp_ns in self._skipped or (last is not None and stamp_ns < last)

    def on_detections_skipped(self, msg: Header) -> None:
        """The detector will not detect this image (its rate cap, or it rejected it): its frame stops waiting."""
        self.detections_skipped_in += 1
        self._skipped[stamp_to_ns(msg.stamp)] = None
        _keep_newest(self._skipped, 30)
        self._drain()

    def _carried_detections(self, stamp_ns: int) -> Any:
        """The newest earlier detections for a frame that has none of its own (`core.late_detections`), or None."""
        from changing_slam_ros.core.dynamic.late_detections import carried_forward

        if self._newest_detections is None or self._carry.max_age_s <= 0:
            return None
        c0 = time.process_time()
        images = None
        if self._carry.flow:
            before = self._recent_images.get(self._newest_detections.stamp_ns)
            after = self._recent_images.get(stamp_ns)
            images = (before, after) if before is not None and after is not None else None
        carried = carried_forward(self._newest_detections, stamp_ns, self._carry, self._previous_detections, images)
        if carried is not None:
            self.frames_with_carried_detections += 1
            self.carry_cpu_ms.append((time.process_time() - c0) * 1e3)
        return carried

    def on_map_update(self, msg: MapUpdate) -> None:
        """Split backend: local_mapping's change of the map into the replica (in publication order)."""
        if self.split is None:
            return
        marker = marker_of(msg, msg.keyframe_id)
        if marker is not None:
            self._on_marker("updates", marker)
            return
        if not self.epochs.current("updates"):
            return  # the owner's change of the map it held before ~/load_map
        from changing_slam_ros.nodes.replication_conversions import update_from_msg

        try:
            update = update_from_msg(msg, "/local_mapping/map_updates")
            released = self.split.apply_update(update)
        except (SlamError, ValueError) as err:
            self.updates_rejected += 1
            self.get_logger().warning(f"tracking: map update rejected: {err}", throttle_duration_sec=5.0)
            return
        for packet in released:  # provisional points: keyframes held until this update named their points
            self._send_packet(packet)
        self.updates_applied += 1
        sent = self._kf_sent_s.pop(update.keyframe_id, None)
        if sent is not None:
            self.update_latency_ms.append((time.monotonic() - sent) * 1e3)
        if update.loop_query_kf_id >= 0:
            self.split.n_loops += int(update.merge is None)  # a merge is counted in split.n_merges
            self._relays_seen.add(update.loop_query_kf_id)
            self._rebuild_path()
        self._settle(update=update.keyframe_id, relay=update.loop_query_kf_id)

    def _resend_unmapped(self) -> None:
        """After a map snapshot: keyframes sent but not mapped (local_mapping was down) go out again."""
        for packet in self.split.resend():
            self._send_packet(packet, resend=True)

    def on_loop_correction(self, msg: LoopCorrection) -> None:
        """Split backend: loop_closing's verdict; a closed loop reaches the replica through local_mapping's update."""
        if self.split is None:
            return
        marker = marker_of(msg, msg.query_keyframe_id)
        if marker is not None:
            self._on_marker("loops", marker)
            return
        if not self.epochs.current("loops"):
            return  # a verdict on the map before ~/load_map
        # a map merge, like a closed loop, comes back as local_mapping's update: wait for that relay too
        self._settle(verdict=int(msg.query_keyframe_id), closed=bool(msg.closed) or bool(msg.merge))

    def _on_marker(self, stream: str, marker: LoadMarker) -> None:
        """A load announced on `stream` (local_mapping's ~/load_map): the first announcement of a newer load
        replaces the replica with the marker's file (`TrackingSide.start_from_map`: relocalise in it first)."""
        if not self.epochs.on_marker(stream, marker):
            return
        from changing_slam_ros.io.map_file import load_map
        from changing_slam_ros.nodes.split_backend import TrackingSide, object_layer_for

        p, old = self.params, self.split

        def build() -> TrackingSide:
            return TrackingSide.build(self._cfg, loop=p["loop_closing"], dynamic=p["dynamic"], objects=p["objects"],
                                      provisional=old.provisional is not None)  # fmt: skip

        side = build()
        try:
            side.start_from_map(load_map(marker.path), object_layer_for(self._cfg, p["objects"]))
        except (SlamError, OSError, ValueError) as err:  # local_mapping loaded it: the file changed since
            self.get_logger().error(f"tracking: map {marker.path} not loaded ({err}); starting a new map")
            side = build()
        if old.system.records:
            self._before_load.append(old.system.online_trajectory())
        self.split, self.backend = side, side.backend
        if self.movers is not None and side.backend.dynamic is not None:
            self.movers = side.backend.dynamic.movers
        self.epochs.adopt(marker)
        self.loads += 1
        self.poses_out.replace_path([], [])  # the path goes on in the loaded map's frame
        self._kf_sent_s.clear()
        self._relays_seen.clear()
        self.keyframe_pub.publish(keyframe_marker(marker))
        atlas = side.system.atlas
        self.get_logger().info(f"tracking: {atlas.n_keyframes} keyframes in {len(atlas.maps)} maps loaded from "
                               f"{marker.path} (LoadMap); relocalising in map {atlas.current.id}")  # fmt: skip
        if self._awaiting is not None:  # its update and verdict will not come: the old map is gone
            held, self._awaiting = self._awaiting["header"], None
            self._ack(held)
        self._drain()

    def on_object_states(self, msg: ObjectStateArray) -> None:
        pass  # Point activity comes from the object layer (in local_mapping, or in-process), not from object_map.

    def _settle(self, update: int = -2, relay: int = -2, verdict: int = -2, closed: bool = False) -> None:
        """wait_for_map_updates: tick off what the held acknowledgement waits for; send it when all is in."""
        a = self._awaiting
        if a is None:
            return
        kf = a["kf"]
        if update == kf:
            a["update"] = True
        if verdict == kf:
            a["verdict"] = True
            a["relay"] = not closed or kf in self._relays_seen
        if relay == kf:
            a["relay"] = True
        if a["update"] and a["verdict"] and a["relay"]:
            self._awaiting = None
            self._ack(a["header"])
            self._drain()

    def _check_wait(self) -> None:
        a = self._awaiting
        if a is not None and time.monotonic() > a["deadline"]:
            self.get_logger().warning(f"tracking: no map update / loop verdict for keyframe {a['kf']} after "
                                      f"{self.params['map_update_timeout_s']} s; going on")  # fmt: skip
            self._awaiting = None
            self._ack(a["header"])

    # -- one RGB-D frame ------------------------------------------------------------------------
    def on_frame(self, stamp_ns: int, rgb_msg: Any, depth_msg: Any) -> None:
        now = time.monotonic()
        received = self._received_s.pop(stamp_ns, now)
        wait = self.params["detections_wait_s"] if self._wait_for_detections() else 0.0
        if wait > 0 and self._detections_hopelessly_late(wait):
            wait = 0.0
            self.frames_not_waited += 1
        self._processed_received_s[stamp_ns] = received
        _keep_newest(self._processed_received_s, 200)
        self.queue.push(PendingFrame(stamp_ns, rgb_msg, depth_msg, received, now + wait))
        self._drain()

    def _detections_hopelessly_late(self, wait_s: float) -> bool:
        """detections_skip_late: the last `detections_late_window` detections all came after `wait_s`."""
        d = self._recent_delays_ms
        return bool(self.params["detections_skip_late"] and len(d) == d.maxlen and min(d) > wait_s * 1e3)

    def _wait_for_detections(self) -> bool:
        return (self.backend is not None and self.backend.wants_detections
                and (self._detections_seen or self.params["detections_required"]))  # fmt: skip

    def _drain(self) -> None:
        """Process waiting frames in order: each when its detections are in, or at its deadline. frame_policy
        latest: the frames older than the newest ready one (detections in or deadline passed) are dropped.
        Then the drain timer is set to the next deadline, or stopped when nothing waits."""
        try:
            self._drain_pending()
        finally:
            self._arm_drain_timer()

    def _arm_drain_timer(self) -> None:
        """The timer fires at the earliest deadline of a waiting frame or of the held ack (`_awaiting`); every
        change to either goes through `_drain`, so this is the only place that sets it."""
        first = self.queue.next_deadline_s()
        due = [] if first is None else [first]
        if self._awaiting is not None:
            due.append(self._awaiting["deadline"])
        if not due:
            self._drain_timer.cancel()
            return
        delay_s = max(min(due) - time.monotonic(), 0.001)
        self._drain_timer.timer_period_ns = round(delay_s * 1e9)
        self._drain_timer.reset()

    def _drain_pending(self) -> None:
        self._check_wait()
        if self._holding_for_camera_info():
            return
        if self._awaiting is None:
            for stale in self.queue.take_stale(time.monotonic()):
                self.detections.pop(stale.stamp_ns, None)
                self.frames_dropped_stale += 1
                self._ack(stale.rgb_msg.header)
        while self._awaiting is None and (head := self.queue.pop_ready(time.monotonic())) is not None:
            self._process(head)

    def _holding_for_camera_info(self) -> bool:
        """Lossless (frame_policy all): frames that come before the first camera_info (a separate DDS writer, which
        can be matched seconds after the images) wait for it instead of being skipped, up to
        `frames_held_for_camera_info`; each is acked at once so that the player goes on to publish it."""
        limit = self.params["frames_held_for_camera_info"]
        if self.params["frame_policy"] != "all" or limit <= 0 or (self.config_camera or self.camera) is not None:
            return False
        for item in self.queue:
            if item.stamp_ns not in self._acked_early:
                self._acked_early.add(item.stamp_ns)
                self._ack(item.rgb_msg.header)
        if len(self.queue) > limit:
            return False  # no camera_info for too long: the queued frames go on to _process, which skips them
        self._warn_once("held_for_camera", f"tracking: no camera_info yet; holding frames for it (at most {limit})")
        return True

    def _frame_camera(self, width: int, height: int) -> CameraIntrinsics | None:
        cam = self.config_camera if self.config_camera is not None else self.camera
        if cam is not None and (cam.width, cam.height) != (width, height):
            cam = cam.scaled(width, height)
        return cam

    def _process(self, item: PendingFrame) -> None:
        t0 = time.monotonic()
        c0 = time.process_time()
        try:
            rgb = image_to_rgb(item.rgb_msg, self.colour_topic)
            depth = image_to_depth_m(item.depth_msg, self.depth_topic)
            camera = self._frame_camera(rgb.shape[1], rgb.shape[0])
            if camera is None:
                self._warn_once("no_camera", "tracking: no camera_info yet; frames are skipped until one arrives")
                self._ack(item.rgb_msg.header)
                return
            if depth.shape != rgb.shape[:2]:
                raise ValueError(f"depth {depth.shape} and colour {rgb.shape[:2]} sizes differ")
            # (image_to_depth_m returns float32 with NaN, inf and <= 0 already set to 0 = no reading)
            frame = RgbdFrame(stamp_ns=item.stamp_ns, rgb=rgb, depth_m=depth, camera=camera, index=self.frames_in)
        except (SlamError, ValueError) as err:
            self.frames_rejected += 1
            self.get_logger().warning(f"tracking: frame rejected: {err}", throttle_duration_sec=5.0)
            self._ack(item.rgb_msg.header)
            return
        self.frames_in += 1
        if self.backend is None:
            self._warn_once("no_backend", "tracking: in_process_backend:=false: frames pair and convert, no poses")
            self._ack(item.rgb_msg.header)
            return
        if self._carry.flow and self._carry.max_age_s > 0 and self.backend.wants_detections:
            from changing_slam_ros.core.dynamic.box_flow import FlowImage  # boxes carried from or to this frame later

            self._recent_images.add(FlowImage.from_rgb(frame.stamp_ns, frame.rgb, frame.depth_m))
        dets = self.detections.pop(item.stamp_ns, None)
        used = None if dets is None else dets.detections
        if dets is None and self.backend.wants_detections:
            self.frames_without_detections += 1
            used = self._carried_detections(item.stamp_ns)
        packet = None
        if self.split is not None:
            out, packet = self.split.process(frame, used)
            if out is None:  # a new map waits for its first points from local_mapping
                self._warn_once("waiting_map", "tracking: a new map waits for its first map update; frames skipped")
                self._ack(item.rgb_msg.header)
                return
        else:
            out = self.backend.system.process(frame, used)
        if out.state == TrackingState.OK and out.T_world_cam is not None:
            self.publish_pose(item.stamp_ns, out.T_world_cam)
            self.latency_ms.append((time.monotonic() - item.received_s) * 1e3)
        if out.loop_corrected:
            self._rebuild_path()
        if packet is not None:
            if self.params["wait_for_map_updates"]:
                self._awaiting = {"kf": packet.keyframe.id, "update": False, "verdict": False, "relay": False,
                                  "header": item.rgb_msg.header,
                                  "deadline": time.monotonic() + self.params["map_update_timeout_s"]}  # fmt: skip
            self._send_packet(packet)
        elif out.keyframe is not None and self.split is None:
            self.keyframe_pub.publish(keyframe_to_msg(out.keyframe, self.params["map_frame"]))
        if out.objects is not None:
            self.publish_semantic_map(item.stamp_ns)
        self._movers_stamp_ns = item.stamp_ns
        if self.movers_out is not None and self.movers_out.due():
            self.publish_moving_objects(item.stamp_ns)
        if self.debug_pub is not None and self.debug_pub.get_subscription_count() > 0:
            last = self.backend.system.tracker.last_frame
            self.debug_pub.publish(debug_image(frame, last, out.dynamic, dets, self.params["camera_frame"]))
        self.process_ms.append((time.monotonic() - t0) * 1e3)
        self.process_cpu_ms.append((time.process_time() - c0) * 1e3)
        if self._awaiting is None:
            self._ack(item.rgb_msg.header)

    # -- outputs --------------------------------------------------------------------------------
    def _send_packet(self, packet: Any, resend: bool = False) -> None:
        """A keyframe packet to local_mapping and loop_closing (~/keyframes). The map-update latency counts from
        the first send (`resend`: again after a map snapshot, for a restarted owner; the clock is not restarted)."""
        from changing_slam_ros.nodes.replication_conversions import packet_to_msg

        msg = packet_to_msg(packet, self.params["map_frame"])
        if not resend:
            self._kf_sent_s[packet.keyframe.id] = time.monotonic()
        self.keyframe_pub.publish(msg)

    def publish_pose(self, stamp_ns: int, T_world_cam: Any) -> None:  # noqa: N803
        """Pose, odometry, path and TF (odom = map until loop corrections separate them; `PoseOutputs`)."""
        self.poses_out.publish(stamp_ns, T_world_cam)
        self.published_poses += 1

    def _rebuild_path(self) -> None:
        """After a loop closure: the path becomes the optimised (final) trajectory so far."""
        traj = self.backend.system.final_trajectory()
        if len(traj) == 0:
            return
        self.poses_out.replace_path(traj.stamps_s, traj.poses())

    def publish_semantic_map(self, stamp_ns: int) -> None:
        from changing_slam_ros.nodes.object_map_node import semantic_map_to_msg

        layer = self.backend.objects
        smap = layer.semantic_map(self.backend.system.atlas.current.id, include_inactive=True)
        self.semantic_pub.publish(semantic_map_to_msg(smap, make_header(stamp_ns, self.params["map_frame"])))

    def publish_moving_objects(self, stamp_ns: int) -> None:
        """~/moving_objects and ~/moving_object_markers (`MoverOutputs`): the movers tracked long enough."""
        if self.movers is not None and self.movers_out is not None:
            self.movers_out.publish(self.movers, stamp_ns)

    def stats(self) -> dict[str, Any]:
        """Counts and latencies for tracking_stats.json and the log."""
        s = self.pairer.stats
        lat = np.asarray(self.latency_ms) if self.latency_ms else np.zeros(0)
        proc = np.asarray(self.process_ms) if self.process_ms else np.zeros(0)
        prov = self.split.provisional if self.split is not None else None
        return {
            "colour_received": self.colour_in, "pairs": s.pairs, "unpaired_colour_dropped": s.dropped_first,
            "unpaired_depth_dropped": s.dropped_second, "frames_converted": self.frames_in,
            "frames_rejected": self.frames_rejected, "poses_published": self.published_poses,
            "frames_without_detections": self.frames_without_detections,
            "detections_skipped_received": self.detections_skipped_in,
            "frames_with_carried_detections": self.frames_with_carried_detections,
            "carry_cpu_ms_mean": float(np.mean(self.carry_cpu_ms)) if self.carry_cpu_ms else None,
            "deferred_refinement": None if self.backend is None or self.backend.system.refinement is None
            else dict(vars(self.backend.system.refinement.stats)),  # frames bracketed / optimised again / refined
            "frames_dropped_stale": self.frames_dropped_stale, "frame_policy": self.params["frame_policy"],
            "frames_not_waited_for_late_detections": self.frames_not_waited,
            "latency_ms_median": float(np.median(lat)) if lat.size else None,
            "latency_ms_p90": float(np.percentile(lat, 90)) if lat.size else None,
            "process_ms_median": float(np.median(proc)) if proc.size else None,
            "process_cpu_ms_median": float(np.median(self.process_cpu_ms)) if self.process_cpu_ms else None,
            "process_cpu_ms_p90": float(np.percentile(self.process_cpu_ms, 90)) if self.process_cpu_ms else None,
            "detection_delay_ms_median": float(np.median(self.detection_delay_ms)) if self.detection_delay_ms else None,
            "detections_received": self.detections_in,
            "backend": "in_process" if self.split is None else "split",
            "map_updates_applied": self.updates_applied, "map_updates_rejected": self.updates_rejected,
            "map_update_latency_ms_median": float(np.median(self.update_latency_ms)) if self.update_latency_ms else None,
            "loops_closed_split": self.split.n_loops if self.split is not None else None,
            "maps_merged_split": self.split.n_merges if self.split is not None else None,
            "keyframes_moved_by_merges": self.split.n_moved_keyframes if self.split is not None else None,
            "provisional_points_moved_by_merges": self.split.n_moved_provisional if self.split is not None else None,
            "frames_skipped_waiting_for_map": self.split.n_skipped if self.split is not None else None,
            "provisional_points_created": prov.n_created if prov is not None else None,
            "provisional_points_replaced": prov.n_replaced if prov is not None else None,
            "provisional_points_dropped": prov.n_dropped if prov is not None else None,
            "moving_objects_messages": self.movers_out.published if self.movers_out is not None else 0,
            "map_loads": self.loads,
            "load_relocalised_after_s": self._relocalised_after_load_s(),
            "dropped_before_load": self.epochs.dropped,
            "latency_ms": [round(float(v), 2) for v in lat],
        }  # fmt: skip

    def _relocalised_after_load_s(self) -> float | None:
        """After a LoadMap: seconds (frame stamps) from the first frame tracked after it to the frame that
        relocalised in the loaded map; None before a load or while not relocalised."""
        if not self.epochs.epoch_ns or self.split is None:
            return None
        system = self.split.system
        i = system.tracker.loaded_map_relocalised_index
        if i < 0 or not system.records:
            return None
        return (system.records[i].stamp_ns - system.records[0].stamp_ns) * 1e-9

    def diagnostic_values(self) -> dict[str, Any]:
        """Counts and latencies for /diagnostics (no per-frame lists)."""
        s = self.stats()
        keep = ("colour_received", "frames_converted", "poses_published", "unpaired_colour_dropped",
                "unpaired_depth_dropped", "frames_rejected", "frames_without_detections", "frames_dropped_stale",
                "latency_ms_median",
                "latency_ms_p90", "process_ms_median", "process_cpu_ms_median", "detections_received", "map_updates_applied", "map_update_latency_ms_median")  # fmt: skip
        out = {k: s[k] for k in keep}
        out["dropped"] = self.colour_in - self.published_poses
        return out

    def finish(self) -> list[Path]:
        """Process frames still waiting, then write the outputs to `output_dir` (once; no-op without it)."""
        if self._finished:
            return []
        self._finished = True
        while self.queue:
            item = self.queue.pop()
            try:
                self._process(item)
            except RCLError as err:  # shut down: tracked and recorded for the files below, only not published
                self.get_logger().warning(f"tracking: frame {item.stamp_ns} tracked at shutdown, not published ({err})")
        if self.movers is not None and self._movers_stamp_ns and self.context.ok():
            try:
                self.publish_moving_objects(self._movers_stamp_ns)  # the final trajectories
            except Exception as err:  # noqa: BLE001 - shutting down: the file below still has them
                self.get_logger().warning(f"tracking: last moving objects not published ({err})")
        if not self.params["output_dir"] or self.backend is None:
            return []
        from changing_slam_ros.nodes.slam_backend import write_backend_outputs

        out_dir = Path(self.params["output_dir"])
        self.backend.system.settle_refinement()  # tracking.deferred_refinement: the last frames' final poses
        written = write_backend_outputs(out_dir, self.backend, self.stats())
        if self._before_load:
            from changing_slam_ros.io.tum_trajectory import write_tum_trajectory

            for i, traj in enumerate(self._before_load):  # other frames than trajectory.txt's: kept apart
                write_tum_trajectory(out_dir / f"trajectory_online_before_load_{i}.txt", traj)
                written.append(out_dir / f"trajectory_online_before_load_{i}.txt")
        if self.movers is not None:
            from changing_slam_ros.io.moving_objects_file import INDEX_NAME, write_moving_objects

            write_moving_objects(out_dir, self.movers.tracks())
            written.append(out_dir / INDEX_NAME)
        self.get_logger().info(f"tracking: wrote {', '.join(p.name for p in written)} to {self.params['output_dir']}")
        return written

    def destroy_node(self) -> None:
        try:
            self.finish()
        finally:
            super().destroy_node()

    def _log_stats(self) -> None:
        s = self.pairer.stats
        if s.pairs or s.dropped_first or s.dropped_second:
            lat = f", latency median {np.median(self.latency_ms):.0f} ms" if self.latency_ms else ""
            self.get_logger().info(
                f"tracking: {self.frames_in} frames, {s.pairs} colour/depth pairs, unpaired dropped: "
                f"{s.dropped_first} colour, {s.dropped_second} depth, {self.published_poses} poses{lat}"
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


def _warn_if(values: Any) -> str | None:
    lat = values.get("latency_ms_median")
    if lat is not None and lat > 60.0:
        return f"image-to-pose latency median {lat:.0f} ms > 60 ms"
    return None


def main(args: Sequence[str] | None = None) -> int:
    return run_node(lambda argv: TrackingNode(), args)


if __name__ == "__main__":
    raise SystemExit(main())
