"""The object layer asks for a keyframe when a frame shows a whole detection of an object it does not know yet."""

from __future__ import annotations

import dataclasses

import numpy as np

from changing_slam_ros.core.dynamic.dynamic_objects import ObjectMotion, ObjectState
from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.map.slam_map import SlamMap
from changing_slam_ros.core.objects.object_layer import ObjectLayer, ObjectLayerConfig

CAM = CameraIntrinsics(320, 240, 262.5, 262.5, 159.5, 119.5)
CHAIR, CUP = 56, 41
CHAIR_BOX = (100.0, 60.0, 180.0, 180.0)
ON = dataclasses.replace(ObjectLayerConfig(), new_object_keyframes=True)


def _state(class_id: int, box: tuple[float, float, float, float], sid: int = 7,
           motion: ObjectMotion = ObjectMotion.STATIC) -> ObjectState:
    nan3 = np.full(3, np.nan)
    return ObjectState(sid, class_id, box, nan3, nan3, 0.0, motion, 3, False)


def _layer_with_chair() -> ObjectLayer:
    """A layer whose map holds a chair 2 m in front of the origin (from one keyframe's depth samples)."""
    depth = np.full((240, 320), 4.0, np.float32)
    depth[60:180, 100:180] = 2.0
    kf = Keyframe(0, 0, np.eye(4), CAM, np.zeros((0, 2), np.float32), np.zeros(0, np.int8),
                  np.zeros((0, 32), np.uint8), np.zeros(0, np.float32), np.zeros(0, np.int64))
    m = SlamMap(0)
    m.add_keyframe(kf)
    layer = ObjectLayer(ON)
    layer.after_keyframe(kf, m, depth, [_state(CHAIR, CHAIR_BOX)])
    assert len(layer.objects(0)) == 1
    return layer


def test_a_detection_nothing_explains_asks_for_a_keyframe_once_known_it_does_not() -> None:
    layer = _layer_with_chair()
    pose = np.eye(4)
    assert not layer.wants_keyframe(0, [_state(CHAIR, CHAIR_BOX)], pose, CAM)  # the mapped chair
    shifted = pose.copy()
    shifted[0, 3] = 0.2  # 20 cm to the right: the chair's box moves 26 px left, its centroid still inside
    assert not layer.wants_keyframe(0, [_state(CHAIR, (74.0, 60.0, 154.0, 180.0))], shifted, CAM)
    cup = _state(CUP, (200.0, 100.0, 240.0, 140.0), 8)
    assert layer.wants_keyframe(0, [_state(CHAIR, CHAIR_BOX), cup], pose, CAM)  # a cup the map has not seen
    assert layer.wants_keyframe(0, [_state(CHAIR, (200.0, 60.0, 280.0, 180.0))], pose, CAM)  # a second chair


def test_cut_small_and_dynamic_detections_ask_for_nothing() -> None:
    layer = _layer_with_chair()
    pose = np.eye(4)
    assert not layer.wants_keyframe(0, [_state(CUP, (0.0, 100.0, 40.0, 140.0))], pose, CAM)  # cut by the border
    assert not layer.wants_keyframe(0, [_state(CUP, (200.0, 100.0, 205.0, 105.0))], pose, CAM)  # 25 px < 40
    moving = _state(CUP, (200.0, 100.0, 240.0, 140.0), motion=ObjectMotion.DYNAMIC)
    assert not layer.wants_keyframe(0, [moving], pose, CAM)
    assert not ObjectLayer().wants_keyframe(0, [_state(CUP, (200.0, 100.0, 240.0, 140.0))], pose, CAM)  # off: default
    assert ObjectLayer(ON).wants_keyframe(0, [_state(CUP, (200.0, 100.0, 240.0, 140.0))], pose, CAM)  # empty map
