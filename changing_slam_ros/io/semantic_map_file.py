"""Semantic map files (Changing-SLAM §4.8): versioned JSON, or YAML for a `.yaml` / `.yml` name.

The semantic map (`FORMAT`, version 1; layout in `semantic_map_to_dict`) lists the mapped objects with
their class, centroid, box, belief and activity. Writes are atomic (`io/atomic.py`). Load errors are
`MapFileError`s naming the file and the field (`objects[2].centroid_m`).

The object map (every MapObject with its point ids, point positions, optional point weights, boxes and
persistence state, for a saved map that a later session starts from) has its own document,
`object_map_to_dict` / `object_map_from_dict` (format "changing_slam_ros object map", version 1), meant to be
embedded in the map file or written alone with `write_object_map` / `read_object_map`.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import yaml

from changing_slam_ros.core.objects.map_object import MapObject
from changing_slam_ros.core.objects.object_point_weights import Plane
from changing_slam_ros.core.objects.semantic_map import SemanticMap, SemanticObject
from changing_slam_ros.errors import MapFileError, yaml_error
from changing_slam_ros.io.atomic import atomic_write_text

FORMAT = "changing_slam_ros semantic map"
VERSION = 1
OBJECT_MAP_FORMAT = "changing_slam_ros object map"
OBJECT_MAP_VERSION = 1


def _is_yaml(path: Path) -> bool:
    return path.suffix.lower() in (".yaml", ".yml")


def semantic_map_to_dict(smap: SemanticMap) -> dict[str, Any]:
    """The semantic map as a document (version 1):

        format: "changing_slam_ros semantic map"
        version: 1
        frame_id: "map"
        belief_threshold: 0.6
        objects:                      # ordered by id
          - {id, class_id, class_name, centroid_m: [x, y, z], box_center_m: [x, y, z], box_size_m: [dx, dy, dz],
             belief, active, n_points, first_seen_keyframe, last_seen_keyframe}

    Positions in metres in `frame_id`; boxes axis-aligned in that frame.
    """
    return {
        "format": FORMAT,
        "version": VERSION,
        "frame_id": smap.frame_id,
        "belief_threshold": smap.belief_threshold,
        "objects": [
            {
                "id": o.id, "class_id": o.class_id, "class_name": o.class_name,
                "centroid_m": list(o.centroid_w), "box_center_m": list(o.box_center_w),
                "box_size_m": list(o.box_size_m), "belief": o.belief, "active": o.active,
                "n_points": o.n_points, "first_seen_keyframe": o.first_seen_keyframe,
                "last_seen_keyframe": o.last_seen_keyframe,
            }
            for o in smap.objects
        ],
    }


def write_semantic_map(path: str | Path, smap: SemanticMap) -> None:
    """Write `smap` to `path` atomically, YAML for .yaml / .yml, JSON otherwise."""
    p = Path(path)
    doc = semantic_map_to_dict(smap)
    if _is_yaml(p):
        text = yaml.safe_dump(doc, sort_keys=False, default_flow_style=None)
    else:
        text = json.dumps(doc, indent=1) + "\n"
    atomic_write_text(p, text)


def read_semantic_map(path: str | Path) -> SemanticMap:
    """Read a file written by `write_semantic_map`; MapFileError names the file and the bad field."""
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as err:
        raise MapFileError(f"{p}: cannot read semantic map ({err.strerror})") from err
    try:
        doc = yaml.safe_load(text) if _is_yaml(p) else json.loads(text)
    except (json.JSONDecodeError, yaml.YAMLError) as err:
        raise MapFileError(yaml_error(p, err) if _is_yaml(p) else f"{p}: not valid JSON ({err})") from err
    return semantic_map_from_dict(doc, str(p))


def semantic_map_from_dict(doc: Any, where: str) -> SemanticMap:
    """Validate and convert a parsed document; `where` (the file name) starts every error message."""
    if not isinstance(doc, dict):
        raise MapFileError(f"{where}: expected a mapping at top level, got {type(doc).__name__}")
    if doc.get("format") != FORMAT:
        raise MapFileError(f"{where}: format: expected {FORMAT!r}, got {doc.get('format')!r}")
    version = doc.get("version")
    if version != VERSION:
        raise MapFileError(f"{where}: version: expected {VERSION}, got {version!r} (file from a newer release?)")
    frame_id = _field(doc, "frame_id", str, where)
    threshold = _number(doc, "belief_threshold", where)
    objects = []
    for w, item in _object_entries(doc, where):
        objects.append(SemanticObject(
            id=_field(item, "id", int, w), class_id=_field(item, "class_id", int, w),
            class_name=_field(item, "class_name", str, w), centroid_w=_vec3(item, "centroid_m", w),
            box_center_w=_vec3(item, "box_center_m", w), box_size_m=_vec3(item, "box_size_m", w),
            belief=_number(item, "belief", w), active=_field(item, "active", bool, w),
            n_points=_field(item, "n_points", int, w),
            first_seen_keyframe=_field(item, "first_seen_keyframe", int, w),
            last_seen_keyframe=_field(item, "last_seen_keyframe", int, w),
        ))
        if not 0.0 <= objects[-1].belief <= 1.0:
            raise MapFileError(f"{w}.belief: expected within [0, 1], got {objects[-1].belief}")
        if any(s < 0.0 for s in objects[-1].box_size_m):
            raise MapFileError(f"{w}.box_size_m: expected sizes >= 0, got {list(objects[-1].box_size_m)}")
    ids = [o.id for o in objects]
    if len(set(ids)) != len(ids):
        raise MapFileError(f"{where}: objects: duplicated ids {sorted({i for i in ids if ids.count(i) > 1})}")
    return SemanticMap(tuple(objects), threshold, frame_id)


def object_map_to_dict(objects: list[MapObject]) -> dict[str, Any]:
    """Every field of every MapObject (ordered by id); points as [[id, x, y, z], ...], optional `point_weights` (one
    per point, the centroid's weights). Embedded in the map file, or written alone with `write_object_map`.

    Each object's evidence for the change report, `belief_history` ([[keyframe id, belief, reason], ...]) and
    `seen_keyframes`, is optional (empty when absent).
    """
    return {
        "format": OBJECT_MAP_FORMAT,
        "version": OBJECT_MAP_VERSION,
        "objects": [
            {
                "id": o.id, "class_id": o.class_id, "first_box_xyxy": list(o.first_box_xyxy),
                "current_box_xyxy": list(o.current_box_xyxy), "first_keyframe": o.first_keyframe,
                "last_seen_keyframe": o.last_seen_keyframe, "last_belief_update_keyframe": o.last_belief_update_keyframe,
                "n_observations": o.n_observations, "belief": o.belief, "active": o.active,
                "points": [[int(i), *(float(v) for v in p)] for i, p in zip(o.point_ids, o.points_w)],
                **({} if o.point_weights is None else {"point_weights": [float(w) for w in o.point_weights]}),
                "view_sum_w": [float(v) for v in o.view_sum_w], "n_views": o.n_views,
                "up_sum_w": [float(v) for v in o.up_sum_w],
                "belief_history": [[int(k), float(b), str(r)] for k, b, r in o.belief_history],
                "seen_keyframes": [int(k) for k in o.seen_keyframes],
            }
            for o in sorted(objects, key=lambda o: o.id)
        ],
    }


def object_map_from_dict(doc: Any, where: str) -> list[MapObject]:
    """Validate and rebuild the MapObjects of an object-map document (centroids and boxes recomputed)."""
    if not isinstance(doc, dict):
        raise MapFileError(f"{where}: expected a mapping, got {type(doc).__name__}")
    if doc.get("format") != OBJECT_MAP_FORMAT:
        raise MapFileError(f"{where}: format: expected {OBJECT_MAP_FORMAT!r}, got {doc.get('format')!r}")
    if doc.get("version") != OBJECT_MAP_VERSION:
        raise MapFileError(f"{where}: version: expected {OBJECT_MAP_VERSION}, got {doc.get('version')!r}")
    out = []
    for w, item in _object_entries(doc, where):
        pts = item.get("points")
        if (not isinstance(pts, list) or any(not isinstance(p, list) or len(p) != 4 for p in pts)
                or any(isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)
                       for p in pts for v in p)):
            raise MapFileError(f"{w}.points: expected a list of [id, x, y, z] numbers")
        belief = _number(item, "belief", w)
        if not 0.0 <= belief <= 1.0:
            raise MapFileError(f"{w}.belief: expected within [0, 1], got {belief}")
        arr = np.asarray(pts, float).reshape(-1, 4)
        weights = item.get("point_weights")  # optional: the centroid's per-point weights (none = equal weights)
        if weights is not None and (
                not isinstance(weights, list) or len(weights) != len(arr)
                or any(isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0
                       for v in weights)):
            raise MapFileError(f"{w}.point_weights: expected {len(arr)} finite numbers >= 0, one per point")
        view_sum, up_sum = _optional_vec3(item, "view_sum_w", w), _optional_vec3(item, "up_sum_w", w)  # optional (box completion)
        n_views = _field(item, "n_views", int, w) if "n_views" in item else 0
        if n_views < 0:
            raise MapFileError(f"{w}.n_views: expected >= 0, got {n_views}")
        obj = MapObject(
            _field(item, "id", int, w), _field(item, "class_id", int, w), _box(item, "first_box_xyxy", w),
            _box(item, "current_box_xyxy", w), _field(item, "first_keyframe", int, w),
            _field(item, "last_seen_keyframe", int, w), belief=belief, active=_field(item, "active", bool, w),
            point_ids=arr[:, 0].astype(np.int64), points_w=arr[:, 1:],
            last_belief_update_keyframe=_field(item, "last_belief_update_keyframe", int, w),
            n_observations=_field(item, "n_observations", int, w),
            point_weights=None if weights is None else np.asarray(weights, float),
            view_sum_w=view_sum, n_views=n_views, up_sum_w=up_sum,
            belief_history=_belief_history(item, w), seen_keyframes=_keyframe_list(item, "seen_keyframes", w),
        )
        out.append(obj)
    ids = [o.id for o in out]
    if len(set(ids)) != len(ids):
        raise MapFileError(f"{where}: objects: duplicated ids")
    return out


BELIEF_REASONS = ("new", "seen", "missed", "session")


def _belief_history(item: dict[str, Any], where: str) -> list[tuple[int, float, str]]:
    """Optional [[keyframe id, belief in [0, 1], reason], ...] (empty when absent: files written before it)."""
    rows = item.get("belief_history", [])
    ok = isinstance(rows, list) and all(
        isinstance(r, list) and len(r) == 3 and isinstance(r[0], int) and not isinstance(r[0], bool)
        and isinstance(r[1], (int, float)) and not isinstance(r[1], bool) and 0.0 <= r[1] <= 1.0
        and r[2] in BELIEF_REASONS for r in rows)
    if not ok:
        raise MapFileError(f"{where}.belief_history: expected [[keyframe id, belief in [0, 1], reason], ...] with a "
                           f"reason in {list(BELIEF_REASONS)}")
    return [(int(k), float(b), str(r)) for k, b, r in rows]


def _keyframe_list(item: dict[str, Any], key: str, where: str) -> list[int]:
    """Optional list of keyframe ids (empty when absent)."""
    v = item.get(key, [])
    if not isinstance(v, list) or any(isinstance(k, bool) or not isinstance(k, int) for k in v):
        raise MapFileError(f"{where}.{key}: expected a list of keyframe ids")
    return [int(k) for k in v]


def _optional_vec3(item: dict[str, Any], key: str, where: str) -> npt.NDArray[np.float64]:
    """An optional [x, y, z] of finite numbers (zeros when absent: files written before it existed)."""
    v = item.get(key, [0.0, 0.0, 0.0])
    if (not isinstance(v, list) or len(v) != 3
            or any(isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x) for x in v)):
        raise MapFileError(f"{where}.{key}: expected 3 finite numbers")
    return np.asarray(v, np.float64)


def write_object_map(path: str | Path, objects: list[MapObject], planes: Sequence[Plane] = ()) -> None:
    """Write every MapObject to `path` (JSON) atomically, with the room's large planes (`structure_planes`:
    [[nx, ny, nz, offset], ...], map frame) that bound the semantic map's box completion."""
    doc = object_map_to_dict(objects)
    doc["structure_planes"] = [[*(float(v) for v in p.normal), float(p.offset)] for p in planes]
    atomic_write_text(Path(path), json.dumps(doc, separators=(",", ":")) + "\n")


