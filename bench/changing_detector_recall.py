"""How often the shipped detector names the changing-room family's objects, per class, on rendered seeds.

For every `--stride`-th frame of each rendered folder (a `random_changing` render: `detections.json` holds the
oracle boxes from the instance masks), the default detector runs on the colour image; an object seen whole
(oracle box not truncated, at least `--min-pixels` pixels) counts as named when a detection of its class
overlaps its oracle box with IoU >= 0.5. Detections that overlap no oracle box of their class (IoU < 0.3) are
listed by class: pictures on the walls, structure, or objects under another name. Prints numbers, asserts
nothing. Separates what the detector cannot see from what the object layer loses.

    .venv/bin/python bench/changing_detector_recall.py out/sim_cache/random_changing_s200_* --stride 10
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path

import cv2
import numpy as np

from changing_slam_ros.core.dynamic.detector import Detector, class_name, iou_matrix


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folders", nargs="+", type=Path)
    ap.add_argument("--stride", type=int, default=10)
    ap.add_argument("--min-pixels", type=int, default=1500)
    args = ap.parse_args()
    detector = Detector()
    seen: Counter[str] = Counter()
    named: Counter[str] = Counter()
    other_name: Counter[str] = Counter()
    unexplained: Counter[str] = Counter()
    for folder in args.folders:
        frames = json.loads((folder / "detections.json").read_text())["frames"]
        for k in range(0, len(frames), args.stride):
            stamp = frames[k]["stamp_ns"]
            bgr = cv2.imread(str(folder / "rgb" / f"{stamp * 1e-9:.6f}.png"))
            if bgr is None:
                continue
            dets = detector.detect(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), stamp)
            boxes = dets.boxes_xyxy() if len(dets) else np.zeros((0, 4))
            ids = dets.class_ids() if len(dets) else np.zeros(0, int)
            truth = [d for d in frames[k]["detections"] if d["class_id"] >= 0]
            tb = np.array([d["box_xyxy"] for d in truth], float).reshape(-1, 4)
            iou = iou_matrix(tb, boxes) if len(truth) and len(boxes) else np.zeros((len(truth), len(boxes)))
            for i, d in enumerate(truth):
                if d["truncated"] or d["pixels"] < args.min_pixels:
                    continue
                seen[d["class_name"]] += 1
                same = (ids == d["class_id"]) & (iou[i] >= 0.5) if len(boxes) else np.zeros(0, bool)
                if same.any():
                    named[d["class_name"]] += 1
                elif len(boxes) and (iou[i] >= 0.5).any():
                    other_name[f"{d['class_name']}->{class_name(int(ids[int(np.argmax(iou[i]))]))}"] += 1
            for j in range(len(boxes)):
                explained = any(truth[i]["class_id"] == ids[j] and iou[i, j] >= 0.3 for i in range(len(truth)))
                if not explained:
                    unexplained[class_name(int(ids[j]))] += 1
    print("class            whole views  named  rate")
    for c in sorted(seen):
        print(f"{c:<16} {seen[c]:>11}  {named[c]:>5}  {named[c] / seen[c]:.2f}")
    print("named as another class: " + (", ".join(f"{k} {v}" for k, v in other_name.most_common()) or "none"))
    print("detections of no object of their class: "
          + (", ".join(f"{k} {v}" for k, v in unexplained.most_common()) or "none"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
