"""The object layer of the SLAM system (Changing-SLAM §4.2, §4.6-4.8): MapObjects, beliefs and active points.

`ObjectLayer` wraps one `LongTermAssociation` per map of the Atlas. `SlamSystem` calls
`after_keyframe(kf, slam_map, depth_m, short_term_objects)` once per new keyframe, after local mapping
and before loop closing, so that loop closing already sees the points this keyframe deactivated:

1. every object's points are re-read from the map (bundle adjustment and loop correction move them);
2. the keyframe's candidates: its map points grouped by the short-term object id of their keypoint
   (`Keyframe.object_ids`, set by the dynamic filter), one candidate per object the dynamic stage does
   not consider dynamic, with its class and box in this keyframe; boxes touching the border are
   truncated candidates (`long_term_association.box_truncated`);
3. Algorithm 1 (`LongTermAssociation.process_keyframe`) merges, creates and belief-updates objects and
   runs the vicinity search with the keyframe's depth image;
4. the map points take their object's id and class, and the active flag follows the object's belief
   (`apply_to_point_store`): tracking, local BA, map fusion and place recognition skip inactive points
   through `PointStore.usable()` / the loop closer's active masks.

Object points outlive metric culling. Inactive points are never matched again, so ORB-SLAM's
recent-point culling removes most of them two keyframes after their creation; a MapObject that lost its
points would fall under `min_points` and could never be associated again. The layer therefore anchors
every object point in the keyframe that first gave it to the object (position in that camera's frame)
and, once the map culled the point, re-expresses it from that keyframe's current pose (culled keyframes
through their parents, `SlamMap.pose_of`). Points still in the map are read from the map.

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

from changing_slam_ros.core.dynamic_objects import ObjectState
from changing_slam_ros.core.keyframe import Keyframe
from changing_slam_ros.core.long_term_association import (
    AssociationResult, LongTermAssociation, ObjectCandidate, apply_to_point_store, box_truncated,
    candidates_from_keyframe,
)
from changing_slam_ros.core.map_object import BoxXyxy, MapObject, ObjectMapConfig, object_map_config
from changing_slam_ros.core.se3 import invert
from changing_slam_ros.core.semantic_map import SemanticMap, build_semantic_map
from changing_slam_ros.core.slam_map import SlamMap
from changing_slam_ros.errors import ConfigError

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


@dataclass(frozen=True)
class ObjectLayerConfig:
    """YAML section `objects:`: `enabled` (the layer's switch) plus every `ObjectMapConfig` field."""

    enabled: bool = True
    association: ObjectMapConfig = field(default_factory=ObjectMapConfig)


def object_layer_config(data: dict[str, Any] | None, where: str = "objects") -> ObjectLayerConfig:
    """Parse the `objects:` mapping (None = defaults); `enabled` is read here, the rest by `ObjectMapConfig`."""
    if data is None:
        return ObjectLayerConfig()
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a mapping, got {type(data).__name__}")
    rest = dict(data)
    enabled = rest.pop("enabled", True)
    if not isinstance(enabled, bool):
        raise ConfigError(f"{where}.enabled: expected true or false, got {enabled!r}")
    return ObjectLayerConfig(enabled, object_map_config(rest, where))


@dataclass(frozen=True)
class ObjectLayerResult:
    """What one keyframe did to the object map of its map: `association` (None when the layer is off),
    `candidates` (the keyframe's object candidates, in association order), points whose active flag was set
    (`n_activated`, `n_deactivated`) and the milliseconds spent."""

    map_id: int
    association: AssociationResult | None
    candidates: tuple[ObjectCandidate, ...]
    n_activated: int
    n_deactivated: int
    ms: float

    @property
    def active_flags_changed(self) -> bool:
        return self.n_activated + self.n_deactivated > 0


@dataclass
class _MapObjects:
    """The object map of one SlamMap: the association and each object point's anchor
    (point id -> (keyframe id, position (3,) in that keyframe's camera frame))."""

    lta: LongTermAssociation
    anchors: dict[int, tuple[int, F64]] = field(default_factory=dict)


class ObjectLayer:
    """MapObjects and persistence beliefs for every map of the Atlas; one instance per run."""

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

    def _for(self, map_id: int) -> _MapObjects:
        if map_id not in self._maps:
            self._maps[map_id] = _MapObjects(LongTermAssociation(self.config.association))
        return self._maps[map_id]

    # --- per keyframe ---
    def after_keyframe(self, kf: Keyframe, slam_map: SlamMap, depth_m: npt.NDArray[np.floating] | None,
                       short_term_objects: Sequence[ObjectState]) -> ObjectLayerResult:
        """Run the layer on a mapped keyframe. depth_m (H, W) metres (0 invalid) of the keyframe, or None;
        `short_term_objects`: the dynamic stage's objects in the keyframe's frame (dynamic ones are ignored)."""
        t0 = time.perf_counter()
        if not self.config.enabled:
            return ObjectLayerResult(slam_map.id, None, (), 0, 0, 0.0)
        mo = self._for(slam_map.id)
        mo.lta.refresh_points(lambda ids: self._positions(mo, slam_map, ids))
        boxes: dict[int, tuple[int, BoxXyxy, bool]] = {
            int(o.object_id): (int(o.class_id), o.box_xyxy, box_truncated(o.box_xyxy, kf.camera))
            for o in short_term_objects if not o.is_dynamic
        }
        cands: list[ObjectCandidate] = []
        if boxes and kf.object_ids is not None and len(kf.object_ids) == len(kf.point_ids):
            cands = candidates_from_keyframe(kf, lambda ids: slam_map.points.positions[ids].copy(), boxes)
        res = mo.lta.process_keyframe(kf.id, cands, kf.T_world_cam, kf.camera, depth_m)
        self._anchor(mo, kf, cands, res)
        apply_to_point_store(slam_map.points, cands, res)
        ms = (time.perf_counter() - t0) * 1e3
        self.keyframe_ms.append(ms)
        return ObjectLayerResult(slam_map.id, res, tuple(cands), len(res.activated_point_ids),
                                 len(res.deactivated_point_ids), ms)

    @staticmethod
    def _anchor(mo: _MapObjects, kf: Keyframe, cands: Sequence[ObjectCandidate], res: AssociationResult) -> None:
        T_cam_world = invert(kf.T_world_cam)
        for cand, oid in zip(cands, res.assignments):
            if oid < 0:
                continue
            for pid, p in zip(np.asarray(cand.point_ids, np.int64).tolist(), np.asarray(cand.points_w, float)):
                if pid not in mo.anchors:
                    mo.anchors[pid] = (kf.id, T_cam_world[:3, :3] @ p + T_cam_world[:3, 3])

    @staticmethod
    def _positions(mo: _MapObjects, slam_map: SlamMap, ids: I64) -> tuple[F64, npt.NDArray[np.bool_]]:
        """World positions (N, 3) of object points: from the map while the point lives, else from its anchor."""
        pts = slam_map.points
        ids = np.asarray(ids, np.int64)
        known = (ids >= 0) & (ids < pts.size)
        safe = np.where(known, ids, 0)
        pos: F64 = pts.positions[safe].copy()
        usable = known.copy()
        for i in np.flatnonzero(known & pts.bad[safe]).tolist():
            anchor = mo.anchors.get(int(ids[i]))
            kf_id = -1 if anchor is None else anchor[0]
            if anchor is None or not (kf_id in slam_map.keyframes or kf_id in slam_map.removed):
                usable[i] = False
                continue
            T = slam_map.pose_of(kf_id)
            pos[i] = T[:3, :3] @ anchor[1] + T[:3, 3]
        return pos, usable

    # --- results ---
    def semantic_map(self, map_id: int, min_belief: float | None = None, include_inactive: bool = False) -> SemanticMap:
        """§4.8 semantic map of one map: objects with belief >= min_belief (default the belief threshold)."""
        return build_semantic_map(self.objects(map_id), self.config.association, include_inactive=include_inactive,
                                  min_belief=min_belief)

    def summary(self) -> dict[str, Any]:
        """Counts for metrics.json: objects, active ones, milliseconds per keyframe."""
        objs = self.objects()
        ms = np.asarray(self.keyframe_ms) if self.keyframe_ms else np.zeros(1)
        return {
            "enabled": self.config.enabled,
            "objects": len(objs),
            "objects_active": sum(1 for o in objs if o.active),
            "objects_inactive_with_points": sum(1 for o in objs if not o.active and o.n_points >= self.config.association.min_points),
            "keyframes": len(self.keyframe_ms),
            "ms_per_keyframe_mean": float(ms.mean()),
            "ms_per_keyframe_p90": float(np.percentile(ms, 90)),
        }
