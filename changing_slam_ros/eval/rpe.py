"""Relative pose error (RPE): drift of the estimate's motion over a fixed interval.

For a pair of associated poses (i, j), with ground truth Q and estimate P (camera-to-world):
    E_ij = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)
(Sturm et al. 2012, eq. 1; evo's `RPE.rpe_base`). The translation error is ||trans(E_ij)|| in
metres and the rotation error the angle of rot(E_ij) in degrees.

Pairs are chosen on the associated estimate:
- `DeltaUnit.FRAMES`: as evo: consecutive pairs (0, d), (d, 2d), ...; with `all_pairs` every
  (i, i + d). For d = 1 both give every consecutive pair.
- `DeltaUnit.SECONDS` (evo has no time unit; this is the TUM benchmark's fixed-time RPE): for
  every i, the j > i whose stamp difference is nearest to the delta, kept when it is within
  `rel_tol * delta` of it. Without `all_pairs` the pairs are chained: the next pair starts at j.
"""

from __future__ import annotations

import enum
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
IDX = npt.NDArray[np.intp]


class DeltaUnit(enum.Enum):
    FRAMES = "frames"
    SECONDS = "seconds"


@dataclass(frozen=True)
class RpeResult:
    """RPE of one estimate.

    - `pairs`: (K, 2) indices (i, j) into the associated trajectories.
    - `trans_errors_m`: (K,) metres; `rot_errors_deg`: (K,) degrees.
    - `stamps_s`: (K,) ground-truth stamp of the pair's second pose j.
    """

    trans: ErrorStatistics
    rot: ErrorStatistics
    trans_errors_m: F64
    rot_errors_deg: F64
    pairs: IDX
    stamps_s: F64
    delta: float
    delta_unit: DeltaUnit
    all_pairs: bool
    association: Association
    alignment: Alignment
    sim3: bool

    def to_dict(self, per_pair: bool = False) -> dict[str, Any]:
        out: dict[str, Any] = {
            "metric": "rpe",
            "delta": self.delta,
            "delta_unit": self.delta_unit.value,
            "all_pairs": self.all_pairs,
            "alignment": "sim3" if self.sim3 else "none",
            "max_diff_s": self.association.max_diff_s,
            "offset_s": self.association.offset_s,
            "associated_poses": len(self.association),
            "pairs": int(len(self.pairs)),
            "translation_m": self.trans.to_dict(),
            "rotation_deg": self.rot.to_dict(),
        }
        if self.sim3:
            out["transform"] = self.alignment.to_dict()
        if per_pair:
            out["per_pair"] = {
                "i": self.pairs[:, 0].tolist(),
                "j": self.pairs[:, 1].tolist(),
                "stamps_s": self.stamps_s.tolist(),
                "translation_m": self.trans_errors_m.tolist(),
                "rotation_deg": self.rot_errors_deg.tolist(),
            }
        return out


def frame_pairs(n: int, delta: int, all_pairs: bool = False) -> IDX:
    """Index pairs (K, 2) at a distance of `delta` frames among n poses."""
    if delta < 1:
        raise EvalError(f"RPE delta must be at least 1 frame, got {delta}")
    if all_pairs:
        i = np.arange(0, max(n - delta, 0), dtype=np.intp)
        return np.stack([i, i + delta], axis=1)
    ids = np.arange(0, n, delta, dtype=np.intp)
    return np.stack([ids[:-1], ids[1:]], axis=1)


def time_pairs(stamps_s: F64, delta_s: float, rel_tol: float = 0.1, all_pairs: bool = True) -> IDX:
    """Index pairs (K, 2) whose stamp difference is `delta_s` within `rel_tol * delta_s`.

    - `stamps_s`: (N,) non-decreasing seconds.
    """
    t = np.asarray(stamps_s, dtype=np.float64).reshape(-1)
    if not delta_s > 0:
        raise EvalError(f"RPE delta must be a positive number of seconds, got {delta_s}")
    if len(t) > 1 and np.any(np.diff(t) < 0):
        raise EvalError("RPE over seconds needs stamps in increasing order")
    tol = rel_tol * delta_s
    n = len(t)
    best = np.full(n, -1, dtype=np.intp)
    for i in range(n - 1):
        target = t[i] + delta_s
        k = int(np.searchsorted(t, target, side="left"))
        cands = [c for c in (k - 1, k) if i < c < n]
        if not cands:
            continue
        j = min(cands, key=lambda c: (abs(t[c] - target), c))
        if abs(t[j] - target) <= tol:
            best[i] = j
    if all_pairs:
        first = np.flatnonzero(best >= 0).astype(np.intp)
        return np.stack([first, best[first]], axis=1).astype(np.intp).reshape(-1, 2)
    chain: list[tuple[int, int]] = []
    i = 0
    while i < n - 1:
        j = int(best[i])
        if j < 0:
            i += 1
            continue
        chain.append((i, j))
        i = j
    return np.array(chain, dtype=np.intp).reshape(-1, 2)


