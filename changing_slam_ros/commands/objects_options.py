"""Changing-scene options and outputs of `changing-slam run` (a helper of `commands/run.py`, not a subcommand).

    --objects / --no-objects   the object layer (MapObjects, persistence beliefs, inactive points)
                               on (default, or `objects.enabled`) / off (every map point stays active)

Config section read: `objects:` (`core.objects.object_layer.ObjectLayerConfig`: `enabled` plus `ObjectMapConfig`).
Outputs (`write_object_outputs`): the semantic map (json, png), the object map, and object metrics against the
simulator's ground truth. Every accepted loop is logged (`LoopRecord`); with ground truth each gets its
relative-pose error (`loop_error`) and is counted wrong above `WRONG_LOOP_M` / `WRONG_LOOP_DEG`.
"""

from __future__ import annotations

import argparse
import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.objects.object_layer import ObjectLayer, object_layer_config
from changing_slam_ros.core.geometry.se3 import invert, quat_to_rot, rotation_angle_rad
from changing_slam_ros.core.objects.semantic_map import build_semantic_map
from changing_slam_ros.core.geometry.trajectory import Trajectory
from changing_slam_ros.eval.object_alignment import aligned_objects, aligned_planes, trajectory_alignment

F64 = npt.NDArray[np.float64]
# the map frame is the first camera's optical frame (x right, y down, z forward); the top view looks down its -y
T_LEVEL_MAP = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
# a loop whose relative pose is off by more than this is wrong: the changing scenes' bound (10 cm / 5 degrees)
WRONG_LOOP_M = 0.10
WRONG_LOOP_DEG = 5.0
MAX_STAMP_GAP_S = 0.02


def add_object_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("changing scenes (object layer)")
    group.add_argument("--objects", action=argparse.BooleanOptionalAction, default=None,
                       help="object layer: MapObjects, persistence beliefs, inactive points (default on, or objects.enabled)")


def object_layer_setup(args: argparse.Namespace, data: dict[str, Any], where: str) -> ObjectLayer:
    """The run's object layer from the `objects:` section and --objects/--no-objects."""
    cfg = object_layer_config(data.get("objects"), f"{where}: objects")
    if getattr(args, "objects", None) is not None:
        cfg = dataclasses.replace(cfg, enabled=bool(args.objects))
    return ObjectLayer(cfg)


@dataclass(frozen=True)
class LoopRecord:
    """One accepted loop: keyframe stamps (ns) and the verified pose of the query camera in the match camera (4, 4)."""

    query_stamp_ns: int
    match_stamp_ns: int
    T_match_query: F64


@dataclass
class LoopLog:
    """Accepted loops of a run, recorded right after each correction."""

    loops: list[LoopRecord] = field(default_factory=list)

    def record(self, closing: Any, system: Any) -> None:
        """Read `closing.last_correction` (a `SlamMapLoopClosing`) after a frame that corrected the map."""
        corr = getattr(closing, "last_correction", None)
        if corr is None:
            return
        m = system.atlas.maps[corr.map_id]
        q, mt = m.keyframes.get(corr.query_kf_id), m.keyframes.get(corr.match_kf_id)
        if q is None or mt is None:
            return
        self.loops.append(LoopRecord(int(q.stamp_ns), int(mt.stamp_ns), np.array(corr.T_match_query, float)))

    def evaluate(self, gt: Trajectory | None) -> dict[str, Any]:
        """metrics.json `loops`: every loop with its error against ground truth (when given) and the wrong count."""
        rows: list[dict[str, Any]] = []
        n_wrong = 0
        for rec in self.loops:
            row: dict[str, Any] = {"query_stamp_s": rec.query_stamp_ns * 1e-9, "match_stamp_s": rec.match_stamp_ns * 1e-9}
            if gt is not None:
                err = loop_error(gt, rec)
                if err is not None:
                    t_m, r_deg = err
                    wrong = t_m > WRONG_LOOP_M or r_deg > WRONG_LOOP_DEG
                    n_wrong += int(wrong)
                    row.update({"error_m": t_m, "error_deg": r_deg, "wrong": wrong})
            rows.append(row)
        out: dict[str, Any] = {"accepted": len(self.loops), "loops": rows}
        if gt is not None:
            out["wrong"] = n_wrong
        return out


def _gt_pose(gt: Trajectory, stamp_s: float) -> F64 | None:
    i = int(np.argmin(np.abs(gt.stamps_s - stamp_s)))
    if abs(gt.stamps_s[i] - stamp_s) > MAX_STAMP_GAP_S:
        return None
    T = np.eye(4)
    T[:3, :3] = quat_to_rot(gt.quats_xyzw[i])
    T[:3, 3] = gt.positions[i]
    return T


