"""The active flags of map points that belong to MapObjects (Changing-SLAM §4.7, and where we go beyond it).

A map point of an object is usable by tracking, local BA, map fusion and place recognition only while its
flag is set (`PointStore.usable()`); the flag follows its object's belief. Three rules settle a keyframe's
flags after long-term association (`object_layer.ObjectLayer.after_keyframe` runs them in this order):

- `settle_shared`: a point held by two objects follows the one it was last associated with;
- `flip_labelled`: every point labelled with an object whose state changed takes the new flag;
- `keep_enough_active`: a keyframe keeps a floor of usable points, however much of it new objects cover.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np

from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.map.map_point import PointStore
from changing_slam_ros.core.objects.long_term_association import AssociationResult
from changing_slam_ros.core.objects.map_object import MapObject


def settle_shared(objects: Mapping[int, MapObject], pts: PointStore, res: AssociationResult) -> None:
    """A map point seen inside the boxes of two objects (a wall point behind both places of a moved chair)
    belongs to both; its flag follows the object it was last associated with (`PointStore.object_id`),
    not whichever object changed state last."""
    ids = np.concatenate([res.activated_point_ids, res.deactivated_point_ids])
    ids = ids[(ids >= 0) & (ids < pts.size)]
    if len(ids) == 0:
        return
    owner = pts.object_id[ids]
    known = np.array([int(o) in objects for o in owner.tolist()], bool)
    pts.active[ids[known]] = [objects[int(o)].active for o in owner[known].tolist()]


def flip_labelled(objects: Mapping[int, MapObject], pts: PointStore, was_active: dict[int, bool],
                  survivors: Iterable[int] = ()) -> None:
    """Every live map point labelled with an object that changed state, or that absorbed a duplicate
    (`survivors`), takes its flag, also the points of its cut views that are not in its point set
    (`long_term_association`: truncated candidates)."""
    keep = set(survivors)
    flipped = [oid for oid, obj in objects.items()
               if (oid in was_active and was_active[oid] != obj.active) or oid in keep]
    if not flipped:
        return
    n = pts.size
    for oid in flipped:
        sel = np.flatnonzero((pts.object_id[:n] == oid) & ~pts.bad[:n])
        pts.active[sel] = objects[oid].active


def keep_enough_active(objects: Mapping[int, MapObject], kf: Keyframe, pts: PointStore, floor: int) -> int:
    """Hold `floor` usable map points in `kf` (0 = no floor): while it has fewer, the inactive points of its
    undecided objects (belief >= 0.5: nothing says they moved), largest object first, are made active again.
    Objects with evidence of a change (belief below 0.5) stay inactive. Returns how many points were freed."""
    ids = kf.point_ids[(kf.point_ids >= 0) & (kf.point_ids < pts.size)]
    if floor <= 0 or len(ids) == 0:
        return 0
    ids = ids[~pts.bad[ids]]
    short = floor - int(pts.active[ids].sum())
    if short <= 0:
        return 0
    idle = ids[~pts.active[ids]]
    owner = pts.object_id[idle]
    held, counts = np.unique(owner[owner >= 0], return_counts=True)
    freed = 0
    for oid, count in sorted(zip(held.tolist(), counts.tolist()), key=lambda oc: -oc[1]):
        if oid not in objects or objects[oid].belief < 0.5:
            continue
        pts.active[idle[owner == oid]] = True
        freed += count
        if freed >= short:
            break
    return freed
