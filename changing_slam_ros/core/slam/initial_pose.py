"""An initial pose for relocalisation: where an operator says the camera is in the map (RViz / Nav2 `/initialpose`).

A `PoseHint` is the camera pose in the current map with a tolerance (`radius_m`, `angle_rad`). While one is set,
relocalisation (`Tracker._relocalise`) tries the candidate keyframes near it (`HintedCandidates`: the appearance
index's candidates that lie near, then the nearest others) and accepts only a pose within the tolerance: in a
room whose texture repeats, the place that looks the same elsewhere is refused. The hint is dropped once
tracking relocalises by it, or after `TrackingConfig.initial_pose_timeout_s` of frames without success
(relocalisation then searches the whole map again). Candidate keyframes may be up to `CANDIDATE_SPAN` times the
tolerance away: a keyframe need not stand where the camera is to see what it sees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.se3 import rotation_angle_rad
from changing_slam_ros.errors import ConfigError

if TYPE_CHECKING:
    from changing_slam_ros.core.features.frame import Frame
    from changing_slam_ros.core.map.slam_map import SlamMap

F64 = npt.NDArray[np.float64]
CANDIDATE_SPAN = 2.0  # candidate keyframes within this many tolerances of the hint (the pose within one)


@dataclass(frozen=True)
class PoseHint:
    """The camera pose `T_world_cam` (4, 4, optical frame, in the current map) within `radius_m` and `angle_rad`."""

    T_world_cam: F64
    radius_m: float
    angle_rad: float

    def __post_init__(self) -> None:
        T = np.asarray(self.T_world_cam, dtype=np.float64)  # noqa: N806
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ConfigError("initial pose: expected a finite 4x4 pose")
        if abs(np.linalg.det(T[:3, :3]) - 1.0) > 1e-3:
            raise ConfigError("initial pose: the orientation is not a rotation (quaternion not normalised?)")
        if not (self.radius_m > 0 and math.isfinite(self.radius_m)):
            raise ConfigError(f"initial pose: radius must be > 0 m, got {self.radius_m}")
        if not (0 < self.angle_rad <= math.pi):
            raise ConfigError(f"initial pose: angle must be in (0, pi] rad, got {self.angle_rad}")

    def offset(self, T_world_cam: F64) -> tuple[float, float]:  # noqa: N803
        """(distance in m, rotation angle in rad) from the hint to pose `T_world_cam`."""
        d = float(np.linalg.norm(T_world_cam[:3, 3] - self.T_world_cam[:3, 3]))
        return d, rotation_angle_rad(self.T_world_cam[:3, :3].T @ T_world_cam[:3, :3])

    def admits(self, T_world_cam: F64, span: float = 1.0) -> bool:  # noqa: N803
        """The pose lies within `span` times the tolerance."""
        d, a = self.offset(T_world_cam)
        return d <= span * self.radius_m and a <= min(math.pi, span * self.angle_rad)

    def keyframes_near(self, slam_map: SlamMap, span: float = CANDIDATE_SPAN) -> list[int]:
        """Keyframe ids of `slam_map` within `span` tolerances, nearest first (distance and angle each in units
        of their tolerance, summed)."""
        ranked = []
        for kf_id, kf in slam_map.keyframes.items():
            if self.admits(kf.T_world_cam, span):
                d, a = self.offset(kf.T_world_cam)
                ranked.append((d / self.radius_m + a / self.angle_rad, kf_id))
        return [kf_id for _, kf_id in sorted(ranked)]


def hint_from_covariance(T_world_cam: F64, covariance_6x6: F64, min_radius_m: float,  # noqa: N803
                         min_angle_rad: float, sigmas: float = 3.0) -> PoseHint:  # fmt: skip
    """A hint from a pose with covariance (ROS order x y z, rotation about x y z): `sigmas` standard deviations
    of the largest position and rotation variance, at least `min_radius_m` / `min_angle_rad`."""
    cov = np.asarray(covariance_6x6, dtype=np.float64).reshape(6, 6)
    diag = np.where(np.isfinite(np.diag(cov)), np.diag(cov), 0.0).clip(min=0.0)
    radius = max(min_radius_m, sigmas * math.sqrt(float(diag[:3].max())))
    angle = min(math.pi, max(min_angle_rad, sigmas * math.sqrt(float(diag[3:].max()))))
    return PoseHint(np.asarray(T_world_cam, dtype=np.float64), radius, angle)


class KeyframeSource(Protocol):
    def candidates(self, frame: Frame, slam_map: SlamMap) -> list[int]: ...


class HintedCandidates:
    """Relocalisation candidates near a hint: those of `inner` (appearance) that lie near it first, then the
    nearest keyframes, at most `n`."""

    def __init__(self, inner: KeyframeSource, hint: PoseHint, n: int) -> None:
        self.inner = inner
        self.hint = hint
        self.n = n

    def candidates(self, frame: Frame, slam_map: SlamMap) -> list[int]:
        near = self.hint.keyframes_near(slam_map)
        allowed = set(near)
        first = [k for k in self.inner.candidates(frame, slam_map) if k in allowed]
        return (first + [k for k in near if k not in set(first)])[: self.n]
