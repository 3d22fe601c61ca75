"""The "what changed" report on disk: JSON, and the object maps it is computed from.

Layout (version 1):
    format: "changing_slam_ros change report", version: 1, before / after: where each map came from,
    counts: {moved, removed, added, replaced, unchanged},
    changes: [{kind, class_name, from_m: [x, y, z] | null, to_m | null, distance_m | null,
               before, after, before_later: <object> | null}, ...],
    unchanged: [{before_id, after_id, class_name, distance_m}, ...],
    withdrawn: [{before_id, class_name}, ...] (earlier objects the continued map dropped: pictures, merged)
An <object> is {id, class_id, class_name, centroid_m, box_size_m, belief, n_points, present, first_keyframe,
last_seen_keyframe, belief_history: [[keyframe id, belief, reason], ...], seen_keyframes: [...]}, map frame,
metres. `read_report_objects` reads the objects of a map file (`map.npz`, with thumbnails), of an object-map
JSON file (`object_map.json`) or of a semantic-map file (JSON / YAML, as `object_map` saves it: no evidence
beyond the first and last sighting). Writes are atomic.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.objects.change_report import ChangeReport
from changing_slam_ros.core.objects.map_object import MapObject
from changing_slam_ros.core.objects.object_evidence import (
    EvidenceConfig, ObjectEvidence, evidence_of, evidence_of_semantic,
)
from changing_slam_ros.core.objects.semantic_map import SemanticObject
from changing_slam_ros.errors import MapFileError
from changing_slam_ros.io.atomic import atomic_write_text

FORMAT = "changing_slam_ros change report"
VERSION = 1


@dataclass
class ReportObjects:
    """The objects of one map for the report (MapObjects, or semantic-map records when the file holds only
    those) and the thumbnails of its keyframes (id -> (72, 96, 3) uint8)."""

    objects: list[MapObject]
    thumbnails: dict[int, npt.NDArray[np.uint8]] = field(default_factory=dict)
    semantic: list[SemanticObject] = field(default_factory=list)

    def evidence(self, config: EvidenceConfig) -> list[ObjectEvidence]:
        return [evidence_of(o, config) for o in self.objects] + [evidence_of_semantic(o, config) for o in self.semantic]


def read_report_objects(path: str | Path, map_id: int | None = None) -> ReportObjects:
    """The objects of `map_id` (default: the current map) of a map file, or of an object-map or semantic-map file
    (told apart by their `format` field)."""
    from changing_slam_ros.io.map_file import load_object_maps
    from changing_slam_ros.io.semantic_map_file import FORMAT, read_object_map, read_semantic_map

    p = Path(path)
    if p.suffix.lower() in (".yaml", ".yml"):
        return ReportObjects([], semantic=list(read_semantic_map(p).objects))
    if p.suffix.lower() == ".json":
        try:
            is_semantic = json.loads(p.read_text()).get("format") == FORMAT
        except (OSError, json.JSONDecodeError, AttributeError):
            is_semantic = False  # the reader below names the problem
        if is_semantic:
            return ReportObjects([], semantic=list(read_semantic_map(p).objects))
        return ReportObjects(read_object_map(p))
    maps, current = load_object_maps(p)
    wanted = current if map_id is None else int(map_id)
    if wanted not in maps:
        raise MapFileError(f"{p}: no object map for map {wanted} (maps with objects: {sorted(maps)})")
    saved = maps[wanted]
    return ReportObjects(saved.objects, dict(saved.thumbnails))


def evidence_to_dict(e: ObjectEvidence | None) -> dict[str, Any] | None:
    if e is None:
        return None
    return {
        "id": e.id, "class_id": e.class_id, "class_name": e.class_name, "centroid_m": list(e.centroid_w),
        "box_size_m": list(e.box_size_m), "belief": e.belief, "n_points": e.n_points, "present": e.present,
        "first_keyframe": e.first_keyframe, "last_seen_keyframe": e.last_seen_keyframe,
        "belief_history": [[k, b, r] for k, b, r in e.belief_history], "seen_keyframes": list(e.seen_keyframes),
    }


def change_report_to_dict(report: ChangeReport, before: str = "", after: str = "") -> dict[str, Any]:
    """The JSON document of a report; `before` / `after` say where the two maps came from."""
    changes = []
    for c in report.changes:
        ref = c.after if c.after is not None else c.before
        assert ref is not None
        changes.append({
            "kind": c.kind.value, "class_name": ref.class_name if c.before is None else c.before.class_name,
            "from_m": None if c.before is None else list(c.before.centroid_w),
            "to_m": None if c.after is None else list(c.after.centroid_w),
            "distance_m": c.distance_m, "before": evidence_to_dict(c.before), "after": evidence_to_dict(c.after),
            "before_later": evidence_to_dict(c.before_later),
        })
    unchanged = [{"before_id": b.id, "after_id": a.id, "class_name": b.class_name,
                  "distance_m": float(np.linalg.norm(np.subtract(a.centroid_w, b.centroid_w)))}
                 for b, a in report.unchanged]
    withdrawn = [{"before_id": b.id, "class_name": b.class_name} for b in report.withdrawn]
    return {"format": FORMAT, "version": VERSION, "before": before, "after": after, "counts": report.counts(),
            "changes": changes, "unchanged": unchanged, "withdrawn": withdrawn}


def write_change_report(path: str | Path, report: ChangeReport, before: str = "", after: str = "") -> None:
    """Write the report's JSON document to `path` atomically."""
    atomic_write_text(Path(path), json.dumps(change_report_to_dict(report, before, after), indent=1) + "\n")


def summary_lines(report: ChangeReport) -> list[str]:
    """One line per change, for a terminal: `moved chair #1 -> #4: 2.03 m`, `removed potted plant #2`, ..."""
    out = []
    for c in report.changes:
        b, a = c.before, c.after
        if b is not None and a is not None:
            what = f"{b.class_name} #{b.id}" + (f" -> {a.class_name}" if a.class_name != b.class_name else "")
            out.append(f"{c.kind.value} {what} #{a.id}: {c.distance_m:.2f} m")
        elif b is not None:
            out.append(f"{c.kind.value} {b.class_name} #{b.id} (belief now "
                       f"{'-' if c.before_later is None else f'{c.before_later.belief:.2f}'})")
        elif a is not None:
            out.append(f"{c.kind.value} {a.class_name} #{a.id} (belief {a.belief:.2f})")
    return out
