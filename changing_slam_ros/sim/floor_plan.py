"""The ground-truth floor plan of a scenario: which floor cells hold something in a height band (`floor_plan`).

Walls, shelves and the actors' parts at a given time, each part's bounding box (its corners with the part's and
the actor's pose) laid onto the floor where its height range meets the band. Rasterised with sub-cell samples:
a cell is occupied when any of its samples lies in a footprint, so that a wall's one-cell-thick face counts
where a depth camera sees it. People (COCO class 0) are left out: they are the dynamic part of a scene, not
its plan. The world frame is the simulator's (z up, floor at z = 0).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from changing_slam_ros.sim.actors import Part
from changing_slam_ros.sim.scenarios import Scenario

F64 = npt.NDArray[np.float64]
PERSON = 0


@dataclass(frozen=True)
class FloorPlan:
    """`occupied` (H, W) bool; cell (r, c) spans [x0 + c res, x0 + (c + 1) res) x [y0 + r res, ...) in world
    metres, (x0, y0) = `origin_xy`."""

    occupied: npt.NDArray[np.bool_]
    resolution_m: float
    origin_xy: F64

    def lookup(self, xy_w: F64) -> npt.NDArray[np.int8]:
        """Per world point (N, 2): 1 occupied, 0 free, -1 outside the plan."""
        ij = np.floor((np.asarray(xy_w, float).reshape(-1, 2) - self.origin_xy) / self.resolution_m).astype(int)
        h, w = self.occupied.shape
        ok = (ij[:, 0] >= 0) & (ij[:, 0] < w) & (ij[:, 1] >= 0) & (ij[:, 1] < h)
        out = np.full(len(ij), -1, np.int8)
        out[ok] = self.occupied[ij[ok, 1], ij[ok, 0]]
        return out


def _footprints(parts: Sequence[Part], T_world: F64, min_z: float, max_z: float) -> list[F64]:
    out = []
    for p in parts:
        c = p.corners_m() @ T_world[:3, :3].T + T_world[:3, 3]
        if c[:, 2].max() >= min_z and c[:, 2].min() <= max_z:
            out.append(c[:, :2])
    return out


def _fill(mask: npt.NDArray[np.bool_], xs: F64, ys: F64, corners_xy: F64) -> None:
    """Set the samples (xs (W,), ys (H,)) inside the convex hull of `corners_xy` (8, 2)."""
    import cv2

    hull = cv2.convexHull(corners_xy.astype(np.float32)).reshape(-1, 2).astype(np.float64)
    x0, y0 = hull.min(axis=0)
    x1, y1 = hull.max(axis=0)
    ci = np.flatnonzero((xs >= x0) & (xs <= x1))
    ri = np.flatnonzero((ys >= y0) & (ys <= y1))
    if not len(ci) or not len(ri):
        return
    gx, gy = np.meshgrid(xs[ci], ys[ri])
    inside = np.ones(gx.shape, bool)
    n = len(hull)
    area2 = sum(hull[i, 0] * hull[(i + 1) % n, 1] - hull[(i + 1) % n, 0] * hull[i, 1] for i in range(n))
    sign = 1.0 if area2 >= 0 else -1.0
    for i in range(n):
        a, b = hull[i], hull[(i + 1) % n]
        cross = (b[0] - a[0]) * (gy - a[1]) - (b[1] - a[1]) * (gx - a[0])
        inside &= sign * cross >= -1e-9
    mask[np.ix_(ri, ci)] |= inside


def floor_plan(scenario: Scenario, t_s: float, min_z: float, max_z: float, resolution_m: float = 0.05,
               samples: int = 3) -> FloorPlan:
    """The plan at time `t_s`: the room's parts and the present non-person actors in the band [min_z, max_z]
    (metres above the floor), `samples` x `samples` samples per cell."""
    hx, hy = scenario.room.size_m[0] / 2.0 + 0.2, scenario.room.size_m[1] / 2.0 + 0.2
    origin = np.array([-hx, -hy])
    w, h = int(np.ceil(2 * hx / resolution_m)), int(np.ceil(2 * hy / resolution_m))
    sub = resolution_m / samples
    xs = origin[0] + (np.arange(w * samples) + 0.5) * sub
    ys = origin[1] + (np.arange(h * samples) + 0.5) * sub
    fine = np.zeros((h * samples, w * samples), bool)
    footprints = _footprints(scenario.room.parts, np.eye(4), min_z, max_z)
    for a in scenario.actors:
        T = a.track.pose_at(t_s)
        if a.class_id != PERSON and T is not None:
            footprints += _footprints(a.parts, T, min_z, max_z)
    for f in footprints:
        _fill(fine, xs, ys, f)
    occupied = fine.reshape(h, samples, w, samples).any(axis=(1, 3))
    return FloorPlan(occupied, resolution_m, origin)


def swept_plan(scenario: Scenario, actors: Sequence[int], times: Sequence[float], min_z: float, max_z: float,
               plan: FloorPlan, samples: int = 3) -> FloorPlan:
    """The cells of `plan`'s raster that the footprints of `actors` (indices) covered at any of `times` and that
    lie more than one cell from `plan`'s occupied cells: where a person walked, or an object stood before it
    moved, and nothing stands now (one cell of slack: an estimated grid's cells are not aligned with these)."""
    h, w = plan.occupied.shape
    res = plan.resolution_m
    sub = res / samples
    xs = plan.origin_xy[0] + (np.arange(w * samples) + 0.5) * sub
    ys = plan.origin_xy[1] + (np.arange(h * samples) + 0.5) * sub
    fine = np.zeros((h * samples, w * samples), bool)
    for i in actors:
        a = scenario.actors[i]
        for t in times:
            T = a.track.pose_at(float(t))
            if T is not None:
                for f in _footprints(a.parts, T, min_z, max_z):
                    _fill(fine, xs, ys, f)
    near = plan.occupied.copy()
    near[1:] |= plan.occupied[:-1]
    near[:-1] |= plan.occupied[1:]
    near[:, 1:] |= near[:, :-1].copy()
    near[:, :-1] |= near[:, 1:].copy()
    covered = fine.reshape(h, samples, w, samples).any(axis=(1, 3))
    return FloorPlan(covered & ~near, res, plan.origin_xy)
