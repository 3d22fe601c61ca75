"""The sensor input every reader yields and every consumer takes: one registered RGB-D pair."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.camera import CameraIntrinsics


@dataclass
class RgbdFrame:
    """One time-stamped colour + depth pair.

    - `stamp_ns`: colour image stamp, nanoseconds (integer, no float rounding).
    - `rgb`: (H, W, 3) uint8, RGB channel order.
    - `depth_m`: (H, W) float32 metres, registered to `rgb`; 0.0 where there is no reading
      (NaN and negative values are converted to 0.0 at the reader boundary).
    - `camera`: intrinsics of `rgb`.
    - `T_world_cam_gt`: optional ground-truth camera-to-world pose (4, 4) in the optical frame.
    - `index`: position of the frame in its sequence.
    """

    stamp_ns: int
    rgb: npt.NDArray[np.uint8]
    depth_m: npt.NDArray[np.float32]
    camera: CameraIntrinsics
    T_world_cam_gt: npt.NDArray[np.float64] | None = None
    index: int = 0

    @property
    def stamp_s(self) -> float:
        return self.stamp_ns * 1e-9
