"""Constructed object maps for the object layer's tests: a keyframe over static points, one object of each kind of
change."""

from __future__ import annotations

import numpy as np

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.map.slam_map import SlamMap
from changing_slam_ros.core.objects.map_object import MapObject

CHAIR, PLANT, TV, SUITCASE, CUP, BOTTLE = 56, 58, 62, 28, 41, 39


def static_keyframe(kf_id: int, points: np.ndarray, camera: CameraIntrinsics) -> tuple[SlamMap, Keyframe]:
    """A map whose one keyframe (id `kf_id`, at the origin: camera frame = map frame) sees `points` (N, 3) as static
    map points, each at its projection; the keyframe is not yet added to the map."""
    n = len(points)
    px = np.c_[camera.fx * points[:, 0] / points[:, 2] + camera.cx, camera.fy * points[:, 1] / points[:, 2] + camera.cy]
    T = np.eye(4)
    kf = Keyframe(kf_id, kf_id * 10**9, T, camera, px.astype(np.float32), np.zeros(n, np.int8),
                  np.zeros((n, 32), np.uint8), points[:, 2].astype(np.float32), np.full(n, -1, np.int64))
    m = SlamMap(0)
    kf.point_ids[:] = m.points.add(points, kf.descriptors, kf_id, np.arange(n), T[:3, 3], np.zeros(n, np.int64),
                                   np.ones(8))
    return m, kf


def map_object(oid: int, class_id: int, centre: list[float], belief: float, first_kf: int = 0) -> MapObject:
    """A MapObject of 30 points within 10 cm of `centre` (their mean exactly there), first seen in `first_kf`."""
    rng = np.random.default_rng(oid)
    pts = np.asarray(centre) + rng.uniform(-0.1, 0.1, (30, 3))
    pts -= pts.mean(axis=0) - np.asarray(centre)
    obj = MapObject(oid, class_id, (0, 0, 10, 10), (0, 0, 10, 10), first_kf, first_kf, belief=belief,
                    point_ids=np.arange(oid * 100, oid * 100 + 30), points_w=pts)
    obj.record_belief(first_kf, "new")
    obj.record_sighting(first_kf)
    return obj


def changed_room_maps() -> tuple[list[MapObject], list[MapObject]]:
    """Before: a tv that stays, a chair that moves 2 m, a plant that goes, a suitcase replaced by a bottle.
    After (continuing the before map): the tv and the three lost objects (belief 0.18 after a miss in keyframe
    29), a new chair at the new place, a new cup, a new bottle 0.2 m from where the suitcase stood."""
    before = [map_object(0, TV, [0.0, 0.0, 3.0], 0.7), map_object(1, CHAIR, [1.0, 0.0, 2.0], 0.7, 2),
              map_object(2, PLANT, [-1.0, 0.0, 2.5], 0.5, 4), map_object(3, SUITCASE, [2.0, 0.0, 3.0], 0.6, 5)]
    after = [map_object(0, TV, [0.02, 0.0, 3.01], 0.8), map_object(1, CHAIR, [1.0, 0.0, 2.0], 0.18, 2),
             map_object(2, PLANT, [-1.0, 0.0, 2.5], 0.18, 4), map_object(3, SUITCASE, [2.0, 0.0, 3.0], 0.18, 5),
             map_object(4, CHAIR, [1.0, 0.0, 4.0], 0.5, 30), map_object(5, CUP, [0.0, 0.5, 1.0], 0.5, 31),
             map_object(6, BOTTLE, [2.2, 0.0, 3.0], 0.5, 33)]
    for o in after[1:4]:
        o.belief = 0.5
        o.record_belief(28, "session")
        o.belief = 0.18
        o.record_belief(29, "missed")
    return before, after
