"""A level start for a map: the first camera's pose above the floor it sees, from one depth image.

Without a robot base whose mounting is known, a map is built in the first camera's optical frame (z forward,
y down), which a planar consumer (Nav2 reads x, y and yaw only) cannot use. When the first depth image shows the
floor, `level_first_pose` gives the pose of that camera in a floor frame: z up along the floor's normal, origin on
the floor below the camera, x along the camera's viewing direction laid onto the floor. A map started there
(`SlamSystem.set_first_pose`) is z-up, as REP-105 wants of `map`, and its occupancy grid lies in its x-y plane.

The floor is `floor_plane.estimate_floor` over the image's back-projected depth, with the camera's up (-y) as
the hint: it must hold `min_fraction` of the readings and lie `min_height_m`-`max_height_m` below the camera.
Anything else (a camera facing a wall, a floor out of view) gives None, and the map keeps the optical frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.map.floor_plane import FloorEstimate, estimate_floor

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class FloorStartConfig:
    """How the floor is looked for in the first depth image.

    - `stride_px`: every stride-th pixel in each direction is back-projected.
    - `max_depth_m`: readings farther than this are left out (depth noise grows with distance).
    - `min_fraction`: the floor's share of the readings (a floor glimpsed in a corner is no evidence of level).
    - `max_tilt_deg`: the floor's normal within this of the camera's up (a camera pitched by more: no floor).
    - `min_height_m`, `max_height_m`: the camera's height above the floor it may have.
    """

    stride_px: int = 4
    max_depth_m: float = 4.0
    min_fraction: float = 0.08
    max_tilt_deg: float = 35.0
    min_height_m: float = 0.1
    max_height_m: float = 3.0


@dataclass(frozen=True)
class FloorStart:
    """The first camera's pose `T_floor_cam` (4, 4) and the floor it was found from (in the camera's frame)."""

    T_floor_cam: F64  # noqa: N815
    floor: FloorEstimate

    @property
    def height_m(self) -> float:
        """The camera's height above the floor."""
        return float(self.T_floor_cam[2, 3])

    @property
    def pitch_deg(self) -> float:
        """How far the camera's viewing direction points below the horizon (negative: above)."""
        return float(np.degrees(np.arcsin(np.clip(-self.T_floor_cam[2, 2], -1.0, 1.0))))


def depth_points(depth_m: npt.NDArray[np.floating], camera: CameraIntrinsics, stride_px: int,
                 max_depth_m: float) -> F64:
    """Back-projected readings (N, 3) of every `stride_px`-th pixel with 0 < depth <= `max_depth_m`, camera frame."""
    d = np.asarray(depth_m, np.float64)[::stride_px, ::stride_px]
    v, u = np.nonzero(np.isfinite(d) & (d > 0.0) & (d <= max_depth_m))
    return camera.backproject(np.stack([u, v], axis=1).astype(np.float64) * stride_px, d[v, u])


def level_first_pose(depth_m: npt.NDArray[np.floating], camera: CameraIntrinsics,
                     config: FloorStartConfig | None = None) -> FloorStart | None:
    """The camera's pose in the floor frame it sees (module doc), or None without a floor it can trust."""
    cfg = config or FloorStartConfig()
    pts = depth_points(depth_m, camera, cfg.stride_px, cfg.max_depth_m)
    if len(pts) < 100:
        return None
    floor = estimate_floor(pts, np.array([0.0, -1.0, 0.0]), min_fraction=cfg.min_fraction,
                           max_tilt_deg=cfg.max_tilt_deg)
    if floor is None or floor.n_support < cfg.min_fraction * len(pts):
        return None
    if not cfg.min_height_m <= -floor.height <= cfg.max_height_m:  # the camera sits at -height above it
        return None
    T_cam_floor = floor.frame(np.array([0.0, 0.0, 1.0]))  # noqa: N806
    return FloorStart(np.linalg.inv(T_cam_floor), floor)
