"""The occupancy grid of a SlamMap: each new keyframe's depth scan (`keyframe_scan`), the grid of a whole map
(`map_grid`).

A scan is made once the object layer has run on the keyframe, so that its points can carry the MapObject
they belong to; the dynamic stage's dynamic objects (people, anything seen moving) flag theirs. The grid is
built from the keyframes' current poses (after local BA and loop corrections) and the objects' current beliefs:
points of an object whose belief fell below `GridConfig.object_min_belief` are left out then, whenever
they were seen.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.map.grid_scan import GridScan, ObjectView, label_objects, mark_dynamic, scan_from_depth
from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.map.occupancy_grid import (
    GridConfig, OccupancyGrid, ScanView, build_grid, inactive_objects,
)
from changing_slam_ros.core.map.slam_map import SlamMap


def object_views(layer_result: Any | None, objects_by_id: dict[int, Any]) -> list[ObjectView]:
    """The MapObjects a keyframe's candidates went to (`ObjectLayerResult`: candidates and their assignments), with
    the candidate's box and the object's 3-D box as they are now; [] without a result."""
    if layer_result is None or layer_result.association is None:
        return []
    out = []
    for cand, oid in zip(layer_result.candidates, layer_result.association.assignments):
        obj = objects_by_id.get(int(oid))
        if oid >= 0 and obj is not None and obj.n_points > 0:
            out.append(ObjectView(int(oid), tuple(float(v) for v in cand.box_xyxy), obj.box_center_w.copy(),
                                  obj.box_size_m.copy()))  # fmt: skip
    return out


def keyframe_scan(kf: Keyframe, depth_m: npt.NDArray[np.floating] | None, cfg: GridConfig,
                  short_term_objects: Sequence[Any] = (), views: Sequence[ObjectView] = ()) -> GridScan | None:
    """The grid scan of a mapped keyframe: its depth sampled (`scan_from_depth`), the points of the dynamic stage's
    dynamic objects flagged and those of `views` labelled; None without depth or with the grid off."""
    if depth_m is None or not cfg.enabled or np.asarray(depth_m).size == 0:
        return None
    scan = scan_from_depth(depth_m, kf.camera, cfg.scan_columns, cfg.max_range_m)
    h, w = np.asarray(depth_m).shape
    camera = kf.camera if (w, h) == (kf.camera.width, kf.camera.height) else kf.camera.scaled(w, h)
    dynamic = [tuple(float(v) for v in o.box_xyxy) for o in short_term_objects if o.is_dynamic]
    mark_dynamic(scan, camera, dynamic, cfg.dynamic_band_m)  # type: ignore[arg-type]
    label_objects(scan, camera, kf.T_world_cam, views, cfg.object_margin_m)
    return scan


def map_views(slam_map: SlamMap) -> list[ScanView]:
    """Every live keyframe of the map that keeps a scan, at its current pose, oldest first."""
    views = [ScanView(kf.stamp_ns, kf.T_world_cam, kf.grid_scan) for kf in slam_map.keyframes.values()
             if kf.grid_scan is not None]  # fmt: skip
    return sorted(views, key=lambda v: v.stamp_ns)


def map_grid(slam_map: SlamMap, cfg: GridConfig, objects: Sequence[Any] = ()) -> OccupancyGrid | None:
    """The occupancy grid of `slam_map` with the objects of its object map (their beliefs); None when no keyframe
    keeps a scan."""
    return build_grid(map_views(slam_map), cfg, excluded_objects=inactive_objects(objects, cfg.object_min_belief))
