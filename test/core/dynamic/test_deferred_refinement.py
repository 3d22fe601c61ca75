"""Deferred pose refinement: tracked frames' poses optimised again once the detections around them are in."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from changing_slam_ros.core.dynamic.deferred_refinement import (
    DeferredRefinement,
    RefinementConfig,
    TrackedFrameMatches,
    interpolated_boxes,
    refine_frame,
)
from changing_slam_ros.core.dynamic.detector import Detection, DetectionSet
from changing_slam_ros.core.dynamic.keypoint_classification import KeypointClassificationConfig
from changing_slam_ros.core.geometry.pose_optimizer import PinholeStereo, PoseObservations, optimize_pose
from changing_slam_ros.core.geometry.se3 import invert
from changing_slam_ros.errors import ConfigError

MS = 1_000_000
CAM = PinholeStereo(250.0, 250.0, 160.0, 120.0, 40.0)
PERSON = (130.0, 50.0, 190.0, 210.0)  # where the person is in the frame (x0, y0, x1, y1), at 2 m before a 4 m wall


def _rot(axis: tuple[float, float, float], deg: float) -> np.ndarray:
    return cv2.Rodrigues(np.radians(deg) * np.asarray(axis, dtype=np.float64))[0]


def _frame(stamp_ns: int, record_index: int = 0, person_shift_m: float = 0.015) -> tuple[TrackedFrameMatches, np.ndarray]:
    """A tracked frame of a synthetic scene and its true pose: 220 static points (3-6 m) and 90 points on a
    person (2 m, in front of a 4 m wall) whose map points were made before the person stepped `person_shift_m` to the right. The tracked pose is
    what tracking's optimisation gives on all matches, its inliers kept, as tracking keeps them: pulled by the
    person. Returns (frame, T_world_cam true)."""
    rng = np.random.default_rng(3)
    T_true = np.eye(4)
    T_true[:3, :3] = _rot((0.3, 1.0, 0.1), 2.0)
    T_true[:3, 3] = (0.04, -0.02, 0.03)
    x0, y0, x1, y1 = PERSON
    wall_px = rng.uniform((5.0, 5.0), (315.0, 235.0), (400, 2))
    wall_px = wall_px[~((wall_px[:, 0] > x0 - 3) & (wall_px[:, 0] < x1 + 3) & (wall_px[:, 1] > y0 - 3) & (wall_px[:, 1] < y1 + 3))][:220]
    person_px = rng.uniform((x0 + 4, y0 + 4), (x1 - 4, y1 - 4), (90, 2))
    px = np.vstack([wall_px, person_px])
    z = np.r_[rng.uniform(3.0, 6.0, len(wall_px)), np.full(len(person_px), 2.0)]  # the room's depths vary
    pc = np.c_[(px[:, 0] - CAM.cx) * z / CAM.fx, (px[:, 1] - CAM.cy) * z / CAM.fy, z]  # where they are now (camera)
    now_w = pc @ T_true[:3, :3].T + T_true[:3, 3]
    map_w = now_w.copy()
    map_w[len(wall_px):, 0] -= person_shift_m  # the person's map points: where it was
    uv = px + rng.normal(0.0, 0.2, px.shape)
    u_right = uv[:, 0] - CAM.bf / z
    inv_sigma2 = np.ones(len(px))
    T_start = T_true.copy()
    T_start[:3, 3] += (0.01, 0.0, -0.01)
    res = optimize_pose(invert(T_start), PoseObservations(map_w, uv, u_right, inv_sigma2), CAM)
    keep = res.inliers
    assert keep[len(wall_px):].mean() > 0.9  # the person's matches are inliers: they pull the pose
    depth = np.full((240, 320), 4.0, np.float32)
    depth[int(y0) : int(y1) + 1, int(x0) : int(x1) + 1] = 2.0
    T_tracked = invert(res.T_cam_world)
    frame = TrackedFrameMatches(
        stamp_ns, record_index, T_tracked, T_tracked.copy(), uv[keep], uv[keep], u_right[keep], inv_sigma2[keep],
        np.flatnonzero(keep).astype(np.int64), map_w[keep], depth, CAM,
    )
    return frame, T_true


def _person_set(stamp_ns: int, dx_px: float) -> DetectionSet:
    x0, y0, x1, y1 = PERSON
    return DetectionSet(stamp_ns, (Detection((x0 + dx_px, y0, x1 + dx_px, y1), 0, 0.9),), 320, 240)


def _error_m(T: np.ndarray, T_true: np.ndarray) -> float:
    return float(np.linalg.norm(T[:3, 3] - T_true[:3, 3]))


def test_a_bracketed_frame_loses_its_person_matches_and_its_pose_error_drops():
    # The person walks right: 12 px left of the frame's place in the detections 50 ms before, 12 px right in those
    # 50 ms after; interpolated, the box lands on the person (the wall behind it stays, by its depth).
    frame, T_true = _frame(1050 * MS, record_index=7)
    before_m = _error_m(frame.T_world_cam, T_true)
    assert before_m > 0.01  # tracked with the person's stale map points: 22 mm off
    ring = DeferredRefinement(RefinementConfig(enabled=True))
    assert ring.add(frame) == []  # no detections after it yet
    assert ring.on_detections(_person_set(1000 * MS, -12.0)) == []  # before it: nothing bracketed yet
    (refined,) = ring.on_detections(_person_set(1100 * MS, 12.0))
    assert (refined.stamp_ns, refined.record_index) == (1050 * MS, 7)
    assert refined.n_person == int((frame.point_ids >= 220).sum())  # every person match, no wall match
    after_m = _error_m(refined.T_world_cam, T_true)
    assert after_m < 0.2 * before_m and after_m < 0.003  # the static matches alone: 1.3 mm (their noise)
    # The relative pose moves by the same correction: T_ref_cam = T_ref_cam(tracked) @ inv(T tracked) @ T refined.
    assert refined.T_ref_cam == pytest.approx(frame.T_ref_cam @ invert(frame.T_world_cam) @ refined.T_world_cam, abs=1e-12)
    assert refined.translation_m == pytest.approx(float(np.linalg.norm(refined.T_world_cam[:3, 3] - frame.T_world_cam[:3, 3])), abs=1e-9)
    assert ring.stats.frames_refined == 1 and ring.stats.matches_dropped == refined.n_person


def test_in_the_current_map_every_bracketed_frame_is_optimised_again_and_keeps_its_place_relative_to_the_keyframe():
    # Local BA moved the frame's reference keyframe and its points together (rigidly, by G) after it was tracked.
    G = np.eye(4)
    G[:3, :3] = _rot((0.0, 0.0, 1.0), 1.0)
    G[:3, 3] = (0.02, 0.0, -0.01)

    def now(f: TrackedFrameMatches) -> TrackedFrameMatches:
        return f.in_map(G @ f.T_world_cam, np.ones(len(f), bool), f.points_w @ G[:3, :3].T + G[:3, 3])

    frame, T_true = _frame(1050 * MS, record_index=1)
    plain = DeferredRefinement(RefinementConfig(enabled=True))
    moved = DeferredRefinement(RefinementConfig(enabled=True, settle_s=0.0))  # at once, not settle_s later
    for ring in (plain, moved):
        ring.add(frame)
        ring.on_detections(_person_set(1000 * MS, -12.0))
    (without,) = plain.on_detections(_person_set(1100 * MS, 12.0))
    (within,) = moved.on_detections(_person_set(1100 * MS, 12.0), now)
    assert _error_m(within.T_world_cam, G @ T_true) < 0.003  # refined in the moved map
    assert within.T_ref_cam == pytest.approx(without.T_ref_cam, abs=1e-6)  # the same place relative to the keyframe
    # Person boxes away from the frame's matches: in the current map the frame is optimised again all the same; in
    # the map as tracked (or with current_map off) it is left alone.
    corner = (Detection((0.0, 0.0, 2.0, 2.0), 0, 0.9),)  # a person box where no tracked keypoint lies
    away = (DetectionSet(2000 * MS, corner, 320, 240), DetectionSet(2100 * MS, corner, 320, 240))
    at_once = RefinementConfig(enabled=True, settle_s=0.0)
    for cfg, hand_over, optimised in ((at_once, True, 1), (at_once, False, 0),
                                      (dataclasses.replace(at_once, current_map=False), True, 0)):  # fmt: skip
        ring = DeferredRefinement(cfg)
        ring.add(dataclasses.replace(frame, stamp_ns=2050 * MS))
        ring.on_detections(away[0])
        out = ring.on_detections(away[1], now if hand_over else None)
        assert (ring.stats.frames_optimised, len(out), ring.stats.matches_dropped) == (optimised, optimised, 0)


def _same_map(f: TrackedFrameMatches) -> TrackedFrameMatches:
    return f.in_map(f.T_world_cam, np.ones(len(f), bool), f.points_w)


def test_bracketed_frames_settle_settle_s_after_they_were_tracked_or_at_the_end():
    ring = DeferredRefinement(RefinementConfig(enabled=True, settle_s=1.0))
    frame, T_true = _frame(1050 * MS, record_index=1)
    ring.add(frame, _same_map)
    ring.add(dataclasses.replace(frame, stamp_ns=1150 * MS, record_index=2), _same_map)
    ring.on_detections(_person_set(1000 * MS, -12.0), _same_map)
    assert ring.on_detections(_person_set(1100 * MS, 12.0), _same_map) == []  # bracketed: waits for the map to settle
    assert len(ring) == 2 and ring.stats.frames_bracketed == 1 and ring.stats.frames_optimised == 0
    # A frame tracked 1 s after it: the bracketed frame is optimised again now and leaves the ring; the frame of
    # 1150 ms, never bracketed, is forgotten after max_age_s.
    (settled,) = ring.add(dataclasses.replace(frame, stamp_ns=2050 * MS, record_index=3), _same_map)
    assert settled.record_index == 1 and _error_m(settled.T_world_cam, T_true) < 0.003
    assert [f.record_index for f in ring._frames] == [3]  # noqa: SLF001
    # The end of the run: what is bracketed settles; the rest stays as tracked.
    ring.on_detections(_person_set(2100 * MS, 0.0), _same_map)
    ring.on_detections(_person_set(2000 * MS, -10.0), _same_map)  # late and out of order: brackets 2050 with 2100
    (last,) = ring.settle_all(_same_map)
    assert last.record_index == 3 and len(ring) == 0
    assert ring.settle_all(_same_map) == []
    assert ring.stats.frames_refined == 2 and ring.stats.cpu_ms > 0.0


def test_frames_without_detections_on_both_sides_keep_their_pose():
    cfg = RefinementConfig(enabled=True, max_bracket_gap_s=0.3)
    ring = DeferredRefinement(cfg)
    for k, stamp in enumerate((1000, 1033, 1066, 1100, 1133)):
        assert ring.add(_frame(stamp * MS, record_index=k)[0]) == []
    # The first set ever, of frame 1100: only its own frame is refined (its boxes are exact); the frames before
    # it have no set before them, and 1133 comes after it.
    (own,) = ring.on_detections(_person_set(1100 * MS, 0.0))
    assert own.record_index == 3
    # A set 0.4 s later (over max_bracket_gap_s): 1133 lies between the two but is not bracketed.
    assert ring.on_detections(_person_set(1500 * MS, 0.0)) == []
    # A set of a frame never tracked (dropped), nothing kept in its bracket: nothing to refine.
    assert ring.on_detections(_person_set(1600 * MS, 0.0)) == []
    # A set that came twice is not used twice.
    assert ring.on_detections(_person_set(1100 * MS, 0.0)) == []
    assert ring.stats.frames_bracketed == 1


def test_a_frame_off_every_person_box_or_without_boxes_is_left_as_tracked():
    frame, _ = _frame(1050 * MS)
    cfg = RefinementConfig(enabled=True)
    cls = KeypointClassificationConfig()
    far = (Detection((0.0, 0.0, 2.0, 2.0), 0, 0.9),)  # a person box where no tracked keypoint lies
    assert refine_frame(frame, (), cfg, cls) == (None, 0)
    refined, n_person = refine_frame(frame, far, cfg, cls)
    assert refined is None and n_person == 0
    # The person's matches taken away but too few left to trust the pose.
    strict = dataclasses.replace(cfg, min_inliers=len(frame))
    refined, n_person = refine_frame(frame, (Detection(PERSON, 0, 0.9),), strict, cls)
    assert refined is None and n_person > 0


def test_a_frame_tracked_after_the_sets_around_it_arrived_is_refined_when_added_but_not_one_tracked_with_its_own():
    frame, T_true = _frame(1050 * MS, record_index=2)
    ring = DeferredRefinement(RefinementConfig(enabled=True))
    ring.on_detections(_person_set(1000 * MS, -12.0))
    ring.on_detections(_person_set(1100 * MS, 12.0))
    (refined,) = ring.add(frame)
    assert refined.record_index == 2
    assert _error_m(refined.T_world_cam, T_true) < 0.3 * _error_m(frame.T_world_cam, T_true)
    # A frame whose own detections were in when it was tracked (lossless: every frame) was tracked with them.
    ring.on_detections(_person_set(1150 * MS, 0.0))
    assert ring.add(dataclasses.replace(frame, stamp_ns=1150 * MS, record_index=3)) == []


def test_the_ring_forgets_frames_older_than_max_age_and_beyond_max_frames():
    ring = DeferredRefinement(RefinementConfig(enabled=True, max_age_s=0.1, max_frames=3))
    frame, _ = _frame(0)
    for k in range(6):
        ring.add(dataclasses.replace(frame, stamp_ns=k * 33 * MS, record_index=k))
    assert len(ring) == 3  # max_frames; 0.1 s behind 165 ms keeps 66, 99, 132, 165: four
    assert ring.nbytes == 3 * frame.nbytes and frame.nbytes == len(frame) * 80
    ring.add(dataclasses.replace(frame, stamp_ns=400 * MS, record_index=6))
    assert len(ring) == 1  # max_age_s


def test_boxes_are_interpolated_between_paired_boxes_and_carried_when_unpaired():
    cfg = RefinementConfig(interpolated_grow_widths_per_s=0.0, carried_grow_widths_per_s=1.0)
    before = DetectionSet(1000 * MS, (Detection((100.0, 50.0, 150.0, 150.0), 0, 0.8),
                                      Detection((10.0, 10.0, 30.0, 50.0), 0, 0.9),
                                      Detection((200.0, 100.0, 260.0, 160.0), 56, 0.9)), 320, 240)  # fmt: skip
    after = DetectionSet(1100 * MS, (Detection((120.0, 60.0, 170.0, 170.0), 0, 0.9),
                                     Detection((280.0, 20.0, 300.0, 60.0), 0, 0.7)), 320, 240)  # fmt: skip
    walker, left, entering = interpolated_boxes(before, after, 1025 * MS, cfg, 320, 240)
    assert walker.box_xyxy == pytest.approx((105.0, 52.5, 155.0, 155.0))  # a quarter of the way
    assert walker.score == 0.9
    # Only in the set before: carried from 1000 ms, grown 0.025 s x 1 width/s = 2.5 % per side (0.5 px, 1 px).
    assert left.box_xyxy == pytest.approx((9.5, 9.0, 30.5, 51.0))
    # Only in the set after: carried back 0.075 s: 7.5 % per side (1.5 px, 3 px).
    assert entering.box_xyxy == pytest.approx((278.5, 17.0, 301.5, 63.0))
    # The class not listed (chair, 56) is left out; the later set's own frame takes its boxes as they are.
    assert [d.box_xyxy for d in interpolated_boxes(before, after, 1100 * MS, cfg)] == [d.box_xyxy for d in after.detections]
    grown = interpolated_boxes(before, after, 1050 * MS, dataclasses.replace(cfg, interpolated_grow_widths_per_s=1.0))[0]
    assert grown.box_xyxy == pytest.approx((110.0 - 2.5, 55.0 - 5.25, 160.0 + 2.5, 160.0 + 5.25))  # 5 % per side at mid-way


def test_boxes_of_different_classes_or_without_overlap_are_not_paired():
    cfg = RefinementConfig(class_ids=(0, 56), interpolated_grow_widths_per_s=0.0, carried_grow_widths_per_s=0.0)
    before = DetectionSet(0, (Detection((0.0, 0.0, 50.0, 50.0), 56, 0.9), Detection((200.0, 0.0, 250.0, 50.0), 0, 0.9)))
    after = DetectionSet(100 * MS, (Detection((0.0, 0.0, 50.0, 50.0), 0, 0.9),))
    boxes = interpolated_boxes(before, after, 50 * MS, cfg)
    assert sorted(d.box_xyxy for d in boxes) == [(0.0, 0.0, 50.0, 50.0), (0.0, 0.0, 50.0, 50.0), (200.0, 0.0, 250.0, 50.0)]


def test_bad_settings_are_named():
    with pytest.raises(ConfigError, match="max_bracket_gap_s"):
        RefinementConfig(max_bracket_gap_s=0.0)
    with pytest.raises(ConfigError, match="max_age_s"):
        RefinementConfig(max_age_s=-1.0)
    with pytest.raises(ConfigError, match="grow"):
        RefinementConfig(carried_grow_widths_per_s=-0.1)


def test_the_tracking_section_parses_the_refinement_settings():
    from changing_slam_ros.config import section
    from changing_slam_ros.core.slam.tracking_config import TrackingConfig

    cfg = section(TrackingConfig, {"deferred_refinement": {"enabled": True, "max_age_s": 0.4}}, "sim.yaml: tracking")
    assert cfg.deferred_refinement == RefinementConfig(enabled=True, max_age_s=0.4)
    with pytest.raises(ConfigError, match="deferred_refinement"):
        section(TrackingConfig, {"deferred_refinement": {"enable": True}}, "sim.yaml: tracking")



# -- in the SLAM system: late detections replayed on a simulated walking sequence ----------------------------------


@pytest.mark.slow
def test_the_system_refines_bracketed_frames_only_and_leaves_the_online_poses_and_the_map_alone(tmp_path):
    """walking_xyz (seed 0, 320x240, 30 fps, 60 frames, oracle boxes), each frame's boxes usable 4 frames later on
    every 3rd frame (the graph's 1x cadence, as bench/late_detections.py replays it), carried forward to the frames
    without their own: with the refinement on, the online trajectory and the keyframes are the run without it to
    the bit, frames that no two detection sets bracket keep their final pose, and bracketed frames are refined
    (1 s later, or at the end of the run)."""
    from changing_slam_ros.core.dynamic.dynamic_filter import DynamicConfig, DynamicFilter
    from changing_slam_ros.core.dynamic.late_detections import CarryConfig, carried_forward
    from changing_slam_ros.core.system import SlamSystem, SystemConfig
    from changing_slam_ros.core.slam.tracking_config import TrackingConfig
    from changing_slam_ros.io.dataset import open_dataset
    from changing_slam_ros.io.detections_file import find_detections_file, read_detections_file
    from changing_slam_ros.sim.scenarios import build_scenario
    from changing_slam_ros.sim.sequence import RenderOptions, simulate

    simulate(build_scenario("walking_xyz", 0), tmp_path, RenderOptions(width=320, height=240, frames=60, fps=30.0), 0)
    frames = list(open_dataset(tmp_path, "sim"))
    oracle = read_detections_file(find_detections_file(tmp_path))
    sets = [DetectionSet(f.stamp_ns, oracle.for_stamp(f.stamp_ns), 320, 240) for f in frames]
    every, delay = 3, 4
    carry = CarryConfig(flow=False)

    def run(refine: bool) -> SlamSystem:
        tracking = TrackingConfig(deferred_refinement=RefinementConfig(enabled=refine, settle_s=1.0))
        system = SlamSystem(SystemConfig(tracking=tracking), dynamic_filter=DynamicFilter(DynamicConfig()))
        newest = None
        for i, rgbd in enumerate(frames):
            j = i - delay
            if j >= 0 and j % every == 0:  # frame j's detections arrive now
                newest = sets[j]
                system.refine_with_detections(sets[j])
            system.process(rgbd, None if newest is None else carried_forward(newest, rgbd.stamp_ns, carry))
        system.settle_refinement()  # the end of the run: the frames of the last second settle now
        return system

    off, on = run(False), run(True)
    assert on.refinement is not None and off.refinement is None
    for a, b in ((off.online_trajectory(), on.online_trajectory()), (off.keyframe_trajectory(), on.keyframe_trajectory())):
        assert np.array_equal(a.stamps_s, b.stamps_s) and np.array_equal(a.positions, b.positions)
        assert np.array_equal(a.quats_xyzw, b.quats_xyzw)
    last_set_ns = sets[(len(frames) - 1 - delay) // every * every].stamp_ns
    changed = [a.T_ref_cam is not None and not np.array_equal(a.T_ref_cam, b.T_ref_cam) for a, b in zip(off.records, on.records)]
    for rec, moved in zip(on.records, changed):
        if rec.stamp_ns > last_set_ns or rec.stamp_ns <= sets[0].stamp_ns:  # after the last set, or before the first
            assert not moved
    stats = on.refinement.stats
    assert sum(changed) == stats.frames_refined >= 5
    assert stats.frames_optimised <= stats.frames_bracketed <= len(frames)
