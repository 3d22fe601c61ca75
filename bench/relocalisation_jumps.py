"""Where each relocalisation put the camera, against ground truth (prints, never asserts).

    .venv/bin/python bench/relocalisation_jumps.py --cache CACHE OUT [OUT ...]

OUT is a `changing-slam bench dynamic --out` folder; CACHE its `--cache` folder (the renders). For every full run
(controls left out) and every gap in its online trajectory (frames without a pose, then a relocalised one), the
line gives the camera's error just before the gap and just after it. The online trajectory is aligned to ground
truth on the frames before the run's first gap (at least 10), so that a pose a mover dragged before the loss
shows as an error before the gap, and a relocalisation into a part of the map a mover bent as an error after it.
A gap closed by a new map shows as a large error after it (the new map starts at the last pose).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from changing_slam_ros.eval.alignment import umeyama  # noqa: E402
from changing_slam_ros.io.tum_folder import read_file_list  # noqa: E402
from changing_slam_ros.io.tum_trajectory import read_tum_trajectory  # noqa: E402


def gaps_of(run: Path, seq: Path) -> list[tuple[int, int, float, float]]:
    """(last frame before, first frame after, error before m, error after m) per gap of `run`'s online poses."""
    frame_stamps = np.array([f.stamp_ns * 1e-9 for f in read_file_list(seq / "rgb.txt")])
    gt = read_tum_trajectory(seq / "groundtruth.txt")
    est = read_tum_trajectory(run / "trajectory_online.txt")
    if len(est.stamps_s) < 2:
        return []
    frames = np.array([int(np.argmin(np.abs(frame_stamps - t))) for t in est.stamps_s])
    truth = gt.positions[[int(np.argmin(np.abs(gt.stamps_s - t))) for t in est.stamps_s]]
    gaps = [k for k in range(1, len(frames)) if frames[k] - frames[k - 1] > 1]
    if not gaps:
        return []
    n = min(max(10, gaps[0]), len(frames))
    err = np.linalg.norm(umeyama(est.positions[:n], truth[:n]).apply_points(est.positions) - truth, axis=1)
    return [(int(frames[k - 1]), int(frames[k]), float(err[k - 1]), float(err[k])) for k in gaps]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cache", type=Path, required=True, help="the bench's --cache folder")
    ap.add_argument("outs", type=Path, nargs="+", help="`changing-slam bench dynamic --out` folders")
    args = ap.parse_args()
    better = worse = total = 0
    for out in args.outs:
        bench = json.loads((out / "bench.json").read_text())
        for row in bench["per_seed"]:
            seed = row["seed"]
            seqs = sorted(p for p in args.cache.glob(f"{bench['scenario']}_s{seed}_*") if (p / ".complete").exists())
            run = out / "runs" / f"s{seed}_full"
            if not seqs or not (run / "trajectory_online.txt").exists():
                continue
            for before, after, e0, e1 in gaps_of(run, seqs[0]):
                total += 1
                better += int(e1 < e0 - 0.05)
                worse += int(e1 > e0 + 0.05)
                print(f"{out.name} seed {seed}: frames {before} -> {after}, error {100 * e0:.1f} -> {100 * e1:.1f} cm")
    print(f"{total} gaps; the error fell by more than 5 cm at {better}, rose by more than 5 cm at {worse}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
