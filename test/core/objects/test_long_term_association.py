"""Long-term data association (Changing-SLAM §4.7, Algorithm 1) on hand-built candidates."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.objects.long_term_association import (
    LongTermAssociation, ObjectCandidate, apply_to_point_store, box_truncated, candidates_from_keyframe, point_lookup,
)
from changing_slam_ros.core.map.map_point import PointStore
from changing_slam_ros.core.objects.map_object import ObjectMapConfig
from changing_slam_ros.core.objects.object_visibility import Visibility
from changing_slam_ros.core.objects.persistence_filter import update_missed, update_seen

CAM = CameraIntrinsics(160, 120, 131.25, 131.25, 79.5, 59.5)
# cut views skipped (`truncated_views` off) and centroids plain means (`centroid_voxel_m` 0): Algorithm 1 as the paper
# gives it; CFG_CUT turns cut views on (the default)
CFG = ObjectMapConfig(ltda_threshold_m=0.5, n_keyframes_unseen=5, belief_threshold=0.6, p_detect=0.8,
                      p_false=0.1, min_points=5, min_projected_area_px=40.0, truncated_views=False, centroid_voxel_m=0.0)
LOOK_Z = np.eye(4)  # camera at the origin looking down world +z
LOOK_AWAY = np.diag([-1.0, 1.0, -1.0, 1.0])  # looking down -z
WALL = np.full((CAM.height, CAM.width), 5.0, np.float32)
CHAIR, CUP = 56, 41
CFG_CUT = dataclasses.replace(CFG, truncated_views=True)  # cut views' points belong to objects


def _cand(centre: list[float], first_id: int, n: int = 20, class_id: int = CHAIR, seed: int = 0) -> ObjectCandidate:
    rng = np.random.default_rng(seed + first_id)
    pts = np.asarray(centre) + rng.normal(0.0, 0.05, (n, 3))
    pts -= pts.mean(axis=0) - np.asarray(centre)  # centroid exactly at `centre`
    return ObjectCandidate(class_id, (10, 10, 50, 50), np.arange(first_id, first_id + n, dtype=np.int64), pts)


def test_first_candidate_creates_an_inactive_object_at_belief_one_half() -> None:
    lta = LongTermAssociation(CFG)
    res = lta.process_keyframe(0, [_cand([0.0, 0.0, 2.5], 100)], LOOK_Z, CAM, WALL)
    assert res.new_object_ids == (0,) and res.assignments == (0,) and res.merged_object_ids == ()
    obj = lta.objects[0]
    assert obj.belief == 0.5 and not obj.active and obj.class_id == CHAIR
    np.testing.assert_allclose(obj.centroid_w, [0.0, 0.0, 2.5], atol=1e-12)
    assert res.deactivated_point_ids.tolist() == list(range(100, 120))  # §4.7: object points start inactive
    assert res.activated_point_ids.size == 0 and res.belief_changes == ()


def test_close_same_class_candidate_is_merged_without_belief_update_when_seen_recently() -> None:
    lta = LongTermAssociation(CFG)
    lta.process_keyframe(0, [_cand([0.0, 0.0, 2.5], 100)], LOOK_Z, CAM, WALL)
    res = lta.process_keyframe(3, [_cand([0.1, 0.0, 2.5], 200)], LOOK_Z, CAM, WALL)
    assert res.merged_object_ids == (0,) and res.new_object_ids == () and res.belief_changes == ()
    obj = lta.objects[0]
    assert obj.n_points == 40 and obj.last_seen_keyframe == 3 and obj.belief == 0.5
    np.testing.assert_allclose(obj.centroid_w, [0.05, 0.0, 2.5], atol=1e-12)  # points combined
    assert res.deactivated_point_ids.tolist() == list(range(200, 220))  # joined an inactive object


def test_other_class_or_farther_than_ltda_threshold_makes_a_new_object() -> None:
    lta = LongTermAssociation(CFG)
    lta.process_keyframe(0, [_cand([0.0, 0.0, 2.5], 100)], LOOK_Z, CAM, WALL)
    res = lta.process_keyframe(1, [_cand([0.0, 0.1, 2.5], 200, class_id=CUP),
                                   _cand([0.55, 0.0, 2.5], 300)], LOOK_Z, CAM, WALL)
    assert res.new_object_ids == (1, 2) and res.assignments == (1, 2) and len(lta.objects) == 3
    assert lta.objects[1].class_id == CUP and lta.objects[2].class_id == CHAIR


def test_two_same_class_detections_of_one_keyframe_never_fuse_and_small_candidates_are_skipped() -> None:
    lta = LongTermAssociation(CFG)
    res = lta.process_keyframe(0, [_cand([0.0, 0.0, 2.5], 100, class_id=CUP), _cand([0.2, 0.0, 2.5], 200, class_id=CUP),
                                   _cand([1.0, 0.0, 2.5], 300, n=4)], LOOK_Z, CAM, WALL)
    assert res.new_object_ids == (0, 1) and res.assignments == (0, 1, -1)


def test_belief_is_updated_only_after_n_keyframes_unseen_and_points_switch_at_the_threshold() -> None:
    lta = LongTermAssociation(CFG)
    lta.process_keyframe(0, [_cand([0.0, 0.0, 2.5], 100)], LOOK_Z, CAM, WALL)
    # kf 5: 5 - 0 = 5 is not more than N = 5 -> only last-seen updated
    res = lta.process_keyframe(5, [_cand([0.0, 0.0, 2.5], 200)], LOOK_Z, CAM, WALL)
    assert res.belief_changes == () and lta.objects[0].belief == 0.5
    # kf 6..10 look away (out of view, no miss), kf 11: 11 - 5 = 6 > 5 -> "seen" update
    for kf in range(6, 11):
        res = lta.process_keyframe(kf, [], LOOK_AWAY, CAM, WALL)
        assert res.belief_changes == () and res.visibility[0] is Visibility.BEHIND_CAMERA
    n_before = lta.objects[0].n_points
    centroid_before = lta.objects[0].centroid_w.copy()
    side_before = float(lta.objects[0].box_size_m.max())
    res = lta.process_keyframe(11, [_cand([0.05, 0.0, 2.5], 300)], LOOK_Z, CAM, WALL)
    expected = update_seen(0.5, np.array([0.05, 0.0, 2.5]), centroid_before, n_before, CFG, side_before).posterior
    assert [c.reason for c in res.belief_changes] == ["seen"]
    assert lta.objects[0].belief == pytest.approx(expected) and expected > 0.6
    assert lta.objects[0].active
    assert res.activated_point_ids.tolist() == list(range(100, 120)) + list(range(200, 220)) + list(range(300, 320))
    assert res.deactivated_point_ids.size == 0


def test_expected_but_missed_object_loses_belief_once_per_n_keyframes_and_turns_inactive() -> None:
    cfg = ObjectMapConfig(n_keyframes_unseen=2, belief_threshold=0.6, min_projected_area_px=40.0, centroid_voxel_m=0.0)
    lta = LongTermAssociation(cfg)
    lta.process_keyframe(0, [_cand([0.0, 0.0, 2.5], 100)], LOOK_Z, CAM, WALL)
    lta.process_keyframe(3, [], LOOK_AWAY, CAM, WALL)
    lta.process_keyframe(4, [_cand([0.0, 0.0, 2.5], 200)], LOOK_Z, CAM, WALL)  # 4 - 0 > 2: seen update
    obj = lta.objects[0]
    assert obj.belief == pytest.approx(0.4 / 0.45) and obj.active
    # kf 5, 6: in view and missed, but seen at kf 4 (within N = 2): a detector miss, no update
    for kf in (5, 6):
        assert lta.process_keyframe(kf, [], LOOK_Z, CAM, WALL).belief_changes == ()
    # kf 7: 7 - 4 > 2 -> "missed" update; the object goes inactive and all its points are reported
    res = lta.process_keyframe(7, [], LOOK_Z, CAM, WALL)
    assert [c.reason for c in res.belief_changes] == ["missed"]
    assert obj.belief == pytest.approx(update_missed(0.4 / 0.45, cfg).posterior)  # 0.64: still active
    assert obj.active and res.deactivated_point_ids.size == 0
    assert lta.process_keyframe(8, [], LOOK_Z, CAM, WALL).belief_changes == ()  # next miss waits N keyframes
    assert lta.process_keyframe(9, [], LOOK_Z, CAM, WALL).belief_changes == ()
    res = lta.process_keyframe(10, [], LOOK_Z, CAM, WALL)
    assert obj.belief < 0.6 and not obj.active
    assert res.deactivated_point_ids.tolist() == list(range(100, 120)) + list(range(200, 220))


def test_a_same_class_box_over_the_object_explains_a_miss_and_truncated_candidates_do_not_associate() -> None:
    cfg = ObjectMapConfig(n_keyframes_unseen=2, min_projected_area_px=40.0, truncated_views=False)
    lta = LongTermAssociation(cfg)
    lta.process_keyframe(0, [_cand([0.0, 0.0, 2.5], 100)], LOOK_Z, CAM, WALL)
    # kf 10: the object projects to (79.5, 59.5); a truncated chair box covers it: no miss, no merge
    part = _cand([0.3, 0.0, 2.5], 200)
    cover = ObjectCandidate(CHAIR, (0, 30, 100, 90), part.point_ids, part.points_w, truncated=True)
    res = lta.process_keyframe(10, [cover], LOOK_Z, CAM, WALL)
    assert res.assignments == (-1,) and res.belief_changes == () and lta.objects[0].n_points == 20
    # a cup box there does not explain a chair away; a chair box elsewhere neither
    elsewhere = ObjectCandidate(CHAIR, (100, 10, 150, 50), part.point_ids, part.points_w, truncated=True)
    cup = ObjectCandidate(CUP, (0, 30, 100, 90), part.point_ids, part.points_w, truncated=True)
    res = lta.process_keyframe(11, [cup, elsewhere], LOOK_Z, CAM, WALL)
    assert [c.reason for c in res.belief_changes] == ["missed"]


def test_a_same_class_detection_that_is_no_candidate_explains_a_miss_too() -> None:
    cfg = ObjectMapConfig(n_keyframes_unseen=2, min_projected_area_px=40.0)
    lta = LongTermAssociation(cfg)
    lta.process_keyframe(0, [_cand([0.0, 0.0, 2.5], 100)], LOOK_Z, CAM, WALL)
    # kf 10: no candidate, but a chair detection (flagged dynamic this keyframe) covers (79.5, 59.5): no miss
    res = lta.process_keyframe(10, [], LOOK_Z, CAM, WALL, detected_boxes=[(CHAIR, (40.0, 20.0, 120.0, 100.0))])
    assert res.belief_changes == () and lta.objects[0].belief == 0.5
    # a cup detection there, or a chair detection elsewhere, does not: missed, 0.5 -> 0.2 * 0.5 / (0.2 * 0.5 + 0.9 * 0.5)
    res = lta.process_keyframe(13, [], LOOK_Z, CAM, WALL,
                               detected_boxes=[(CUP, (40.0, 20.0, 120.0, 100.0)), (CHAIR, (100.0, 10.0, 150.0, 50.0))])
    assert [c.reason for c in res.belief_changes] == ["missed"]
    assert lta.objects[0].belief == pytest.approx(0.1 / 0.55)


def test_occluded_or_out_of_range_objects_keep_their_belief() -> None:
    lta = LongTermAssociation(CFG)
    lta.process_keyframe(0, [_cand([0.0, 0.0, 2.5], 100)], LOOK_Z, CAM, WALL)
    near_wall = np.full_like(WALL, 1.0)  # something stands 1 m in front of the camera
    res = lta.process_keyframe(20, [], LOOK_Z, CAM, near_wall)
    assert res.visibility[0] is Visibility.OCCLUDED and res.belief_changes == ()
    far = np.eye(4)
    far[2, 3] = -3.0  # camera 5.5 m from the object
    res = lta.process_keyframe(21, [], far, CAM, WALL)
    assert res.visibility[0] is Visibility.OUT_OF_RANGE and lta.objects[0].belief == 0.5


def test_refresh_points_follows_the_map_and_drops_culled_points() -> None:
    lta = LongTermAssociation(CFG)
    lta.process_keyframe(0, [_cand([0.0, 0.0, 2.5], 100)], LOOK_Z, CAM, WALL)

    def lookup(ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pos = np.zeros((len(ids), 3))
        pos[:, 0] = 1.0  # bundle adjustment moved every point to x = 1
        return pos, ids % 2 == 0  # odd ids were culled

    lta.refresh_points(lookup)
    obj = lta.objects[0]
    assert obj.point_ids.tolist() == list(range(100, 120, 2))
    np.testing.assert_allclose(obj.centroid_w, [1.0, 0.0, 0.0])
    assert lta.object_of_point()[104] == 0


def test_candidates_from_a_keyframe_group_its_map_points_by_short_term_object() -> None:
    n = 8
    kf = Keyframe(4, 0, np.eye(4), CAM, np.zeros((n, 2), np.float32), np.zeros(n, np.int8),
                  np.zeros((n, 32), np.uint8), np.ones(n, np.float32),
                  point_ids=np.array([10, 11, -1, 12, 13, 14, 14, -1]),
                  object_ids=np.array([2, 2, 2, 5, 5, -1, 9, 9]))
    positions = {10: [0, 0, 1], 11: [0, 0, 3], 12: [1, 1, 1], 13: [1, 1, 3], 14: [5, 5, 5]}

    def points_w_of(ids: np.ndarray) -> np.ndarray:
        return np.array([positions[int(i)] for i in ids], float)

    cands = candidates_from_keyframe(kf, points_w_of, {5: (CUP, (1, 2, 3, 4), True), 2: (CHAIR, (5, 6, 7, 8), False),
                                                       7: (CHAIR, (0, 0, 1, 1), False)})
    assert [(c.class_id, c.point_ids.tolist(), c.truncated) for c in cands] == [(CHAIR, [10, 11], False),
                                                                                 (CUP, [12, 13], True)]
    np.testing.assert_allclose(cands[0].centroid_w, [0.0, 0.0, 2.0])
    assert box_truncated((0, 5, 20, 20), CAM) and box_truncated((5, 5, 160, 20), CAM)
    assert not box_truncated((1, 1, 159, 119), CAM) and box_truncated((1, 1, 159, 119), CAM, border_px=2)


def test_a_loaded_map_in_a_new_session_updates_beliefs_at_first_sight_or_miss() -> None:
    first = LongTermAssociation(CFG)
    first.process_keyframe(0, [_cand([0.0, 0.0, 2.5], 100), _cand([0.8, 0.0, 2.5], 200, class_id=CUP)],
                           LOOK_Z, CAM, WALL)
    first.process_keyframe(40, [], LOOK_AWAY, CAM, WALL)
    second = LongTermAssociation(CFG)
    for obj in first.objects.values():
        second.add_object(obj)
    second.new_session(0)  # keyframe ids restart at 0
    res = second.process_keyframe(0, [_cand([0.02, 0.0, 2.5], 300)], LOOK_Z, CAM, WALL)  # chair there, cup gone
    assert sorted((c.object_id, c.reason) for c in res.belief_changes) == [(0, "seen"), (1, "missed")]
    assert second.objects[0].belief > 0.6 and second.objects[1].belief < 0.5
    assert second.process_keyframe(1, [], LOOK_AWAY, CAM, WALL).new_object_ids == ()
    assert second.process_keyframe(2, [_cand([3.0, 0.0, 2.5], 400)], LOOK_Z, CAM, WALL).new_object_ids == (2,)


def test_outcome_is_written_into_a_point_store_and_read_back_after_culling() -> None:
    store = PointStore()
    rng = np.random.default_rng(1)
    pos = np.array([0.0, 0.0, 2.5]) + rng.normal(0.0, 0.05, (30, 3))
    ids = store.add(pos, np.zeros((30, 32), np.uint8), 0, np.arange(30), np.zeros(3), np.zeros(30, np.int64),
                    np.ones(8))
    lta = LongTermAssociation(CFG)
    cands = [ObjectCandidate(CHAIR, (10, 10, 50, 50), ids[:20], store.positions[ids[:20]])]
    res = lta.process_keyframe(0, cands, LOOK_Z, CAM, WALL)
    apply_to_point_store(store, cands, res)
    assert store.object_id[:20].tolist() == [0] * 20 and store.object_id[20:30].tolist() == [-1] * 10
    assert store.class_id[:20].tolist() == [CHAIR] * 20
    assert not store.active[:20].any() and store.active[20:30].all()  # object points start inactive
    assert not store.usable()[:20].any()
    # culling and bundle adjustment: the object follows the store
    store.set_bad(ids[:5])
    store.positions[ids[5:20]] += [0.0, 1.0, 0.0]
    lta.refresh_points(point_lookup(store))
    assert lta.objects[0].point_ids.tolist() == ids[5:20].tolist()
    np.testing.assert_allclose(lta.objects[0].centroid_w, store.positions[ids[5:20]].mean(axis=0))
    # a long-term sighting activates the points again
    cands = [ObjectCandidate(CHAIR, (10, 10, 50, 50), ids[5:20], store.positions[ids[5:20]])]
    res = lta.process_keyframe(10, cands, LOOK_Z, CAM, WALL)
    apply_to_point_store(store, cands, res)
    assert lta.objects[0].active and store.active[ids[5:20]].all()


def test_truncated_candidates_give_their_points_to_an_object_without_updating_its_belief() -> None:
    """§4.2: map points created in a box belong to its MapObject and follow its active flag, also when the box is
    cut by the image border (an object seen close up). A cut view with no mapped object of its class nearby
    creates one (inactive); next to one, its points are labelled with it and take its flag, but stay out of its
    point set (centroid, box), and its biased centroid neither updates the belief nor counts as a sighting."""
    cut = _cand([0.0, 0.0, 1.0], 100)
    cut = ObjectCandidate(CHAIR, (60, 40, 160, 120), cut.point_ids, cut.points_w, truncated=True)
    lta = LongTermAssociation(dataclasses.replace(CFG_CUT, cut_only_views_join=False))
    res = lta.process_keyframe(0, [cut], LOOK_Z, CAM, WALL)
    assert res.new_object_ids == (0,) and res.assignments == (0,)
    assert not lta.objects[0].active and res.deactivated_point_ids.tolist() == list(range(100, 120))
    near = _cand([0.2, 0.0, 1.0], 200)
    near_cut = ObjectCandidate(CHAIR, (60, 40, 160, 120), near.point_ids, near.points_w, truncated=True)
    res = lta.process_keyframe(9, [near_cut], LOOK_Z, CAM, WALL)
    obj = lta.objects[0]
    assert res.assignments == (0,) and res.new_object_ids == () and res.belief_changes == ()
    assert obj.n_points == 20 and obj.last_seen_keyframe == 0 and obj.belief == 0.5
    np.testing.assert_allclose(obj.centroid_w, [0.0, 0.0, 1.0], atol=1e-12)
    assert res.deactivated_point_ids.tolist() == list(range(200, 220))  # they take the object's flag
    points = PointStore()
    points.add(np.zeros((220, 3)), np.zeros((220, 32), np.uint8), 0, np.arange(220), np.zeros(3),
               np.zeros(220, np.int64), np.ones(220))
    apply_to_point_store(points, [near_cut], res)
    assert (points.object_id[200:220] == 0).all() and not points.active[200:220].any() and points.active[:200].all()
    res = lta.process_keyframe(10, [_cand([0.1, 0.0, 1.0], 300)], LOOK_Z, CAM, WALL)  # a whole view merges
    assert res.merged_object_ids == (0,) and lta.objects[0].n_points == 40
    off = LongTermAssociation(CFG)  # cut views skipped
    res = off.process_keyframe(0, [cut], LOOK_Z, CAM, WALL)
    assert res.assignments == (-1,) and not off.objects and res.deactivated_point_ids.size == 0
    off.process_keyframe(1, [_cand([0.0, 0.0, 1.0], 400)], LOOK_Z, CAM, WALL)
    res = off.process_keyframe(2, [near_cut], LOOK_Z, CAM, WALL)  # off: a cut view is not labelled either
    assert res.assignments == (-1,) and res.deactivated_point_ids.size == 0


def test_the_first_whole_view_of_an_object_known_from_cut_views_is_no_long_term_update() -> None:
    """A glimpse at the image edge is no earlier visit: the object it created is first *seen* by its first whole
    view, which therefore leaves the belief at 0.5; the next whole view after N keyframes is a long-term update."""
    base = _cand([0.0, 0.0, 1.0], 100)
    cut = ObjectCandidate(CHAIR, (60, 40, 160, 120), base.point_ids, base.points_w, truncated=True)
    lta = LongTermAssociation(CFG_CUT)
    lta.process_keyframe(0, [cut], LOOK_Z, CAM, WALL)
    assert lta.objects[0].n_observations == 0
    res = lta.process_keyframe(20, [_cand([0.05, 0.0, 1.0], 200)], LOOK_Z, CAM, WALL)
    assert res.merged_object_ids == (0,) and res.belief_changes == () and lta.objects[0].belief == 0.5
    assert lta.objects[0].n_observations == 1
    res = lta.process_keyframe(40, [_cand([0.05, 0.0, 1.0], 300)], LOOK_Z, CAM, WALL)
    assert [c.reason for c in res.belief_changes] == ["seen"] and lta.objects[0].belief > 0.5


def test_an_object_known_only_from_cut_views_takes_the_points_of_its_later_cut_views() -> None:
    """`cut_only_views_join`: while no whole view exists, each cut view adds its points (the union of what was
    seen: a plant whose top the camera never saw), without a belief update or a sighting; once the object has
    been seen whole, cut views are labelled only and its centroid stays that of its whole views."""
    left = _cand([-0.1, 0.0, 1.0], 100)
    right = _cand([0.1, 0.0, 1.0], 200)
    lta = LongTermAssociation(CFG_CUT)
    lta.process_keyframe(0, [ObjectCandidate(CHAIR, (0, 40, 60, 120), left.point_ids, left.points_w, True)],
                         LOOK_Z, CAM, WALL)
    res = lta.process_keyframe(9, [ObjectCandidate(CHAIR, (100, 40, 160, 120), right.point_ids, right.points_w,
                                                   True)], LOOK_Z, CAM, WALL)
    obj = lta.objects[0]
    assert res.assignments == (0,) and res.new_object_ids == () and res.belief_changes == ()
    assert obj.n_points == 40 and obj.n_observations == 0 and obj.last_seen_keyframe == 0 and obj.belief == 0.5
    np.testing.assert_allclose(obj.centroid_w, [0.0, 0.0, 1.0], atol=1e-12)  # was -0.1: one side only
    assert res.deactivated_point_ids.tolist() == list(range(200, 220))  # the joiners take its (inactive) flag
    whole = _cand([0.0, 0.0, 1.0], 300)
    lta.process_keyframe(12, [whole], LOOK_Z, CAM, WALL)
    assert obj.n_observations == 1 and obj.n_points == 60
    later = _cand([0.4, 0.0, 1.0], 400)
    res = lta.process_keyframe(14, [ObjectCandidate(CHAIR, (100, 40, 160, 120), later.point_ids, later.points_w,
                                                    True)], LOOK_Z, CAM, WALL)
    assert res.assignments == (0,) and obj.n_points == 60  # seen whole: a cut view is labelled only
    np.testing.assert_allclose(obj.centroid_w, [0.0, 0.0, 1.0], atol=1e-12)
