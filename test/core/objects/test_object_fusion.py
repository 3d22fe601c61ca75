"""Duplicates of one large object seen cut from far-apart places fuse into one MapObject (`object_fusion`)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.map.map_point import PointStore
from changing_slam_ros.core.objects.change_report import ChangeKind, compare_object_maps
from changing_slam_ros.core.objects.long_term_association import (
    LongTermAssociation, ObjectCandidate, apply_to_point_store,
)
from changing_slam_ros.core.objects.map_object import MapObject, ObjectMapConfig
from changing_slam_ros.core.objects.object_fusion import box_overlap_fraction, fuse_duplicates
from changing_slam_ros.core.objects.semantic_map import build_semantic_map
from changing_slam_ros.errors import ConfigError

CAM = CameraIntrinsics(160, 120, 131.25, 131.25, 79.5, 59.5)
CFG = ObjectMapConfig(min_projected_area_px=40.0)
WALL = np.full((CAM.height, CAM.width), 5.0, np.float32)
LOOK_AWAY = np.diag([-1.0, 1.0, -1.0, 1.0])  # the camera at the origin facing -z
SUITCASE, CHAIR, COUCH = 28, 56, 57
WHOLE, CUT_LEFT, CUT_RIGHT = (20, 20, 140, 100), (0, 40, 120, 120), (40, 40, 160, 120)


def _at(x_m: float) -> np.ndarray:
    """The camera at (x_m, 0, 0) facing +z (optical frame: y down)."""
    T = np.eye(4)
    T[0, 3] = x_m
    return T


def _box_points(lo: list[float], hi: list[float], first_id: int, n: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """`n` points spread uniformly in the box [lo, hi] (metres), ids first_id.. (seeded)."""
    pts = np.random.default_rng(first_id).uniform(lo, hi, (n, 3))
    return np.arange(first_id, first_id + n, dtype=np.int64), pts


def _cand(class_id: int, lo: list[float], hi: list[float], first_id: int, box: tuple[int, int, int, int] = WHOLE,
          truncated: bool = False) -> ObjectCandidate:
    ids, pts = _box_points(lo, hi, first_id)
    return ObjectCandidate(class_id, box, ids, pts, truncated)


# A couch 2 m long (x), 0.9 m high (y, down) and 0.85 m deep (z), its centre at (0, 0.55, 3.0). From the left the
# image bottom cuts it and the camera sees x in [-1.0, 0.4]; from the right x in [-0.4, 1.0]. The two views'
# centroids lie 0.6 m apart (beyond `ltda_threshold_m`, 0.5) and their boxes share 0.8 / 1.4 = 0.57 of the smaller.
COUCH_LEFT = ([-1.0, 0.1, 2.6], [0.4, 1.0, 3.4])
COUCH_RIGHT = ([-0.4, 0.1, 2.6], [1.0, 1.0, 3.4])


def test_two_cut_views_of_one_couch_from_far_apart_places_become_one_object() -> None:
    lta = LongTermAssociation(CFG)
    lta.process_keyframe(0, [_cand(COUCH, *COUCH_LEFT, 1000, CUT_LEFT, True)], _at(-1.5), CAM, WALL)
    res = lta.process_keyframe(3, [_cand(COUCH, *COUCH_RIGHT, 2000, CUT_RIGHT, True)], _at(1.5), CAM, WALL)
    assert list(lta.objects) == [0] and res.fused == {1: 0}
    assert res.assignments == (0,) and res.new_object_ids == () and res.belief_changes == ()
    couch = lta.objects[0]
    # both known only from cut views: the union of what the two views saw, centred on the couch
    assert couch.n_points == 800 and couch.n_observations == 0 and couch.belief == 0.5 and couch.n_views == 2
    np.testing.assert_allclose(couch.centroid_w, [0.0, 0.55, 3.0], atol=0.03)
    assert couch.box_size_m[0] > 1.75  # each view's box: 1.4 m (less the robust box's trim)
    assert [(k, r) for k, _, r in couch.belief_history] == [(0, "new")]
    # the duplicate's points in the map take the survivor's id and its (inactive) flag
    points = PointStore()
    points.add(np.zeros((2400, 3)), np.zeros((2400, 32), np.uint8), 0, np.arange(2400), np.zeros(3),
               np.zeros(2400, np.int64), np.ones(2400))
    apply_to_point_store(points, [_cand(COUCH, *COUCH_RIGHT, 2000, CUT_RIGHT, True)], res)
    assert (points.object_id[2000:2400] == 0).all() and not points.active[2000:2400].any()
    # without fusion the couch is two objects 0.6 m apart
    off = LongTermAssociation(dataclasses.replace(CFG, fuse_cut_duplicates=False))
    off.process_keyframe(0, [_cand(COUCH, *COUCH_LEFT, 1000, CUT_LEFT, True)], _at(-1.5), CAM, WALL)
    off.process_keyframe(3, [_cand(COUCH, *COUCH_RIGHT, 2000, CUT_RIGHT, True)], _at(1.5), CAM, WALL)
    assert list(off.objects) == [0, 1]
    assert float(np.linalg.norm(off.objects[0].centroid_w - off.objects[1].centroid_w)) == pytest.approx(0.6, abs=0.03)
    assert box_overlap_fraction(off.objects[0], off.objects[1]) == pytest.approx(0.8 / 1.4, abs=0.05)


def test_a_cut_duplicate_of_a_couch_seen_whole_is_labelled_with_it_and_leaves_its_centroid_and_belief() -> None:
    """The object with whole views survives (even when younger) and keeps its point set, centroid, belief and last
    sighting: the cut view's centroid is biased and carries no evidence."""
    lta = LongTermAssociation(CFG)
    lta.process_keyframe(0, [_cand(COUCH, *COUCH_LEFT, 1000, CUT_LEFT, True)], _at(-1.5), CAM, WALL)
    whole = _cand(COUCH, [-0.4, 0.1, 2.6], [1.2, 1.0, 3.4], 2000)  # the right part and beyond, seen whole
    res = lta.process_keyframe(2, [whole], _at(1.5), CAM, WALL)
    assert res.fused == {0: 1} and list(lta.objects) == [1] and res.new_object_ids == (1,)
    couch = lta.objects[1]
    assert couch.n_points == 400 and couch.n_observations == 1 and couch.first_keyframe == 0
    assert couch.last_seen_keyframe == 2 and couch.seen_keyframes == [2] and couch.belief == 0.5
    np.testing.assert_allclose(couch.centroid_w, whole.points_w.mean(axis=0), atol=1e-12)


