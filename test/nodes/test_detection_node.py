"""detection node in-process: a real TUM fr3 walking frame in, people out, stamped with the image's stamp."""

from __future__ import annotations

import time

import numpy as np
import pytest
from helpers import FR3_WALKING_FRAMES, require

pytestmark = [pytest.mark.ros, pytest.mark.slow]  # ~30 s: model load and first inference on a busy CPU

pytest.importorskip("rclpy")
pytest.importorskip("changing_slam_msgs.msg", reason="interfaces not built (tools/build_interfaces.sh)")

import cv2  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.lifecycle import TransitionCallbackReturn  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import qos_profile_sensor_data  # noqa: E402
from sensor_msgs.msg import Image  # noqa: E402

from changing_slam_msgs.msg import DetectionArray  # noqa: E402
from changing_slam_ros.nodes.conversions import rgb_to_image, stamp_to_ns  # noqa: E402
from changing_slam_ros.nodes.detection_node import DetectionNode  # noqa: E402

STAMP_NS = 1341846313_553992000


def test_detection_publishes_the_people_of_a_walking_frame_with_the_image_stamp(ros_context):
    frame = require(FR3_WALKING_FRAMES) / "1341846313.553992.png"
    rgb = np.ascontiguousarray(cv2.imread(str(frame))[:, :, ::-1])
    node = DetectionNode(
        context=ros_context,
        parameter_overrides=[Parameter("intra_op_threads", value=1)],
        cli_args=["--ros-args", "-r", "image:=/camera/rgb/image_color"],
    )
    assert node.trigger_configure() == TransitionCallbackReturn.SUCCESS
    assert node.trigger_activate() == TransitionCallbackReturn.SUCCESS
    peer = Node("camera", context=ros_context)
    pub = peer.create_publisher(Image, "/camera/rgb/image_color", qos_profile_sensor_data)
    got: list[DetectionArray] = []
    peer.create_subscription(DetectionArray, "/detection/detections", got.append, 10)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    executor.add_node(peer)

    deadline = time.monotonic() + 30.0
    while not got and time.monotonic() < deadline:
        if pub.get_subscription_count() > 0:
            pub.publish(rgb_to_image(rgb, STAMP_NS, "openni_rgb_optical_frame"))
        for _ in range(5):
            executor.spin_once(timeout_sec=0.1)
    assert got, "no DetectionArray within 30 s"
    msg = got[0]
    assert stamp_to_ns(msg.header.stamp) == STAMP_NS and msg.header.frame_id == "openni_rgb_optical_frame"
    assert (msg.width, msg.height) == (640, 480)
    people = [d for d in msg.detections if d.class_id == 0]
    assert len(people) >= 1 and max(d.score for d in people) > 0.5  # the frame shows two walking people
    for d in msg.detections:
        assert 0 <= d.x and d.x + d.w <= 640.5 and 0 <= d.y and d.y + d.h <= 480.5 and d.w > 0 and d.h > 0

    assert node.trigger_deactivate() == TransitionCallbackReturn.SUCCESS and node.detector is None
    executor.shutdown()
    node.destroy_node()
    peer.destroy_node()


def test_images_are_taken_only_once_the_detections_have_a_subscriber_or_the_wait_is_over(ros_context):
    """A detection published before discovery matched its subscriber is lost; a lossless player waits for this
    node's image subscription, so the node makes it only once ~/detections has a subscriber (or after
    output_wait_s, with a warning)."""
    node = DetectionNode(context=ros_context, parameter_overrides=[
        Parameter("intra_op_threads", value=1), Parameter("output_wait_s", value=1.5)])
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)

    def spin_until(done, seconds):  # noqa: ANN001, ANN202
        deadline = time.monotonic() + seconds
        while not done() and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        return done()

    assert node.trigger_configure() == TransitionCallbackReturn.SUCCESS
    assert node.trigger_activate() == TransitionCallbackReturn.SUCCESS
    t0 = time.monotonic()
    assert not spin_until(lambda: node._sub is not None, 0.3), "images taken with nobody to receive detections"
    peer = Node("consumer", context=ros_context)
    peer.create_subscription(DetectionArray, "/detection/detections", lambda msg: None, 10)
    assert spin_until(lambda: node._sub is not None, 10.0), "no image subscription after a subscriber came"
    assert time.monotonic() - t0 < 1.5 or node._pub.get_subscription_count() > 0
    assert node.trigger_deactivate() == TransitionCallbackReturn.SUCCESS and node._sub is None
    peer.destroy_node()
    assert spin_until(lambda: node._pub.get_subscription_count() == 0, 10.0)

    assert node.trigger_activate() == TransitionCallbackReturn.SUCCESS  # nobody listens: taken after the wait
    t0 = time.monotonic()
    assert spin_until(lambda: node._sub is not None, 10.0)
    assert time.monotonic() - t0 >= 1.4
    assert node.trigger_deactivate() == TransitionCallbackReturn.SUCCESS
    executor.shutdown()
    node.destroy_node()


