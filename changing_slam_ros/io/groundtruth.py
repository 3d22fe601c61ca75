"""Ground truth with exact integer stamps, shared by the folder and bag readers."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.se3 import rot_to_quat
from changing_slam_ros.core.geometry.trajectory import Trajectory

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class GroundTruth:
    """Camera-to-world poses: stamps_ns (N,) int64 sorted, positions (N, 3) m, quats_xyzw (N, 4) unit."""

    stamps_ns: npt.NDArray[np.int64]
    positions: F64
    quats_xyzw: F64

    @classmethod
    def from_poses(cls, stamps_ns: list[int], poses: list[F64]) -> "GroundTruth":
        """From stamps and T_world_cam (4, 4) matrices; sorted by stamp."""
        order = np.argsort(np.asarray(stamps_ns, dtype=np.int64), kind="stable")
        stamps = np.asarray(stamps_ns, dtype=np.int64)[order]
        mats = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)[order]
        quats = np.array([rot_to_quat(m[:3, :3]) for m in mats]).reshape(-1, 4)
        return cls(stamps, mats[:, :3, 3].copy(), quats)

    def __len__(self) -> int:
        return len(self.stamps_ns)

    def trajectory(self) -> Trajectory:
        return Trajectory(self.stamps_ns.astype(np.float64) * 1e-9, self.positions, self.quats_xyzw)

    def nearest_pose(self, stamp_ns: int, max_diff_ns: int) -> F64 | None:
        """T_world_cam (4, 4) of the nearest stamp with |difference| <= max_diff_ns, else None."""
        if len(self.stamps_ns) == 0:
            return None
        k = int(np.searchsorted(self.stamps_ns, stamp_ns))
        best = min(
            (c for c in (k - 1, k) if 0 <= c < len(self.stamps_ns)),
            key=lambda c: (abs(int(self.stamps_ns[c]) - stamp_ns), c),
        )
        if abs(int(self.stamps_ns[best]) - stamp_ns) > max_diff_ns:
            return None
        return pose_matrix(self.positions[best], self.quats_xyzw[best])


def pose_matrix(position: F64, quat_xyzw: F64) -> F64:
    """(3,) translation and (4,) unit quaternion (x, y, z, w) -> 4x4 transform."""
    x, y, z, w = (float(v) for v in quat_xyzw)
    T = np.eye(4)
    T[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    T[:3, 3] = position
    return T


class GroundTruthAccess:
    """The two ground-truth accessors of an `RgbdSource`, for readers that keep theirs in `self._gt`."""

    _gt: GroundTruth | None

    @property
    def groundtruth(self) -> Trajectory | None:
        return self._gt.trajectory() if self._gt is not None else None

    @property
    def groundtruth_stamped(self) -> GroundTruth | None:
        """Ground truth with exact integer stamps."""
        return self._gt
