"""Absolute trajectory error (ATE): translation error after aligning the estimate to ground truth.

Sturm et al. 2012 (TUM RGB-D benchmark) and evo's APE with the `translation_part` relation:
associate stamps, align the estimate's positions to ground truth with Umeyama (SE(3), or Sim(3)
for scale-ambiguous estimates), then e_i = || p_gt,i - (s R p_est,i + t) || for every associated
pose i. The statistics use all associated poses.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.trajectory import Trajectory
from changing_slam_ros.eval.alignment import Alignment, align_trajectories
from changing_slam_ros.eval.association import DEFAULT_MAX_DIFF_S, Association, associate
from changing_slam_ros.eval.statistics import ErrorStatistics
from changing_slam_ros.errors import EvalError

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class AteResult:
    """ATE of one estimate.

    - `errors_m`: (M,) translation error per associated pose, metres.
    - `stamps_s`: (M,) ground-truth stamps of those poses.
    - `association`: the pairs; `alignment`: estimate -> ground truth (identity if not aligned).
    - `est_aligned`: the associated estimate after alignment (for plots).
    """

    stats: ErrorStatistics
    errors_m: F64
    stamps_s: F64
    association: Association
    alignment: Alignment
    aligned: bool
    sim3: bool
    est_aligned: Trajectory

    def to_dict(self, per_pose: bool = False) -> dict[str, Any]:
        out: dict[str, Any] = {
            "metric": "ate",
            "unit": "m",
            "alignment": "sim3" if self.sim3 else ("se3" if self.aligned else "none"),
            "max_diff_s": self.association.max_diff_s,
            "offset_s": self.association.offset_s,
            "associated_poses": len(self.association),
            **self.stats.to_dict(),
            "transform": self.alignment.to_dict(),
        }
        if per_pose:
            out["per_pose"] = {
                "stamps_s": self.stamps_s.tolist(),
                "errors_m": self.errors_m.tolist(),
            }
        return out


def ate(
    gt: Trajectory,
    est: Trajectory,
    max_diff_s: float = DEFAULT_MAX_DIFF_S,
    offset_s: float = 0.0,
    align: bool = True,
    sim3: bool = False,
    gt_name: str = "ground truth",
    est_name: str = "estimate",
) -> AteResult:
    """Associate, align (SE(3); Sim(3) when `sim3`) and measure the translation error.

    `align=False` compares raw positions (only meaningful when both share a frame).
    Equals `evo_ape tum GT EST -a --t_max_diff D --t_offset S` (and `-as` with `sim3`).
    """
    assoc = associate(gt, est, max_diff_s, offset_s, gt_name=gt_name, est_name=est_name)
    try:
        return ate_associated(assoc, align=align, sim3=sim3)
    except EvalError as err:
        raise EvalError(f"{est_name} vs {gt_name}: {err}") from err


def ate_associated(assoc: Association, align: bool = True, sim3: bool = False) -> AteResult:
    """ATE of already associated trajectories."""
    if align or sim3:
        alignment = align_trajectories(assoc.gt, assoc.est, with_scale=sim3)
    else:
        alignment = Alignment()
    est_aligned = alignment.apply(assoc.est)
    errors = np.linalg.norm(assoc.gt.positions - est_aligned.positions, axis=1)
    return AteResult(
        stats=ErrorStatistics.of(errors),
        errors_m=errors,
        stamps_s=assoc.gt.stamps_s.copy(),
        association=assoc,
        alignment=alignment,
        aligned=bool(align or sim3),
        sim3=sim3,
        est_aligned=est_aligned,
    )
