"""The object layer of the SLAM system (Changing-SLAM §4.2, §4.6-4.8): MapObjects, beliefs and active points.

`ObjectLayer` wraps one `LongTermAssociation` per map of the Atlas. `SlamSystem` calls
`after_keyframe(kf, slam_map, depth_m, short_term_objects)` once per new keyframe, after local mapping
and before loop closing, so that loop closing already sees the points this keyframe deactivated. It builds
the keyframe's candidates from the dynamic stage's static objects (map points and depth samples in their
boxes), runs Algorithm 1 and sets the map points' object ids and active flags; tracking, local BA, map
fusion and place recognition skip inactive points. Object points outlive metric culling (anchored in
keyframes, see `ObjectLayer`).

`enabled=False` (YAML `objects: {enabled: false}`, CLI `--no-objects`) turns the layer into a no-op:
every map point stays active, as in the plain engine; this is the "what the layer prevents" baseline.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.dynamic.dynamic_objects import ObjectState
from changing_slam_ros.core.map.floor_plane import FloorEstimate
from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.objects.long_term_association import (
    AssociationResult, LongTermAssociation, ObjectCandidate, apply_to_point_store, box_truncated,
)
from changing_slam_ros.core.map.map_point import PointStore
from changing_slam_ros.core.objects.box_depth import (  # noqa: F401 - re-exported: the layer's depth band
    MIN_DEPTH_BAND_M, DepthBand, box_depth_band, box_depth_samples,
)
from changing_slam_ros.core.objects.map_object import MapObject, ObjectMapConfig, object_map_config
from changing_slam_ros.core.objects.object_box_completion import gravity_up
from changing_slam_ros.core.objects.object_map_merge import join, moved_object, remap_point_ids, same_object
from changing_slam_ros.core.objects.object_point_weights import Plane, fit_structure_planes, reweight_objects
from changing_slam_ros.core.objects.floor_check import floor_as_plane, is_floor_patch, scans_floor
from changing_slam_ros.core.objects.picture_check import is_picture, plane_extent_m
from changing_slam_ros.core.objects.point_flags import flip_labelled, keep_enough_active, settle_shared
from changing_slam_ros.core.geometry.se3 import invert
from changing_slam_ros.core.objects.semantic_map import SemanticMap, build_semantic_map
from changing_slam_ros.core.map.slam_map import SlamMap
from changing_slam_ros.errors import ConfigError

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
U8 = npt.NDArray[np.uint8]
MAX_PLACES = 200  # candidates' places kept for `wants_keyframe` (the newest)


@dataclass(frozen=True)
class ObjectLayerConfig:
    """YAML section `objects:`: the layer's own keys plus every `ObjectMapConfig` field.

    - `enabled`: the layer's switch (off = every map point stays active).
    - `depth_samples`: depth pixels sampled per candidate box (on a regular grid); 0 = map points only.
    - `depth_band_m`: samples farther than this from the box's median depth are background and left out
      (smaller boxes use a narrower band, see `box_depth_samples`).
    - `depth_band_near_quantile`: the band's near end reaches at least this quantile of the box's depths (0: the
      band stays centred on the median): the nearest depths in a whole box are its object's, and a chair seen at
      a slant, its frame seen through, has its median depth at its far part (`box_depth_band`).
    - `band_map_points`: apply the same band to the map points of the box's keypoints (camera-frame depth).
    - `cut_min_side_m`: a box cut by the image border gives depth samples (`cut_only_views_join`) only when its
      smaller side spans at least this many metres at its median depth: a sliver at the image edge is mostly
      what lies behind the object (shift: a 2-pixel-wide chair box, 1.5 cm at 2 m, gave 25 samples of the
      wall and a spurious chair 1 m from the real one). Whole boxes are not concerned (a cup is small).
    - `new_object_keyframes`: a whole detection (not cut by the border, at least the visibility's minimum box
      area) of a non-dynamic object that nothing the layer knows explains (no mapped object and no earlier
      candidate of its class projects inside its box) asks tracking for a keyframe (`wants_keyframe`): the layer
      runs on keyframes only, so an object seen for less than a keyframe interval, or seen whole only between
      two keyframes, never becomes a candidate. Off by default: the split node graph's tracking keeps no object
      map, so with it on the lossless graph would take other keyframes than the offline run.
    - `session_belief_decay`: a map loaded for a new session (multi-session) pulls every object's belief this
      fraction of the way back to 0.5 (0 = keep, 1 = forget): time has passed and the room may have changed, so
      what the last session saw counts less than what this one sees (a one-step stand-in for a survival-time
      prior). An object that falls below `belief_threshold` starts the session inactive.
    - `min_active_points`: a keyframe keeps at least this many usable map points. The points of a new object
      start inactive (§4.7) until its belief passes `belief_threshold`; where that would leave the keyframe with
      fewer, the points of its undecided objects (belief not below 0.5: nothing says they moved) stay active,
      largest objects first, so tracking is never left without a map: a detector that names most of the view
      one object (a wall photo taken for a "clock" box over 90 % of the image) made the first keyframe keep 50
      of its 793 points, and the next 29 frames were lost. Objects with evidence of a change stay inactive.
      The same floor as the dynamic filter's `min_kept_keypoints`, for the same reason; 0 = the paper's rule.
    """

    enabled: bool = True
    depth_samples: int = 100
    depth_band_m: float = 0.35
    depth_band_near_quantile: float = 0.05
    band_map_points: bool = True
    session_belief_decay: float = 0.5
    cut_min_side_m: float = 0.1
    new_object_keyframes: bool = False
    min_active_points: int = 300
    association: ObjectMapConfig = field(default_factory=ObjectMapConfig)

    def __post_init__(self) -> None:
        if self.depth_samples < 0:
            raise ConfigError(f"objects.depth_samples: expected >= 0, got {self.depth_samples}")
        if self.depth_band_m <= 0.0:
            raise ConfigError(f"objects.depth_band_m: expected > 0, got {self.depth_band_m}")
        if not 0.0 <= self.depth_band_near_quantile < 0.5:
            raise ConfigError(f"objects.depth_band_near_quantile: expected within [0, 0.5), got "
                              f"{self.depth_band_near_quantile}")
        if self.cut_min_side_m < 0.0:
            raise ConfigError(f"objects.cut_min_side_m: expected >= 0, got {self.cut_min_side_m}")
        if not 0.0 <= self.session_belief_decay <= 1.0:
            raise ConfigError(f"objects.session_belief_decay: expected within [0, 1], got {self.session_belief_decay}")
        if self.min_active_points < 0:
            raise ConfigError(f"objects.min_active_points: expected >= 0, got {self.min_active_points}")


_OWN_KEYS = {"enabled": bool, "depth_samples": int, "depth_band_m": float, "depth_band_near_quantile": float,
             "band_map_points": bool, "new_object_keyframes": bool,
             "session_belief_decay": float, "cut_min_side_m": float, "min_active_points": int}


def object_layer_config(data: dict[str, Any] | None, where: str = "objects") -> ObjectLayerConfig:
    """Parse the `objects:` mapping (None = defaults); the layer's keys are read here, the rest by `ObjectMapConfig`."""
    if data is None:
        return ObjectLayerConfig()
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a mapping, got {type(data).__name__}")
    rest = dict(data)
    own: dict[str, Any] = {}
    for key, kind in _OWN_KEYS.items():
        if key not in rest:
            continue
        v = rest.pop(key)
        ok = isinstance(v, bool) if kind is bool else (isinstance(v, (int, float)) and not isinstance(v, bool)
                                                       and (kind is float or isinstance(v, int)))
        if not ok:
            raise ConfigError(f"{where}.{key}: expected {kind.__name__}, got {v!r}")
        own[key] = kind(v)
    return ObjectLayerConfig(**own, association=object_map_config(rest, where))


