"""`core.dynamic.detection_cadence.DetectionCadence`: the detector on every n-th frame, the frames between with
the last boxes carried by their image motion; the same boxes reach the same frames in serial and overlapped
runs (`commands.frame_pipeline`)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from changing_slam_ros.commands.frame_pipeline import FramePipeline
from changing_slam_ros.core.dynamic.detection_cadence import DetectionCadence
from changing_slam_ros.core.dynamic.detector import Detection, DetectionSet
from changing_slam_ros.core.features.rgbd_frame import RgbdFrame
from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.errors import ConfigError

CAM = CameraIntrinsics(width=320, height=240, fx=262.5, fy=262.5, cx=159.5, cy=119.5)
STEP_PX = 6  # the textured 'person' moves this far right per frame (30 fps)
MS = 1_000_000


def frames(n: int) -> list[RgbdFrame]:
    rng = np.random.default_rng(3)
    patch = cv2.GaussianBlur(rng.integers(0, 256, (80, 50)).astype(np.uint8), (5, 5), 1.5)
    out = []
    for k in range(n):
        grey = np.full((240, 320), 90, np.uint8)
        depth = np.full((240, 320), 4.0, np.float32)
        x = 60 + STEP_PX * k
        grey[60:140, x:x + 50] = patch
        depth[60:140, x:x + 50] = 2.0
        out.append(RgbdFrame(stamp_ns=k * 33 * MS, rgb=np.repeat(grey[..., None], 3, axis=2), depth_m=depth,
                             camera=CAM, index=k))  # fmt: skip
    return out


class TrueBoxes:
    """A detector that boxes the person exactly where it is; counts its calls."""

    def __init__(self) -> None:
        self.calls: list[int] = []

    def __call__(self, frame: RgbdFrame) -> DetectionSet:
        self.calls.append(frame.index)
        x = 60.0 + STEP_PX * frame.index
        return DetectionSet(frame.stamp_ns, (Detection((x, 60.0, x + 49.0, 139.0), 0, 0.9),), 320, 240)


def test_every_third_frame_is_detected_and_the_boxes_between_follow_the_person() -> None:
    detector = TrueBoxes()
    cadence = DetectionCadence(detector, every=3)
    seq = frames(9)
    boxes = [cadence(f) for f in seq]
    assert detector.calls == [0, 3, 6]
    assert (cadence.n_detected, cadence.n_carried) == (3, 6)
    for f, found in zip(seq, boxes, strict=True):
        (d,) = found
        x = 60.0 + STEP_PX * f.index
        centre = ((d.box_xyxy[0] + d.box_xyxy[2]) / 2, (d.box_xyxy[1] + d.box_xyxy[3]) / 2)
        assert centre == pytest.approx((x + 24.5, 99.5), abs=1.0)  # moved with the person, not left behind
        assert d.box_xyxy[2] - d.box_xyxy[0] <= 49.0 * (1 + 2 * 0.25 * 0.07) + 1e-6  # grown by its age only


def test_every_frame_detected_is_the_reference_and_bad_cadences_are_refused() -> None:
    detector = TrueBoxes()
    cadence = DetectionCadence(detector, every=1)
    assert [len(cadence(f)) for f in frames(4)] == [1, 1, 1, 1] and detector.calls == [0, 1, 2, 3]
    with pytest.raises(ConfigError, match="every >= 1"):
        DetectionCadence(detector, every=0)


def test_serial_and_overlapped_runs_give_each_frame_the_same_boxes() -> None:
    seq = frames(10)
    runs = []
    for overlap in (False, True):
        cadence = DetectionCadence(TrueBoxes(), every=2)
        with FramePipeline(iter(seq), len(seq), cadence, overlap=overlap) as pipeline:
            runs.append([(f.index, d) for f, d in pipeline])
    assert runs[0] == runs[1] and len(runs[0]) == 10
