"""RgbdFrame reader over ROS 1 bags, ROS 2 bags (sqlite3, mcap) and bare mcap files.

Opening makes one indexing pass over the small topics and the image stamps (image payloads are read
but not decoded or kept): it finds the topics (configured, or the TUM / RealSense set the bag has,
including `/compressed` and `/compressedDepth` variants), pairs colour and depth by their header
stamps exactly as TUM's associate.py does (`dataset.max_time_diff_s` slop, `offset_s` added to depth),
reads CameraInfo and builds the ground truth (a PoseStamped topic, else the TF chain). Iterating
makes a second pass and decodes each pair as it completes, so memory stays at a few images.

Frames carry the colour image's header stamp and the intrinsics of the latest CameraInfo received
before them (or the config's camera: `dataset.bag_intrinsics_from`). `camera_mismatch` says when the first
CameraInfo and the config's camera disagree (a CameraInfo equal to the ROS driver default is no calibration
and is not compared).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.features.rgbd_frame import RgbdFrame
from changing_slam_ros.errors import BagError, SlamError
from changing_slam_ros.io.bag_messages import BagConnection, BagMessages, RawMessage
from changing_slam_ros.io.camera_check import ROS_DEFAULT_CAMERA, CameraMismatch, check_cameras, compare_cameras
from changing_slam_ros.io.camera_info import intrinsics_from_camera_info
from changing_slam_ros.io.dataset_config import CameraConfig, DatasetConfig, TopicSet
from changing_slam_ros.io.groundtruth import GroundTruth, GroundTruthAccess
from changing_slam_ros.io.image_codec import decode_any_depth, decode_any_rgb
from changing_slam_ros.io.tf_chain import TfBuffer, transform_matrix
from changing_slam_ros.io.tum_folder import associate, format_stamp

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
CAMERA_INFO_TYPE = "sensor_msgs/msg/CameraInfo"
POSE_TYPES = ("geometry_msgs/msg/PoseStamped",)
TF_TYPE = "tf2_msgs/msg/TFMessage"


@dataclass(frozen=True)
class _Pair:
    rgb_ordinal: int  # k-th message on the colour topic
    depth_ordinal: int
    rgb_stamp_ns: int
    depth_stamp_ns: int


def resolve_topics(bag: BagMessages, config: DatasetConfig) -> TopicSet:
    """The colour / depth / camera_info topics to read; BagError listing the bag's topics if absent."""
    topics = bag.topics
    candidates = config.candidate_topics()
    for cand in candidates:
        rgb = _present(topics, cand.rgb, ("/compressed",))
        depth = _present(topics, cand.depth, ("/compressedDepth", "/compressed"))
        if rgb and depth:
            info = cand.camera_info if cand.camera_info in topics else ""
            return TopicSet(rgb, depth, info)
    wanted = " or ".join(f"{c.rgb} + {c.depth}" for c in candidates)
    raise BagError(
        f"{bag.path}: no colour/depth topics {wanted} (or their /compressed variants); "
        f"the bag has: {bag.describe_topics()}; set dataset.rgb_topic / depth_topic"
    )


def _present(topics: dict[str, BagConnection], name: str, suffixes: tuple[str, ...]) -> str:
    for t in (name, *(name + s for s in suffixes)):
        if t in topics and topics[t].msgtype in IMAGE_TYPES:
            return t
    return ""


@dataclass(frozen=True)
class SkippedMessage:
    """A message the reader could not use: its topic, stamp (header, else log time) and why."""

    topic: str
    stamp_ns: int
    reason: str

    def message(self) -> str:
        return f"skipped a malformed message on {self.topic} at stamp {format_stamp(self.stamp_ns)} s: {self.reason}"


class MalformedMessage(BagError):
    """One message that cannot be decoded (raised when the reader is `strict`); `skipped` says which."""

    def __init__(self, path: Path, skipped: SkippedMessage) -> None:
        super().__init__(f"{path}: {skipped.topic} at stamp {format_stamp(skipped.stamp_ns)} s: {skipped.reason}")
        self.skipped = skipped

    @classmethod
    def of(cls, path: Path, msg: RawMessage, err: BagError) -> MalformedMessage:
        reason = str(err)
        for prefix in (f"{path}: ", f"{msg.topic}: "):  # the message names both already
            reason = reason.removeprefix(prefix)
        return cls(path, SkippedMessage(msg.topic, _stamp(msg), reason))


