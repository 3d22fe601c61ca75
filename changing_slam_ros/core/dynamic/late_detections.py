"""Detections of an earlier image used for a later one (real time: the detector is slower than tracking).

In real time tracking does not wait for a frame's own detections (`detections_wait_s` 0): a frame is tracked
with the detections already in for its stamp, and otherwise with the newest earlier ones, carried forward.
The objects may have moved since, so each carried box is grown on every side by `grow_widths_per_s` of its
own width (and height) per second of age. The §4.1 depth statistics keep the background behind a grown box
static (repopulation), and the object EKFs see the same object by IoU, but a grown box still takes keypoints
from tracking: with the graph's 1x cadence replayed offline (`bench/late_detections.py`), half a width per
second gave a lower ATE than one width (a person walking 1 m/s, 0.5 m wide, crosses two widths a second) in
7 of 8 cadences on two bags, 1.52x / 1.31x the offline ATE against 1.73x / 1.49x (docs/architecture.md,
"Session 8: late detections"). Older than `max_age_s`: not used.
Only `class_ids` are carried (default: person, the a-priori dynamic class): a static object's box carried
while the camera turns lands beside the object and only takes static keypoints away (measured on the sample
bag at 1x: carrying every class lost tracking for ~28 frames of the pan in two of four runs).

A grown box still lags: it stays centred where the person was. With the detections of an image before
(`previous`), each carried box is first moved on at the velocity of its own edges between the two sets
(`extrapolate`: the same-class box of `previous` it overlaps most, IoU >= `match_min_iou`, the two images at
most `max_gap_s` apart; each edge's speed clamped to `max_speed_widths_per_s` of the box's width or height per
second). The image motion of a box is the person's walk and the camera's own motion together, and both carry
on over the ~0.1-0.2 s a detection is late; growing then covers what the extrapolation gets wrong. Off by
default: in the same replay it helped most at the longest delay (4 frames between detections, 5 late: 2.01x ->
1.52x the offline ATE) but not on average, and on the sample bag with a detection every frame 2 frames late it
doubled the error (box velocities from images 67 ms apart are mostly detector jitter).

Better than guessing the motion is measuring it (`flow`): with the grey (and depth) images of the detections'
stamp and of the frame, each carried box is moved by the image motion of its foreground between the two
(`core.box_flow`, Median Flow) and then grown by the smaller `flow_grow_widths_per_s` (the moved box is located;
growing covers the person's limbs and the measurement's error). A box whose motion cannot be measured (no
texture, no points left after the forward-backward check, no image of the detections' stamp) is carried as
without `flow`. `flow_hull` joins the moved box with where it was first (the person's path). `RecentImages` keeps
the images a tracker needs for it. On by default (session 9, the lead's call on the helper's figures): in the
replay it lowered the mean ATE on all four 30 Hz walking bags (with `flow_grow_widths_per_s` 0.25: wxyz30s 1.22 -> 1.05 cm, walking_halfsphere 3.15 -> 1.35,
walking_static 0.58 -> 0.48, walking_rpy 0.80 -> 0.62) but not on the 15 Hz sample bag (0.86 -> 0.93 on five
cadences, within that bag's run-to-run spread: 6 wins, 7 losses over 13 runs), and `flow_hull` helped on none
consistently (docs/architecture.md, "Session 9: late boxes moved by the
image motion").
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
