"""Which of a MapObject's points are the object's, and how much each counts in its centroid (ours).

An object's point set (map points and depth samples taken inside its boxes, within a depth band) also holds
what the band cannot separate: the floor between a chair's legs, the wall behind it, the teddy bear sitting on
it; and parts seen from many keyframes hold many more samples than parts seen once. The mean of such a set
leans toward all three. `point_weights` gives 0 to points on the room's large planes or on a smaller object,
and down-weights densely sampled parts so that every occupied voxel of the surface counts once (an offline
study of centroid estimators, `bench/centroid_estimators.py`, chose this rule).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from changing_slam_ros.core.objects.map_object import MapObject, ObjectMapConfig

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Plane:
    """Points x with normal . x + offset = 0; `normal` (3,) unit."""

    normal: F64
    offset: float

    def distance(self, points: F64) -> F64:
        return np.abs(np.asarray(points, float).reshape(-1, 3) @ self.normal + self.offset)


def fit_structure_planes(points: F64, dist_m: float, min_fraction: float, max_planes: int, iterations: int,
                         max_points: int, seed: int = 0) -> list[Plane]:
    """Sequential RANSAC on `points` (N, 3): up to `max_planes` planes, each holding at least `min_fraction` of
    the N points within `dist_m`, refined by least squares on its inliers; each found plane's inliers are
    removed before the next. Hypotheses are scored on at most `max_points` points (a seeded subsample)."""
    pts = np.asarray(points, float).reshape(-1, 3)
    rng = np.random.default_rng(seed)
    if len(pts) > max_points:
        pts = pts[rng.choice(len(pts), max_points, replace=False)]
    need = max(3, int(np.ceil(min_fraction * len(pts))))
    planes: list[Plane] = []
    rest = pts
    for _ in range(max_planes):
        if len(rest) < need:
            break
        tri = rest[rng.integers(0, len(rest), size=(iterations, 3))]
        normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        norms = np.linalg.norm(normals, axis=1)
        ok = norms > 1e-9
        if not ok.any():
            break
        normals = normals[ok] / norms[ok, None]
        offsets = -np.einsum("ij,ij->i", normals, tri[ok, 0])
        counts = (np.abs(rest @ normals.T + offsets) < dist_m).sum(axis=0)
        best = int(np.argmax(counts))
        if counts[best] < need:
            break
        inl = np.abs(rest @ normals[best] + offsets[best]) < dist_m
        for _ in range(2):  # least-squares refit on the inliers, then select them again
            mu = rest[inl].mean(axis=0)
            n = np.linalg.svd(rest[inl] - mu, full_matrices=False)[2][-1]
            inl = np.abs((rest - mu) @ n) < dist_m
        if inl.sum() < need:
            break
        planes.append(Plane(n, float(-n @ mu)))
        rest = rest[~inl]
    return planes


def voxel_weights(points: F64, voxel_m: float) -> F64:
    """1 / (number of points in the point's `voxel_m` cube) per point (N,); all 1 for voxel_m 0."""
    pts = np.asarray(points, float).reshape(-1, 3)
    if voxel_m <= 0.0 or len(pts) == 0:
        return np.ones(len(pts))
    cells = np.floor(pts / voxel_m).astype(np.int64)
    cells -= cells.min(axis=0)
    span = cells.max(axis=0) + 1
    keys = (cells[:, 0] * span[1] + cells[:, 1]) * span[2] + cells[:, 2]  # one integer per cube
    _, inv, counts = np.unique(keys, return_inverse=True, return_counts=True)
    return 1.0 / counts[inv]


def point_weights(points: F64, planes: Sequence[Plane], smaller_points: F64 | None, config: ObjectMapConfig) -> F64:
    """Weights (N,) of one object's points (N, 3); rules below. `smaller_points` (M, 3): the points
    of the objects whose boxes are smaller than this one's (None or empty: none).

    - 0 to points closer than `structure_plane_dist_m` to one of the room's large planes (`fit_structure_planes`,
      fitted to the *static* map points, never to the object's own);
    - 0 to points closer than `shared_point_dist_m` to the points of another object whose box is smaller (what
      sits on or in front of this object belongs to the more specific object);
    - 1 / (the number of remaining points in its `centroid_voxel_m` cube) to the rest, so that every occupied cube
      of the surface counts once (0: every remaining point 1).

    If fewer than `min_points` points would keep a positive weight, all of them keep weight 1 (an object lying
    wholly on a plane, or wholly covered by a smaller one, is better described by all its points than by none).
    """
    pts = np.asarray(points, float).reshape(-1, 3)
    own = np.ones(len(pts), bool)
    if config.structure_plane_dist_m > 0.0:
        for plane in planes:
            own &= plane.distance(pts) >= config.structure_plane_dist_m
    if config.shared_point_dist_m > 0.0 and smaller_points is not None and len(smaller_points):
        d = cKDTree(np.asarray(smaller_points, float).reshape(-1, 3)).query(
            pts, distance_upper_bound=config.shared_point_dist_m)[0]
        own &= d >= config.shared_point_dist_m
    if own.sum() < config.min_points:
        own[:] = True
    w = np.zeros(len(pts))
    w[own] = voxel_weights(pts[own], config.centroid_voxel_m)
    return w


def reweight_objects(objects: Sequence[MapObject], planes: Sequence[Plane], config: ObjectMapConfig) -> None:
    """Set every object's point weights (`MapObject.set_weights`), with the room's `planes` and, per object, the
    points of every other object with a smaller box (volume of the current robust box) whose points come within
    `shared_point_dist_m` of this object's bounding box (the others cannot hold a point that close)."""
    with_points = [o for o in objects if o.n_points]
    volume = {o.id: float(np.prod(o.box_size_m)) for o in with_points}
    r = config.shared_point_dist_m
    lo = {o.id: o.points_w.min(axis=0) - r for o in with_points}
    hi = {o.id: o.points_w.max(axis=0) + r for o in with_points}
    for obj in with_points:
        smaller = [o.points_w for o in with_points
                   if o.id != obj.id and volume[o.id] < volume[obj.id] and r > 0.0
                   and np.all(lo[o.id] <= hi[obj.id]) and np.all(lo[obj.id] <= hi[o.id])]
        obj.set_weights(point_weights(obj.points_w, planes, np.vstack(smaller) if smaller else None, config))
