"""Centroid weights of MapObjects (core/objects/object_point_weights.py, MapObject.point_weights): constructed point sets
with a known own-surface centroid."""

from __future__ import annotations

import numpy as np
import pytest

from changing_slam_ros.core.objects.map_object import MapObject, ObjectMapConfig, object_map_config
from changing_slam_ros.core.objects.object_point_weights import (
    fit_structure_planes, point_weights, reweight_objects, voxel_weights,
)
from changing_slam_ros.errors import ConfigError, MapFileError
from changing_slam_ros.io.semantic_map_file import object_map_from_dict, object_map_to_dict

CFG = ObjectMapConfig()


def _grid(x: tuple[float, float], y: tuple[float, float], z: tuple[float, float], step: float = 0.01) -> np.ndarray:
    ax = [np.arange(a, b + 1e-9, step) if b > a else np.array([a]) for a, b in (x, y, z)]
    return np.stack(np.meshgrid(*ax, indexing="ij"), -1).reshape(-1, 3)


def _room(rng: np.random.Generator) -> np.ndarray:
    """Static map points: a 4 x 4 m floor (z 0), a wall (y 2) and some clutter."""
    floor = np.c_[rng.uniform(-2, 2, (2000, 2)), rng.normal(0, 0.003, 2000)]
    wall = np.c_[rng.uniform(-2, 2, 1500), 2 + rng.normal(0, 0.003, 1500), rng.uniform(0, 2.5, 1500)]
    clutter = rng.uniform([-2, -2, 0.1], [2, 2, 2.0], (300, 3))
    return np.vstack([floor, wall, clutter])