@dataclass(frozen=True)
class ObjectLayerResult:
    """What one keyframe did to the object map of its map: `association` (None when the layer is off),
    `candidates` (the keyframe's object candidates, in association order), map points whose active flag was
    set (`n_activated`, `n_deactivated`) and the milliseconds spent."""

    map_id: int
    association: AssociationResult | None
    candidates: tuple[ObjectCandidate, ...]
    n_activated: int
    n_deactivated: int
    ms: float

    @property
    def active_flags_changed(self) -> bool:
        return self.n_activated + self.n_deactivated > 0


class _Anchors:
    """Object points anchored in keyframes: point id -> (keyframe id, position (3,) in that camera's frame)."""

    def __init__(self) -> None:
        self._ids: list[I64] = []
        self._kfs: list[I64] = []
        self._pts: list[F64] = []
        self._cache: tuple[I64, I64, F64] | None = None

    def add(self, kf_id: int, ids: I64, points_cam: F64) -> None:
        self._ids.append(np.asarray(ids, np.int64))
        self._kfs.append(np.full(len(ids), kf_id, np.int64))
        self._pts.append(np.asarray(points_cam, float).reshape(-1, 3))
        self._cache = None

    def arrays(self) -> tuple[I64, I64, F64]:
        """(ids (M,) sorted, keyframe ids (M,), camera-frame positions (M, 3)); the first anchor of an id wins."""
        if self._cache is None:
            if not self._ids:
                self._cache = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)))
            else:
                ids, kfs, pts = np.concatenate(self._ids), np.concatenate(self._kfs), np.vstack(self._pts)
                uniq, first = np.unique(ids, return_index=True)
                self._cache = (uniq, kfs[first], pts[first])
                self._ids, self._kfs, self._pts = [uniq], [kfs[first]], [pts[first]]
        return self._cache


