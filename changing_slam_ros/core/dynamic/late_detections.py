"""Detections of an earlier image used for a later one (real time: the detector is slower than tracking).

A frame tracked before its own detections are in takes the newest earlier ones, carried forward
(`carried_forward`). Only `class_ids` are carried (default: person; a static object's box carried while the
camera turns lands beside the object and only takes static keypoints away). Each carried box is first moved
(`flow`, on by default: the image motion of its foreground between the detections' image and the frame,
`core.box_flow`, Median Flow; `RecentImages` keeps the images it needs) or extrapolated from the same-class box
of the set before (`extrapolate`, off by default: box velocities from images 67 ms apart are mostly detector
jitter), then grown on every side by `grow_widths_per_s` (or the smaller `flow_grow_widths_per_s` for a moved
box) of its size per second of age, which covers the limbs and what the motion estimate gets wrong. The §4.1
depth statistics keep the background behind a grown box static. Older than `max_age_s`: not used. The
defaults were chosen by replaying the graph's 1x cadence offline (`bench/late_detections.py`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.dynamic.box_flow import BoxFlowConfig, BoxMotion, FlowImage, box_motions
from changing_slam_ros.core.dynamic.detector import Detection, DetectionSet, iou_matrix


@dataclass(frozen=True)
class CarryConfig:
    max_age_s: float = 0.5
    grow_widths_per_s: float = 0.5
    class_ids: tuple[int, ...] = (0,)
    extrapolate: bool = False
    match_min_iou: float = 0.1
    max_gap_s: float = 0.5
    max_speed_widths_per_s: float = 4.0
    flow: bool = True
    flow_grow_widths_per_s: float = 0.25
    flow_hull: bool = False
    box_flow: BoxFlowConfig = BoxFlowConfig()


def carried_forward(
    earlier: DetectionSet,
    stamp_ns: int,
    cfg: CarryConfig,
    previous: DetectionSet | None = None,
    images: tuple[FlowImage, FlowImage] | None = None,
) -> tuple[Detection, ...] | None:
    """`earlier`'s detections for an image stamped `stamp_ns`, boxes moved by their measured image motion
    (`cfg.flow`, with `images` = the image of `earlier`'s detections and the frame's) or on at their velocity since
    `previous` (when given and `cfg.extrapolate`), then grown with their age; None when `earlier` is not older
    than the image or older than `cfg.max_age_s` (the caller then tracks without detections)."""
    age_s = (stamp_ns - earlier.stamp_ns) * 1e-9
    if age_s <= 0.0 or age_s > cfg.max_age_s:
        return None
    carried = [d for d in earlier.detections if d.class_id in cfg.class_ids]
    motions: list[BoxMotion | None] = [None] * len(carried)
    if cfg.flow and images is not None and carried:
        motions = box_motions([d.box_xyxy for d in carried], images[0], images[1], cfg.box_flow)
    out = []
    for d, motion in zip(carried, motions):
        if motion is not None:
            x0, y0, x1, y1 = motion.apply(d.box_xyxy, earlier.width, earlier.height)
            if cfg.flow_hull:  # the moved box joined with where it was: the person's path since
                bx0, by0, bx1, by1 = d.box_xyxy
                x0, y0, x1, y1 = min(x0, bx0), min(y0, by0), max(x1, bx1), max(y1, by1)
            grow = cfg.flow_grow_widths_per_s * age_s
        else:
            x0, y0, x1, y1 = _moved_on(d, earlier.stamp_ns, age_s, previous, cfg) if cfg.extrapolate else d.box_xyxy
            grow = cfg.grow_widths_per_s * age_s
        out.append(Detection(grown_box((x0, y0, x1, y1), grow, earlier.width, earlier.height), d.class_id, d.score))
    return tuple(out)


def grown_box(box_xyxy: tuple[float, float, float, float] | npt.NDArray[np.float64], grow: float, width: int,
              height: int) -> tuple[float, float, float, float]:
    """`box_xyxy` grown by `grow` of its width and height per side, kept inside a `width` x `height` image when
    its size is known (0: not clipped)."""
    x0, y0, x1, y1 = (float(v) for v in box_xyxy)
    gx, gy = grow * (x1 - x0), grow * (y1 - y0)
    x0, y0, x1, y1 = x0 - gx, y0 - gy, x1 + gx, y1 + gy
    if width > 0 and height > 0:  # stay inside the image
        x0, y0, x1, y1 = max(x0, 0.0), max(y0, 0.0), min(x1, width - 1.0), min(y1, height - 1.0)
    return (x0, y0, x1, y1)


class RecentImages:
    """The grey (and depth) images of the last frames, by stamp, at most `max_age_s` behind the newest: the
    images late detections were made on, for `carried_forward`'s flow."""

    def __init__(self, max_age_s: float, max_stamp_gap_s: float = 0.05) -> None:
        self.max_age_ns = round(max_age_s * 1e9)
        self.max_gap_ns = round(max_stamp_gap_s * 1e9)
        self._images: dict[int, FlowImage] = {}

    def __len__(self) -> int:
        return len(self._images)

    def add(self, image: FlowImage) -> None:
        """Keep `image`; images older than `max_age_s` before it are forgotten."""
        self._images[image.stamp_ns] = image
        oldest = image.stamp_ns - self.max_age_ns
        for stamp in [s for s in self._images if s < oldest]:
            del self._images[stamp]

    def get(self, stamp_ns: int) -> FlowImage | None:
        """The image of `stamp_ns`, else the nearest one within `max_stamp_gap_s` (a detector may have seen a
        frame that tracking dropped), else None."""
        if stamp_ns in self._images:
            return self._images[stamp_ns]
        if not self._images:
            return None
        nearest = min(self._images, key=lambda s: abs(s - stamp_ns))
        return self._images[nearest] if abs(nearest - stamp_ns) <= self.max_gap_ns else None


def _moved_on(
    d: Detection, stamp_ns: int, age_s: float, previous: DetectionSet | None, cfg: CarryConfig
) -> tuple[float, float, float, float]:
    """`d`'s box moved on by `age_s` at the velocity of its edges since its match in `previous` (unmoved
    without one)."""
    if previous is None:
        return d.box_xyxy
    gap_s = (stamp_ns - previous.stamp_ns) * 1e-9
    same = [p for p in previous.detections if p.class_id == d.class_id]
    if gap_s <= 0.0 or gap_s > cfg.max_gap_s or not same:
        return d.box_xyxy
    box = np.asarray(d.box_xyxy, dtype=np.float64)
    overlap = iou_matrix(box[None, :], np.array([p.box_xyxy for p in same], dtype=np.float64))[0]
    best = int(np.argmax(overlap))
    if overlap[best] < cfg.match_min_iou:
        return d.box_xyxy
    velocity = (box - np.asarray(same[best].box_xyxy, dtype=np.float64)) / gap_s
    size = np.array([box[2] - box[0], box[3] - box[1]] * 2)
    limit = cfg.max_speed_widths_per_s * np.maximum(size, 1.0)
    moved = box + np.clip(velocity, -limit, limit) * age_s
    return (float(moved[0]), float(moved[1]), float(max(moved[2], moved[0] + 1.0)), float(max(moved[3], moved[1] + 1.0)))
