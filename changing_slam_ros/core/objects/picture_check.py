"""Pictures on walls: a detection of a 3-D class whose points lie in a wall is a picture, not an object (ours).

A detector names what an image shows, also on a poster: a photo of a plant is a "potted plant", a photo of a
face a "person". A real plant, chair or ball has depth: its points stand off the wall behind it by a good part
of its size, while every point of a picture lies in the wall's plane (within the depth noise). The object layer
already fits the room's large planes to the static map points (`object_point_weights.fit_structure_planes`);
walls are those that span at least `wall_min_extent_m` (`plane_extent_m`: a plane through one object's own map
points, fitted before they were labelled, is no wall) and whose normal is far from the map's up. A candidate of a class outside `flat_classes` with at least
`picture_min_fraction` of its points within `picture_plane_dist_m` of one wall is a picture. Thin classes that do
hang on walls as real objects (a clock, a screen: `flat_classes`) are never pictures. Floors and table tops are
not walls: a book on a table, or a rug, is left to the other rules.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.objects.map_object import ObjectMapConfig
from changing_slam_ros.core.objects.object_point_weights import Plane

F64 = npt.NDArray[np.float64]


def walls(planes: Sequence[Plane], up_w: F64 | None, min_tilt_deg: float) -> list[Plane]:
    """The planes whose normal makes at least `min_tilt_deg` with `up_w` (3,) (vertical planes: walls, cupboard
    fronts); none while the up direction is unknown (None): a table top must not pass for a wall."""
    if up_w is None:
        return []
    up = np.asarray(up_w, np.float64).reshape(3)
    up = up / np.linalg.norm(up)
    max_cos = float(np.cos(np.radians(min_tilt_deg)))
    return [p for p in planes if abs(float(p.normal @ up)) <= max_cos + 1e-12]


def plane_extent_m(plane: Plane, points_w: F64, dist_m: float) -> float:
    """The larger 5-95 % spread (metres) of the points (N, 3) within `dist_m` of `plane`, along two axes in it."""
    pts = np.asarray(points_w, np.float64).reshape(-1, 3)
    on = pts[plane.distance(pts) < dist_m]
    if len(on) < 3:
        return 0.0
    seed = np.eye(3)[int(np.argmin(np.abs(plane.normal)))]
    e1 = seed - (seed @ plane.normal) * plane.normal
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(plane.normal, e1)
    spans = [float(np.subtract(*np.percentile(on @ e, [95, 5]))) for e in (e1, e2)]
    return max(spans)


def wall_fraction(points_w: F64, wall_planes: Sequence[Plane], dist_m: float) -> float:
    """The largest fraction of `points_w` (N, 3) within `dist_m` of any one of `wall_planes`; 0 without points."""
    pts = np.asarray(points_w, np.float64).reshape(-1, 3)
    if len(pts) == 0 or not wall_planes:
        return 0.0
    return max(float(np.mean(p.distance(pts) < dist_m)) for p in wall_planes)


def is_picture(class_id: int, points_w: F64, planes: Sequence[Plane], up_w: F64 | None,
               config: ObjectMapConfig) -> bool:
    """True when a detection of `class_id` with points `points_w` (N, 3, map frame) is a picture on a wall of the
    room's `planes` (see the module doc); never for `config.flat_classes` or with the check off."""
    if config.picture_plane_dist_m <= 0.0 or int(class_id) in config.flat_classes:
        return False
    on_wall = wall_fraction(points_w, walls(planes, up_w, config.wall_min_tilt_deg), config.picture_plane_dist_m)
    return on_wall >= config.picture_min_fraction
