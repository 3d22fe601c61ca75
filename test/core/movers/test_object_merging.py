"""Volume overlap checking (Dai et al. 2021, eq. 12) and fusion of object targets."""

from __future__ import annotations

import numpy as np
import pytest

from changing_slam_ros.core.movers.object_merging import MergeConfig, merge_objects, overlap_m3, overlapping_groups
from changing_slam_ros.core.movers.object_tracking import MovingObject
from changing_slam_ros.core.geometry.se3 import make_pose, transform_points
from changing_slam_ros.errors import ConfigError


def _box_points(rng: np.random.Generator, n: int, centre: list[float], half_m: list[float], noise_m: float = 0.003) -> np.ndarray:
    """n points on the surface of a box (n, 3) with measurement noise."""
    pts = rng.uniform(-1.0, 1.0, (n, 3))
    face = rng.integers(0, 3, n)
    pts[np.arange(n), face] = rng.choice([-1.0, 1.0], n)
    return np.asarray(centre) + pts * np.asarray(half_m) + rng.normal(0.0, noise_m, (n, 3))


def test_two_interleaved_halves_of_one_object_overlap_and_merge() -> None:
    rng = np.random.default_rng(0)
    box = _box_points(rng, 200, [0.0, 0.0, 1.5], [0.2, 0.15, 0.1])
    first, second = box[::2], box[1::2]  # the same surfaces, points created twice from two viewpoints
    d = overlap_m3(first, second)
    assert d > 0.5 * 0.4 * 0.3 * 0.2 * 0.5  # most of the box volume is shared
    assert overlapping_groups([first, second], MergeConfig()) == [[0, 1]]


def test_two_views_sharing_one_face_overlap() -> None:
    rng = np.random.default_rng(1)
    box = _box_points(rng, 400, [0.0, 0.0, 1.5], [0.2, 0.15, 0.1])
    front = box[(box[:, 2] < 1.41) | (box[:, 1] > 0.14)]  # front face and top face
    side = box[(box[:, 0] > 0.19) | (box[:, 1] > 0.14)]  # right face and top face
    assert overlap_m3(front, side) > 0.0
    assert overlapping_groups([front, side], MergeConfig()) == [[0, 1]]


def test_distant_objects_stay_apart() -> None:
    rng = np.random.default_rng(2)
    a = _box_points(rng, 100, [0.0, 0.0, 1.5], [0.2, 0.15, 0.1])
    b = _box_points(rng, 100, [0.8, 0.1, 1.7], [0.2, 0.15, 0.1])
    c = _box_points(rng, 100, [0.45, 0.0, 1.5], [0.1, 0.1, 0.1])  # between them, touching neither
    assert overlap_m3(a, b) < 0.0
    assert overlapping_groups([a, b, c], MergeConfig()) == [[0], [1], [2]]
    # Even a generous tolerance keeps them apart: d is several times the smaller volume below zero.
    assert overlapping_groups([a, b], MergeConfig(overlap_tolerance=0.5)) == [[0], [1]]


def test_an_intermediate_target_connects_two_that_do_not_overlap() -> None:
    """The paper's Fig. 5b: A overlaps B, B overlaps C, A and C are far apart; all three are fused."""
    rng = np.random.default_rng(3)
    long_box = _box_points(rng, 600, [0.0, 0.0, 1.5], [0.6, 0.1, 0.1])
    x = long_box[:, 0]
    a, b, c = long_box[x < -0.1], long_box[(x > -0.35) & (x < 0.35)], long_box[x > 0.1]
    assert overlap_m3(a, c) < 0.0
    assert overlapping_groups([a, c, b], MergeConfig()) == [[0, 1, 2]]


def test_halves_split_by_a_plane_need_the_tolerance() -> None:
    rng = np.random.default_rng(4)
    box = _box_points(rng, 300, [0.0, 0.0, 1.5], [0.2, 0.15, 0.1])
    left, right = box[box[:, 0] < 0.0], box[box[:, 0] >= 0.0]
    d = overlap_m3(left, right)
    assert d <= 0.0  # eq. 12 alone: the union's hull also fills the gap between the halves
    assert overlapping_groups([left, right], MergeConfig()) == [[0], [1]]
    assert overlapping_groups([left, right], MergeConfig(overlap_tolerance=0.3)) == [[0, 1]]


def test_merge_objects_fuses_a_new_target_into_the_existing_moving_object() -> None:
    rng = np.random.default_rng(5)
    points_true = _box_points(rng, 120, [0.0, 0.0, 0.0], [0.2, 0.15, 0.1], noise_m=0.0)
    motion = [make_pose(np.eye(3), np.array([0.1 * k, 0.0, 1.5])) for k in range(4)]
    ids = np.arange(120)
    # Object 1 existed from stamp 0 with the even points; object 2 was created at stamp 2 from the odd
    # points (with the same motion), its frame at their centre.
    old = MovingObject.create(1, ids[::2], transform_points(motion[0], points_true[::2]), 0)
    for k in range(1, 4):
        old.poses[k] = motion[k] @ np.linalg.inv(motion[0]) @ old.poses[0]
    new = MovingObject.create(2, ids[1::2], transform_points(motion[2], points_true[1::2]), 2)
    new.poses[3] = motion[3] @ np.linalg.inv(motion[2]) @ new.poses[2]
    far = MovingObject.create(3, np.arange(500, 560), transform_points(motion[3], points_true[:60] + [2.0, 0, 0]), 3)
    merged = merge_objects([new, old, far], 3, MergeConfig())
    assert [o.object_id for o in merged] == [1, 3]
    fused = merged[0]
    assert len(fused.point_ids) == 120
    order = np.argsort(fused.point_ids)
    np.testing.assert_allclose(fused.points_world(3)[order], transform_points(motion[3], points_true), atol=1e-9)
    np.testing.assert_allclose(fused.points_world(0)[order], transform_points(motion[0], points_true), atol=1e-9)


def test_merge_config_rejects_negative_tolerance() -> None:
    with pytest.raises(ConfigError, match="overlap_tolerance"):
        MergeConfig(overlap_tolerance=-0.1)
