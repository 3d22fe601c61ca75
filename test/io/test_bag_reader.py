"""RgbdFrame reading from bags in every format, checked against the real fr1 frames they were written from."""

from __future__ import annotations

from typing import Any

from pathlib import Path

import cv2
import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from changing_slam_ros.errors import BagError
from changing_slam_ros.io.bag_reader import BagRgbdReader
from changing_slam_ros.io.dataset import open_dataset
from changing_slam_ros.io.dataset_config import DatasetConfig, DatasetSettings, load_dataset_settings
from changing_slam_ros.io.groundtruth import GroundTruth
from changing_slam_ros.io.image_codec import encode_compressed_rgb
from changing_slam_ros.io.mcap_writer import write_rgbd_mcap
from changing_slam_ros.io.tum_folder import associate


def _expected_pairs(src: Any) -> list[tuple[int, int]]:
    return associate([f.rgb_stamp_ns for f in src.frames], [f.depth_stamp_ns for f in src.frames])


def _check_gt(frame_T: np.ndarray | None, gt: GroundTruth, stamp_ns: int) -> None:
    expected = gt.nearest_pose(stamp_ns, 20_000_000)
    assert expected is not None and frame_T is not None
    np.testing.assert_allclose(frame_T, expected, atol=1e-9)


def test_ros1_tum_bag_frames_equal_the_source(ros1_tum_bag: Path, fr1_source: Any) -> None:
    src = open_dataset(ros1_tum_bag, "tum_fr1")
    assert isinstance(src, BagRgbdReader)
    pairs = _expected_pairs(fr1_source)
    assert len(src) == len(pairs) == 8  # 9 colour and 9 depth stamps; associate.py pairs 8
    frames = list(src)
    for k, (frame, (i, j)) in enumerate(zip(frames, pairs)):
        assert frame.index == k
        assert frame.stamp_ns == fr1_source.frames[i].rgb_stamp_ns
        np.testing.assert_array_equal(frame.rgb, fr1_source.frames[i].rgb)
        np.testing.assert_array_equal(frame.depth_m, fr1_source.frames[j].depth_m)  # NaN holes -> 0.0
        _check_gt(frame.T_world_cam_gt, fr1_source.gt, frame.stamp_ns)
    # tum_fr1 config: calibrated intrinsics instead of the bag's ROS default CameraInfo
    assert (src.camera.fx, src.camera.fy, src.camera.cx, src.camera.cy) == (517.3, 516.5, 318.6, 255.3)
    assert "TF world -> openni_rgb_optical_frame" in src.description


def test_ros1_ground_truth_from_tf_equals_groundtruth_txt(ros1_tum_bag: Path, fr1_source: Any) -> None:
    src = BagRgbdReader(ros1_tum_bag, DatasetConfig())
    gt = src.groundtruth_stamped
    assert gt is not None and len(gt) > 30
    ref = fr1_source.gt
    idx = np.searchsorted(ref.stamps_ns, gt.stamps_ns)
    np.testing.assert_array_equal(ref.stamps_ns[idx], gt.stamps_ns)
    np.testing.assert_allclose(gt.positions, ref.positions[idx], atol=1e-9)
    # quaternions equal up to sign
    dots = np.abs(np.sum(gt.quats_xyzw * ref.quats_xyzw[idx], axis=1))
    np.testing.assert_allclose(dots, 1.0, atol=1e-9)
    traj = src.groundtruth
    assert traj is not None
    np.testing.assert_allclose(traj.stamps_s, gt.stamps_ns * 1e-9)


def test_ros1_bag_without_camera_config_uses_camera_info(ros1_tum_bag: Path) -> None:
    src = BagRgbdReader(ros1_tum_bag, DatasetConfig())
    assert (src.camera.fx, src.camera.cx, src.camera.cy) == (525.0, 319.5, 239.5)
    assert next(iter(src)).camera == src.camera


def test_ros2_sqlite_bag_realsense_topics_jpeg_and_16uc1(
    ros2_sqlite_bag: Path, fr1_source: Any, realsense_camera: Any
) -> None:
    s = load_dataset_settings("realsense_d435")
    settings = DatasetSettings(
        DatasetConfig(topic_preset="realsense", gt_world_frame="odom", gt_camera_frame="camera_color_optical_frame"),
        s.camera, "test",
    )  # fmt: skip
    src = open_dataset(ros2_sqlite_bag, settings)
    assert src.camera == realsense_camera  # from the bag's CameraInfo, not the config's typical values
    assert isinstance(src, BagRgbdReader) and src.topics.rgb == "/camera/color/image_raw/compressed"
    pairs = _expected_pairs(fr1_source)
    frames = list(src)
    assert len(frames) == len(pairs)
    for frame, (i, j) in zip(frames, pairs):
        assert frame.stamp_ns == fr1_source.frames[i].rgb_stamp_ns
        _, jpeg = encode_compressed_rgb(fr1_source.frames[i].rgb, "jpeg", 90)
        np.testing.assert_array_equal(frame.rgb, cv2.imdecode(jpeg, cv2.IMREAD_COLOR)[:, :, ::-1])
        assert np.abs(frame.rgb.astype(int) - fr1_source.frames[i].rgb).mean() < 4.0
        np.testing.assert_allclose(frame.depth_m, np.rint(fr1_source.frames[j].depth_m * 1000) / 1000, atol=1e-6)
        _check_gt(frame.T_world_cam_gt, fr1_source.gt, frame.stamp_ns)
    assert "TF odom -> camera_color_optical_frame" in src.description


