"""A rendered scenario folder as a ROS 2 mcap (Image or CompressedImage, CameraInfo, ground-truth PoseStamped).

The file itself is written by the IO layer's `write_rgbd_mcap` (TUM topic names, see
`changing_slam_ros/io/mcap_writer.py`); this module only reads the simulator's own output folder back
into `RgbdFrame`s with their ground-truth poses.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from changing_slam_ros.core.features.rgbd_frame import RgbdFrame
from changing_slam_ros.errors import SimError
from changing_slam_ros.io.camera_info import read_camera_info_yaml
from changing_slam_ros.io.tum_folder import parse_stamp_ns
from changing_slam_ros.io.tum_trajectory import read_tum_trajectory
from changing_slam_ros.sim.writer import DEPTH_SCALE


def sim_frames(folder: Path, max_frames: int | None = None) -> Iterator[RgbdFrame]:
    """Frames of a simulator output folder, in order, with `T_world_cam_gt` set."""
    folder = Path(folder)
    camera = read_camera_info_yaml(folder / "camera_info.yaml")
    gt = read_tum_trajectory(folder / "groundtruth.txt")
    poses = gt.poses()  # (N, 4, 4), in file order (stamps increase)
    lines = [ln.split() for ln in (folder / "associations.txt").read_text().splitlines() if ln.strip()]
    if len(lines) != len(gt):
        raise SimError(f"{folder}: {len(lines)} frames in associations.txt but {len(gt)} poses in groundtruth.txt")
    for i, (stamp, rgb_rel, _, depth_rel) in enumerate(lines):
        if max_frames is not None and i >= max_frames:
            return
        bgr = cv2.imread(str(folder / rgb_rel), cv2.IMREAD_COLOR)
        depth = cv2.imread(str(folder / depth_rel), cv2.IMREAD_UNCHANGED)
        if bgr is None or depth is None:
            raise SimError(f"{folder}: cannot read {rgb_rel} or {depth_rel}")
        yield RgbdFrame(parse_stamp_ns(stamp), cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB),
                        (depth.astype(np.float32) / np.float32(DEPTH_SCALE)), camera, poses[i], i)


def write_sim_mcap(folder: Path, mcap_path: Path, compress: bool = True, max_frames: int | None = None,
                   jpeg_quality: int = 90) -> int:
    """Write the scenario in `folder` to `mcap_path`; JPEG colour and 16-bit PNG depth (millimetres) when
    `compress`, raw rgb8 and 32FC1 otherwise. Returns the number of frames written."""
    try:
        from changing_slam_ros.io.mcap_writer import RgbdMcapWriter
    except ImportError as err:  # pragma: no cover - the IO layer ships it
        raise SimError("mcap output needs changing_slam_ros.io.mcap_writer") from err
    with RgbdMcapWriter(mcap_path, compress=compress, jpeg_quality=jpeg_quality) as writer:
        for frame in sim_frames(folder, max_frames):
            writer.write_frame(frame)
        return int(writer.frames_written)
