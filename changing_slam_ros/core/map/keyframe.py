"""Keyframe: the unit that crosses tracking -> local mapping -> loop closing (mirrors msg Keyframe)."""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.map.grid_scan import GridScan


class KeypointClass(enum.IntEnum):
    """Changing-SLAM §4.1 keypoint classes (values are what the messages carry)."""

    STATIC = 0
    MOVABLE = 1
    DYNAMIC = 2
    UNUSED = 3  # object keypoints disabled (occluded / depth spread too high)


@dataclass
class Keyframe:
    """A keyframe with its features.

    Arrays are per keypoint, N rows:
    - `keypoints_px` (N, 2) float32, undistorted pixel coordinates;
    - `octaves` (N,) int8 pyramid level; `descriptors` (N, 32) uint8 ORB;
    - `depths_m` (N,) float32, 0 where there is no valid depth;
    - `point_ids` (N,) int64 map point id or -1; `kp_classes` (N,) int8 `KeypointClass`;
    - `object_ids` (N,) int64 MapObject id or -1.
    `T_world_cam` is the camera-to-world pose (4, 4), optical frame. `grid_scan`: the depth samples the occupancy
    grid is built from (`grid_scan.py`), kept by the map owner only (None: none kept; not in the message).
    """

    id: int
    stamp_ns: int
    T_world_cam: npt.NDArray[np.float64]
    camera: CameraIntrinsics
    keypoints_px: npt.NDArray[np.float32]
    octaves: npt.NDArray[np.int8]
    descriptors: npt.NDArray[np.uint8]
    depths_m: npt.NDArray[np.float32]
    point_ids: npt.NDArray[np.int64]
    kp_classes: npt.NDArray[np.int8] = field(default_factory=lambda: np.zeros(0, np.int8))
    object_ids: npt.NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    map_id: int = 0
    grid_scan: GridScan | None = None

    def __post_init__(self) -> None:
        n = len(self.keypoints_px)
        if len(self.kp_classes) != n:
            self.kp_classes = np.zeros(n, np.int8)
        if len(self.object_ids) != n:
            self.object_ids = np.full(n, -1, np.int64)

    def __len__(self) -> int:
        return len(self.keypoints_px)