def test_ros2_mcap_bag_png_colour_compressed_depth_and_pose_ground_truth(
    ros2_mcap_bag: Path, fr1_source: Any, realsense_camera: Any
) -> None:
    src = open_dataset(ros2_mcap_bag, None)  # auto-detects the RealSense topics
    assert isinstance(src, BagRgbdReader)
    assert src.topics.depth == "/camera/aligned_depth_to_color/image_raw/compressedDepth"
    assert src.camera == realsense_camera
    pairs = _expected_pairs(fr1_source)
    for frame, (i, j) in zip(src, pairs, strict=True):
        assert frame.stamp_ns == fr1_source.frames[i].rgb_stamp_ns
        np.testing.assert_array_equal(frame.rgb, fr1_source.frames[i].rgb)
        np.testing.assert_allclose(frame.depth_m, np.rint(fr1_source.frames[j].depth_m * 1000) / 1000, atol=1e-6)
        _check_gt(frame.T_world_cam_gt, fr1_source.gt, frame.stamp_ns)
    assert "/ground_truth/pose (PoseStamped)" in src.description


@pytest.mark.parametrize("compress", [False, True])
def test_bare_mcap_from_our_writer_reads_back(tmp_path: Path, compress: bool) -> None:
    from helpers import FR1_XYZ_10, require

    folder = open_dataset(require(FR1_XYZ_10), "tum_fr1")
    out = tmp_path / "fr1.mcap"
    n = write_rgbd_mcap(out, folder, gt=folder.groundtruth_stamped, compress=compress)  # type: ignore[attr-defined]
    assert n == 9
    back = open_dataset(out, "tum_fr1")
    assert len(back) == 9 and back.camera == folder.camera
    for a, b in zip(folder, back, strict=True):
        assert a.stamp_ns == b.stamp_ns
        if compress:
            assert np.abs(a.rgb.astype(int) - b.rgb).mean() < 4.0
            assert np.abs(a.depth_m - b.depth_m).max() <= 0.0005 + 1e-6
        else:
            np.testing.assert_array_equal(a.rgb, b.rgb)
            np.testing.assert_array_equal(a.depth_m, b.depth_m)
        np.testing.assert_allclose(a.T_world_cam_gt, b.T_world_cam_gt, atol=1e-12)
    gt_a, gt_b = folder.groundtruth, back.groundtruth
    np.testing.assert_array_equal(gt_a.stamps_s, gt_b.stamps_s)
    np.testing.assert_array_equal(gt_a.positions, gt_b.positions)


