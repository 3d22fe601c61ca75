"""Amodal completion of an object's 3D box for the semantic map: the side the camera never saw.

A MapObject's box is the robust extent of its points (`map_object.box_extent`), and its points lie on the
surfaces the camera saw. A potted plant by a wall, passed on one side, gives points on its front half only:
its box is 30 x 25 cm where the plant is 44 x 44 cm, and its centre sits 10-15 cm toward the camera
(docs/changing_scenes.md, "Session 7: box completion"). Object-level SLAM systems fill the unseen part with a
class prior on the object's size (CubeSLAM's and QuadricSLAM's size priors); here the prior is one figure per
class, its typical depth (`ObjectMapConfig.class_depth_m`), and the box grows only along the direction it was
seen from:

- `v`, the mean of the unit vectors from the camera to the object over its whole views (`MapObject.view_sum_w`
  / `n_views`); its length R says how much the views agree. R below `completion_min_concentration` means the
  object was seen from around, so its points already span its depth: no completion.
- the depth seen, e = the 5-95 % spread of the points (those of positive weight) along v/|v| around the plane
  that fits them best (`depth_seen`: the camera looks down on most objects, and a plain spread would count
  their height as depth);
- when e is below the class's typical depth D, the box is extended by D - e along v/|v|, away from the camera:
  its centre moves by (D - e) / 2 along that direction and each axis grows by |v_i| (D - e) (the axis-aligned box
  that holds the box and its copy pushed back).

It never shrinks a box, never moves it toward the camera, and leaves classes without a prior alone. It changes
only what the semantic map reports (box centre and size); the MapObject's own box and centroid (§4.2, used by
the association and the persistence filter) are untouched. View directions are kept in the map frame when they
are taken; a later loop correction that turns the map by a few degrees leaves them that much off.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.map_object import MapObject, ObjectMapConfig

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class CompletedBox:
    """The semantic map's box of one object: centre (3,) and size (3,) in metres, and how far it was grown (0: not)."""

    center_w: F64
    size_m: F64
    extension_m: float


def depth_seen(points_w: F64, direction: F64, fraction: float = 0.05) -> float:
    """Depth (metres) of the surface that points (N, 3) show along the unit `direction` (3,): the
    `fraction`..1 - `fraction` quantile spread of their coordinate along it, less what a plane through them
    explains. Without the plane, a tall plant seen from 20 degrees above would count its height's share along
    the tilted direction as depth (90 cm x sin 20 deg = 31 cm); with it, the front half of a round plant shows
    about its radius, a flat poster nothing. Needs no gravity direction (the map frame has none)."""
    pts = np.asarray(points_w, np.float64).reshape(-1, 3)
    if len(pts) < 4:
        return 0.0
    v = np.asarray(direction, np.float64).reshape(3)
    helper = np.eye(3)[int(np.argmin(np.abs(v)))]
    u1 = np.cross(v, helper)
    u1 /= np.linalg.norm(u1)
    u2 = np.cross(v, u1)
    a = np.c_[pts @ u1, pts @ u2, np.ones(len(pts))]
    along = pts @ v
    coef, *_ = np.linalg.lstsq(a, along, rcond=None)
    lo, hi = np.quantile(along - a @ coef, [fraction, 1.0 - fraction])
    return float(hi - lo)


def completed_box(obj: MapObject, config: ObjectMapConfig) -> CompletedBox:
    """The object's box, grown away from the camera to its class's typical depth when it was seen from one side
    only (module doc); the MapObject's own box otherwise."""
    center = np.asarray(obj.box_center_w, np.float64).copy()
    size = np.asarray(obj.box_size_m, np.float64).copy()
    unchanged = CompletedBox(center, size, 0.0)
    prior = config.class_depth_m.get(int(obj.class_id), 0.0)
    if not config.box_completion or prior <= 0.0 or obj.n_views < 1 or obj.n_points < 2:
        return unchanged
    length = float(np.linalg.norm(obj.view_sum_w))
    if not np.isfinite(length) or length / obj.n_views < config.completion_min_concentration:
        return unchanged
    v = obj.view_sum_w / length
    pts = obj.points_w if obj.point_weights is None else obj.points_w[obj.point_weights > 0.0]
    grow = prior - depth_seen(pts, v)
    if grow <= 0.0:
        return unchanged
    return CompletedBox(center + 0.5 * grow * v, size + grow * np.abs(v), float(grow))
