"""Floor patches: a detection whose points lie mostly on the floor is the floor, not an object (ours).

A detection box holds its object and what lies around it. For a camera at robot height the floor fills the lower
part of most boxes, and the depth band (`box_depth`) keeps the floor at the object's foot. Where the object itself
gave few points (a thin chair, a picture's box reaching down to the floor, a false detection on floor texture),
the floor is most of what is left, and its mean lies on the floor, up to a metre from anything real. A real
chair, plant or suitcase stands up from the floor: most of its points lie above it.

The floor comes from the keyframes' depth scans (the occupancy grid's samples, `keyframe_grid`), found by
`floor_plane.estimate_floor` with the cameras' up as the hint; the static map points seldom hold it (the floor is
seen at a grazing angle and has little texture). A candidate of a class outside `flat_classes` (a book, a phone, a
laptop may lie flat on the floor) with at least `floor_patch_min_fraction` of its points within
`floor_patch_dist_m` of the floor is a floor patch.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.map.floor_plane import FloorEstimate, camera_up_hint, estimate_floor
from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.map.occupancy_grid import GridConfig
from changing_slam_ros.core.objects.map_object import ObjectMapConfig
from changing_slam_ros.core.objects.object_point_weights import Plane

F64 = npt.NDArray[np.float64]
FLOOR_INLIER_M = GridConfig.floor_inlier_m  # the floor the occupancy grid stands on, fitted alike
FLOOR_MIN_FRACTION = GridConfig.floor_min_fraction
MAX_FLOOR_POINTS = 8000


def scans_floor(keyframes: Iterable[Keyframe], seed: int = 0) -> FloorEstimate | None:
    """The floor under the depth scans of `keyframes` (map frame); None without scans or where no plane holds the
    floor (`estimate_floor` falls back to the lowest points, which is no floor to test against)."""
    scanned = [kf for kf in keyframes if kf.grid_scan is not None and len(kf.grid_scan)]
    if not scanned:
        return None
    # a seeded random share of each scan, at most MAX_FLOOR_POINTS in all: the fit's cost stays flat as the map grows
    share = min(1.0, MAX_FLOOR_POINTS / sum(len(kf.grid_scan) for kf in scanned))  # type: ignore[arg-type]
    rng = np.random.default_rng(seed)
    pts, poses = [], []
    for kf in scanned:
        scan = kf.grid_scan
        assert scan is not None
        pick = rng.random(len(scan)) < share
        pick &= ~np.asarray(scan.dynamic, bool)
        p = np.asarray(scan.points_cam, np.float64)[pick]
        pts.append(p @ kf.T_world_cam[:3, :3].T + kf.T_world_cam[:3, 3])
        poses.append(kf.T_world_cam)
    if not any(len(p) for p in pts):
        return None
    floor = estimate_floor(np.vstack(pts), camera_up_hint(np.array(poses)), FLOOR_INLIER_M, FLOOR_MIN_FRACTION,
                           iterations=100, seed=seed)
    return floor if floor is not None and floor.n_support > 0 else None


def floor_fraction(points_w: F64, floor: FloorEstimate, dist_m: float) -> float:
    """The fraction of `points_w` (N, 3, map frame) within `dist_m` of the floor plane; 0 without points."""
    pts = np.asarray(points_w, np.float64).reshape(-1, 3)
    if len(pts) == 0:
        return 0.0
    return float(np.mean(floor_as_plane(floor).distance(pts) < dist_m))


def is_floor_patch(class_id: int, points_w: F64, floor: FloorEstimate | None, config: ObjectMapConfig) -> bool:
    """True when a detection of `class_id` with points `points_w` (N, 3, map frame) is a patch of `floor` (see the
    module doc); never without a floor, for `config.flat_classes`, or with the check off."""
    if floor is None or config.floor_patch_min_fraction <= 0.0 or int(class_id) in config.flat_classes:
        return False
    return floor_fraction(points_w, floor, config.floor_patch_dist_m) >= config.floor_patch_min_fraction


def floor_as_plane(floor: FloorEstimate) -> Plane:
    """The floor as one of the room's structure planes (`object_point_weights.Plane`: up . x - height = 0)."""
    up = floor.up / np.linalg.norm(floor.up)
    return Plane(up, -float(floor.height))
