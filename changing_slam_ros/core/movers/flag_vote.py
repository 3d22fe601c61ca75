"""The segmentation's verdicts carried to the keypoints it could not test, by a vote of their 3-D neighbours.

The two-frame segmentation (`edge_test`) tests only the keypoints it matched across its gap, about half of a
walking person's: the others stay in tracking, and on a mover that fills much of the view they can outnumber
the background and take the camera's pose with them. A keypoint with depth that the test did not reach is
flagged when most of the tested keypoints around it in 3-D (the camera frame, within `radius_m`) were found
moving: points of one rigid body lie together in space, and a mover stands apart from the wall behind it by
more than the radius.

Unlike an image-space spread of the flags, the vote never overrules a test: a tested keypoint keeps its own
verdict, so the static floor under a person's feet or a wall close behind a carried board, whose keypoints the
test found static, stays in tracking and outvotes the flags around its untested neighbours.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree  # type: ignore[import-untyped]

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.errors import ConfigError

BoolArr = npt.NDArray[np.bool_]
F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class FlagVoteConfig:
    """YAML section `dynamic: flag_vote:`.

    - `radius_m`: tested keypoints within this 3-D distance of an untested one vote on it (0 = off). A
      person's torso is ~0.4 m wide and stands >= 0.3 m clear of a wall most of the time.
    - `neighbours`: at most this many nearest tested keypoints vote.
    - `min_votes` / `moving_fraction`: the keypoint is flagged when at least `min_votes` of its voters, and at
      least this fraction of them, were flagged (a lone false alarm of the test among two or three voters on a
      sparse wall does not flag its neighbours).
    """

    radius_m: float = 0.0
    neighbours: int = 8
    min_votes: int = 3
    moving_fraction: float = 0.5

    def __post_init__(self) -> None:
        if self.radius_m < 0.0:
            raise ConfigError(f"dynamic.flag_vote.radius_m: expected >= 0 (0 = off), got {self.radius_m}")
        if self.neighbours < 1 or not 1 <= self.min_votes <= self.neighbours:
            raise ConfigError("dynamic.flag_vote: expected neighbours >= 1 and 1 <= min_votes <= neighbours, got "
                              f"{self.neighbours} and {self.min_votes}")
        if not 0.0 < self.moving_fraction <= 1.0:
            raise ConfigError(f"dynamic.flag_vote.moving_fraction: expected in (0, 1], got {self.moving_fraction}")

    @property
    def enabled(self) -> bool:
        return self.radius_m > 0.0


def vote_flags(moving: BoolArr, tested: BoolArr, keypoints_px: F64, depths_m: F64, camera: CameraIntrinsics,
               config: FlagVoteConfig) -> BoolArr:
    """(N,) keypoints flagged by the vote alone: untested keypoints with depth whose tested neighbours within
    `config.radius_m` (the `neighbours` nearest) hold at least `min_votes` flagged ones, making at least
    `moving_fraction` of them. `moving` (N,) the test's flags, `tested` (N,) the keypoints it tested."""
    n = len(moving)
    out = np.zeros(n, dtype=bool)
    has_depth = depths_m > 0
    voters = np.flatnonzero(tested & has_depth)
    asked = np.flatnonzero(~tested & ~moving & has_depth)
    if not config.enabled or len(voters) < config.min_votes or len(asked) == 0 or not moving[voters].any():
        return out
    pts = camera.backproject(keypoints_px, np.where(has_depth, depths_m, 1.0))
    k = min(config.neighbours, len(voters))
    dist, nn = cKDTree(pts[voters]).query(pts[asked], k=k, distance_upper_bound=config.radius_m)
    dist, nn = dist.reshape(len(asked), k), nn.reshape(len(asked), k)
    near = np.isfinite(dist)
    n_flagged = (near & moving[voters[np.where(near, nn, 0)]]).sum(axis=1)
    verdict = (n_flagged >= config.min_votes) & (n_flagged >= config.moving_fraction * near.sum(axis=1))
    out[asked[verdict]] = True
    return out
