"""Short-term data association (Changing-SLAM §4.3): same-class IoU matching with the previous frame."""

from __future__ import annotations

import numpy as np
import pytest

from changing_slam_ros.core.dynamic.detector import CHAIR_CLASS_ID, PERSON_CLASS_ID, Detection
from changing_slam_ros.core.dynamic.short_term_association import (
    ShortTermAssociationConfig,
    ShortTermAssociator,
    match_boxes,
)
from changing_slam_ros.errors import ConfigError


def det(x0: float, y0: float, w: float, h: float, cls: int = CHAIR_CLASS_ID) -> Detection:
    return Detection((x0, y0, x0 + w, y0 + h), cls, 0.9)


def test_boxes_moving_a_little_each_frame_keep_their_ids_for_a_whole_sequence() -> None:
    a = ShortTermAssociator()
    ids = []
    for k in range(30):  # a person walking right 6 px/frame, a chair still, boxes jittering 1 px
        jitter = (-1) ** k
        res = a.associate([det(100 + 6 * k, 50, 80, 200, PERSON_CLASS_ID), det(400 + jitter, 300, 100, 90)])
        ids.append(res.object_ids.tolist())
        assert res.is_new.tolist() == ([True, True] if k == 0 else [False, False])
    assert ids == [[0, 1]] * 30


def test_an_unmatched_detection_or_a_different_class_starts_a_new_instance() -> None:
    a = ShortTermAssociator()
    a.associate([det(100, 100, 50, 50)])
    res = a.associate([det(102, 100, 50, 50, PERSON_CLASS_ID), det(300, 300, 40, 40), det(101, 101, 50, 50)])
    assert res.object_ids.tolist() == [1, 2, 0]  # person on the chair's spot is new; the chair keeps id 0
    assert res.is_new.tolist() == [True, True, False]
    gone = a.associate([])
    assert sorted(gone.lost_ids) == [0, 1, 2] and a.tracks == ()


def test_matching_is_one_to_one_and_prefers_the_highest_iou() -> None:
    prev = np.array([[0, 0, 100, 100], [60, 0, 160, 100]], float)
    cur = np.array([[55, 0, 155, 100], [5, 0, 105, 100], [30, 0, 130, 100]], float)
    classes = np.zeros(3, np.int64)
    match = match_boxes(prev, np.zeros(2, np.int64), cur, classes, min_iou=0.3)
    assert match.tolist() == [1, 0, -1]  # the third box overlaps both but each is taken by a better one


def test_a_missed_frame_is_bridged_only_when_configured() -> None:
    paper = ShortTermAssociator()
    bridged = ShortTermAssociator(ShortTermAssociationConfig(max_missed_frames=1))
    for a in (paper, bridged):
        a.associate([det(100, 100, 50, 50)])
        a.associate([])  # detector drop-out
    assert paper.associate([det(100, 100, 50, 50)]).object_ids.tolist() == [1]
    assert bridged.associate([det(100, 100, 50, 50)]).object_ids.tolist() == [0]


def test_min_iou_out_of_range_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match="short_term_association.min_iou"):
        ShortTermAssociationConfig(min_iou=0.0)
