"""bag_player in-process: every frame arrives with its stamps, /clock advances, lossless mode loses nothing."""

from __future__ import annotations

import time

import numpy as np
import pytest

pytestmark = pytest.mark.ros
S = 1_000_000_000

rclpy = pytest.importorskip("rclpy")
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import Image  # noqa: E402
from std_msgs.msg import Header  # noqa: E402

from changing_slam_ros.errors import BagError, ConfigError  # noqa: E402
from changing_slam_ros.io.image_codec import decode_rgb, decode_depth  # noqa: E402
from changing_slam_ros.nodes.bag_player_node import BagPlayerNode, main  # noqa: E402
from changing_slam_ros.io.playback import pass_period_ns  # noqa: E402


def stamp_ns(msg) -> int:  # noqa: ANN001
    return msg.header.stamp.sec * S + msg.header.stamp.nanosec


class Recorder(Node):
    """Subscribes to images and /clock and keeps what arrives (with the wall time of arrival)."""

    def __init__(self, context, topics=("/camera/rgb/image_color",), depth=100, work_s=0.0, ack_topic=None):  # noqa: ANN001
        super().__init__("recorder", context=context)
        self.images: dict[str, list[Image]] = {t: [] for t in topics}
        self.arrival_s: list[float] = []
        self.clock_ns: list[int] = []
        self.work_s = work_s
        qos = QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE)
        for topic in topics:
            self.create_subscription(Image, topic, lambda m, t=topic: self._on_image(t, m), qos)
        self.create_subscription(Clock, "/clock", self._on_clock, 100)
        self.ack_pub = self.create_publisher(Header, ack_topic, 100) if ack_topic else None

    def _on_image(self, topic: str, msg: Image) -> None:
        self.images[topic].append(msg)
        self.arrival_s.append(time.monotonic())
        if self.work_s:
            time.sleep(self.work_s)  # a slow consumer (tracking at a few Hz)
        if self.ack_pub is not None:
            self.ack_pub.publish(Header(stamp=msg.header.stamp, frame_id=self.get_name()))

    def _on_clock(self, msg: Clock) -> None:
        self.clock_ns.append(msg.clock.sec * S + msg.clock.nanosec)


def make_player(context, bag, **params) -> BagPlayerNode:  # noqa: ANN001
    overrides = [Parameter("bag", value=str(bag))] + [Parameter(k, value=v) for k, v in params.items()]
    return BagPlayerNode(context=context, parameter_overrides=overrides)


def play(context, player, *others):  # noqa: ANN001, ANN201
    executor = SingleThreadedExecutor(context=context)
    for node in (player, *others):
        executor.add_node(node)
    # Let discovery match the subscriptions before playing (lossless mode waits by itself).
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline and any(p.get_subscription_count() == 0 for p in player.bag_publishers.values()
                                               if p.topic_name in {t for o in others for t in o.images}):
        executor.spin_once(timeout_sec=0.05)
    try:
        return player.play(executor)
    finally:
        drain(executor)
        executor.shutdown()


def test_every_image_arrives_with_its_recorded_stamp_and_pixels_and_clock_advances(ros_context, fr1_bag):
    rec = Recorder(ros_context, topics=("/camera/rgb/image_color", "/camera/depth/image"))
    player = make_player(ros_context, fr1_bag.path)
    result = play(ros_context, player, rec)

    n = len(fr1_bag.rgb_stamps_ns)  # 9: the folder associates 9 of its 10 colour frames
    assert n == 9 and result.completed and result.published == 3 * n  # colour, depth, camera_info
    rgb = rec.images["/camera/rgb/image_color"]
    assert [stamp_ns(m) for m in rgb] == fr1_bag.rgb_stamps_ns
    assert [stamp_ns(m) for m in rec.images["/camera/depth/image"]] == fr1_bag.depth_stamps_ns
    np.testing.assert_array_equal(decode_rgb(rgb[0]), fr1_bag.first_rgb)
    depth = decode_depth(rec.images["/camera/depth/image"][0])
    assert depth.shape == (480, 640) and 0.5 < float(np.median(depth[depth > 0])) < 2.0  # metres

    # /clock: published in bag time, never backwards, from the first stamp up to the last message.
    clock = rec.clock_ns
    assert len(clock) >= 10 and all(b >= a for a, b in zip(clock, clock[1:]))
    assert clock[0] >= fr1_bag.rgb_stamps_ns[0] and clock[-1] >= fr1_bag.depth_stamps_ns[-1]
    player.destroy_node()
    rec.destroy_node()