def test_the_model_parameter_picks_a_shipped_detector_and_model_path_still_wins(ros_context, tmp_path):
    node = DetectionNode(context=ros_context, parameter_overrides=[Parameter("model", value="ssd_mobilenet_v2_coco_int8")])
    assert node.detector_config.model == "ssd_mobilenet_v2_coco_int8" and node.detector_config.model_path == ""
    node.destroy_node()
    node = DetectionNode(context=ros_context, parameter_overrides=[
        Parameter("model", value="ssd_mobilenet_v2_coco_int8"), Parameter("model_path", value=str(tmp_path / "x.onnx"))])
    assert node.detector_config.model_path == str(tmp_path / "x.onnx")  # a path overrides the shipped name
    node.destroy_node()


def test_max_rate_hz_detects_every_other_frame_of_a_30_hz_stream_by_stamp_and_a_busy_node_takes_what_comes(ros_context):
    """max_rate_hz 15 on 30 Hz images: frames 0, 2, 4, ... are detected, the others skipped before decoding; when
    the node was busy and the next image it sees is already two periods on, that one is detected (no catching
    up), and a stamp that goes back (a looping bag) is detected at once. Every image skipped (and one rejected)
    is announced on ~/skipped with its own header, so a tracker stops waiting for its detections."""
    from changing_slam_ros.core.dynamic.detector import DetectionSet

    node = DetectionNode(context=ros_context, parameter_overrides=[Parameter("max_rate_hz", value=15.0)])
    detected: list[int] = []
    decoded: list[int] = []

    class Stub:
        def detect(self, rgb, stamp_ns):  # noqa: ANN001, ANN202
            detected.append(stamp_ns)
            return DetectionSet(stamp_ns, (), rgb.shape[1], rgb.shape[0])

    class Sink:
        def publish(self, msg):  # noqa: ANN001, ANN202
            decoded.append(stamp_to_ns(msg.header.stamp))

    skipped: list[int] = []

    class SkipSink:
        def publish(self, header):  # noqa: ANN001, ANN202
            skipped.append(stamp_to_ns(header.stamp))

    node.detector, node._pub, node._skipped_pub = Stub(), Sink(), SkipSink()
    rgb = np.zeros((24, 32, 3), np.uint8)
    period_ns = 33_333_333
    t0 = STAMP_NS
    for k in [0, 1, 2, 3, 4, 7, 8, 9, 10, 0, 1]:  # frames 5 and 6 never reach it (busy); then the bag loops
        node.on_image(rgb_to_image(rgb, t0 + k * period_ns, "camera"))
    assert [(s - t0) // period_ns for s in detected] == [0, 2, 4, 7, 9, 0]
    assert decoded == detected and node.images_skipped_rate == 5
    assert node.diagnostic_values()["images_skipped_rate"] == 5
    assert [(s - t0) // period_ns for s in skipped] == [1, 3, 8, 10, 1]  # each skipped image, none detected
    bad = rgb_to_image(rgb, t0 + 40 * period_ns, "camera")
    bad.encoding = "yuv422_weird"
    node.on_image(bad)  # rejected: no detections will come for it either
    assert skipped[-1] == t0 + 40 * period_ns and len(detected) == 6
    node.detector = None
    node.destroy_node()
