"""Class-agnostic moving points by free space: a keypoint now lies where an earlier frame saw through.

An earlier frame's depth image says, along each of its pixel rays, that space is empty up to the measured surface.
A current keypoint with depth, moved into that frame by the two poses, that lands in front of the surface the
earlier frame measured there (by more than the sensor's noise) occupies space that was empty then: something
moved into it. This is the multi-view depth check of DynaSLAM (Bescos et al. 2018) reduced to the tracked
keypoints and one earlier frame; it needs no class and no match between the frames, so it catches a person the
detector misses and a box of no COCO class alike, however much of the image they cover, as long as the earlier
frame saw the space behind them.

What it cannot see, by construction, is left unflagged rather than guessed: a point behind the earlier surface
(occluded then), a point outside the earlier image, a pixel without depth then, a mover moving away along the
ray, and one that has not moved since the earlier frame (a person sitting still).

Robustness to the pose prediction and to silhouettes: the earlier depth is min-filtered over a window
(`window_px`), so a static keypoint on the edge of a nearer object finds that object's depth within reach of a
few pixels of misalignment; the tolerance grows with the square of the depth, as depth noise does; and a flag
needs `min_neighbours` flagged keypoints among its `neighbours` nearest ones (isolated flags are noise or a
wrong depth).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.geometry.se3 import invert
from changing_slam_ros.errors import ConfigError

F64 = npt.NDArray[np.float64]
F32 = npt.NDArray[np.float32]
BoolArr = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class FreeSpaceConfig:
    """- `window_px`: half-size of the min filter on the earlier depth, in pixels of a 640-wide image (scaled
      with the width): how far a keypoint's projection may miss the nearer surface it belongs to.
    - `tolerance_m` + `tolerance_per_m2` * depth^2: how far in front of the earlier surface a point must lie.
    - `neighbours` / `min_neighbours`: a flagged keypoint is kept only with this many flagged ones among its
      nearest keypoints with depth (image distance)."""

    window_px: int = 8
    tolerance_m: float = 0.05
    tolerance_per_m2: float = 0.02
    neighbours: int = 6
    min_neighbours: int = 2

    def __post_init__(self) -> None:
        if self.window_px < 0 or self.tolerance_m < 0 or self.tolerance_per_m2 < 0:
            raise ConfigError("dynamic.free_space: window_px, tolerance_m and tolerance_per_m2 must be >= 0")
        if self.min_neighbours < 0 or self.neighbours < self.min_neighbours:
            raise ConfigError("dynamic.free_space: expected 0 <= min_neighbours <= neighbours")


def near_surface(depth_m: F32 | F64, width_ref: int, window_px: int) -> F32:
    """(H, W) the nearest measured depth within the window around each pixel; +inf where none is measured."""
    d = np.asarray(depth_m, dtype=np.float32)
    d = np.where(np.isfinite(d) & (d > 0), d, np.inf).astype(np.float32)
    r = int(round(window_px * d.shape[1] / width_ref))
    if r <= 0:
        return d
    return cv2.erode(d, cv2.getStructuringElement(cv2.MORPH_RECT, (2 * r + 1, 2 * r + 1)), borderValue=np.inf)


def free_space_violations(keypoints_px: F64, depths_m: F64, T_world_now: F64, near_then: F32, T_world_then: F64,
                          camera: CameraIntrinsics, cfg: FreeSpaceConfig) -> BoolArr:  # fmt: skip
    """(N,) keypoints (pixels, depths; 0 = none) of the current frame at pose `T_world_now` that lie in front of
    the earlier frame's surface (`near_surface` of its depth, pose `T_world_then`) by more than the tolerance, with
    enough flagged neighbours."""
    n = len(depths_m)
    flagged = np.zeros(n, dtype=bool)
    valid = np.flatnonzero(np.isfinite(depths_m) & (depths_m > 0))
    if len(valid) == 0:
        return flagged
    T_then_now = invert(T_world_then) @ T_world_now
    pts = camera.backproject(keypoints_px[valid], depths_m[valid]) @ T_then_now[:3, :3].T + T_then_now[:3, 3]
    z = pts[:, 2]
    front = z > 1e-3
    uv = np.full((len(valid), 2), -1.0)
    uv[front] = camera.project(pts[front])
    h, w = near_then.shape
    u, v = np.rint(uv[:, 0]).astype(np.int64), np.rint(uv[:, 1]).astype(np.int64)
    inside = front & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    surface = np.full(len(valid), np.inf)
    surface[inside] = near_then[v[inside], u[inside]]
    seen = np.isfinite(surface)
    tol = cfg.tolerance_m + cfg.tolerance_per_m2 * np.where(seen, surface, 0.0) ** 2
    hit = seen & (z < surface - tol)
    flagged[valid[hit]] = True
    if cfg.min_neighbours <= 0 or not hit.any():
        return flagged
    return _with_support(flagged, keypoints_px, valid, cfg.neighbours, cfg.min_neighbours)


def _with_support(flagged: BoolArr, keypoints_px: F64, valid: npt.NDArray[np.int64], k: int, need: int) -> BoolArr:
    """Flags that have at least `need` flagged keypoints among their `k` nearest keypoints with depth."""
    from scipy.spatial import cKDTree  # type: ignore[import-untyped]

    src = np.flatnonzero(flagged)
    k = min(k, len(valid) - 1)
    if k < need or k <= 0:
        return np.zeros_like(flagged)
    _, nn = cKDTree(keypoints_px[valid]).query(keypoints_px[src], k=k + 1)  # the first is the keypoint itself
    support = flagged[valid[nn[:, 1:]]].sum(axis=1)
    out = np.zeros_like(flagged)
    out[src[support >= need]] = True
    return out
