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
from pathlib import Path

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]


def _stamps(path: Path) -> F64:
    return np.array([float(line.split()[0]) for line in path.read_text().splitlines() if line and not line.startswith("#")])


def _rigid_fit(src: F64, dst: F64) -> tuple[F64, F64, F64]:
    """R, mean of src, mean of dst with dst ~ R (src - mean_src) + mean_dst (Kabsch, no scale)."""
    ms, md = src.mean(axis=0), dst.mean(axis=0)
    u, _, vt = np.linalg.svd((dst - md).T @ (src - ms))
    d = np.eye(3)
    d[2, 2] = np.sign(np.linalg.det(u @ vt))
    return u @ d @ vt, ms, md


def gaps_of(run: Path, seq: Path) -> list[tuple[int, int, float, float]]:
    """(last frame before, first frame after, error before m, error after m) per gap of `run`'s online poses."""
    frame_stamps = _stamps(seq / "rgb.txt")
    gt = np.loadtxt(seq / "groundtruth.txt", ndmin=2)
    est = np.loadtxt(run / "trajectory_online.txt", ndmin=2)
    if len(est) < 2:
        return []
    frames = np.array([int(np.argmin(np.abs(frame_stamps - t))) for t in est[:, 0]])
    truth = np.array([gt[int(np.argmin(np.abs(gt[:, 0] - t))), 1:4] for t in est[:, 0]])
    gaps = [k for k in range(1, len(frames)) if frames[k] - frames[k - 1] > 1]
    if not gaps:
        return []
    n = min(max(10, gaps[0]), len(est))
    R, ms, md = _rigid_fit(est[:n, 1:4], truth[:n])
    err = np.linalg.norm((R @ (est[:, 1:4] - ms).T).T + md - truth, axis=1)
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
