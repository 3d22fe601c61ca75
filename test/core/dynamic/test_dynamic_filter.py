"""DynamicFilter on constructed frames: each ablation switch changes exactly what it should."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from changing_slam_ros.config import section
from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.dynamic.detector import CHAIR_CLASS_ID, PERSON_CLASS_ID, Detection
from changing_slam_ros.core.dynamic.dynamic_filter import DynamicConfig, DynamicFilter
from changing_slam_ros.core.map.keyframe import KeypointClass
from changing_slam_ros.core.movers.flag_vote import FlagVoteConfig
from changing_slam_ros.core.features.orb_features import Features
from changing_slam_ros.core.features.rgbd_frame import RgbdFrame
from changing_slam_ros.core.geometry.se3 import invert, transform_points
from changing_slam_ros.errors import ConfigError

CAM = CameraIntrinsics(320, 240, 300.0, 300.0, 159.5, 119.5)
FRAME_NS = 33_333_333


def _features(px: np.ndarray, depths: np.ndarray, descriptors: np.ndarray | None = None) -> Features:
    n = len(px)
    desc = descriptors if descriptors is not None else np.zeros((n, 32), np.uint8)
    return Features(px.astype(float), px.astype(float), np.zeros(n, np.int64), np.zeros(n), np.ones(n), desc,
                    depths.astype(float), px[:, 0] - 40.0 / np.maximum(depths, 1e-9))


def _scene() -> tuple[RgbdFrame, Features, dict[str, np.ndarray]]:
    """A wall at 4 m, a person (1.5 m) inside a larger person box, a chair (2 m) in its own box; grid keypoints."""
    depth = np.full((240, 320), 4.0, np.float32)
    depth[50:206, 50:118] = 1.5  # person body (most of its box 40..130 x 40..220)
    depth[150:220, 220:290] = 2.0  # chair, box 215..295 x 145..225
    u, v = np.meshgrid(np.arange(10, 320, 8), np.arange(10, 240, 8))
    px = np.stack([u.ravel(), v.ravel()], axis=1).astype(float)
    d = depth[px[:, 1].astype(int), px[:, 0].astype(int)].astype(float)
    in_pbox = (px[:, 0] >= 40) & (px[:, 0] < 130) & (px[:, 1] >= 40) & (px[:, 1] < 220)
    regions = {
        "person": in_pbox & (d < 2.0),
        "behind_person": in_pbox & (d > 3.0),
        "chair": (px[:, 0] >= 215) & (px[:, 0] < 295) & (px[:, 1] >= 145) & (px[:, 1] < 225) & (d < 3.0),
    }
    g = 2.0  # keypoints within the classification's box_margin_px of a box count as inside it
    near_pbox = (px[:, 0] >= 40 - g) & (px[:, 0] < 130 + g) & (px[:, 1] >= 40 - g) & (px[:, 1] < 220 + g)
    regions["elsewhere"] = ~(near_pbox | regions["chair"]) & ~(
        (px[:, 0] >= 215 - g) & (px[:, 0] < 295 + g) & (px[:, 1] >= 145 - g) & (px[:, 1] < 225 + g)
    )
    rgbd = RgbdFrame(0, np.zeros((240, 320, 3), np.uint8), depth, CAM)
    return rgbd, _features(px, d), regions


DETS = (Detection((40.0, 40.0, 130.0, 220.0), PERSON_CLASS_ID, 0.9), Detection((215.0, 145.0, 295.0, 225.0), CHAIR_CLASS_ID, 0.8))


def _run(config: DynamicConfig, frames: int) -> tuple[list, dict[str, np.ndarray]]:
    flt = DynamicFilter(config)
    rgbd, feats, regions = _scene()
    out = []
    for k in range(frames):
        res = flt.before_tracking(dataclasses.replace(rgbd, stamp_ns=k * FRAME_NS), feats, DETS)
        flt.after_tracking(np.eye(4))
        out.append(res)
    return out, regions


def test_plain_keeps_every_keypoint_and_calls_them_static() -> None:
    (res,), _ = _run(DynamicConfig(enabled=False), 1)
    assert res.keep.all() and (res.kp_classes == KeypointClass.STATIC).all() and (res.object_ids == -1).all()


def test_detection_filtering_without_repopulation_drops_whole_boxes() -> None:
    cfg = DynamicConfig(repopulation=False, ekf_doc=False)
    results, r = _run(cfg, 5)
    for res in results:
        assert not res.keep[r["person"] | r["behind_person"] | r["chair"]].any()
        assert res.keep[r["elsewhere"]].all()
    assert (results[0].kp_classes[r["person"]] == KeypointClass.DYNAMIC).all()


def test_repopulation_keeps_the_wall_behind_the_person_and_still_drops_the_person() -> None:
    results, r = _run(DynamicConfig(ekf_doc=False), 5)
    for res in results:
        assert res.keep[r["behind_person"]].all()
        assert not res.keep[r["person"]].any()
        assert not res.keep[r["chair"]].any()  # without EKF-DOC a chair is never found static


def test_ekf_doc_uses_a_static_chair_after_a_few_frames_and_never_the_person() -> None:
    results, r = _run(DynamicConfig(min_kept_keypoints=0), 30)  # the paper: new objects filtered a priori
    assert not results[0].keep[r["chair"]].any()  # new object: filtered a priori
    first_kept = next(k for k, res in enumerate(results) if res.keep[r["chair"]].all())
    assert first_kept <= 10
    assert all(res.keep[r["chair"]].all() for res in results[first_kept:])
    assert not any(res.keep[r["person"]].any() for res in results)
    assert len({int(i) for i in results[-1].object_ids[r["chair"]]}) == 1  # one object id for the chair


def test_an_undecided_chair_is_used_from_the_first_frame_and_the_person_never() -> None:
    results, r = _run(DynamicConfig(keep_undecided=True), 30)
    assert all(res.keep[r["chair"]].all() for res in results)
    assert not any(res.keep[r["person"]].any() for res in results)


def test_undecided_objects_are_used_when_too_few_other_keypoints_are_left() -> None:
    rgbd, feats, r = _scene()  # a grid of 1131 keypoints: between 300 and 1100 kept without the chair
    for min_kept, chair_kept in ((300, False), (1100, True), (0, False)):
        res = DynamicFilter(DynamicConfig(min_kept_keypoints=min_kept)).before_tracking(rgbd, feats, DETS)
        assert res.keep[r["chair"]].all() == chair_kept and not res.keep[r["person"]].any()


def test_an_undecided_object_filling_most_of_the_view_is_used() -> None:
    """A "clock" box over 73 % of the image, on the wall at 4 m (a wall photo the detector named): with
    `undecided_view_fraction` 0.5 its keypoints are used from the first frame, the person's never; the chair's
    small box stays out until its EKF decides, unless the fraction is below its 8 %. Off (0, the default), the
    clock's keypoints stay out too."""
    rgbd, feats, r = _scene()
    clock = Detection((20.0, 20.0, 300.0, 220.0), 74, 0.6)
    in_clock = (feats.keypoints_px[:, 0] >= 22) & (feats.keypoints_px[:, 0] < 298) \
        & (feats.keypoints_px[:, 1] >= 22) & (feats.keypoints_px[:, 1] < 218) & r["elsewhere"]  # fmt: skip
    assert in_clock.sum() > 300
    for fraction, clock_kept, chair_kept in ((0.5, True, False), (0.0, False, False), (0.05, True, True)):
        cfg = DynamicConfig(min_kept_keypoints=0, undecided_view_fraction=fraction)
        res = DynamicFilter(cfg).before_tracking(rgbd, feats, (*DETS, clock))
        assert res.keep[in_clock].all() if clock_kept else not res.keep[in_clock].any()
        assert res.keep[r["chair"]].all() == chair_kept and not res.keep[r["person"]].any()
    with pytest.raises(ConfigError, match="undecided_view_fraction"):
        DynamicConfig(undecided_view_fraction=1.5)


