"""Ground truth per lap of the changing-room family (`changing_truth.json`, written beside the render).

Layout: `format`, `seed`, `with_changes`, `params` (what the seed drew), `initial` (the objects at the start),
`laps` (per lap: start and end time and every object present at its end: name, class, pose [x, y, z, yaw],
world-axis-aligned box, extent in its own frame, support floor / table / wall), `changes` (time, the lap it
happens in, kind, objects, from and to poses, distance, turn),
`wall_items` (pictures and objects hung on walls: `is_object` false for a photo, true for a clock or a screen)
and `structure` (classed furniture that the object layer treats as fixed background: tables).
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from changing_slam_ros.sim.actors import coco_name

if TYPE_CHECKING:
    from changing_slam_ros.sim.random_changing import ChangingRoom, Item
    from changing_slam_ros.sim.scenarios import Scenario

F64 = npt.NDArray[np.float64]
TRUTH_FORMAT = "changing_slam_ros changing-room truth v1"
TRUTH_FILE = "changing_truth.json"


def _r(v: Any, nd: int = 4) -> list[float]:
    return [round(float(x), nd) for x in np.asarray(v, float).ravel()]


def _yaw(T: F64) -> float:
    return float(np.arctan2(T[1, 0], T[0, 0]))


def _pose4(T: F64 | None) -> list[float] | None:
    return None if T is None else _r([T[0, 3], T[1, 3], T[2, 3], _yaw(T)])


def item_box_w(item: "Item", T: F64) -> tuple[F64, F64]:
    """World-axis-aligned bounds (min (3,), max (3,)) of `item` at pose `T` (4, 4)."""
    corners = np.concatenate([p.corners_m() for p in item.parts])
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    box = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    pts = box @ T[:3, :3].T + T[:3, 3]
    return pts.min(axis=0), pts.max(axis=0)


def _object_row(item: "Item", T: F64) -> dict[str, Any]:
    lo, hi = item_box_w(item, T)
    corners = np.concatenate([p.corners_m() for p in item.parts])
    return {"name": item.name, "kind": item.kind, "class_id": item.class_id, "class_name": coco_name(item.class_id),
            "support": item.support, "pose": _pose4(T), "box_min_w": _r(lo), "box_max_w": _r(hi),
            "centre_w": _r((lo + hi) / 2), "extent_m": _r(corners.max(axis=0) - corners.min(axis=0))}


def truth_document(room: "ChangingRoom", scenario: "Scenario", with_changes: bool) -> str:
    """The JSON text of `changing_truth.json` for `scenario` (built from `room`)."""
    actors = {a.name: a for a in scenario.actors}
    n_frames = scenario.n_frames()
    t_last = (n_frames - 1) / scenario.fps

    def present(t_s: float) -> list[dict[str, Any]]:
        rows = []
        for name, actor in actors.items():
            T = actor.track.pose_at(t_s)
            if T is not None and room.items[name].class_id >= 0:
                rows.append(_object_row(room.items[name], T))
        return rows

    laps = []
    for k in range(room.n_laps):
        t0, t1 = k * room.lap_s, min((k + 1) * room.lap_s, t_last)
        laps.append({"lap": k, "t_start_s": round(t0, 4), "t_end_s": round(t1, 4), "objects": present(t1)})
    changes = []
    for c in room.changes if with_changes else ():
        moves = []
        for name, new in c.to_poses.items():
            old = room.initial.get(name)
            row: dict[str, Any] = {"object": name, "class_name": coco_name(room.items[name].class_id),
                                   "from": _pose4(old), "to": _pose4(new)}
            if old is not None and new is not None:
                row["distance_m"] = round(float(np.linalg.norm(new[:2, 3] - old[:2, 3])), 4)
                turn = (_yaw(new) - _yaw(old) + np.pi) % (2 * np.pi) - np.pi
                row["turn_deg"] = round(float(np.degrees(turn)), 2)
            moves.append(row)
        changes.append({"t_s": round(c.t_s, 4), "lap": min(int(c.t_s // room.lap_s), room.n_laps - 1), "kind": c.kind, "object": c.actor, "other": c.other,
                        "objects": moves})
    wall_items: list[dict[str, Any]] = []
    for p in room.pictures:
        n = np.asarray(p.normal_w)
        along = np.array([-n[1], n[0], 0.0])
        half = 0.5 * p.size_m[0] * np.abs(along) + np.array([0.0, 0.0, 0.5 * p.size_m[1]]) + 0.006 * np.abs(n)
        c = np.asarray(p.centre_w)
        wall_items.append({"name": p.name, "wall": p.wall, "is_object": False, "texture": p.texture,
                           "depicts": p.depicts, "centre_w": _r(c), "size_m": _r(p.size_m), "normal_w": _r(n),
                           "box_min_w": _r(c - half), "box_max_w": _r(c + half)})
    for name, item in room.items.items():
        T = room.initial.get(name)
        if item.support == "wall" and T is not None:
            wall_items.append({**_object_row(item, T), "is_object": True})
    structure = [_object_row(room.items[n], T) for n, T in room.initial.items()
                 if T is not None and room.items[n].class_id == 60]
    doc = {"format": TRUTH_FORMAT, "scenario": scenario.name, "seed": room.seed, "with_changes": with_changes,
           "frames": n_frames, "fps": scenario.fps, "params": room.params, "initial": present(0.0), "laps": laps, "changes": changes,
           "wall_items": wall_items, "structure": structure}
    return json.dumps(doc, indent=1) + "\n"
