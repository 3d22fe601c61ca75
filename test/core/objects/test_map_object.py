"""MapObject (Changing-SLAM §4.2): centroid, robust 3D box, point bookkeeping."""

from __future__ import annotations

import numpy as np
import pytest

from changing_slam_ros.core.objects.map_object import MapObject, box_extent


def _box_surface_points(rng: np.random.Generator, lo: np.ndarray, hi: np.ndarray, n: int) -> np.ndarray:
    pts = rng.uniform(lo, hi, size=(n, 3))
    axis = rng.integers(0, 3, n)
    side = rng.integers(0, 2, n)
    pts[np.arange(n), axis] = np.where(side == 1, hi[axis], lo[axis])
    return pts


def test_box_dimensions_are_the_median_of_the_five_percent_extremes_and_ignore_outliers() -> None:
    rng = np.random.default_rng(3)
    lo, hi = np.array([1.0, 2.0, 0.0]), np.array([1.5, 2.4, 0.9])
    pts = _box_surface_points(rng, lo, hi, 400)
    pts[:4] = [[4.0, 2.2, 0.5], [1.2, -3.0, 0.5], [1.2, 2.2, 5.0], [-2.0, 2.2, 0.5]]  # 1 % stray points
    centre, size = box_extent(pts)
    np.testing.assert_allclose(size, hi - lo, atol=0.03)
    np.testing.assert_allclose(centre, (lo + hi) / 2, atol=0.02)
    naive = pts.max(axis=0) - pts.min(axis=0)
    assert np.all(naive > size + 0.5)  # max - min is ruined by the stray points


def test_box_extent_by_hand_on_twenty_points() -> None:
    # 20 points: 5 % = 1 point each side, so the box is exactly max - min; centre half-way
    x = np.arange(20, dtype=float)
    pts = np.c_[x, 2 * x, np.zeros(20)]
    centre, size = box_extent(pts)
    np.testing.assert_allclose(size, [19.0, 38.0, 0.0])
    np.testing.assert_allclose(centre, [9.5, 19.0, 0.0])
    # 40 points: 2 per side, median of the two largest (38, 39) and smallest (0, 1)
    x = np.arange(40, dtype=float)
    _, size = box_extent(np.c_[x, x, x])
    np.testing.assert_allclose(size, [38.0] * 3)


def test_map_object_centroid_is_the_mean_and_add_points_is_a_union() -> None:
    obj = MapObject(7, 56, (0, 0, 10, 10), (0, 0, 10, 10), 3, 3,
                    point_ids=np.array([1, 2, 3]), points_w=np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0.0]]))
    np.testing.assert_allclose(obj.centroid_w, [1.0, 0.0, 0.0])
    obj.add_points(np.array([3, 4, 4]), np.array([[9.0, 9.0, 9.0], [3.0, 0.0, 0.0], [3.0, 0.0, 0.0]]))  # 3 held
    assert obj.point_ids.tolist() == [1, 2, 3, 4]
    np.testing.assert_allclose(obj.centroid_w, [1.5, 0.0, 0.0])
    assert obj.belief == 0.5 and not obj.active
    obj.refresh_points(obj.points_w + [0.0, 1.0, 0.0], keep=np.array([True, True, False, True]))
    assert obj.point_ids.tolist() == [1, 2, 4]
    np.testing.assert_allclose(obj.centroid_w, [4.0 / 3.0, 1.0, 0.0])
    with pytest.raises(ValueError, match="MapObject 7: 2 point ids for 1 positions"):
        obj.set_points(np.array([1, 2]), np.zeros((1, 3)))
