"""Duplicates of one large object seen cut by the image border from far-apart places fuse into one MapObject (ours).

Algorithm 1 associates a candidate with a mapped object when their centroids lie within `ltda_threshold_m`. A
view cut by the image border sees only part of an object, so its centroid lies somewhere inside the object, and
for large furniture (a couch 2 m long) two cut views from far-apart places can have centroids more than the reach
apart: each makes a MapObject of its own. Their 3D boxes overlap all the same, because both lie inside the
object. After each keyframe, two same-class objects fuse when

1. one of them at least is known only from cut views (`MapObject.n_observations` 0): two objects seen whole have
   unbiased centroids, and the fixed reach decides between them (a moved object stays a new object at its new
   place, and the change report sees the move);
2. neither is lost (belief >= `semantic_min_belief`): a lost object's place is the evidence of a removal or a move;
3. the intersection of their boxes (`MapObject.box_center_w`, `box_size_m`) holds at least `fuse_min_overlap` of
   the smaller box's volume: two chairs side by side have touching boxes that share a sliver, one object's parts
   share most of the smaller part;
4. no keyframe gave points to both (their first keyframe, their whole views, the candidates of this keyframe):
   two boxes of one class in one image are two objects.

The object with whole views survives, or of two objects known only from cut views the older one (earlier first
keyframe, then lower id). An object known only from cut views carries no belief evidence (cut views update no
belief, and a miss would have made it lost) and no sighting: the survivor keeps its own belief, belief history
and last sighting (`last_seen_keyframe`, which times the next long-term update). What the
absorbed object's points become follows the cut-view rules of `long_term_association`: into the survivor's point
set when the survivor is known only from cut views too (`cut_only_views_join`), else labelled with the survivor
only (its map points take the survivor's id and active flag, and stay out of its centroid and box).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from changing_slam_ros.core.objects.map_object import EVIDENCE_CAP, EVIDENCE_HEAD, MapObject, ObjectMapConfig


def box_overlap_fraction(a: MapObject, b: MapObject) -> float:
    """Volume of the intersection of the two objects' world-axis boxes over the smaller box's volume, in [0, 1];
    0 when either box is flat (zero volume)."""
    lo = np.maximum(a.box_center_w - 0.5 * a.box_size_m, b.box_center_w - 0.5 * b.box_size_m)
    hi = np.minimum(a.box_center_w + 0.5 * a.box_size_m, b.box_center_w + 0.5 * b.box_size_m)
    smaller = min(float(np.prod(a.box_size_m)), float(np.prod(b.box_size_m)))
    if not smaller > 0.0:
        return 0.0
    return min(1.0, float(np.prod(np.clip(hi - lo, 0.0, None))) / smaller)


def _keyframes(obj: MapObject) -> set[int]:
    return {obj.first_keyframe, *obj.seen_keyframes}


def may_fuse(a: MapObject, b: MapObject, config: ObjectMapConfig, this_keyframe: Iterable[int] = ()) -> bool:
    """Rules 1-4 of the module docstring for one pair; `this_keyframe`: ids of the objects that took a candidate
    in the current keyframe."""
    if a.id == b.id or a.class_id != b.class_id or min(a.n_observations, b.n_observations) > 0:
        return False
    if min(a.n_points, b.n_points) < config.min_points or min(a.belief, b.belief) < config.semantic_min_belief:
        return False
    took = set(this_keyframe)
    if (a.id in took and b.id in took) or _keyframes(a) & _keyframes(b):
        return False
    return box_overlap_fraction(a, b) >= config.fuse_min_overlap


def survivor_of(a: MapObject, b: MapObject) -> tuple[MapObject, MapObject]:
    """(survivor, absorbed): the object with whole views, else the older one."""
    if (a.n_observations > 0) != (b.n_observations > 0):
        return (a, b) if a.n_observations > 0 else (b, a)
    return (a, b) if (a.first_keyframe, a.id) <= (b.first_keyframe, b.id) else (b, a)


def absorb(survivor: MapObject, absorbed: MapObject, join_points: bool) -> None:
    """Fold `absorbed` into `survivor` (see the module docstring); `join_points`: the absorbed points enter the
    survivor's point set, with its viewing directions (both known only from cut views, `cut_only_views_join`)."""
    if join_points:
        survivor.add_points(absorbed.point_ids, absorbed.points_w)
        survivor.view_sum_w = survivor.view_sum_w + absorbed.view_sum_w
        survivor.up_sum_w = survivor.up_sum_w + absorbed.up_sum_w
        survivor.n_views += absorbed.n_views
    if (absorbed.first_keyframe, absorbed.id) < (survivor.first_keyframe, survivor.id):
        survivor.first_keyframe, survivor.first_box_xyxy = absorbed.first_keyframe, absorbed.first_box_xyxy
    survivor.n_observations += absorbed.n_observations
    seen = sorted(set(survivor.seen_keyframes) | set(absorbed.seen_keyframes))
    survivor.seen_keyframes = seen[:EVIDENCE_HEAD] + seen[EVIDENCE_HEAD:][-(EVIDENCE_CAP - EVIDENCE_HEAD):]


def fuse_duplicates(objects: dict[int, MapObject], config: ObjectMapConfig,
                    this_keyframe: Iterable[int] = ()) -> dict[int, int]:
    """Fuse every pair that `may_fuse`, the largest overlap first, until none is left; absorbed objects leave
    `objects`. Returns absorbed id -> survivor id (chains resolved to the final survivor); empty with
    `fuse_cut_duplicates` off."""
    fused: dict[int, int] = {}
    if not config.fuse_cut_duplicates:
        return fused
    took = set(this_keyframe)
    while True:
        pool = sorted(objects.values(), key=lambda o: o.id)
        pairs = [(box_overlap_fraction(a, b), a.id, b.id) for i, a in enumerate(pool) for b in pool[i + 1:]
                 if may_fuse(a, b, config, took)]
        if not pairs:
            break
        _, ia, ib = max(pairs, key=lambda p: (p[0], -p[1], -p[2]))
        keep, gone = survivor_of(objects[ia], objects[ib])
        absorb(keep, gone, join_points=keep.n_observations == 0 and config.cut_only_views_join)
        del objects[gone.id]
        if gone.id in took:
            took.add(keep.id)
        fused[gone.id] = keep.id
        for k, v in fused.items():
            if v == gone.id:
                fused[k] = keep.id
    return fused
