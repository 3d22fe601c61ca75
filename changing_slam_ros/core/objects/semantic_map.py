"""The object-level semantic map (Changing-SLAM §4.8): the MapObjects with a high belief.

"The semantic map is composed of MapObjects with their respective centroids and 3D bounding boxes ...
Only objects with a high belief are active in the map." `build_semantic_map` keeps the objects whose
belief is at least `semantic_min_belief` (0.5 by default: seen and not contradicted) and that hold at least
`min_points` points, and turns each into a plain record (no point ids), ordered by id. Each record says
whether the object is `confirmed`: its belief reached `belief_threshold` (a long-term re-observation), so
its points are active. An unconfirmed object (belief in [semantic_min_belief, belief_threshold)) was seen
in one continuous pass only, or its evidence is mixed: it is in the map, flagged, and its points do not
localise the robot. `include_inactive=True` keeps every object (for debugging and for the plot, which draws
low-belief objects dashed).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.dynamic.detector import class_name
from changing_slam_ros.core.objects.map_object import MapObject, ObjectMapConfig
from changing_slam_ros.core.objects.object_box_completion import completed_box
from changing_slam_ros.core.objects.object_point_weights import Plane

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class SemanticObject:
    """One object of the semantic map, world (map) frame, metres.

    centroid_w (3,) mean of the points; box_center_w (3,) and box_size_m (3,) the world-axis-aligned box, grown
    to the class's typical depth for an object seen from one side only (`object_box_completion`).
    """

    id: int
    class_id: int
    class_name: str
    centroid_w: tuple[float, float, float]
    box_center_w: tuple[float, float, float]
    box_size_m: tuple[float, float, float]
    belief: float
    active: bool
    n_points: int
    first_seen_keyframe: int
    last_seen_keyframe: int

    @property
    def confirmed(self) -> bool:
        """The belief reached BeliefThreshold (the object's points are active): re-observed on a later pass."""
        return self.active

    @property
    def box_min_w(self) -> F64:
        return np.asarray(self.box_center_w) - 0.5 * np.asarray(self.box_size_m)

    @property
    def box_max_w(self) -> F64:
        return np.asarray(self.box_center_w) + 0.5 * np.asarray(self.box_size_m)


@dataclass(frozen=True)
class SemanticMap:
    """The semantic map: objects (ordered by id) and the threshold they were selected with."""

    objects: tuple[SemanticObject, ...]
    belief_threshold: float
    frame_id: str = "map"

    def by_id(self, object_id: int) -> SemanticObject | None:
        for o in self.objects:
            if o.id == object_id:
                return o
        return None


def _triple(a: F64) -> tuple[float, float, float]:
    v = np.asarray(a, float).reshape(3)
    return float(v[0]), float(v[1]), float(v[2])


def semantic_object(obj: MapObject, config: ObjectMapConfig, planes: Sequence[Plane] = ()) -> SemanticObject:
    """The semantic-map record of one MapObject, its box completed per `config` within the room's `planes`."""
    box = completed_box(obj, config, planes)
    return SemanticObject(
        obj.id, obj.class_id, class_name(obj.class_id), _triple(obj.centroid_w), _triple(box.center_w),
        _triple(box.size_m), float(obj.belief), bool(obj.active), obj.n_points, obj.first_keyframe,
        obj.last_seen_keyframe,
    )


def build_semantic_map(objects: Iterable[MapObject], config: ObjectMapConfig, include_inactive: bool = False,
                       frame_id: str = "map", min_belief: float | None = None,
                       planes: Sequence[Plane] = ()) -> SemanticMap:
    """The objects with belief >= `min_belief` (by default config.semantic_min_belief: 0.5 keeps the objects
    seen in one continuous pass only, which Algorithm 1 never updates, flagged unconfirmed) and at least
    config.min_points points. `min_belief=config.belief_threshold` gives the confirmed objects only. `planes`: the
    room's large planes in the objects' frame (`ObjectLayer.planes`), which bound box completion."""
    threshold = config.semantic_min_belief if min_belief is None else float(min_belief)
    kept = [
        semantic_object(o, config, planes) for o in sorted(objects, key=lambda o: o.id)
        if o.n_points >= config.min_points and (include_inactive or o.belief >= threshold)
    ]
    return SemanticMap(tuple(kept), threshold, frame_id)