def loop_error(gt: Trajectory, rec: LoopRecord) -> tuple[float, float] | None:
    """(translation m, rotation degrees) between a loop's T_match_query and the ground-truth relative pose."""
    Tq, Tm = _gt_pose(gt, rec.query_stamp_ns * 1e-9), _gt_pose(gt, rec.match_stamp_ns * 1e-9)
    if Tq is None or Tm is None:
        return None
    E = invert(invert(Tm) @ Tq) @ rec.T_match_query
    return float(np.linalg.norm(E[:3, 3])), float(np.degrees(rotation_angle_rad(E[:3, :3])))


def find_objects_ground_truth(source: str | Path) -> Path | None:
    """The simulator's objects.json inside a TUM folder SOURCE, or beside a file SOURCE."""
    p = Path(source)
    for cand in (p / "objects.json", p.parent / "objects.json"):
        if cand.is_file():
            return cand
    return None


def write_object_outputs(out: Path, layer: ObjectLayer, final: Trajectory, gt: Trajectory | None, source: str,
                         no_plot: bool) -> dict[str, Any]:
    """Semantic map files, and object metrics against the simulator's ground truth when available (metrics.json `objects`).

    Written into `out` when the layer is on:
    - `semantic_map.json`  the §4.8 semantic map (objects with belief >= the belief threshold), map frame;
    - `object_map.json`    every MapObject of the main map (points, beliefs; `io.semantic_map_file` object-map layout);
    - `semantic_map.png`   top view of every object over the final trajectory (low-belief objects dashed), seen
                           along the first camera's down axis (a levelled start is assumed);
    - `objects.json` metrics (when the source folder holds the simulator's `objects.json`): the estimated
      objects, moved into the ground-truth frame with the SE(3) alignment of the final trajectory, matched to
      the objects present at the last frame (`eval.object_metrics.evaluate_objects`).
    """
    from changing_slam_ros.io.semantic_map_file import write_object_map, write_semantic_map

    result: dict[str, Any] = {"layer": layer.summary()}
    if not layer.enabled:
        return result
    map_id = _main_map(layer)
    smap = layer.semantic_map(map_id)
    write_semantic_map(out / "semantic_map.json", smap)
    write_object_map(out / "object_map.json", layer.objects(map_id), layer.planes(map_id))
    if not no_plot:
        from changing_slam_ros.errors import EvalError
        from changing_slam_ros.eval.semantic_map_plot import plot_semantic_map

        levelled = aligned_objects(layer.objects(map_id), T_LEVEL_MAP)
        traj = final.positions @ T_LEVEL_MAP[:3, :3].T if len(final) else None
        try:
            plot_semantic_map(out / "semantic_map.png",
                              build_semantic_map(levelled, layer.config.association, include_inactive=True,
                                                 planes=aligned_planes(layer.planes(map_id), T_LEVEL_MAP)), traj,
                              title="semantic map (x right, y ahead of the first camera)")
        except EvalError as err:
            result["plot_error"] = str(err)
    gt_path = find_objects_ground_truth(source)
    if gt_path is not None and gt is not None:
        result.update(object_metrics(layer, map_id, final, gt, gt_path))
    return result


def _main_map(layer: ObjectLayer) -> int:
    """The map holding the most objects (the first one on ties); 0 when none."""
    counts = {m: len(layer.objects(m)) for m in layer.map_ids}
    return max(counts, key=lambda m: (counts[m], -m)) if counts else 0


def object_metrics(layer: ObjectLayer, map_id: int, final: Trajectory, gt: Trajectory, gt_path: Path) -> dict[str, Any]:
    """metrics.json `objects` entries against the ground truth present at the last frame: the semantic map
    (belief >= semantic_min_belief, 0.5 by default: also objects seen in one pass only, unconfirmed), the
    confirmed objects (belief >= belief_threshold) and the loose map (>= 0.5, for runs of older configs)."""
    from changing_slam_ros.errors import EvalError
    from changing_slam_ros.eval.object_metrics import evaluate_objects, load_ground_truth_objects

    T = trajectory_alignment(gt, final)
    if T is None:
        return {"objects_error": "no trajectory alignment with ground truth"}
    try:
        truth = load_ground_truth_objects(gt_path)
    except EvalError as err:
        return {"objects_error": str(err)}
    objs = aligned_objects(layer.objects(map_id), T)
    cfg = layer.config.association
    out: dict[str, Any] = {"ground_truth": str(gt_path)}
    for key, min_belief in (("semantic_map", None), ("confirmed", cfg.belief_threshold), ("loose", 0.5)):
        smap = build_semantic_map(objs, cfg, min_belief=min_belief, planes=aligned_planes(layer.planes(map_id), T))
        out[key] = evaluate_objects(smap.objects, truth).to_dict()
    return out
