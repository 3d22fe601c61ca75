"""Least-squares alignment of an estimated trajectory to ground truth (Umeyama 1991, Horn 1987).

Finds the similarity (s, R, t) minimising sum_i || y_i - (s R x_i + t) ||^2 over corresponding
positions x_i (estimate) and y_i (ground truth). SE(3) alignment fixes s = 1; Sim(3) alignment
also estimates s (needed for monocular estimates, whose scale is arbitrary).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.trajectory import Trajectory
from changing_slam_ros.errors import EvalError

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Alignment:
    """A similarity transform mapping estimate coordinates to ground-truth coordinates.

    y = scale * R_gt_est @ x + t_gt_est. `scale` is 1.0 for SE(3) alignment.
    """

    R_gt_est: F64 = field(default_factory=lambda: np.eye(3))
    t_gt_est: F64 = field(default_factory=lambda: np.zeros(3))
    scale: float = 1.0

    @property
    def T_gt_est(self) -> F64:
        """(4, 4) homogeneous matrix [[s R, t], [0, 1]] (a similarity when scale != 1)."""
        m = np.eye(4)
        m[:3, :3] = self.scale * self.R_gt_est
        m[:3, 3] = self.t_gt_est
        return m

    def apply_points(self, points: F64) -> F64:
        """Map positions (N, 3) from estimate to ground-truth coordinates."""
        return self.scale * (np.asarray(points, dtype=np.float64) @ self.R_gt_est.T) + self.t_gt_est

    def apply(self, traj: Trajectory) -> Trajectory:
        """The trajectory with positions mapped and orientations rotated by R_gt_est.

        Each camera-to-world pose T becomes [[R R_T, s R t_T + t], [0, 1]]: the scale changes
        positions only, so orientations stay rotations.
        """
        poses = traj.poses()
        out = np.empty_like(poses)
        out[:] = np.eye(4)
        out[:, :3, :3] = self.R_gt_est @ poses[:, :3, :3]
        out[:, :3, 3] = self.apply_points(poses[:, :3, 3])
        return Trajectory.from_poses(traj.stamps_s.copy(), out)

    def to_dict(self) -> dict[str, Any]:
        return {
            "R_gt_est": self.R_gt_est.tolist(),
            "t_gt_est_m": self.t_gt_est.tolist(),
            "scale": float(self.scale),
        }


def umeyama(x_est: F64, y_gt: F64, with_scale: bool = False) -> Alignment:
    """Umeyama's closed-form alignment of corresponding points.

    - `x_est`: (N, 3) estimate positions; `y_gt`: (N, 3) ground-truth positions; N >= 3 for a
      unique rotation (fewer raise EvalError), points must not all coincide.
    Returns the `Alignment` with y ~ scale * R x + t.
    """
    x = np.asarray(x_est, dtype=np.float64).reshape(-1, 3)
    y = np.asarray(y_gt, dtype=np.float64).reshape(-1, 3)
    if len(x) != len(y):
        raise EvalError(f"alignment needs corresponding points, got {len(x)} and {len(y)}")
    n = len(x)
    if n < 3:
        raise EvalError(f"alignment needs at least 3 associated poses, got {n}")
    mean_x = x.mean(axis=0)
    mean_y = y.mean(axis=0)
    xc = x - mean_x
    yc = y - mean_y
    var_x = float(np.sum(xc * xc)) / n  # Umeyama eq. (36): mean squared distance to centroid
    if var_x <= 0.0:
        raise EvalError("alignment is undefined: all estimated positions coincide")
    cov = (yc.T @ xc) / n  # eq. (38): Sigma_xy = 1/n sum (y - mu_y)(x - mu_x)^T, (3, 3)
    u, d, vt = np.linalg.svd(cov)
    # eq. (39): S = diag(1, 1, -1) when det(U) det(V) < 0, so that R is a proper rotation.
    s = np.ones(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0.0:
        s[2] = -1.0
    rot = (u * s) @ vt  # eq. (40): R = U S V^T
    scale = float(np.sum(d * s) / var_x) if with_scale else 1.0  # eq. (42): c = tr(D S) / var_x
    trans = mean_y - scale * (rot @ mean_x)  # eq. (41)
    return Alignment(R_gt_est=rot, t_gt_est=trans, scale=scale)


def align_trajectories(gt: Trajectory, est: Trajectory, with_scale: bool = False) -> Alignment:
    """Alignment of associated trajectories (same length, pair k = (gt[k], est[k]))."""
    if len(gt) != len(est):
        raise EvalError(
            f"alignment needs associated trajectories of equal length, got {len(gt)} and {len(est)}"
        )
    return umeyama(est.positions, gt.positions, with_scale=with_scale)