class BagRgbdReader(GroundTruthAccess):
    """RgbdSource over one bag file or folder.

    A colour, depth or CameraInfo message that cannot be decoded ends the iteration with a `MalformedMessage`
    when `strict`; otherwise its frame is skipped (a CameraInfo: the frames keep the previous one), the
    message recorded in `skipped` and passed to `on_skip`."""

    def __init__(self, path: str | Path, config: DatasetConfig, camera: CameraConfig | None = None,
                 config_name: str = "the config", strict: bool = True,
                 on_skip: Callable[[SkippedMessage], None] | None = None) -> None:  # fmt: skip
        self.strict = strict
        self.on_skip = on_skip
        self.skipped: list[SkippedMessage] = []
        self.path = Path(path)
        self.config = config
        self._config_camera = camera
        self.config_name = config_name
        self.camera_mismatch: CameraMismatch | None = None
        with BagMessages(self.path) as bag:
            self.kind = bag.kind
            self.topics = resolve_topics(bag, config)
            self._gt_source = self._index(bag)
        self.camera = self._initial_camera()
        self.camera_mismatch = self._check_camera()
        gt_text = f"ground truth from {self._gt_source}" if self._gt is not None else "no ground truth"
        self.description = (
            f"{bag.kind.value} {self.path} ({len(self._pairs)} frames: {self.topics.rgb} + "
            f"{self.topics.depth}, {gt_text}; intrinsics from {self._camera_source})"
        )

    # -- RgbdSource ----------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self._pairs)

    def __iter__(self) -> Iterator[RgbdFrame]:
        self.skipped = []
        want_rgb = {p.rgb_ordinal: k for k, p in enumerate(self._pairs)}
        want_depth = {p.depth_ordinal: k for k, p in enumerate(self._pairs)}
        rgb_msgs: dict[int, tuple[RawMessage, CameraIntrinsics]] = {}
        depth_msgs: dict[int, RawMessage] = {}
        next_k = 0
        n_rgb = n_depth = 0
        camera = self.camera
        info_cache: dict[bytes, CameraIntrinsics] = {}
        topics = {self.topics.rgb, self.topics.depth} | ({self.topics.camera_info} - {""})
        with BagMessages(self.path) as bag:
            for msg in bag.messages(topics=topics):
                if msg.topic == self.topics.camera_info:
                    if self._track_camera_info:
                        if msg.cdr not in info_cache:
                            try:
                                info_cache[msg.cdr] = intrinsics_from_camera_info(bag.deserialize(msg), msg.topic)
                            except BagError as err:  # the frames keep the latest good CameraInfo
                                self._skip(MalformedMessage.of(self.path, msg, err))
                                continue
                        camera = info_cache[msg.cdr]
                    continue
                if msg.topic == self.topics.rgb:
                    if n_rgb in want_rgb:
                        rgb_msgs[want_rgb[n_rgb]] = (msg, camera)
                    n_rgb += 1
                else:
                    if n_depth in want_depth:
                        depth_msgs[want_depth[n_depth]] = msg
                    n_depth += 1
                while next_k in rgb_msgs and next_k in depth_msgs:
                    (rgb_msg, cam), depth_msg = rgb_msgs.pop(next_k), depth_msgs.pop(next_k)
                    try:
                        frame = self._frame(bag, next_k, rgb_msg, depth_msg, cam)
                    except MalformedMessage as err:
                        self._skip(err)
                        frame = None
                    next_k += 1
                    if frame is not None:
                        yield frame
        if next_k != len(self._pairs):
            raise BagError(
                f"{self.path}: bag changed while reading (frame {next_k} of {len(self._pairs)} never completed)"
            )

    # -- internals -----------------------------------------------------------------------------
    def _skip(self, err: MalformedMessage) -> None:
        """Record (and report through `on_skip`) a malformed message; raise it instead when `strict`."""
        if self.strict:
            raise err
        self.skipped.append(err.skipped)
        if self.on_skip is not None:
            self.on_skip(err.skipped)

    def _frame(
        self, bag: BagMessages, k: int, rgb_msg: RawMessage, depth_msg: RawMessage, camera: CameraIntrinsics
    ) -> RgbdFrame:
        try:
            rgb = decode_any_rgb(bag.deserialize(rgb_msg), rgb_msg.topic)
        except BagError as err:
            raise MalformedMessage.of(self.path, rgb_msg, err) from err
        try:
            depth = decode_any_depth(bag.deserialize(depth_msg), depth_msg.topic)
        except BagError as err:
            raise MalformedMessage.of(self.path, depth_msg, err) from err
        if rgb.shape[:2] != depth.shape:
            raise MalformedMessage.of(self.path, depth_msg, BagError(
                f"depth is {depth.shape[1]}x{depth.shape[0]} but colour {rgb_msg.topic} is "
                f"{rgb.shape[1]}x{rgb.shape[0]}; they must be registered, same size"))  # fmt: skip
        if (rgb.shape[1], rgb.shape[0]) != (camera.width, camera.height):
            raise BagError(
                f"{self.path}: colour {rgb_msg.topic} is {rgb.shape[1]}x{rgb.shape[0]} but the camera "
                f"({self._camera_source}) is {camera.width}x{camera.height}"
            )
        stamp = self._pairs[k].rgb_stamp_ns
        T = None
        if self._gt is not None:
            T = self._gt.nearest_pose(stamp, round(self.config.gt_max_time_diff_s * 1e9))
        return RgbdFrame(stamp, rgb, depth, camera, T, k)

    def _index(self, bag: BagMessages) -> str:
        """First pass: image stamps, first CameraInfo, ground truth. Returns the ground-truth source."""
        cfg = self.config
        topics = bag.topics
        gt_pose = cfg.gt_pose_topic if cfg.gt_pose_topic in topics else ""
        if gt_pose and topics[gt_pose].msgtype not in POSE_TYPES:
            raise BagError(
                f"{self.path}: ground-truth topic {gt_pose} is {topics[gt_pose].msgtype}, expected PoseStamped"
            )
        tf_topics = set()
        if not gt_pose:
            tf_topics = {t for t in (cfg.tf_topic, "/tf_static") if t in topics and topics[t].msgtype == TF_TYPE}
        wanted = {self.topics.rgb, self.topics.depth, self.topics.camera_info, gt_pose} | tf_topics
        wanted.discard("")
        rgb_stamps: list[int] = []
        depth_stamps: list[int] = []
        self._first_info: CameraIntrinsics | None = None
        self._info_error: BagError | None = None
        info_read = False
        gt_stamps: list[int] = []
        gt_poses: list[np.ndarray] = []
        tf = TfBuffer(str(self.path))
        images = {self.topics.rgb, self.topics.depth}
        # one pass; image payloads are skipped (stamps only), the small topics are decoded
        for msg in bag.messages(topics=wanted, payload=wanted - images):
            if msg.topic == self.topics.rgb:
                rgb_stamps.append(_stamp(msg))
            elif msg.topic == self.topics.depth:
                depth_stamps.append(_stamp(msg))
            elif msg.topic == self.topics.camera_info:
                if not info_read:  # the first one: used with bag_intrinsics_from camera_info, else compared
                    info_read = True
                    try:
                        self._first_info = intrinsics_from_camera_info(bag.deserialize(msg), msg.topic)
                    except BagError as err:  # e.g. an uncalibrated driver: K all zero
                        self._info_error = err if cfg.bag_intrinsics_from == "camera_info" else None
            elif msg.topic == gt_pose:
                p = bag.deserialize(msg)
                pos, q = p.pose.position, p.pose.orientation
                gt_stamps.append(_stamp(msg))
                gt_poses.append(_pose(self.path, msg.topic, (pos.x, pos.y, pos.z), (q.x, q.y, q.z, q.w)))
            elif msg.topic in tf_topics:
                for ts in bag.deserialize(msg).transforms:
                    tr, rot = ts.transform.translation, ts.transform.rotation
                    stamp = ts.header.stamp.sec * 1_000_000_000 + ts.header.stamp.nanosec
                    T = _pose(self.path, msg.topic, (tr.x, tr.y, tr.z), (rot.x, rot.y, rot.z, rot.w))
                    tf.add(ts.header.frame_id, ts.child_frame_id, stamp, T, static=msg.topic == "/tf_static")
        if not rgb_stamps or not depth_stamps:
            empty = self.topics.rgb if not rgb_stamps else self.topics.depth
            raise BagError(f"{self.path}: topic {empty} has no messages")
        matches = associate(
            rgb_stamps, depth_stamps, round(cfg.offset_s * 1e9), round(cfg.max_time_diff_s * 1e9)
        )
        if not matches:
            raise BagError(
                f"{self.path}: no {self.topics.rgb} message has a {self.topics.depth} message within "
                f"{cfg.max_time_diff_s} s (offset {cfg.offset_s} s); check dataset.max_time_diff_s / offset_s"
            )
        self._pairs = [_Pair(i, j, rgb_stamps[i], depth_stamps[j]) for i, j in matches]
        self._gt: GroundTruth | None = None
        if gt_stamps:
            self._gt = GroundTruth.from_poses(gt_stamps, gt_poses)
            return f"{gt_pose} (PoseStamped)"
        if tf.edges:
            try:
                self._gt = tf.groundtruth(cfg.gt_world_frame, cfg.gt_camera_frame)
            except BagError:
                if not _has_frame(tf, cfg.gt_camera_frame):
                    return ""  # TF of something else (e.g. a robot), no camera ground truth
                raise
            return f"TF {cfg.gt_world_frame} -> {cfg.gt_camera_frame}"
        return ""

    def _check_camera(self) -> CameraMismatch | None:
        """The first CameraInfo against the config's camera, whichever of the two the frames use."""
        info = self._first_info
        if info is None or self._config_camera is None or not compare_cameras(ROS_DEFAULT_CAMERA, info, False):
            return None
        try:
            configured = self._config_camera.intrinsics()
        except SlamError:
            return None
        from_info = self._track_camera_info
        used = "the CameraInfo (dataset.bag_intrinsics_from: camera_info)" if from_info else \
            f"the camera of {self.config_name} (dataset.bag_intrinsics_from: config)"
        return check_cameras(f"the CameraInfo on {self.topics.camera_info} of {self.path}", info, self.config_name,
                             configured, used)  # fmt: skip

    def _initial_camera(self) -> CameraIntrinsics:
        cfg = self.config
        self._track_camera_info = False
        if cfg.bag_intrinsics_from == "camera_info" and self._first_info is not None:
            self._camera_source = f"CameraInfo on {self.topics.camera_info}"
            self._track_camera_info = True
            return self._first_info
        if self._info_error is not None and self._config_camera is None:
            raise BagError(f"{self.path}: {self._info_error} and the config has no camera: section to use instead")
        if self._config_camera is None:
            if cfg.bag_intrinsics_from == "config":
                raise BagError(f"{self.path}: dataset.bag_intrinsics_from is 'config' but the config has no camera:")
            raise BagError(
                f"{self.path}: no CameraInfo topic ({self.topics.camera_info or 'none found next to '}"
                f"{'' if self.topics.camera_info else self.topics.rgb}) and no camera: section in the config"
            )
        self._camera_source = "config camera section"
        if self._info_error is not None:
            self._camera_source += f" (CameraInfo unusable: {self._info_error})"
        try:
            return self._config_camera.intrinsics()
        except SlamError as err:
            raise BagError(f"{self.path}: {err}") from err


def _stamp(msg: RawMessage) -> int:
    return msg.header_stamp_ns if msg.header_stamp_ns is not None else msg.log_stamp_ns


def _pose(path: Path, topic: str, t: tuple[float, float, float], q: tuple[float, float, float, float]) -> Any:
    try:
        return transform_matrix(t, q)
    except ValueError as err:
        raise BagError(f"{path}: {topic}: pose has a {err}") from err


def _has_frame(tf: TfBuffer, name: str) -> bool:
    return name.lstrip("/") in tf.frames()