@pytest.mark.parametrize("method", ["edge_test", "correlation"])
def test_segmentation_flags_a_group_that_moves_between_frames(method: str) -> None:
    """Static points in a room and a 40-point box moving 8 cm per frame; the camera moves too. The box hides
    the wall behind it (no static point projects inside its outline in any frame)."""
    rng = np.random.default_rng(3)
    static = np.column_stack([rng.uniform(-2, 2, 600), rng.uniform(-1.5, 1.5, 600), rng.uniform(3.0, 5.0, 600)])
    # Directions of the box over its path (x from 0.15 to 0.69 m at 1.8 m, y 0.05 to 0.35 m) are occluded.
    ray = static[:, :2] / static[:, 2:3] * 1.8
    hidden = (ray[:, 0] > 0.05) & (ray[:, 0] < 0.79) & (ray[:, 1] > -0.05) & (ray[:, 1] < 0.45)
    static = static[~hidden][:400]
    box0 = np.array([0.3, 0.2, 1.8]) + rng.uniform(-0.15, 0.15, (40, 3))
    desc = rng.integers(0, 256, (440, 32), dtype=np.uint8)
    cfg = DynamicConfig(detection_filtering=False, segmentation=True, segmentation_gap_frames=1,
                        segmentation_method=method)
    flt = DynamicFilter(cfg)
    rgbd = RgbdFrame(0, np.zeros((240, 320, 3), np.uint8), np.zeros((240, 320), np.float32), CAM)
    moving_hits = []
    for k in range(4):
        T_world_cam = np.eye(4)
        T_world_cam[:3, 3] = [0.02 * k, 0.0, 0.0]  # camera moves at constant velocity
        world = np.vstack([static, box0 + np.array([0.08 * k, 0.0, 0.0])])
        cam = transform_points(invert(T_world_cam), world)
        feats = _features(CAM.project(cam), cam[:, 2], desc)
        res = flt.before_tracking(dataclasses.replace(rgbd, stamp_ns=k * FRAME_NS), feats, None)
        flt.after_tracking(T_world_cam)
        moving_hits.append(res.moving)
    assert not moving_hits[0].any()  # no earlier frame to compare with
    for moving in moving_hits[2:]:  # from the third frame the prediction has a velocity
        assert moving[400:].mean() >= 0.9
        assert moving[:400].mean() <= 0.02
    assert flt.kept_fraction() < 1.0


