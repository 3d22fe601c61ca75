"""The saved map (`map.npz`): every map of the Atlas and its object map, enough to start a second session.

One deflate-compressed npz archive (numpy arrays, no pickles), written atomically and
byte-for-byte deterministically (fixed zip member dates, sorted members), so that save -> load -> save
gives the same bytes. Version `MAP_FORMAT_VERSION` (4); versions 3 (no keyframe depth scans for the occupancy
grid) and 2 (nor keyframe thumbnails, nor object evidence) still load; version 1 (keyframe poses and usable points only, written before multi-session support) is refused
with an error that says so. The fields are listed in `save_map`.

`load_map` checks every field (present, shape, dtype kind, ids that refer to stored keyframes and points)
and raises `MapFileError` naming the file and the field.
"""

from __future__ import annotations

import io
import json
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.map.grid_scan import GridScan
from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.map.map_point import PointStore
from changing_slam_ros.core.objects.object_evidence import THUMBNAIL_SIZE_PX
from changing_slam_ros.core.objects.object_layer import ObjectLayer, SavedObjectMap
from changing_slam_ros.core.map.slam_map import Atlas, RemovedKeyframe, SlamMap
from changing_slam_ros.errors import MapFileError
from changing_slam_ros.io.atomic import atomic_write_bytes

MAP_FORMAT_VERSION = 4
# version 3 has no grid scans; version 2 no thumbnails either, and its object documents no evidence (all optional)
READABLE_VERSIONS = (2, 3, 4)
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)
Arrays = dict[str, npt.NDArray[Any]]


@dataclass
class LoadedMap:
    """What a map file holds: the Atlas (current map as saved), the object map of each map that had one, and the
    first keyframe id a new session may use."""

    atlas: Atlas
    objects: dict[int, SavedObjectMap] = field(default_factory=dict)
    next_keyframe_id: int = 0


# --- save ------------------------------------------------------------------------------------------

def object_maps_of(layer: ObjectLayer | None) -> dict[int, SavedObjectMap]:
    """The object map of every map of `layer` (none when it is absent or switched off)."""
    if layer is None or not layer.enabled:
        return {}
    return {m: layer.saved_objects(m) for m in layer.map_ids}


def map_arrays(atlas: Atlas, objects: Mapping[int, SavedObjectMap] | None = None,
               next_keyframe_id: int | None = None) -> Arrays:
    """The arrays of a map file for `atlas` and the object maps `objects` (map id -> object map)."""
    all_ids = [k for m in atlas.maps for k in (*m.keyframes, *m.removed)]
    nxt = max(all_ids, default=-1) + 1 if next_keyframe_id is None else int(next_keyframe_id)
    arrays: Arrays = {
        "format_version": np.array(MAP_FORMAT_VERSION, np.int64),
        "map_ids": np.array([m.id for m in atlas.maps], np.int64),
        "current_map_id": np.array(atlas.current.id, np.int64),
        "next_keyframe_id": np.array(nxt, np.int64),
        "merged_into": _pairs(sorted(atlas.merged_into.items()), 2),
    }
    objects = objects or {}
    for m in atlas.maps:
        pre = f"m{m.id}_"
        arrays.update({pre + k: v for k, v in _keyframe_arrays(m).items()})
        arrays.update({pre + k: v for k, v in _grid_scan_arrays(m).items()})
        arrays.update({pre + k: v for k, v in _point_arrays(m.points).items()})
        arrays.update({pre + k: v for k, v in _graph_arrays(m).items()})
        if m.id in objects:
            arrays.update({pre + k: v for k, v in _object_arrays(objects[m.id]).items()})
    return arrays


