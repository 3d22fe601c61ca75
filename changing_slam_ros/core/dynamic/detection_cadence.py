"""Offline detection on every n-th frame, the frames between taking the last detections carried forward.

The detector is the dearest stage of the default pipeline (a 300x300 SSD on every frame, ~50 ms of CPU here),
and offline it runs on a thread beside tracking, so at 30 fps it bounds the run. `DetectionCadence` runs it on
frames 0, n, 2n, ... of the sequence and gives each frame between the newest detections carried to it
(`late_detections.carried_forward`: each box moved by the image motion of its foreground, Median Flow, then
grown by its age); what a frame sees depends only on the frame order, never on timing, in `--serial` and
overlapped runs alike. Every class is carried (not only people, as the real-time graph does): a movable object
whose box vanished on every other frame would lose its EKF track (short-term association has no miss budget).
`every` = 1 detects every frame, the reference order.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from changing_slam_ros.core.dynamic.box_flow import FlowImage
from changing_slam_ros.core.dynamic.detector import COCO80_NAMES, Detection, DetectionSet
from changing_slam_ros.core.dynamic.late_detections import CarryConfig, carried_forward
from changing_slam_ros.core.features.rgbd_frame import RgbdFrame
from changing_slam_ros.errors import ConfigError

ALL_CLASSES = tuple(range(len(COCO80_NAMES)))


@dataclass
class DetectionCadence:
    """Detect on every `every`-th frame in call order (`detect(frame)` gives that frame's `DetectionSet`); the
    frames between get the last set carried forward with `carry` (its `max_age_s` bounds how old a carried set
    may be: older, the frame gets no boxes)."""

    detect: Callable[[RgbdFrame], DetectionSet]
    every: int = 1
    carry: CarryConfig = field(default_factory=lambda: CarryConfig(class_ids=ALL_CLASSES))
    n_detected: int = 0
    n_carried: int = 0
    _count: int = 0
    _last: tuple[DetectionSet, FlowImage] | None = None  # the newest detected set and the image it was made on

    def __post_init__(self) -> None:
        if self.every < 1:
            raise ConfigError(f"detection cadence: expected every >= 1 frame, got {self.every}")

    def __call__(self, frame: RgbdFrame) -> tuple[Detection, ...]:
        k = self._count
        self._count += 1
        if k % self.every == 0:  # frame 0 always: a carried frame has a detected one before it
            found = self.detect(frame)
            self.n_detected += 1
            if self.every > 1:
                self._last = (found, FlowImage.from_rgb(frame.stamp_ns, frame.rgb, frame.depth_m))
            return found.detections
        assert self._last is not None
        self.n_carried += 1
        detected, image = self._last
        now = FlowImage.from_rgb(frame.stamp_ns, frame.rgb, frame.depth_m)
        return carried_forward(detected, frame.stamp_ns, self.carry, images=(image, now)) or ()