def test_map_points_of_a_flagged_group_are_reported_while_their_keypoints_stay_out_of_tracking() -> None:
    """The moving box above, with map point ids as tracking would give them (static points 0-399, the box's
    1000-1039; a keypoint left out of tracking has none). With `forget_moving_points` the filter names the box's
    points in every frame that flags the box, also after the box's keypoints have left tracking: the ids follow
    the segmentation's own matches. Off, it names none."""
    rng = np.random.default_rng(3)
    static = np.column_stack([rng.uniform(-2, 2, 600), rng.uniform(-1.5, 1.5, 600), rng.uniform(3.0, 5.0, 600)])
    ray = static[:, :2] / static[:, 2:3] * 1.8
    static = static[~((ray[:, 0] > 0.05) & (ray[:, 0] < 0.79) & (ray[:, 1] > -0.05) & (ray[:, 1] < 0.45))][:400]
    box0 = np.array([0.3, 0.2, 1.8]) + rng.uniform(-0.15, 0.15, (40, 3))
    desc = rng.integers(0, 256, (440, 32), dtype=np.uint8)
    ids = np.r_[np.arange(400), 1000 + np.arange(40)]
    rgbd = RgbdFrame(0, np.zeros((240, 320, 3), np.uint8), np.zeros((240, 320), np.float32), CAM)
    for forget in (1, 0):
        flt = DynamicFilter(DynamicConfig(detection_filtering=False, segmentation=True, segmentation_gap_frames=1,
                                          forget_moving_points=forget))
        named = []
        for k in range(6):
            T_world_cam = np.eye(4)
            T_world_cam[:3, 3] = [0.02 * k, 0.0, 0.0]
            cam = transform_points(invert(T_world_cam), np.vstack([static, box0 + np.array([0.08 * k, 0.0, 0.0])]))
            res = flt.before_tracking(dataclasses.replace(rgbd, stamp_ns=k * FRAME_NS), _features(CAM.project(cam), cam[:, 2], desc), None)
            named.append(set(np.concatenate([p for _, p in res.moving_points]).tolist()) if res.moving_points else set())
            assert all(m == 0 for m, _ in res.moving_points)
            flt.after_tracking(T_world_cam, np.where(res.keep, ids, -1), 0)
        if forget:
            for k in range(3, 6):  # the box's keypoints left tracking in frame 2 and after
                box = {i for i in named[k] if i >= 1000}
                assert len(box) >= 36, (k, len(box))
                assert len(named[k] - box) <= 8
        else:
            assert not any(named)
    with pytest.raises(ConfigError, match="forget_moving_points"):
        DynamicConfig(forget_moving_points=-1)


