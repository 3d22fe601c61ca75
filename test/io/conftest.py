"""Bags in every format, written by the tests themselves from the real TUM fr1_xyz frames.

- `ros1_tum_bag`: ROS 1 bag as TUM distributes them: `/camera/rgb/image_color` rgb8,
  `/camera/depth/image` 32FC1 metres with NaN holes at the depth frames' own stamps,
  `/camera/rgb/camera_info` with the ROS default 525/525/319.5/239.5, ground truth in `/tf`
  (`/world -> /kinect` at the ground-truth stamps plus a constant chain down to
  `/openni_rgb_optical_frame`, republished on `/tf`), types `tf/tfMessage` and ROS 1 Headers.
- `ros2_sqlite_bag`: ROS 2 bag, sqlite3 storage, RealSense topics, JPEG colour on
  `.../image_raw/compressed`, 16UC1 depth, CameraInfo, ground truth in `/tf` + `/tf_static`.
- `ros2_mcap_bag`: ROS 2 bag, mcap storage, RealSense topics, PNG colour on `.../compressed`,
  `compressedDepth` 16UC1 depth, ground truth as PoseStamped on `/ground_truth/pose`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers import FR1_XYZ_10, require
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from changing_slam_ros.core.geometry.se3 import invert, rot_to_quat
from changing_slam_ros.io.camera_info import camera_info_fields
from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.io.groundtruth import GroundTruth, pose_matrix
from changing_slam_ros.io.image_codec import depth_image_fields, encode_compressed_depth, encode_compressed_rgb, rgb_image_fields
from changing_slam_ros.io.tum_folder import read_groundtruth

ROS_DEFAULT_CAMERA = CameraIntrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)
REALSENSE_CAMERA = CameraIntrinsics(640, 480, 615.3, 615.9, 322.4, 238.7)

# Constant chain kinect -> openni_camera -> openni_rgb_frame -> openni_rgb_optical_frame: small offsets
# and the REP-103 optical rotation, so a mistake in chaining or direction shows.
STATIC_CHAIN = [
    ("/kinect", "/openni_camera", (0.01, -0.02, 0.03), (0.0, 0.0, 0.0871557, 0.9961947)),
    ("/openni_camera", "/openni_rgb_frame", (0.0, -0.045, 0.0), (0.0, 0.0, 0.0, 1.0)),
    ("/openni_rgb_frame", "/openni_rgb_optical_frame", (0.0, 0.0, 0.0), (-0.5, 0.5, -0.5, 0.5)),
]


@dataclass(frozen=True)
class SourceFrame:
    """One real fr1 frame: colour stamp and RGB, the depth stamp and metres it was paired with."""

    rgb_stamp_ns: int
    rgb: np.ndarray
    depth_stamp_ns: int
    depth_m: np.ndarray


@dataclass(frozen=True)
class Fr1Source:
    frames: list[SourceFrame]
    gt: GroundTruth


@pytest.fixture(scope="session")
def realsense_camera() -> CameraIntrinsics:
    return REALSENSE_CAMERA


@pytest.fixture(scope="session")
def fr1_source() -> Fr1Source:
    root = require(FR1_XYZ_10)
    frames = []
    for line in (root / "associations.txt").read_text().splitlines():
        if not line.strip():
            continue
        t_rgb, rgb_rel, t_depth, depth_rel = line.split()
        bgr = cv2.imread(str(root / rgb_rel), cv2.IMREAD_COLOR)
        raw = cv2.imread(str(root / depth_rel), cv2.IMREAD_UNCHANGED)
        frames.append(
            SourceFrame(
                read_file_list_stamp(t_rgb), bgr[:, :, ::-1].copy(),
                read_file_list_stamp(t_depth), raw.astype(np.float32) / np.float32(5000.0),
            )  # fmt: skip
        )
    return Fr1Source(frames, read_groundtruth(root / "groundtruth.txt"))


def read_file_list_stamp(text: str) -> int:
    from changing_slam_ros.io.tum_folder import parse_stamp_ns

    return parse_stamp_ns(text)


def _time(t, stamp_ns: int):  # noqa: ANN001, ANN202
    sec, nsec = divmod(stamp_ns, 1_000_000_000)
    return t["builtin_interfaces/msg/Time"](sec, nsec)


def _transform(t, xyz, q):  # noqa: ANN001, ANN202
    return t["geometry_msgs/msg/Transform"](
        t["geometry_msgs/msg/Vector3"](*map(float, xyz)), t["geometry_msgs/msg/Quaternion"](*map(float, q))
    )


def static_chain_matrix() -> np.ndarray:
    T = np.eye(4)
    for _, _, xyz, q in STATIC_CHAIN:
        T = T @ pose_matrix(np.array(xyz), np.array(q) / np.linalg.norm(q))
    return T


def _info_msg(t, header, camera: CameraIntrinsics):  # noqa: ANN001, ANN202
    f = camera_info_fields(camera)
    return t["sensor_msgs/msg/CameraInfo"](
        header, f["height"], f["width"], f["distortion_model"], f["d"], f["k"], f["r"], f["p"], 0, 0,
        t["sensor_msgs/msg/RegionOfInterest"](0, 0, 0, 0, False),
    )  # fmt: skip


@pytest.fixture(scope="session")
def ros1_tum_bag(fr1_source: Fr1Source, tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("ros1") / "rgbd_dataset_freiburg1_xyz.bag"
    store = get_typestore(Stores.ROS1_NOETIC)
    store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf/msg/tfMessage"))
    t = store.types

    def header(seq: int, stamp_ns: int, frame: str):  # noqa: ANN202
        return t["std_msgs/msg/Header"](seq, _time(t, stamp_ns), frame)

    # messages: (log time, connection key, message); TUM bags log a little after the header stamp
    msgs: list[tuple[int, str, object]] = []
    for k, f in enumerate(fr1_source.frames):
        fields = rgb_image_fields(f.rgb, "rgb8")
        msgs.append((f.rgb_stamp_ns + 3_000_000, "rgb", t["sensor_msgs/msg/Image"](header(k, f.rgb_stamp_ns, "/openni_rgb_optical_frame"), **fields)))
        depth = f.depth_m.copy()
        depth[depth == 0] = np.nan  # TUM bags mark missing depth with NaN
        fields = depth_image_fields(np.zeros_like(depth), "32FC1")
        fields["data"] = depth.astype("<f4").view(np.uint8).reshape(-1)
        msgs.append((f.depth_stamp_ns + 2_000_000, "depth", t["sensor_msgs/msg/Image"](header(k, f.depth_stamp_ns, "/openni_depth_optical_frame"), **fields)))
        msgs.append((f.rgb_stamp_ns + 3_000_001, "info", _info_msg(t, header(k, f.rgb_stamp_ns, "/openni_rgb_optical_frame"), ROS_DEFAULT_CAMERA)))
        statics = [
            t["geometry_msgs/msg/TransformStamped"](header(0, f.rgb_stamp_ns, parent), child, _transform(t, xyz, q))
            for parent, child, xyz, q in STATIC_CHAIN
        ]
        msgs.append((f.rgb_stamp_ns + 1, "tf", t["tf/msg/tfMessage"](statics)))
    inv_static = invert(static_chain_matrix())
    g = fr1_source.gt
    lo, hi = fr1_source.frames[0].rgb_stamp_ns - 100_000_000, fr1_source.frames[-1].rgb_stamp_ns + 100_000_000
    for s, p, q in zip(g.stamps_ns.tolist(), g.positions, g.quats_xyzw):
        if not lo <= s <= hi:
            continue
        T_world_kinect = pose_matrix(p, q) @ inv_static
        ts = t["geometry_msgs/msg/TransformStamped"](
            header(0, s, "/world"), "/kinect", _transform(t, T_world_kinect[:3, 3], rot_to_quat(T_world_kinect[:3, :3]))
        )
        msgs.append((s + 500_000, "tf", t["tf/msg/tfMessage"]([ts])))
    msgs.sort(key=lambda m: m[0])
    types = {"rgb": "sensor_msgs/msg/Image", "depth": "sensor_msgs/msg/Image",
             "info": "sensor_msgs/msg/CameraInfo", "tf": "tf/msg/tfMessage"}  # fmt: skip
    topics = {"rgb": "/camera/rgb/image_color", "depth": "/camera/depth/image",
              "info": "/camera/rgb/camera_info", "tf": "/tf"}  # fmt: skip
    with Writer1(path) as w:
        conns = {k: w.add_connection(topics[k], types[k], typestore=store) for k in types}
        for log_ns, key, msg in msgs:
            w.write(conns[key], log_ns, store.serialize_ros1(msg, types[key]))
    return path


LATCHED = Qos(
    QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL,
    QosTime(0, 0), QosTime(0, 0), QosLiveliness.AUTOMATIC, QosTime(0, 0), False,
)  # fmt: skip


def _write_ros2(path: Path, fr1: Fr1Source, plugin: StoragePlugin, *, png_colour: bool, gt: str) -> Path:
    store = get_typestore(Stores.ROS2_JAZZY)
    t = store.types

    def header(stamp_ns: int, frame: str):  # noqa: ANN202
        return t["std_msgs/msg/Header"](_time(t, stamp_ns), frame)

    msgs: list[tuple[int, str, object]] = []
    for f in fr1.frames:
        fmt, data = encode_compressed_rgb(f.rgb, "png" if png_colour else "jpeg", 90)
        msgs.append((f.rgb_stamp_ns + 5_000_000, "rgb", t["sensor_msgs/msg/CompressedImage"](header(f.rgb_stamp_ns, "camera_color_optical_frame"), fmt, data)))
        if gt == "pose":  # mcap storage: compressedDepth
            fmt, data = encode_compressed_depth(f.depth_m, "16UC1")
            depth_msg = t["sensor_msgs/msg/CompressedImage"](header(f.depth_stamp_ns, "camera_color_optical_frame"), fmt, data)
        else:
            depth_msg = t["sensor_msgs/msg/Image"](header(f.depth_stamp_ns, "camera_color_optical_frame"), **depth_image_fields(f.depth_m, "16UC1"))
        msgs.append((f.depth_stamp_ns + 4_000_000, "depth", depth_msg))
        msgs.append((f.rgb_stamp_ns + 5_000_001, "info", _info_msg(t, header(f.rgb_stamp_ns, "camera_color_optical_frame"), REALSENSE_CAMERA)))
    g = fr1.gt
    lo, hi = fr1.frames[0].rgb_stamp_ns - 100_000_000, fr1.frames[-1].rgb_stamp_ns + 100_000_000
    # RealSense-like TF: odom -> camera_link moves, camera_link -> camera_color_optical_frame is static
    T_link_optical = pose_matrix(np.array([0.0, 0.015, 0.0]), np.array([-0.5, 0.5, -0.5, 0.5]))
    if gt == "tf":
        st = t["geometry_msgs/msg/TransformStamped"](header(fr1.frames[0].rgb_stamp_ns, "camera_link"), "camera_color_optical_frame",
                                                     _transform(t, T_link_optical[:3, 3], rot_to_quat(T_link_optical[:3, :3])))  # fmt: skip
        msgs.append((lo, "tf_static", t["tf2_msgs/msg/TFMessage"]([st])))
    for s, p, q in zip(g.stamps_ns.tolist(), g.positions, g.quats_xyzw):
        if not lo <= s <= hi:
            continue
        if gt == "tf":
            T = pose_matrix(p, q) @ invert(T_link_optical)
            ts = t["geometry_msgs/msg/TransformStamped"](header(s, "odom"), "camera_link",
                                                         _transform(t, T[:3, 3], rot_to_quat(T[:3, :3])))  # fmt: skip
            msgs.append((s + 1000, "tf", t["tf2_msgs/msg/TFMessage"]([ts])))
        else:
            pose = t["geometry_msgs/msg/Pose"](t["geometry_msgs/msg/Point"](*map(float, p)),
                                               t["geometry_msgs/msg/Quaternion"](*map(float, q)))  # fmt: skip
            msgs.append((s + 1000, "gt", t["geometry_msgs/msg/PoseStamped"](header(s, "world"), pose)))
    msgs.sort(key=lambda m: m[0])
    types = {"rgb": "sensor_msgs/msg/CompressedImage",
             "depth": "sensor_msgs/msg/CompressedImage" if gt == "pose" else "sensor_msgs/msg/Image",
             "info": "sensor_msgs/msg/CameraInfo", "tf": "tf2_msgs/msg/TFMessage",
             "tf_static": "tf2_msgs/msg/TFMessage", "gt": "geometry_msgs/msg/PoseStamped"}  # fmt: skip
    topics = {"rgb": "/camera/color/image_raw/compressed",
              "depth": "/camera/aligned_depth_to_color/image_raw" + ("/compressedDepth" if gt == "pose" else ""),
              "info": "/camera/color/camera_info", "tf": "/tf", "tf_static": "/tf_static", "gt": "/ground_truth/pose"}  # fmt: skip
    used = sorted({key for _, key, _ in msgs})
    with Writer2(path, version=9, storage_plugin=plugin) as w:
        conns = {
            k: w.add_connection(topics[k], types[k], typestore=store,
                                offered_qos_profiles=[LATCHED] if k == "tf_static" else [])  # fmt: skip
            for k in used
        }
        for log_ns, key, msg in msgs:
            w.write(conns[key], log_ns, store.serialize_cdr(msg, types[key]))
    return path


@pytest.fixture(scope="session")
def ros2_sqlite_bag(fr1_source: Fr1Source, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _write_ros2(tmp_path_factory.mktemp("ros2") / "realsense_sqlite", fr1_source,
                       StoragePlugin.SQLITE3, png_colour=False, gt="tf")  # fmt: skip


@pytest.fixture(scope="session")
def ros2_mcap_bag(fr1_source: Fr1Source, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _write_ros2(tmp_path_factory.mktemp("ros2") / "realsense_mcap", fr1_source,
                       StoragePlugin.MCAP, png_colour=True, gt="pose")  # fmt: skip
