"""A 2-D occupancy grid on the floor, built from the keyframes' depth scans (`grid_scan.py`) at their current poses.

The grid lies in the floor frame (`floor_plane.FloorEstimate.frame`: z up, on the floor). Each keyframe, oldest
first, adds log-odds evidence (`build_grid`):

- obstacles: its points whose height above the floor lies in [`min_height_m`, `max_height_m`], except points of
  dynamic detections and of MapObjects whose belief fell below `object_min_belief` (an object the map no longer
  believes is there: a moved chair's old place);
- free space: the cells its rays cross on the floor plane, from the camera to each point, ending `free_margin_m`
  before the point and at the first cell this keyframe itself finds occupied (a ray that passes over a low
  table must not clear the table). Rays to excluded points count too: the line of sight to a person is free
  up to the person, and that is what clears the ghost a person left while the detector missed them.

Evidence is clamped, so newer views outweigh older ones after a few keyframes (a place seen empty after an
object left it clears); the grid is recomputed from all keyframes at their current poses whenever asked for.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.map.floor_plane import FloorEstimate, camera_up_hint, estimate_floor
from changing_slam_ros.core.map.grid_scan import GridScan
from changing_slam_ros.errors import ConfigError

F64 = npt.NDArray[np.float64]
FREE, UNKNOWN, OCCUPIED = 0, -1, 100  # nav_msgs/OccupancyGrid cell values


@dataclass(frozen=True)
class GridConfig:
    """YAML section `grid:`: the 2-D occupancy grid for navigation, built from a depth scan kept per keyframe.

    - `enabled`: keyframes keep a depth scan and the grid is built (false: neither; no grid is published or saved).
    - `resolution_m`: cell side (metres).
    - `min_height_m`, `max_height_m`: points at heights (above the estimated floor) in this band are obstacles;
      below is floor, above is what the robot passes under.
    - `max_range_m`: depth readings beyond this are not kept (depth noise grows with the square of range).
    - `scan_columns`: samples across the image per keyframe scan (rows follow the image's aspect): 64 keeps
      about 3000 points per keyframe at 4:3.
    - `free_margin_m`: a ray clears cells up to this far short of its point (depth noise, cell edges).
    - `hit_log_odds`: evidence one keyframe adds to a cell it sees occupied.
    - `miss_log_odds`: evidence one keyframe adds to a cell its rays cross (negative).
    - `clamp_min_log_odds`: a cell's evidence never goes below this.
    - `clamp_max_log_odds`: a cell's evidence never goes above this: low enough that a few newer views of the
      place empty overturn many older views of an object there (2.0: four keyframes).
    - `occupied_log_odds`: a cell with more evidence than this is occupied.
    - `free_log_odds`: a cell with less evidence than this is free (unknown between the two).
    - `dynamic_band_m`: inside a dynamic detection's box, points nearer than the box's median depth plus this
      are the mover's and never obstacles.
    - `object_min_belief`: points of MapObjects with a belief below this are never obstacles (0.5 is the belief
      of an object seen and never missed; below it, an object missed where it was expected).
    - `object_margin_m`: a point within this of a MapObject's 3-D box (and inside its image box) is the object's.
    - `floor_inlier_m`: points within this of the floor plane are the floor's (`floor_plane.estimate_floor`).
    - `floor_min_fraction`: the floor holds at least this fraction of the scan points; a grid without such a
      plane stands on the lowest points.
    - `max_cells`: a grid larger than this many cells is refused (a pose far off would otherwise allocate
      without bound).
    """

    enabled: bool = True
    resolution_m: float = 0.05
    min_height_m: float = 0.05
    max_height_m: float = 1.5
    max_range_m: float = 4.0
    scan_columns: int = 64
    free_margin_m: float = 0.1
    hit_log_odds: float = 0.85
    miss_log_odds: float = -0.4
    clamp_min_log_odds: float = -2.0
    clamp_max_log_odds: float = 2.0
    occupied_log_odds: float = 0.5
    free_log_odds: float = -0.3
    dynamic_band_m: float = 0.5
    object_min_belief: float = 0.5
    object_margin_m: float = 0.1
    floor_inlier_m: float = 0.03
    floor_min_fraction: float = 0.01
    max_cells: int = 16_000_000

    def __post_init__(self) -> None:
        if not self.resolution_m > 0.0:
            raise ConfigError(f"grid.resolution_m: expected > 0, got {self.resolution_m}")
        if not self.max_height_m > self.min_height_m:
            raise ConfigError(f"grid.max_height_m ({self.max_height_m}) must be above grid.min_height_m "
                              f"({self.min_height_m})")  # fmt: skip
        if not self.max_range_m > 0.0 or self.scan_columns < 1:
            raise ConfigError("grid.max_range_m must be > 0 and grid.scan_columns >= 1")
        if not self.clamp_min_log_odds < self.free_log_odds <= self.occupied_log_odds < self.clamp_max_log_odds:
            raise ConfigError("grid: expected clamp_min_log_odds < free_log_odds <= occupied_log_odds < "
                              "clamp_max_log_odds")
        if not (self.hit_log_odds > 0.0 > self.miss_log_odds):
            raise ConfigError("grid: expected hit_log_odds > 0 > miss_log_odds")


@dataclass(frozen=True)
class ScanView:
    """One keyframe's scan at its current pose: `T_map_cam` (4, 4) and the scan; `stamp_ns` orders the views."""

    stamp_ns: int
    T_map_cam: F64
    scan: GridScan


@dataclass
class OccupancyGrid:
    """`log_odds` (H, W) float32, row r / column c is the cell [x0 + c res, x0 + (c+1) res) x [y0 + r res, ...) of
    the floor frame `T_map_floor` (4, 4), (x0, y0) = `origin_xy`; `floor` the plane it lies on."""

    log_odds: npt.NDArray[np.float32]
    resolution_m: float
    origin_xy: F64
    T_map_floor: F64
    floor: FloorEstimate
    n_views: int

    @property
    def shape(self) -> tuple[int, int]:
        return self.log_odds.shape  # type: ignore[return-value]

    def occupancy(self, cfg: GridConfig) -> npt.NDArray[np.int8]:
        """(H, W) int8: 100 occupied, 0 free, -1 unknown (nav_msgs/OccupancyGrid values)."""
        out = np.full(self.log_odds.shape, UNKNOWN, np.int8)
        out[self.log_odds > cfg.occupied_log_odds] = OCCUPIED
        out[self.log_odds < cfg.free_log_odds] = FREE
        return out

    def origin_in_map(self) -> F64:
        """The pose (4, 4) of cell (0, 0)'s outer corner in the map frame (nav_msgs/MapMetaData.origin)."""
        T = np.eye(4)
        T[:2, 3] = self.origin_xy
        return self.T_map_floor @ T

    def cell_centres_map(self) -> F64:
        """Centres of all cells (H, W, 3) in the map frame, on the floor."""
        h, w = self.shape
        c, r = np.meshgrid(np.arange(w), np.arange(h))
        local = np.stack([self.origin_xy[0] + (c + 0.5) * self.resolution_m,
                          self.origin_xy[1] + (r + 0.5) * self.resolution_m, np.zeros((h, w))], axis=-1)  # fmt: skip
        return local @ self.T_map_floor[:3, :3].T + self.T_map_floor[:3, 3]


def views_floor(views: Sequence[ScanView], cfg: GridConfig, up_hint: F64 | None = None) -> FloorEstimate | None:
    """The floor under all scans (`floor_plane.estimate_floor`), with the cameras' up as the hint unless given."""
    pts = [v.scan.points_cam.astype(np.float64) @ v.T_map_cam[:3, :3].T + v.T_map_cam[:3, 3] for v in views]
    if not pts:
        return None
    hint = camera_up_hint(np.array([v.T_map_cam for v in views])) if up_hint is None else up_hint
    return estimate_floor(np.vstack(pts), hint, cfg.floor_inlier_m, cfg.floor_min_fraction)


def build_grid(views: Sequence[ScanView], cfg: GridConfig, floor: FloorEstimate | None = None,
               excluded_objects: Collection[int] = ()) -> OccupancyGrid | None:
    """The grid of `views` (see the module doc). `floor`: None estimates it from the scans; `excluded_objects`:
    MapObject ids whose points are never obstacles (`inactive_objects`). None when no view has a point."""
    views = sorted((v for v in views if len(v.scan)), key=lambda v: v.stamp_ns)
    if not views:
        return None
    floor = floor if floor is not None else views_floor(views, cfg)
    if floor is None:
        return None
    T_map_floor = floor.frame()
    T_floor_map = np.linalg.inv(T_map_floor)
    local = []
    for v in views:
        T = T_floor_map @ v.T_map_cam
        local.append((T[:3, 3], v.scan.points_cam.astype(np.float64) @ T[:3, :3].T + T[:3, 3]))
    res = cfg.resolution_m
    xy = np.vstack([np.vstack([c[None, :2], p[:, :2]]) for c, p in local])
    lo = np.floor(xy.min(axis=0) / res) * res - 2 * res
    hi = np.ceil(xy.max(axis=0) / res) * res + 2 * res
    w, h = (int(round(v)) for v in (hi - lo) / res)
    if w * h > cfg.max_cells:
        raise ValueError(f"occupancy grid of {w} x {h} cells exceeds grid.max_cells {cfg.max_cells}")
    log_odds = np.zeros(h * w, np.float32)
    scratch = np.zeros(h * w, bool)
    excluded = np.fromiter(excluded_objects, np.int64) if len(excluded_objects) else np.zeros(0, np.int64)
    for v, (centre, pts) in zip(views, local):
        hit, free = _view_evidence(centre, pts, v.scan, excluded, lo, (h, w), cfg, scratch)
        log_odds[free] += cfg.miss_log_odds
        log_odds[hit] += cfg.hit_log_odds
        np.clip(log_odds, cfg.clamp_min_log_odds, cfg.clamp_max_log_odds, out=log_odds)
    return OccupancyGrid(log_odds.reshape(h, w), res, lo, T_map_floor, floor, len(views))


def _cells(xy: F64, lo: F64, shape: tuple[int, int], res: float) -> npt.NDArray[np.int64]:
    """Flat cell index of floor-frame points (N, 2); -1 outside the grid."""
    h, w = shape
    ij = np.floor((xy - lo) / res).astype(np.int64)
    ok = (ij[:, 0] >= 0) & (ij[:, 0] < w) & (ij[:, 1] >= 0) & (ij[:, 1] < h)
    return np.where(ok, ij[:, 1] * w + ij[:, 0], -1)


def _view_evidence(centre: F64, pts: F64, scan: GridScan, excluded: npt.NDArray[np.int64], lo: F64,
                   shape: tuple[int, int], cfg: GridConfig,
                   scratch: npt.NDArray[np.bool_]) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """One keyframe's (occupied cells, free cells), each flat and unique, disjoint. `scratch` (H W,) all False
    on entry and on return."""
    res = cfg.resolution_m
    height = pts[:, 2]
    keep_out = scan.dynamic | (np.isin(scan.object_ids, excluded) if len(excluded) else False)
    obstacle = (height >= cfg.min_height_m) & (height <= cfg.max_height_m) & ~keep_out
    hit = np.unique(_cells(pts[obstacle, :2], lo, shape, res))
    hit = hit[hit >= 0]
    # Rays on the floor plane, sampled every half cell, from the camera to `free_margin_m` short of the point. Rays
    # that end in the same cell cross the same cells: one per end cell (the longest) is cast.
    end = _cells(pts[:, :2], lo, shape, res)
    d = pts[:, :2] - centre[:2]
    length = np.linalg.norm(d, axis=1)
    order = np.lexsort((-length, end))
    keep = order[np.r_[True, end[order][1:] != end[order][:-1]]]
    d, length = d[keep], length[keep]
    step = res / 2.0
    n = np.maximum(np.floor((length - cfg.free_margin_m) / step).astype(np.int64), 0)
    total = int(n.sum())
    if total == 0:
        return hit, np.zeros(0, np.int64)
    ray = np.repeat(np.arange(len(n)), n)
    first = np.cumsum(n) - n
    t = (np.arange(total) - first[ray] + 0.5) * step
    unit = d / np.maximum(length, 1e-9)[:, None]
    cells = _cells(centre[:2] + unit[ray] * t[:, None], lo, shape, res)
    # a ray stops at the first cell this keyframe sees occupied
    scratch[hit] = True
    blocked = np.where(cells >= 0, scratch[np.maximum(cells, 0)], True)
    scratch[hit] = False
    seen = np.cumsum(blocked)
    before_ray = seen[first] - blocked[first]
    open_cells = cells[(seen - before_ray[ray]) == 0]
    scratch[open_cells] = True
    scratch[hit] = False
    free = np.flatnonzero(scratch)
    scratch[free] = False
    return hit, free


def inactive_objects(objects: Sequence[object], min_belief: float) -> set[int]:
    """Ids of the MapObjects (anything with `id` and `belief`) whose belief is below `min_belief`."""
    return {int(o.id) for o in objects if float(o.belief) < min_belief}  # type: ignore[attr-defined]
