"""Moving objects and their trajectories on disk: `moving_objects.json` plus one TUM file per object.

Layout inside a run's output folder:
- `moving_objects.json`: `{"format": FORMAT, "frame": ..., "objects": [{"id", "class_id", "first_stamp_ns",
  "last_stamp_ns", "poses", "points", "trajectory"}]}`; `class_id` is the COCO 0-based id, -1 for a
  class-agnostic target; `trajectory` is the path of the object's TUM file relative to the folder.
- `moving_objects/object_<id>.txt`: the object-to-world poses (TUM: stamp tx ty tz qx qy qz qw).
Every file is written atomically (the JSON last, so a reader never sees it name a missing file).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from changing_slam_ros.core.movers.object_tracking import MovingObjectTrack
from changing_slam_ros.errors import EvalError
from changing_slam_ros.io.atomic import atomic_write_text
from changing_slam_ros.io.tum_trajectory import read_tum_trajectory, write_tum_trajectory

FORMAT = "changing_slam_ros moving objects v1"
INDEX_NAME = "moving_objects.json"
FOLDER_NAME = "moving_objects"


def write_moving_objects(out_dir: Path, tracks: list[MovingObjectTrack]) -> dict[str, Any]:
    """Write the tracks' TUM files and the index into `out_dir`; returns a summary for metrics.json."""
    out_dir = Path(out_dir)
    (out_dir / FOLDER_NAME).mkdir(parents=True, exist_ok=True)
    entries: list[dict[str, Any]] = []
    for track in sorted(tracks, key=lambda t: t.object_id):
        rel = f"{FOLDER_NAME}/object_{track.object_id}.txt"
        write_tum_trajectory(out_dir / rel, track.trajectory())
        entries.append({
            "id": track.object_id, "class_id": track.class_id, "first_stamp_ns": track.first_stamp_ns,
            "last_stamp_ns": track.last_stamp_ns, "poses": len(track.stamps_ns), "points": track.n_points,
            "trajectory": rel,
        })
    doc = {
        "format": FORMAT,
        "frame": "T_world_obj in the SLAM world (the map frame); class_id -1 = class-agnostic target",
        "objects": entries,
    }
    index = out_dir / INDEX_NAME
    atomic_write_text(index, json.dumps(doc, indent=1) + "\n")
    return {"file": INDEX_NAME, "objects": len(entries), "poses": sum(e["poses"] for e in entries)}


def read_moving_objects(index: Path) -> list[MovingObjectTrack]:
    """Read `moving_objects.json` and its TUM files; EvalError names the file and field that is wrong."""
    index = Path(index)
    try:
        doc = json.loads(index.read_text())
    except (OSError, ValueError) as err:
        raise EvalError(f"{index}: cannot read moving objects ({err})") from err
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise EvalError(f"{index}: format: expected {FORMAT!r}")
    objects = doc.get("objects")
    if not isinstance(objects, list):
        raise EvalError(f"{index}: objects: expected a list")
    tracks = []
    for k, entry in enumerate(objects):
        where = f"{index}: objects[{k}]"
        try:
            obj_id, class_id, rel, n_points = int(entry["id"]), int(entry["class_id"]), str(entry["trajectory"]), int(entry["points"])
        except (KeyError, TypeError, ValueError) as err:
            raise EvalError(f"{where}: missing or invalid field ({err})") from err
        traj = read_tum_trajectory(index.parent / rel)
        stamps = np.round(traj.stamps_s * 1e9).astype(np.int64)
        if len(stamps) != int(entry.get("poses", len(stamps))):
            raise EvalError(f"{where}: poses: {entry.get('poses')} in the index, {len(stamps)} in {rel}")
        tracks.append(MovingObjectTrack(obj_id, class_id, stamps, traj.poses(), n_points))
    return tracks
