"""Pinhole camera model with Brown-Conrady (plumb-bob) distortion, as in `sensor_msgs/CameraInfo`."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt


@dataclass(frozen=True)
class CameraIntrinsics:
    """Intrinsics of the colour camera; depth is assumed registered to it.

    `dist` holds the plumb-bob coefficients (k1, k2, p1, p2, k3), zeros when the images are rectified.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, ...] = field(default=(0.0, 0.0, 0.0, 0.0, 0.0))

    @property
    def K(self) -> npt.NDArray[np.float64]:  # noqa: N802 - conventional name
        """3x3 camera matrix."""
        return np.array(
            [[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]], dtype=np.float64
        )

    @property
    def has_distortion(self) -> bool:
        return any(abs(d) > 0.0 for d in self.dist)

    def project(self, points_cam: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """Project points (N, 3) in the optical frame to pixels (N, 2), ignoring distortion."""
        z = points_cam[:, 2]
        u = self.fx * points_cam[:, 0] / z + self.cx
        v = self.fy * points_cam[:, 1] / z + self.cy
        return np.stack([u, v], axis=1)

    def backproject(
        self, pixels: npt.NDArray[np.float64], depths_m: npt.NDArray[np.float64]
    ) -> npt.NDArray[np.float64]:
        """Back-project undistorted pixels (N, 2) with depths (N,) in metres to points (N, 3)."""
        x = (pixels[:, 0] - self.cx) / self.fx * depths_m
        y = (pixels[:, 1] - self.cy) / self.fy * depths_m
        return np.stack([x, y, depths_m], axis=1)

    def scaled(self, width: int, height: int) -> "CameraIntrinsics":
        """The same camera for an image resized to (width, height)."""
        sx, sy = width / self.width, height / self.height
        return CameraIntrinsics(
            width, height, self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy, self.dist
        )