def save_map(path: str | Path, atlas: Atlas, objects: ObjectLayer | Mapping[int, SavedObjectMap] | None = None,
             next_keyframe_id: int | None = None) -> None:
    """Write the map file (atomic, deterministic bytes); `objects`: the run's object layer, or object maps by map id
    (a loaded map's, `LoadedMap.objects`); `next_keyframe_id` defaults to one above the largest keyframe id.

    Top level: `format_version` (), `map_ids` (M,), `current_map_id` (), `next_keyframe_id` (), `merged_into` (E, 2)
    rows (merged-away map, the map it went into; such a map is stored empty).
    Per map, prefixed `m{map_id}_`:
    - keyframes, K rows in id order: `kf_ids`, `kf_stamps_ns`, `kf_poses` (K, 4, 4) camera-to-world,
      `kf_cameras` (K, 6) width, height, fx, fy, cx, cy, `kf_camera_dist` (K, D) distortion,
      `kf_n_keypoints` (K,); their N keypoints concatenated in keyframe order: `kp_px` (N, 2) float32,
      `kp_octaves` (N,) int8, `kp_descriptors` (N, 32) uint8, `kp_depths_m` (N,) float32,
      `kp_point_ids` (N,) int64, `kp_classes` (N,) int8, `kp_object_ids` (N,) int64;
    - from version 4, the depth scans of the keyframes that keep one (`core.map.grid_scan`), S keyframes in id
      order: `gs_kf_ids` (S,), `gs_counts` (S,); their P points concatenated: `gs_points_cam` (P, 3) float32,
      `gs_dynamic` (P,) bool, `gs_object_ids` (P,) int64;
    - map points, one row per point id of the `PointStore` (a culled point stays, flagged `bad`, with the
      store's gone row for its values):
      `pt_<column>` for each `PointStore.COLUMNS` (position, descriptor, normal, scale range, counters, class,
      object id, active, bad, ...), `pt_obs` (E, 3) rows (point id, keyframe id, keypoint index) in the
      point's observation order, `pt_size` ();
    - graph: `cov_keys` (C,), `cov` (E, 3) rows (keyframe, other, shared points); `parent` (E, 2) rows
      (child, parent); `children_keys`, `children` (E, 2) rows (parent, child); `removed_ids`,
      `removed_parents`, `removed_T_parent_kf` (R, 4, 4) (culled keyframes); `loop_edges` (E, 2);
      `origin_kf_id` ();
    - object map (when the run had an object layer for this map): `objects_json` (the `io.semantic_map_file`
      object-map document: objects, points, beliefs), `obj_anchor_ids` (A,), `obj_anchor_kf_ids` (A,),
      `obj_anchor_points_cam` (A, 3), `obj_next_sample_id` (); from version 3 the thumbnails of the keyframes the
      objects' evidence names (`core.objects.object_evidence`), `obj_thumb_kf_ids` (T,), `obj_thumbs` (T, 72, 96, 3)
      uint8 RGB.
    """
    maps = object_maps_of(objects) if isinstance(objects, ObjectLayer) else objects
    atomic_write_bytes(path, npz_bytes(map_arrays(atlas, maps, next_keyframe_id)))