@dataclass
class _MapObjects:
    """The object map of one SlamMap: the association, the anchors, the next depth-sample id (negative)."""

    lta: LongTermAssociation
    anchors: _Anchors = field(default_factory=_Anchors)
    next_sample_id: int = -2
    planes: list[Plane] = field(default_factory=list)  # the room's large planes (`object_point_weights`)
    room_planes: list[Plane] = field(default_factory=list)  # those spanning a room's size (`picture_check.walls`)
    keyframes_since_planes: int = -1  # keyframes since the planes were fitted (-1: never)
    floor: FloorEstimate | None = None  # the floor in the keyframes' depth scans (`floor_check`), with the planes
    thumbnails: dict[int, U8] = field(default_factory=dict)  # keyframe id -> (72, 96, 3) image its objects name
    places: list[tuple[int, F64]] = field(default_factory=list)  # (class, centroid (3,)) of recent candidates


@dataclass
class SavedObjectMap:
    """The object map of one SlamMap as a saved map holds it (multi-session): the MapObjects with beliefs, the
    anchors of their points (ids (M,), keyframe ids (M,), camera-frame positions (M, 3)) and the next
    depth-sample id (negative), and the thumbnails of the keyframes the objects' evidence names."""

    objects: list[MapObject]
    anchor_ids: I64
    anchor_kf_ids: I64
    anchor_points_cam: F64
    next_sample_id: int = -2
    thumbnails: dict[int, U8] = field(default_factory=dict)  # keyframe id -> thumbnail (`object_evidence`)


