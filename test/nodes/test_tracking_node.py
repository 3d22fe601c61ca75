"""The tracking node with its in-process backend, in-process: the bundled fr1 bag through a lossless bag_player."""

from __future__ import annotations


import numpy as np
import pytest

pytestmark = pytest.mark.ros

pytest.importorskip("rclpy")
pytest.importorskip("changing_slam_msgs.msg", reason="interfaces not built (tools/build_interfaces.sh)")

from geometry_msgs.msg import PoseStamped  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import QoSProfile  # noqa: E402
from tf2_msgs.msg import TFMessage  # noqa: E402

from sensor_msgs.msg import Image  # noqa: E402

from changing_slam_msgs.msg import Detection, DetectionArray  # noqa: E402
from changing_slam_msgs.msg import Keyframe as KeyframeMsg  # noqa: E402
from changing_slam_ros.core.geometry.trajectory import Trajectory  # noqa: E402
from changing_slam_ros.eval.ate import ate  # noqa: E402
from changing_slam_ros.io.dataset import open_dataset  # noqa: E402
from changing_slam_ros.io.tum_trajectory import read_tum_trajectory  # noqa: E402
from changing_slam_ros.nodes import conversions as cv  # noqa: E402
from changing_slam_ros.nodes.tracking_node import TrackingNode  # noqa: E402
from helpers import lossless_player, spin_until  # noqa: E402


def test_tracking_node_poses_on_the_fr1_bag_match_ground_truth_and_follow_rep105(ros_context, tmp_path):
    from helpers import REPO, require

    bag = require(REPO / "bags" / "tum_fr1_xyz_first10.mcap")
    out = tmp_path / "out"
    tracking = TrackingNode(context=ros_context, parameter_overrides=[
        Parameter("config", value="tum_fr1"), Parameter("ack_topic", value="/bag_player/ack"),
        Parameter("in_process_backend", value=True),
        Parameter("output_dir", value=str(out)), Parameter("camera_frame", value="camera_link"),
    ])  # fmt: skip
    player = lossless_player(ros_context, bag)
    probe = Node("probe", context=ros_context)
    poses: list[PoseStamped] = []
    tfs: list[TFMessage] = []
    keyframes: list[KeyframeMsg] = []
    probe.create_subscription(PoseStamped, "/tracking/pose", poses.append, 100)
    probe.create_subscription(TFMessage, "/tf", tfs.append, 100)
    probe.create_subscription(KeyframeMsg, "/tracking/keyframes", keyframes.append, QoSProfile(depth=100))
    executor = SingleThreadedExecutor(context=ros_context)
    for node in (tracking, probe, player):
        executor.add_node(node)
    result = player.play(executor)
    assert result.completed and result.ack_timeouts == 0
    spin_until(executor, lambda: len(poses) >= 9 and len(tfs) >= 9, 5.0)

    # Every one of the 9 frames tracked, no frame dropped in lossless mode.
    assert tracking.frames_in == 9 and len(poses) == 9
    gt = open_dataset(bag, "tum_fr1").groundtruth
    stamps = np.array([cv.stamp_to_ns(p.header.stamp) * 1e-9 for p in poses])
    est = Trajectory.from_poses(stamps, np.array([cv.pose_to_matrix(p.pose) for p in poses]))
    online = ate(gt, est)
    # Offline `changing-slam run` on the same bag: 0.36 cm. The node runs the same system on the same frames.
    assert online.stats.rmse < 0.01 and len(online.errors_m) == 9
    # Camera moves ~2 cm over these 0.6 s: the estimate is not a constant pose.
    assert np.linalg.norm(est.positions[-1] - est.positions[0]) > 0.005

    # REP-105: map -> odom (identity while there is no separate odometry), odom -> camera = the pose.
    assert len(tfs) == 9
    by_stamp = {cv.stamp_to_ns(m.transforms[0].header.stamp): m.transforms for m in tfs}
    for pose in poses:
        tf = by_stamp[cv.stamp_to_ns(pose.header.stamp)]
        assert [(t.header.frame_id, t.child_frame_id) for t in tf] == [("map", "odom"), ("odom", "camera_link")]
        assert tf[0].transform.translation.x == 0.0 and tf[0].transform.rotation.w == 1.0
        assert tf[1].transform.translation.x == pytest.approx(pose.pose.position.x)
        assert tf[1].transform.rotation.w == pytest.approx(pose.pose.orientation.w)
    assert keyframes and keyframes[0].id == 0 and len(keyframes[0].descriptors) == 32 * len(keyframes[0].depths)

    executor.shutdown()
    tracking.destroy_node()  # writes the outputs
    final = read_tum_trajectory(out / "trajectory.txt")
    assert len(final) == 9 and ate(gt, final).stats.rmse < 0.01
    stats = (out / "tracking_stats.json").read_text()
    assert '"poses_published": 9' in stats and '"latency_ms_median"' in stats
    player.destroy_node()
    probe.destroy_node()


