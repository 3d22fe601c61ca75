"""Carrying an earlier image's detections forward to a later frame (real-time tracking)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from changing_slam_ros.core.dynamic.box_flow import BoxFlowConfig, FlowImage, box_motion, grid_points
from changing_slam_ros.core.dynamic.detector import Detection, DetectionSet
from changing_slam_ros.core.dynamic.late_detections import CarryConfig, RecentImages, carried_forward

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


# -- carried boxes moved by the image motion (core.box_flow) ------------------------------------------------------


def _textured_person(shift_xy: tuple[int, int], scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """A 320x240 grey image: a flat wall (depth 4 m) and a textured 50x80 px 'person' (depth 2 m) whose top-left
    corner is at (100, 60) + shift, resized by `scale` about that corner; returns (grey, depth)."""
    rng = np.random.default_rng(7)
    patch = cv2.GaussianBlur(rng.integers(0, 256, (80, 50)).astype(np.uint8), (5, 5), 1.5)
    if scale != 1.0:
        patch = cv2.resize(patch, None, fx=scale, fy=scale, interpolation=cv2.INTER_LINEAR)
    grey = np.full((240, 320), 90, np.uint8)
    depth = np.full((240, 320), 4.0, np.float32)
    x, y = 100 + shift_xy[0], 60 + shift_xy[1]
    grey[y : y + patch.shape[0], x : x + patch.shape[1]] = patch
    depth[y : y + patch.shape[0], x : x + patch.shape[1]] = 2.0
    return grey, depth


def test_a_carried_box_moves_with_the_image_motion_of_the_person_inside_it():
    before, depth = _textured_person((0, 0))
    after, _ = _textured_person((9, -5))  # the person moved 9 px right and 5 px up in the 0.12 s since
    earlier = DetectionSet(1000 * MS, (Detection((100.0, 60.0, 150.0, 140.0), 0, 0.9),), 320, 240)
    images = (FlowImage(1000 * MS, before, depth), FlowImage(1120 * MS, after, None))
    cfg = CarryConfig(flow=True, flow_grow_widths_per_s=0.0)
    (moved,) = carried_forward(earlier, 1120 * MS, cfg, images=images)
    assert moved.box_xyxy == pytest.approx((109.0, 55.0, 159.0, 135.0), abs=1.0)
    # The moved box is grown by flow_grow_widths_per_s: 0.12 s x 0.25 = 3 % of the width / height per side.
    (grown,) = carried_forward(earlier, 1120 * MS, CarryConfig(flow=True, flow_grow_widths_per_s=0.25), images=images)
    assert grown.box_xyxy == pytest.approx((107.5, 52.6, 160.5, 137.4), abs=1.0)
    # flow_hull: the moved box joined with where it was (the person's path), then grown.
    (path,) = carried_forward(earlier, 1120 * MS, CarryConfig(flow=True, flow_grow_widths_per_s=0.0, flow_hull=True),
                              images=images)  # fmt: skip
    assert path.box_xyxy == pytest.approx((100.0, 55.0, 159.0, 140.0), abs=1.0)
    # Without flow (or without images) the box stays where it was, grown by grow_widths_per_s.
    (still,) = carried_forward(earlier, 1120 * MS, CarryConfig(grow_widths_per_s=0.0, flow=False), images=images)
    assert still.box_xyxy == pytest.approx((100.0, 60.0, 150.0, 140.0))


def test_the_box_motion_measures_a_shift_and_a_scale_change_on_the_foreground_only():
    before, depth = _textured_person((0, 0))
    after, _ = _textured_person((4, 3), scale=1.1)  # the person came closer: 10 % larger
    motion = box_motion((100.0, 60.0, 150.0, 140.0), FlowImage(0, before, depth), FlowImage(1, after), BoxFlowConfig())
    assert motion is not None and motion.n_points >= 30
    assert motion.scale == pytest.approx(1.1, abs=0.02)
    # the box's centre (125, 100) maps to (104 + 1.1 x 25, 63 + 1.1 x 40) = (131.5, 107)
    x0, y0, x1, y1 = motion.apply((100.0, 60.0, 150.0, 140.0))
    assert ((x0 + x1) / 2, (y0 + y1) / 2) == pytest.approx((131.5, 107.0), abs=1.0)
    # A box twice the person's width: the wall beside the person (2 m behind it) is not tracked.
    assert len(grid_points((75.0, 60.0, 175.0, 140.0), FlowImage(0, before, depth), BoxFlowConfig())) == 32


def test_without_texture_the_box_falls_back_to_the_grown_box():
    flat = np.full((240, 320), 90, np.uint8)
    earlier = DetectionSet(1000 * MS, (Detection((100.0, 60.0, 150.0, 140.0), 0, 0.9),), 320, 240)
    images = (FlowImage(1000 * MS, flat), FlowImage(1100 * MS, flat))
    cfg = CarryConfig(grow_widths_per_s=1.0, flow=True, flow_grow_widths_per_s=0.0)
    assert box_motion((100.0, 60.0, 150.0, 140.0), images[0], images[1], BoxFlowConfig()) is None
    (carried,) = carried_forward(earlier, 1100 * MS, cfg, images=images)
    assert carried.box_xyxy == pytest.approx((95.0, 52.0, 155.0, 148.0))  # grown by 1 width/s x 0.1 s
    # No valid depth in the box: no foreground points, no motion either.
    textured, _ = _textured_person((0, 0))
    no_depth = np.zeros((240, 320), np.float32)
    assert box_motion((100.0, 60.0, 150.0, 140.0), FlowImage(0, textured, no_depth), FlowImage(1, textured),
                      BoxFlowConfig()) is None  # fmt: skip


def test_the_recent_images_keep_max_age_and_find_the_nearest_stamp():
    ring = RecentImages(max_age_s=0.1, max_stamp_gap_s=0.02)
    grey = np.zeros((4, 4), np.uint8)
    for ms in (0, 33, 67, 100, 133):
        ring.add(FlowImage(ms * MS, grey))
    assert len(ring) == 4  # 0 ms is more than 0.1 s before 133 ms
    assert ring.get(0) is None
    assert ring.get(67 * MS).stamp_ns == 67 * MS
    assert ring.get(80 * MS).stamp_ns == 67 * MS  # a frame tracking dropped: the nearest within 20 ms
    assert ring.get(200 * MS) is None  # 67 ms from the newest: no image of that frame


def test_bad_box_flow_settings_and_image_pairs_are_rejected_with_the_field_named():
    from changing_slam_ros.core.dynamic.box_flow import box_motions
    from changing_slam_ros.errors import ConfigError

    with pytest.raises(ConfigError, match="box_flow.window_px"):
        BoxFlowConfig(window_px=8)
    with pytest.raises(ConfigError, match="box_flow.near_depth_percentile"):
        BoxFlowConfig(near_depth_percentile=50.0)
    small, large = FlowImage(0, np.zeros((240, 320), np.uint8)), FlowImage(1, np.zeros((480, 640), np.uint8))
    with pytest.raises(ValueError, match="image sizes differ"):
        box_motions([(0.0, 0.0, 10.0, 10.0)], small, large, BoxFlowConfig())


def test_a_box_cut_by_the_image_border_keeps_that_edge_on_the_border_and_moves_the_other():
    from changing_slam_ros.core.dynamic.box_flow import BoxMotion

    leaving = BoxMotion(dx_px=-10.0, dy_px=4.0, scale=0.8, n_points=30)  # a person walking out on the left
    # Cut on the left: the left edge stays at 0, the right edge moves 10 px left, unscaled; y moves and scales.
    assert leaving.apply((0.0, 60.0, 50.0, 140.0), 320, 240) == pytest.approx((0.0, 72.0, 40.0, 136.0))
    # Cut on the right (x1 = 319): the right edge stays, the left moves.
    assert leaving.apply((250.0, 60.0, 319.0, 140.0), 320, 240) == pytest.approx((240.0, 72.0, 319.0, 136.0))
    # Cut top and bottom (a person filling the image height): y unchanged.
    assert leaving.apply((100.0, 0.0, 150.0, 239.0), 320, 240) == pytest.approx((95.0, 0.0, 135.0, 239.0))
    # Without the image size: moved and scaled about the centre.
    assert leaving.apply((0.0, 60.0, 50.0, 140.0)) == pytest.approx((-5.0, 72.0, 35.0, 136.0))


def test_the_scale_needs_enough_points():
    a = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [10.0, 10.0], [5.0, 5.0], [2.0, 8.0]])
    b = (a - 5.0) * 1.2 + 5.0  # 20 % larger about (5, 5)
    from changing_slam_ros.core.dynamic.box_flow import _median_motion

    assert _median_motion(a, b, BoxFlowConfig(min_scale_points=5)).scale == pytest.approx(1.2)
    assert _median_motion(a, b, BoxFlowConfig(min_scale_points=12)).scale == 1.0  # 6 points: not trusted
