"""Raw message iteration over ROS 1 bags, ROS 2 bags (sqlite3, mcap) and bare mcap files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from changing_slam_ros.errors import BagError
from changing_slam_ros.io.bag_messages import BagKind, BagMessages, detect_bag_kind

JAZZY = get_typestore(Stores.ROS2_JAZZY)
IMAGE = "sensor_msgs/msg/Image"
INFO = "sensor_msgs/msg/CameraInfo"

# (sec, nanosec) of header stamps and log times (ns) of three messages: log times differ from
# header stamps so a mix-up shows.
STAMPS = [(1305031102, 175304000), (1305031102, 211214000), (1305031102, 243211000)]
LOG_NS = [s * 10**9 + ns + 12345 for s, ns in STAMPS]


def _image(store, i: int, *, ros1: bool):  # noqa: ANN001, ANN202 - rosbags dataclasses
    t = store.types
    hdr_args = (i, t["builtin_interfaces/msg/Time"](*STAMPS[i]), "openni_rgb_optical_frame")
    header = t["std_msgs/msg/Header"](*hdr_args) if ros1 else t["std_msgs/msg/Header"](*hdr_args[1:])
    data = (np.arange(2 * 3 * 3, dtype=np.uint8) + i).astype(np.uint8)
    return t[IMAGE](header, 2, 3, "rgb8", 0, 9, data)


def write_ros1(path: Path) -> None:
    store = get_typestore(Stores.ROS1_NOETIC)
    store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf/msg/tfMessage"))
    t = store.types
    with Writer1(path) as w:
        img = w.add_connection("/camera/rgb/image_color", IMAGE, typestore=store)
        tf = w.add_connection("/tf", "tf/msg/tfMessage", typestore=store, latching=1)
        for i in range(3):
            w.write(img, LOG_NS[i], store.serialize_ros1(_image(store, i, ros1=True), IMAGE))
            ts = t["geometry_msgs/msg/TransformStamped"](
                t["std_msgs/msg/Header"](0, t["builtin_interfaces/msg/Time"](*STAMPS[i]), "/world"),
                "/kinect",
                t["geometry_msgs/msg/Transform"](
                    t["geometry_msgs/msg/Vector3"](1.0 + i, 2.0, 3.0),
                    t["geometry_msgs/msg/Quaternion"](0.0, 0.0, 0.0, 1.0),
                ),
            )
            w.write(tf, LOG_NS[i] + 1, store.serialize_ros1(t["tf/msg/tfMessage"]([ts]), "tf/msg/tfMessage"))


LATCHED_QOS = Qos(
    QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL,
    QosTime(0, 0), QosTime(0, 0), QosLiveliness.AUTOMATIC, QosTime(0, 0), False,
)  # fmt: skip


def write_ros2(path: Path, plugin: StoragePlugin) -> None:
    with Writer2(path, version=9, storage_plugin=plugin) as w:
        img = w.add_connection("/camera/color/image_raw", IMAGE, typestore=JAZZY)
        info = w.add_connection(
            "/camera/color/camera_info", INFO, typestore=JAZZY, offered_qos_profiles=[LATCHED_QOS]
        )
        for i in range(3):
            w.write(img, LOG_NS[i], JAZZY.serialize_cdr(_image(JAZZY, i, ros1=False), IMAGE))
        t = JAZZY.types
        msg = t[INFO](
            t["std_msgs/msg/Header"](t["builtin_interfaces/msg/Time"](*STAMPS[0]), "cam"),
            480, 640, "plumb_bob", np.zeros(5), np.array([525.0, 0, 319.5, 0, 525.0, 239.5, 0, 0, 1]),
            np.eye(3).ravel(), np.zeros(12), 0, 0,
            t["sensor_msgs/msg/RegionOfInterest"](0, 0, 0, 0, False),
        )  # fmt: skip
        w.write(info, LOG_NS[0] - 1, JAZZY.serialize_cdr(msg, INFO))


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("bags")
    write_ros1(d / "tum.bag")
    write_ros2(d / "sqlite", StoragePlugin.SQLITE3)
    write_ros2(d / "mcapdir", StoragePlugin.MCAP)
    mcaps = list((d / "mcapdir").glob("*.mcap"))
    assert len(mcaps) == 1
    return {"ros1": d / "tum.bag", "sqlite": d / "sqlite", "mcapdir": d / "mcapdir", "mcap": mcaps[0]}


def test_kinds_are_detected_from_content(bags: dict[str, Path]) -> None:
    assert detect_bag_kind(bags["ros1"]) is BagKind.ROS1
    assert detect_bag_kind(bags["sqlite"]) is BagKind.ROS2_SQLITE3
    assert detect_bag_kind(bags["mcapdir"]) is BagKind.ROS2_MCAP
    assert detect_bag_kind(bags["mcap"]) is BagKind.MCAP


def test_ros1_payloads_become_cdr_with_ros2_names_and_stamps(bags: dict[str, Path]) -> None:
    with BagMessages(bags["ros1"]) as bag:
        topics = bag.topics
        assert topics["/camera/rgb/image_color"].msgtype == IMAGE
        assert topics["/camera/rgb/image_color"].msgcount == 3
        assert topics["/tf"].msgtype == "tf2_msgs/msg/TFMessage"
        assert topics["/tf"].latched and not topics["/camera/rgb/image_color"].latched
        msgs = list(bag.messages())
    assert [m.topic for m in msgs] == ["/camera/rgb/image_color", "/tf"] * 3
    images = [m for m in msgs if m.msgtype == IMAGE]
    assert [m.log_stamp_ns for m in images] == LOG_NS
    assert [m.header_stamp_ns for m in images] == [s * 10**9 + ns for s, ns in STAMPS]
    # The CDR bytes decode with the plain ROS 2 Jazzy definitions, as rclpy will see them.
    img = JAZZY.deserialize_cdr(images[2].cdr, IMAGE)
    assert (img.height, img.width, img.encoding, img.step) == (2, 3, "rgb8", 9)
    assert img.header.frame_id == "openni_rgb_optical_frame"
    np.testing.assert_array_equal(img.data, np.arange(18, dtype=np.uint8) + 2)
    tf = JAZZY.deserialize_cdr([m for m in msgs if m.topic == "/tf"][1].cdr, "tf2_msgs/msg/TFMessage")
    assert tf.transforms[0].child_frame_id == "/kinect"
    assert tf.transforms[0].transform.translation.x == 2.0
    assert [m.header_stamp_ns for m in msgs if m.topic == "/tf"] == [None] * 3


@pytest.mark.parametrize("key", ["sqlite", "mcapdir", "mcap"])
def test_ros2_bags_yield_stored_cdr_in_log_order(bags: dict[str, Path], key: str) -> None:
    with BagMessages(bags[key]) as bag:
        assert bag.topics["/camera/color/camera_info"].latched
        assert bag.message_count == 4
        assert (bag.start_ns, bag.end_ns) == (LOG_NS[0] - 1, LOG_NS[2] + 1)
        msgs = list(bag.messages())
        assert [m.log_stamp_ns for m in msgs] == [LOG_NS[0] - 1, *LOG_NS]
        info = bag.deserialize(msgs[0])
        assert list(info.k) == [525.0, 0, 319.5, 0, 525.0, 239.5, 0, 0, 1]
        only = list(bag.messages(topics={"/camera/color/image_raw"}, start_ns=LOG_NS[1]))
    assert [m.header_stamp_ns for m in only] == [s * 10**9 + ns for s, ns in STAMPS[1:]]
    np.testing.assert_array_equal(
        JAZZY.deserialize_cdr(only[0].cdr, IMAGE).data, np.arange(18, dtype=np.uint8) + 1
    )


def test_unknown_topic_filter_yields_nothing(bags: dict[str, Path]) -> None:
    with BagMessages(bags["ros1"]) as bag:
        assert list(bag.messages(topics={"/nope"})) == []


def test_missing_path_raises_bag_error_naming_it(tmp_path: Path) -> None:
    with pytest.raises(BagError, match=r"nothere\.bag: no such file"):
        BagMessages(tmp_path / "nothere.bag")


def test_folder_without_metadata_is_rejected(tmp_path: Path) -> None:
    with pytest.raises(BagError, match=r"not a ROS 2 bag \(no metadata.yaml\)"):
        BagMessages(tmp_path)


def test_garbage_files_are_rejected_by_magic(tmp_path: Path) -> None:
    for name in ("x.bag", "x.mcap", "x.txt"):
        (tmp_path / name).write_bytes(b"this is not a bag at all")
    with pytest.raises(BagError, match=r"x\.bag: not a ROS 1 bag"):
        BagMessages(tmp_path / "x.bag")
    with pytest.raises(BagError, match=r"x\.mcap: not an mcap file"):
        BagMessages(tmp_path / "x.mcap")
    with pytest.raises(BagError, match=r"x\.txt: unrecognised bag"):
        BagMessages(tmp_path / "x.txt")


@pytest.mark.parametrize("key", ["ros1", "mcap"])
def test_truncated_files_raise_bag_error_naming_the_file(
    bags: dict[str, Path], key: str, tmp_path: Path
) -> None:
    data = bags[key].read_bytes()
    for keep in (0.3, 0.6, 0.9):
        cut = tmp_path / f"cut{int(keep * 10)}{bags[key].suffix}"
        cut.write_bytes(data[: int(len(data) * keep)])
        with pytest.raises(BagError, match=cut.name):
            with BagMessages(cut) as bag:
                list(bag.messages())


def test_corrupted_chunk_raises_bag_error(bags: dict[str, Path], tmp_path: Path) -> None:
    data = bytearray(bags["ros1"].read_bytes())
    # Overwrite the middle of the file (inside the message chunk) with noise.
    mid = len(data) // 2
    data[mid - 40 : mid + 40] = bytes(range(80))
    bad = tmp_path / "bad.bag"
    bad.write_bytes(bytes(data))
    with pytest.raises(BagError, match=r"bad\.bag"):
        with BagMessages(bad) as bag:
            for msg in bag.messages():
                bag.deserialize(msg)


def test_sqlite_bag_with_broken_database_raises_bag_error(bags: dict[str, Path], tmp_path: Path) -> None:
    import shutil

    broken = tmp_path / "broken"
    shutil.copytree(bags["sqlite"], broken)
    for db in broken.glob("*.db3"):
        db.write_bytes(b"not sqlite" * 100)
    with pytest.raises(BagError, match="broken"):
        with BagMessages(broken) as bag:
            list(bag.messages())


def test_using_a_closed_reader_is_an_error(bags: dict[str, Path]) -> None:
    bag = BagMessages(bags["mcap"])
    with pytest.raises(BagError, match="not open"):
        list(bag.messages())


@pytest.mark.parametrize("key", ["ros1", "sqlite", "mcap"])
def test_index_pass_without_payload_gives_the_same_stamps(bags: dict[str, Path], key: str) -> None:
    with BagMessages(bags[key]) as bag:
        full = [(m.topic, m.log_stamp_ns, m.header_stamp_ns) for m in bag.messages()]
        light = list(bag.messages(payload=False))
    assert [(m.topic, m.log_stamp_ns, m.header_stamp_ns) for m in light] == full
    assert all(m.cdr == b"" for m in light)


def test_payload_can_be_kept_for_some_topics_only(bags: dict[str, Path]) -> None:
    with BagMessages(bags["sqlite"]) as bag:
        msgs = list(bag.messages(payload={"/camera/color/camera_info"}))
    assert [len(m.cdr) > 0 for m in msgs] == [True, False, False, False]
    assert msgs[1].header_stamp_ns == STAMPS[0][0] * 10**9 + STAMPS[0][1]


@pytest.mark.ros
def test_ros1_payloads_deserialize_with_rclpy_as_bag_player_publishes_them(ros1_tum_bag: Path) -> None:
    serialization = pytest.importorskip("rclpy.serialization")
    sensor_msgs = pytest.importorskip("sensor_msgs.msg")
    tf2_msgs = pytest.importorskip("tf2_msgs.msg")
    classes = {
        "sensor_msgs/msg/Image": sensor_msgs.Image,
        "sensor_msgs/msg/CameraInfo": sensor_msgs.CameraInfo,
        "tf2_msgs/msg/TFMessage": tf2_msgs.TFMessage,
    }
    seen: dict[str, object] = {}
    with BagMessages(ros1_tum_bag) as bag:
        for msg in bag.messages():
            if msg.msgtype not in seen:
                seen[msg.msgtype] = serialization.deserialize_message(msg.cdr, classes[msg.msgtype])
                if msg.msgtype == IMAGE:
                    ref = bag.deserialize(msg)
    assert set(seen) == set(classes)
    img = seen[IMAGE]
    assert (img.height, img.width, img.encoding, img.step) == (480, 640, "rgb8", 1920)
    assert bytes(img.data) == bytes(ref.data) and img.header.stamp.sec == 1305031102
    assert img.header.stamp.nanosec == 175304000
    info = seen[INFO]
    assert list(info.k) == [525.0, 0.0, 319.5, 0.0, 525.0, 239.5, 0.0, 0.0, 1.0]
    tf = seen["tf2_msgs/msg/TFMessage"]
    # the first /tf message is the motion-capture pose, 0.1 s before the first image
    assert [(t.header.frame_id, t.child_frame_id) for t in tf.transforms] == [("/world", "/kinect")]
