"""The image motion of what is inside a box, between two images (Median Flow, Kalal et al. 2010).

A person box detected in one image is needed in a later one (real time: the detector is slower than tracking,
`core.late_detections`). Instead of guessing where the person went, measure it: points on a regular grid over
the box in the earlier image -- only those on the foreground, i.e. with a depth at or in front of the box's near
depth plus `foreground_margin_m` (the person, not the wall seen past it) -- are tracked into the later image with
pyramidal Lucas-Kanade (`cv2.calcOpticalFlowPyrLK`) and back again. A point whose backward track misses its start
by more than `max_fb_error_px` is dropped (forward-backward error: occlusions, textureless areas, drift). The box
moves by the median displacement of the points left and scales about its centre by the median ratio of their
distances to their median point (after / before). Too few points left: no motion (the caller falls back to
growing the box).

The image motion measured this way is the person's own motion and the camera's together, which is what the
late box needs. Each box is tracked in a window around it only (cheap pyramids).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from changing_slam_ros.errors import ConfigError

F32 = npt.NDArray[np.float32]
U8 = npt.NDArray[np.uint8]


@dataclass(frozen=True)
class BoxFlowConfig:
    """How a box's image motion is measured.

    - `grid_side`: points per box side on the regular grid (Median Flow: 10 x 10; 8 x 8 costs less).
    - `window_px`: Lucas-Kanade window side (pixels, odd); `pyramid_levels`: pyramid levels above the image.
    - `max_fb_error_px`: a point tracked forward then back must land within this many pixels of its start.
    - `min_points`: fewer points left than this = no motion measured.
    - `foreground_margin_m`: with depth, a grid point is used only where its depth is valid and at most this far
      behind the box's near depth (`near_depth_percentile` of the valid depths in the box); the §4.1 person
      margin is 0.8 m.
    - `max_scale_change`: the scale ratio is clamped to [1 / (1 + this), 1 + this]; with fewer than
      `min_scale_points` points left the scale is taken as 1 (a median of a few ratios is mostly noise).
    - `search_margin`: points are tracked within the box grown by this many of its widths (heights) per side
      (plus the LK window); a point that moves farther is lost. A person walking 1 m/s at 2 m crosses about a
      third of a box width in the ~0.15 s a detection is late.
    """

    grid_side: int = 8
    window_px: int = 9
    pyramid_levels: int = 3
    max_fb_error_px: float = 1.0
    min_points: int = 6
    foreground_margin_m: float = 0.8
    near_depth_percentile: float = 5.0
    max_scale_change: float = 0.3
    min_scale_points: int = 12
    search_margin: float = 0.5

    def __post_init__(self) -> None:
        if self.grid_side < 2:
            raise ConfigError(f"box_flow.grid_side: expected >= 2, got {self.grid_side}")
        if self.window_px < 3 or self.window_px % 2 == 0:
            raise ConfigError(f"box_flow.window_px: expected an odd number >= 3, got {self.window_px}")
        if self.min_points < 1:
            raise ConfigError(f"box_flow.min_points: expected >= 1, got {self.min_points}")
        if not 0.0 <= self.near_depth_percentile < 50.0:
            raise ConfigError(f"box_flow.near_depth_percentile: expected [0, 50), got {self.near_depth_percentile}")


@dataclass(frozen=True)
class FlowImage:
    """One image the flow is measured on: `grey` (H, W) uint8, `depth_m` (H, W) float32 metres (0 = no reading)
    or None (then every grid point is used)."""

    stamp_ns: int
    grey: U8
    depth_m: F32 | None = None

    @classmethod
    def from_rgb(cls, stamp_ns: int, rgb: U8, depth_m: F32 | None = None) -> FlowImage:
        """From an (H, W, 3) RGB image (grey: OpenCV's luma weights)."""
        return cls(stamp_ns, cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), depth_m)


@dataclass(frozen=True)
class BoxMotion:
    """A box's image motion: median displacement (pixels) and scale ratio about its centre, from `n_points`."""

    dx_px: float
    dy_px: float
    scale: float
    n_points: int

    def apply(
        self, box_xyxy: tuple[float, float, float, float], width: int = 0, height: int = 0, border_px: float = 2.0
    ) -> tuple[float, float, float, float]:
        """The box moved by (dx, dy) and scaled about its centre. With the image size given, a box cut by the image
        border (an edge within `border_px` of it) keeps that edge on the border and moves only its other edge by
        the displacement, unscaled (the person goes on beyond the border; the box is only what is in view)."""
        x0, x1 = _moved_interval(box_xyxy[0], box_xyxy[2], self.dx_px, self.scale, width, border_px)
        y0, y1 = _moved_interval(box_xyxy[1], box_xyxy[3], self.dy_px, self.scale, height, border_px)
        return (x0, y0, x1, y1)


def _moved_interval(lo: float, hi: float, shift: float, scale: float, size: int, border_px: float) -> tuple[float, float]:
    """One axis of `BoxMotion.apply`: [lo, hi] shifted and scaled about its centre, or, cut by the image border
    (size > 0), kept on the border on that side and shifted on the other (both sides cut: unchanged)."""
    at_lo = size > 0 and lo <= border_px
    at_hi = size > 0 and hi >= size - 1 - border_px
    if at_lo and at_hi:
        return lo, hi
    if at_lo:
        return lo, max(hi + shift, lo + 1.0)
    if at_hi:
        return min(lo + shift, hi - 1.0), hi
    centre, half = 0.5 * (lo + hi) + shift, 0.5 * (hi - lo) * scale
    return centre - half, centre + half