def test_tracking_node_uses_the_detections_stamped_for_each_frame(ros_context, tmp_path):
    """A stand-in detection node answers every colour image with a person box over its left third, a little
    later; tracking waits for it (detections_required), drops the keypoints inside and still tracks."""
    from helpers import REPO, require

    bag = require(REPO / "bags" / "tum_fr1_xyz_first10.mcap")
    tracking = TrackingNode(context=ros_context, parameter_overrides=[
        Parameter("config", value="tum_fr1"), Parameter("ack_topic", value="/bag_player/ack"),
        Parameter("in_process_backend", value=True),
        Parameter("detections_required", value=True), Parameter("detections_wait_s", value=30.0),
    ])  # fmt: skip
    player = lossless_player(ros_context, bag)
    detector = Node("fake_detection", context=ros_context)
    det_pub = detector.create_publisher(DetectionArray, "/detection/detections", 10)
    waiting: list[Image] = []
    detector.create_subscription(Image, "/camera/rgb/image_color", waiting.append, 10)
    debug: list[Image] = []
    poses: list[PoseStamped] = []
    detector.create_subscription(Image, "/tracking/debug_image", debug.append, 10)
    detector.create_subscription(PoseStamped, "/tracking/pose", poses.append, 100)

    def answer() -> None:  # one detection message per colour image, published from a timer (later than the image)
        while waiting:
            img = waiting.pop(0)
            msg = DetectionArray(header=img.header, width=img.width, height=img.height)
            msg.detections.append(Detection(x=0.0, y=0.0, w=img.width / 3.0, h=float(img.height), class_id=0, score=0.9))
            det_pub.publish(msg)

    detector.create_timer(0.05, answer)
    executor = SingleThreadedExecutor(context=ros_context)
    for node in (tracking, detector, player):
        executor.add_node(node)
    assert spin_until(executor, lambda: tracking.debug_pub.get_subscription_count() > 0)
    result = player.play(executor)
    assert result.completed and result.ack_timeouts == 0
    spin_until(executor, lambda: len(poses) >= 9 and len(debug) >= 9, 5.0)
    assert tracking.frames_without_detections == 0 and len(tracking.detection_delay_ms) == 9
    # About a third of the keypoints lay inside the person box and were not used.
    kept = tracking.backend.dynamic.kept_fraction()
    assert 0.45 < kept < 0.85
    gt = open_dataset(bag, "tum_fr1").groundtruth
    stamps = np.array([cv.stamp_to_ns(p.header.stamp) * 1e-9 for p in poses])
    est = Trajectory.from_poses(stamps, np.array([cv.pose_to_matrix(p.pose) for p in poses]))
    assert len(poses) == 9 and ate(gt, est).stats.rmse < 0.015
    # Debug image: the box edge in red, used keypoints (static class) in green, none inside the box.
    img = cv.image_to_rgb(debug[-1])
    green = (img[:, :, 0] == 0) & (img[:, :, 1] == 220) & (img[:, :, 2] == 0)
    assert green[:, 640 // 3 + 3:].sum() > 200 and green[:, : 640 // 3 - 3].sum() < 0.05 * green.sum()
    assert (img[:, 640 // 3, 0] == 255).sum() > 400  # the box's right edge (x = 213), red
    executor.shutdown()
    for node in (tracking, detector, player):
        node.destroy_node()


def test_tracking_node_rejects_malformed_images_and_survives_nan_depth(ros_context):
    import cv2
    from helpers import FR1_XYZ_10, require

    root = require(FR1_XYZ_10)
    row = next(ln.split() for ln in (root / "associations.txt").read_text().splitlines() if ln and ln[0] != "#")
    rgb = np.ascontiguousarray(cv2.imread(str(root / row[1]), cv2.IMREAD_COLOR)[:, :, ::-1])
    depth = cv2.imread(str(root / row[3]), cv2.IMREAD_UNCHANGED).astype(np.float32) / 5000
    depth[100:200, 100:300] = np.nan  # NaN = no reading, not a crash
    tracking = TrackingNode(context=ros_context, parameter_overrides=[Parameter("config", value="tum_fr1"),
                                                                         Parameter("in_process_backend", value=True)])
    assert tracking.intrinsics_from == "config"  # TUM bags carry ROS default intrinsics; the config's are used
    probe = Node("probe", context=ros_context)
    colour_pub = probe.create_publisher(Image, "/camera/rgb/image_color", 10)
    depth_pub = probe.create_publisher(Image, "/camera/depth/image", 10)
    poses: list[PoseStamped] = []
    probe.create_subscription(PoseStamped, "/tracking/pose", poses.append, 10)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(tracking)
    executor.add_node(probe)
    assert spin_until(executor, lambda: colour_pub.get_subscription_count() > 0 and depth_pub.get_subscription_count() > 0)

    def send(i: int, colour: Image, depth_msg: Image) -> None:
        stamp = cv.ns_to_stamp(1_000_000_000 * (i + 1))
        colour.header.stamp = stamp
        depth_msg.header.stamp = stamp
        colour_pub.publish(colour)
        depth_pub.publish(depth_msg)
        spin_until(executor, lambda: tracking.frames_in + tracking.frames_rejected > i, 20.0)

    good_depth = cv.depth_to_image(depth, 0, "cam")
    send(0, cv.rgb_to_image(rgb, 0, "cam"), good_depth)
    bad_encoding = cv.rgb_to_image(rgb, 0, "cam")
    bad_encoding.encoding = "yuv422_weird"
    send(1, bad_encoding, cv.depth_to_image(depth, 0, "cam"))
    truncated = cv.rgb_to_image(rgb, 0, "cam")
    truncated.data = truncated.data[: len(truncated.data) // 2]
    send(2, truncated, cv.depth_to_image(depth, 0, "cam"))
    small_depth = cv.depth_to_image(np.ascontiguousarray(depth[::2, ::2]), 0, "cam")
    send(3, cv.rgb_to_image(rgb, 0, "cam"), small_depth)  # colour and depth sizes differ
    assert (tracking.frames_in, tracking.frames_rejected) == (1, 3)
    assert spin_until(executor, lambda: poses) and len(poses) == 1  # the NaN-depth frame initialised the map
    executor.shutdown()
    tracking.destroy_node()
    probe.destroy_node()


@pytest.mark.parametrize("policy", ["latest", "all"])
def test_frames_whose_detections_will_not_come_are_tracked_at_once_and_latest_drops_those_past_their_wait(ros_context, policy):
    """Four fr1 frames wait (60 s) for their detections. The detector announces it skips frame 0 (its rate cap):
    frame 0 is tracked at once with no detections. Frame 3's detections come next: the detector works in order,
    so none will come for frames 1 and 2, and all three are tracked in order, with both policies, since none is
    past its wait. With a short wait (50 ms) that is over, `latest` tracks the newest frame and drops the older
    ones (real time: no queue behind them); `all` tracks every one."""
    import itertools
    import time

    from helpers import FR1_XYZ_10, require

    src = open_dataset(require(FR1_XYZ_10), "tum_fr1")
    frames = list(itertools.islice(iter(src), 7))

    def node_waiting(wait_s: float) -> TrackingNode:
        node = TrackingNode(context=ros_context, parameter_overrides=[
            Parameter("config", value="tum_fr1"), Parameter("in_process_backend", value=True),
            Parameter("detections_required", value=True), Parameter("detections_wait_s", value=wait_s),
            Parameter("frame_policy", value=policy), Parameter("debug_image", value=False),
        ])  # fmt: skip
        node.on_camera_info(cv.intrinsics_to_camera_info(src.camera, frames[0].stamp_ns, "camera"))
        return node

    def frame(node: TrackingNode, k: int) -> None:
        node.on_colour(cv.rgb_to_image(frames[k].rgb, frames[k].stamp_ns, "camera"))
        node.on_depth(cv.depth_to_image(frames[k].depth_m, frames[k].stamp_ns, "camera"))

    node = node_waiting(60.0)
    for k in range(4):
        frame(node, k)
    assert node.frames_in == 0 and len(node.queue) == 4  # all wait for their detections
    node.on_detections_skipped(cv.make_header(frames[0].stamp_ns, "camera"))
    assert node.frames_in == 1 and node.detections_skipped_in == 1 and len(node.queue) == 3
    node.on_detections(DetectionArray(header=cv.make_header(frames[3].stamp_ns, "camera"), detections=[]))
    assert (node.frames_in, node.frames_dropped_stale, node.published_poses) == (4, 0, 4)
    assert [r.stamp_ns for r in node.backend.system.records] == [f.stamp_ns for f in frames[:4]]
    assert node.frames_without_detections == 3 and node.stats()["detections_skipped_received"] == 1
    node.destroy_node()

    node = node_waiting(0.05)
    for k in range(4, 7):
        frame(node, k)
    time.sleep(0.08)
    node._drain()  # noqa: SLF001 - the drain timer's call: every wait is over
    if policy == "latest":
        assert (node.frames_in, node.frames_dropped_stale) == (1, 2)
        assert node.backend.system.records[0].stamp_ns == frames[6].stamp_ns
    else:
        assert (node.frames_in, node.frames_dropped_stale) == (3, 0)
    assert node.stats()["frames_dropped_stale"] == node.frames_dropped_stale
    node.destroy_node()


def test_detections_skip_late_stops_waiting_while_detections_come_too_late_and_resumes(ros_context):
    """detections_skip_late with a window of 2: after two frames whose detections came after the 50 ms wait,
    the next frame is tracked at once; a detection in time makes the wait resume."""
    import itertools
    import time

    from helpers import FR1_XYZ_10, require

    src = open_dataset(require(FR1_XYZ_10), "tum_fr1")
    frames = list(itertools.islice(iter(src), 4))
    node = TrackingNode(context=ros_context, parameter_overrides=[
        Parameter("config", value="tum_fr1"), Parameter("in_process_backend", value=True),
        Parameter("detections_required", value=True), Parameter("detections_wait_s", value=0.05),
        Parameter("detections_skip_late", value=True), Parameter("detections_late_window", value=2),
        Parameter("debug_image", value=False),
    ])  # fmt: skip
    node.on_camera_info(cv.intrinsics_to_camera_info(src.camera, frames[0].stamp_ns, "camera"))

    def frame(k: int) -> None:
        node.on_colour(cv.rgb_to_image(frames[k].rgb, frames[k].stamp_ns, "camera"))
        node.on_depth(cv.depth_to_image(frames[k].depth_m, frames[k].stamp_ns, "camera"))

    def detections_for(k: int) -> None:
        node.on_detections(DetectionArray(header=cv.make_header(frames[k].stamp_ns, "camera"), detections=[]))

    for k in (0, 1):
        frame(k)
        assert node.frames_in == k  # waits for its detections
        time.sleep(0.08)
        node._drain()  # noqa: SLF001 - the timer's call: the wait is over
        assert node.frames_in == k + 1
        detections_for(k)  # too late (> 50 ms after the frame)
    frame(2)
    assert node.frames_in == 3 and node.frames_not_waited == 1  # no wait: it could not succeed
    # Frame 3's detections come with its colour image, before its depth: in time, so it is waited for again.
    node.on_colour(cv.rgb_to_image(frames[3].rgb, frames[3].stamp_ns, "camera"))
    detections_for(3)
    node.on_depth(cv.depth_to_image(frames[3].depth_m, frames[3].stamp_ns, "camera"))
    assert node.frames_in == 4 and node.frames_not_waited == 1 and node.frames_without_detections == 3
    assert node.stats()["frames_not_waited_for_late_detections"] == 1
    assert len(node.detection_delay_ms) == 3 and min(node.detection_delay_ms[:2]) > 50.0 > node.detection_delay_ms[2]
    node.destroy_node()


def _first_frame_and_node_waiting_for_detections(ros_context, wait_s: float):
    """fr1_xyz's first frame, and an in-process tracking node that waits `wait_s` for each frame's detections."""
    import itertools

    from helpers import FR1_XYZ_10, require

    src = open_dataset(require(FR1_XYZ_10), "tum_fr1")
    f = next(itertools.islice(iter(src), 1))
    node = TrackingNode(context=ros_context, parameter_overrides=[
        Parameter("config", value="tum_fr1"), Parameter("in_process_backend", value=True),
        Parameter("detections_required", value=True), Parameter("detections_wait_s", value=wait_s),
        Parameter("debug_image", value=False),
    ])  # fmt: skip
    return src, f, node


def test_a_frame_waiting_for_detections_that_never_come_is_tracked_at_its_deadline_by_the_drain_timer(ros_context):
    """The drain timer is armed at the waiting frame's deadline (not a fixed poll): spinning the executor, the
    frame is tracked once its 0.3 s wait is over, not before, and the timer stops when nothing waits."""
    import time

    src, f, node = _first_frame_and_node_waiting_for_detections(ros_context, wait_s=0.3)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    assert node._drain_timer.is_canceled()  # noqa: SLF001 - nothing waits yet: no wake-ups
    node.on_camera_info(cv.intrinsics_to_camera_info(src.camera, f.stamp_ns, "camera"))
    t0 = time.monotonic()
    node.on_colour(cv.rgb_to_image(f.rgb, f.stamp_ns, "camera"))
    node.on_depth(cv.depth_to_image(f.depth_m, f.stamp_ns, "camera"))
    assert node.frames_in == 0 and not node._drain_timer.is_canceled()  # noqa: SLF001
    assert spin_until(executor, lambda: node.frames_in == 1, 5.0)
    waited_s = time.monotonic() - t0
    assert 0.29 <= waited_s < 2.0 and node.frames_without_detections == 1
    assert node._drain_timer.is_canceled()  # noqa: SLF001 - the queue is empty again
    executor.remove_node(node)
    node.destroy_node()


def test_detections_for_a_frame_never_received_are_kept_and_a_waiting_frames_delay_is_measured(ros_context):
    """Real time: the middleware may drop a colour image the detector got; its detections must not break the
    node (regression test: such detections crashed tracking). A waiting frame's detections are used at once."""

    src, f, node = _first_frame_and_node_waiting_for_detections(ros_context, wait_s=60.0)
    node.on_detections(DetectionArray(header=cv.make_header(f.stamp_ns - 33_000_000, "camera"), detections=[]))
    assert node.detections_in == 1 and len(node.detection_delay_ms) == 0  # no frame of that stamp: no delay
    node.on_camera_info(cv.intrinsics_to_camera_info(src.camera, f.stamp_ns, "camera"))
    node.on_colour(cv.rgb_to_image(f.rgb, f.stamp_ns, "camera"))
    node.on_depth(cv.depth_to_image(f.depth_m, f.stamp_ns, "camera"))
    assert node.frames_in == 0 and len(node.queue) == 1
    node.on_detections(DetectionArray(header=cv.make_header(f.stamp_ns, "camera"), detections=[]))
    assert node.frames_in == 1 and node.frames_without_detections == 0 and len(node.detection_delay_ms) == 1
    node.destroy_node()


@pytest.mark.parametrize("policy", ["all", "latest"])
def test_lossless_frames_before_the_first_camera_info_wait_for_it_and_real_time_skips_them(ros_context, policy):
    """camera_info is its own DDS writer and can be matched seconds after the images (seen in the graph's
    --load-map run: 12 of 60 lossless frames skipped). Lossless (`all`), the frames wait for it, acked at once
    so that the player goes on; real time (`latest`) skips them as before."""
    import itertools

    from helpers import FR1_XYZ_10, require

    src = open_dataset(require(FR1_XYZ_10), "tum_fr1")
    frames = list(itertools.islice(iter(src), 3))
    node = TrackingNode(context=ros_context, parameter_overrides=[
        Parameter("config", value="tum_fr1"), Parameter("in_process_backend", value=True),
        Parameter("intrinsics_from", value="camera_info"), Parameter("frame_policy", value=policy),
        Parameter("debug_image", value=False), Parameter("ack_topic", value="/bag_player/ack"),
    ])  # fmt: skip
    acked: list[int] = []
    node._ack = lambda header: acked.append(cv.stamp_to_ns(header.stamp))  # what the player waits for
    confirmed: list[str] = []  # camera_info confirmations (the player re-sends camera_info until one comes)
    node.ack_pub.publish = lambda header: confirmed.append(header.frame_id)
    for f in frames:
        node.on_colour(cv.rgb_to_image(f.rgb, f.stamp_ns, "camera"))
        node.on_depth(cv.depth_to_image(f.depth_m, f.stamp_ns, "camera"))
    assert sorted(set(acked)) == [f.stamp_ns for f in frames]  # the player is never held up
    assert node.published_poses == 0
    bad = cv.intrinsics_to_camera_info(src.camera, frames[0].stamp_ns, "camera")
    bad.k[0] = 0.0  # fx 0: rejected, and not confirmed
    node.on_camera_info(bad)
    assert confirmed == [] and node.published_poses == 0
    node.on_camera_info(cv.intrinsics_to_camera_info(src.camera, frames[0].stamp_ns, "camera"))
    assert confirmed == ["/camera/rgb/camera_info"]
    if policy == "all":
        assert node.published_poses == 3 and [r.stamp_ns for r in node.backend.system.records] == [f.stamp_ns for f in frames]
    else:
        assert node.published_poses == 0 and len(node.queue) == 0
    node.destroy_node()


def test_real_time_carried_boxes_move_with_the_image_motion_when_detections_carry_flow_is_on(ros_context):
    """detections_carry_flow: the node keeps its frames' grey and depth by stamp, and a frame tracked before its
    own detections get the boxes of frame 0 moved by the image motion between frame 0 and it (what
    `carried_forward` gives on the dataset's own images, to 0.5 px), not the boxes left where they were."""
    import itertools

    from helpers import FR1_XYZ_10, require

    from changing_slam_ros.core.dynamic.box_flow import FlowImage
    from changing_slam_ros.core.dynamic.detector import Detection as CoreDetection
    from changing_slam_ros.core.dynamic.detector import DetectionSet
    from changing_slam_ros.core.dynamic.late_detections import CarryConfig, carried_forward

    src = open_dataset(require(FR1_XYZ_10), "tum_fr1")
    frames = list(itertools.islice(iter(src), 8))
    node = TrackingNode(context=ros_context, parameter_overrides=[
        Parameter("config", value="tum_fr1"), Parameter("in_process_backend", value=True),
        Parameter("dynamic", value="on"), Parameter("frame_policy", value="latest"),
        Parameter("detections_carry_flow", value=True), Parameter("detections_carry_flow_grow_widths_per_s", value=0.0),
        Parameter("detections_carry_grow_widths_per_s", value=0.0), Parameter("debug_image", value=False),
    ])  # fmt: skip
    used: list = []
    process = node.backend.system.process
    node.backend.system.process = lambda frame, dets: used.append(dets) or process(frame, dets)
    node.on_camera_info(cv.intrinsics_to_camera_info(src.camera, frames[0].stamp_ns, "camera"))
    box = (250.0, 150.0, 400.0, 400.0)
    for k, f in enumerate(frames):
        node.on_colour(cv.rgb_to_image(f.rgb, f.stamp_ns, "camera"))
        node.on_depth(cv.depth_to_image(f.depth_m, f.stamp_ns, "camera"))
        if k == 0:  # frame 0's detections come after it was tracked
            x0, y0, x1, y1 = box
            node.on_detections(DetectionArray(header=cv.make_header(f.stamp_ns, "camera"), width=640, height=480,
                                              detections=[Detection(x=x0, y=y0, w=x1 - x0, h=y1 - y0, class_id=0,
                                                                    score=0.9)]))  # fmt: skip
    assert node.frames_in == 8 and node.frames_with_carried_detections == 7 and len(node.carry_cpu_ms) == 7
    assert len(node._recent_images) == 8  # noqa: SLF001 - 0.27 s of frames, all within detections_carry_max_age_s
    earlier = DetectionSet(frames[0].stamp_ns, (CoreDetection(box, 0, 0.9),), 640, 480)
    first = FlowImage.from_rgb(frames[0].stamp_ns, frames[0].rgb, frames[0].depth_m)
    cfg = CarryConfig(grow_widths_per_s=0.0, flow=True, flow_grow_widths_per_s=0.0)
    moved = 0.0
    for k in range(1, 8):
        (carried,) = used[k]
        later = FlowImage.from_rgb(frames[k].stamp_ns, frames[k].rgb, frames[k].depth_m)
        (expected,) = carried_forward(earlier, frames[k].stamp_ns, cfg, images=(first, later))
        assert carried.box_xyxy == pytest.approx(expected.box_xyxy, abs=0.5)
        moved = max(moved, float(np.max(np.abs(np.subtract(carried.box_xyxy, box)))))
    assert moved > 2.0, moved  # the hand-held camera moved the scene by pixels; the boxes followed (no growth)
    node.destroy_node()


def test_real_time_frames_tracked_before_later_detections_get_their_final_pose_refined(ros_context, tmp_path):
    """tracking.deferred_refinement (on by default): frames 1-4 are tracked with frame 0's boxes carried forward;
    when frame 4's detections come, those four are bracketed by frames 0 and 4 (core.deferred_refinement), and when
    the node finishes they are optimised again in the map as it is then: trajectory.txt has their refined poses, the
    published (online) poses stay."""
    import itertools

    from helpers import FR1_XYZ_10, require

    src = open_dataset(require(FR1_XYZ_10), "tum_fr1")
    frames = list(itertools.islice(iter(src), 6))
    out = tmp_path / "out"
    node = TrackingNode(context=ros_context, parameter_overrides=[
        Parameter("config", value="tum_fr1"), Parameter("in_process_backend", value=True),
        Parameter("dynamic", value="on"), Parameter("frame_policy", value="latest"), Parameter("output_dir", value=str(out)),
        Parameter("detections_carry_flow", value=False), Parameter("debug_image", value=False),
    ])  # fmt: skip
    system = node.backend.system
    assert system.refinement is not None
    node.on_camera_info(cv.intrinsics_to_camera_info(src.camera, frames[0].stamp_ns, "camera"))

    def detections(stamp_ns: int, x0: float) -> DetectionArray:
        return DetectionArray(header=cv.make_header(stamp_ns, "camera"), width=640, height=480,
                              detections=[Detection(x=x0, y=150.0, w=150.0, h=250.0, class_id=0, score=0.9)])  # fmt: skip

    for k, f in enumerate(frames):
        node.on_colour(cv.rgb_to_image(f.rgb, f.stamp_ns, "camera"))
        node.on_depth(cv.depth_to_image(f.depth_m, f.stamp_ns, "camera"))
        if k == 0:
            node.on_detections(detections(f.stamp_ns, 250.0))
    online = [r.T_world_cam_online.copy() for r in system.records]
    before = [None if r.T_ref_cam is None else r.T_ref_cam.copy() for r in system.records]
    node.on_detections(detections(frames[4].stamp_ns, 330.0))  # frame 4's, after frame 5 was tracked
    stats = node.stats()["deferred_refinement"]
    assert node.frames_in == 6 and stats["frames_bracketed"] >= 3  # frames 1-4 less keyframes
    assert stats["frames_refined"] == 0  # they settle 1 s (settle_s) later, or when the node finishes
    node.finish()
    stats = node.stats()["deferred_refinement"]
    assert stats["frames_refined"] == stats["frames_bracketed"]
    changed = [b is not None and not np.array_equal(b, r.T_ref_cam) for b, r in zip(before, system.records)]
    assert sum(changed) == stats["frames_refined"]
    assert not changed[0] and not changed[5]  # frame 0 has its own boxes; frame 5 comes after frame 4's
    assert all(np.array_equal(a, r.T_world_cam_online) for a, r in zip(online, system.records))
    written = read_tum_trajectory(out / "trajectory.txt")
    assert np.allclose(written.positions, system.final_trajectory().positions, atol=1e-6)
    node.destroy_node()


def test_frames_still_queued_at_shutdown_are_tracked_and_written_when_publishing_fails(ros_context, tmp_path):
    """SIGINT shuts the context down before `destroy_node` runs `finish`: publishing a queued frame's pose raises
    ("publisher's context is invalid"). Tracking must still track it and write every output file."""
    import itertools

    from helpers import FR1_XYZ_10, require
    from rclpy._rclpy_pybind11 import RCLError

    from changing_slam_ros.io.tum_trajectory import read_tum_trajectory

    src = open_dataset(require(FR1_XYZ_10), "tum_fr1")
    frames = list(itertools.islice(iter(src), 3))
    node = TrackingNode(context=ros_context, parameter_overrides=[
        Parameter("config", value="tum_fr1"), Parameter("in_process_backend", value=True),
        Parameter("intrinsics_from", value="camera_info"), Parameter("frame_policy", value="all"),
        Parameter("debug_image", value=False), Parameter("output_dir", value=str(tmp_path)),
    ])  # fmt: skip
    for f in frames:  # held: no camera_info yet
        node.on_colour(cv.rgb_to_image(f.rgb, f.stamp_ns, "camera"))
        node.on_depth(cv.depth_to_image(f.depth_m, f.stamp_ns, "camera"))
    assert node.published_poses == 0 and len(node.queue) == 3

    def context_gone(*args):  # noqa: ANN002, ANN202
        raise RCLError("Failed to publish: publisher's context is invalid")

    node.poses_out.publish = context_gone
    node.camera = src.camera  # as if camera_info had come just before the shutdown
    node.destroy_node()
    traj = read_tum_trajectory(tmp_path / "trajectory.txt")
    np.testing.assert_allclose(traj.stamps_s, [f.stamp_ns / 1e9 for f in frames], atol=1e-6, rtol=0)



class _Log:
    """A logger that keeps the warnings and drops everything else."""

    def __init__(self) -> None:
        self.warnings: list[str] = []

    def warning(self, msg: str, **_kw) -> None:
        self.warnings.append(msg)

    def __getattr__(self, _name: str):
        return lambda *_a, **_kw: None


def test_frames_from_a_bag_played_again_are_dropped_with_one_warning(ros_context):
    """A bag played again into a running tracking sends stamps tens of seconds older than the newest: the frames are
    dropped (the map takes each stamp once, in order) and one warning per stream names the jump; a player's short
    resume overlap is no such jump."""
    import itertools

    from helpers import FR1_XYZ_10, require

    src = open_dataset(require(FR1_XYZ_10), "tum_fr1")
    frames = list(itertools.islice(iter(src), 4))
    node = TrackingNode(context=ros_context, parameter_overrides=[
        Parameter("config", value="tum_fr1"), Parameter("in_process_backend", value=True),
        Parameter("debug_image", value=False)])  # fmt: skip
    log = _Log()
    node.get_logger = lambda: log

    def send(f, shift_ns: int = 0) -> None:
        node.on_colour(cv.rgb_to_image(f.rgb, f.stamp_ns + shift_ns, "camera"))
        node.on_depth(cv.depth_to_image(f.depth_m, f.stamp_ns + shift_ns, "camera"))

    later = 60 * 10**9
    for f in frames[2:]:
        send(f, later)
    send(frames[3], later)  # the player resumed a frame early: a duplicate, no warning
    assert node.duplicates == {"colour": 1, "depth": 1} and log.warnings == []
    for f in frames[:2]:  # the bag again from its start, a minute earlier
        send(f)
    assert node.duplicates == {"colour": 3, "depth": 3}
    assert [w.split(" stamps went back ")[0] for w in log.warnings] == ["tracking: colour", "tracking: depth"]
    assert all(" went back 60." in w for w in log.warnings), log.warnings
    assert node.published_poses == 2
    node.destroy_node()
