"""Box completion for the semantic map: an object seen from one side gets its class's depth behind what was seen."""

import dataclasses

import numpy as np
import pytest

from changing_slam_ros.core.objects.map_object import MapObject, ObjectMapConfig
from changing_slam_ros.core.objects.object_box_completion import completed_box, depth_seen, gravity_up
from changing_slam_ros.core.objects.semantic_map import build_semantic_map
from changing_slam_ros.io.semantic_map_file import object_map_from_dict, object_map_to_dict

PLANT = 58
CENTRE = np.array([1.0, 2.0, 0.45])  # a potted plant, 44 cm across and 90 cm tall, standing on the floor (z up)
RADIUS, HEIGHT = 0.22, 0.9


def _surface(rng, n=4000):
    """Points on the plant's round side (foliage seen from the side), with their outward normals."""
    t = rng.uniform(0.0, 2.0 * np.pi, n)
    normals = np.c_[np.cos(t), np.sin(t), np.zeros(n)]
    p = np.c_[RADIUS * normals[:, :2], rng.uniform(-0.5, 0.5, n) * HEIGHT]
    return CENTRE + p, normals


UP = np.array([0.0, 0.0, 1.0])


def _seen_from(cameras, rng, up=UP):
    """The plant as a MapObject whose points are the surface visible from any of `cameras`, one view each."""
    pts, normals = _surface(rng)
    visible = np.zeros(len(pts), bool)
    for c in cameras:
        visible |= np.einsum("ij,ij->i", normals, c - pts) > 0.0
    obj = MapObject(1, PLANT, (0, 0, 1, 1), (0, 0, 1, 1), 0, 0, point_ids=np.arange(visible.sum()),
                    points_w=pts[visible])
    for c in cameras:
        obj.add_view(c, obj.centroid_w, up)
    return obj


def _cameras(angles_deg, dist=2.5, height=1.3):
    a = np.radians(np.asarray(angles_deg, float))
    return [CENTRE + np.array([dist * np.cos(t), dist * np.sin(t), height - CENTRE[2]]) for t in a]


def test_a_plant_seen_from_one_side_gets_its_box_centre_back():
    rng = np.random.default_rng(0)
    obj = _seen_from(_cameras([-100, -90, -80]), rng)  # the camera passes in front of it (the -y side)
    raw_err = np.linalg.norm(obj.box_center_w - CENTRE)
    assert raw_err > 0.08  # the box of the points is the front half: the centre sits on the camera's side
    box = completed_box(obj, ObjectMapConfig(class_depth_m={PLANT: 0.44}))
    assert 0.15 < box.extension_m < 0.3  # the front half of a round plant shows about its radius of relief
    assert np.linalg.norm(box.center_w - CENTRE) < 0.4 * raw_err
    assert np.linalg.norm(box.center_w[:2] - CENTRE[:2]) < 0.04  # on the floor plan, where the plant stands
    assert box.size_m[1] > 0.4  # the depth along the viewing direction (y) is the class's


def test_a_plant_seen_from_around_is_left_as_its_points_say():
    rng = np.random.default_rng(1)
    obj = _seen_from(_cameras([0, 90, 180, 270]), rng)
    assert obj.n_views == 4 and np.linalg.norm(obj.view_sum_w) / obj.n_views < 0.75
    box = completed_box(obj, ObjectMapConfig(class_depth_m={PLANT: 0.6}))  # a prior larger than the plant
    assert box.extension_m == 0.0 and np.allclose(box.center_w, obj.box_center_w)


def test_no_prior_no_switch_or_deep_enough_changes_nothing():
    rng = np.random.default_rng(2)
    obj = _seen_from(_cameras([-90]), rng)
    for cfg in (ObjectMapConfig(class_depth_m={}), ObjectMapConfig(box_completion=False),
                ObjectMapConfig(class_depth_m={PLANT: 0.01})):
        box = completed_box(obj, cfg)
        assert box.extension_m == 0.0 and np.allclose(box.size_m, obj.box_size_m)
    # the semantic map reports the completed box; the MapObject keeps its own
    smap = build_semantic_map([obj], ObjectMapConfig(class_depth_m={PLANT: 0.44}))
    assert np.linalg.norm(np.asarray(smap.objects[0].box_center_w) - CENTRE) < np.linalg.norm(obj.box_center_w - CENTRE)
    assert np.allclose(smap.objects[0].centroid_w, obj.centroid_w)