def _chair(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(the chair's own surface sampled uniformly (seat at 0.45 m, back at y 0.45), the point set a layer would
    collect: the same surface, the back seen from four times as many views, and the floor between the legs)."""
    # offset by half a 2.5 cm voxel: a surface lying exactly on a voxel boundary fills two layers of cubes
    seat = _grid((0, 0.45), (0, 0.45), (0.45, 0.45)) + 0.0125
    back = _grid((0, 0.45), (0.45, 0.45), (0.46, 0.9)) + 0.0125
    own = np.vstack([seat, back])
    extra_back = np.vstack([back + rng.normal(0, 0.002, back.shape) for _ in range(3)])
    floor = np.c_[rng.uniform(-0.05, 0.5, (3000, 2)), rng.normal(0, 0.003, 3000)]
    return own, np.vstack([own, extra_back, floor])


def test_fit_structure_planes_finds_floor_and_wall() -> None:
    planes = fit_structure_planes(_room(np.random.default_rng(1)), 0.02, 0.05, 6, 150, 4000, seed=3)
    normals = np.abs(np.array([p.normal for p in planes]))
    assert len(planes) == 2  # the clutter holds no plane of 5 % of the points
    assert {int(np.argmax(n)) for n in normals} == {1, 2}  # the wall's normal is y, the floor's z
    floor = planes[int(np.argmax(normals[:, 2]))]
    wall = planes[int(np.argmax(normals[:, 1]))]
    assert floor.distance(np.array([[0.3, -1.0, 0.0]]))[0] < 0.005
    assert wall.distance(np.array([[0.3, 2.0, 1.0]]))[0] < 0.005
    assert wall.distance(np.array([[0.3, 1.5, 1.0]]))[0] == pytest.approx(0.5, abs=0.01)


def test_voxel_weights_count_each_cube_once() -> None:
    pts = np.array([[0.001, 0.001, 0.001], [0.002, 0.002, 0.002], [0.003, 0.001, 0.002], [0.1, 0.1, 0.1]])
    w = voxel_weights(pts, 0.025)
    np.testing.assert_allclose(w, [1 / 3, 1 / 3, 1 / 3, 1.0])
    np.testing.assert_allclose(voxel_weights(pts, 0.0), 1.0)


def test_chair_with_floor_and_doubled_back_gets_its_own_centroid() -> None:
    rng = np.random.default_rng(0)
    own, collected = _chair(rng)
    truth = own.mean(axis=0)
    planes = fit_structure_planes(_room(rng), CFG.structure_plane_dist_m, CFG.structure_plane_min_fraction,
                                  CFG.structure_max_planes, CFG.structure_plane_iterations,
                                  CFG.structure_plane_max_points)
    plain = MapObject(0, 56, (0, 0, 1, 1), (0, 0, 1, 1), 0, 0, point_ids=np.arange(len(collected)), points_w=collected)
    assert np.linalg.norm(plain.centroid_w - truth) > 0.06  # 7.9 cm: the floor pulls the mean down, the back back
    obj = MapObject(0, 56, (0, 0, 1, 1), (0, 0, 1, 1), 0, 0, point_ids=np.arange(len(collected)), points_w=collected)
    obj.set_weights(point_weights(collected, planes, None, CFG))
    assert np.linalg.norm(obj.centroid_w - truth) < 0.02
    # without the plane rule the floor stays in; without the voxels the back counts four times
    no_planes = point_weights(collected, [], None, CFG)
    assert np.linalg.norm((no_planes @ collected) / no_planes.sum() - truth) > 0.10
    flat = point_weights(collected, planes, None, ObjectMapConfig(centroid_voxel_m=0.0))
    assert np.linalg.norm((flat @ collected) / flat.sum() - truth) > 0.05
    # the box is over the chair's points only: it starts at the seat's legs' height, not at the floor
    assert obj.box_center_w[2] - obj.box_size_m[2] / 2 > 0.4
    assert plain.box_center_w[2] - plain.box_size_m[2] / 2 < 0.05


def test_points_of_a_smaller_object_on_top_are_left_to_it() -> None:
    rng = np.random.default_rng(2)
    seat = _grid((0, 0.45), (0, 0.45), (0.45, 0.45)) + 0.0125  # off the voxel boundaries (see _chair)
    d = rng.normal(size=(800, 3))
    bear = np.array([0.22, 0.22, 0.63]) + 0.12 * d / np.linalg.norm(d, axis=1, keepdims=True)
    chair = MapObject(0, 56, (0, 0, 1, 1), (0, 0, 1, 1), 0, 0, point_ids=np.arange(len(seat) + 800),
                      points_w=np.vstack([seat, bear]))
    teddy = MapObject(1, 77, (0, 0, 1, 1), (0, 0, 1, 1), 0, 0, point_ids=-np.arange(2, 802), points_w=bear + 0.002)
    assert chair.centroid_w[2] > 0.49  # the bear lifts the mean
    reweight_objects([chair, teddy], [], CFG)
    assert np.linalg.norm(chair.centroid_w - seat.mean(axis=0)) < 0.01
    assert np.linalg.norm(teddy.centroid_w - (bear + 0.002).mean(axis=0)) < 0.01  # the bear keeps its own points
    # off: the chair keeps the bear
    chair.set_weights(point_weights(chair.points_w, [], teddy.points_w, ObjectMapConfig(shared_point_dist_m=0.0)))
    assert chair.centroid_w[2] > 0.49


def test_an_object_wholly_on_a_plane_keeps_its_points() -> None:
    mat = _grid((0, 0.3), (0, 0.3), (0.005, 0.005))  # a mat on the floor: every point within 2 cm of it
    planes = fit_structure_planes(_room(np.random.default_rng(4)), 0.02, 0.05, 6, 150, 4000)
    w = point_weights(mat, planes, None, CFG)
    assert np.all(w > 0)
    np.testing.assert_allclose((w @ mat) / w.sum(), mat.mean(axis=0), atol=3e-3)


def test_map_object_weights_follow_points() -> None:
    pts = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]])
    obj = MapObject(0, 41, (0, 0, 1, 1), (0, 0, 1, 1), 0, 0, point_ids=np.arange(4), points_w=pts)
    assert obj.centroid_w[0] == pytest.approx(1.5)
    obj.set_weights(np.array([1.0, 1.0, 0.0, 2.0]))
    assert obj.centroid_w[0] == pytest.approx((0 + 1 + 6) / 4)
    assert obj.box_size_m[0] == pytest.approx(3.0)  # points 0, 1 and 3 span the box
    obj.refresh_points(pts + 1.0, keep=np.array([True, False, True, True]))
    np.testing.assert_allclose(obj.point_weights, [1.0, 0.0, 2.0])
    assert obj.centroid_w[0] == pytest.approx((1 + 8) / 3)
    obj.add_points(np.array([9]), np.array([[10.0, 0, 0]]))
    assert obj.point_weights[-1] == pytest.approx(1.0)  # the mean weight until re-weighted
    with pytest.raises(ValueError, match="weights"):
        obj.set_weights(np.array([1.0, -1.0, 1.0, 1.0]))
    obj.set_weights(np.zeros(4))  # all zero: the plain mean
    assert obj.point_weights is None
    assert obj.centroid_w[0] == pytest.approx((1 + 3 + 4 + 10) / 4)


def test_object_map_document_keeps_weights() -> None:
    obj = MapObject(3, 41, (0, 0, 1, 1), (0, 0, 1, 1), 0, 0, point_ids=np.arange(3),
                    points_w=np.array([[0.0, 0, 0], [1, 0, 0], [4, 0, 0]]), point_weights=np.array([1.0, 1.0, 0.0]))
    back = object_map_from_dict(object_map_to_dict([obj]), "test")[0]
    np.testing.assert_allclose(back.point_weights, [1.0, 1.0, 0.0])
    assert back.centroid_w[0] == pytest.approx(0.5)
    doc = object_map_to_dict([obj])
    doc["objects"][0]["point_weights"] = [1.0, -2.0, 0.0]
    with pytest.raises(MapFileError, match=r"objects\[0\]\.point_weights"):
        object_map_from_dict(doc, "test")


def test_config_rejects_bad_values() -> None:
    with pytest.raises(ConfigError, match="objects.centroid_voxel_m"):
        object_map_config({"centroid_voxel_m": -0.01})
    with pytest.raises(ConfigError, match="objects.structure_plane_min_fraction"):
        object_map_config({"structure_plane_min_fraction": 0.0})
    with pytest.raises(ConfigError, match="objects.structure_refit_keyframes"):
        object_map_config({"structure_refit_keyframes": 0})
