"""A moved object re-found at its new place over a constructed two-lap sequence (long-term association, §4.7)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.objects.change_report import ChangeKind, compare_object_maps
from changing_slam_ros.core.objects.long_term_association import LongTermAssociation, ObjectCandidate
from changing_slam_ros.core.objects.map_object import ObjectMapConfig
from changing_slam_ros.core.objects.semantic_map import build_semantic_map

CAM = CameraIntrinsics(160, 120, 131.25, 131.25, 79.5, 59.5)
CFG = ObjectMapConfig(min_projected_area_px=40.0)
WALL = np.full((CAM.height, CAM.width), 5.0, np.float32)
LOOK_AWAY = np.diag([-1.0, 1.0, -1.0, 1.0])  # the camera at the origin facing -z: the room's other half
CHAIR, CUP = 56, 41


def _at(x_m: float) -> np.ndarray:
    """The camera at (x_m, 0, 0) facing +z."""
    T = np.eye(4)
    T[0, 3] = x_m
    return T


def _cand(class_id: int, centre: list[float], first_id: int, half_m: float) -> ObjectCandidate:
    rng = np.random.default_rng(first_id)
    pts = np.asarray(centre) + rng.uniform(-half_m, half_m, (60, 3))
    pts -= pts.mean(axis=0) - np.asarray(centre)
    return ObjectCandidate(class_id, (40, 30, 120, 90), np.arange(first_id, first_id + 60, dtype=np.int64), pts)


def _two_laps(class_id: int, a: list[float], b: list[float], half_m: float, config: ObjectMapConfig,
              camera_x2_m: float) -> LongTermAssociation:
    """Lap 1 (keyframes 0-3) sees the object at `a`, then the camera looks away (4-19); between the laps the object
    moves to `b`. Lap 2: keyframe 20 looks at `a` and sees nothing there; keyframes 26-28, from x = `camera_x2_m`,
    see the object at `b`."""
    lta = LongTermAssociation(config)
    for kf in range(4):
        lta.process_keyframe(kf, [_cand(class_id, a, 1000 * kf, half_m)], _at(0.0), CAM, WALL)
    for kf in range(4, 20):
        lta.process_keyframe(kf, [], LOOK_AWAY, CAM, WALL)
    lta.process_keyframe(20, [], _at(0.0), CAM, WALL)
    for kf in range(26, 29):
        lta.process_keyframe(kf, [_cand(class_id, b, 1000 * kf, half_m)], _at(camera_x2_m), CAM, WALL)
    return lta


def test_a_chair_moved_two_metres_is_refound_at_its_new_place_and_reported_moved() -> None:
    a, b = [0.0, 0.3, 2.5], [2.0, 0.3, 2.5]
    lta = _two_laps(CHAIR, a, b, 0.25, CFG, 2.0)
    old, new = lta.objects[0], lta.objects[1]
    assert [(k, r) for k, _, r in old.belief_history] == [(0, "new"), (20, "missed")]
    assert old.belief == pytest.approx(0.5 * 0.2 / (0.5 * 0.2 + 0.5 * 0.9))  # one miss: 0.18
    assert old.seen_keyframes == [0, 1, 2, 3] and new.seen_keyframes == [26, 27, 28]
    smap = build_semantic_map(lta.objects.values(), CFG)
    assert [o.id for o in smap.objects] == [1]  # the chair, where it is now
    np.testing.assert_allclose(smap.objects[0].centroid_w, b, atol=1e-9)
    # the report from the end of lap 1 (the object at a, belief 0.5) to the end of lap 2
    lap1 = LongTermAssociation(CFG)
    for kf in range(4):
        lap1.process_keyframe(kf, [_cand(CHAIR, a, 1000 * kf, 0.25)], _at(0.0), CAM, WALL)
    report = compare_object_maps(list(lap1.objects.values()), list(lta.objects.values()))
    moved, = report.changes
    assert moved.kind == ChangeKind.MOVED and (moved.before.id, moved.after.id) == (0, 1)
    assert moved.distance_m == pytest.approx(2.0, abs=1e-9)


def test_a_cup_moved_within_the_association_gate_is_a_new_object_once_its_old_place_is_lost() -> None:
    a, b = [0.0, 0.3, 2.5], [0.35, 0.3, 2.5]  # 0.35 m: inside ltda_threshold_m (0.5)
    lta = _two_laps(CUP, a, b, 0.1, CFG, 0.0)
    present = [o for o in build_semantic_map(lta.objects.values(), CFG).objects]
    assert [o.id for o in present] == [1] and lta.objects[0].belief < 0.5
    np.testing.assert_allclose(present[0].centroid_w, b, atol=1e-9)
    # without relocation the lost cup takes the new place's points and its centroid lands between the two places
    merged = _two_laps(CUP, a, b, 0.1, dataclasses.replace(CFG, relocation=False), 0.0)
    assert list(merged.objects) == [0]
    assert 0.1 < float(merged.objects[0].centroid_w[0]) < 0.25


def test_a_lost_object_seen_back_at_its_place_is_merged_and_regains_belief() -> None:
    a = [0.0, 0.3, 2.5]
    lta = _two_laps(CUP, a, a, 0.1, CFG, 0.0)
    assert list(lta.objects) == [0]
    cup = lta.objects[0]
    assert [r for _, _, r in cup.belief_history] == ["new", "missed", "seen"] and cup.belief > 0.5