def npz_bytes(arrays: Arrays) -> bytes:
    """An npz archive of `arrays` (members sorted, fixed dates, deflate): equal arrays give equal bytes."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for name in sorted(arrays):
            info = zipfile.ZipInfo(name + ".npy", date_time=_ZIP_DATE)
            info.compress_type = zipfile.ZIP_DEFLATED
            with zf.open(info, "w", force_zip64=True) as f:
                np.lib.format.write_array(f, np.asanyarray(arrays[name]), allow_pickle=False)
    return buf.getvalue()


def _keyframe_arrays(m: SlamMap) -> Arrays:
    kfs = [m.keyframes[k] for k in sorted(m.keyframes)]
    n_dist = max((len(k.camera.dist) for k in kfs), default=5)
    dist = np.zeros((len(kfs), n_dist))
    for i, k in enumerate(kfs):
        dist[i, : len(k.camera.dist)] = k.camera.dist

    def cat(name: str, dtype: Any, tail: tuple[int, ...] = ()) -> npt.NDArray[Any]:
        parts = [np.asarray(getattr(k, name), dtype).reshape((-1,) + tail) for k in kfs]
        return np.concatenate(parts) if parts else np.zeros((0,) + tail, dtype)

    return {
        "kf_ids": np.array([k.id for k in kfs], np.int64),
        "kf_stamps_ns": np.array([k.stamp_ns for k in kfs], np.int64),
        "kf_poses": np.array([k.T_world_cam for k in kfs], np.float64).reshape(-1, 4, 4),
        "kf_cameras": np.array([[k.camera.width, k.camera.height, k.camera.fx, k.camera.fy, k.camera.cx, k.camera.cy]
                                for k in kfs], np.float64).reshape(-1, 6),
        "kf_camera_dist": dist,
        "kf_n_keypoints": np.array([len(k) for k in kfs], np.int64),
        "kp_px": cat("keypoints_px", np.float32, (2,)),
        "kp_octaves": cat("octaves", np.int8),
        "kp_descriptors": cat("descriptors", np.uint8, (32,)),
        "kp_depths_m": cat("depths_m", np.float32),
        "kp_point_ids": cat("point_ids", np.int64),
        "kp_classes": cat("kp_classes", np.int8),
        "kp_object_ids": cat("object_ids", np.int64),
    }


def _grid_scan_arrays(m: SlamMap) -> Arrays:
    kfs = [m.keyframes[k] for k in sorted(m.keyframes) if m.keyframes[k].grid_scan is not None]
    scans = [k.grid_scan for k in kfs]
    return {
        "gs_kf_ids": np.array([k.id for k in kfs], np.int64),
        "gs_counts": np.array([len(s) for s in scans], np.int64),
        "gs_points_cam": np.concatenate([s.points_cam for s in scans] or [np.zeros((0, 3), np.float32)]),
        "gs_dynamic": np.concatenate([s.dynamic for s in scans] or [np.zeros(0, bool)]),
        "gs_object_ids": np.concatenate([s.object_ids for s in scans] or [np.zeros(0, np.int64)]),
    }


def _point_arrays(points: PointStore) -> Arrays:
    out: Arrays = {"pt_" + k: v for k, v in points.column_arrays().items()}
    out["pt_size"] = np.array(points.size, np.int64)
    rows = [(p, k, i) for p, obs in enumerate(points.observations[: points.size]) for k, i in obs.items()]
    out["pt_obs"] = np.array(rows, np.int64).reshape(-1, 3)
    return out


def _pairs(rows: list[tuple[int, ...]], width: int) -> npt.NDArray[np.int64]:
    return np.array(rows, np.int64).reshape(-1, width)


def _graph_arrays(m: SlamMap) -> Arrays:
    removed = list(m.removed.items())
    return {
        "cov_keys": np.array(list(m.covisibility), np.int64),
        "cov": _pairs([(k, o, w) for k, links in m.covisibility.items() for o, w in links.items()], 3),
        "parent": _pairs(list(m.parent.items()), 2),
        "children_keys": np.array(list(m.children), np.int64),
        "children": _pairs([(p, c) for p, cs in m.children.items() for c in sorted(cs)], 2),
        "removed_ids": np.array([k for k, _ in removed], np.int64),
        "removed_parents": np.array([r.parent_id for _, r in removed], np.int64),
        "removed_T_parent_kf": np.array([r.T_parent_kf for _, r in removed], np.float64).reshape(-1, 4, 4),
        "loop_edges": _pairs([(k, o) for k, os in m.loop_edges.items() for o in sorted(os)], 2),
        "origin_kf_id": np.array(m.origin_kf_id, np.int64),
    }


def _object_arrays(saved: SavedObjectMap) -> Arrays:
    from changing_slam_ros.io.semantic_map_file import object_map_to_dict

    doc = json.dumps(object_map_to_dict(saved.objects), separators=(",", ":"))
    w, h = THUMBNAIL_SIZE_PX
    thumb_ids = sorted(saved.thumbnails)
    return {
        "obj_thumb_kf_ids": np.array(thumb_ids, np.int64),
        "obj_thumbs": np.array([saved.thumbnails[k] for k in thumb_ids], np.uint8).reshape(-1, h, w, 3),
        "objects_json": np.array(doc),
        "obj_anchor_ids": np.asarray(saved.anchor_ids, np.int64),
        "obj_anchor_kf_ids": np.asarray(saved.anchor_kf_ids, np.int64),
        "obj_anchor_points_cam": np.asarray(saved.anchor_points_cam, np.float64).reshape(-1, 3),
        "obj_next_sample_id": np.array(saved.next_sample_id, np.int64),
    }


# --- load ------------------------------------------------------------------------------------------

def read_map_arrays(path: str | Path) -> Arrays:
    """The raw arrays of a map file, after the version check (MapFileError when unreadable or another version)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except FileNotFoundError as err:
        raise MapFileError(f"{path}: cannot read map (no such file)") from err
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as err:
        raise MapFileError(f"{path}: cannot read map ({type(err).__name__}: {err})") from err
    if "format_version" not in arrays:
        raise MapFileError(f"{path}: not a map file (no format_version)")
    version = int(np.asarray(arrays["format_version"]).reshape(-1)[0])
    if version not in READABLE_VERSIONS:
        hint = (" (written before multi-session support: keyframe poses and points only; run the sequence again"
                " to write a loadable map)" if version == 1 else "")
        raise MapFileError(f"{path}: map format version {version}, expected one of {list(READABLE_VERSIONS)}{hint}")
    return arrays


