"""Where a run's object centroid errors come from. Prints, never asserts.

For each object of the run's semantic map matched to the simulator's ground truth (`changing-slam run` output with
`object_map.json`, `map.npz` and `trajectory.txt`; the scenario folder with `objects.json` and `masks/`):

    .venv/bin/python bench/object_points_diag.py --root ROOT --scenario shift --run ROOT/runs/shift-objects

The rows and the method: `main`.
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path

import numpy as np


def main() -> int:
    """Parse the options, measure, print the table.

    - the centroid error against the visible-surface centroid (bench/changing_scenes.py's cache
      ROOT/runs/SCENARIO.surface_centroids.json) with the object-placing alignment (`trajectory_alignment`, camera
      axes weighed) and with the position-only one (`lever_m` 0);
    - the **perfect-pose** centroid: every anchored object point (map.npz `obj_anchor_*`: keyframe id and position in
      that camera's frame) re-expressed with its keyframe's ground-truth pose: what the layer's points give without
      any SLAM error;
    - where the points came from: each anchored point projected back into its keyframe and labelled with the
      simulator's instance mask at that pixel (own object, room, other objects).
    """
    import cv2

    from changing_slam_ros.commands.objects_options import aligned_objects, trajectory_alignment
    from changing_slam_ros.core.objects.map_object import ObjectMapConfig
    from changing_slam_ros.core.objects.semantic_map import build_semantic_map
    from changing_slam_ros.eval.object_metrics import evaluate_objects, load_ground_truth_objects
    from changing_slam_ros.io.dataset import open_dataset
    from changing_slam_ros.io.semantic_map_file import read_object_map
    from changing_slam_ros.io.tum_trajectory import read_tum_trajectory

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", type=Path, required=True, help="folder with the rendered scenarios and runs/")
    ap.add_argument("--scenario", required=True)
    ap.add_argument("--run", type=Path, required=True, help="the run's output folder")
    args = ap.parse_args()
    folder = args.root / args.scenario
    source = open_dataset(folder, "sim")
    gt = source.groundtruth
    assert gt is not None
    gt_poses = gt.poses()
    truth = load_ground_truth_objects(folder / "objects.json")
    cache = args.root / "runs" / f"{args.scenario}.surface_centroids.json"
    surf = {k: np.asarray(v) for k, v in json.loads(cache.read_text()).items()}
    est = read_tum_trajectory(args.run / "trajectory.txt")
    loaded = read_object_map(args.run / "object_map.json")
    errors: dict[tuple[float, str], float] = {}
    matches = []
    for lever in (1.0, 0.0):
        T = trajectory_alignment(gt, est, lever_m=lever)
        assert T is not None
        objs = aligned_objects(loaded, T)
        ev = evaluate_objects(build_semantic_map(objs, ObjectMapConfig()).objects, truth, surface_centroids=surf)
        for m in ev.matches:
            errors[(lever, m.gt_name)] = m.surface_centroid_error_m
        if lever == 1.0:
            matches = [(m, next(o for o in objs if o.id == m.estimate_id)) for m in ev.matches]
    z = np.load(args.run / "map.npz")
    mid = int(z["current_map_id"])
    a_ids, a_kf, a_pc = z[f"m{mid}_obj_anchor_ids"], z[f"m{mid}_obj_anchor_kf_ids"], z[f"m{mid}_obj_anchor_points_cam"]
    stamp_of = dict(zip(z[f"m{mid}_kf_ids"].tolist(), z[f"m{mid}_kf_stamps_ns"].tolist()))
    cam = source.frame(0).camera
    names = {o.id: o.name for o in truth.objects}
    masks: dict[int, np.ndarray] = {}
    print("| object | belief | points | surface cm (pose-aware / position-only alignment) | perfect-pose cm | "
          "own-mask fraction | labels |")
    print("|---|---|---|---|---|---|---|")
    for m, obj in matches:
        own_id = next(o.id for o in truth.objects if o.name == m.gt_name)
        sel = np.flatnonzero(np.isin(a_ids, obj.point_ids))
        pts_w, labels = [], []
        for k in sel:
            kf = int(a_kf[k])
            if kf not in stamp_of:
                continue  # anchored in a culled keyframe: no stamp in the map file
            stamp = stamp_of[kf]
            i = int(np.argmin(np.abs(gt.stamps_s - stamp * 1e-9)))
            pc = a_pc[k]
            pts_w.append(pc @ gt_poses[i][:3, :3].T + gt_poses[i][:3, 3])
            if stamp not in masks:
                masks[stamp] = cv2.imread(str(folder / "masks" / f"{stamp * 1e-9:.6f}.png"), cv2.IMREAD_UNCHANGED)
            mk = masks[stamp]
            u = int(np.clip(round(cam.fx * pc[0] / pc[2] + cam.cx - 0.5), 0, mk.shape[1] - 1))
            v = int(np.clip(round(cam.fy * pc[1] / pc[2] + cam.cy - 0.5), 0, mk.shape[0] - 1))
            labels.append(int(mk[v, u]))
        perfect = 100 * np.linalg.norm(np.mean(pts_w, axis=0) - surf[m.gt_name]) if pts_w else float("nan")
        lab = np.asarray(labels)
        counts = Counter(names.get(x, "room") if x else "room" for x in labels)
        print(f"| {m.gt_name} | {obj.belief:.2f} | {obj.n_points} | {100 * errors[(1.0, m.gt_name)]:.1f} / "
              f"{100 * errors.get((0.0, m.gt_name), float('nan')):.1f} | {perfect:.1f} | "
              f"{(lab == own_id).mean() if len(lab) else float('nan'):.2f} | "
              + ", ".join(f"{k} {v}" for k, v in counts.most_common(3)) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
