"""Carrying an earlier image's detections forward to a later frame (real-time tracking)."""

from __future__ import annotations

import pytest

from changing_slam_ros.core.detector import Detection, DetectionSet
from changing_slam_ros.core.late_detections import CarryConfig, carried_forward

MS = 1_000_000


def test_boxes_grow_with_age_and_stay_in_the_image():
    earlier = DetectionSet(1000 * MS, (Detection((100.0, 50.0, 150.0, 150.0), 0, 0.9),
                                       Detection((0.0, 200.0, 40.0, 239.0), 56, 0.8)), 320, 240)  # fmt: skip
    cfg = CarryConfig(max_age_s=0.5, grow_widths_per_s=1.0, class_ids=(0, 56))
    person, chair = carried_forward(earlier, 1100 * MS, cfg)  # 0.1 s later: 10 % of the size per side
    assert person.box_xyxy == pytest.approx((95.0, 40.0, 155.0, 160.0))
    assert (person.class_id, person.score) == (0, 0.9)
    assert chair.box_xyxy == pytest.approx((0.0, 196.1, 44.0, 239.0))  # clipped at the left and bottom edges
    assert carried_forward(earlier, 1000 * MS, cfg) is None  # not older than the frame
    assert carried_forward(earlier, 900 * MS, cfg) is None  # a later image's detections: never backwards
    assert carried_forward(earlier, 1600 * MS, cfg) is None  # too old


def test_only_the_configured_classes_are_carried():
    earlier = DetectionSet(0, (Detection((10.0, 10.0, 20.0, 20.0), 0, 0.9), Detection((30.0, 30.0, 40.0, 40.0), 56, 0.8)))
    carried = carried_forward(earlier, 50 * MS, CarryConfig())  # default: person only
    assert [d.class_id for d in carried] == [0]