# -- bad input ----------------------------------------------------------------------------------------
def _small_ros2_bag(path: Path, topics: dict[str, tuple[str, list[object]]]) -> Path:
    store = get_typestore(Stores.ROS2_JAZZY)
    with Writer2(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        for topic, (msgtype, msgs) in topics.items():
            c = w.add_connection(topic, msgtype, typestore=store)
            for k, m in enumerate(msgs):
                w.write(c, 1_000_000_000 + k, store.serialize_cdr(m, msgtype))
    return path


def _image(store, w: int, h: int, enc: str, stamp_ns: int = 1_000_000_000):  # noqa: ANN001, ANN202
    t = store.types
    bpp = {"rgb8": 3, "16UC1": 2, "32FC1": 4, "bayer_grbg8": 1}[enc]
    sec, ns = divmod(stamp_ns, 1_000_000_000)
    hdr = t["std_msgs/msg/Header"](t["builtin_interfaces/msg/Time"](sec, ns), "cam")
    return t["sensor_msgs/msg/Image"](hdr, h, w, enc, 0, w * bpp, np.zeros(w * h * bpp, np.uint8))


def test_bag_without_configured_topics_lists_what_it_has(tmp_path: Path) -> None:
    store = get_typestore(Stores.ROS2_JAZZY)
    bag = _small_ros2_bag(tmp_path / "other", {"/front/image": ("sensor_msgs/msg/Image", [_image(store, 4, 3, "rgb8")])})
    with pytest.raises(BagError, match=r"other: no colour/depth topics .*the bag has: /front/image \(sensor_msgs/msg/Image\)"):
        open_dataset(bag, None)
    cfg = DatasetSettings(DatasetConfig(rgb_topic="/front/image", depth_topic="/front/depth"), None, "t")
    with pytest.raises(BagError, match=r"no colour/depth topics /front/image \+ /front/depth"):
        open_dataset(bag, cfg)


def test_colour_and_depth_of_different_sizes_are_rejected(tmp_path: Path) -> None:
    store = get_typestore(Stores.ROS2_JAZZY)
    bag = _small_ros2_bag(tmp_path / "mismatch", {
        "/camera/rgb/image_color": ("sensor_msgs/msg/Image", [_image(store, 640, 480, "rgb8")]),
        "/camera/depth/image": ("sensor_msgs/msg/Image", [_image(store, 320, 240, "32FC1")]),
    })  # fmt: skip
    src = open_dataset(bag, "sim")
    with pytest.raises(BagError, match=r"/camera/depth/image at stamp 1.000000 s: depth is 320x240 but colour "
                                       r"/camera/rgb/image_color is 640x480"):  # fmt: skip
        list(src)


def test_unknown_encoding_in_a_bag_names_topic_and_encoding(tmp_path: Path) -> None:
    store = get_typestore(Stores.ROS2_JAZZY)
    bag = _small_ros2_bag(tmp_path / "bayer", {
        "/camera/rgb/image_color": ("sensor_msgs/msg/Image", [_image(store, 8, 6, "bayer_grbg8")]),
        "/camera/depth/image": ("sensor_msgs/msg/Image", [_image(store, 8, 6, "32FC1")]),
    })  # fmt: skip
    with pytest.raises(BagError, match=r"/camera/rgb/image_color at stamp 1.000000 s: unsupported colour encoding "
                                       r"'bayer_grbg8'"):  # fmt: skip
        list(open_dataset(bag, "sim"))


def test_bag_without_camera_info_or_camera_config(tmp_path: Path) -> None:
    store = get_typestore(Stores.ROS2_JAZZY)
    bag = _small_ros2_bag(tmp_path / "nocam", {
        "/camera/rgb/image_color": ("sensor_msgs/msg/Image", [_image(store, 8, 6, "rgb8")]),
        "/camera/depth/image": ("sensor_msgs/msg/Image", [_image(store, 8, 6, "32FC1")]),
    })  # fmt: skip
    with pytest.raises(BagError, match=r"nocam: no CameraInfo topic .* and no camera: section"):
        open_dataset(bag, None)
    with pytest.raises(BagError, match=r"colour /camera/rgb/image_color is 8x6 but the camera \(config camera section\) is 640x480"):
        list(open_dataset(bag, "sim"))


def test_unpairable_stamps_are_explained(tmp_path: Path) -> None:
    store = get_typestore(Stores.ROS2_JAZZY)
    bag = _small_ros2_bag(tmp_path / "apart", {
        "/camera/rgb/image_color": ("sensor_msgs/msg/Image", [_image(store, 8, 6, "rgb8", 1_000_000_000)]),
        "/camera/depth/image": ("sensor_msgs/msg/Image", [_image(store, 8, 6, "32FC1", 1_500_000_000)]),
    })  # fmt: skip
    with pytest.raises(BagError, match=r"no /camera/rgb/image_color message has a /camera/depth/image message within 0\.02 s"):
        open_dataset(bag, "sim")
    ok = open_dataset(bag, DatasetSettings(DatasetConfig(offset_s=-0.5), load_dataset_settings("sim").camera, "t"))
    assert len(ok) == 1


def test_corrupt_and_truncated_bags_name_the_file(ros1_tum_bag: Path, tmp_path: Path) -> None:
    data = ros1_tum_bag.read_bytes()
    cut = tmp_path / "cut.bag"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(BagError, match=r"cut\.bag"):
        list(open_dataset(cut, "tum_fr1"))
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"\x89MCAP0\r\n" + bytes(range(256)) * 4)
    with pytest.raises(BagError, match=r"junk\.mcap: cannot open mcap file"):
        open_dataset(junk, "tum_fr1")


