"""Volume overlap checking and merging of object targets (Dai et al. 2021, Section 3.5.2, eq. 12).

Points of one moving object are often created again from a new viewpoint and segmented as a new target.
Two targets g and h overlap when

    d = V_g + V_h - V_{g,h} > 0                                   (eq. 12)

with V the volume of the Delaunay tetrahedralisation (= convex hull) of a target's points and V_{g,h} that
of both targets' points together, all in the world frame at one stamp. Overlap is merged transitively,
so an intermediate target can join two that do not touch (the paper's Fig. 5b).

Eq. 12 merges point sets that interleave in space (the paper's case: duplicate points on the same
surfaces). Two halves of an object split by a plane do not overlap (d <= 0: the union's hull also covers
the gap between them); `MergeConfig.overlap_tolerance` can accept a small negative d for that case.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.backend.object_ba import ObjectObservations
from changing_slam_ros.core.movers.object_tracking import MovingObject
from changing_slam_ros.core.movers.delaunay_graph import hull_volume_m3
from changing_slam_ros.core.geometry.se3 import invert
from changing_slam_ros.errors import ConfigError

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


@dataclass(frozen=True)
class MergeConfig:
    """`overlap_tolerance`: merge when d > -overlap_tolerance * min(V_g, V_h); 0.0 is the paper's d > 0.

    `min_points`: targets with fewer points have no meaningful volume and are never merged.
    """

    overlap_tolerance: float = 0.0
    min_points: int = 4

    def __post_init__(self) -> None:
        if self.overlap_tolerance < 0.0:
            raise ConfigError(f"object_merging.overlap_tolerance: expected >= 0, got {self.overlap_tolerance}")


def overlap_m3(points_g: F64, points_h: F64) -> float:
    """Eq. 12: d = V_g + V_h - V_{g,h} in m^3 for two point sets (N, 3) and (M, 3); > 0 means overlap."""
    return hull_volume_m3(points_g) + hull_volume_m3(points_h) - hull_volume_m3(np.vstack([points_g, points_h]))


def _boxes_touch(a: F64, b: F64) -> bool:
    """Axis-aligned bounding boxes intersect (a necessary condition for hull overlap)."""
    return bool(np.all(a.min(axis=0) <= b.max(axis=0)) and np.all(b.min(axis=0) <= a.max(axis=0)))


def overlapping_groups(point_sets: list[F64], config: MergeConfig) -> list[list[int]]:
    """Indices of the point sets (each (N_g, 3), world frame, same stamp) grouped by transitive overlap.

    Every input index appears in exactly one group; groups and their members are in ascending order.
    """
    n = len(point_sets)
    parent = list(range(n))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    volumes = [hull_volume_m3(p) for p in point_sets]
    for g in range(n):
        for h in range(g + 1, n):
            a, b = point_sets[g], point_sets[h]
            if len(a) < config.min_points or len(b) < config.min_points:
                continue
            # Disjoint bounding boxes cannot give d > 0 (only checked for the paper's strict rule).
            if config.overlap_tolerance == 0.0 and not _boxes_touch(a, b):
                continue
            d = volumes[g] + volumes[h] - hull_volume_m3(np.vstack([a, b]))
            if d > -config.overlap_tolerance * min(volumes[g], volumes[h]):
                parent[find(h)] = find(g)
    groups: dict[int, list[int]] = {}
    for i in range(n):
        groups.setdefault(find(i), []).append(i)
    return sorted(groups.values())


def fuse_into(host: MovingObject, other: MovingObject, stamp_ns: int) -> MovingObject:
    """A new object: `other`'s points, poses and keyposes expressed in `host`'s frame, via both poses at `stamp_ns`.

    Both objects must be tracked at `stamp_ns`. Points `host` already has (same map point id) keep the
    host's position. The host's id and reference keypose are kept.
    """
    if stamp_ns not in host.poses or stamp_ns not in other.poses:
        raise ValueError(f"fuse_into: objects {host.object_id} and {other.object_id} must both be tracked at {stamp_ns}")
    # Rigid transform from the other object's frame to the host's (both frames move with the one object).
    T_host_other = invert(host.poses[stamp_ns]) @ other.poses[stamp_ns]
    new = ~np.isin(other.point_ids, host.point_ids)
    moved = other.points_obj @ T_host_other[:3, :3].T + T_host_other[:3, 3]
    point_ids = np.concatenate([host.point_ids, other.point_ids[new]])
    fused = MovingObject(host.object_id, point_ids, np.vstack([host.points_obj, moved[new]]), dict(host.poses))
    for stamp, T_world_other in other.poses.items():
        fused.poses.setdefault(stamp, T_world_other @ invert(T_host_other))
    # Keyposes re-indexed to the fused points by map point id, through one lookup table per source object
    # (the host's points come first and keep their indices when its ids are unique).
    host_map = fused.index_of(host.point_ids)
    if np.array_equal(host_map, np.arange(len(host.point_ids))):
        fused.keyposes = list(host.keyposes)
    else:
        fused.keyposes = [_remap(kp, host_map) for kp in host.keyposes]
    other_map = fused.index_of(other.point_ids)
    host_stamps = {kp.stamp_ns for kp in host.keyposes}
    fused.keyposes += [_remap(kp, other_map) for kp in other.keyposes if kp.stamp_ns not in host_stamps]
    fused.keyposes = fused.keyposes[:1] + sorted(fused.keyposes[1:], key=lambda kp: kp.stamp_ns)
    return fused


def _remap(kp: ObjectObservations, index_map: I64) -> ObjectObservations:
    """Keypose measurements re-indexed through `index_map` (source point index -> target point index)."""
    return ObjectObservations(kp.stamp_ns, kp.T_world_cam, index_map[kp.point_index], kp.points_cam)


def merge_objects(objects: list[MovingObject], stamp_ns: int, config: MergeConfig) -> list[MovingObject]:
    """Eq. 12 over the objects tracked at `stamp_ns`; each overlapping group is fused into its oldest member.

    The oldest member (earliest first pose, then lowest id) is the existing object new targets join.
    Objects not tracked at `stamp_ns` are returned unchanged. Order: by object id.
    """
    tracked = [o for o in objects if stamp_ns in o.poses]
    untouched = [o for o in objects if stamp_ns not in o.poses]
    groups = overlapping_groups([o.points_world(stamp_ns) for o in tracked], config)
    merged: list[MovingObject] = []
    for group in groups:
        members = sorted((tracked[i] for i in group), key=lambda o: (min(o.poses), o.object_id))
        host = members[0]
        for other in members[1:]:
            host = fuse_into(host, other, stamp_ns)
        merged.append(host)
    return sorted(merged + untouched, key=lambda o: o.object_id)
