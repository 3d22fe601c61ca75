"""The change report on a constructed pair of maps: one object of each kind of change, exact verdicts."""

from __future__ import annotations

import numpy as np
import pytest

from changing_slam_ros.core.objects.change_report import ChangeKind, ChangeReportConfig, compare_maps
from changing_slam_ros.core.objects.object_evidence import evidence_of, keyframe_thumbnail, map_up

from object_maps import BOTTLE, CHAIR, CUP, PLANT, TV, changed_room_maps, map_object  # noqa: F401

_obj = map_object


def test_change_report_gives_one_exact_verdict_per_kind_of_change() -> None:
    before, after = changed_room_maps()
    report = compare_maps([evidence_of(o) for o in before], [evidence_of(o) for o in after])
    assert report.counts() == {"moved": 1, "removed": 1, "added": 1, "replaced": 1, "unchanged": 1}
    moved, = report.of_kind(ChangeKind.MOVED)
    assert (moved.before.id, moved.after.id, moved.before_later.id) == (1, 4, 1)
    assert moved.distance_m == pytest.approx(2.0, abs=1e-9)
    assert [k for k, _, _ in moved.before_later.belief_history] == [2, 28, 29]
    assert moved.before_later.belief_history[-1][2] == "missed"
    removed, = report.of_kind(ChangeKind.REMOVED)
    assert (removed.before.id, removed.after, removed.before_later.id) == (2, None, 2)
    added, = report.of_kind(ChangeKind.ADDED)
    assert (added.before, added.after.id, added.after.class_name) == (None, 5, "cup")
    replaced, = report.of_kind(ChangeKind.REPLACED)
    assert (replaced.before.class_name, replaced.after.class_name) == ("suitcase", "bottle")
    assert replaced.distance_m == pytest.approx(0.2, abs=1e-9)
    (b, a), = report.unchanged
    assert (b.id, a.id) == (0, 0)


def test_swapped_objects_of_two_classes_are_two_moves_and_a_duplicate_is_no_addition() -> None:
    before = [_obj(0, CHAIR, [0.0, 0.0, 2.0], 0.7), _obj(1, PLANT, [2.0, 0.0, 2.0], 0.7)]
    after = [_obj(0, CHAIR, [0.0, 0.0, 2.0], 0.2), _obj(1, PLANT, [2.0, 0.0, 2.0], 0.2),
             _obj(2, PLANT, [0.05, 0.0, 2.0], 0.5, 9), _obj(3, CHAIR, [2.0, 0.05, 2.0], 0.5, 9),
             _obj(4, CHAIR, [2.1, 0.05, 2.0], 0.5, 10)]
    report = compare_maps([evidence_of(o) for o in before], [evidence_of(o) for o in after])
    assert report.counts() == {"moved": 2, "removed": 0, "added": 0, "replaced": 0, "unchanged": 0}
    assert sorted((c.before.id, c.after.id) for c in report.changes) == [(0, 3), (1, 2)]


def test_an_object_the_continued_map_withdrew_is_not_removed() -> None:
    """A flat "plant" on a wall the second session's picture check dropped: the continued map has no record of it,
    which says nothing about the room. Compared as independent maps, the same absence is a removal."""
    before = [_obj(0, CHAIR, [0.0, 0.0, 2.0], 0.7), _obj(2, PLANT, [1.0, 0.0, 3.0], 0.5)]
    after = [_obj(0, CHAIR, [0.0, 0.0, 2.0], 0.8)]
    continued = compare_maps([evidence_of(o) for o in before], [evidence_of(o) for o in after],
                             absent_is_withdrawn=True)
    assert continued.counts()["removed"] == 0 and [o.id for o in continued.withdrawn] == [2]
    assert len(continued.unchanged) == 1
    independent = compare_maps([evidence_of(o) for o in before], [evidence_of(o) for o in after])
    assert independent.counts()["removed"] == 1 and independent.withdrawn == ()


def test_maps_of_separate_runs_are_matched_by_place() -> None:
    before = [_obj(0, CHAIR, [0.0, 0.0, 2.0], 0.7), _obj(1, CUP, [1.0, 0.0, 2.0], 0.7)]
    after = [_obj(7, CHAIR, [0.1, 0.0, 2.0], 0.5, 3), _obj(8, CUP, [1.0, 0.0, 3.0], 0.5, 4)]  # ids of another run
    report = compare_maps([evidence_of(o) for o in before], [evidence_of(o) for o in after],
                          ChangeReportConfig(max_move_m=0.5))
    assert report.counts() == {"moved": 0, "removed": 1, "added": 1, "replaced": 0, "unchanged": 1}


def test_evidence_is_bounded_and_keeps_the_first_steps() -> None:
    obj = _obj(0, CHAIR, [0.0, 0.0, 2.0], 0.5)
    for kf in range(1, 60):
        obj.record_belief(kf, "seen")
        obj.record_sighting(kf)
        obj.record_sighting(kf)  # once per keyframe
    assert len(obj.belief_history) == 24 and len(obj.seen_keyframes) == 24
    assert obj.seen_keyframes[:5] == [0, 1, 2, 3, 40] and obj.seen_keyframes[-1] == 59


def test_keyframe_thumbnail_and_map_up() -> None:
    thumb = keyframe_thumbnail(np.full((240, 320, 3), 7, np.uint8))
    assert thumb.shape == (72, 96, 3) and int(thumb[0, 0, 0]) == 7
    with pytest.raises(ValueError, match="uint8"):
        keyframe_thumbnail(np.zeros((240, 320), np.float32))
    a, b = _obj(0, CHAIR, [0.0, 0.0, 2.0], 0.5), _obj(1, CUP, [0.0, 0.0, 1.0], 0.5)
    assert map_up([a, b]) is None
    a.up_sum_w = np.array([0.0, -2.0, 0.0])
    np.testing.assert_allclose(map_up([a, b]), [0.0, -1.0, 0.0])