def grid_points(box_xyxy: tuple[float, float, float, float], image: FlowImage, cfg: BoxFlowConfig) -> F32:
    """The box's grid points (N, 2) float32 (x, y) inside the image, on its foreground when there is depth."""
    h, w = image.grey.shape[:2]
    x0, y0, x1, y1 = box_xyxy
    t = (np.arange(cfg.grid_side, dtype=np.float32) + 0.5) / cfg.grid_side
    xs, ys = np.meshgrid(x0 + t * (x1 - x0), y0 + t * (y1 - y0))
    pts = np.stack([xs.ravel(), ys.ravel()], axis=1).astype(np.float32)
    pts = pts[(pts[:, 0] >= 0) & (pts[:, 0] <= w - 1) & (pts[:, 1] >= 0) & (pts[:, 1] <= h - 1)]
    if image.depth_m is None or len(pts) == 0:
        return pts
    d = image.depth_m[np.round(pts[:, 1]).astype(np.intp), np.round(pts[:, 0]).astype(np.intp)]
    valid = d > 0
    if not valid.any():
        return pts[:0]
    vals = _box_depths(box_xyxy, image.depth_m)
    k = int(cfg.near_depth_percentile / 100.0 * (len(vals) - 1))
    near = float(np.partition(vals, k)[k])  # the percentile's lower neighbour (np.percentile costs more)
    return pts[valid & (d <= near + cfg.foreground_margin_m)]


def _box_depths(box_xyxy: tuple[float, float, float, float], depth_m: F32) -> F32:
    """Valid depths in the box, sampled on a stride (the near depth needs no more)."""
    h, w = depth_m.shape
    x0, y0 = max(int(box_xyxy[0]), 0), max(int(box_xyxy[1]), 0)
    x1, y1 = min(int(np.ceil(box_xyxy[2])) + 1, w), min(int(np.ceil(box_xyxy[3])) + 1, h)
    stride = max(1, min(x1 - x0, y1 - y0) // 32)
    vals = depth_m[y0:y1:stride, x0:x1:stride].ravel()
    vals = vals[vals > 0]
    return vals if vals.size else np.zeros(1, dtype=np.float32)


def box_motions(
    boxes_xyxy: list[tuple[float, float, float, float]], before: FlowImage, after: FlowImage, cfg: BoxFlowConfig
) -> list[BoxMotion | None]:
    """Each box's image motion from `before` to `after` (None where too few points survive)."""
    if before.grey.shape != after.grey.shape:
        raise ValueError(f"box flow: image sizes differ, {before.grey.shape} and {after.grey.shape}")
    return [box_motion(b, before, after, cfg) for b in boxes_xyxy]


def box_motion(
    box_xyxy: tuple[float, float, float, float], before: FlowImage, after: FlowImage, cfg: BoxFlowConfig
) -> BoxMotion | None:
    """One box's image motion from `before` to `after`, or None. Only a window around the box is tracked in (the
    box grown by `search_margin` of its size per side plus the LK window): cheap pyramids, and a point that
    leaves the window is lost."""
    pts = grid_points(box_xyxy, before, cfg)
    if len(pts) < cfg.min_points:
        return None
    h, w = before.grey.shape[:2]
    x0, y0, x1, y1 = box_xyxy
    mx = cfg.search_margin * (x1 - x0) + cfg.window_px
    my = cfg.search_margin * (y1 - y0) + cfg.window_px
    cx0, cy0 = max(int(x0 - mx), 0), max(int(y0 - my), 0)
    cx1, cy1 = min(int(np.ceil(x1 + mx)) + 1, w), min(int(np.ceil(y1 + my)) + 1, h)
    offset = np.array([cx0, cy0], dtype=np.float32)
    crop0 = np.ascontiguousarray(before.grey[cy0:cy1, cx0:cx1])
    crop1 = np.ascontiguousarray(after.grey[cy0:cy1, cx0:cx1])
    lk = {"winSize": (cfg.window_px, cfg.window_px), "maxLevel": cfg.pyramid_levels,
          "criteria": (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.03)}  # fmt: skip
    p0 = (pts - offset).reshape(-1, 1, 2)
    p1, st1, _ = cv2.calcOpticalFlowPyrLK(crop0, crop1, p0, None, **lk)
    pb, st2, _ = cv2.calcOpticalFlowPyrLK(crop1, crop0, p1, None, **lk)
    back = (pb - p0).reshape(-1, 2)
    fb_sq = back[:, 0] ** 2 + back[:, 1] ** 2
    keep = (st1.ravel() == 1) & (st2.ravel() == 1) & (fb_sq <= cfg.max_fb_error_px**2)
    if int(keep.sum()) < cfg.min_points:
        return None
    a, b = p0.reshape(-1, 2)[keep].astype(np.float64), p1.reshape(-1, 2)[keep].astype(np.float64)
    return _median_motion(a, b, cfg)


def _median_motion(a: npt.NDArray[np.float64], b: npt.NDArray[np.float64], cfg: BoxFlowConfig) -> BoxMotion:
    """Median displacement of matched points a -> b (N, 2), and the median ratio of their distances to their
    median point (after / before: the scale, N ratios instead of Median Flow's N^2 / 2 pairs)."""
    med = np.median(np.hstack([b - a, a, b]), axis=0)  # one call: displacement, median point before, after
    ra = np.hypot(a[:, 0] - med[2], a[:, 1] - med[3])
    rb = np.hypot(b[:, 0] - med[4], b[:, 1] - med[5])
    d = med[:2]
    use = ra > 1.0
    scale = float(np.median(rb[use] / ra[use])) if int(use.sum()) >= cfg.min_scale_points else 1.0
    limit = 1.0 + cfg.max_scale_change
    return BoxMotion(float(d[0]), float(d[1]), float(np.clip(scale, 1.0 / limit, limit)), len(a))
