"""`detection`: colour image -> `~/detections` (changing_slam_msgs/DetectionArray, stamped with the image's stamp).

Every image it receives but will not detect (`max_rate_hz` skipped it, or it was rejected) is announced on
`~/skipped` (std_msgs/Header, the image's header), so that a tracker waiting for that frame's detections
(`detections_wait_s`) stops waiting at once and tracks it with the earlier ones carried forward.

A lifecycle node: the ONNX session (core.dynamic.detector.Detector) and the image subscription are created in
`on_activate` and released in `on_deactivate`, as yolo_ros does; `main()` configures and activates it at start
(`autostart`). Subscribing only once the model is loaded lets a publisher that waits for subscribers (the lossless
bag player) know that every image it sends will be detected.
Images arrive with sensor-data QoS (best effort, shallow queue): when inference is slower than the camera,
old frames are dropped rather than queued (tracking then carries the last detections forward).
Topics and parameters: docs/nodes.md#detection.

    detection --ros-args -r image:=/camera/rgb/image_color -p intra_op_threads:=2
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import CompressedImage, Image
from std_msgs.msg import Header

from changing_slam_msgs.msg import DetectionArray
from changing_slam_ros.config import find_config, load_yaml, section
from changing_slam_ros.core.dynamic.detector import Detector, DetectorConfig
from changing_slam_ros.errors import SlamError
from changing_slam_ros.nodes.conversions import detections_to_msg, image_to_rgb, stamp_to_ns
from changing_slam_ros.nodes.node_help import NodeHelp, ParamSpec, first_line
from changing_slam_ros.nodes.node_runner import declare_parameters, run_node
from changing_slam_ros.nodes.qos_events import QuietQosEvents


DETECTION_PARAMETERS: tuple[ParamSpec, ...] = (
    ("config", "", "config name (tum_fr3, realsense_d435, ...) or YAML path; its `detector` section"),
    ("model_path", "", "ONNX detector; empty = from the config, else the shipped SSD-MobileNetV2"),
    ("model", "", "shipped detector (ssd_mobilenet_v2_coco, ssd_mobilenet_v2_coco_int8); empty = from the config"),
    ("score_threshold", -1.0, "drop detections below this score; < 0 = from the config (0.3)"),
    ("intra_op_threads", -1, "onnxruntime threads; < 0 = from the config (2)"),
    ("max_rate_hz", 0.0, "detect at most this often by image stamp (an image less than 1/max_rate_hz after "
                         "the last detected one is skipped before decoding); 0 = every image it is free for"),
    ("compressed", False, "subscribe sensor_msgs/CompressedImage on image/compressed instead"),
    ("autostart", True, "configure and activate at start (main() only)"),
    ("reliable_images", False, "reliable image subscription (keep last 1) instead of sensor-data best effort"),
    ("diagnostics_period_s", 5.0, "seconds between /diagnostics reports (0 = off)"),
    ("output_wait_s", 5.0, "on activation, wait up to this long for a subscriber of ~/detections before taking "
                           "images (detections published before discovery matched it are lost); 0 = take at once"),
)  # fmt: skip


class DetectionNode(QuietQosEvents, LifecycleNode):
    """Subscribes `image` (or `image/compressed`), publishes `~/detections`."""

    def __init__(
        self,
        image_qos: QoSProfile = qos_profile_sensor_data,
        detections_qos: QoSProfile | int = 10,
        **node_kwargs: Any,
    ) -> None:
        super().__init__("detection", **node_kwargs)
        self.params = declare_parameters(self, DETECTION_PARAMETERS)
        self._image_qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE) if self.params["reliable_images"] \
            else image_qos  # fmt: skip
        self._detections_qos = detections_qos
        self.detector: Detector | None = None
        self.detector_config = self._detector_config()
        self._pub: Any = None
        self._skipped_pub: Any = None
        self._sub: Any = None
        self._wait_timer: Any = None
        self._wait_started_s = 0.0
        self.frames = 0
        self.images_in = 0
        self.images_skipped_rate = 0  # skipped by max_rate_hz
        self._min_step_ns = round(1e9 / self.params["max_rate_hz"]) if self.params["max_rate_hz"] > 0 else 0
        self._last_detected_ns: int | None = None
        self.latency_ms: list[float] = []
        self.cpu_ms: list[float] = []  # process CPU time per detected frame (load-independent)
        self._started_s = time.monotonic()
        from changing_slam_ros.nodes.diagnostics import NodeDiagnostics

        self.diagnostics = NodeDiagnostics(self, self.params["diagnostics_period_s"])
        self.diagnostics.set_source(self.diagnostic_values)

    def _detector_config(self) -> DetectorConfig:
        p = self.params
        base: dict[str, Any] = {}
        if p["config"]:
            path = find_config(p["config"])
            base = dict(load_yaml(path).get("detector") or {})
            where = f"{path}: detector"
        else:
            where = "detection node parameters"
        if p["model_path"]:
            base["model_path"] = p["model_path"]
        if p["model"]:
            base["model"] = p["model"]
        if p["score_threshold"] >= 0:
            base["score_threshold"] = float(p["score_threshold"])
        if p["intra_op_threads"] >= 0:
            base["intra_op_threads"] = int(p["intra_op_threads"])
        return section(DetectorConfig, base, where)

    # -- lifecycle ------------------------------------------------------------------------------
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._pub = self.create_lifecycle_publisher(
            DetectionArray, "~/detections", self._detections_qos,
            qos_overriding_options=QoSOverridingOptions.with_default_policies(),
        )  # fmt: skip
        self._skipped_pub = self.create_lifecycle_publisher(Header, "~/skipped", self._detections_qos)
        self.get_logger().info("detection: configured")
        return TransitionCallbackReturn.SUCCESS

    def _subscribe_images(self) -> None:
        """The image subscription exists only while the node is active (detector loaded): a lossless player that
        waits for subscribers then never sends an image to a node that would drop it while its model loads."""
        if self.params["compressed"]:
            self._sub = self.create_subscription(CompressedImage, "image/compressed", self.on_image, self._image_qos,
                                                 event_callbacks=SubscriptionEventCallbacks())  # fmt: skip
        else:
            self._sub = self.create_subscription(Image, "image", self.on_image, self._image_qos,
                                                 event_callbacks=SubscriptionEventCallbacks())  # fmt: skip

    def _unsubscribe_images(self) -> None:
        if self._sub is not None:
            self.destroy_subscription(self._sub)
            self._sub = None

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        try:
            self.detector = Detector(self.detector_config)
        except SlamError as err:
            self.get_logger().error(f"detection: {err}")
            return TransitionCallbackReturn.FAILURE
        result = super().on_activate(state)
        if self.params["output_wait_s"] > 0.0 and self._pub.get_subscription_count() == 0:
            self._wait_started_s = time.monotonic()
            self._wait_timer = self.create_timer(0.05, self._check_output_matched)
        else:
            self._start_taking_images()
        return result

    def _check_output_matched(self) -> None:
        """Images are taken once `~/detections` has a subscriber (or `output_wait_s` has passed): a lossless player
        waits for this node's image subscription, so the first frames' detections then reach their subscriber."""
        waited = time.monotonic() - self._wait_started_s
        matched = self._pub is not None and self._pub.get_subscription_count() > 0
        if not matched and waited < self.params["output_wait_s"]:
            return
        self._cancel_wait()
        if not matched:
            self.get_logger().warning(
                f"detection: no subscriber on {self._pub.topic_name} after {waited:.1f} s; detecting anyway")
        self._start_taking_images()

    def _cancel_wait(self) -> None:
        if self._wait_timer is not None:
            self._wait_timer.cancel()
            self.destroy_timer(self._wait_timer)
            self._wait_timer = None

    def _start_taking_images(self) -> None:
        if self.detector is None or self._sub is not None:
            return
        self._subscribe_images()
        self.get_logger().info(
            f"detection: active, model {self.detector.model_path.name} ({self.detector.layout}) on "
            f"{', '.join(self.detector.providers)}, images on {self._sub.topic_name}, publishing {self._pub.topic_name}"
        )

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._cancel_wait()
        self._unsubscribe_images()
        if self.detector is not None:
            self.detector.close()
            self.detector = None
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._cancel_wait()
        self._unsubscribe_images()
        if self._pub is not None:
            self.destroy_lifecycle_publisher(self._pub)
            self._pub = None
        if self._skipped_pub is not None:
            self.destroy_lifecycle_publisher(self._skipped_pub)
            self._skipped_pub = None
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        if self.detector is not None:
            self.detector.close()
            self.detector = None
        return TransitionCallbackReturn.SUCCESS

    # -- work -----------------------------------------------------------------------------------
    def on_image(self, msg: Any) -> None:
        self.images_in += 1
        if self.detector is None:
            return
        stamp_ns = stamp_to_ns(msg.header.stamp)
        if self._rate_capped(stamp_ns):
            self.images_skipped_rate += 1
            self._skipped_pub.publish(msg.header)
            return
        t0 = time.perf_counter()
        c0 = time.process_time()
        topic = self._sub.topic_name if self._sub is not None else "image"
        try:
            rgb = image_to_rgb(msg, topic)
        except SlamError as err:
            self.get_logger().warning(f"detection: image rejected: {err}", throttle_duration_sec=5.0)
            self._skipped_pub.publish(msg.header)
            return
        self._last_detected_ns = stamp_ns
        detections = self.detector.detect(rgb, stamp_ns)
        self._pub.publish(detections_to_msg(detections, msg.header.frame_id))
        self.frames += 1
        self.latency_ms.append(1000.0 * (time.perf_counter() - t0))
        self.cpu_ms.append(1000.0 * (time.process_time() - c0))
        if self.frames % 100 == 0:
            recent = sorted(self.latency_ms[-100:])
            self.get_logger().info(
                f"detection: {self.frames} frames, median {recent[len(recent) // 2]:.1f} ms per frame"
            )


    def _rate_capped(self, stamp_ns: int) -> bool:
        """max_rate_hz: the image comes less than one period after the last detected one (a stamp that goes back,
        a replayed bag looping, resets the cap)."""
        if not self._min_step_ns or self._last_detected_ns is None:
            return False
        step_ns = stamp_ns - self._last_detected_ns
        return 0 <= step_ns < self._min_step_ns - self._min_step_ns // 10  # 10 % slack for stamp jitter

    def diagnostic_values(self) -> dict[str, Any]:
        """Images in, frames detected, the rate since the first frame and per-frame time, for /diagnostics."""
        from changing_slam_ros.nodes.diagnostics import summarise_ms

        out: dict[str, Any] = {"images_received": self.images_in, "frames_detected": self.frames,
                               "images_skipped_rate": self.images_skipped_rate}
        out.update(summarise_ms(self.latency_ms, "detect"))
        out.update(summarise_ms(self.cpu_ms, "detect_cpu"))
        return out


NODE_HELP = NodeHelp("detection", first_line(__doc__), DETECTION_PARAMETERS)


def main(args: Sequence[str] | None = None) -> int:
    def make(argv: list[str]) -> DetectionNode:
        node = DetectionNode()
        if node.params["autostart"]:
            node.trigger_configure()
            node.trigger_activate()
        return node

    return run_node(make, args, node_help=NODE_HELP)


if __name__ == "__main__":
    raise SystemExit(main())
