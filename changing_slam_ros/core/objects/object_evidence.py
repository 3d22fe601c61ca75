"""What one map says about one object, as the change report needs it: place, belief, and the keyframes behind it.

`ObjectEvidence` is a plain record made from a MapObject (`evidence_of`, with its belief history and sighting
keyframes) or from a semantic-map record (`evidence_of_semantic`: a node's map, which keeps neither). `present`
says whether the map holds the object as there: belief >= `present_belief` (the semantic map's 0.5, seen and
not contradicted) and at least `min_points` points. Keyframe thumbnails (`keyframe_thumbnail`) are small
fixed-size copies of a keyframe's image that the object layer keeps for the keyframes its objects' evidence
names, so that a report can show what the camera saw before and after.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.dynamic.detector import class_name
from changing_slam_ros.core.objects.map_object import MapObject
from changing_slam_ros.core.objects.semantic_map import SemanticObject

F64 = npt.NDArray[np.float64]
U8 = npt.NDArray[np.uint8]
Vec3 = tuple[float, float, float]
THUMBNAIL_SIZE_PX = (96, 72)  # (width, height) of every keyframe thumbnail


@dataclass(frozen=True)
class EvidenceConfig:
    """Which objects a map holds as there: belief >= `present_belief` and >= `min_points` points."""

    present_belief: float = 0.5
    min_points: int = 5


@dataclass(frozen=True)
class ObjectEvidence:
    """One object in one map (map frame, metres). `belief_history`: rows (keyframe id, belief after, reason);
    `seen_keyframes`: keyframes whose whole view went into it; both empty when the map keeps none."""

    id: int
    class_id: int
    class_name: str
    centroid_w: Vec3
    box_size_m: Vec3
    belief: float
    n_points: int
    present: bool
    first_keyframe: int
    last_seen_keyframe: int
    belief_history: tuple[tuple[int, float, str], ...] = ()
    seen_keyframes: tuple[int, ...] = ()


def _vec3(a: object) -> Vec3:
    v = np.asarray(a, float).reshape(3)
    return float(v[0]), float(v[1]), float(v[2])


def evidence_of(obj: MapObject, config: EvidenceConfig = EvidenceConfig()) -> ObjectEvidence:
    """The record of a MapObject, with its belief history and sighting keyframes (copied)."""
    return ObjectEvidence(
        obj.id, obj.class_id, class_name(obj.class_id), _vec3(obj.centroid_w), _vec3(obj.box_size_m),
        float(obj.belief), obj.n_points, obj.belief >= config.present_belief and obj.n_points >= config.min_points,
        obj.first_keyframe, obj.last_seen_keyframe,
        tuple((int(k), float(b), str(r)) for k, b, r in obj.belief_history), tuple(int(k) for k in obj.seen_keyframes),
    )


def evidence_of_semantic(obj: SemanticObject, config: EvidenceConfig = EvidenceConfig()) -> ObjectEvidence:
    """The record of a semantic-map object (no history; its first and last sightings stand for the keyframes)."""
    seen = tuple(sorted({obj.first_seen_keyframe, obj.last_seen_keyframe} - {-1}))
    return ObjectEvidence(
        obj.id, obj.class_id, obj.class_name, _vec3(obj.centroid_w), _vec3(obj.box_size_m), float(obj.belief),
        obj.n_points, obj.belief >= config.present_belief and obj.n_points >= config.min_points,
        obj.first_seen_keyframe, obj.last_seen_keyframe, (), seen,
    )


def keyframe_thumbnail(rgb: npt.NDArray[np.uint8]) -> U8:
    """A (72, 96, 3) uint8 copy of an (H, W, 3) RGB image (area-averaged; other aspect ratios are stretched)."""
    img = np.asarray(rgb)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise ValueError(f"keyframe_thumbnail: expected an (H, W, 3) uint8 image, got {img.shape} {img.dtype}")
    out: U8 = cv2.resize(img, THUMBNAIL_SIZE_PX, interpolation=cv2.INTER_AREA)
    return out


def map_up(objects: list[MapObject]) -> F64 | None:
    """The map's up direction (3,) unit as the objects recorded it (`MapObject.up_sum_w`); None when none did."""
    total = np.sum([o.up_sum_w for o in objects], axis=0) if objects else np.zeros(3)
    n = float(np.linalg.norm(total))
    return None if n < 1e-9 else total / n  # type: ignore[no-any-return]