def rotation_angle_deg(r: F64) -> F64:
    """Angles (...) in degrees of rotation matrices (..., 3, 3), accurate near 0 and near 180."""
    sin_part = 0.5 * np.linalg.norm(
        np.stack(
            [r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]],
            axis=-1,
        ),
        axis=-1,
    )
    cos_part = 0.5 * (np.trace(r, axis1=-2, axis2=-1) - 1.0)
    angles: F64 = np.degrees(np.arctan2(sin_part, cos_part))
    return angles


def relative_errors(gt_poses: F64, est_poses: F64, pairs: IDX) -> tuple[F64, F64]:
    """Translation (m) and rotation (deg) errors (K,) of E_ij for poses (N, 4, 4) and pairs (K, 2)."""
    i, j = pairs[:, 0], pairs[:, 1]
    q_rel = np.linalg.inv(gt_poses[i]) @ gt_poses[j]
    p_rel = np.linalg.inv(est_poses[i]) @ est_poses[j]
    e = np.linalg.inv(q_rel) @ p_rel
    return np.linalg.norm(e[:, :3, 3], axis=1), rotation_angle_deg(e[:, :3, :3])


def rpe(
    gt: Trajectory,
    est: Trajectory,
    delta: float = 1.0,
    delta_unit: DeltaUnit = DeltaUnit.FRAMES,
    all_pairs: bool = False,
    rel_tol: float = 0.1,
    max_diff_s: float = DEFAULT_MAX_DIFF_S,
    offset_s: float = 0.0,
    sim3: bool = False,
    gt_name: str = "ground truth",
    est_name: str = "estimate",
) -> RpeResult:
    """Associate, optionally correct scale (Sim(3) alignment), and measure the RPE.

    SE(3) alignment cannot change the RPE, so only `sim3` alignment is offered. With frames it
    equals `evo_rpe tum GT EST -r trans_part|angle_deg -d D -u f [--all_pairs] [-as]`.
    """
    assoc = associate(gt, est, max_diff_s, offset_s, gt_name=gt_name, est_name=est_name)
    try:
        return rpe_associated(assoc, delta, delta_unit, all_pairs, rel_tol, sim3)
    except EvalError as err:
        raise EvalError(f"{est_name} vs {gt_name}: {err}") from err


def rpe_associated(
    assoc: Association,
    delta: float = 1.0,
    delta_unit: DeltaUnit = DeltaUnit.FRAMES,
    all_pairs: bool = False,
    rel_tol: float = 0.1,
    sim3: bool = False,
) -> RpeResult:
    """RPE of already associated trajectories."""
    if delta_unit is DeltaUnit.FRAMES:
        if float(delta) != int(delta):
            raise EvalError(f"RPE delta in frames must be a whole number, got {delta}")
        pairs = frame_pairs(len(assoc), int(delta), all_pairs)
    else:
        pairs = time_pairs(assoc.est.stamps_s, float(delta), rel_tol, all_pairs)
    if len(pairs) == 0:
        raise EvalError(
            f"RPE with delta {delta} {delta_unit.value} found no pose pairs among "
            f"{len(assoc)} associated poses (try a smaller delta)"
        )
    alignment = align_trajectories(assoc.gt, assoc.est, with_scale=True) if sim3 else Alignment()
    est = alignment.apply(assoc.est) if sim3 else assoc.est
    t_err, r_err = relative_errors(assoc.gt.poses(), est.poses(), pairs)
    return RpeResult(
        trans=ErrorStatistics.of(t_err),
        rot=ErrorStatistics.of(r_err),
        trans_errors_m=t_err,
        rot_errors_deg=r_err,
        pairs=pairs,
        stamps_s=assoc.gt.stamps_s[pairs[:, 1]],
        delta=float(delta),
        delta_unit=delta_unit,
        all_pairs=all_pairs,
        association=assoc,
        alignment=alignment,
        sim3=sim3,
    )
