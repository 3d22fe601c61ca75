"""The depth band of a detection box: which of its depth pixels are its object, not what is seen past it.

A box holds its object and what lies behind or around it (the wall, the table top). `box_depth_band` keeps the
depths within half the box's smaller side (in metres, at its median depth) of that median, its near end
reaching toward the box's nearest depths; `box_depth_samples` back-projects a regular grid of the box's pixels
inside the band: the object's shape from depth alone, for the object layer's candidates (`object_layer`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.objects.map_object import BoxXyxy

F64 = npt.NDArray[np.float64]
MIN_DEPTH_BAND_M = 0.05


@dataclass(frozen=True)
class DepthBand:
    """The camera-frame depths (metres) taken as a box's object: within `half_m` of `median_m`, the box's median
    depth, and from `near_m` (<= median_m - half_m) up to that."""

    median_m: float
    half_m: float
    near_m: float

    def contains(self, depth_m: npt.ArrayLike) -> npt.NDArray[np.bool_]:
        """Which depths (any shape) lie inside the band."""
        d = np.asarray(depth_m, float)
        centred = np.abs(d - self.median_m) < self.half_m
        return centred | ((d > self.near_m) & (d <= self.median_m - self.half_m))  # type: ignore[no-any-return]


def _box_grid(depth_m: npt.NDArray[np.floating], box_xyxy: BoxXyxy,
              n_samples: int) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64], F64, int] | None:
    """Pixel columns, rows and depths (metres, 0 invalid) of a regular grid of about `n_samples` pixels of the
    box, and its smaller side in pixels inside the image; None for a box under 2 pixels a side."""
    h, w = depth_m.shape[:2]
    x0, y0 = max(0, int(np.floor(box_xyxy[0]))), max(0, int(np.floor(box_xyxy[1])))
    x1, y1 = min(w, int(np.ceil(box_xyxy[2]))), min(h, int(np.ceil(box_xyxy[3])))
    if x1 - x0 < 2 or y1 - y0 < 2:
        return None
    step = max(1, int(np.ceil(np.sqrt((x1 - x0) * (y1 - y0) / max(n_samples, 1)))))
    vv, uu = np.mgrid[y0 + step // 2:y1:step, x0 + step // 2:x1:step]
    return uu, vv, np.asarray(depth_m[vv, uu], float), min(x1 - x0, y1 - y0)


def _band(d_valid: F64, side_px: int, camera: CameraIntrinsics, depth_band_m: float,
          near_quantile: float) -> DepthBand:
    """The band of a box from its valid grid depths and its smaller side in pixels (see `box_depth_band`)."""
    median_m = float(np.median(d_valid))
    width_m = side_px * median_m / camera.fx
    half_m = float(np.clip(0.5 * width_m, MIN_DEPTH_BAND_M, depth_band_m))
    near_m = median_m - half_m
    if near_quantile > 0.0:  # toward the nearest depths, but at most one band width (the box's side) in front
        near_m = min(near_m, max(float(np.quantile(d_valid, near_quantile)) - 1e-6, median_m - 2.0 * half_m))
    return DepthBand(median_m, half_m, near_m)


def box_depth_band(depth_m: npt.NDArray[np.floating], box_xyxy: BoxXyxy, camera: CameraIntrinsics,
                   depth_band_m: float, n_samples: int = 100, near_quantile: float = 0.0) -> DepthBand | None:
    """The depths of a box's object, as `box_depth_samples` keeps them; None without depth (under 3 valid grid
    pixels).

    The band is centred on the median depth of the box's pixels, half the box's smaller side in metres at that
    depth wide on each side, within [MIN_DEPTH_BAND_M, depth_band_m]: a cup keeps 5 cm, not the table top behind
    it; a monitor keeps its screen, not the wall 30 cm behind. With `near_quantile` > 0 its near end reaches at
    least the box's `near_quantile` depth: a box holds its object and what is seen past and around it, seldom in
    front of it (a whole view), so its nearest depths are the object's. An open object seen at a slant (a chair
    from the side: 0.5 m of depth, its frame seen through) has a median depth at its far part or behind it, and
    the centred band cut its near half off (vanishing's moved chair: 40 % of its pixels kept in three of its five
    views). The near end moves at most one band width (2 `half_m`, the box's
    smaller side in metres) in front of the median: an object's depth span is about its width, since a footprint
    seen from any side spans in depth about what it spans across; what is nearer is something else in the box (a
    table's front edge below a cup seen from the table's height). The far end stays: behind is the background."""
    grid = _box_grid(depth_m, box_xyxy, n_samples)
    if grid is None:
        return None
    d = grid[2][grid[2] > 0]
    if len(d) < 3:
        return None
    return _band(d, grid[3], camera, depth_band_m, near_quantile)


def box_depth_samples(depth_m: npt.NDArray[np.floating], box_xyxy: BoxXyxy, camera: CameraIntrinsics,
                      n_samples: int, depth_band_m: float, near_quantile: float = 0.0) -> F64:
    """Camera-frame points (M, 3), M <= about n_samples: the box's pixels on a regular grid with valid depth
    inside its depth band (`box_depth_band`: the object, not the background seen past it)."""
    grid = _box_grid(depth_m, box_xyxy, n_samples)
    if grid is None:
        return np.zeros((0, 3))
    uu, vv, d, side_px = grid
    ok = d > 0
    if ok.sum() < 3:
        return np.zeros((0, 3))
    band = _band(d[ok], side_px, camera, depth_band_m, near_quantile)
    ok &= band.contains(d)
    px = np.c_[uu[ok], vv[ok]].astype(float)
    pts: F64 = camera.backproject(px, d[ok])
    return pts