def read_object_map(path: str | Path) -> list[MapObject]:
    """The MapObjects of an object-map file (`read_object_map_file` also gives its planes)."""
    return read_object_map_file(path)[0]


def read_object_map_file(path: str | Path) -> tuple[list[MapObject], list[Plane]]:
    """The MapObjects of an object-map file and its `structure_planes` (optional: none when the key is absent)."""
    p = Path(path)
    try:
        doc = json.loads(p.read_text())
    except OSError as err:
        raise MapFileError(f"{p}: cannot read object map ({err.strerror})") from err
    except json.JSONDecodeError as err:
        raise MapFileError(f"{p}: not valid JSON ({err})") from err
    objects = object_map_from_dict(doc, str(p))
    rows = doc.get("structure_planes", [])
    if (not isinstance(rows, list) or any(not isinstance(r, list) or len(r) != 4 for r in rows)
            or any(isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) for r in rows for v in r)):
        raise MapFileError(f"{p}: structure_planes: expected a list of [nx, ny, nz, offset] numbers")
    return objects, [Plane(np.asarray(r[:3], np.float64), float(r[3])) for r in rows]


def _box(d: dict[str, Any], key: str, where: str) -> tuple[float, float, float, float]:
    v = d.get(key)
    if (not isinstance(v, list) or len(v) != 4
            or any(isinstance(x, bool) or not isinstance(x, (int, float)) for x in v)):
        raise MapFileError(f"{where}.{key}: expected 4 numbers [x_min, y_min, x_max, y_max], got {v!r}")
    return float(v[0]), float(v[1]), float(v[2]), float(v[3])