def test_dynamic_section_parses_nested_settings_and_rejects_unknown_keys() -> None:
    cfg = section(DynamicConfig, {"segmentation": True, "objects": {"min_updates": 2}}, "x.yaml: dynamic")
    assert cfg.segmentation and cfg.objects.min_updates == 2
    assert cfg.tracker_config().min_updates == 2
    assert dataclasses.replace(cfg, ekf_doc=False).tracker_config().min_updates > 10**6
    with pytest.raises(ConfigError, match="x.yaml: dynamic: unknown key"):
        section(DynamicConfig, {"segmentaton": True}, "x.yaml: dynamic")
    with pytest.raises(ConfigError, match="segmentation_gap_frames"):
        DynamicConfig(segmentation_gap_frames=0)


def test_a_person_box_the_detector_misses_is_held_for_the_configured_frames() -> None:
    flt = DynamicFilter(DynamicConfig(detection_hold_frames=3))
    rgbd, feats, r = _scene()
    kept_person = []
    for k in range(6):
        dets = DETS if k == 0 else ()  # the detector reports the person in the first frame only
        res = flt.before_tracking(dataclasses.replace(rgbd, stamp_ns=k * FRAME_NS), feats, dets)
        flt.after_tracking(np.eye(4))
        kept_person.append(bool(res.keep[r["person"]].any()))
    assert kept_person == [False, False, False, False, True, True]
    # Off (the paper's behaviour): the person's keypoints are used as soon as the box is missing.
    plain = DynamicFilter(DynamicConfig(detection_hold_frames=0))
    plain.before_tracking(rgbd, feats, DETS)
    plain.after_tracking(np.eye(4))
    assert plain.before_tracking(dataclasses.replace(rgbd, stamp_ns=FRAME_NS), feats, ()).keep[r["person"]].all()


def test_a_close_person_the_detector_names_chair_every_other_frame_is_never_movable_by_default() -> None:
    """The shipped SSD names a person filling half the view "person" and "chair" in turn (random_dynamic seed 6).
    Without the hold the "chair" frames make the person's keypoints movable, which the EKF may find static and
    tracking then uses; with the default hold the held person box keeps them out (dynamic, or unused where
    the two boxes cover each other)."""
    person, chair = DETS[0], Detection(DETS[0].box_xyxy, CHAIR_CLASS_ID, 0.7)
    for cfg, movable_frames in ((DynamicConfig(), []), (DynamicConfig(detection_hold_frames=0), [1, 3, 5, 7])):
        flt = DynamicFilter(cfg)
        rgbd, feats, r = _scene()
        movable = []
        for k in range(8):
            res = flt.before_tracking(dataclasses.replace(rgbd, stamp_ns=k * FRAME_NS), feats,
                                      (person if k % 2 == 0 else chair, DETS[1]))
            flt.after_tracking(np.eye(4))
            classes = res.kp_classes[r["person"]]
            if k % 2 == 0:
                assert (classes == KeypointClass.DYNAMIC).all()
            if (classes == KeypointClass.MOVABLE).all():
                movable.append(k)
            else:
                assert np.isin(classes, (KeypointClass.DYNAMIC, KeypointClass.UNUSED)).all()
                assert not res.keep[r["person"]].any()
        assert movable == movable_frames, (cfg.detection_hold_frames, movable)


def _flags_with_unmatched_box_points(configs: list[DynamicConfig]) -> list[np.ndarray]:
    """The moving-box scene above with 60 box points, 20 of whose descriptors never match (a deforming person):
    each config's final-frame flags (400 room points, then 40 matched and 20 unmatched box points)."""
    rng = np.random.default_rng(4)
    static = np.column_stack([rng.uniform(-2, 2, 600), rng.uniform(-1.5, 1.5, 600), rng.uniform(3.0, 5.0, 600)])
    ray = static[:, :2] / static[:, 2:3] * 1.8  # the box hides the wall behind its path, as above
    static = static[~((ray[:, 0] > 0.05) & (ray[:, 0] < 0.79) & (ray[:, 1] > -0.05) & (ray[:, 1] < 0.45))][:400]
    box0 = np.array([0.3, 0.2, 1.8]) + rng.uniform(-0.15, 0.15, (60, 3))
    desc = rng.integers(0, 256, (460, 32), dtype=np.uint8)
    out = []
    for cfg in configs:
        flt = DynamicFilter(cfg)
        rgbd = RgbdFrame(0, np.zeros((240, 320, 3), np.uint8), np.zeros((240, 320), np.float32), CAM)
        for k in range(4):
            T_world_cam = np.eye(4)
            T_world_cam[:3, 3] = [0.02 * k, 0.0, 0.0]
            world = np.vstack([static, box0 + np.array([0.08 * k, 0.0, 0.0])])
            cam = transform_points(invert(T_world_cam), world)
            d = desc.copy()
            d[440:] = rng.integers(0, 256, (20, 32), dtype=np.uint8)  # new descriptors every frame
            res = flt.before_tracking(dataclasses.replace(rgbd, stamp_ns=k * FRAME_NS), _features(CAM.project(cam), cam[:, 2], d), None)
            flt.after_tracking(T_world_cam)
        out.append(res.moving)
    return out


