"""A rotation that re-aims a motion-model prediction the projection search could not follow.

Where a camera starts or stops turning, the constant-velocity model misses its rotation by a few degrees: at
5 frames per second a robot that starts a 18 deg/s turn moves the image by ~30 px at 640x480, beyond the search
window (`tracking.radius_motion_px`). A wider window does not help on a repetitive texture (brick, tiles,
gravel): it finds the pattern's copies as well, and the pose optimisation then has no consistent majority.

The vote asks where the image moved. The map points the last frame tracked are projected with the prediction
and matched to this frame's keypoints by descriptor alone, the `k` nearest each and no ratio test (on a repeated
pattern the true partner is rarely the unique best). A rotation of the camera moves every point's image by
nearly the same displacement; the wrong partners spread over the pattern's period. The displacements vote in a
2-D histogram; the matches in the winning bin and its neighbours give the rotation that best aligns the
predicted bearings with the observed ones (Wahba's problem, solved by SVD). The caller searches again from the
re-aimed prediction with its usual window, and the usual pose optimisation and motion gate judge the result:
the vote only proposes where to look.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.errors import ConfigError

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class RotationVoteConfig:
    """YAML `tracking.rotation_vote:`.

    - `enabled`: re-aim a failed motion-model prediction by the vote (off: the frame goes straight to the
      reference-keyframe fallback and relocalisation).
    - `bin_px`: histogram bin size of the displacements (px at the image's resolution).
    - `k`: candidate partners per point (descriptor nearest neighbours).
    - `max_hamming`: a candidate farther than this (bits) gives no vote (ORB-SLAM's TH_HIGH).
    - `min_votes`: matches needed in the winning bin and its neighbours; fewer: no re-aim.
    - `max_shift_px`: displacements larger than this are not counted.
    - `max_translation_m`: the pose optimised from the re-aimed prediction is refused when its camera centre
      lies farther than this from the prediction's (the vote corrects the rotation only; a pose that also
      moved the centre matched a shifted copy of a repeated pattern).
    """

    enabled: bool = True
    bin_px: float = 8.0
    k: int = 2
    max_hamming: int = 100
    min_votes: int = 15
    max_shift_px: float = 160.0
    max_translation_m: float = 0.15

    def __post_init__(self) -> None:
        if self.bin_px <= 0:
            raise ConfigError(f"tracking.rotation_vote.bin_px: expected > 0, got {self.bin_px}")
        if self.k < 1:
            raise ConfigError(f"tracking.rotation_vote.k: expected >= 1, got {self.k}")
        if self.min_votes < 3:
            raise ConfigError(f"tracking.rotation_vote.min_votes: expected >= 3, got {self.min_votes}")


@dataclass(frozen=True)
class RotationVote:
    """The vote's result: `R_delta` (3, 3) rotates points in the predicted camera frame into the re-aimed one
    (`T_cw_new = [R_delta 0; 0 1] @ T_cw_pred`); `shift_px` the winning displacement; `votes` its matches."""

    R_delta: F64
    shift_px: tuple[float, float]
    votes: int


def vote_rotation(
    cfg: RotationVoteConfig,
    camera: CameraIntrinsics,
    points_cam: F64,
    point_descriptors: npt.NDArray[np.uint8],
    keypoints_px: npt.NDArray[np.float32],
    descriptors: npt.NDArray[np.uint8],
) -> RotationVote | None:
    """The re-aiming rotation from map points (N, 3) in the predicted camera frame with their descriptors
    (N, 32) against this frame's keypoints (M, 2) and descriptors (M, 32); None when no bin wins clearly."""
    front = points_cam[:, 2] > 1e-3
    points_cam, point_descriptors = points_cam[front], point_descriptors[front]
    if len(points_cam) < cfg.min_votes or len(descriptors) < cfg.min_votes:
        return None
    uv = camera.project(points_cam)
    k = min(cfg.k, len(descriptors))
    knn = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(point_descriptors, descriptors, k=k)
    rows, cols = [], []
    for i, cand in enumerate(knn):
        for m in cand:
            if m.distance <= cfg.max_hamming:
                rows.append(i)
                cols.append(m.trainIdx)
    if len(rows) < cfg.min_votes:
        return None
    ia, ib = np.asarray(rows, np.int64), np.asarray(cols, np.int64)
    d = keypoints_px[ib].astype(np.float64) - uv[ia]
    keep = np.abs(d).max(axis=1) <= cfg.max_shift_px
    ia, ib, d = ia[keep], ib[keep], d[keep]
    if len(d) < cfg.min_votes:
        return None
    # Votes per bin, summed over each bin's 3x3 neighbourhood so that a displacement on a bin border counts whole.
    n_bins = int(np.ceil(2 * cfg.max_shift_px / cfg.bin_px)) + 1
    cell = np.clip(np.floor((d + cfg.max_shift_px) / cfg.bin_px).astype(np.int64), 0, n_bins - 1)
    hist = np.zeros((n_bins + 2, n_bins + 2), np.int64)
    np.add.at(hist, (cell[:, 1] + 1, cell[:, 0] + 1), 1)
    summed = sum(np.roll(np.roll(hist, dy, 0), dx, 1) for dy in (-1, 0, 1) for dx in (-1, 0, 1))
    by, bx = np.unravel_index(int(np.argmax(summed)), summed.shape)
    member = (np.abs(cell[:, 1] + 1 - by) <= 1) & (np.abs(cell[:, 0] + 1 - bx) <= 1)
    # One vote per point: a point whose two candidates both fall in the bin counts once.
    ia, ib = ia[member], ib[member]
    _, first = np.unique(ia, return_index=True)
    ia, ib = ia[first], ib[first]
    if len(ia) < cfg.min_votes:
        return None
    a = _bearings(camera, uv[ia])
    b = _bearings(camera, keypoints_px[ib].astype(np.float64))
    R = _wahba(a, b)
    shift = np.median(keypoints_px[ib].astype(np.float64) - uv[ia], axis=0)
    return RotationVote(R, (float(shift[0]), float(shift[1])), len(ia))


def _bearings(camera: CameraIntrinsics, px: F64) -> F64:
    x = camera.backproject(px, np.ones(len(px)))
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def _wahba(a: F64, b: F64) -> F64:
    """The rotation R minimising sum |b_i - R a_i|^2 over unit vectors (SVD of the correlation matrix)."""
    u, _, vt = np.linalg.svd(b.T @ a)
    s = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    return u @ s @ vt
