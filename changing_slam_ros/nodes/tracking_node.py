"""`tracking`: colour + depth + camera_info (+ detections) -> camera pose, path, TF, keyframes, semantic map.

    python -m changing_slam_ros.nodes.tracking_node --ros-args -p config:=tum_fr1 -p output_dir:=/tmp/out

Pairs colour and depth (`nodes/stamp_sync.py`), lets each frame wait for its detections
(`nodes/tracking_detections.py`), picks the frames to track (`frame_policy`, `nodes/frame_queue.py`) and runs
them through the SLAM core: in this process (`in_process_backend:=true`, `nodes/slam_backend.py`) or against a
replica of the map that local_mapping owns (`nodes/tracking_replica.py`, `nodes/split_backend.py`). Outputs are in
`nodes/tracking_outputs.py`, counts in `nodes/tracking_stats.py`; on shutdown with `output_dir` set the
trajectories, keyframes, semantic map and tracking_stats.json are written atomically.
Topics, parameters and the waiting rules: docs/nodes.md#tracking.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rclpy._rclpy_pybind11 import RCLError  # a publish after the context shut down
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from std_msgs.msg import Header

from changing_slam_msgs.msg import DetectionArray, LoopCorrection, MapObjectArray, MapUpdate
from changing_slam_msgs.msg import ObjectStateArray
from changing_slam_msgs.msg import Keyframe as KeyframeMsg
from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.geometry.rep105 import PoseCovarianceModel
from changing_slam_ros.core.recent_values import RecentValues
from changing_slam_ros.core.slam.localization import Mode
from changing_slam_ros.core.features.rgbd_frame import RgbdFrame
from changing_slam_ros.core.slam.tracking import TrackingState
from changing_slam_ros.errors import SlamError
from changing_slam_ros.nodes.conversions import (
    camera_info_to_intrinsics,
    image_to_depth_m,
    image_to_rgb,
    keyframe_to_msg,
    make_header,
    stamp_to_ns,
)
from changing_slam_ros.nodes.keep_newest import keep_newest as _keep_newest
from changing_slam_ros.nodes.frame_queue import FrameQueue, PendingFrame
from changing_slam_ros.nodes.map_load import LoadEpochs
from changing_slam_ros.nodes.node_help import NodeHelp, first_line
from changing_slam_ros.nodes.node_runner import declare_parameters, run_node
from changing_slam_ros.nodes.qos_events import QuietQosEvents
from changing_slam_ros.nodes.qos_profiles import LATCHED
from changing_slam_ros.nodes.stamp_sync import ApproximatePairer
from changing_slam_ros.nodes.tracking_outputs import MoverOutputs, PoseOutputs, debug_image
from changing_slam_ros.nodes.tracking_initial_pose import InitialPoseInput
from changing_slam_ros.nodes.tracking_mode import ModeControl
from changing_slam_ros.nodes.tracking_tf import Rep105Outputs
from changing_slam_ros.nodes.tracking_detections import DetectionInputs
from changing_slam_ros.nodes.tracking_params import TRACKING_PARAMETERS
from changing_slam_ros.nodes.tracking_replica import ReplicaInputs
from changing_slam_ros.nodes.tracking_stats import TrackingStats, _warn_if



class TrackingNode(DetectionInputs, ReplicaInputs, TrackingStats, QuietQosEvents, Node):
    """Colour + depth (+ detections) in, camera pose and keyframes out; see docs/nodes.md#tracking."""

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
        self.frames_no_camera = 0  # converted but skipped: no camera_info (nor config intrinsics) yet
        self.frames_lost = 0  # tracked without a pose (not initialised, lost, relocalising)
        # a colour / depth stamp not newer than the newest received: a player re-sending after a restart
        self.duplicates = {"colour": 0, "depth": 0}
        self._newest_ns = {"colour": -1, "depth": -1}
        self._warned_backward = {"colour": False, "depth": False}  # a jump back is warned about once
        self.latency_ms = RecentValues()  # per frame, the recent ones kept (core/recent_values.py); image -> pose
        self.process_ms = RecentValues()
        self.process_cpu_ms = RecentValues()  # process CPU time per processed frame (load-independent)
        self.detection_delay_ms = RecentValues()  # colour received -> its detections received
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
        self.carry_cpu_ms = RecentValues()  # CPU of carrying boxes forward (with flow: measuring their motion)
        self.frames_with_carried_detections = 0
        self._finished = False

        self.backend: Any = None
        self.split: Any = None  # split_backend.TrackingSide when the map comes from local_mapping
        self.config_camera: CameraIntrinsics | None = None
        self.updates_applied = 0
        self.updates_rejected = 0
        self.detections_in = 0
        self.update_latency_ms = RecentValues()  # keyframe published -> its map update applied
        self._awaiting: dict[str, Any] | None = None  # wait_for_map_updates: what the held ack waits for
        self.map_update_waits_timed_out = 0  # held acks sent after map_update_timeout_s without update / verdict
        self.keyframes_resent = 0  # awaited keyframes sent again after a node's restart (`_check_wait`)
        self._kf_sent_s: dict[int, float] = {}
        self._relays_seen: set[int] = set()
        self._peers_since_s: float | None = None  # wait_for_map_updates: when frames began to wait for the peers
        self._peers_matched = False
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
        self.update_sub = self.create_subscription(MapUpdate, "/local_mapping/map_updates", self.on_map_update, 10)
        self.loop_sub = self.create_subscription(LoopCorrection, "/loop_closing/loop_corrections",
                                                 self.on_loop_correction, 10)  # fmt: skip
        self.create_subscription(ObjectStateArray, "/object_map/object_states", self.on_object_states, 10)

        self.frames_out = Rep105Outputs(self, p)  # TF: map -> odom (-> base_frame with visual odometry)
        self.poses_out = PoseOutputs(self, output_qos, p["map_frame"], self.frames_out.base_frame, p["path_max_poses"])
        self.covariance = PoseCovarianceModel(p["pose_sigma_m"], p["pose_sigma_rad"], p["pose_sigma_inliers"])
        self._n_merges = 0
        objects = None if self.backend is None or self.backend.objects is None else self.backend.objects
        self.mode_control = ModeControl(self, p["mode"], lambda: None if self.backend is None else self.backend.system,
                                        None if objects is None else objects.config.association, p["map_frame"],
                                        output_qos)  # fmt: skip
        self.initial_pose = InitialPoseInput(self, self.mode_control.system, self.frames_out.base_cam, p["map_frame"],
                                             p["initial_pose_radius_m"], p["initial_pose_angle_deg"])  # fmt: skip
        if self.mode_control.mode is Mode.LOCALIZATION and self.backend is not None:
            ok, why = self.mode_control.apply(Mode.LOCALIZATION)
            if not ok:
                raise SlamError(f"tracking: parameter mode: {why}")
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
            self.backend.system.start_from_map(loaded.atlas, loaded.next_keyframe_id, loaded.objects,
                                               Mode.parse(self.params["mode"]))  # fmt: skip
        atlas = self.backend.system.atlas
        self.get_logger().info(f"tracking: {atlas.n_keyframes} keyframes in {len(atlas.maps)} maps loaded from "
                               f"{map_file}; relocalising in map {atlas.current.id} first")  # fmt: skip

    # -- inputs ---------------------------------------------------------------------------------
    def on_colour(self, msg: Any) -> None:
        stamp_ns = stamp_to_ns(msg.header.stamp)
        if self._duplicate("colour", stamp_ns):
            self._ack(msg.header)  # a lossless player waits for it before it sends the next frame
            return
        self.colour_in += 1
        self._received_s[stamp_ns] = time.monotonic()
        _keep_newest(self._received_s, 200)
        for t_rgb, rgb_msg, _t_d, depth_msg in self.pairer.add_first(stamp_ns, msg):
            self.on_frame(t_rgb, rgb_msg, depth_msg)
        self._warn_if_unpaired()

    def on_depth(self, msg: Any) -> None:
        stamp_ns = stamp_to_ns(msg.header.stamp)
        if self._duplicate("depth", stamp_ns):
            return
        for t_rgb, rgb_msg, _t_d, depth_msg in self.pairer.add_second(stamp_ns, msg):
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

    def on_object_states(self, msg: ObjectStateArray) -> None:
        pass  # Point activity comes from the object layer (in local_mapping, or in-process), not from object_map.

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
            if not self._awaiting["update"] and "resend_at" in self._awaiting:  # after a restart (`_check_wait`)
                due.append(self._awaiting["resend_at"])
        if self._peers_since_s is not None and not self._peers_matched:
            due.append(time.monotonic() + 0.05)  # poll the DDS matches (no event reports them)
        if not due:
            self._drain_timer.cancel()
            return
        delay_s = max(min(due) - time.monotonic(), 0.001)
        self._drain_timer.timer_period_ns = round(delay_s * 1e9)
        self._drain_timer.reset()

    def _drain_pending(self) -> None:
        self._check_wait()
        if self._holding_for_camera_info() or self._holding_for_peers():
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

    def _holding_for_peers(self) -> bool:
        """wait_for_map_updates: frames wait until local_mapping and loop_closing are matched both ways (their
        keyframe subscriptions, their update and verdict publishers). A keyframe published before its
        subscription matched is lost (volatile QoS), and its held acknowledgement would wait out
        `map_update_timeout_s`. After `peers_wait_s` without them, frames go on with a warning."""
        if self._peers_matched or self.split is None or not self.params["wait_for_map_updates"] or not len(self.queue):
            return False
        now = time.monotonic()
        if self._peers_since_s is None:
            self._peers_since_s = now
        missing = self._missing_peers()
        if not missing:
            self._peers_matched = True
            return False
        if now - self._peers_since_s > self.params["peers_wait_s"]:
            self._peers_matched = True
            self.get_logger().warning(f"tracking: {', '.join(missing)} not matched after "
                                      f"{self.params['peers_wait_s']} s; tracking without them")  # fmt: skip
            return False
        self._warn_once("held_for_peers", f"tracking: holding frames until {', '.join(missing)} are matched")
        return True

    def _missing_peers(self) -> list[str]:
        missing = []
        if self.keyframe_pub.get_subscription_count() < self.params["keyframe_subscribers"]:
            missing.append(f"{self.params['keyframe_subscribers']} subscriptions of ~/keyframes")
        if self.update_sub.get_publisher_count() < 1:
            missing.append("a publisher of /local_mapping/map_updates")
        if self.loop_sub.get_publisher_count() < 1:
            missing.append("a publisher of /loop_closing/loop_corrections")
        return missing

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
                self.frames_no_camera += 1
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
        self.frames_out.place_map(self.backend.system)
        if self.split is not None:
            out, packet = self.split.process(frame, used)
            if out is None:  # a new map waits for its first points from local_mapping
                self._warn_once("waiting_map", "tracking: a new map waits for its first map update; frames skipped")
                self._ack(item.rgb_msg.header)
                return
        else:
            out = self.backend.system.process(frame, used)
        if out.state == TrackingState.OK and out.T_world_cam is not None:
            # A relocalised frame or a new map jumps at once; a loop correction or a merge moves the map after
            # this frame was tracked, so the next frame is the first in the moved map (`_rebuild_path`, below).
            system = self.backend.system
            self.publish_pose(item.stamp_ns, out.T_world_cam, out.n_inliers, out.relocalised or out.new_map,
                              system.tracker.velocity)  # fmt: skip
            if len(system.merges) != self._n_merges:
                self._n_merges = len(system.merges)
                self.frames_out.map_moved()
            self.latency_ms.append((time.monotonic() - item.received_s) * 1e3)
        else:
            self.frames_lost += 1
            self.frames_out.on_lost(item.stamp_ns)
        self.mode_control.after_frame(item.stamp_ns, out)
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

    def publish_pose(self, stamp_ns: int, T_world_cam: Any, n_inliers: int = 0, map_moved: bool = False,  # noqa: N803
                     T_prev_cur_cam: Any = None) -> None:  # noqa: N803  # fmt: skip
        """TF (`Rep105Outputs`), then pose, odometry with its covariance from `n_inliers`, and path (`PoseOutputs`),
        of the base frame (the camera's while its mounting is unknown). `map_moved`: the pose is not continuous
        with the last (its jump goes into map -> odom); `T_prev_cur_cam`: the camera motion tracking measured."""
        T_map_pose, child = self.frames_out.on_tracked(stamp_ns, T_world_cam, map_moved, T_prev_cur_cam)  # noqa: N806
        self.poses_out.publish(stamp_ns, T_map_pose, child, self.covariance.covariance(n_inliers))
        self.published_poses += 1

    def _rebuild_path(self) -> None:
        """After a loop closure: the path becomes the optimised (final) trajectory so far; the map moved under
        the robot (the next pose's jump goes into map -> odom)."""
        self.frames_out.map_moved()
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

    def work_pending(self) -> str:
        """What a stop still waits for (`node_runner.drain_work`): the map update and loop verdict of the last
        keyframe sent (wait_for_map_updates) while local_mapping and loop_closing are there to send them, so its
        map is in the trajectory written; "" when nothing."""
        senders = (self.update_sub, self.loop_sub) if self.split is not None else ()
        if self._awaiting is not None and all(self.count_publishers(s.topic_name) > 0 for s in senders):
            return f"the map update and loop verdict of keyframe {self._awaiting['kf']}"
        return ""

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

    def _ack(self, header: Header) -> None:
        if self.ack_pub is not None:
            self.ack_pub.publish(Header(stamp=header.stamp, frame_id=self.get_name()))

    def _warn_once(self, key: str, text: str) -> None:
        if key not in self._warned:
            self._warned.add(key)
            self.get_logger().warning(text)


NODE_HELP = NodeHelp("tracking", first_line(__doc__), TRACKING_PARAMETERS)


def main(args: Sequence[str] | None = None) -> int:
    return run_node(lambda argv: TrackingNode(), args, node_help=NODE_HELP)


if __name__ == "__main__":
    raise SystemExit(main())
