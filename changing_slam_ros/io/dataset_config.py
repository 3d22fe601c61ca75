"""Typed `dataset:` and `camera:` configuration sections, and the topic presets for bags.

Built with `config.section` from a YAML file such as `config/tum_fr1.yaml`::

    camera: {width: 640, height: 480, fx: 517.3, fy: 516.5, cx: 318.6, cy: 255.3,
             dist: [0.2624, -0.9531, -0.0054, 0.0026, 1.1633]}
    dataset: {depth_scale: 5000.0, max_time_diff_s: 0.02}
"""

from __future__ import annotations

import math

from dataclasses import dataclass
from pathlib import Path

from changing_slam_ros.config import load_config, section
from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.errors import ConfigError


@dataclass(frozen=True)
class TopicSet:
    """Topic names of one camera driver's bag (`""` = not recorded / not wanted)."""

    rgb: str
    depth: str
    camera_info: str


TUM_TOPICS = TopicSet("/camera/rgb/image_color", "/camera/depth/image", "/camera/rgb/camera_info")
REALSENSE_TOPICS = TopicSet(
    "/camera/color/image_raw", "/camera/aligned_depth_to_color/image_raw", "/camera/color/camera_info"
)
# realsense2_camera 4.5x on Jazzy (rs_launch.py, align_depth.enable:=true): camera_namespace and camera_name
# both default to `camera`, so every topic is under /camera/camera.
REALSENSE_JAZZY_TOPICS = TopicSet(
    "/camera/camera/color/image_raw", "/camera/camera/aligned_depth_to_color/image_raw",
    "/camera/camera/color/camera_info",
)
# Our own mcaps (convert, simulator) use the TUM names, so they need no preset of their own.
TOPIC_PRESETS: dict[str, TopicSet] = {"tum": TUM_TOPICS, "realsense": REALSENSE_TOPICS,
                                      "realsense_jazzy": REALSENSE_JAZZY_TOPICS}  # fmt: skip


