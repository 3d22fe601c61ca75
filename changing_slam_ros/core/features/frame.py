"""Frame: one RGB-D image as tracking sees it (features, matches to map points, pose)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.features.orb_features import Features

F64 = npt.NDArray[np.float64]


@dataclass
class Frame:
    """A tracked frame.

    - `features`: keypoints (N rows), see `orb_features.Features`.
    - `point_ids` (N,) int64: matched map point id, -1 when unmatched.
    - `outliers` (N,) bool: matches rejected by the last pose optimisation.
    - `T_world_cam`: camera-to-world (4, 4), None until tracked.
    - `ref_kf_id`: the reference keyframe (its pose anchors this frame's final pose).
    - `n_depth_extracted`: keypoints with depth the image gave before the dynamic stage dropped some from
      `features`; -1 = `features` holds them all.
    """

    stamp_ns: int
    index: int
    camera: CameraIntrinsics
    features: Features
    point_ids: npt.NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    outliers: npt.NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, bool))
    T_world_cam: F64 | None = None
    ref_kf_id: int = -1
    n_depth_extracted: int = -1
    _tree: cKDTree | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        n = len(self.features)
        if len(self.point_ids) != n:
            self.point_ids = np.full(n, -1, np.int64)
        if len(self.outliers) != n:
            self.outliers = np.zeros(n, bool)

    def __len__(self) -> int:
        return len(self.features)

    @property
    def stamp_s(self) -> float:
        return self.stamp_ns * 1e-9

    def kd_tree(self) -> cKDTree:
        """A k-d tree over the undistorted keypoints, built once."""
        if self._tree is None:
            self._tree = cKDTree(self.features.keypoints_px if len(self) else np.zeros((1, 2)) - 1e9)
        return self._tree

    def tracked_mask(self) -> npt.NDArray[np.bool_]:
        """(N,) keypoints with a map point that survived the pose optimisation."""
        return (self.point_ids >= 0) & ~self.outliers
