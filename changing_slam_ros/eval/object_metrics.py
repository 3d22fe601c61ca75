"""Object-map accuracy against the simulator's ground truth (`objects.json`, see `sim/writer.py`).

Ground truth at a chosen frame (the last one by default): every object with a COCO class that is
present there, its world-axis-aligned box (the 8 corners of its own box moved by T_world_object) and the
box centre as its position. Estimated objects (a semantic map) are matched one to one, greedily by
increasing distance, to present ground-truth objects of the same class whose box centre is within
`max_distance_m` (0.3 m) of the estimated centroid (or, with `match_on="box_center"`, of the estimated
box centre: a large object seen from one side has its point centroid on that side, while the robust
box centre sits nearer the middle). Per match: centroid error (estimated centroid to
ground-truth box centre), box-centre error, and the 3D IoU of the two axis-aligned boxes.

Matching, surface centroids, structure classes and the stale / spurious / missed split: `evaluate_objects`.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.se3 import quat_to_rot
from changing_slam_ros.core.objects.semantic_map import SemanticObject
from changing_slam_ros.errors import EvalError

F64 = npt.NDArray[np.float64]
DEFAULT_MAX_DISTANCE_M = 0.3


@dataclass(frozen=True)
class GroundTruthObject:
    """One simulated object: per-frame world boxes (min (3,), max (3,)) or None while absent."""

    id: int
    name: str
    class_id: int
    class_name: str
    moving: bool
    boxes_w: tuple[tuple[F64, F64] | None, ...]

    def box_at(self, frame: int) -> tuple[F64, F64] | None:
        return self.boxes_w[frame]


@dataclass(frozen=True)
class GroundTruthObjects:
    scenario: str
    stamps_ns: tuple[int, ...]
    objects: tuple[GroundTruthObject, ...]


def world_box(box_min_m: Sequence[float], box_max_m: Sequence[float], pose_row: Sequence[float]) -> tuple[F64, F64]:
    """World-axis-aligned bounds of an object box given [tx, ty, tz, qx, qy, qz, qw] of T_world_object."""
    lo, hi = np.asarray(box_min_m, float), np.asarray(box_max_m, float)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    r = quat_to_rot(np.asarray(pose_row[3:7], float))
    pts = corners @ r.T + np.asarray(pose_row[:3], float)
    return pts.min(axis=0), pts.max(axis=0)


def load_ground_truth_objects(path: str | Path) -> GroundTruthObjects:
    """Read a simulator `objects.json`; EvalError names the file and field on malformed input."""
    p = Path(path)
    try:
        doc = json.loads(p.read_text())
    except OSError as err:
        raise EvalError(f"{p}: cannot read objects ground truth ({err.strerror})") from err
    except json.JSONDecodeError as err:
        raise EvalError(f"{p}: not valid JSON ({err})") from err
    try:
        if not str(doc["format"]).startswith("changing_slam_ros sim objects"):
            raise EvalError(f"{p}: format: expected 'changing_slam_ros sim objects v1', got {doc['format']!r}")
        stamps = tuple(int(s) for s in doc["stamps_ns"])
        objects = []
        for i, o in enumerate(doc["objects"]):
            if len(o["poses"]) != len(stamps):
                raise EvalError(f"{p}: objects[{i}].poses: {len(o['poses'])} poses for {len(stamps)} stamps")
            boxes = tuple(None if row is None else world_box(o["box_min_m"], o["box_max_m"], row) for row in o["poses"])
            objects.append(GroundTruthObject(int(o["id"]), str(o["name"]), int(o["class_id"]), str(o["class_name"]),
                                             bool(o.get("moving", False)), boxes))
    except (KeyError, TypeError, ValueError) as err:
        raise EvalError(f"{p}: malformed objects ground truth ({type(err).__name__}: {err})") from err
    return GroundTruthObjects(str(doc.get("scenario", "")), stamps, tuple(objects))


def box_iou_3d(min_a: F64, max_a: F64, min_b: F64, max_b: F64) -> float:
    """Intersection over union of two axis-aligned boxes given by corners (3,)."""
    inter = np.clip(np.minimum(max_a, max_b) - np.maximum(min_a, min_b), 0.0, None)
    vi = float(np.prod(inter))
    va = float(np.prod(np.clip(np.asarray(max_a) - min_a, 0.0, None)))
    vb = float(np.prod(np.clip(np.asarray(max_b) - min_b, 0.0, None)))
    union = va + vb - vi
    return vi / union if union > 0.0 else 0.0


@dataclass(frozen=True)
class ObjectMatch:
    estimate_id: int
    gt_name: str
    class_id: int
    centroid_error_m: float
    box_center_error_m: float
    iou: float
    surface_centroid_error_m: float = float("nan")  # against the visible-surface centroid, when given


@dataclass(frozen=True)
class ObjectMetrics:
    """Matches, missed ground truth (names), stale estimates (estimate id, name of the object that left),
    spurious estimates (ids) and the present fixed-background objects left unmatched (`structure`, names)."""

    matches: tuple[ObjectMatch, ...]
    missed: tuple[str, ...]
    stale: tuple[tuple[int, str], ...]
    spurious: tuple[int, ...]
    frame: int
    structure: tuple[str, ...] = ()

    @property
    def mean_centroid_error_m(self) -> float:
        return float(np.mean([m.centroid_error_m for m in self.matches])) if self.matches else float("nan")

    @property
    def mean_iou(self) -> float:
        return float(np.mean([m.iou for m in self.matches])) if self.matches else float("nan")

    @property
    def mean_surface_centroid_error_m(self) -> float:
        errs = [m.surface_centroid_error_m for m in self.matches if np.isfinite(m.surface_centroid_error_m)]
        return float(np.mean(errs)) if errs else float("nan")

    def to_dict(self) -> dict[str, Any]:
        return {
            "frame": self.frame, "matched": len(self.matches), "missed": list(self.missed),
            "stale": [{"estimate_id": e, "gt_name": n} for e, n in self.stale], "spurious": list(self.spurious),
            "structure": list(self.structure),
            "mean_centroid_error_m": self.mean_centroid_error_m, "mean_iou": self.mean_iou,
            "mean_surface_centroid_error_m": self.mean_surface_centroid_error_m,
            "matches": [m.__dict__ for m in self.matches],
        }


def evaluate_objects(estimates: Iterable[SemanticObject], gt: GroundTruthObjects, frame: int = -1,
                     max_distance_m: float = DEFAULT_MAX_DISTANCE_M,
                     only_names: Iterable[str] | None = None, match_on: str = "centroid",
                     surface_centroids: Mapping[str, F64] | None = None,
                     structure_class_ids: Iterable[int] | None = None) -> ObjectMetrics:
    """Match `estimates` to the ground truth present at `frame` (negative counts from the end).
    `surface_centroids`: ground-truth name -> visible-surface centroid (3,) (see below).
    `structure_class_ids`: fixed-background classes, unmatched ones go to `structure` (None: the dynamic
    stage's default `fixed_class_ids`; () counts them as missed).

    The ground-truth box centre is the centre of the object's volume, while a MapObject's centroid is the mean
    of surface points the camera saw: an object seen from one side only has its point centroid on that side even
    with perfect points (a 44 cm plant seen from the front: 17 cm). For a fair comparison pass
    `surface_centroids` (ground-truth name -> the mean of the object's *visible* surface at its final place, see
    `visible_surface_centroids`: its mask pixels back-projected with the simulator's depth and the ground-truth
    camera pose) and each match also reports `surface_centroid_error_m`, the estimated centroid against the
    same quantity in ground truth. Matching itself stays on the box centre.

    Fixed-background classes (`structure_class_ids`, by default the dynamic stage's `fixed_class_ids`: bed,
    dining table, toilet, oven, sink, refrigerator) are structure by our design: the dynamic filter hands their
    boxes to nobody, so they never become MapObjects and their points are ordinary map points. A present
    ground-truth object of such a class that no estimate matches is listed in `structure`, not in `missed`, so
    "every present object matched" means every present object the layer is built to map; an estimate that does
    match one (a config without the class in `fixed_class_ids`) still counts as a match.

    Unmatched estimates are split into `stale` (within `max_distance_m` of a place a same-class object
    occupied earlier in the sequence and has since left: a removed or moved object wrongly kept) and
    `spurious` (anything else). Present ground-truth objects left unmatched are `missed` (this includes
    objects the camera never saw; pass `only_names` to restrict the ground truth).
    """
    if match_on not in ("centroid", "box_center"):
        raise EvalError(f"match_on: expected 'centroid' or 'box_center', got {match_on!r}")
    n = len(gt.stamps_ns)
    if n == 0:
        raise EvalError(f"objects ground truth of {gt.scenario!r} has no frames")
    f = frame if frame >= 0 else n + frame
    if not 0 <= f < n:
        raise EvalError(f"frame {frame}: ground truth has {n} frames")
    names = None if only_names is None else set(only_names)
    pool = [o for o in gt.objects if o.class_id >= 0 and not o.moving and (names is None or o.name in names)]
    present = [(o, o.box_at(f)) for o in pool if o.box_at(f) is not None]
    est = list(estimates)
    pairs = []
    for i, e in enumerate(est):
        c = np.asarray(e.centroid_w if match_on == "centroid" else e.box_center_w)
        for j, (o, box) in enumerate(present):
            assert box is not None
            d = float(np.linalg.norm(c - (box[0] + box[1]) / 2.0))
            if o.class_id == e.class_id and d <= max_distance_m:
                pairs.append((d, i, j))
    used_e: set[int] = set()
    used_g: set[int] = set()
    matches = []
    for d, i, j in sorted(pairs):
        if i in used_e or j in used_g:
            continue
        used_e.add(i)
        used_g.add(j)
        o, box = present[j]
        assert box is not None
        e = est[i]
        centre = (box[0] + box[1]) / 2.0
        surface = None if surface_centroids is None else surface_centroids.get(o.name)
        matches.append(ObjectMatch(
            e.id, o.name, o.class_id, float(np.linalg.norm(np.asarray(e.centroid_w) - centre)),
            float(np.linalg.norm(np.asarray(e.box_center_w) - centre)),
            box_iou_3d(e.box_min_w, e.box_max_w, box[0], box[1]),
            float("nan") if surface is None else float(np.linalg.norm(np.asarray(e.centroid_w) - surface)),
        ))
    structure_ids = set(default_structure_class_ids() if structure_class_ids is None else structure_class_ids)
    unmatched = [present[j][0] for j in range(len(present)) if j not in used_g]
    missed = tuple(o.name for o in unmatched if o.class_id not in structure_ids)
    structure = tuple(o.name for o in unmatched if o.class_id in structure_ids)
    stale, spurious = [], []
    for i, e in enumerate(est):
        if i in used_e:
            continue
        left = _left_place(e, pool, f, max_distance_m, match_on)
        if left is not None:
            stale.append((e.id, left))
        else:
            spurious.append(e.id)
    return ObjectMetrics(tuple(sorted(matches, key=lambda m: m.estimate_id)), missed, tuple(stale), tuple(spurious), f,
                         structure)


def default_structure_class_ids() -> tuple[int, ...]:
    """The dynamic stage's default fixed-background classes (`DynamicConfig.fixed_class_ids`)."""
    from changing_slam_ros.core.dynamic.dynamic_filter import DynamicConfig

    return tuple(DynamicConfig().fixed_class_ids)


def _left_place(e: SemanticObject, pool: list[GroundTruthObject], frame: int, max_distance_m: float,
                match_on: str) -> str | None:
    """Name of a same-class object that stood within reach of `e` at some earlier frame and not at `frame`."""
    c = np.asarray(e.centroid_w if match_on == "centroid" else e.box_center_w)
    for o in pool:
        if o.class_id != e.class_id:
            continue
        now = o.box_at(frame)
        if now is not None and np.linalg.norm(c - (now[0] + now[1]) / 2.0) <= max_distance_m:
            continue
        for k in range(frame):
            box = o.box_at(k)
            if box is not None and np.linalg.norm(c - (box[0] + box[1]) / 2.0) <= max_distance_m:
                return o.name
    return None


@dataclass(frozen=True)
class SurfaceView:
    """One frame for `visible_surface_centroids`: instance ids (H, W) (0 = room), depth (H, W) metres (0 = none),
    the ground-truth T_world_cam (4, 4) and the camera's `backproject(px (N, 2), depth (N,)) -> (N, 3)`."""

    instance_ids: npt.NDArray[np.integer]
    depth_m: npt.NDArray[np.floating]
    T_world_cam: F64
    backproject: Any


def visible_surface_centroids(gt: GroundTruthObjects, views: Iterable[tuple[int, SurfaceView]],
                              max_pixels_per_view: int = 400) -> dict[str, F64]:
    """Ground-truth name -> mean world position (3,) of the object's surface seen in `views` ((frame index,
    view) pairs) while it stood at its place of the last frame (the place the semantic map is evaluated at).
    Each view contributes at most `max_pixels_per_view` pixels per object (evenly subsampled), so that close-up
    frames do not outweigh the rest, as the layer's fixed number of depth samples per box does."""
    n = len(gt.stamps_ns)
    final = {o.id: o.box_at(n - 1) for o in gt.objects if o.class_id >= 0 and not o.moving}
    sums: dict[int, F64] = {}
    counts: dict[int, int] = {}
    for frame, view in views:
        ids = np.asarray(view.instance_ids)
        for oid, box_final in final.items():
            if box_final is None:
                continue
            o = next(g for g in gt.objects if g.id == oid)
            now = o.box_at(frame)
            if now is None or not (np.allclose(now[0], box_final[0]) and np.allclose(now[1], box_final[1])):
                continue
            vv, uu = np.nonzero((ids == oid) & (np.asarray(view.depth_m) > 0))
            if len(vv) == 0:
                continue
            step = max(1, int(np.ceil(len(vv) / max_pixels_per_view)))
            vv, uu = vv[::step], uu[::step]
            pts_c = view.backproject(np.c_[uu, vv].astype(np.float64), np.asarray(view.depth_m, np.float64)[vv, uu])
            pts_w = pts_c @ view.T_world_cam[:3, :3].T + view.T_world_cam[:3, 3]
            sums[oid] = sums.get(oid, np.zeros(3)) + pts_w.sum(axis=0)
            counts[oid] = counts.get(oid, 0) + len(pts_w)
    names = {o.id: o.name for o in gt.objects}
    return {names[oid]: sums[oid] / counts[oid] for oid in sums}