def test_playback_follows_the_recorded_timing_times_the_rate(ros_context, fr1_bag):
    rec = Recorder(ros_context)
    span_s = (fr1_bag.depth_stamps_ns[-1] - fr1_bag.rgb_stamps_ns[0]) / S  # 0.31 s of bag
    player = make_player(ros_context, fr1_bag.path, rate=0.5, topics=["/camera/rgb/image_color", "/camera/depth/image"])
    result = play(ros_context, player, rec)
    assert result.completed and abs(result.wall_s - span_s / 0.5) < 0.15  # 0.62 s at half speed
    gaps = np.diff(rec.arrival_s)
    recorded = np.diff(fr1_bag.rgb_stamps_ns) / S / 0.5
    assert np.median(np.abs(gaps - recorded)) < 0.02  # each frame spaced as recorded / rate
    player.destroy_node()
    rec.destroy_node()


def test_offset_and_remaps_by_parameter_and_by_ros_args(ros_context, fr1_bag):
    rec = Recorder(ros_context, topics=("/image", "/depth"))
    player = BagPlayerNode(
        context=ros_context,
        cli_args=["--ros-args", "-r", "/camera/rgb/image_color:=/image"],
        parameter_overrides=[
            Parameter("bag", value=str(fr1_bag.path)),
            Parameter("remap", value=["/camera/depth/image:=/depth"]),
            Parameter("start_offset_s", value=0.1),
            Parameter("rate", value=4.0),
        ],
    )
    result = play(ros_context, player, rec)
    assert result.completed
    first = fr1_bag.rgb_stamps_ns[0]
    expected_rgb = [t for t in fr1_bag.rgb_stamps_ns if t >= first + S // 10]
    assert [stamp_ns(m) for m in rec.images["/image"]] == expected_rgb and 0 < len(expected_rgb) < 9
    assert len(rec.images["/depth"]) == sum(t >= first + S // 10 for t in fr1_bag.depth_stamps_ns)
    player.destroy_node()
    rec.destroy_node()


def test_a_slow_subscriber_loses_frames_at_full_speed_but_none_in_lossless_mode(ros_context, tmp_path, fr1_bag_writer):
    bag = fr1_bag_writer(tmp_path / "small", n=10, scale=4)
    topics = ["/camera/rgb/image_color"]

    slow = Recorder(ros_context, depth=1, work_s=0.08)  # 80 ms per frame, queue of one
    result = play(ros_context, make_player(ros_context, bag.path, rate=5.0, topics=topics), slow)
    assert result.completed and len(slow.images[topics[0]]) < 9  # frames overwritten in its queue
    slow.destroy_node()

    slow = Recorder(ros_context, depth=1, work_s=0.08, ack_topic="/bag_player/ack")
    player = make_player(
        ros_context, bag.path, rate=5.0, topics=topics, lossless=True, ack_topics=topics,
        wait_subscribers_timeout_s=5.0,
    )  # fmt: skip
    result = play(ros_context, player, slow)
    assert result.completed and result.ack_timeouts == 0
    assert [stamp_ns(m) for m in slow.images[topics[0]]] == bag.rgb_stamps_ns
    slow.destroy_node()
    player.destroy_node()


def test_loop_plays_the_bag_again_shifted_in_time_until_stopped(ros_context, tmp_path, fr1_bag_writer):
    bag = fr1_bag_writer(tmp_path / "small", n=3, scale=8)
    rec = Recorder(ros_context)
    topic = "/camera/rgb/image_color"

    def stop_after_seven(msg=None):  # noqa: ANN001
        if len(rec.images[topic]) >= 7 or msg is None:
            ros_context.try_shutdown()

    rec.create_subscription(Image, topic, stop_after_seven, 100)
    rec.create_timer(20.0, stop_after_seven)  # bound the test if frames went missing
    player = make_player(ros_context, bag.path, rate=4.0, loop=True, topics=[topic])
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(player)
    executor.add_node(rec)
    for _ in range(40):
        executor.spin_once(timeout_sec=0.02)
    result = player.play(executor)
    assert not result.completed and result.passes >= 3
    # each pass later by the bag's duration and one frame: header stamps keep running forward
    period = pass_period_ns(player.bag, player.options)
    assert period > bag.rgb_stamps_ns[-1] - bag.rgb_stamps_ns[0]
    shifted = [t + k * period for k in range(3) for t in bag.rgb_stamps_ns]
    assert [stamp_ns(m) for m in rec.images[topic]][:7] == shifted[:7]


def test_lossless_mode_refuses_to_play_to_nobody(ros_context, fr1_bag):
    player = make_player(ros_context, fr1_bag.path, lossless=True, wait_subscribers_timeout_s=0.3)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(player)
    result = player.play(executor)
    assert result.published == 0 and "no subscribers" in result.error
    player.destroy_node()


def test_lossless_mode_waits_for_depth_too_not_only_for_the_acknowledged_colour(ros_context, fr1_bag):
    """A depth frame published before tracking's depth subscription matched is lost (its colour frame then has no
    pair): the graph's player waits for every sensor topic, the ack topic with `min_subscribers`, the others with one."""
    colour, depth = "/camera/rgb/image_color", "/camera/depth/image"
    params = dict(lossless=True, wait_subscribers_timeout_s=1.0, ack_topics=[colour], min_subscribers=2,
                  wait_for_topics=[colour, depth], ack_topic="/bag_player/ack")
    only_colour = [Recorder(ros_context, topics=(colour,)), Recorder(ros_context, topics=(colour,))]
    player = make_player(ros_context, fr1_bag.path, **params)
    executor = SingleThreadedExecutor(context=ros_context)
    for node in (player, *only_colour):
        executor.add_node(node)
    result = player.play(executor)
    assert result.published == 0 and result.error == "no subscribers"  # two on colour, none on depth
    executor.shutdown()
    for node in (player, *only_colour):
        node.destroy_node()
    # One subscriber on depth is enough (only tracking reads it); colour still needs its two.
    both = Recorder(ros_context, topics=(colour, depth))
    other = Recorder(ros_context, topics=(colour,))
    player = make_player(ros_context, fr1_bag.path, **{**params, "ack_count": 0, "wait_subscribers_timeout_s": 10.0})
    result = play(ros_context, player, both, other)
    assert result.error in ("", None) and result.published > 0
    assert len(both.images[depth]) == len(both.images[colour]) > 0
    for node in (player, both, other):
        node.destroy_node()


class LateCameraInfoReader(Node):
    """Reads colour and camera_info, but loses every camera_info that comes within `deaf_s` of its first colour
    frame, as a reader that matched camera_info's writer late does (volatile: what was sent before is gone); each
    camera_info it keeps is confirmed on the ack topic (frame_id = the topic), as tracking does, and each colour
    frame is acknowledged."""

    def __init__(self, context, deaf_s: float, ack_frames: bool = True):  # noqa: ANN001
        from sensor_msgs.msg import CameraInfo

        super().__init__("late_reader", context=context)
        self.deaf_s, self.ack_frames = deaf_s, ack_frames
        self.first_colour_s: float | None = None
        self.events: list[str] = []  # "colour" / "info" in the order they were kept
        self.images: dict[str, list] = {"/camera/rgb/image_color": []}  # play() waits for this topic's match
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.create_subscription(Image, "/camera/rgb/image_color", self._on_colour, qos)
        self.info_sub = self.create_subscription(CameraInfo, "/camera/rgb/camera_info", self._on_info, qos)
        self.ack_pub = self.create_publisher(Header, "/bag_player/ack", 100)

    def _on_colour(self, msg: Image) -> None:
        self.first_colour_s = self.first_colour_s or time.monotonic()
        self.events.append("colour")
        if self.ack_frames:
            self.ack_pub.publish(Header(stamp=msg.header.stamp, frame_id=self.get_name()))

    def _on_info(self, msg) -> None:  # noqa: ANN001
        if self.first_colour_s is None or time.monotonic() - self.first_colour_s < self.deaf_s:
            return  # not matched yet: lost
        self.events.append("info")
        self.ack_pub.publish(Header(stamp=msg.header.stamp, frame_id=self.info_sub.topic_name))


def test_lossless_mode_re_sends_camera_info_until_a_late_matched_reader_confirms_it(ros_context, fr1_bag):
    """Regression test: camera_info's writer can be matched by tracking's reader only after the frames have gone
    out, so tracking never gets intrinsics. With `confirm_topics` the player holds the next colour frame
    and re-sends camera_info until the reader confirms one; without, the reader sees frames before intrinsics."""
    colour, info = "/camera/rgb/image_color", "/camera/rgb/camera_info"
    params = dict(lossless=True, rate=5.0, ack_topics=[colour], ack_topic="/bag_player/ack", ack_timeout_s=10.0,
                  wait_for_topics=[colour, info], wait_subscribers_timeout_s=10.0, dds_ack_wait=False,
                  topics=[colour, info])  # fmt: skip

    reader = LateCameraInfoReader(ros_context, deaf_s=1.0)
    result = play(ros_context, make_player(ros_context, fr1_bag.path, **params), reader)
    assert result.completed and result.confirm_resends == 0
    assert reader.events[:2] == ["colour", "colour"]  # the second frame before any intrinsics: the old failure
    reader.destroy_node()

    reader = LateCameraInfoReader(ros_context, deaf_s=1.0)
    player = make_player(ros_context, fr1_bag.path, **params, confirm_topics=[info], confirm_resend_s=0.1)
    result = play(ros_context, player, reader)
    assert result.completed and result.confirm_timeouts == 0 and result.ack_timeouts == 0
    assert result.confirm_resends >= 5  # ~1 s deaf, re-sent every 0.1 s
    assert reader.events[:2] == ["colour", "info"]  # intrinsics before the second frame
    assert reader.events.count("colour") == len(fr1_bag.rgb_stamps_ns)
    reader.destroy_node()
    player.destroy_node()
    # A confirmation (same stamp as its frame) is not a frame's processing ack: a reader that confirms camera_info
    # but never acknowledges a frame leaves every frame's wait to time out.
    reader = LateCameraInfoReader(ros_context, deaf_s=0.0, ack_frames=False)
    player = make_player(ros_context, fr1_bag.path, **{**params, "ack_timeout_s": 0.2}, confirm_topics=[info])
    result = play(ros_context, player, reader)
    assert result.completed and result.ack_timeouts == len(fr1_bag.rgb_stamps_ns)
    reader.destroy_node()
    player.destroy_node()
    # ... also when the player asks for no confirmation (tracking confirms every camera_info it accepts).
    reader = LateCameraInfoReader(ros_context, deaf_s=0.0, ack_frames=False)
    player = make_player(ros_context, fr1_bag.path, **{**params, "ack_timeout_s": 0.2})
    result = play(ros_context, player, reader)
    assert result.completed and result.ack_timeouts == len(fr1_bag.rgb_stamps_ns)
    reader.destroy_node()
    player.destroy_node()
    # A topic the bag does not play (a bag without camera_info) has nothing to confirm: the bag plays as without.
    reader = LateCameraInfoReader(ros_context, deaf_s=0.0)
    player = make_player(ros_context, fr1_bag.path, **{**params, "topics": [colour], "wait_for_topics": [colour]},
                         confirm_topics=[info])  # fmt: skip
    result = play(ros_context, player, reader)
    assert result.completed and result.confirm_resends == result.confirm_timeouts == 0
    assert reader.events == ["colour"] * len(fr1_bag.rgb_stamps_ns)
    reader.destroy_node()
    player.destroy_node()


def test_bad_bags_and_topics_raise_errors_naming_them(ros_context, tmp_path, fr1_bag):
    with pytest.raises(BagError, match="nope.mcap: no such file"):
        make_player(ros_context, tmp_path / "nope.mcap")
    with pytest.raises(BagError, match="no topic /missing; the bag has /camera/depth/image"):
        make_player(ros_context, fr1_bag.path, topics=["/missing"])
    with pytest.raises(ConfigError, match="rate must be > 0"):
        make_player(ros_context, fr1_bag.path, rate=-1.0)


def test_main_returns_1_with_one_line_for_a_missing_bag(monkeypatch, capsys, tmp_path):
    monkeypatch.setenv("ROS_DOMAIN_ID", "117")
    assert main(["bag_player", str(tmp_path / "missing.bag")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"error: {tmp_path / 'missing.bag'}: no such file or folder"]


def _spin_player(context, player, *others):  # noqa: ANN001, ANN202
    executor = SingleThreadedExecutor(context=context)
    for node in (player, *others):
        executor.add_node(node)
    for _ in range(40):  # discovery
        executor.spin_once(timeout_sec=0.025)
    result = player.play(executor)
    drain(executor)
    executor.shutdown()
    return result


def drain(executor, quiet_s: float = 0.3, limit_s: float = 5.0) -> None:  # noqa: ANN001
    """Spin until no callback ran for `quiet_s` (spin_once returns early when it did work)."""
    start = last_work = time.monotonic()
    while time.monotonic() - last_work < quiet_s and time.monotonic() - start < limit_s:
        t0 = time.monotonic()
        executor.spin_once(timeout_sec=quiet_s)
        if time.monotonic() - t0 < quiet_s * 0.9:
            last_work = time.monotonic()


def test_a_tum_style_ros1_bag_replays_images_and_tf_as_ros2_messages(ros_context, tmp_path):
    """ROS 1 payloads go out as ROS 2 CDR; tf/tfMessage is published as tf2_msgs/msg/TFMessage."""
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    from tf2_msgs.msg import TFMessage

    store = get_typestore(Stores.ROS1_NOETIC)
    store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf/msg/tfMessage"))
    t = store.types
    stamps = [1305031102 * S + k * 33_000_000 for k in range(5)]
    path = tmp_path / "tum.bag"
    with Writer1(path) as w:
        c_img = w.add_connection("/camera/rgb/image_color", "sensor_msgs/msg/Image", typestore=store)
        c_tf = w.add_connection("/tf", "tf/msg/tfMessage", typestore=store)
        for k, ns in enumerate(stamps):
            time_ = t["builtin_interfaces/msg/Time"](sec=ns // S, nanosec=ns % S)
            hdr = t["std_msgs/msg/Header"](seq=k, stamp=time_, frame_id="/openni_rgb_optical_frame")
            data = np.full(4 * 6 * 3, k, dtype=np.uint8)
            img = t["sensor_msgs/msg/Image"](hdr, 4, 6, "rgb8", 0, 18, data)
            w.write(c_img, ns, store.serialize_ros1(img, "sensor_msgs/msg/Image"))
            tr = t["geometry_msgs/msg/TransformStamped"](
                t["std_msgs/msg/Header"](seq=k, stamp=time_, frame_id="/world"), "/kinect",
                t["geometry_msgs/msg/Transform"](t["geometry_msgs/msg/Vector3"](x=0.1 * k, y=0.0, z=1.0),
                                                 t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)),
            )  # fmt: skip
            w.write(c_tf, ns + 1, store.serialize_ros1(t["tf/msg/tfMessage"]([tr]), "tf/msg/tfMessage"))

    rec = Recorder(ros_context)
    tfs: list[TFMessage] = []
    rec.create_subscription(TFMessage, "/tf", tfs.append, 100)
    result = _spin_player(ros_context, make_player(ros_context, path, rate=4.0), rec)
    assert result.completed and result.per_topic == {"/camera/rgb/image_color": 5, "/tf": 5}
    images = rec.images["/camera/rgb/image_color"]
    assert [stamp_ns(m) for m in images] == stamps
    assert [decode_rgb(m)[0, 0, 0] for m in images] == [0, 1, 2, 3, 4]
    assert [m.transforms[0].transform.translation.x for m in tfs] == pytest.approx([0.0, 0.1, 0.2, 0.3, 0.4])
    assert tfs[0].transforms[0].child_frame_id == "/kinect"


def test_the_bundled_fr1_sample_replays_every_frame_and_ground_truth_pose(ros_context):
    from geometry_msgs.msg import PoseStamped
    from helpers import REPO, require

    from changing_slam_ros.io.bag_messages import BagMessages

    path = require(REPO / "bags" / "tum_fr1_xyz_first10.mcap")
    with BagMessages(path) as bag:
        counts = {t: c.msgcount for t, c in bag.topics.items()}
    rec = Recorder(ros_context, topics=("/camera/rgb/image_color", "/camera/depth/image"))
    gt: list[PoseStamped] = []
    rec.create_subscription(PoseStamped, "/ground_truth/pose", gt.append, 100)
    result = _spin_player(ros_context, make_player(ros_context, path, rate=2.0), rec)
    assert result.completed and result.per_topic == counts
    assert len(rec.images["/camera/rgb/image_color"]) == counts["/camera/rgb/image_color"] >= 9
    assert len(rec.images["/camera/depth/image"]) == counts["/camera/depth/image"]
    assert len(gt) == counts["/ground_truth/pose"]
    depth = decode_depth(rec.images["/camera/depth/image"][0])
    assert 0.3 < float(np.median(depth[depth > 0])) < 3.0


def test_a_ros2_sqlite3_bag_replays_like_the_mcap_one(ros_context, tmp_path, fr1_bag_writer):
    bag = fr1_bag_writer(tmp_path / "sqlite_bag", n=4, scale=8, storage="sqlite3")
    assert any(p.suffix == ".db3" for p in bag.path.iterdir())
    rec = Recorder(ros_context, topics=("/camera/rgb/image_color", "/camera/depth/image"))
    result = _spin_player(ros_context, make_player(ros_context, bag.path, rate=2.0), rec)
    assert result.completed and player_kind(bag.path) == "ros2 bag (sqlite3)"
    assert [stamp_ns(m) for m in rec.images["/camera/rgb/image_color"]] == bag.rgb_stamps_ns
    assert [stamp_ns(m) for m in rec.images["/camera/depth/image"]] == bag.depth_stamps_ns
    np.testing.assert_array_equal(decode_rgb(rec.images["/camera/rgb/image_color"][0]), bag.first_rgb)


def player_kind(path) -> str:  # noqa: ANN001
    from changing_slam_ros.io.bag_messages import detect_bag_kind

    return detect_bag_kind(path).value


def test_a_node_with_use_sim_time_follows_the_bag_clock(ros_context, fr1_bag):
    sim = Node("sim_time_node", context=ros_context, parameter_overrides=[Parameter("use_sim_time", value=True)])
    seen: list[int] = []
    sim.create_timer(0.01, lambda: seen.append(sim.get_clock().now().nanoseconds))  # runs on the bag's clock
    rec = Recorder(ros_context)
    result = _spin_player(ros_context, make_player(ros_context, fr1_bag.path, rate=1.0), rec, sim)
    assert result.completed
    now_ns = sim.get_clock().now().nanoseconds
    last = max(fr1_bag.rgb_stamps_ns[-1], fr1_bag.depth_stamps_ns[-1])
    assert last <= now_ns < last + S // 2  # sim time = bag time (2011), not the wall clock
    assert seen and seen[0] >= fr1_bag.rgb_stamps_ns[0] and all(b >= a for a, b in zip(seen, seen[1:]))
    sim.destroy_node()
