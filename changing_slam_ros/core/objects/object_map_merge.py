"""Object maps follow a map merge: the MapObjects of a map welded into another move with its keyframes.

When tracking is lost the Atlas starts a new map, and a later place recognition welds it into an older one
(`core/slam/map_merging.py`): the source map's keyframes and points move into the target by `T_into_from`, and
the source map is left empty. Its MapObjects must move too, or what the robot mapped while the source map was
current is lost: the objects stay behind in a map that holds no keyframe, in that map's old frame. This module
expresses them in the target map: positions and viewing directions moved by `T_into_from`, map point ids
shifted like the points (`point_id_offset`), depth-sample ids (negative, numbered per map) renumbered below the
target's, and object ids continued after the target's. A moved object within `ltda_threshold_m` of a target object
of its class (centroid to centroid, Algorithm 1's association test) is the same object seen before and after the
loss, and joins it.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.objects.map_object import EVIDENCE_CAP, EVIDENCE_HEAD, MapObject, ObjectMapConfig

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


def remap_point_ids(ids: I64, point_id_offset: int, sample_shift: int) -> I64:
    """Point ids of the source map in the target: map points (>= 0) shift by `point_id_offset`, depth samples
    (<= -2) by `sample_shift` (<= 0, so they stay below the target's own samples); -1 stays."""
    ids = np.asarray(ids, np.int64)
    out: I64 = np.where(ids >= 0, ids + point_id_offset, np.where(ids <= -2, ids + sample_shift, ids))
    return out


def moved_object(obj: MapObject, new_id: int, T_into_from: F64, point_id_offset: int, sample_shift: int) -> MapObject:
    """A copy of `obj` expressed in the target map (see the module docstring), with id `new_id`."""
    R, t = T_into_from[:3, :3], T_into_from[:3, 3]
    return dataclasses.replace(
        obj, id=new_id, point_ids=remap_point_ids(obj.point_ids, point_id_offset, sample_shift),
        points_w=np.asarray(obj.points_w, float).reshape(-1, 3) @ R.T + t,
        point_weights=None if obj.point_weights is None else obj.point_weights.copy(),
        view_sum_w=R @ obj.view_sum_w, up_sum_w=R @ obj.up_sum_w,
        belief_history=list(obj.belief_history), seen_keyframes=list(obj.seen_keyframes))


def same_object(moved: MapObject, targets: list[MapObject], config: ObjectMapConfig) -> MapObject | None:
    """The nearest target object of `moved`'s class within `ltda_threshold_m` (centroid to centroid), or None."""
    best, best_d = None, config.ltda_threshold_m
    for obj in targets:
        if obj.class_id != moved.class_id or obj.n_points < config.min_points or moved.n_points == 0:
            continue
        d = float(np.linalg.norm(obj.centroid_w - moved.centroid_w))
        if d < best_d:
            best, best_d = obj, d
    return best


def join(target: MapObject, moved: MapObject) -> None:
    """Fold `moved` into `target` (the same object seen in both maps): points unioned, the later sighting kept,
    whole views and viewing directions added; the belief is the target's (the older map's evidence)."""
    target.add_points(moved.point_ids, moved.points_w)
    target.last_seen_keyframe = max(target.last_seen_keyframe, moved.last_seen_keyframe)
    target.last_belief_update_keyframe = max(target.last_belief_update_keyframe, moved.last_belief_update_keyframe)
    target.n_observations += moved.n_observations
    target.view_sum_w = target.view_sum_w + moved.view_sum_w
    target.up_sum_w = target.up_sum_w + moved.up_sum_w
    target.n_views += moved.n_views
    seen = sorted(set(target.seen_keyframes) | set(moved.seen_keyframes))
    target.seen_keyframes = seen[:EVIDENCE_HEAD] + seen[EVIDENCE_HEAD:][-(EVIDENCE_CAP - EVIDENCE_HEAD):]