class ObjectLayer:
    """MapObjects and persistence beliefs for every map of the Atlas; one instance per run.

    Object points outlive metric culling. Inactive points are never matched again, so ORB-SLAM's recent-point
    culling removes most of them two keyframes after their creation; a MapObject that lost its points would
    fall under `min_points` and could never be associated again. Every object point is therefore anchored in
    the keyframe that first gave it to the object (position in that camera's frame); depth samples, and map
    points once the map culled them, are re-expressed from that keyframe's current pose (culled keyframes
    through their parents, `SlamMap.pose_of`). Live map points are read from the map.
    """

    def __init__(self, config: ObjectLayerConfig | None = None) -> None:
        self.config = config or ObjectLayerConfig()
        self._maps: dict[int, _MapObjects] = {}
        self.keyframe_ms: list[float] = []

    @property
    def enabled(self) -> bool:
        return self.config.enabled

    @property
    def map_ids(self) -> list[int]:
        """Maps that have an object map, ascending."""
        return sorted(self._maps)

    def association(self, map_id: int) -> LongTermAssociation:
        """The object map of `map_id` (created empty on first use)."""
        return self._for(map_id).lta

    def objects(self, map_id: int | None = None) -> list[MapObject]:
        """The MapObjects of one map, or of every map (ordered by map, then id)."""
        ids = sorted(self._maps) if map_id is None else [map_id]
        return [o for m in ids if m in self._maps for _, o in sorted(self._maps[m].lta.objects.items())]

    def planes(self, map_id: int) -> list[Plane]:
        """The room's large planes of one map as last fitted (`object_point_weights`), map frame; [] before."""
        return list(self._maps[map_id].planes) if map_id in self._maps else []

    def _for(self, map_id: int) -> _MapObjects:
        if map_id not in self._maps:
            self._maps[map_id] = _MapObjects(LongTermAssociation(self.config.association))
        return self._maps[map_id]

    # --- saved maps (multi-session) ---
    def saved_objects(self, map_id: int) -> SavedObjectMap:
        """The object map of `map_id` in the form a map file stores."""
        mo = self._for(map_id)
        ids, kfs, pts = mo.anchors.arrays()
        return SavedObjectMap(self.objects(map_id), ids.copy(), kfs.copy(), pts.copy(), mo.next_sample_id,
                              dict(mo.thumbnails))

    def load_objects(self, map_id: int, saved: SavedObjectMap, first_keyframe_id: int,
                     points: PointStore | None = None) -> None:
        """Start `map_id`'s object map from a loaded one; beliefs are pulled toward 0.5 by `session_belief_decay`
        and the active flags of the objects and of their map points in `points` (the loaded map's) follow. The
        new session's keyframes start at `first_keyframe_id`, and every object counts as long unseen
        (`LongTermAssociation.new_session`): its first sighting, or expected miss, updates its belief."""
        mo = _MapObjects(LongTermAssociation(self.config.association), next_sample_id=saved.next_sample_id,
                         thumbnails=dict(saved.thumbnails))
        keep = 1.0 - self.config.session_belief_decay
        for obj in saved.objects:
            obj.belief = 0.5 + (obj.belief - 0.5) * keep
            obj.active = obj.belief >= self.config.association.belief_threshold
            mo.lta.add_object(obj)
            if points is not None:
                ids = obj.point_ids[(obj.point_ids >= 0) & (obj.point_ids < points.size)]
                ids = ids[points.object_id[ids] == obj.id]  # a shared point follows its last object
                points.active[ids] = obj.active
        for kf_id in np.unique(saved.anchor_kf_ids).tolist():
            sel = saved.anchor_kf_ids == kf_id
            mo.anchors.add(int(kf_id), saved.anchor_ids[sel], saved.anchor_points_cam[sel])
        mo.lta.new_session(first_keyframe_id)
        self._maps[map_id] = mo

    def maps_merged(self, from_map_id: int, into_map_id: int, T_into_from: F64, point_id_offset: int,
                    points: PointStore) -> None:
        """Map `from_map_id` was welded into `into_map_id` (`core.slam.map_merging`): its objects, anchors and
        thumbnails move into the target's object map (`object_map_merge`) and the labels of its map points,
        now rows of the target's `points`, name the objects' new ids."""
        src = self._maps.pop(from_map_id, None)
        if src is None or not self.config.enabled:
            return
        dst = self._for(into_map_id)
        shift = dst.next_sample_id + 2  # the source's first sample id (-2) lands on the target's next one
        ids, kfs, pts = src.anchors.arrays()
        moved_ids = remap_point_ids(ids, point_id_offset, shift)
        for kf_id in np.unique(kfs).tolist():
            dst.anchors.add(int(kf_id), moved_ids[kfs == kf_id], pts[kfs == kf_id])
        dst.next_sample_id = min(dst.next_sample_id, src.next_sample_id + shift)
        targets = list(dst.lta.objects.values())
        new_id: dict[int, int] = {}
        for oid, obj in sorted(src.lta.objects.items()):
            moved = moved_object(obj, dst.lta.next_id, T_into_from, point_id_offset, shift)
            same = same_object(moved, targets, self.config.association)
            if same is not None:
                join(same, moved)
            else:
                dst.lta.add_object(moved)
            new_id[oid] = moved.id if same is None else same.id
        rows = np.arange(point_id_offset, points.size)
        labels = points.object_id[rows].copy()
        for old, new in new_id.items():
            sel = rows[labels == old]
            points.object_id[sel] = new
            points.active[sel] = dst.lta.objects[new].active  # a joined object's flag may differ from the moved one's
        dst.thumbnails.update(src.thumbnails)
        R, t = T_into_from[:3, :3], T_into_from[:3, 3]
        dst.places = (dst.places + [(k, R @ c + t) for k, c in src.places])[-MAX_PLACES:]

    # --- per keyframe ---
    def after_keyframe(self, kf: Keyframe, slam_map: SlamMap, depth_m: npt.NDArray[np.floating] | None,
                       short_term_objects: Sequence[ObjectState], thumbnail: U8 | None = None) -> ObjectLayerResult:
        """Run the layer on a mapped keyframe. depth_m (H, W) metres (0 invalid) of the keyframe, or None;
        `short_term_objects`: the dynamic stage's objects in the keyframe's frame (dynamic ones are ignored);
        `thumbnail`: the keyframe's image (`object_evidence.keyframe_thumbnail`), kept while an object's evidence
        names the keyframe (a sighting or a belief step), for the change report.

        Steps:

        1. every object's points are re-read (bundle adjustment and loop correction move keyframes and points);
        2. the keyframe's candidates, one per short-term object of the dynamic stage that is not dynamic (static,
           or not yet classified), with its class and its box in this keyframe; boxes touching the border are
           truncated candidates (`long_term_association.box_truncated`). A candidate's points are
           - the map points of its keypoints (`Keyframe.object_ids`, set by the dynamic filter): only the keypoints
             tracking was allowed to use have map points, i.e. those of objects the EKF found static. With
             `band_map_points` only those within the box's depth band (below) are kept: a box also holds keypoints
             of the wall or the table seen past the object, which would pull the object's box back to the wall;
           - depth samples inside its box (`depth_samples` on a grid, within `depth_band_m` of the box's median
             depth, back-projected from the keyframe; cut boxes too with `truncated_views` and `cut_only_views_join`,
             kept only where an object known only from cut views takes them): the object's shape even while its
             keypoints are filtered (a movable object the EKF has not yet called static has no map point at all).
             They carry negative ids (below -1) and never enter the metric map;
        3. Algorithm 1 (`LongTermAssociation.process_keyframe`) merges, creates and belief-updates objects and
           runs the vicinity search with the keyframe's depth image;
        4. the map points take their object's id and class, and their active flag follows the object's belief
           (`apply_to_point_store`; a point held by two objects follows the one it was last associated with):
           tracking, local BA, map fusion and place recognition skip inactive points through
           `PointStore.usable()` and the loop closer's active masks.
        """
        t0 = time.perf_counter()
        if not self.config.enabled:
            return ObjectLayerResult(slam_map.id, None, (), 0, 0, 0.0)
        mo = self._for(slam_map.id)
        mo.lta.refresh_points(lambda ids: self._positions(mo, slam_map, ids))
        cands = self._candidates(mo, kf, slam_map, depth_m, short_term_objects)
        # every detection of the keyframe explains a miss away, also those that gave no candidate (flagged dynamic,
        # or a cut box without map points)
        flagged = [(int(o.class_id), tuple(float(v) for v in o.box_xyxy)) for o in short_term_objects]
        was_active = {oid: obj.active for oid, obj in mo.lta.objects.items()}
        up = gravity_up([p.normal for p in mo.planes], -kf.T_world_cam[:3, 1])  # the camera's -y is its up
        # walls for the picture check: without a floor among the planes (a camera at robot height sees it at a
        # grazing angle) the camera's own up stands in, a robot's camera being held about level
        walls_up = up if up is not None else -kf.T_world_cam[:3, 1]
        res = mo.lta.process_keyframe(kf.id, [c for c, _ in cands], kf.T_world_cam, kf.camera, depth_m,
                                      detected_boxes=flagged, up_w=up, planes=mo.room_planes,
                                      walls_up_w=walls_up, floor=mo.floor,
                                      structure=self._structure(mo))  # type: ignore[arg-type]
        self._anchor(mo, kf, cands, res)
        mo.places = (mo.places + [(c.class_id, c.centroid_w) for c, _ in cands])[-MAX_PLACES:]
        if self._reweight(mo, slam_map, kf.id):
            up = gravity_up([p.normal for p in mo.planes], -kf.T_world_cam[:3, 1])
        # every keyframe: an object grows by merges between plane fits, and the last fit may come before the end
        n_freed = self._drop_pictures(mo, slam_map, up if up is not None else walls_up)
        apply_to_point_store(slam_map.points, [c for c, _ in cands], res)
        settle_shared(mo.lta.objects, slam_map.points, res)
        flip_labelled(mo.lta.objects, slam_map.points, was_active, res.fused.values())
        n_kept = keep_enough_active(mo.lta.objects, kf, slam_map.points, self.config.min_active_points)
        self._keep_thumbnail(mo, kf.id, thumbnail)
        ms = (time.perf_counter() - t0) * 1e3
        self.keyframe_ms.append(ms)
        return ObjectLayerResult(slam_map.id, res, tuple(c for c, _ in cands),
                                 int((res.activated_point_ids >= 0).sum()) + n_freed + n_kept,
                                 int((res.deactivated_point_ids >= 0).sum()), ms)

    def _candidates(self, mo: _MapObjects, kf: Keyframe, slam_map: SlamMap,
                    depth_m: npt.NDArray[np.floating] | None,
                    short_term_objects: Sequence[ObjectState]) -> list[tuple[ObjectCandidate, F64]]:
        """(candidate, camera-frame positions (N, 3) of its points) per non-dynamic short-term object."""
        out = []
        has_ids = len(kf.object_ids) == len(kf.point_ids)
        T_cam_world = invert(kf.T_world_cam)
        for o in sorted(short_term_objects, key=lambda o: o.object_id):
            if o.is_dynamic:
                continue
            ids = np.zeros(0, np.int64)
            if has_ids:
                sel = (kf.object_ids == o.object_id) & (kf.point_ids >= 0)
                ids = np.unique(kf.point_ids[sel])
                ids = ids[~slam_map.points.bad[ids]]
            pts_w = slam_map.points.positions[ids].reshape(-1, 3)
            pts_c = pts_w @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
            band = None if depth_m is None else box_depth_band(depth_m, o.box_xyxy, kf.camera, self.config.depth_band_m,
                                                               near_quantile=self.config.depth_band_near_quantile)
            if self.config.band_map_points and band is not None:
                near = band.contains(pts_c[:, 2])
                ids, pts_w, pts_c = ids[near], pts_w[near], pts_c[near]
            box = tuple(float(v) for v in o.box_xyxy)
            truncated = box_truncated(box, kf.camera)  # type: ignore[arg-type]
            assoc = self.config.association
            # a cut box's samples are for objects known only from cut views; a sliver at the edge gives none
            cut_samples = (assoc.truncated_views and assoc.cut_only_views_join and band is not None
                           and min(box[2] - box[0], box[3] - box[1]) * band.median_m / kf.camera.fx
                           >= self.config.cut_min_side_m)
            if depth_m is not None and self.config.depth_samples > 0 and (cut_samples or not truncated):
                sample_c = box_depth_samples(depth_m, o.box_xyxy, kf.camera, self.config.depth_samples,
                                             self.config.depth_band_m, self.config.depth_band_near_quantile)
                sample_ids = np.arange(mo.next_sample_id, mo.next_sample_id - len(sample_c), -1, dtype=np.int64)
                mo.next_sample_id -= len(sample_c)
                ids = np.concatenate([ids, sample_ids])
                pts_c = np.vstack([pts_c, sample_c])
                pts_w = np.vstack([pts_w, sample_c @ kf.T_world_cam[:3, :3].T + kf.T_world_cam[:3, 3]])
            if len(ids) == 0:
                continue
            cand = ObjectCandidate(int(o.class_id), box, ids, pts_w, truncated)  # type: ignore[arg-type]
            out.append((cand, pts_c))
        return out

    def _reweight(self, mo: _MapObjects, slam_map: SlamMap, kf_id: int) -> bool:
        """Point weights of every object (`object_point_weights`): the room's planes are refitted to the static
        map points every `structure_refit_keyframes` keyframes. True when the planes were refitted now."""
        cfg = self.config.association
        refit = False
        if cfg.centroid_voxel_m <= 0.0 and cfg.structure_plane_dist_m <= 0.0 and cfg.shared_point_dist_m <= 0.0:
            return refit  # the paper's plain mean
        if cfg.structure_plane_dist_m > 0.0 and (mo.keyframes_since_planes < 0
                                                 or mo.keyframes_since_planes + 1 >= cfg.structure_refit_keyframes):
            pts = slam_map.points
            n = pts.size
            static = (pts.object_id[:n] < 0) & ~pts.bad[:n]
            mo.planes = fit_structure_planes(pts.positions[:n][static], cfg.structure_plane_dist_m,
                                             cfg.structure_plane_min_fraction, cfg.structure_max_planes,
                                             cfg.structure_plane_iterations, cfg.structure_plane_max_points, seed=kf_id)
            mo.room_planes = [p for p in mo.planes if plane_extent_m(p, pts.positions[:n][static],
                                                                      cfg.structure_plane_dist_m) >= cfg.wall_min_extent_m]
            if cfg.floor_patch_min_fraction > 0.0:
                mo.floor = scans_floor(slam_map.keyframes.values(), seed=kf_id)
            mo.keyframes_since_planes = 0
            refit = True
        else:
            mo.keyframes_since_planes += 1
        reweight_objects(list(mo.lta.objects.values()), self._structure(mo), cfg)
        return refit

    @staticmethod
    def _structure(mo: _MapObjects) -> list[Plane]:
        """The planes whose points are no object's in centroids and boxes: the room's large planes and the floor
        (seldom among them: the static map points hold little of it)."""
        return mo.planes + ([floor_as_plane(mo.floor)] if mo.floor is not None else [])

    @staticmethod
    def _keep_thumbnail(mo: _MapObjects, kf_id: int, thumbnail: U8 | None) -> None:
        """Keep this keyframe's thumbnail when an object's evidence names it; drop those no evidence names now."""
        named: set[int] = set()
        for obj in mo.lta.objects.values():
            named.update(obj.seen_keyframes)
            named.update(k for k, _, _ in obj.belief_history)
        if thumbnail is not None and kf_id in named:
            mo.thumbnails[kf_id] = np.asarray(thumbnail, np.uint8)
        for k in [k for k in mo.thumbnails if k not in named]:
            del mo.thumbnails[k]

    def _drop_pictures(self, mo: _MapObjects, slam_map: SlamMap, up_w: F64 | None) -> int:
        """Objects mapped before the walls or the floor were known that turn out to be pictures (`picture_check`)
        or floor patches (`floor_check`) leave the object map; their map points become plain static points again
        (unlabelled, active): a poster is wall, a patch of floor is floor. Returns how many map points were freed."""
        cfg = self.config.association
        pictures = [oid for oid, obj in mo.lta.objects.items()
                    if is_picture(obj.class_id, obj.points_w, mo.room_planes, up_w, cfg)
                    or is_floor_patch(obj.class_id, obj.points_w, mo.floor, cfg)]
        pts = slam_map.points
        n = pts.size
        freed = 0
        for oid in pictures:
            del mo.lta.objects[oid]
            sel = np.flatnonzero(pts.object_id[:n] == oid)
            pts.object_id[sel] = -1
            pts.class_id[sel] = 0
            pts.active[sel] = True
            freed += len(sel)
        return freed

    @staticmethod
    def _anchor(mo: _MapObjects, kf: Keyframe, cands: Sequence[tuple[ObjectCandidate, F64]],
                res: AssociationResult) -> None:
        for (cand, pts_c), oid in zip(cands, res.assignments):
            if oid < 0:
                continue
            ids = cand.point_ids
            if cand.truncated:  # a cut view's depth samples count only where the object took them
                keep = (ids >= 0) | np.isin(ids, mo.lta.objects[oid].point_ids)
                ids, pts_c = ids[keep], pts_c[keep]
            mo.anchors.add(kf.id, ids, pts_c)

    @staticmethod
    def _positions(mo: _MapObjects, slam_map: SlamMap, ids: I64) -> tuple[F64, npt.NDArray[np.bool_]]:
        """World positions (N, 3) of object points: live map points from the map, the others from their anchor."""
        pts = slam_map.points
        ids = np.asarray(ids, np.int64)
        live = (ids >= 0) & (ids < pts.size)
        safe = np.where(live, ids, 0)
        live &= ~pts.bad[safe]
        pos: F64 = pts.positions[safe].copy()
        usable = live.copy()
        need = np.flatnonzero(~live)
        if len(need) == 0:
            return pos, usable
        a_ids, a_kfs, a_pts = mo.anchors.arrays()
        if len(a_ids) == 0:
            return pos, usable
        j = np.searchsorted(a_ids, ids[need]).clip(0, len(a_ids) - 1)
        found = a_ids[j] == ids[need]
        need, j = need[found], j[found]
        for kf_id in np.unique(a_kfs[j]).tolist():
            if kf_id not in slam_map.keyframes and kf_id not in slam_map.removed:
                continue
            sel = a_kfs[j] == kf_id
            T = slam_map.pose_of(kf_id)
            pos[need[sel]] = a_pts[j[sel]] @ T[:3, :3].T + T[:3, 3]
            usable[need[sel]] = True
        return pos, usable

    def wants_keyframe(self, map_id: int, short_term_objects: Sequence[ObjectState], T_world_cam: F64,
                       camera: CameraIntrinsics) -> bool:
        """True when a frame at pose T_world_cam (4, 4) shows a whole, non-dynamic detection that no mapped object
        and no recent candidate of its class explains (its centroid projects inside the box, in front of the
        camera): an object the map has not seen yet (`new_object_keyframes`)."""
        if not (self.config.enabled and self.config.new_object_keyframes):
            return False
        mo = self._maps.get(map_id)
        known = [(o.class_id, o.centroid_w) for o in mo.lta.objects.values()] + list(mo.places) if mo else []
        cfg = self.config.association
        min_area = max(cfg.min_projected_area_fraction * camera.width * camera.height, cfg.min_projected_area_px)
        T_cw = invert(T_world_cam)
        for o in short_term_objects:
            box = tuple(float(v) for v in o.box_xyxy)
            if (o.is_dynamic or box_truncated(box, camera)  # type: ignore[arg-type]
                    or (box[2] - box[0]) * (box[3] - box[1]) < min_area):
                continue
            cents = np.array([c for k, c in known if k == int(o.class_id)]).reshape(-1, 3)
            pc = cents @ T_cw[:3, :3].T + T_cw[:3, 3]
            front = pc[:, 2] > 1e-6
            u = camera.fx * pc[front, 0] / pc[front, 2] + camera.cx
            v = camera.fy * pc[front, 1] / pc[front, 2] + camera.cy
            if not np.any((u >= box[0]) & (u <= box[2]) & (v >= box[1]) & (v <= box[3])):
                return True
        return False

    # --- results ---
    def semantic_map(self, map_id: int, min_belief: float | None = None, include_inactive: bool = False) -> SemanticMap:
        """§4.8 semantic map of one map: objects with belief >= min_belief (default `semantic_min_belief`,
        0.5; each flagged `confirmed` at `belief_threshold`)."""
        return build_semantic_map(self.objects(map_id), self.config.association, include_inactive=include_inactive,
                                  planes=self.planes(map_id),
                                  min_belief=min_belief)

    def summary(self) -> dict[str, Any]:
        """Counts for metrics.json: objects, active ones, milliseconds per keyframe."""
        objs = self.objects()
        ms = np.asarray(self.keyframe_ms) if self.keyframe_ms else np.zeros(1)
        min_points = self.config.association.min_points
        return {
            "enabled": self.config.enabled,
            "objects": len(objs),
            "objects_active": sum(1 for o in objs if o.active),
            "objects_inactive_with_points": sum(1 for o in objs if not o.active and o.n_points >= min_points),
            "keyframes": len(self.keyframe_ms),
            "ms_per_keyframe_mean": float(ms.mean()),
            "ms_per_keyframe_p90": float(np.percentile(ms, 90)),
        }
