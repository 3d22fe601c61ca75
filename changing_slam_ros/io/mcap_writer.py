"""Write RGB-D sequences as a bare ROS 2 mcap file (profile `ros2`, CDR, `ros2msg` schemas embedded).

Opens in Foxglove and rosbags, replays with `bag_player`, reads back with `BagRgbdReader`. TUM topic names:

| topic | type | content |
|---|---|---|
| `/camera/rgb/image_color` | Image rgb8 | colour (raw mode) |
| `/camera/depth/image` | Image 32FC1 | depth in metres, lossless (raw mode) |
| `/camera/rgb/image_color/compressed` | CompressedImage jpeg | colour (`compress=True`) |
| `/camera/depth/image/compressed` | CompressedImage png | depth, 16-bit millimetres (`compress=True`) |
| `/camera/rgb/camera_info` | CameraInfo | intrinsics, one per frame |
| `/ground_truth/pose` | PoseStamped | T_world_cam of the rgb optical frame in `world` |

Log time = header stamp; writes are atomic (`RgbdMcapWriter`).
"""

from __future__ import annotations

import os
from collections import deque
from contextlib import ExitStack
from collections.abc import Callable, Iterable
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.features.rgbd_frame import RgbdFrame
from changing_slam_ros.io.atomic import atomic_open
from changing_slam_ros.io.camera_info import camera_info_fields
from changing_slam_ros.io.dataset_config import TUM_TOPICS, TopicSet
from changing_slam_ros.io.groundtruth import GroundTruth
from changing_slam_ros.io.image_codec import (
    depth_image_fields,
    encode_compressed_rgb,
    encode_png_depth,
    rgb_image_fields,
)

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
POSE = "geometry_msgs/msg/PoseStamped"
GT_TOPIC = "/ground_truth/pose"
OPTICAL_FRAME = "openni_rgb_optical_frame"
WORLD_FRAME = "world"


