"""Person recall of the shipped detector on simulated frames, against the simulator's oracle person boxes.

A person counts as found when a detected person box overlaps its oracle box with IoU >= `--iou` (0.5).
Recall is printed for three sets of oracle persons: all of them (>= 40 visible pixels, the oracle's
floor), the "reasonably visible" ones (>= `--min-pixels` visible pixels), and those of them not cut by
the image border. Precision: detected person boxes that overlap an oracle person box (any of them) with IoU
>= `--iou`, over all detected person boxes. Detections come from `ablation_dynamic.model_detections` (cached
per folder, frame count and model file name) of the shipped detector or `--model`. Prints, never asserts.

    nice -n 10 .venv/bin/python bench/person_recall_sim.py /tmp/sim/walking_xyz [--frames 300] [--stride 1]
        [--model changing_slam_ros/models/ssd_mobilenet_v2_coco_int8.onnx]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

from ablation_dynamic import model_detections  # noqa: E402

from changing_slam_ros.core.dynamic.detector import Detection, Detector, DetectorConfig  # noqa: E402
from changing_slam_ros.io.detections_file import find_detections_file  # noqa: E402

PERSON = 0


def iou(a: tuple[float, ...], b: tuple[float, ...]) -> float:
    iw = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    ih = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = iw * ih
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / union if union > 0 else 0.0


def person_recall(folder: Path, detections: dict[int, tuple[Detection, ...]], n_frames: int, stride: int,
                  min_iou: float, min_pixels: int) -> dict[str, tuple[int, int]]:
    """{set name: (found, total)} over every `stride`-th of the first `n_frames` frames; set "precision": (detected
    person boxes matching an oracle person, detected person boxes)."""
    doc = json.loads(find_detections_file(folder).read_text())
    sets = {"all": [0, 0], "visible": [0, 0], "visible_uncut": [0, 0], "precision": [0, 0]}
    for k, frame in enumerate(doc["frames"][:n_frames]):
        if k % stride:
            continue
        found_boxes = [d.box_xyxy for d in detections.get(int(frame["stamp_ns"]), ()) if d.class_id == PERSON]
        oracle = [tuple(o["box_xyxy"]) for o in frame["detections"] if o["class_id"] == PERSON]
        for b in found_boxes:
            sets["precision"][0] += int(any(iou(o, b) >= min_iou for o in oracle))
            sets["precision"][1] += 1
        for o in frame["detections"]:
            if o["class_id"] != PERSON:
                continue
            hit = any(iou(tuple(o["box_xyxy"]), b) >= min_iou for b in found_boxes)
            names = ["all"]
            if o["pixels"] >= min_pixels:
                names.append("visible")
                if not o["truncated"]:
                    names.append("visible_uncut")
            for name in names:
                sets[name][0] += int(hit)
                sets[name][1] += 1
    return {k: (v[0], v[1]) for k, v in sets.items()}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", nargs="+", type=Path, help="rendered scenario folders (changing-slam simulate)")
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--stride", type=int, default=1)
    parser.add_argument("--iou", type=float, default=0.5)
    parser.add_argument("--min-pixels", type=int, default=5000, help="'reasonably visible': this many pixels")
    parser.add_argument("--model-cache", type=Path, default=Path(tempfile.gettempdir()) / "changing_slam_bench_detections")
    parser.add_argument("--model", default="", help="ONNX detector (default: the shipped fp32 SSD-MobileNetV2)")
    args = parser.parse_args()
    detector = Detector(DetectorConfig(model_path=args.model))
    for folder in args.folders:
        dets, ms = model_detections(folder, args.frames, detector, args.model_cache)
        rec = person_recall(folder, dets, args.frames, args.stride, args.iou, args.min_pixels)
        cells = "  ".join(f"{k} {f}/{t} = {100 * f / t if t else float('nan'):.1f} %" for k, (f, t) in rec.items())
        print(f"{folder}: person recall (IoU >= {args.iou}): {cells}  [{detector.model_path.name}, {ms:.0f} ms/frame]",
              flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