def test_without_a_known_up_there_is_no_completion():
    obj = _seen_from(_cameras([-100, -90, -80]), np.random.default_rng(5), up=None)
    assert completed_box(obj, ObjectMapConfig(class_depth_m={PLANT: 0.44})).extension_m == 0.0


def test_depth_seen_is_the_robust_spread_along_a_direction():
    pts = np.c_[np.linspace(0.0, 1.0, 101), np.zeros(101), np.zeros(101)]
    assert depth_seen(pts, np.array([1.0, 0.0, 0.0])) == pytest.approx(0.9)
    assert depth_seen(pts, np.array([0.0, 1.0, 0.0])) == pytest.approx(0.0)


def test_gravity_up_is_the_floor_normal_near_the_camera_up_not_a_wall():
    wall, floor = np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, -1.0])  # the wall holds more points: first
    pitched = np.array([0.0, np.sin(np.radians(30)), np.cos(np.radians(30))])  # a camera looking 30 deg down
    assert np.allclose(gravity_up([wall, floor], pitched), [0.0, 0.0, 1.0])
    assert gravity_up([wall], pitched) is None


def test_viewing_directions_are_saved_and_turned_with_the_map():
    from changing_slam_ros.eval.object_alignment import aligned_objects

    obj = _seen_from(_cameras([-90, -80]), np.random.default_rng(3))
    back = object_map_from_dict(object_map_to_dict([obj]), "test")[0]
    assert back.n_views == 2 and np.allclose(back.view_sum_w, obj.view_sum_w) and np.allclose(back.up_sum_w, 2 * UP)
    old = dict(object_map_to_dict([obj]))
    old["objects"] = [{k: v for k, v in old["objects"][0].items() if k not in ("view_sum_w", "n_views")}]
    assert object_map_from_dict(old, "old file")[0].n_views == 0  # files without view records still load
    T = np.eye(4)
    T[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]  # 90 deg about z
    turned = aligned_objects([dataclasses.replace(obj)], T)[0]
    assert np.allclose(turned.view_sum_w, T[:3, :3] @ obj.view_sum_w)


def test_completion_stops_at_the_wall_behind_the_object():
    from changing_slam_ros.core.objects.object_point_weights import Plane

    obj = _seen_from(_cameras([-100, -90, -80]), np.random.default_rng(6))
    free = completed_box(obj, ObjectMapConfig(class_depth_m={PLANT: 0.8}))  # a prior far deeper than the plant
    wall = Plane(np.array([0.0, -1.0, 0.0]), CENTRE[1] + RADIUS + 0.02)  # y = 2.24, 2 cm behind the plant's back
    bounded = completed_box(obj, ObjectMapConfig(class_depth_m={PLANT: 0.8}), [wall])
    far_face = lambda b: b.center_w[1] + 0.5 * b.size_m[1]  # noqa: E731
    assert far_face(free) > CENTRE[1] + 0.4 and far_face(bounded) < CENTRE[1] + RADIUS + 0.05
    floor = Plane(np.array([0.0, 0.0, 1.0]), 0.0)  # not facing the viewing direction: no limit
    assert completed_box(obj, ObjectMapConfig(class_depth_m={PLANT: 0.8}), [floor]).extension_m == pytest.approx(
        free.extension_m, abs=0.01)  # (the floor plane only takes the points within 2 cm of it out of the depth)


def test_object_map_files_keep_the_room_planes(tmp_path):
    from changing_slam_ros.core.objects.object_point_weights import Plane
    from changing_slam_ros.io.semantic_map_file import read_object_map_file, write_object_map

    obj = _seen_from(_cameras([-90]), np.random.default_rng(7))
    write_object_map(tmp_path / "o.json", [obj], [Plane(np.array([0.0, 0.0, 1.0]), -0.5)])
    objects, planes = read_object_map_file(tmp_path / "o.json")
    assert len(planes) == 1 and np.allclose(planes[0].normal, [0, 0, 1]) and planes[0].offset == -0.5
    assert objects[0].n_views == 1