class RgbdMcapWriter:
    """Context manager writing frames (and optional full-rate ground truth) to one mcap file.

    Colour and depth of a frame carry the colour stamp (the pair is already associated). The file is written to
    a temporary sibling and renamed on success: a failure never leaves a truncated file where a good one stood.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        compress: bool = False,
        jpeg_quality: int = 95,
        depth_encoding: str = "32FC1",
        topics: TopicSet = TUM_TOPICS,
        gt_topic: str = GT_TOPIC,
        frame_id: str = OPTICAL_FRAME,
        world_frame: str = WORLD_FRAME,
    ) -> None:
        from rosbags.typesys import Stores, get_typestore

        self.path = Path(path)
        self.compress = compress
        self.jpeg_quality = jpeg_quality
        self.depth_encoding = depth_encoding
        self.frame_id = frame_id
        self.world_frame = world_frame
        suffix = "/compressed" if compress else ""
        self.rgb_topic = topics.rgb + suffix
        self.depth_topic = topics.depth + suffix
        self.info_topic = topics.camera_info or TUM_TOPICS.camera_info
        self.gt_topic = gt_topic
        self._store = get_typestore(Stores.ROS2_JAZZY)
        self._writer: Any = None
        self._fh: Any = None
        self._stack: ExitStack | None = None
        self._channels: dict[str, int] = {}
        self._channel_types: dict[str, str] = {}
        self._schemas: dict[str, int] = {}
        self._seq: dict[int, int] = {}
        self._pending_gt: deque[tuple[int, np.ndarray]] = deque()
        self._full_gt = False
        self.frames_written = 0
        self.poses_written = 0

    # -- lifetime ----------------------------------------------------------------------------
    def __enter__(self) -> "RgbdMcapWriter":
        from mcap.writer import CompressionType, Writer

        self._stack = ExitStack()
        self._fh = self._stack.enter_context(atomic_open(self.path, "wb"))
        os.fchmod(self._fh.fileno(), _default_file_mode())  # mkstemp's 0600 -> what open() would give
        # Raw images: lz4 chunks (half the size, reads at about half the speed of uncompressed; zstd is
        # smaller still but reads 4x slower). JPEG/PNG payloads do not compress further: no chunk codec.
        codec = CompressionType.NONE if self.compress else CompressionType.LZ4
        self._writer = Writer(self._fh, compression=codec, chunk_size=4 * 1024 * 1024)
        self._writer.start(profile="ros2", library="changing_slam_ros")
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if exc_type is None:
            self._flush_gt(None)
            self._writer.finish()
        # io.atomic renames the temporary file into place on success and deletes it on an exception
        stack, self._stack, self._writer = self._stack, None, None
        assert stack is not None
        stack.__exit__(exc_type, exc, tb)

    # -- content -------------------------------------------------------------------------------
    def add_groundtruth(self, gt: GroundTruth) -> None:
        """Queue a full-rate ground truth; poses are interleaved in time order with the frames.

        Frames' own `T_world_cam_gt` are then not written (they are samples of this one).
        """
        self._full_gt = True
        merged = list(self._pending_gt)
        for s, p, q in zip(gt.stamps_ns.tolist(), gt.positions, gt.quats_xyzw):
            merged.append((int(s), np.concatenate([p, q])))
        merged.sort(key=lambda x: x[0])
        self._pending_gt = deque(merged)

    def write_frame(self, frame: RgbdFrame, camera: CameraIntrinsics | None = None) -> None:
        """Colour, depth and CameraInfo at the frame's stamp (+ its ground truth when no full-rate one)."""
        stamp = int(frame.stamp_ns)
        self._flush_gt(stamp)
        t = self._store.types
        header = self._header(stamp)
        if self.compress:
            fmt, data = encode_compressed_rgb(frame.rgb, "jpeg", self.jpeg_quality)
            rgb_msg = t[COMPRESSED](header, fmt, data)
            fmt, data = encode_png_depth(frame.depth_m)
            depth_msg = t[COMPRESSED](header, fmt, data)
        else:
            rgb_msg = t[IMAGE](header, **rgb_image_fields(frame.rgb, "rgb8"))
            depth_msg = t[IMAGE](header, **depth_image_fields(frame.depth_m, self.depth_encoding))
        cam = camera or frame.camera
        info = t[CAMERA_INFO](
            header, **camera_info_fields(cam), binning_x=0, binning_y=0,
            roi=t["sensor_msgs/msg/RegionOfInterest"](0, 0, 0, 0, False),
        )  # fmt: skip
        self._write(self.info_topic, CAMERA_INFO, info, stamp)
        self._write(self.rgb_topic, COMPRESSED if self.compress else IMAGE, rgb_msg, stamp)
        self._write(self.depth_topic, COMPRESSED if self.compress else IMAGE, depth_msg, stamp)
        if frame.T_world_cam_gt is not None and not self._full_gt:
            self.write_pose(stamp, frame.T_world_cam_gt)
        self.frames_written += 1

    def write_pose(self, stamp_ns: int, T_world_cam: np.ndarray) -> None:
        from changing_slam_ros.core.geometry.se3 import rot_to_quat

        q = rot_to_quat(np.asarray(T_world_cam)[:3, :3])
        self._write_pose_values(stamp_ns, np.concatenate([np.asarray(T_world_cam)[:3, 3], q]))

    @property
    def typestore(self) -> Any:
        """The rosbags typestore messages are built and serialised with (ROS 2 Jazzy types; register
        project message types on it before writing them)."""
        return self._store

    def write_message(self, topic: str, msgtype: str, msg: Any, stamp_ns: int) -> None:
        """Any other message (a rosbags dataclass of `typestore`), logged at `stamp_ns`.

        The channel and its schema are registered on first use; e.g. the simulator's object poses.
        """
        self._write(topic, msgtype, msg, int(stamp_ns))

    # -- internals -----------------------------------------------------------------------------
    def _flush_gt(self, until_ns: int | None) -> None:
        while self._pending_gt and (until_ns is None or self._pending_gt[0][0] <= until_ns):
            s, v = self._pending_gt.popleft()
            self._write_pose_values(s, v)

    def _write_pose_values(self, stamp_ns: int, v: np.ndarray) -> None:
        t = self._store.types
        pose = t["geometry_msgs/msg/Pose"](
            t["geometry_msgs/msg/Point"](float(v[0]), float(v[1]), float(v[2])),
            t["geometry_msgs/msg/Quaternion"](float(v[3]), float(v[4]), float(v[5]), float(v[6])),
        )
        msg = t[POSE](self._header(stamp_ns, self.world_frame), pose)
        self._write(self.gt_topic, POSE, msg, stamp_ns)
        self.poses_written += 1

    def _header(self, stamp_ns: int, frame_id: str | None = None) -> Any:
        t = self._store.types
        sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
        return t["std_msgs/msg/Header"](t["builtin_interfaces/msg/Time"](sec, nsec), frame_id or self.frame_id)

    def _channel(self, topic: str, msgtype: str) -> int:
        """Channel id of `topic`, registered (with its schema) on first use."""
        if topic not in self._channels:
            if msgtype not in self._schemas:
                self._schemas[msgtype] = self._writer.register_schema(
                    name=msgtype,
                    encoding="ros2msg",
                    data=self._store.generate_msgdef(msgtype, ros_version=2)[0].encode(),
                )
            self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding="cdr", schema_id=self._schemas[msgtype]
            )
            self._channel_types[topic] = msgtype
        elif self._channel_types[topic] != msgtype:
            raise ValueError(f"{topic} already carries {self._channel_types[topic]}, not {msgtype}")
        return self._channels[topic]

    def _write(self, topic: str, msgtype: str, msg: Any, stamp_ns: int) -> None:
        channel = self._channel(topic, msgtype)
        data = bytes(self._store.serialize_cdr(msg, msgtype))
        seq = self._seq.get(channel, 0)
        self._seq[channel] = seq + 1
        self._writer.add_message(channel, log_time=stamp_ns, data=data, publish_time=stamp_ns, sequence=seq)


def _default_file_mode() -> int:
    """0o666 minus the process umask (read without changing it: /proc, else a set-and-restore)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return 0o666 & ~int(line.split()[1], 8)
    except OSError:
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return 0o666 & ~mask


def write_rgbd_mcap(
    path: str | Path,
    frames: Iterable[RgbdFrame],
    camera: CameraIntrinsics | None = None,
    gt: GroundTruth | None = None,
    *,
    compress: bool = False,
    progress: Callable[[int], None] | None = None,
) -> int:
    """Write frames (and a full-rate ground truth, if given) to a bare ROS 2 mcap; returns frames written.

    Without `gt`, each frame's `T_world_cam_gt` is written at the frame stamp. `camera` overrides
    the frames' own intrinsics in the CameraInfo messages. `progress(n)` is called after each frame.
    """
    with RgbdMcapWriter(path, compress=compress) as writer:
        if gt is not None:
            writer.add_groundtruth(gt)
        for frame in frames:
            writer.write_frame(frame, camera)
            if progress is not None:
                progress(writer.frames_written)
        return writer.frames_written