def _segmenting(**kwargs: object) -> DynamicConfig:
    return DynamicConfig(detection_filtering=False, segmentation=True, segmentation_gap_frames=1, **kwargs)  # type: ignore[arg-type]


def test_segmentation_spread_flags_unmatched_keypoints_next_to_flagged_ones_at_similar_depth() -> None:
    """Only the spread flags the unmatched box points, unless that leaves tracking fewer than
    `min_kept_keypoints` keypoints with depth."""
    plain, spread, short = _flags_with_unmatched_box_points([
        _segmenting(), _segmenting(segmentation_spread_px=25.0), _segmenting(segmentation_spread_px=25.0,
                                                                            min_kept_keypoints=420)])
    assert not plain[440:].any() and plain[400:440].mean() >= 0.9
    assert spread[400:].mean() >= 0.9
    assert spread[:400].mean() <= 0.02
    # With 420 keypoints asked of tracking, the spread yields: the 400 room points alone are too few.
    assert (short == plain).all()


def test_flag_vote_flags_untested_keypoints_among_flagged_ones_and_leaves_the_tested_room() -> None:
    """The vote flags the unmatched box points from their flagged 3-D neighbours; the room's tested points keep
    their verdict; it yields as the spread does."""
    plain, voted, short = _flags_with_unmatched_box_points([
        _segmenting(), _segmenting(flag_vote=FlagVoteConfig(radius_m=0.25)),
        _segmenting(flag_vote=FlagVoteConfig(radius_m=0.25), min_kept_keypoints=420)])
    assert not plain[440:].any() and plain[400:440].mean() >= 0.9
    assert voted[440:].mean() >= 0.9
    assert (voted[:400] == plain[:400]).all()
    assert (short == plain).all()


def test_boxes_of_fixed_furniture_classes_are_background_unless_configured_movable() -> None:
    """A 'dining table' box over the chair's keypoints: kept as static by default, filtered as the paper does with []."""
    table = (Detection((215.0, 145.0, 295.0, 225.0), 60, 0.8),)
    rgbd, feats, r = _scene()
    default = DynamicFilter(DynamicConfig()).before_tracking(rgbd, feats, table)
    assert default.keep[r["chair"]].all() and (default.kp_classes[r["chair"]] == KeypointClass.STATIC).all()
    paper = DynamicFilter(DynamicConfig(fixed_class_ids=(), min_kept_keypoints=0)).before_tracking(rgbd, feats, table)
    assert not paper.keep[r["chair"]].any()  # a new movable object: filtered a priori
    assert paper.keep[r["elsewhere"]].all() and default.keep[r["elsewhere"]].all()


