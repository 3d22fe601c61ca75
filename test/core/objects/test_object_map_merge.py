"""Object maps follow a map merge (`ObjectLayer.maps_merged`, `core/objects/object_map_merge.py`)."""

from __future__ import annotations

import numpy as np

from changing_slam_ros.core.dynamic.dynamic_objects import ObjectMotion, ObjectState
from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.geometry.se3 import make_pose
from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.map.slam_map import SlamMap
from changing_slam_ros.core.objects.object_layer import ObjectLayer
from changing_slam_ros.core.slam.map_merging import append_points

CAM = CameraIntrinsics(320, 240, 262.5, 262.5, 159.5, 119.5)
CHAIR, CUP = 56, 41
BOX = (100.0, 60.0, 180.0, 180.0)


def _depth() -> np.ndarray:
    d = np.full((240, 320), 4.0, np.float32)
    d[60:180, 100:180] = 2.0
    return d


def _state(class_id: int) -> ObjectState:
    nan3 = np.full(3, np.nan)
    return ObjectState(7, class_id, BOX, nan3, nan3, 0.0, ObjectMotion.STATIC, 3, False)


def _map(map_id: int, kf_id: int) -> tuple[SlamMap, Keyframe]:
    """A map with one keyframe at the origin: 12 keypoints on the object (short-term id 7) with map points at 2 m."""
    rng = np.random.default_rng(kf_id)
    px = np.c_[rng.uniform(105, 165, 12), rng.uniform(65, 175, 12)].astype(np.float32)
    depth = np.full(12, 2.0, np.float32)
    kf = Keyframe(kf_id, kf_id * 10**9, np.eye(4), CAM, px, np.zeros(12, np.int8), np.zeros((12, 32), np.uint8),
                  depth, np.full(12, -1, np.int64), object_ids=np.full(12, 7, np.int64))
    m = SlamMap(map_id)
    kf.point_ids[:] = m.points.add(CAM.backproject(px, depth), kf.descriptors, kf_id, np.arange(12), np.zeros(3),
                                   np.zeros(12, np.int64), np.ones(8))
    m.add_keyframe(kf)
    return m, kf


def _merge(layer: ObjectLayer, src: SlamMap, dst: SlamMap, T: np.ndarray) -> int:
    """What `merge_maps` does to the points and keyframes, then the layer's part; returns the point id offset."""
    offset = append_points(dst.points, src.points, T)
    for kf in src.keyframes.values():
        kf.T_world_cam = T @ kf.T_world_cam
        kf.point_ids[kf.point_ids >= 0] += offset
        dst.keyframes[kf.id] = kf
    layer.maps_merged(src.id, dst.id, T, offset, dst.points)
    return offset


def test_the_objects_of_a_merged_away_map_move_into_the_target_map() -> None:
    layer = ObjectLayer()
    m0, kf0 = _map(0, 0)
    m1, kf1 = _map(1, 5)
    layer.after_keyframe(kf0, m0, _depth(), [_state(CHAIR)])
    layer.after_keyframe(kf1, m1, _depth(), [_state(CUP)])
    (chair,), (cup,) = layer.objects(0), layer.objects(1)
    cup_centroid, cup_samples = cup.centroid_w.copy(), cup.point_ids[cup.point_ids < -1]
    T = make_pose(np.eye(3), np.array([1.0, 0.0, 0.0]))
    offset = _merge(layer, m1, m0, T)
    assert layer.objects(1) == [] and layer.map_ids == [0]
    moved = next(o for o in layer.objects(0) if o.class_id == CUP)
    assert moved.id != chair.id
    np.testing.assert_allclose(moved.centroid_w, cup_centroid + [1.0, 0.0, 0.0], atol=1e-9)
    assert (moved.point_ids[moved.point_ids >= 0] >= offset).all()
    # depth samples renumbered below the target's own: no id is shared with the chair's
    assert len(moved.point_ids[moved.point_ids < -1]) == len(cup_samples)
    assert not np.isin(moved.point_ids, chair.point_ids).any()
    assert (m0.points.object_id[offset:offset + 12] == moved.id).all()
    # the next keyframe re-reads every point from the map and the anchors: the moved cup stays where it was put
    kf2 = _map(0, 6)[1]
    m0.add_keyframe(kf2)
    layer.after_keyframe(kf2, m0, None, [])
    np.testing.assert_allclose(moved.centroid_w, cup_centroid + [1.0, 0.0, 0.0], atol=1e-6)


def test_an_object_mapped_in_both_maps_is_joined() -> None:
    layer = ObjectLayer()
    m0, kf0 = _map(0, 0)
    m1, kf1 = _map(1, 5)
    layer.after_keyframe(kf0, m0, _depth(), [_state(CHAIR)])
    layer.after_keyframe(kf1, m1, _depth(), [_state(CHAIR)])
    (chair,) = layer.objects(0)
    n_before = chair.n_points
    offset = _merge(layer, m1, m0, make_pose(np.eye(3), np.array([0.05, 0.0, 0.0])))
    assert [o.id for o in layer.objects(0)] == [chair.id]
    assert chair.n_points > n_before and chair.n_observations == 2
    assert (m0.points.object_id[offset:offset + 12] == chair.id).all()
