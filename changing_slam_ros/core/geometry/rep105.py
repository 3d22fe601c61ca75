"""REP-105 frames from a visual SLAM pose: map -> odom -> base (ROS REP 105, "Coordinate Frames for Mobile
Platforms").

`odom -> base` must be continuous (it is what controllers integrate); `map -> odom` takes every discrete jump.
Odometry comes either from SLAM itself or from the robot (`OdomSource`, which says how each frame is formed).

The SLAM pose is the camera's; `base_pose` moves it to the base with the robot's static `T_base_cam`.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.se3 import invert
from changing_slam_ros.errors import ConfigError

F64 = npt.NDArray[np.float64]


class OdomSource(enum.Enum):
    """Who publishes odom -> base: this package from the visual estimate, or the robot on /tf.

    - `VISUAL`: the robot has no odometry of its own, SLAM publishes both. While tracking goes on
      normally `T_map_odom` stays fixed and `T_odom_base = T_map_odom^-1 · T_map_base`, so odom -> base moves
      exactly as the SLAM pose. When the map moves under the robot (loop correction, relocalisation after a loss,
      a new or merged map), odom -> base continues from its last value by the robot's own motion since then (the
      tracker's frame-to-frame motion when it has one, else none) and the jump goes into `T_map_odom =
      T_map_base · T_odom_base^-1`. `T_map_odom` is identity until the first such jump.
    - `TF`: the robot publishes odom -> base itself (wheel odometry, an EKF); SLAM publishes only
      `T_map_odom = T_map_base · T_odom_base^-1`, with `T_odom_base` the robot's odometry at the image stamp.
    """

    VISUAL = "visual"
    TF = "tf"

    @classmethod
    def parse(cls, text: str) -> OdomSource:
        try:
            return cls(text)
        except ValueError as err:
            raise ConfigError(f"odom_source '{text}' unknown; expected visual or tf") from err


def base_pose(T_map_cam: F64, T_base_cam: F64) -> F64:  # noqa: N803
    """T_map_base = T_map_cam · T_base_cam^-1: the base's pose from the camera's and the camera's mounting."""
    return T_map_cam @ invert(T_base_cam)


def base_motion(T_prev_cur_cam: F64, T_base_cam: F64) -> F64:  # noqa: N803
    """The base's motion between two frames from the camera's: T_base_cam · T_prev_cur_cam · T_base_cam^-1
    (the same rigid motion seen from the base, whose mounting does not move)."""
    return T_base_cam @ T_prev_cur_cam @ invert(T_base_cam)


@dataclass
class Rep105State:
    """map -> odom and (visual) odom -> base as last published; `jumps` counts the map moves absorbed."""

    T_map_odom: F64 = field(default_factory=lambda: np.eye(4))
    T_odom_base: F64 | None = None
    jumps: int = 0

    def visual(self, T_map_base: F64, map_moved: bool, T_prev_cur_base: F64 | None = None) -> F64:  # noqa: N803
        """OdomSource.VISUAL, one tracked frame: returns T_odom_base and updates `T_map_odom`.

        `map_moved`: the pose of this frame is not continuous with the last one (loop correction,
        relocalisation, new or merged map); `T_prev_cur_base`: the base's motion since the last published
        frame when the tracker measured it (None: the robot is taken as having stood still)."""
        if self.T_odom_base is None:  # first pose: odom starts on map
            self.T_odom_base = T_map_base.copy()
            return self.T_odom_base
        if map_moved:
            step = np.eye(4) if T_prev_cur_base is None else T_prev_cur_base
            self.T_odom_base = self.T_odom_base @ step
            self.T_map_odom = T_map_base @ invert(self.T_odom_base)
            self.jumps += 1
        else:
            self.T_odom_base = invert(self.T_map_odom) @ T_map_base
        return self.T_odom_base

    def from_odometry(self, T_map_base: F64, T_odom_base: F64) -> F64:  # noqa: N803
        """OdomSource.TF, one tracked frame with the robot's odometry at its stamp: returns the new
        T_map_odom = T_map_base · T_odom_base^-1."""
        self.T_map_odom = T_map_base @ invert(T_odom_base)
        self.T_odom_base = T_odom_base.copy()
        return self.T_map_odom


@dataclass(frozen=True)
class PoseCovarianceModel:
    """Pose covariance from the number of tracking inliers: each inlier is an independent measurement of the
    pose, so the variance falls as 1 / inliers. `sigma_m` and `sigma_rad` are the 1-sigma position and
    rotation errors at `ref_inliers` inliers; the matrix is diagonal and isotropic per block (so it reads the
    same in the camera's and the base's axes; the lever arm's coupling is left out)."""

    sigma_m: float = 0.01
    sigma_rad: float = 0.01
    ref_inliers: int = 100

    def covariance(self, n_inliers: int) -> F64:
        """6x6, ROS order (x, y, z, rotation about x, y, z), in m^2 and rad^2; `n_inliers` < 1 counts as 1."""
        k = self.ref_inliers / max(int(n_inliers), 1)
        return np.diag([self.sigma_m**2 * k] * 3 + [self.sigma_rad**2 * k] * 3)