def load_map(path: str | Path) -> LoadedMap:
    """Read a map file written by `save_map` back into an Atlas and object maps."""
    return _Reader(read_map_arrays(path), str(path)).loaded()


def load_object_maps(path: str | Path) -> tuple[dict[int, SavedObjectMap], int]:
    """Only the object maps of a map file (map id -> object map) and its current map id; the keyframes and points
    are not rebuilt (the change report needs the objects and their thumbnails only)."""
    reader = _Reader(read_map_arrays(path), str(path))
    map_ids = reader.get("map_ids", "i", (None,)).tolist()
    objects = {int(i): reader._objects(int(i)) for i in map_ids if f"m{i}_objects_json" in reader.a}
    return objects, reader.scalar("current_map_id")


class _Reader:
    """Field-checked access to a map file's arrays; every error names the file and the field."""

    def __init__(self, arrays: Arrays, where: str) -> None:
        self.a = arrays
        self.where = where

    def fail(self, key: str, what: str) -> MapFileError:
        return MapFileError(f"{self.where}: {key}: {what}")

    def get(self, key: str, kind: str, shape: tuple[int | None, ...]) -> npt.NDArray[Any]:
        """Array `key` of dtype kind(s) `kind` ('i' integer, 'f' float, 'u' unsigned, 'b' bool, 'U' text) and
        `shape` (None = any length)."""
        if key not in self.a:
            raise self.fail(key, "missing")
        v = np.asarray(self.a[key])
        if v.dtype.kind not in kind and not (v.dtype.kind == "u" and "i" in kind):
            raise self.fail(key, f"expected dtype kind {kind!r}, got {v.dtype}")
        if v.ndim != len(shape) or any(s is not None and s != d for s, d in zip(shape, v.shape)):
            raise self.fail(key, f"expected shape {tuple('N' if s is None else s for s in shape)}, got {v.shape}")
        if v.dtype.kind == "f" and not np.isfinite(v).all():
            raise self.fail(key, "holds non-finite values")
        return v

    def scalar(self, key: str) -> int:
        return int(self.get(key, "i", ()))

    def loaded(self) -> LoadedMap:
        map_ids = self.get("map_ids", "i", (None,)).tolist()
        if len(map_ids) == 0 or map_ids != list(range(len(map_ids))):
            raise self.fail("map_ids", f"expected 0, 1, ..., got {map_ids}")
        current = self.scalar("current_map_id")
        if current not in map_ids:
            raise self.fail("current_map_id", f"{current} is not one of map_ids {map_ids}")
        atlas = Atlas()
        atlas.maps = [self._map(i) for i in map_ids]
        atlas.current = atlas.maps[current]
        merged = self.get("merged_into", "i", (None, 2))
        if not set(merged.reshape(-1).tolist()) <= set(map_ids):
            raise self.fail("merged_into", f"map ids outside map_ids {map_ids}")
        atlas.merged_into = {int(a): int(b) for a, b in merged.tolist()}
        objects = {i: self._objects(i) for i in map_ids if f"m{i}_objects_json" in self.a}
        used = [k for m in atlas.maps for k in (*m.keyframes, *m.removed)]
        nxt = self.scalar("next_keyframe_id")
        if used and nxt <= max(used):
            raise self.fail("next_keyframe_id", f"{nxt} is not above the largest keyframe id {max(used)}")
        return LoadedMap(atlas, objects, nxt)

    def _map(self, map_id: int) -> SlamMap:
        pre = f"m{map_id}_"
        m = SlamMap(map_id)
        m.points = self._points(pre)
        for kf in self._keyframes(pre, map_id, m.points.size):
            m.keyframes[kf.id] = kf
        self._observations(pre, m)
        self._graph(pre, m)
        if pre + "gs_kf_ids" in self.a:  # version 4
            self._grid_scans(pre, m)
        return m

    def _grid_scans(self, pre: str, m: SlamMap) -> None:
        ids = self.get(pre + "gs_kf_ids", "i", (None,))
        counts = self.get(pre + "gs_counts", "i", (len(ids),))
        unknown = sorted(set(ids.tolist()) - set(m.keyframes))
        if unknown or len(np.unique(ids)) != len(ids):
            raise self.fail(pre + "gs_kf_ids", f"unknown or repeated keyframe ids {unknown[:5]}")
        if (counts < 0).any():
            raise self.fail(pre + "gs_counts", "negative counts")
        n = int(counts.sum())
        pts = self.get(pre + "gs_points_cam", "f", (n, 3)).astype(np.float32)
        dyn = self.get(pre + "gs_dynamic", "b", (n,))
        obj = self.get(pre + "gs_object_ids", "i", (n,)).astype(np.int64)
        starts = np.concatenate([[0], np.cumsum(counts)])
        for i, k in enumerate(ids.tolist()):
            s = slice(int(starts[i]), int(starts[i + 1]))
            m.keyframes[k].grid_scan = GridScan(pts[s].copy(), dyn[s].copy(), obj[s].copy())

    def _keyframes(self, pre: str, map_id: int, n_points: int) -> list[Keyframe]:
        ids = self.get(pre + "kf_ids", "i", (None,))
        k = len(ids)
        if len(np.unique(ids)) != k:
            raise self.fail(pre + "kf_ids", "duplicated keyframe ids")
        stamps = self.get(pre + "kf_stamps_ns", "i", (k,))
        poses = self.get(pre + "kf_poses", "f", (k, 4, 4))
        cams = self.get(pre + "kf_cameras", "f", (k, 6))
        dist = self.get(pre + "kf_camera_dist", "f", (k, None))
        counts = self.get(pre + "kf_n_keypoints", "i", (k,))
        if (counts < 0).any():
            raise self.fail(pre + "kf_n_keypoints", "negative counts")
        n = int(counts.sum())
        cols = {
            "kp_px": self.get(pre + "kp_px", "f", (n, 2)).astype(np.float32),
            "kp_octaves": self.get(pre + "kp_octaves", "i", (n,)).astype(np.int8),
            "kp_descriptors": self.get(pre + "kp_descriptors", "u", (n, 32)).astype(np.uint8),
            "kp_depths_m": self.get(pre + "kp_depths_m", "f", (n,)).astype(np.float32),
            "kp_point_ids": self.get(pre + "kp_point_ids", "i", (n,)).astype(np.int64),
            "kp_classes": self.get(pre + "kp_classes", "i", (n,)).astype(np.int8),
            "kp_object_ids": self.get(pre + "kp_object_ids", "i", (n,)).astype(np.int64),
        }
        pids = cols["kp_point_ids"]
        if ((pids < -1) | (pids >= n_points)).any():
            raise self.fail(pre + "kp_point_ids", f"ids outside -1..{n_points - 1} (the stored points)")
        out = []
        starts = np.concatenate([[0], np.cumsum(counts)])
        for i in range(k):
            s = slice(int(starts[i]), int(starts[i + 1]))
            w, h, fx, fy, cx, cy = cams[i].tolist()
            if w <= 0 or h <= 0 or fx <= 0 or fy <= 0:
                raise self.fail(pre + "kf_cameras", f"row {i}: expected positive width, height, fx, fy")
            cam = CameraIntrinsics(int(w), int(h), fx, fy, cx, cy, tuple(float(d) for d in dist[i]))
            out.append(Keyframe(
                int(ids[i]), int(stamps[i]), poses[i].astype(np.float64), cam, cols["kp_px"][s].copy(),
                cols["kp_octaves"][s].copy(), cols["kp_descriptors"][s].copy(), cols["kp_depths_m"][s].copy(),
                cols["kp_point_ids"][s].copy(), cols["kp_classes"][s].copy(), cols["kp_object_ids"][s].copy(),
                map_id=map_id,
            ))
        return out

    def _points(self, pre: str) -> PointStore:
        size = self.scalar(pre + "pt_size")
        if size < 0:
            raise self.fail(pre + "pt_size", f"expected >= 0, got {size}")
        kinds = {"descriptors": "u", "active": "b", "bad": "b"}
        cols: dict[str, npt.NDArray[Any]] = {}
        template = PointStore(1)
        for name in PointStore.COLUMNS:
            tail = getattr(template, name).shape[1:]
            default = "f" if getattr(template, name).dtype.kind == "f" else "i"
            cols[name] = self.get(pre + "pt_" + name, kinds.get(name, default), (size, *tail))
        obs_rows = self.get(pre + "pt_obs", "i", (None, 3))
        if len(obs_rows) and ((obs_rows[:, 0] < 0) | (obs_rows[:, 0] >= size)).any():
            raise self.fail(pre + "pt_obs", f"point ids outside 0..{size - 1}")
        observations: list[dict[int, int]] = [{} for _ in range(size)]
        for p, k, i in obs_rows.tolist():
            observations[p][k] = i
        return PointStore.from_columns(cols, observations)

    def _observations(self, pre: str, m: SlamMap) -> None:
        """Every observation must name a stored keyframe whose keypoint holds the point, and back."""
        for p, obs in enumerate(m.points.observations):
            for k, i in obs.items():
                kf = m.keyframes.get(k)
                if kf is None or not 0 <= i < len(kf) or int(kf.point_ids[i]) != p:
                    raise self.fail(pre + "pt_obs", f"point {p} observed by keyframe {k} keypoint {i}, which "
                                    "is not a stored keyframe keypoint holding that point")
        for k, kf in m.keyframes.items():
            for i, p in enumerate(kf.point_ids.tolist()):
                if p >= 0 and m.points.observations[p].get(k) != i:
                    raise self.fail(pre + "kp_point_ids", f"keyframe {k} keypoint {i} holds point {p}, which "
                                    "has no such observation")

    def _graph(self, pre: str, m: SlamMap) -> None:
        known = set(m.keyframes)
        removed_ids = self.get(pre + "removed_ids", "i", (None,))
        r = len(removed_ids)
        parents = self.get(pre + "removed_parents", "i", (r,))
        Ts = self.get(pre + "removed_T_parent_kf", "f", (r, 4, 4))
        m.removed = {int(k): RemovedKeyframe(int(p), T.astype(np.float64)) for k, p, T in zip(removed_ids, parents, Ts)}
        for k, rem in m.removed.items():
            if rem.parent_id not in known and rem.parent_id not in m.removed:
                raise self.fail(pre + "removed_parents", f"culled keyframe {k} hangs off unknown keyframe {rem.parent_id}")

        def check(key: str, ids: npt.NDArray[Any], also_culled: bool = False) -> None:
            bad = sorted(set(ids.reshape(-1).tolist()) - known - (set(m.removed) if also_culled else set()))
            if bad:
                raise self.fail(key, f"unknown keyframe ids {bad[:5]}")

        cov_keys = self.get(pre + "cov_keys", "i", (None,))
        cov = self.get(pre + "cov", "i", (None, 3))
        check(pre + "cov_keys", cov_keys)
        check(pre + "cov", cov[:, :2])
        m.covisibility = {int(k): {} for k in cov_keys}
        for k, o, w in cov.tolist():
            if k not in m.covisibility:
                raise self.fail(pre + "cov", f"keyframe {k} is not in cov_keys")
            m.covisibility[k][o] = w
        parent = self.get(pre + "parent", "i", (None, 2))
        check(pre + "parent", parent)
        m.parent = {int(c): int(p) for c, p in parent.tolist()}
        ch_keys = self.get(pre + "children_keys", "i", (None,))
        children = self.get(pre + "children", "i", (None, 2))
        check(pre + "children_keys", ch_keys)
        check(pre + "children", children)
        m.children = {int(k): set() for k in ch_keys}
        for p, c in children.tolist():
            if p not in m.children:
                raise self.fail(pre + "children", f"keyframe {p} is not in children_keys")
            m.children[p].add(c)
        loops = self.get(pre + "loop_edges", "i", (None, 2))
        check(pre + "loop_edges", loops, also_culled=True)  # a loop's keyframe may be culled later
        m.loop_edges = {}
        for k, o in loops.tolist():
            m.loop_edges.setdefault(k, set()).add(o)
        m.origin_kf_id = self.scalar(pre + "origin_kf_id")
        if m.keyframes and m.origin_kf_id not in known:
            raise self.fail(pre + "origin_kf_id", f"{m.origin_kf_id} is not a stored keyframe")

    def _objects(self, map_id: int) -> SavedObjectMap:
        from changing_slam_ros.io.semantic_map_file import object_map_from_dict

        pre = f"m{map_id}_"
        key = pre + "objects_json"
        text = self.get(key, "U", ())
        try:
            doc = json.loads(str(text))
        except json.JSONDecodeError as err:
            raise self.fail(key, f"not valid JSON ({err})") from err
        objects = object_map_from_dict(doc, f"{self.where}: {key}")
        ids = self.get(pre + "obj_anchor_ids", "i", (None,))
        kfs = self.get(pre + "obj_anchor_kf_ids", "i", (len(ids),))
        pts = self.get(pre + "obj_anchor_points_cam", "f", (len(ids), 3))
        nxt = self.scalar(pre + "obj_next_sample_id")
        if nxt > -2:
            raise self.fail(pre + "obj_next_sample_id", f"expected <= -2, got {nxt}")
        thumbs: dict[int, npt.NDArray[np.uint8]] = {}
        if pre + "obj_thumb_kf_ids" in self.a:  # version 3
            t_ids = self.get(pre + "obj_thumb_kf_ids", "i", (None,))
            w, h = THUMBNAIL_SIZE_PX
            imgs = self.get(pre + "obj_thumbs", "u", (len(t_ids), h, w, 3))
            if imgs.dtype != np.uint8:
                raise self.fail(pre + "obj_thumbs", f"expected uint8, got {imgs.dtype}")
            thumbs = {int(k): imgs[i].copy() for i, k in enumerate(t_ids.tolist())}
        return SavedObjectMap(objects, ids.astype(np.int64), kfs.astype(np.int64), pts.astype(np.float64), nxt, thumbs)
