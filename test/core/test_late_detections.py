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


def test_a_carried_box_moves_on_at_the_velocity_of_its_edges_since_the_detections_before():
    # A person walking right: 20 px in the 0.1 s between two detection sets; the frame is 0.15 s after the newer.
    before = DetectionSet(1000 * MS, (Detection((100.0, 50.0, 150.0, 150.0), 0, 0.9),), 320, 240)
    newer = DetectionSet(1100 * MS, (Detection((120.0, 50.0, 170.0, 150.0), 0, 0.8),
                                     Detection((10.0, 10.0, 30.0, 40.0), 0, 0.7)), 320, 240)  # fmt: skip
    cfg = CarryConfig(grow_widths_per_s=0.0, extrapolate=True)
    walker, other = carried_forward(newer, 1250 * MS, cfg, before)
    assert walker.box_xyxy == pytest.approx((150.0, 50.0, 200.0, 150.0))  # +200 px/s x 0.15 s
    assert other.box_xyxy == pytest.approx((10.0, 10.0, 30.0, 40.0))  # no match before: left where it was
    # Growing comes after the move: 0.15 s x 0.5 widths/s = 7.5 % of 50 px per side.
    grown, _ = carried_forward(newer, 1250 * MS, CarryConfig(grow_widths_per_s=0.5, extrapolate=True), before)
    assert grown.box_xyxy == pytest.approx((146.25, 42.5, 203.75, 157.5))
    # Without extrapolation, or without an earlier set, the box stays put.
    assert carried_forward(newer, 1250 * MS, CarryConfig(grow_widths_per_s=0.0, extrapolate=False), before)[0].box_xyxy \
        == pytest.approx((120.0, 50.0, 170.0, 150.0))  # fmt: skip
    assert carried_forward(newer, 1250 * MS, cfg)[0].box_xyxy == pytest.approx((120.0, 50.0, 170.0, 150.0))


def test_extrapolation_needs_a_close_match_of_the_same_class_and_clamps_the_speed():
    newer = DetectionSet(1100 * MS, (Detection((120.0, 50.0, 170.0, 150.0), 0, 0.8),), 320, 240)
    cfg = CarryConfig(grow_widths_per_s=0.0, extrapolate=True)
    chair = DetectionSet(1000 * MS, (Detection((100.0, 50.0, 150.0, 150.0), 56, 0.9),), 320, 240)
    far = DetectionSet(1000 * MS, (Detection((250.0, 50.0, 300.0, 150.0), 0, 0.9),), 320, 240)  # IoU 0
    stale = DetectionSet(400 * MS, (Detection((100.0, 50.0, 150.0, 150.0), 0, 0.9),), 320, 240)  # 0.7 s before
    for previous in (chair, far, stale):
        assert carried_forward(newer, 1250 * MS, cfg, previous)[0].box_xyxy == pytest.approx((120.0, 50.0, 170.0, 150.0))
    # 30 px in 10 ms is 3000 px/s: clamped to 4 widths/s (200 px/s in x), so +30 px after 0.15 s, not +450.
    jump = DetectionSet(1090 * MS, (Detection((90.0, 50.0, 140.0, 150.0), 0, 0.9),), 320, 240)
    assert carried_forward(newer, 1250 * MS, cfg, jump)[0].box_xyxy == pytest.approx((150.0, 50.0, 200.0, 150.0))