@dataclass(frozen=True)
class CameraConfig:
    """`camera:` section: pinhole intrinsics (pixels) and plumb-bob distortion (k1 k2 p1 p2 k3).

    - `width` / `height`: the image size the intrinsics are for; another size scales them.
    - `fx` / `fy`: focal lengths (pixels).
    - `cx` / `cy`: principal point (pixels, 0 = the first pixel's centre).
    - `dist`: distortion coefficients k1 k2 p1 p2 k3 (OpenCV's plumb bob); zeros for rectified images.
    """

    width: int = 0
    height: int = 0
    fx: float = 0.0
    fy: float = 0.0
    cx: float = 0.0
    cy: float = 0.0
    dist: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        named = {"fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy}
        bad = [f"{k} {v}" for k, v in named.items() if not math.isfinite(v)]
        bad += [f"dist {list(self.dist)}"] if not all(math.isfinite(d) for d in self.dist) else []
        if bad:
            raise ConfigError(f"{', '.join(bad)}: intrinsics must be finite numbers")
        if len(self.dist) not in (4, 5, 8):
            raise ConfigError(f"dist: {len(self.dist)} values {list(self.dist)}; expected 4, 5 or 8 (k1 k2 p1 p2 "
                              "[k3 [k4 k5 k6]], OpenCV order)")  # fmt: skip

    def intrinsics(self, where: str = "camera") -> CameraIntrinsics:
        if self.width <= 0 or self.height <= 0 or self.fx <= 0 or self.fy <= 0:
            raise ConfigError(
                f"{where}: camera needs width, height, fx, fy > 0 "
                f"(got {self.width}x{self.height}, fx={self.fx}, fy={self.fy})"
            )
        return CameraIntrinsics(self.width, self.height, self.fx, self.fy, self.cx, self.cy, tuple(self.dist))

    @classmethod
    def from_intrinsics(cls, cam: CameraIntrinsics) -> "CameraConfig":
        return cls(cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy, tuple(cam.dist))


@dataclass(frozen=True)
class DatasetConfig:
    """`dataset:` section.

    - `depth_scale`: depth PNG units per metre in TUM-layout folders (TUM 5000, 7-Scenes 1000).
    - `max_time_diff_s`: colour-depth pairing tolerance (TUM associate.py `--max_difference`);
      also the approximate-time slop for bags.
    - `offset_s`: added to depth stamps before pairing (associate.py `--offset`).
    - `gt_max_time_diff_s`: a frame gets the nearest ground-truth pose within this difference.
    - `topic_preset`: `auto` (detect TUM or RealSense names in the bag), `tum`, `realsense` (`/camera/color/...`)
      or `realsense_jazzy` (`/camera/camera/...`, realsense2_camera's default on Jazzy);
    - `rgb_topic`, `depth_topic`, `camera_info_topic`: override single names of the preset when non-empty.
    - `bag_intrinsics_from`: `camera_info` (the bag's latest CameraInfo, the config's camera when
      none was recorded) or `config` (the config's camera always; TUM bags carry the uncalibrated
      ROS default 525/525/319.5/239.5, so the TUM configs choose `config`).
    - `gt_pose_topic`: `geometry_msgs/PoseStamped` ground truth (our own mcaps).
    - `tf_topic`, `gt_world_frame`, `gt_camera_frame`: ground truth from TF as TUM bags carry it:
      pose of `gt_camera_frame` in `gt_world_frame`, chaining static transforms.
    """

    depth_scale: float = 5000.0
    max_time_diff_s: float = 0.02
    offset_s: float = 0.0
    gt_max_time_diff_s: float = 0.02
    topic_preset: str = "auto"
    rgb_topic: str = ""
    depth_topic: str = ""
    camera_info_topic: str = ""
    bag_intrinsics_from: str = "camera_info"
    gt_pose_topic: str = "/ground_truth/pose"
    tf_topic: str = "/tf"
    gt_world_frame: str = "world"
    gt_camera_frame: str = "openni_rgb_optical_frame"

    def __post_init__(self) -> None:
        if self.topic_preset != "auto" and self.topic_preset not in TOPIC_PRESETS:
            raise ConfigError(
                f"dataset.topic_preset: '{self.topic_preset}' unknown; expected auto, "
                + ", ".join(TOPIC_PRESETS)
            )
        if self.bag_intrinsics_from not in ("camera_info", "config"):
            raise ConfigError(
                f"dataset.bag_intrinsics_from: '{self.bag_intrinsics_from}' unknown; expected camera_info or config"
            )
        if not math.isfinite(self.depth_scale) or self.depth_scale <= 0:
            raise ConfigError(f"dataset.depth_scale: {self.depth_scale}, expected > 0 (PNG units per metre)")
        if self.max_time_diff_s < 0 or self.gt_max_time_diff_s < 0:
            raise ConfigError("dataset: max_time_diff_s and gt_max_time_diff_s must be >= 0")

    def candidate_topics(self) -> list[TopicSet]:
        """Topic sets to look for in a bag, in order: the preset's (or every preset's under `auto`),
        with single names overridden by `rgb_topic` / `depth_topic` / `camera_info_topic`.

        When the colour topic is overridden and `camera_info_topic` is not, CameraInfo is looked for
        beside the colour topic (`/ns/image_raw` -> `/ns/camera_info`), as image_transport places it.
        """
        presets = list(TOPIC_PRESETS.values()) if self.topic_preset == "auto" else [TOPIC_PRESETS[self.topic_preset]]
        out: list[TopicSet] = []
        for base in presets:
            info = self.camera_info_topic or (sibling_camera_info(self.rgb_topic) if self.rgb_topic else base.camera_info)
            cand = TopicSet(self.rgb_topic or base.rgb, self.depth_topic or base.depth, info)
            if cand not in out:
                out.append(cand)
        return out


def sibling_camera_info(image_topic: str) -> str:
    """`/camera/color/image_raw[/compressed]` -> `/camera/color/camera_info`."""
    base = image_topic
    for suffix in ("/compressed", "/compressedDepth"):
        if base.endswith(suffix):
            base = base[: -len(suffix)]
    head, _, _ = base.rpartition("/")
    return f"{head}/camera_info"


@dataclass(frozen=True)
class DatasetSettings:
    """Both sections of one config file, with where they came from (for messages)."""

    dataset: DatasetConfig
    camera: CameraConfig | None
    source: str


def load_dataset_settings(name_or_path: str | Path | None) -> DatasetSettings:
    """Read `dataset:` and `camera:` from a config file or shipped config name; None = defaults."""
    if name_or_path is None:
        return DatasetSettings(DatasetConfig(), None, "defaults")
    data, where = load_config(name_or_path)
    return settings_from_mapping(data, where)


def settings_from_mapping(data: dict[str, object], where: str) -> DatasetSettings:
    ds = data.get("dataset")
    cam = data.get("camera")
    try:
        dataset = section(DatasetConfig, ds, f"{where}: dataset")  # type: ignore[arg-type]
    except ConfigError as err:
        text = str(err)
        raise ConfigError(text if text.startswith(where) else f"{where}: {text}") from err
    try:
        camera = None if cam is None else section(CameraConfig, cam, f"{where}: camera")  # type: ignore[arg-type]
    except ConfigError as err:
        text = str(err)
        raise ConfigError(text if text.startswith(where) else f"{where}: camera: {text}") from err
    if camera is not None:
        camera.intrinsics(f"{where}: camera")  # validate now, at the edge
    return DatasetSettings(dataset, camera, where)
