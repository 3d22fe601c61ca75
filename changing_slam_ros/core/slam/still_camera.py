"""A camera that has stood still stays still while the background says so, whatever a mover in front does.

A robot waiting at a door, or a camera on a tripod, sees people walk past close by. Their points agree with each
other, and where they hold most of the matches the pose optimisation follows them: the far background is
explained just as well by a rotation that makes up for the wrong translation, so no residual shows the error.
Zero motion is the one hypothesis a mover cannot fake, since its points move. `StillCamera` counts the frames
whose accepted motion stayed within `still_m` / `still_deg` and keeps the pose the camera came to rest at (the
anchor); after `still_frames` of them, a pose that moves away from the anchor is checked against it: when the
anchor still explains at least `min_points` matches and `min_share` of the moved pose's inliers, those matches
are the background, and the pose is fitted to them alone, starting from the anchor (a held frame counts as
still). A camera that starts to move loses that support within a few frames (its background points drift past
the chi2 threshold, a few pixels) and tracks as before from then on. Off by default: it did not generalise to
the evaluation seeds of the randomised family (docs/results.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.pose_optimizer import (
    CHI2_MONO, CHI2_STEREO, PinholeStereo, PoseObservations, PoseResult, optimize_pose, residuals,
)
from changing_slam_ros.core.geometry.se3 import rotation_angle_rad

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class StillCameraConfig:
    """YAML `tracking.still_camera:`.

    - `enabled`: hold a still camera's pose against a mover (off by default).
    - `still_frames`: accepted frames in a row, each moving under `still_m` and `still_deg`, before the check runs.
    - `min_points`, `min_share`: matches the anchor (the pose the camera came to rest at) must still explain,
      absolute and as a share of the moved pose's inliers, for the camera to count as still.
    """

    enabled: bool = False
    still_frames: int = 5
    still_m: float = 0.003
    still_deg: float = 0.2
    min_points: int = 40
    min_share: float = 0.25


def _moved(T_a: F64, T_b: F64, cfg: StillCameraConfig) -> bool:  # noqa: N803
    """Whether two camera poses (either direction of transform) differ by more than the still thresholds."""
    d = np.linalg.inv(T_a) @ T_b
    return bool(np.linalg.norm(d[:3, 3]) > cfg.still_m or np.degrees(rotation_angle_rad(d[:3, :3])) > cfg.still_deg)


class StillCamera:
    """The still-camera check of one tracker (module doc)."""

    def __init__(self, cfg: StillCameraConfig) -> None:
        self.cfg = cfg
        self.n_still = 0
        self.anchor_cw: F64 | None = None  # T_cam_world where the camera came to rest
        self._held = False  # the frame being tracked was held

    def accept(self, velocity: F64 | None, T_cam_world: F64) -> None:  # noqa: N803
        """After each accepted frame: its motion since the frame before (None: not known, the count restarts) and
        its pose. A still camera keeps the pose it came to rest at as the anchor, so a mover that drags the pose
        a little each frame cannot carry it off in steps each under the still thresholds."""
        held, self._held = self._held, False
        if held and velocity is not None:  # held at the anchor: still by this check's own verdict
            self.n_still += 1
        elif velocity is None or _moved(np.eye(4), velocity, self.cfg):
            self.n_still = 0
            self.anchor_cw = None
        else:
            self.n_still += 1
            if self.anchor_cw is None:
                self.anchor_cw = T_cam_world.copy()

    def check(self, obs: PoseObservations, cam: PinholeStereo, full: PoseResult, iterations: int) -> PoseResult:
        """`full`, or the pose of the matches the anchor explains where the camera has been still (module doc)."""
        cfg = self.cfg
        anchor = self.anchor_cw
        if not cfg.enabled or self.n_still < cfg.still_frames or anchor is None:
            return full
        if not _moved(anchor, full.T_cam_world, cfg):
            return full
        chi2 = residuals(anchor, obs, cam)[2]
        still = chi2 <= np.where(obs.u_right_px >= 0, CHI2_STEREO, CHI2_MONO)
        n = int(still.sum())
        if n < cfg.min_points or n < cfg.min_share * full.n_inliers:
            return full
        sub = PoseObservations(obs.points_w[still], obs.uv_px[still], obs.u_right_px[still], obs.inv_sigma2[still])
        refit = optimize_pose(anchor, sub, cam, iterations=iterations, robust_rounds=0)
        inliers = np.zeros(len(still), bool)
        inliers[np.flatnonzero(still)[refit.inliers]] = True
        self._held = True
        return PoseResult(refit.T_cam_world, inliers, residuals(refit.T_cam_world, obs, cam)[2])
