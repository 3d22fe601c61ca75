"""Do two detector settings give the same detections? A check over 152 real frames.

    .venv/bin/python bench/check_detector_equivalence.py [--graph-nms] [--every 10] [--per-folder 30] [FOLDER ...]

Compares the default detector (the slimmed SSD head, `detector.slim_graph`) with the head as cut before the NMS
(`slim_graph: false`) and, with --graph-nms, with the original graph and its own NMS (20-45 s to load), on the
two real TUM fr3_walking frames plus every `--every`-th PNG of `FOLDER/rgb` (up to `--per-folder` each). The
default folders are the five walking scenarios at 640x480 in /tmp/sim_cache (make them with `changing-slam
simulate SCENARIO --out DIR --frames 300`); missing folders are reported and skipped. Prints per setting the
images whose class lists differ and the largest box (px) and score differences (prints, never asserts).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import cv2
import numpy as np

from changing_slam_ros.core.dynamic.detector import Detector, DetectorConfig

REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "tum_fr3_walking_frames"
SIM = [
    Path("/tmp/sim_cache") / f"{name}_640x480_s0_f300_people3"
    for name in ("walking_xyz", "walking_static", "walking_rpy", "walking_halfsphere", "sitting_xyz")
]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", nargs="*", type=Path, help="scenario folders with rgb/*.png (default: SIM)")
    parser.add_argument("--graph-nms", action="store_true", help="also compare with the graph's own NMS")
    parser.add_argument("--every", type=int, default=10)
    parser.add_argument("--per-folder", type=int, default=30)
    args = parser.parse_args()
    frames = sorted(REAL.glob("*.png")) if REAL.is_dir() else []
    for folder in args.folders or SIM:
        files = sorted((folder / "rgb").glob("*.png"))[:: args.every][: args.per_folder]
        if not files:
            print(f"skipped (no rgb/*.png): {folder}")
        frames += files
    with tempfile.TemporaryDirectory(prefix="detector-equivalence-") as cache:
        reference = Detector(DetectorConfig(cache_dir=cache))
        others = {"head, not slimmed": Detector(DetectorConfig(cache_dir=cache, slim_graph=False))}
        if args.graph_nms:
            others["graph NMS"] = Detector(DetectorConfig(nms="graph", model_cache=False))
        differ = {name: 0 for name in others}
        worst = {name: [0.0, 0.0] for name in others}
        count = 0
        for path in frames:
            rgb = np.ascontiguousarray(cv2.imread(str(path), cv2.IMREAD_COLOR)[:, :, ::-1])
            want = reference.detect(rgb).detections
            count += len(want)
            for name, det in others.items():
                got = det.detect(rgb).detections
                if [d.class_id for d in got] != [d.class_id for d in want]:
                    differ[name] += 1
                    continue
                if want:
                    box = np.abs(np.array([d.box_xyxy for d in got]) - np.array([d.box_xyxy for d in want])).max()
                    score = max(abs(a.score - b.score) for a, b in zip(got, want))
                    worst[name] = [max(worst[name][0], float(box)), max(worst[name][1], score)]
    print(f"{len(frames)} frames, {count} detections by the default (slimmed graph)")
    for name in others:
        print(f"  vs {name}: class lists differ on {differ[name]} frames; elsewhere max box diff "
              f"{worst[name][0]:.2e} px, max score diff {worst[name][1]:.2e}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
