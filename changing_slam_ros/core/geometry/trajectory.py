"""A stamped trajectory of camera-to-world poses (TUM convention)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.se3 import quat_to_rot, rot_to_quat

F64 = npt.NDArray[np.float64]


@dataclass
class Trajectory:
    """Poses over time.

    - `stamps_s`: (N,) seconds, float64, strictly increasing after `sorted()`.
    - `positions`: (N, 3) metres, camera centre in the world frame.
    - `quats_xyzw`: (N, 4) camera-to-world orientation, (x, y, z, w).
    """

    stamps_s: F64
    positions: F64
    quats_xyzw: F64

    def __post_init__(self) -> None:
        self.stamps_s = np.asarray(self.stamps_s, dtype=np.float64).reshape(-1)
        self.positions = np.asarray(self.positions, dtype=np.float64).reshape(-1, 3)
        self.quats_xyzw = np.asarray(self.quats_xyzw, dtype=np.float64).reshape(-1, 4)
        n = len(self.stamps_s)
        if len(self.positions) != n or len(self.quats_xyzw) != n:
            raise ValueError("stamps, positions and quaternions must have the same length")

    def __len__(self) -> int:
        return len(self.stamps_s)

    @classmethod
    def from_poses(cls, stamps_s: F64, poses: F64) -> "Trajectory":
        """Build from stamps (N,) and camera-to-world transforms (N, 4, 4)."""
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
        quats = np.array([rot_to_quat(p[:3, :3]) for p in poses]).reshape(-1, 4)
        return cls(np.asarray(stamps_s, dtype=np.float64), poses[:, :3, 3], quats)

    def poses(self) -> F64:
        """Camera-to-world transforms (N, 4, 4)."""
        out = np.tile(np.eye(4), (len(self), 1, 1))
        out[:, :3, :3] = quat_to_rot(self.quats_xyzw) if len(self) else out[:, :3, :3]
        out[:, :3, 3] = self.positions
        return out

    def subset(self, indices: npt.NDArray[np.intp]) -> "Trajectory":
        return Trajectory(self.stamps_s[indices], self.positions[indices], self.quats_xyzw[indices])

    def sorted(self) -> "Trajectory":
        order = np.argsort(self.stamps_s, kind="stable")
        return self.subset(order)
