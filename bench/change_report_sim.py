"""The "what changed" report of a two-session run against the simulator's ground truth (prints, never asserts).

The first session maps `static`; the second starts from its map in `shift_final` (the `shift` room after every
move, `bench/multi_session.py --second shift_final` renders it) and ends with `changes.json`
(`commands/changes.py`). Ground truth: every object of `shift` whose box centre moved more than `--min-move-m`
between the first and last frame is moved (old and new volume centre). A reported move is right when its class
matches and both its ends lie within `--max-distance-m` of a ground-truth move's ends (report ends mapped into
the world frame by the first session's trajectory alignment); its displacement error is |reported - true|.

    changing-slam run ROOT/static --out RUNS/static --config sim --detections oracle --objects
    changing-slam run ROOT/shift_final --out RUNS/shift_final --config sim --detections oracle --objects \\
        --map-in RUNS/static/map.npz
    .venv/bin/python bench/change_report_sim.py --root ROOT --first RUNS/static --second RUNS/shift_final
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from changing_slam_ros.commands.objects_options import trajectory_alignment
from changing_slam_ros.eval.object_metrics import load_ground_truth_objects
from changing_slam_ros.io.tum_trajectory import read_tum_trajectory


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", type=Path, required=True, help="folder with the static and shift renders")
    ap.add_argument("--first", type=Path, required=True, help="the first session's run folder")
    ap.add_argument("--second", type=Path, required=True, help="the second session's run folder (changes.json)")
    ap.add_argument("--min-move-m", type=float, default=0.3)
    ap.add_argument("--max-distance-m", type=float, default=0.4)
    args = ap.parse_args()
    T = trajectory_alignment(read_tum_trajectory(args.root / "static" / "groundtruth.txt"),
                             read_tum_trajectory(args.first / "trajectory.txt"))
    if T is None:
        raise SystemExit("the first session cannot be aligned with its ground truth")
    truth = load_ground_truth_objects(args.root / "shift" / "objects.json")
    last = len(truth.stamps_ns) - 1
    moves = []
    for g in truth.objects:
        a, b = g.box_at(0), g.box_at(last)
        if g.moving or a is None or b is None:
            continue
        old, new = (a[0] + a[1]) / 2, (b[0] + b[1]) / 2
        if np.linalg.norm(new - old) > args.min_move_m:
            moves.append((g.name, g.class_id, old, new))
    doc = json.loads((args.second / "changes.json").read_text())
    print(f"report: {doc['counts']}; ground truth: {len(moves)} moved, nothing removed, added or replaced")
    to_w = lambda p: np.asarray(p) @ T[:3, :3].T + T[:3, 3]  # noqa: E731
    found = set()
    for c in doc["changes"]:
        line = f"  {c['kind']:8s} {c['class_name']:12s}"
        if c["kind"] == "moved":
            f, t = to_w(c["from_m"]), to_w(c["to_m"])
            hit = [(n, o, w) for n, k, o, w in moves if k == c["before"]["class_id"]
                   and np.linalg.norm(f - o) < args.max_distance_m and np.linalg.norm(t - w) < args.max_distance_m]
            if hit:
                n, o, w = hit[0]
                found.add(n)
                err = abs(c["distance_m"] - float(np.linalg.norm(w - o)))
                line += (f" {c['distance_m']:.2f} m -> ground truth {n} {np.linalg.norm(w - o):.2f} m (error "
                         f"{err * 100:.1f} cm; ends {np.linalg.norm(f - o) * 100:.1f} / {np.linalg.norm(t - w) * 100:.1f} cm)")
            else:
                line += f" {c['distance_m']:.2f} m -> no ground-truth move (wrong)"
        else:
            line += " (wrong: nothing was " + c["kind"] + ")"
        print(line)
    for n, k, o, w in moves:
        if n not in found:
            print(f"  missed move: {n} {np.linalg.norm(w - o):.2f} m")
    n_moved = sum(c["kind"] == "moved" for c in doc["changes"])
    print(f"moved: precision {len(found)}/{len(doc['changes'])}, recall {len(found)}/{len(moves)} "
          f"(reported moves {n_moved})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
