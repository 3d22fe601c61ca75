"""Amodal completion of an object's 3D box for the semantic map: the side the camera never saw.

A MapObject's box is the robust extent of its points (`map_object.box_extent`), and its points lie on the
surfaces the camera saw: a potted plant by a wall, passed on one side, gives points on its front half only,
so its box is too shallow and its centre sits toward the camera. Object-level SLAM systems fill the unseen
part with a class prior on the object's size (CubeSLAM's and QuadricSLAM's size priors); here the prior is
one figure per class, its typical depth on the floor plan (`ObjectMapConfig.class_depth_m`), and the box
grows only along the horizontal direction it was seen from (`completed_box`).

It never shrinks a box, never moves it toward the camera, and leaves classes without a prior alone. It changes
only what the semantic map reports (box centre and size); the MapObject's own box and centroid (§4.2, used by
the association and the persistence filter) are untouched.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.objects.map_object import MapObject, ObjectMapConfig
from changing_slam_ros.core.objects.object_point_weights import Plane

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class CompletedBox:
    """The semantic map's box of one object: centre (3,) and size (3,) in metres, and how far it was grown (0: not)."""

    center_w: F64
    size_m: F64
    extension_m: float


def gravity_up(plane_normals: Sequence[F64], camera_up_w: F64, max_angle_deg: float = 45.0) -> F64 | None:
    """The map's up direction (3,) unit: the normal of the first plane (the room's planes come largest first:
    floor, walls, table tops) within `max_angle_deg` of the camera's up (its -y axis, `camera_up_w`), turned to
    agree with it; None when no plane is that close. Walls are 90 degrees off; a camera pitched down 30 degrees
    still picks the floor or a table top, which share the floor's normal."""
    hint = np.asarray(camera_up_w, np.float64).reshape(3)
    hint = hint / np.linalg.norm(hint)
    cos_max = np.cos(np.radians(max_angle_deg))
    for n in plane_normals:
        n = np.asarray(n, np.float64).reshape(3)
        c = float(n @ hint) / float(np.linalg.norm(n))
        if abs(c) >= cos_max:
            return np.sign(c) * n / np.linalg.norm(n)  # type: ignore[no-any-return]
    return None


def depth_seen(points_w: F64, direction: F64, fraction: float = 0.05) -> float:
    """Spread (metres) of points (N, 3) along the unit `direction` (3,), from the `fraction` to the
    1 - `fraction` quantile (robust to a few stray points)."""
    proj = np.asarray(points_w, np.float64).reshape(-1, 3) @ np.asarray(direction, np.float64).reshape(3)
    if len(proj) < 2:
        return 0.0
    lo, hi = np.quantile(proj, [fraction, 1.0 - fraction])
    return float(hi - lo)


def room_limit(center_w: F64, direction: F64, planes: Sequence[Plane], min_facing: float = 0.5) -> float:
    """How far (metres) from `center_w` (3,) along the unit `direction` (3,) the nearest of the room's planes
    facing that direction (|normal . direction| >= min_facing: walls for a horizontal direction, not the floor)
    lies; inf when none is ahead."""
    best = np.inf
    for p in planes:
        facing = float(p.normal @ direction)
        if abs(facing) < min_facing:
            continue
        t = -(float(p.normal @ center_w) + p.offset) / facing
        if t > 0.0:
            best = min(best, t)
    return float(best)


def _depth_points(obj: MapObject, planes: Sequence[Plane], structure_dist_m: float) -> F64:
    """The points whose spread is the depth seen: with the room's planes, every point of the object off them (a
    smaller object on top takes its neighbours out of the object's centroid, `shared_point_dist_m`, not out of
    its depth); without, those of positive weight."""
    if not planes:
        return obj.points_w if obj.point_weights is None else obj.points_w[obj.point_weights > 0.0]
    off = np.ones(obj.n_points, bool)
    for p in planes:
        off &= p.distance(obj.points_w) >= structure_dist_m
    return obj.points_w[off] if off.sum() >= 2 else obj.points_w


def completed_box(obj: MapObject, config: ObjectMapConfig, planes: Sequence[Plane] = ()) -> CompletedBox:
    """The object's box, grown away from the camera to its class's typical depth when it was seen from one side
    only (below), but not through a wall: `planes` are the room's large planes (`object_point_weights`,
    map frame), and the grown box ends at the first one behind the object (a plant against a wall is not pushed
    into it); the MapObject's own box otherwise.

    - `up`: the map's up direction, the mean of the ups recorded with the object's whole views
      (`MapObject.up_sum_w`; each the floor's normal as the object layer knew it then, `gravity_up`). Without it
      there is no completion: the map frame is the first camera's, and a camera looking down 20 degrees on a
      90-cm plant would count 30 cm of its height as depth along the tilted viewing direction.
    - `h`: the mean of the unit vectors from the camera to the object over its whole views (`view_sum_w` /
      `n_views`) with its vertical part removed. Its length R over the views' says how much they agree; R below
      `completion_min_concentration` means the object was seen from around, so its points already span its depth.
    - the depth seen, e = the 5-95 % spread along h of the object's points off the room's planes (of positive
      weight when no planes are given);
    - when e is below the class's typical depth D, the box is extended by D - e along h, away from the camera: its
      centre moves by (D - e) / 2 and each axis grows by |h_i| (D - e) (the axis-aligned box holding the box and
      its copy pushed back).

    Directions are kept in the map frame when they are taken; a later loop correction that turns the map by a
    few degrees leaves them that much off.
    """
    center = np.asarray(obj.box_center_w, np.float64).copy()
    size = np.asarray(obj.box_size_m, np.float64).copy()
    unchanged = CompletedBox(center, size, 0.0)
    prior = config.class_depth_m.get(int(obj.class_id), 0.0)
    up_norm = float(np.linalg.norm(obj.up_sum_w))
    if not config.box_completion or prior <= 0.0 or obj.n_views < 1 or obj.n_points < 2 or not up_norm > 0.0:
        return unchanged
    up = obj.up_sum_w / up_norm
    h = obj.view_sum_w - (obj.view_sum_w @ up) * up  # the views' mean direction on the floor plan
    length = float(np.linalg.norm(h))
    if not np.isfinite(length) or length / obj.n_views < config.completion_min_concentration:
        return unchanged
    h = h / length
    pts = _depth_points(obj, planes, config.structure_plane_dist_m)
    grow = prior - depth_seen(pts, h)
    if planes and grow > 0.0:
        proj = pts @ h
        far = float(np.quantile(proj, 0.95)) if len(proj) else float(center @ h)
        wall = float(center @ h) + room_limit(center, h, planes)
        grow = min(grow, wall - far)
    if grow <= 0.0:
        return unchanged
    return CompletedBox(center + 0.5 * grow * h, size + grow * np.abs(h), float(grow))
