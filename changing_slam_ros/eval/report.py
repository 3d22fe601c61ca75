"""One call that evaluates an estimate against ground truth, for the runner's `metrics.json`.

`evaluate()` associates once and computes the ATE, the RPE per frame (delta 1 frame) and the
RPE per second (delta 1 s, all pairs, TUM benchmark convention). Everything in the returned
dict is plain JSON (floats, ints, strings, lists).
"""

from __future__ import annotations

import os
from typing import Any

from changing_slam_ros.core.geometry.trajectory import Trajectory
from changing_slam_ros.errors import EvalError
from changing_slam_ros.eval.association import DEFAULT_MAX_DIFF_S, associate
from changing_slam_ros.eval.ate import ate_associated
from changing_slam_ros.eval.rpe import DeltaUnit, rpe_associated

REPORT_VERSION = 1


def evaluate(
    gt: Trajectory,
    est: Trajectory,
    max_diff_s: float = DEFAULT_MAX_DIFF_S,
    offset_s: float = 0.0,
    sim3: bool = False,
    gt_name: str = "ground truth",
    est_name: str = "estimate",
    per_pose: bool = False,
) -> dict[str, Any]:
    """ATE and RPE of `est` against `gt` as a JSON-ready dict.

    Raises EvalError (naming `gt_name` / `est_name`) for an empty trajectory, no associated
    stamps, or fewer than 3 associated poses. An RPE that has no pairs (e.g. the estimate spans
    less than 1 s) is reported as null with the reason under "warnings".
    """
    assoc = associate(gt, est, max_diff_s, offset_s, gt_name=gt_name, est_name=est_name)
    if len(assoc) < 3:
        raise EvalError(
            f"only {len(assoc)} associated poses between {gt_name} and {est_name}: "
            "at least 3 are needed to align and evaluate"
        )
    ate_res = ate_associated(assoc, align=True, sim3=sim3)
    warnings: list[str] = []
    rpe_out: dict[str, Any] = {}
    for key, delta_unit, all_pairs in (
        ("rpe_per_frame", DeltaUnit.FRAMES, False),
        ("rpe_per_second", DeltaUnit.SECONDS, True),
    ):
        try:
            res = rpe_associated(assoc, 1.0, delta_unit, all_pairs, sim3=sim3)
        except EvalError as err:
            rpe_out[key] = None
            warnings.append(f"{key}: {err}")
        else:
            rpe_out[key] = res.to_dict(per_pair=per_pose)
    return {
        "report_version": REPORT_VERSION,
        "gt": gt_name,
        "est": est_name,
        "gt_poses": len(gt),
        "est_poses": len(est),
        "associated_poses": len(assoc),
        "max_diff_s": float(max_diff_s),
        "offset_s": float(offset_s),
        "alignment": "sim3" if sim3 else "se3",
        "ate": ate_res.to_dict(per_pose=per_pose),
        **rpe_out,
        "warnings": warnings,
    }


def evaluate_files(
    gt_path: str | os.PathLike[str],
    est_path: str | os.PathLike[str],
    max_diff_s: float = DEFAULT_MAX_DIFF_S,
    offset_s: float = 0.0,
    sim3: bool = False,
    per_pose: bool = False,
) -> dict[str, Any]:
    """`evaluate` on two TUM trajectory files; errors name the files."""
    from changing_slam_ros.io.tum_trajectory import read_tum_trajectory

    gt = read_tum_trajectory(gt_path)
    est = read_tum_trajectory(est_path)
    return evaluate(
        gt, est, max_diff_s, offset_s, sim3,
        gt_name=str(gt_path), est_name=str(est_path), per_pose=per_pose,
    )