def _field(d: dict[str, Any], key: str, kind: type, where: str) -> Any:
    if key not in d:
        raise MapFileError(f"{where}.{key}: missing")
    v = d[key]
    if kind is int and (isinstance(v, bool) or not isinstance(v, int)):
        raise MapFileError(f"{where}.{key}: expected an integer, got {v!r}")
    if kind is not int and not isinstance(v, kind):
        raise MapFileError(f"{where}.{key}: expected {kind.__name__}, got {v!r}")
    return v


def _number(d: dict[str, Any], key: str, where: str) -> float:
    if key not in d:
        raise MapFileError(f"{where}.{key}: missing")
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise MapFileError(f"{where}.{key}: expected a finite number, got {v!r}")
    return float(v)


def _vec3(d: dict[str, Any], key: str, where: str) -> tuple[float, float, float]:
    if key not in d:
        raise MapFileError(f"{where}.{key}: missing")
    v = d[key]
    if (not isinstance(v, list) or len(v) != 3
            or any(isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x) for x in v)):
        raise MapFileError(f"{where}.{key}: expected 3 finite numbers, got {v!r}")
    return float(v[0]), float(v[1]), float(v[2])


def _object_entries(doc: dict[str, Any], where: str) -> Iterator[tuple[str, dict[str, Any]]]:
    """The mappings of `doc["objects"]`, each with its place for messages ("FILE: objects[i]")."""
    raw = doc.get("objects")
    if not isinstance(raw, list):
        raise MapFileError(f"{where}: objects: expected a list, got {type(raw).__name__}")
    for i, item in enumerate(raw):
        w = f"{where}: objects[{i}]"
        if not isinstance(item, dict):
            raise MapFileError(f"{w}: expected a mapping, got {type(item).__name__}")
        yield w, item
