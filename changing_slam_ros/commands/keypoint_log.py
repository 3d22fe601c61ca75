"""`changing-slam run --keypoint-log FILE.npz`: every frame's keypoints and the dynamic stage's verdict on each,
for scoring moving-keypoint detection against ground-truth masks (`eval.moving_keypoints`).

A read-only wrapper around the run's `DynamicFilter`: it forwards every call and copies what
`before_tracking` saw and returned. The file holds, concatenated over frames (K keypoints in all):
`stamps_ns` (F,), `offsets` (F + 1,) row ranges per frame, `keypoints_px` (K, 2) float32, `keep` (K,) bool,
`moving` (K,) bool (class-agnostic cue: segmentation or mover tracking), `kp_classes` (K,) int8
(`KeypointClass`, from the detections: 2 = dynamic class, 1 = movable, 3 = unused).
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import numpy as np

from changing_slam_ros.core.dynamic.dynamic_filter import DynamicFilter, DynamicFrame
from changing_slam_ros.core.features.orb_features import Features
from changing_slam_ros.core.features.rgbd_frame import RgbdFrame
from changing_slam_ros.io.atomic import atomic_write_bytes


class KeypointLog:
    """Wraps a DynamicFilter; behaves as it does, and remembers each frame's keypoints and verdict."""

    def __init__(self, inner: DynamicFilter) -> None:
        self._inner = inner
        self._stamps: list[int] = []
        self._kps: list[np.ndarray] = []
        self._keep: list[np.ndarray] = []
        self._moving: list[np.ndarray] = []
        self._classes: list[np.ndarray] = []

    def __getattr__(self, name: str) -> Any:
        return getattr(self._inner, name)

    def before_tracking(self, rgbd: RgbdFrame, features: Features, detections: Any) -> DynamicFrame:
        out = self._inner.before_tracking(rgbd, features, detections)
        self._stamps.append(int(rgbd.stamp_ns))
        self._kps.append(np.asarray(features.keypoints_px, dtype=np.float32).reshape(-1, 2))
        self._keep.append(np.asarray(out.keep, dtype=bool))
        self._moving.append(np.asarray(out.moving, dtype=bool))
        self._classes.append(np.asarray(out.kp_classes, dtype=np.int8))
        return out

    def withheld_used(self, frame: DynamicFrame) -> None:
        """Tracking used the withheld keypoints of the last frame: the log keeps them as kept too."""
        self._inner.withheld_used(frame)
        if frame.withheld is not None and self._keep:
            self._keep[-1] = self._keep[-1] | frame.withheld

    def write(self, path: Path) -> None:
        """The log as a compressed npz, written atomically."""
        sizes = [len(k) for k in self._kps]
        buf = io.BytesIO()
        np.savez_compressed(
            buf, stamps_ns=np.array(self._stamps, dtype=np.int64),
            offsets=np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64),
            keypoints_px=np.concatenate(self._kps) if self._kps else np.zeros((0, 2), np.float32),
            keep=np.concatenate(self._keep) if self._keep else np.zeros(0, bool),
            moving=np.concatenate(self._moving) if self._moving else np.zeros(0, bool),
            kp_classes=np.concatenate(self._classes) if self._classes else np.zeros(0, np.int8),
        )
        atomic_write_bytes(Path(path), buf.getvalue())