def test_two_chairs_side_by_side_stay_two_objects() -> None:
    """Chairs 0.6 m wide, 0.62 m apart centre to centre (beyond the reach), their boxes a sliver apart; one seen
    whole, the other only cut by the image border. Their boxes share nothing: two objects."""
    lta = LongTermAssociation(CFG)
    left = _cand(CHAIR, [-0.61, 0.0, 2.2], [-0.01, 1.0, 2.8], 1000)
    right = _cand(CHAIR, [0.01, 0.0, 2.2], [0.61, 1.0, 2.8], 2000, CUT_RIGHT, True)
    lta.process_keyframe(0, [left], _at(0.0), CAM, WALL)
    res = lta.process_keyframe(2, [right], _at(0.5), CAM, WALL)
    assert list(lta.objects) == [0, 1] and res.fused == {} and res.new_object_ids == (1,)
    assert box_overlap_fraction(lta.objects[0], lta.objects[1]) == 0.0
    # pushed 0.14 m together, their robust boxes (each end trimmed, `box_extent`) overlap by 9 cm of 56, as boxes
    # of noisy points may: still two
    a = MapObject(5, CHAIR, WHOLE, WHOLE, 0, 0, point_ids=left.point_ids, points_w=left.points_w)
    b = MapObject(6, CHAIR, WHOLE, WHOLE, 3, 3, point_ids=right.point_ids, points_w=right.points_w - [0.14, 0, 0],
                  n_observations=0)
    assert box_overlap_fraction(a, b) == pytest.approx(0.16, abs=0.02)
    objects = {5: a, 6: b}
    assert fuse_duplicates(objects, CFG) == {} and sorted(objects) == [5, 6]


def test_two_cut_boxes_of_one_class_in_one_image_stay_two_objects_however_they_overlap() -> None:
    lta = LongTermAssociation(CFG)
    res = lta.process_keyframe(0, [_cand(COUCH, *COUCH_LEFT, 1000, CUT_LEFT, True),
                                   _cand(COUCH, *COUCH_RIGHT, 2000, CUT_RIGHT, True)], _at(0.0), CAM, WALL)
    assert list(lta.objects) == [0, 1] and res.fused == {}


