"""Long-term data association (Changing-SLAM §4.7, Algorithm 1) and the object map it maintains.

At each new keyframe the object candidates of that keyframe (map points created or matched inside one
detection box, with the box's class) are merged into the nearest same-class mapped object, create new
objects (belief 0.5, inactive), or update the beliefs of mapped objects (`persistence_filter.py`); the
vicinity search then lowers the belief of objects that should have been seen and were not
(`object_visibility.py`). The steps, with the paper's line numbers, are in
`LongTermAssociation.process_keyframe`. The result lists the point ids whose active flag the map must
set, the new and merged objects and every belief change with its reason.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.map.map_point import PointStore
from changing_slam_ros.core.map.floor_plane import FloorEstimate
from changing_slam_ros.core.objects.floor_check import is_floor_patch
from changing_slam_ros.core.objects.map_object import BoxXyxy, MapObject, ObjectMapConfig
from changing_slam_ros.core.objects.object_fusion import fuse_duplicates
from changing_slam_ros.core.objects.object_point_weights import Plane, point_weights
from changing_slam_ros.core.objects.object_visibility import Visibility, check_visibility
from changing_slam_ros.core.objects.persistence_filter import BeliefUpdate, likelihood_seen, update_missed, update_seen
from changing_slam_ros.core.objects.picture_check import is_picture

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

# positions_of(point_ids (N,)) -> (positions_w (N, 3), usable (N,) bool: False for culled / bad points)
PointLookup = Callable[[I64], tuple[F64, npt.NDArray[np.bool_]]]


@dataclass(frozen=True)
class ObjectCandidate:
    """Map points (ids (N,), world positions (N, 3)) from one detection box of one keyframe.

    `truncated`: the box touches the image border; its centroid is biased toward the visible part, so it
    neither updates a mapped object's belief nor counts as a sighting of it, nor joins its point set (the
    centroid and 3D box), unless the object is itself known only from cut views (`cut_only_views_join`). Its points still belong to an object (§4.2: every map point created in a box takes the
    box's MapObject, and follows its active flag): they are labelled with the nearest mapped object of its
    class within `ltda_threshold_m` and take its flag, or make a new object (with `truncated_views`; off, cut
    views are skipped as before).
    Its box also explains away a miss (see below).
    """

    class_id: int
    box_xyxy: BoxXyxy
    point_ids: I64
    points_w: F64
    truncated: bool = False

    @property
    def centroid_w(self) -> F64:
        centroid: F64 = np.asarray(self.points_w, float).reshape(-1, 3).mean(axis=0)
        return centroid


def box_truncated(box_xyxy: BoxXyxy, camera: CameraIntrinsics, border_px: float = 1.0) -> bool:
    """True when a box (x_min, y_min, x_max exclusive, y_max exclusive) touches the image border."""
    x0, y0, x1, y1 = box_xyxy
    return x0 < border_px or y0 < border_px or x1 > camera.width - border_px or y1 > camera.height - border_px


def candidates_from_keyframe(kf: Keyframe, points_w_of: Callable[[I64], F64],
                             boxes: Mapping[int, tuple[int, BoxXyxy, bool]]) -> list[ObjectCandidate]:
    """One candidate per short-term object id in `kf.object_ids` that has map points.

    `boxes`: short-term object id -> (COCO class, box in this keyframe, truncated); ids not in it are
    skipped. `points_w_of(point ids (M,)) -> positions (M, 3)` reads the map. Candidates come out in
    increasing short-term id, so `AssociationResult.assignments` lines up with `sorted(boxes)` filtered
    to the ids that have points.
    """
    out = []
    for sid in sorted(boxes):
        sel = (kf.object_ids == sid) & (kf.point_ids >= 0)
        if not sel.any():
            continue
        ids = np.unique(kf.point_ids[sel])
        class_id, box, truncated = boxes[sid]
        out.append(ObjectCandidate(class_id, box, ids, np.asarray(points_w_of(ids), float), truncated))
    return out


@dataclass(frozen=True)
class BeliefChange:
    """A persistence-filter step applied to `object_id`: reason "seen" or "missed"."""

    object_id: int
    reason: str
    update: BeliefUpdate


@dataclass(frozen=True)
class AssociationResult:
    """What one keyframe changed. `assignments[i]` is the map object id candidate i went to (new or
    merged; for a truncated candidate: the object its points are labelled with), -1 if it was skipped (truncated
    with `truncated_views` off, fewer than `min_points` points, a picture or a floor patch: its index is then in
    `pictures` or `floor_patches`).
    `visibility`: the verdict of the vicinity search for every mapped object that no candidate matched.
    `fused`: objects that left the map as duplicates of another (`object_fusion`), absorbed id -> survivor id;
    the assignments, new and merged ids already name the survivor."""

    keyframe_id: int
    assignments: tuple[int, ...]
    new_object_ids: tuple[int, ...]
    merged_object_ids: tuple[int, ...]
    belief_changes: tuple[BeliefChange, ...]
    activated_point_ids: I64 = field(default_factory=lambda: np.zeros(0, np.int64))
    deactivated_point_ids: I64 = field(default_factory=lambda: np.zeros(0, np.int64))
    visibility: dict[int, Visibility] = field(default_factory=dict)
    pictures: tuple[int, ...] = ()
    floor_patches: tuple[int, ...] = ()
    fused: dict[int, int] = field(default_factory=dict)


class LongTermAssociation:
    """Owns the MapObjects of one map and runs Algorithm 1 on each keyframe's candidates.

    Two rules of ours for a changed room: a candidate of a 3-D class whose points lie in a wall of the room's
    planes is a picture and skipped (`picture_check.py`); and a lost object (belief below `semantic_min_belief`)
    takes no candidate that its position model says is elsewhere (`relocated`): that is the class seen at a new
    place, a new object. Each object keeps its belief steps and sighting keyframes (`MapObject`)."""

    def __init__(self, config: ObjectMapConfig, first_object_id: int = 0) -> None:
        self.config = config
        self.objects: dict[int, MapObject] = {}
        self._next_id = first_object_id

    # --- bookkeeping ---
    def add_object(self, obj: MapObject) -> None:
        """Insert an existing object (a loaded map, an Atlas merge); later ids continue after it."""
        self.objects[obj.id] = obj
        self._next_id = max(self._next_id, obj.id + 1)

    @property
    def next_id(self) -> int:
        """The id the next new object gets."""
        return self._next_id

    def new_session(self, first_keyframe_id: int) -> None:
        """Start a session on a loaded map (multi-session): keyframe ids may restart, and time has passed, so
        every object counts as unseen for more than N keyframes; its first sighting or expected miss in the
        new session updates its belief. Each object's belief history gets a "session" step at `first_keyframe_id`."""
        stale = first_keyframe_id - self.config.n_keyframes_unseen - 1
        for obj in self.objects.values():
            obj.last_seen_keyframe = stale
            obj.last_belief_update_keyframe = stale
            obj.record_belief(first_keyframe_id, "session")

    def refresh_points(self, positions_of: PointLookup) -> None:
        """Re-read every object's point positions from the map (after local BA / loop correction) and drop
        culled points; the centroids and boxes follow."""
        for obj in self.objects.values():
            if obj.n_points:
                pos, usable = positions_of(obj.point_ids)
                obj.refresh_points(pos, np.asarray(usable, bool))

    def object_of_point(self) -> dict[int, int]:
        """Map point id -> object id, for labelling map points."""
        return {int(p): oid for oid, obj in self.objects.items() for p in obj.point_ids}

    # --- Algorithm 1 ---
    def process_keyframe(self, keyframe_id: int, candidates: Sequence[ObjectCandidate], T_world_cam: F64,
                         camera: CameraIntrinsics, depth_m: npt.NDArray[np.floating] | None,
                         detected_boxes: Sequence[tuple[int, BoxXyxy]] = (),
                         up_w: F64 | None = None, planes: Sequence[Plane] = (),
                         walls_up_w: F64 | None = None, floor: FloorEstimate | None = None,
                         structure: Sequence[Plane] = ()) -> AssociationResult:
        """Associate this keyframe's candidates, update beliefs, run the vicinity search.

        T_world_cam (4, 4) optical-frame pose of the keyframe; depth_m (H, W) its depth image in metres
        (0 = invalid) for the occlusion test, or None to skip that test. `detected_boxes`: (class, box) of
        the keyframe's detections that are no candidate; they only explain misses away (step 5 below).
        `up_w` (3,): the map's up direction, recorded with each whole view (`MapObject.add_view`; box completion),
        `planes`: the room's large planes (map frame) for the picture check, whose walls are told from floors by
        `walls_up_w` (3,) (default `up_w`; the layer passes the camera's up when the floor is unknown). `floor`: the
        floor plane (map frame) for the floor-patch check (`floor_check.py`), None to skip it. `structure`: the
        planes whose points a candidate's centroid leaves out, as the mapped objects' centroids do
        (`object_point_weights.point_weights`: the room's large planes and the floor).

        Steps (Algorithm 1 line numbers):

        1. the candidate's centroid is the mean of its points (line 2), weighted as the mapped objects' centroids
           are (`object_point_weights`: the points on the `structure` planes left out, every occupied voxel
           counted once; with those rules off, the plain mean);
        2. among mapped objects of the same class (line 4) the nearest centroid is taken; closer than
           `ltda_threshold_m` (line 6) the candidate is merged into it, points combined (line 7);
           the paper loops over every mapped object and could merge one candidate into several; we merge into
           the nearest only, so two neighbouring objects of one class (two cups on a desk) stay apart;
        3. if the mapped object was not seen in the last N keyframes (`kf - last_seen > n_keyframes_unseen`,
           line 8), its belief is updated with the "seen" likelihood (line 9) and its points switch active /
           inactive with `belief_threshold` (lines 11-15); otherwise only the keyframe where it was last seen is
           updated (line 17): objects seen continuously are not re-updated;
        4. otherwise a new MapObject is created with belief 0.5 (lines 20-21), hence inactive by default;
        5. vicinity search (§4.7, last paragraph): every mapped object that no candidate matched, that should
           have been visible from this keyframe and that was neither seen nor belief-updated in the last N
           keyframes gets the "missed" update (belief down). The same N keeps a detector miss during continuous
           viewing from counting, and spaces repeated misses N keyframes apart. An object whose projected
           centroid lies inside the box of a same-class candidate of this keyframe (any candidate, also truncated
           or too small ones) is not missed: the detector did see an object of its class there, even if the
           candidate's 3D centroid (a partial view of a large table) did not associate. The same holds for the
           same-class `detected_boxes` (the dynamic stage flagged them dynamic in this keyframe, which happens
           for a frame or two while the robot turns fast).

        6. duplicates (ours, `object_fusion.py`): two same-class objects, one at least known only from cut views,
           whose 3D boxes overlap by `fuse_min_overlap` of the smaller one are one large object seen cut from
           far-apart places, and fuse.

        Objects created in this keyframe are not candidates for merging within the same keyframe, so two
        same-class detections of one image never fuse.
        """
        cfg = self.config
        before = {oid: (obj.active, obj.n_points) for oid, obj in self.objects.items()}
        existing = list(self.objects.values())
        assignments: list[int] = []
        new_ids: list[int] = []
        merged_ids: list[int] = []
        changes: list[BeliefChange] = []
        seen: set[int] = set()
        attached: list[int] = []
        attached_on: list[I64] = []
        attached_off: list[I64] = []
        pictures: list[int] = []
        floor_patches: list[int] = []
        for index, cand in enumerate(candidates):
            pts = np.asarray(cand.points_w, float).reshape(-1, 3)
            if len(pts) < cfg.min_points:
                assignments.append(-1)
                continue
            if is_picture(cand.class_id, pts, planes, up_w if walls_up_w is None else walls_up_w, cfg):
                pictures.append(index)
                assignments.append(-1)
                continue
            if is_floor_patch(cand.class_id, pts, floor, cfg):
                floor_patches.append(index)
                assignments.append(-1)
                continue
            w = point_weights(pts, structure, None, cfg)
            centroid = (w @ pts) / w.sum()  # line 2
            target = self._nearest_same_class(existing, cand.class_id, centroid)  # lines 3-6
            if cand.truncated and not cfg.truncated_views:
                assignments.append(-1)
                continue
            if cand.truncated and target is not None and target.n_observations == 0 and cfg.cut_only_views_join:
                # an object known only from cut views has nothing better: its cut views join its point set
                # (`_point_flag_changes` gives the joiners its flag), still without a belief update or a sighting
                # (`last_seen_keyframe`); seen in this keyframe all the same, so the vicinity search does not miss it
                target.add_points(np.asarray(cand.point_ids, np.int64), pts)
                target.current_box_xyxy = cand.box_xyxy
                target.add_view(T_world_cam[:3, 3], centroid, up_w)
                seen.add(target.id)
                assignments.append(target.id)
                continue
            if cand.truncated and target is not None:
                # a cut view's points are labelled with the mapped object and take its active flag (the map
                # points then follow it: `ObjectLayer` flips every point labelled with an object that changes
                # state), but they stay out of its point set: their centroid is biased toward the visible part,
                # so they neither move the object's centroid nor update its belief nor count as a sighting
                attached.append(target.id)
                (attached_on if target.active else attached_off).append(np.asarray(cand.point_ids, np.int64))
                assignments.append(target.id)
                continue
            if target is None:  # lines 19-21
                obj = MapObject(self._next_id, cand.class_id, cand.box_xyxy, cand.box_xyxy, keyframe_id,
                                keyframe_id, belief=0.5, active=0.5 >= cfg.belief_threshold,
                                point_ids=np.asarray(cand.point_ids, np.int64), points_w=pts,
                                n_observations=0 if cand.truncated else 1)
                obj.add_view(T_world_cam[:3, 3], centroid, up_w)  # a cut view's direction is still where it was seen from
                obj.last_belief_update_keyframe = keyframe_id
                obj.record_belief(keyframe_id, "new")
                if not cand.truncated:
                    obj.record_sighting(keyframe_id)
                self.objects[obj.id] = obj
                self._next_id += 1
                new_ids.append(obj.id)
                assignments.append(obj.id)
                seen.add(obj.id)
                continue
            # an object known only from cut views (n_observations 0) is first seen whole now: that is its first
            # sighting, not a long-term re-observation (a glimpse at the image edge is no earlier visit)
            if (keyframe_id - target.last_seen_keyframe > cfg.n_keyframes_unseen and target.id not in seen
                    and target.n_observations > 0):
                upd = update_seen(target.belief, centroid, target.centroid_w, target.n_points, cfg,
                                  float(np.max(target.box_size_m)))  # line 9
                target.belief = upd.posterior
                target.last_belief_update_keyframe = keyframe_id
                target.active = target.belief >= cfg.belief_threshold  # lines 11-15
                target.record_belief(keyframe_id, "seen")
                changes.append(BeliefChange(target.id, "seen", upd))
            target.add_points(np.asarray(cand.point_ids, np.int64), pts)  # line 7
            target.current_box_xyxy = cand.box_xyxy
            target.last_seen_keyframe = keyframe_id  # lines 10 and 17
            target.n_observations += 1
            target.record_sighting(keyframe_id)
            target.add_view(T_world_cam[:3, 3], centroid, up_w)
            if target.id not in merged_ids:
                merged_ids.append(target.id)
            seen.add(target.id)
            assignments.append(target.id)
        boxes = [(c.class_id, c.box_xyxy) for c in candidates] + [(int(k), b) for k, b in detected_boxes]
        visibility = self._vicinity_search(keyframe_id, existing, seen, boxes, T_world_cam, camera, depth_m, changes)
        held = {oid: obj.point_ids for oid, obj in self.objects.items()}
        fused = fuse_duplicates(self.objects, cfg, [a for a in assignments if a >= 0])
        if fused:  # the survivor's id everywhere; the absorbed points take its flag
            assignments = [fused.get(a, a) for a in assignments]
            new_ids = [i for i in new_ids if i not in fused]
            merged_ids = list(dict.fromkeys(fused.get(i, i) for i in merged_ids))
            for gone_id, keep_id in fused.items():
                (attached_on if self.objects[keep_id].active else attached_off).append(held[gone_id])
            gone = set(fused)
            changes = [c for c in changes if c.object_id not in gone]
            visibility = {k: v for k, v in visibility.items() if k not in gone}
        activated, deactivated = self._point_flag_changes(before)
        if attached_on:
            activated = np.unique(np.concatenate([activated, *attached_on]))
        if attached_off:
            deactivated = np.unique(np.concatenate([deactivated, *attached_off]))
        return AssociationResult(keyframe_id, tuple(assignments), tuple(new_ids), tuple(merged_ids), tuple(changes),
                                 activated, deactivated, visibility, tuple(pictures),
                                 tuple(floor_patches), fused)

    def _nearest_same_class(self, pool: list[MapObject], class_id: int, centroid_w: F64) -> MapObject | None:
        """The nearest mapped object of the class within `ltda_threshold_m` (lines 3-6) that may take a candidate
        at `centroid_w`: a lost object only where its position model expects it (`relocated`)."""
        best, best_d = None, self.config.ltda_threshold_m
        for obj in pool:
            if obj.class_id != class_id or obj.n_points < self.config.min_points:
                continue
            d = float(np.linalg.norm(obj.centroid_w - centroid_w))  # line 5
            if d < best_d and not self.relocated(obj, centroid_w):
                best, best_d = obj, d
        return best

    def relocated(self, obj: MapObject, centroid_w: F64) -> bool:
        """True when `obj` is lost (belief below `semantic_min_belief`) and a candidate centroid at `centroid_w`
        (3,) is less likely under its position model than a same-class object elsewhere (the "seen" likelihood
        ratio below 1): the class seen at a new place. Always False with `relocation` off."""
        cfg = self.config
        if not cfg.relocation or obj.belief >= cfg.semantic_min_belief:
            return False
        l1, l0 = likelihood_seen(centroid_w, obj.centroid_w, obj.n_points, cfg, float(np.max(obj.box_size_m)))
        return l1 < l0

    def _vicinity_search(self, keyframe_id: int, pool: list[MapObject], seen: set[int],
                         boxes: Sequence[tuple[int, BoxXyxy]], T_world_cam: F64, camera: CameraIntrinsics,
                         depth_m: npt.NDArray[np.floating] | None,
                         changes: list[BeliefChange]) -> dict[int, Visibility]:
        cfg = self.config
        out: dict[int, Visibility] = {}
        for obj in pool:
            if obj.id in seen or obj.n_points < cfg.min_points:
                continue
            check = check_visibility(obj.centroid_w, T_world_cam, camera, depth_m, cfg,
                                     box_size_m=obj.box_size_m)
            out[obj.id] = check.visibility
            if not check.expected:
                continue
            last = max(obj.last_seen_keyframe, obj.last_belief_update_keyframe)
            if keyframe_id - last <= cfg.n_keyframes_unseen:
                continue
            u, v = check.pixel_uv
            if any(k == obj.class_id and b[0] <= u <= b[2] and b[1] <= v <= b[3] for k, b in boxes):
                continue  # a same-class detection covers it: not missing
            upd = update_missed(obj.belief, cfg)
            obj.belief = upd.posterior
            obj.last_belief_update_keyframe = keyframe_id
            obj.active = obj.belief >= cfg.belief_threshold
            obj.record_belief(keyframe_id, "missed")
            changes.append(BeliefChange(obj.id, "missed", upd))
        return out

    def _point_flag_changes(self, before: dict[int, tuple[bool, int]]) -> tuple[I64, I64]:
        """Point ids whose flag must be set: all points of objects whose state flipped, plus the points
        that joined an object (set to the object's state). `before`: object id -> (active, number of points)
        at the start of the keyframe; `MapObject.add_points` appends, so the joiners are the tail."""
        on: list[I64] = []
        off: list[I64] = []
        for oid, obj in self.objects.items():
            if oid not in before or before[oid][0] != obj.active:
                changed = obj.point_ids
            else:
                changed = obj.point_ids[before[oid][1]:]
            (on if obj.active else off).append(changed)
        return (np.unique(np.concatenate(on)) if on else np.zeros(0, np.int64),
                np.unique(np.concatenate(off)) if off else np.zeros(0, np.int64))


# --- glue to the metric map (core.map_point.PointStore) ---

def point_lookup(points: PointStore) -> PointLookup:
    """`positions_of` for `LongTermAssociation.refresh_points` reading a PointStore (bad points dropped)."""

    def positions_of(ids: I64) -> tuple[F64, npt.NDArray[np.bool_]]:
        ids = np.asarray(ids, np.int64)
        known = (ids >= 0) & (ids < points.size)
        safe = np.where(known, ids, 0)
        pos: F64 = points.positions[safe].copy()
        usable = known & ~points.bad[safe]
        return pos, usable

    return positions_of


def apply_to_point_store(points: PointStore, candidates: Sequence[ObjectCandidate], result: AssociationResult) -> None:
    """Write one keyframe's outcome into the map points: each associated candidate's points get the map
    object's id and class (§4.2), the points of a fused duplicate its survivor's id, and the active flags follow
    the objects' beliefs (§4.7)."""
    for gone_id, keep_id in result.fused.items():  # duplicates fused (`object_fusion`): their points are the survivor's
        points.object_id[np.flatnonzero(points.object_id[:points.size] == gone_id)] = keep_id
    for cand, oid in zip(candidates, result.assignments):
        if oid < 0:
            continue
        ids = np.asarray(cand.point_ids, np.int64)
        ids = ids[(ids >= 0) & (ids < points.size)]
        points.object_id[ids] = oid
        points.class_id[ids] = cand.class_id
    for ids, flag in ((result.activated_point_ids, True), (result.deactivated_point_ids, False)):
        ids = ids[(ids >= 0) & (ids < points.size)]
        points.active[ids] = flag