def test_a_person_the_detector_misses_is_still_dropped_by_the_segmentation() -> None:
    """A 60-point person 1.6 m away walks 6 cm per frame across a room of 400 static points while the camera
    moves. The detector reports the person's box in the first four frames and misses it from then on (the
    default config: detection filtering, repopulation, EKF-DOC and segmentation). Its keypoints are dropped
    by the person box first and by the segmentation once the detector misses it: at least 70 % of them in
    every frame (points that moved beyond their 24 nearest candidates go unmatched); no static point is
    flagged. With the flags carried through the segmentation's matches, all but one from frame 11 on."""
    rng = np.random.default_rng(5)
    static = np.column_stack([rng.uniform(-2.5, 2.5, 900), rng.uniform(-1.8, 1.8, 900), rng.uniform(3.0, 5.0, 900)])
    body = np.column_stack([rng.uniform(-0.2, 0.2, 60), rng.uniform(-0.6, 0.6, 60), rng.uniform(1.5, 1.7, 60)])
    desc = rng.integers(0, 256, (960, 32), dtype=np.uint8)
    # the segmentation alone: the depth image is a flat stand-in (4 m) that the free-space check would read as a
    # wall in front of the static points 4-5 m away (its own tests render consistent depth)
    flt = DynamicFilter(DynamicConfig(free_space_check=False))
    depth = np.full((240, 320), 4.0, np.float32)
    dropped = []
    for k in range(16):
        T_world_cam = np.eye(4)
        T_world_cam[:3, 3] = [0.01 * k, 0.005 * k, 0.0]
        person = body + np.array([-0.5 + 0.06 * k, 0.0, 0.0])
        cam_person = transform_points(invert(T_world_cam), person)
        px_person = CAM.project(cam_person)
        lo, hi = px_person.min(axis=0) - 4.0, px_person.max(axis=0) + 4.0
        cam_static = transform_points(invert(T_world_cam), static)
        px_static = CAM.project(cam_static)
        # The wall behind the person is hidden; keep the first 400 static points that stay visible.
        visible = ~np.all((px_static >= lo) & (px_static <= hi), axis=1)
        visible &= np.all((px_static >= 0) & (px_static < [320, 240]), axis=1)
        idx = np.flatnonzero(visible)[:400]
        assert len(idx) == 400
        px = np.vstack([px_static[idx], px_person])
        z = np.concatenate([cam_static[idx, 2], cam_person[:, 2]])
        d = np.vstack([desc[idx], desc[900:]])
        box = (Detection((*lo, *hi), PERSON_CLASS_ID, 0.9),) if k < 4 else ()
        res = flt.before_tracking(RgbdFrame(k * FRAME_NS, np.zeros((240, 320, 3), np.uint8), depth, CAM),
                                  _features(px, z, d), box)
        flt.after_tracking(T_world_cam)
        dropped.append((~res.keep[400:]).mean())
        if k >= 6:  # the detector has missed the person for two frames: the segmentation has a velocity
            assert res.moving[400:].mean() >= 0.7, k
            assert res.moving[:400].mean() <= 0.02, k
    assert min(dropped[:4]) == 1.0  # the person box
    assert min(dropped[6:]) >= 0.7


def test_carried_flags_keep_a_missed_persons_keypoints_flagged() -> None:
    """The scene above without detections: carrying the flags (`segmentation_carry_frames`) lifts the
    per-frame recall once the person has been flagged for a few frames."""
    rng = np.random.default_rng(5)
    static = np.column_stack([rng.uniform(-2.5, 2.5, 900), rng.uniform(-1.8, 1.8, 900), rng.uniform(3.0, 5.0, 900)])
    body = np.column_stack([rng.uniform(-0.2, 0.2, 60), rng.uniform(-0.6, 0.6, 60), rng.uniform(1.5, 1.7, 60)])
    desc = rng.integers(0, 256, (960, 32), dtype=np.uint8)
    recall = {}
    for carry in (0, 12):
        flt = DynamicFilter(DynamicConfig(detection_filtering=False, segmentation_carry_frames=carry,
                                          free_space_check=False))  # the segmentation alone (flat depth stand-in)
        out = []
        for k in range(16):
            T_world_cam = np.eye(4)
            T_world_cam[:3, 3] = [0.01 * k, 0.005 * k, 0.0]
            cam_person = transform_points(invert(T_world_cam), body + np.array([-0.5 + 0.06 * k, 0.0, 0.0]))
            px_person = CAM.project(cam_person)
            lo, hi = px_person.min(axis=0) - 4.0, px_person.max(axis=0) + 4.0
            cam_static = transform_points(invert(T_world_cam), static)
            px_static = CAM.project(cam_static)
            visible = ~np.all((px_static >= lo) & (px_static <= hi), axis=1)
            visible &= np.all((px_static >= 0) & (px_static < [320, 240]), axis=1)
            idx = np.flatnonzero(visible)[:400]
            feats = _features(np.vstack([px_static[idx], px_person]), np.concatenate([cam_static[idx, 2], cam_person[:, 2]]),
                              np.vstack([desc[idx], desc[900:]]))
            res = flt.before_tracking(RgbdFrame(k * FRAME_NS, np.zeros((240, 320, 3), np.uint8),
                                                np.full((240, 320), 4.0, np.float32), CAM), feats, None)
            flt.after_tracking(T_world_cam)
            out.append((res.moving[400:].mean(), res.moving[:400].mean()))
        recall[carry] = out
    assert min(r for r, _ in recall[12][11:]) >= 0.95 and max(f for _, f in recall[12]) <= 0.02
    assert np.mean([r for r, _ in recall[12][11:]]) > np.mean([r for r, _ in recall[0][11:]])