def test_mcap_writer_carries_extra_topics_and_omits_unused_ones(tmp_path: Path) -> None:
    from changing_slam_ros.io.bag_messages import BagMessages
    from changing_slam_ros.io.mcap_writer import RgbdMcapWriter
    from helpers import FR1_XYZ_10, require

    frame = next(iter(open_dataset(require(FR1_XYZ_10), "tum_fr1")))
    frame.T_world_cam_gt = None
    out = tmp_path / "extra.mcap"
    with RgbdMcapWriter(out) as w:
        t = w.typestore.types
        w.write_frame(frame)
        point = t["geometry_msgs/msg/PointStamped"](
            t["std_msgs/msg/Header"](t["builtin_interfaces/msg/Time"](1, 5), "world"),
            t["geometry_msgs/msg/Point"](1.0, 2.0, 3.0),
        )
        w.write_message("/objects/centroid", "geometry_msgs/msg/PointStamped", point, frame.stamp_ns)
        with pytest.raises(ValueError, match="already carries"):
            w.write_message("/objects/centroid", "geometry_msgs/msg/PoseStamped", point, frame.stamp_ns)
    with BagMessages(out) as bag:
        assert sorted(bag.topics) == ["/camera/depth/image", "/camera/rgb/camera_info",
                                      "/camera/rgb/image_color", "/objects/centroid"]  # fmt: skip
        msg = next(bag.messages(topics={"/objects/centroid"}))
        assert bag.deserialize(msg).point.z == 3.0 and msg.header_stamp_ns == 1_000_000_005
    assert open_dataset(out, None).groundtruth is None


def test_every_reader_is_an_rgbd_source(ros1_tum_bag: Path) -> None:
    from helpers import FR1_XYZ_10, require

    from changing_slam_ros.io.dataset import RgbdSource

    for src in (open_dataset(ros1_tum_bag, "tum_fr1"), open_dataset(require(FR1_XYZ_10), "tum_fr1")):
        assert isinstance(src, RgbdSource)
        gt = src.groundtruth_stamped
        assert gt is not None and src.groundtruth is not None and len(gt) == len(src.groundtruth)
        stamps = [f.stamp_ns for f in src]
        assert stamps == sorted(stamps) and len(stamps) == len(src)


def test_custom_topics_find_the_camera_info_beside_the_colour_topic(tmp_path: Path) -> None:
    from changing_slam_ros.core.geometry.camera import CameraIntrinsics
    from changing_slam_ros.io.camera_info import camera_info_fields

    store = get_typestore(Stores.ROS2_JAZZY)
    t = store.types
    cam = CameraIntrinsics(8, 6, 4.5, 4.6, 3.5, 2.5)
    f = camera_info_fields(cam)
    info = t["sensor_msgs/msg/CameraInfo"](
        t["std_msgs/msg/Header"](t["builtin_interfaces/msg/Time"](1, 0), "cam"), f["height"], f["width"],
        f["distortion_model"], f["d"], f["k"], f["r"], f["p"], 0, 0, t["sensor_msgs/msg/RegionOfInterest"](0, 0, 0, 0, False),
    )  # fmt: skip
    bag = _small_ros2_bag(tmp_path / "front", {
        "/front/image": ("sensor_msgs/msg/Image", [_image(store, 8, 6, "rgb8")]),
        "/front/depth": ("sensor_msgs/msg/Image", [_image(store, 8, 6, "16UC1")]),
        "/front/camera_info": ("sensor_msgs/msg/CameraInfo", [info]),
    })  # fmt: skip
    src = open_dataset(bag, DatasetSettings(DatasetConfig(rgb_topic="/front/image", depth_topic="/front/depth"), None, "t"))
    assert src.camera == cam
    frames = list(src)
    assert len(frames) == 1 and frames[0].depth_m.shape == (6, 8) and not frames[0].depth_m.any()


def test_uncalibrated_camera_info_falls_back_to_the_config_camera(tmp_path: Path) -> None:
    store = get_typestore(Stores.ROS2_JAZZY)
    t = store.types
    zero_k = t["sensor_msgs/msg/CameraInfo"](
        t["std_msgs/msg/Header"](t["builtin_interfaces/msg/Time"](1, 0), "cam"), 6, 8, "", np.zeros(0),
        np.zeros(9), np.zeros(9), np.zeros(12), 0, 0, t["sensor_msgs/msg/RegionOfInterest"](0, 0, 0, 0, False),
    )  # fmt: skip
    bag = _small_ros2_bag(tmp_path / "uncal", {
        "/camera/rgb/image_color": ("sensor_msgs/msg/Image", [_image(store, 640, 480, "rgb8")]),
        "/camera/depth/image": ("sensor_msgs/msg/Image", [_image(store, 640, 480, "32FC1")]),
        "/camera/rgb/camera_info": ("sensor_msgs/msg/CameraInfo", [zero_k]),
    })  # fmt: skip
    with pytest.raises(BagError, match=r"camera matrix has fx=0\.0.* and the config has no camera: section"):
        open_dataset(bag, None)
    src = open_dataset(bag, DatasetSettings(DatasetConfig(), load_dataset_settings("sim").camera, "t"))
    assert src.camera.fx == 525.0 and "CameraInfo unusable" in src.description
    assert next(iter(src)).camera.fx == 525.0
