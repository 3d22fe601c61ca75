"""Occupancy-grid figures with the whole offline system: the grid of a simulator run against the scene's floor plan.

    nice -n 10 .venv/bin/python bench/occupancy_grid.py --root /tmp/grid_bench [--scenario static --seconds 101]
        [--scenario one_chair --seconds 70] [--fps 7.5] [--seed 0] [--json FILE]

Per scenario: renders it (320x240, oracle detections) into ROOT/<name>_<seed> unless already there, runs SlamSystem
with loop closing, the dynamic filter and the object layer (config `sim`), builds the current map's grid
(`SlamSystem.occupancy_grid`), places its cell centres in the world with the trajectory's alignment to ground
truth, and prints: keyframes, grid size, floor support, agreement with the floor plan (walls and furniture
footprints at the end, `sim.floor_plan`) on observed cells, occupied precision and recall, scan points labelled
with a MapObject, and for every actor moved, removed or replaced (and every person) the cells of its old
places seen and occupied, with and without the belief exclusion.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np


def one(root: Path, name: str, seed: int, seconds: float, fps: float) -> dict[str, Any]:
    from changing_slam_ros.commands.run import system_config_from_mapping
    from changing_slam_ros.config import find_config, load_yaml
    from changing_slam_ros.core.dynamic.dynamic_filter import DynamicFilter
    from changing_slam_ros.core.features.vocabulary import Vocabulary
    from changing_slam_ros.core.map.keyframe_grid import map_views
    from changing_slam_ros.core.map.occupancy_grid import build_grid
    from changing_slam_ros.core.objects.object_layer import ObjectLayer, object_layer_config
    from changing_slam_ros.core.slam.loop_closing import LoopCloser, LoopConfig, SlamMapLoopClosing
    from changing_slam_ros.core.system import SlamSystem
    from changing_slam_ros.eval.object_alignment import trajectory_alignment
    from changing_slam_ros.io.dataset import open_dataset
    from changing_slam_ros.io.detections_file import find_detections_file, read_detections_file
    from changing_slam_ros.sim import renderer  # noqa: F401 - sets MUJOCO_GL before mujoco loads
    from changing_slam_ros.sim.floor_plan import floor_plan, swept_plan
    from changing_slam_ros.sim.scenarios import build_scenario
    from changing_slam_ros.sim.sequence import RenderOptions, simulate

    folder = root / f"{name}_{seed}"
    sc = build_scenario(name, seed)
    if not (folder / "groundtruth.txt").is_file():
        simulate(sc, folder, RenderOptions(width=320, height=240, frames=int(seconds * fps), fps=fps), seed)
    data = load_yaml(find_config("sim"))
    closing = SlamMapLoopClosing(LoopCloser(LoopConfig(), Vocabulary.load()))
    system = SlamSystem(system_config_from_mapping(data, "sim"), loop_closer=closing, keyframe_index=closing,
                        dynamic_filter=DynamicFilter(),
                        object_layer=ObjectLayer(object_layer_config(data.get("objects"), "sim")))  # fmt: skip
    source = open_dataset(folder, "sim")
    oracle = read_detections_file(find_detections_file(folder))
    for rgbd in source:
        system.process(rgbd, oracle.for_stamp(rgbd.stamp_ns))
    cfg = system.config.grid
    t0 = time.perf_counter()
    grid = system.occupancy_grid()
    build_s = time.perf_counter() - t0
    assert grid is not None and source.groundtruth is not None
    T = trajectory_alignment(source.groundtruth, system.final_trajectory())
    assert T is not None
    centres = grid.cell_centres_map().reshape(-1, 3) @ T[:3, :3].T + T[:3, 3]
    plan = floor_plan(sc, seconds, cfg.min_height_m, cfg.max_height_m, cfg.resolution_m)
    truth = plan.lookup(centres[:, :2])
    occ = grid.occupancy(cfg).reshape(-1)
    observed = (occ != -1) & (truth >= 0)
    scans = [kf.grid_scan for kf in system.atlas.current.keyframes.values() if kf.grid_scan is not None]
    row: dict[str, Any] = {
        "scenario": name, "seed": seed, "seconds": seconds, "fps": fps,
        "keyframes": system.atlas.n_keyframes, "grid_cells": list(grid.shape), "grid_build_s": round(build_s, 3),
        "floor_support_points": grid.floor.n_support, "observed_cells": int(observed.sum()),
        "agreement": float(((occ == 100) == (truth == 1))[observed].mean()),
        "occupied_precision": float((truth[(occ == 100) & observed] == 1).mean()),
        "occupied_recall": float((occ[observed & (truth == 1)] == 100).mean()),
        "scan_points_with_object": int(sum(int((s.object_ids >= 0).sum()) for s in scans)),
        "scan_points_dynamic": int(sum(int(s.dynamic.sum()) for s in scans)),
    }  # fmt: skip
    plain = build_grid(map_views(system.atlas.current), cfg, floor=grid.floor).occupancy(cfg).reshape(-1)
    changed = [(c.t_s, sc.actor_index(c.actor)) for c in sc.changes if c.t_s < seconds]
    people = [i for i, a in enumerate(sc.actors) if a.class_id == 0]
    for label, actors, times in (("old_places", [i for _, i in changed], [t - 1.0 for t, _ in changed]),
                                 ("person_paths", people, list(np.arange(0.0, seconds, 0.2)))):  # fmt: skip
        if not actors:
            continue
        cells = swept_plan(sc, actors, times, cfg.min_height_m, cfg.max_height_m, plan).lookup(centres[:, :2]) == 1
        row[label] = {"cells": int(cells.sum()), "seen": int((cells & (occ != -1)).sum()),
                      "occupied": int((cells & (occ == 100)).sum()),
                      "occupied_without_belief_exclusion": int((cells & (plain == 100)).sum())}  # fmt: skip
    return row


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, required=True, help="folder for the rendered scenarios")
    parser.add_argument("--scenario", action="append", help="scenario name (repeat; default static and one_chair)")
    parser.add_argument("--seconds", action="append", type=float, help="length per scenario (default 101, 70)")
    parser.add_argument("--fps", type=float, default=7.5)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path, help="also write the rows here")
    args = parser.parse_args()
    names = args.scenario or ["static", "one_chair"]
    seconds = args.seconds or [101.0, 70.0][: len(names)]
    rows = [one(args.root, n, args.seed, s, args.fps) for n, s in zip(names, seconds)]
    for r in rows:
        print(json.dumps(r))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
