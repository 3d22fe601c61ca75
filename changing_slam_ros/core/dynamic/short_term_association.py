"""Short-term data association (Changing-SLAM §4.3): each detection of the current frame is matched by IoU
with the boxes of the same class seen in the previous frame; an unmatched detection starts a new MapObject
instance with a fresh id.

Matching is one-to-one and greedy on IoU (highest pairs first), which equals the optimal assignment in the
usual case of well-separated objects and stays O(M^2) for M boxes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.dynamic.detector import Detection, iou_matrix
from changing_slam_ros.errors import ConfigError


@dataclass(frozen=True)
class ShortTermAssociationConfig:
    """`short_term_association` config section.

    - `min_iou`: a pair matches only above this IoU (the paper gives no value).
    - `max_missed_frames`: how many frames an unmatched object's last box stays available for matching
      (0 = the paper's rule, previous frame only; 1-2 bridges single-frame detector drop-outs).
    """

    min_iou: float = 0.3
    max_missed_frames: int = 0

    def __post_init__(self) -> None:
        if not 0.0 < self.min_iou <= 1.0:
            raise ConfigError(f"short_term_association.min_iou: expected a value in (0, 1], got {self.min_iou}")
        if self.max_missed_frames < 0:
            raise ConfigError(f"short_term_association.max_missed_frames: expected >= 0, got {self.max_missed_frames}")


@dataclass(frozen=True)
class TrackedBox:
    """The last box of one object instance: `object_id`, `class_id`, `box_xyxy` pixels, frames since seen."""

    object_id: int
    class_id: int
    box_xyxy: tuple[float, float, float, float]
    missed_frames: int = 0


@dataclass(frozen=True)
class Association:
    """Result for one frame with M detections: `object_ids` (M,) and `is_new` (M,) per detection, in input
    order, and `lost_ids`, the objects dropped from short-term tracking in this frame."""

    object_ids: npt.NDArray[np.int64]
    is_new: npt.NDArray[np.bool_]
    lost_ids: tuple[int, ...]


def match_boxes(
    prev_boxes: npt.NDArray[np.float64],
    prev_classes: npt.NDArray[np.int64],
    boxes: npt.NDArray[np.float64],
    classes: npt.NDArray[np.int64],
    min_iou: float,
) -> npt.NDArray[np.int64]:
    """Greedy one-to-one same-class IoU matching: for each current box (M, 4) the index of its match among
    the previous boxes (P, 4), or -1."""
    match = np.full(len(boxes), -1, dtype=np.int64)
    if len(boxes) == 0 or len(prev_boxes) == 0:
        return match
    iou = iou_matrix(boxes, prev_boxes)
    iou[np.asarray(classes)[:, None] != np.asarray(prev_classes)[None, :]] = 0.0
    pairs = np.argwhere(iou > min_iou)
    order = np.argsort(-iou[pairs[:, 0], pairs[:, 1]], kind="stable")
    used_prev: set[int] = set()
    for k in order:
        i, j = int(pairs[k, 0]), int(pairs[k, 1])
        if match[i] < 0 and j not in used_prev:
            match[i] = j
            used_prev.add(j)
    return match


class ShortTermAssociator:
    """Keeps the previous frame's boxes and hands out MapObject instance ids.

    Object ids are unique over the associator's life; `first_id` lets several associators (e.g. per map)
    use disjoint ranges.
    """

    def __init__(self, config: ShortTermAssociationConfig | None = None, first_id: int = 0) -> None:
        self.config = config or ShortTermAssociationConfig()
        self._next_id = first_id
        self._tracks: list[TrackedBox] = []

    @property
    def tracks(self) -> tuple[TrackedBox, ...]:
        """Boxes available for matching in the next frame."""
        return tuple(self._tracks)

    def reset(self) -> None:
        """Forget the previous frame (after lost tracking or a map change); ids keep counting."""
        self._tracks = []

    def associate(self, detections: tuple[Detection, ...] | list[Detection]) -> Association:
        """Match this frame's detections with the previous frame's boxes; returns one object id per detection."""
        boxes = np.array([d.box_xyxy for d in detections], dtype=np.float64).reshape(-1, 4)
        classes = np.array([d.class_id for d in detections], dtype=np.int64)
        prev_boxes = np.array([t.box_xyxy for t in self._tracks], dtype=np.float64).reshape(-1, 4)
        prev_classes = np.array([t.class_id for t in self._tracks], dtype=np.int64)
        match = match_boxes(prev_boxes, prev_classes, boxes, classes, self.config.min_iou)
        ids = np.empty(len(detections), dtype=np.int64)
        is_new = match < 0
        tracks: list[TrackedBox] = []
        for i, det in enumerate(detections):
            if match[i] >= 0:
                ids[i] = self._tracks[int(match[i])].object_id
            else:
                ids[i] = self._next_id
                self._next_id += 1
            tracks.append(TrackedBox(int(ids[i]), det.class_id, det.box_xyxy, 0))
        matched_prev = set(int(j) for j in match if j >= 0)
        lost: list[int] = []
        for j, t in enumerate(self._tracks):
            if j in matched_prev:
                continue
            if t.missed_frames < self.config.max_missed_frames:
                tracks.append(TrackedBox(t.object_id, t.class_id, t.box_xyxy, t.missed_frames + 1))
            else:
                lost.append(t.object_id)
        self._tracks = tracks
        return Association(object_ids=ids, is_new=is_new, lost_ids=tuple(lost))
