"""The plane check: a picture on a wall is not an object, a box in front of the wall is, a clock on it is."""

from __future__ import annotations

import numpy as np

from changing_slam_ros.core.dynamic.dynamic_objects import ObjectMotion, ObjectState
from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.map.slam_map import SlamMap
from changing_slam_ros.core.objects.map_object import ObjectMapConfig
from changing_slam_ros.core.objects.object_layer import ObjectLayer, ObjectLayerConfig
from changing_slam_ros.core.objects.object_point_weights import Plane
from changing_slam_ros.core.objects.picture_check import is_picture, wall_fraction, walls
from object_maps import static_keyframe

CAM = CameraIntrinsics(320, 240, 262.5, 262.5, 159.5, 119.5)
PLANT, SUITCASE, CLOCK = 58, 28, 74
WALL_Z_M, FLOOR_Y_M = 3.0, 1.0  # camera frame = map frame: x right, y down, z forward
WALL = Plane(np.array([0.0, 0.0, 1.0]), -WALL_Z_M)
FLOOR = Plane(np.array([0.0, 1.0, 0.0]), -FLOOR_Y_M)
UP = np.array([0.0, -1.0, 0.0])
BOXES = {PLANT: (40.0, 60.0, 100.0, 140.0), SUITCASE: (130.0, 80.0, 190.0, 170.0), CLOCK: (220.0, 50.0, 260.0, 90.0)}


def _room_keyframe(kf_id: int, box_depth_m: dict[int, float]) -> tuple[SlamMap, Keyframe, np.ndarray]:
    """One keyframe at the origin facing a wall 3 m away above a floor 1 m below the camera; the room's static map
    points (300 on the wall, 300 on the floor) and a depth image with each class's box region at its depth."""
    rng = np.random.default_rng(kf_id)
    wall = np.c_[rng.uniform(-1.5, 1.5, 300), rng.uniform(-1.0, 0.9, 300), np.full(300, WALL_Z_M)]
    floor = np.c_[rng.uniform(-1.5, 1.5, 300), np.full(300, FLOOR_Y_M), rng.uniform(1.0, 3.0, 300)]
    m, kf = static_keyframe(kf_id, np.vstack([wall, floor]), CAM)
    m.add_keyframe(kf)
    depth = np.full((240, 320), WALL_Z_M, np.float32)
    depth[180:, :] = FLOOR_Y_M * CAM.fy / (np.arange(180, 240)[:, None] - CAM.cy)  # the floor's rows
    for class_id, d in box_depth_m.items():
        x0, y0, x1, y1 = (int(v) for v in BOXES[class_id])
        depth[y0:y1, x0:x1] = d
    return m, kf, depth


def _states(classes: list[int]) -> list[ObjectState]:
    nan3 = np.full(3, np.nan)
    return [ObjectState(i + 1, c, BOXES[c], nan3, nan3, 0.0, ObjectMotion.STATIC, 3, False) for i, c in enumerate(classes)]


def test_a_picture_on_the_wall_is_no_object_and_a_box_in_front_of_it_and_a_clock_on_it_are() -> None:
    layer = ObjectLayer(ObjectLayerConfig(association=ObjectMapConfig(structure_refit_keyframes=1)))
    depths = {PLANT: WALL_Z_M, SUITCASE: WALL_Z_M - 0.3, CLOCK: WALL_Z_M}  # the plant is a photo on the wall
    m, kf, depth = _room_keyframe(0, depths)
    first = layer.after_keyframe(kf, m, depth, _states([PLANT, SUITCASE, CLOCK]))
    # the walls are only known after this keyframe's plane fit: the photo was mapped, then dropped as a picture
    assert len(first.association.new_object_ids) == 3
    assert sorted(o.class_id for o in layer.objects(0)) == [SUITCASE, CLOCK]
    planes = layer.planes(0)
    assert any(abs(p.normal[2]) > 0.99 and abs(abs(p.offset) - WALL_Z_M) < 0.01 for p in planes)
    # the next keyframe knows the wall: the photo is skipped at once, the suitcase and the clock merge
    kf2 = Keyframe(1, 10**9, np.eye(4), CAM, np.zeros((0, 2), np.float32), np.zeros(0, np.int8),
                   np.zeros((0, 32), np.uint8), np.zeros(0, np.float32), np.zeros(0, np.int64))
    m.add_keyframe(kf2)
    second = layer.after_keyframe(kf2, m, depth, _states([PLANT, SUITCASE, CLOCK]))
    assert second.association.pictures == (0,) and second.association.assignments[0] == -1
    assert second.association.new_object_ids == ()
    assert sorted(o.class_id for o in layer.objects(0)) == [SUITCASE, CLOCK]
    suitcase = next(o for o in layer.objects(0) if o.class_id == SUITCASE)
    assert abs(float(np.median(suitcase.points_w[:, 2])) - (WALL_Z_M - 0.3)) < 0.01


def test_is_picture_needs_a_wall_and_a_three_dimensional_class() -> None:
    cfg = ObjectMapConfig()
    rng = np.random.default_rng(0)
    on_wall = np.c_[rng.uniform(-0.3, 0.3, 50), rng.uniform(-0.3, 0.3, 50), WALL_Z_M + rng.normal(0, 0.01, 50)]
    box = np.vstack([on_wall[:25] - [0, 0, 0.3], np.c_[np.full(25, 0.3), on_wall[25:, 1], rng.uniform(2.7, 3.0, 25)]])
    assert walls([WALL, FLOOR], UP, 60.0) == [WALL] and walls([WALL, FLOOR], None, 60.0) == []
    assert wall_fraction(on_wall, [WALL], 0.04) == 1.0
    assert is_picture(PLANT, on_wall, [WALL, FLOOR], UP, cfg)
    assert not is_picture(CLOCK, on_wall, [WALL, FLOOR], UP, cfg)  # wall-hung flat class
    assert not is_picture(PLANT, on_wall, [WALL, FLOOR], None, cfg)  # walls unknown
    assert not is_picture(SUITCASE, box, [WALL, FLOOR], UP, cfg)  # at most 2/5 of its points touch the wall
    on_floor = np.c_[on_wall[:, 0], np.full(50, FLOOR_Y_M), on_wall[:, 1] + 2.0]
    assert not is_picture(PLANT, on_floor, [WALL, FLOOR], UP, cfg)  # a floor is no wall
    assert not is_picture(PLANT, on_wall, [WALL], UP, ObjectMapConfig(picture_plane_dist_m=0.0))  # off


def test_a_plane_through_one_object_is_no_wall() -> None:
    from changing_slam_ros.core.objects.picture_check import plane_extent_m

    rng = np.random.default_rng(1)
    wall = np.c_[rng.uniform(-1.5, 1.5, 200), rng.uniform(-1.0, 0.9, 200), np.full(200, WALL_Z_M)]
    chair_front = np.c_[rng.uniform(-0.2, 0.2, 30), rng.uniform(0.0, 0.45, 30), np.full(30, 2.0)]
    pts = np.vstack([wall, chair_front])
    assert 2.6 < plane_extent_m(WALL, pts, 0.02) < 3.0
    assert 0.3 < plane_extent_m(Plane(np.array([0.0, 0.0, 1.0]), -2.0), pts, 0.02) < 0.45  # under wall_min_extent_m
