"""Time association of a ground-truth and an estimated trajectory (TUM / evo convention).

The rule reproduces `evo_ape tum GT EST --t_max_diff D --t_offset S` exactly:

1. the offset S (seconds) is added to the estimate's stamps;
2. the trajectory with fewer poses is the *short* one (the estimate when both have the same
   length); for every pose of the short trajectory, in order, the pose of the long trajectory
   with the nearest stamp is taken (the first one on a tie) and the pair is kept when the
   stamp difference is at most D;
3. pairs keep the short trajectory's order. A pose of the long trajectory can be used by
   several pairs when the short one has duplicate or very close stamps (evo does the same).

The offset is applied exactly as evo applies it, to the long trajectory's stamps with a sign, so
that the floating-point differences compared with D are bit-identical to evo's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.trajectory import Trajectory
from changing_slam_ros.errors import EvalError

F64 = npt.NDArray[np.float64]
IDX = npt.NDArray[np.intp]

DEFAULT_MAX_DIFF_S = 0.02


@dataclass(frozen=True)
class Association:
    """Matched pairs of two trajectories.

    - `gt`, `est`: the associated poses, same length M, pair k is (`gt[k]`, `est[k]`);
      `est` keeps its own stamps (without the offset).
    - `gt_indices`, `est_indices`: (M,) indices into the trajectories given to `associate`.
    - `max_diff_s`, `offset_s`: the parameters used.
    """

    gt: Trajectory
    est: Trajectory
    gt_indices: IDX
    est_indices: IDX
    max_diff_s: float
    offset_s: float

    def __len__(self) -> int:
        return len(self.gt_indices)

    @property
    def stamp_diffs_s(self) -> F64:
        """(M,) |t_gt - (t_est + offset)| per pair, seconds."""
        return np.abs(self.gt.stamps_s - (self.est.stamps_s + self.offset_s))


def nearest_stamp_indices(
    query_s: F64, stamps_s: F64, offset_s: float = 0.0
) -> tuple[IDX, F64]:
    """For each query stamp, the index of the nearest of `stamps_s + offset_s` and its distance.

    - `query_s`: (Q,) seconds, any order.
    - `stamps_s`: (N,) seconds, N >= 1, any order (sorted input takes the fast path).
    Ties go to the lowest index, as `np.argmin` does. Returns indices (Q,) and |diff| (Q,).
    """
    query = np.asarray(query_s, dtype=np.float64).reshape(-1)
    shifted = np.asarray(stamps_s, dtype=np.float64).reshape(-1) + offset_s
    if len(shifted) == 0:
        raise ValueError("cannot search an empty stamp list")
    if len(shifted) > 1 and np.any(np.diff(shifted) < 0):
        return _nearest_brute_force(query, shifted)
    # Sorted: the nearest value is at the insertion point or just before it. Rounding of
    # |x - q| is monotone on each side of q, so no other index can be strictly nearer.
    right = np.clip(np.searchsorted(shifted, query, side="left"), 0, len(shifted) - 1)
    left = np.clip(right - 1, 0, len(shifted) - 1)
    # The left candidate may sit at the end of a run of equal stamps: take the run's first index.
    left = np.searchsorted(shifted, shifted[left], side="left")
    d_left = np.abs(shifted[left] - query)
    d_right = np.abs(shifted[right] - query)
    take_right = d_right < d_left  # equal distances: the lower index (left) wins
    idx = np.where(take_right, right, left).astype(np.intp)
    return idx, np.where(take_right, d_right, d_left)


def _nearest_brute_force(query: F64, shifted: F64, chunk: int = 512) -> tuple[IDX, F64]:
    idx = np.empty(len(query), dtype=np.intp)
    dist = np.empty(len(query), dtype=np.float64)
    for start in range(0, len(query), chunk):
        q = query[start : start + chunk]
        diffs = np.abs(shifted[None, :] - q[:, None])
        idx[start : start + chunk] = np.argmin(diffs, axis=1)
        dist[start : start + chunk] = diffs[np.arange(len(q)), idx[start : start + chunk]]
    return idx, dist


def associate(
    gt: Trajectory,
    est: Trajectory,
    max_diff_s: float = DEFAULT_MAX_DIFF_S,
    offset_s: float = 0.0,
    gt_name: str = "ground truth",
    est_name: str = "estimate",
) -> Association:
    """Pair poses of `gt` and `est` by stamp (see the module docstring for the exact rule).

    Raises EvalError naming both trajectories when either is empty or no pair is within
    `max_diff_s`. The names are file paths when called from the CLI.
    """
    if max_diff_s < 0 or not np.isfinite(max_diff_s):
        raise EvalError(f"max time difference must be a finite value >= 0 s, got {max_diff_s}")
    if not np.isfinite(offset_s):
        raise EvalError(f"time offset must be finite, got {offset_s}")
    for traj, name in ((gt, gt_name), (est, est_name)):
        if len(traj) == 0:
            raise EvalError(f"{name}: trajectory is empty (no poses to evaluate)")

    est_longer = len(est) > len(gt)
    if est_longer:
        short, long_, sign = gt, est, +1.0
    else:
        short, long_, sign = est, gt, -1.0
    idx_long, dist = nearest_stamp_indices(short.stamps_s, long_.stamps_s, sign * offset_s)
    keep = dist <= max_diff_s
    idx_short = np.flatnonzero(keep).astype(np.intp)
    idx_long = idx_long[keep]
    if len(idx_short) == 0:
        raise EvalError(
            f"no associated stamps between {gt_name} ({len(gt)} poses, "
            f"{_span(gt)}) and {est_name} ({len(est)} poses, {_span(est)}) "
            f"with max difference {max_diff_s} s and offset {offset_s} s"
        )
    gt_idx, est_idx = (idx_short, idx_long) if est_longer else (idx_long, idx_short)
    return Association(
        gt=gt.subset(gt_idx),
        est=est.subset(est_idx),
        gt_indices=gt_idx,
        est_indices=est_idx,
        max_diff_s=float(max_diff_s),
        offset_s=float(offset_s),
    )


def _span(traj: Trajectory) -> str:
    return f"stamps {traj.stamps_s.min():.6f}..{traj.stamps_s.max():.6f} s"
