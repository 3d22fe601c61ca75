"""Detector speed: ms per 640x480 frame with 1 and 2 onnxruntime intra-op threads (prints, never asserts).

    .venv/bin/python bench/bench_detector.py [--model PATH] [--frames 20]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import cv2
import numpy as np

from changing_slam_ros.core.detector import Detector, DetectorConfig, class_name

FRAME = Path(__file__).resolve().parents[2] / "shared" / "data" / "tum_fr3_walking_frames" / "1341846313.553992.png"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="", help="ONNX detector (default: the shipped SSD-MobileNetV2)")
    parser.add_argument("--frames", type=int, default=20, help="timed frames per thread count")
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    args = parser.parse_args()
    if FRAME.is_file():
        rgb = np.ascontiguousarray(cv2.imread(str(FRAME), cv2.IMREAD_COLOR)[:, :, ::-1])
        source = FRAME.name
    else:
        rgb = np.random.default_rng(0).integers(0, 255, (480, 640, 3), dtype=np.uint8)
        source = "random 640x480 image"
    for threads in args.threads:
        t0 = time.perf_counter()
        det = Detector(DetectorConfig(model_path=args.model, intra_op_threads=threads))
        load_s = time.perf_counter() - t0
        res = det.detect(rgb)  # warm-up
        times_ms = []
        for _ in range(args.frames):
            t0 = time.perf_counter()
            res = det.detect(rgb)
            times_ms.append((time.perf_counter() - t0) * 1e3)
        found = ", ".join(f"{class_name(d.class_id)} {d.score:.2f}" for d in res.detections)
        print(
            f"{det.model_path.name} [{det.layout}, {det.providers[0]}] threads={threads}: "
            f"median {statistics.median(times_ms):.1f} ms/frame, min {min(times_ms):.1f}, "
            f"max {max(times_ms):.1f} over {args.frames} frames of {source}; load {load_s:.1f} s"
        )
        print(f"  detections: {found}")
        det.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
