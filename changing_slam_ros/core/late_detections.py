"""Detections of an earlier image used for a later one (real time: the detector is slower than tracking).

In real time tracking does not wait for a frame's own detections (`detections_wait_s` 0): a frame is tracked
with the detections already in for its stamp, and otherwise with the newest earlier ones, carried forward.
The objects may have moved since, so each carried box is grown on every side by `grow_widths_per_s` of its
own width (and height) per second of age: a person walking 1 m/s, 0.5 m wide, crosses two of its widths a
second. Growing errs on the safe side: the §4.1 depth statistics keep the background behind a grown box
static (repopulation), and the object EKFs see the same object by IoU. Older than `max_age_s`: not used.
Only `class_ids` are carried (default: person, the a-priori dynamic class): a static object's box carried
while the camera turns lands beside the object and only takes static keypoints away (measured on the sample
bag at 1x: carrying every class lost tracking for ~28 frames of the pan in two of four runs).
"""

from __future__ import annotations

from dataclasses import dataclass

from changing_slam_ros.core.detector import Detection, DetectionSet


@dataclass(frozen=True)
class CarryConfig:
    max_age_s: float = 0.5
    grow_widths_per_s: float = 1.0
    class_ids: tuple[int, ...] = (0,)


def carried_forward(earlier: DetectionSet, stamp_ns: int, cfg: CarryConfig) -> tuple[Detection, ...] | None:
    """`earlier`'s detections for an image stamped `stamp_ns`, boxes grown with their age; None when `earlier`
    is not older than the image or older than `cfg.max_age_s` (the caller then tracks without detections)."""
    age_s = (stamp_ns - earlier.stamp_ns) * 1e-9
    if age_s <= 0.0 or age_s > cfg.max_age_s:
        return None
    grow = cfg.grow_widths_per_s * age_s
    out = []
    for d in earlier.detections:
        if d.class_id not in cfg.class_ids:
            continue
        x0, y0, x1, y1 = d.box_xyxy
        gx, gy = grow * (x1 - x0), grow * (y1 - y0)
        box = (x0 - gx, y0 - gy, x1 + gx, y1 + gy)
        if earlier.width > 0 and earlier.height > 0:  # stay inside the image
            box = (max(box[0], 0.0), max(box[1], 0.0), min(box[2], earlier.width - 1.0), min(box[3], earlier.height - 1.0))
        out.append(Detection(box, d.class_id, d.score))
    return tuple(out)