def _two_laps(class_id: int, a_lo: list[float], a_hi: list[float], b_lo: list[float], b_hi: list[float],
              config: ObjectMapConfig) -> tuple[LongTermAssociation, LongTermAssociation]:
    """Lap 1 (keyframes 0-3) sees the object whole in [a_lo, a_hi]; the camera looks away (4-19); the object moves
    to [b_lo, b_hi]. Lap 2: keyframe 20 looks at the first place and sees nothing there; keyframe 26 sees the object
    at its new place cut by the image border (its left 70 %), keyframes 27-28 whole. Returns (the map at the end of
    lap 1, the map at the end)."""
    lap1, lta = LongTermAssociation(config), LongTermAssociation(config)
    for kf in range(4):
        for m in (lap1, lta):
            m.process_keyframe(kf, [_cand(class_id, a_lo, a_hi, 1000 * kf + 10)], _at(0.0), CAM, WALL)
    for kf in range(4, 20):
        lta.process_keyframe(kf, [], LOOK_AWAY, CAM, WALL)
    lta.process_keyframe(20, [], _at(0.0), CAM, WALL)
    cut_hi = [b_lo[0] + 0.7 * (b_hi[0] - b_lo[0]), b_hi[1], b_hi[2]]
    lta.process_keyframe(26, [_cand(class_id, b_lo, cut_hi, 26000, CUT_LEFT, True)], _at(0.0), CAM, WALL)
    for kf in (27, 28):
        lta.process_keyframe(kf, [_cand(class_id, b_lo, b_hi, 1000 * kf)], _at(0.0), CAM, WALL)
    return lap1, lta


def test_a_couch_moved_along_its_length_is_still_reported_moved() -> None:
    """Moved 0.7 m along its length (beyond the reach), its boxes at the two places share 1.3 / 2 of their volume:
    the old place was missed (lost, belief 0.18), so it fuses with nothing, and the report says moved."""
    lap1, lta = _two_laps(COUCH, [-1.0, 0.1, 2.6], [1.0, 1.0, 3.4], [-0.3, 0.1, 2.6], [1.7, 1.0, 3.4], CFG)
    old, new = lta.objects[0], lta.objects[1]
    assert sorted(lta.objects) == [0, 1] and old.belief < CFG.semantic_min_belief
    assert box_overlap_fraction(old, new) == pytest.approx(0.65, abs=0.05)
    assert [o.id for o in build_semantic_map(lta.objects.values(), CFG).objects] == [1]
    moved, = compare_object_maps(list(lap1.objects.values()), list(lta.objects.values())).changes
    assert moved.kind == ChangeKind.MOVED and (moved.before.id, moved.after.id) == (0, 1)
    assert moved.distance_m == pytest.approx(0.7, abs=0.05)


def test_a_suitcase_moved_0_4_m_is_still_reported_moved() -> None:
    """Moved 0.4 m along its 0.45 m width (inside the reach), first seen cut at its new place: the lost suitcase takes
    no candidate there (`relocation`), fusion leaves a lost object alone, and the report says moved, as without
    fusion. (Its boxes at the two places share 0.05 / 0.45 anyway: an object that relocation tells apart 0.4 m away
    is smaller than about 0.7 m, so its boxes share less than half.)"""
    a_lo, a_hi = [-0.225, 0.4, 2.35], [0.225, 1.0, 2.65]
    b_lo, b_hi = [0.175, 0.4, 2.35], [0.625, 1.0, 2.65]
    for fuse in (True, False):
        lap1, lta = _two_laps(SUITCASE, a_lo, a_hi, b_lo, b_hi, dataclasses.replace(CFG, fuse_cut_duplicates=fuse))
        assert sorted(lta.objects) == [0, 1] and lta.objects[0].belief < CFG.semantic_min_belief
        moved, = compare_object_maps(list(lap1.objects.values()), list(lta.objects.values())).changes
        assert moved.kind == ChangeKind.MOVED and moved.distance_m == pytest.approx(0.4, abs=0.03)


def test_fuse_min_overlap_must_be_a_fraction() -> None:
    with pytest.raises(ConfigError, match="fuse_min_overlap"):
        ObjectMapConfig(fuse_min_overlap=0.0)
    with pytest.raises(ConfigError, match="fuse_min_overlap"):
        ObjectMapConfig(fuse_min_overlap=1.5)
