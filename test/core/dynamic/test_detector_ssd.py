"""The shipped SSD-MobileNetV2 detector on a real TUM fr3_walking_xyz frame, and the COCO id mapping."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest
from helpers import FR3_WALKING_FRAMES, require

from changing_slam_ros.core.dynamic.detector import (
    CHAIR_CLASS_ID,
    COCO80_NAMES,
    DEFAULT_MODEL_PATH,
    PERSON_CLASS_ID,
    TV_CLASS_ID,
    Detector,
    DetectorConfig,
    coco91_to_80,
    nms,
    postprocess_ssd_tf,
)
from changing_slam_ros.errors import ConfigError


@pytest.fixture(scope="module")
def walking_rgb() -> np.ndarray:
    path = require(FR3_WALKING_FRAMES / "1341846313.553992.png")
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    return np.ascontiguousarray(bgr[:, :, ::-1])


@pytest.fixture(scope="module")
def detector() -> Detector:
    if not DEFAULT_MODEL_PATH.is_file():
        pytest.skip("shipped model missing")
    return Detector(DetectorConfig(intra_op_threads=2))


def test_coco_ids_map_to_the_papers_80_class_ids() -> None:
    got = coco91_to_80([1, 62, 72, 88, 28, 33, 47, 84, 44, 27, 78, 90, 12, 0, 91])
    assert got.tolist() == [0, 56, 62, 77, 25, 28, 41, 73, 39, 24, 68, 79, -1, -1, -1]
    assert COCO80_NAMES[56] == "chair" and COCO80_NAMES[62] == "tv" and len(COCO80_NAMES) == 80


def test_ssd_postprocessing_converts_normalised_yxyx_to_pixels_and_drops_low_scores() -> None:
    boxes = np.array([[0.5, 0.25, 1.0, 0.75], [0.0, 0.0, 0.1, 0.1], [0.1, 0.1, 0.2, 0.2]], np.float32)
    scores = np.array([0.9, 0.2, 0.8], np.float32)
    classes = np.array([62.0, 1.0, 12.0], np.float32)  # chair, person (low score), unknown id 12
    xyxy, s, c = postprocess_ssd_tf(boxes, scores, classes, np.array([3.0]), 640, 480, 0.3)
    assert c.tolist() == [CHAIR_CLASS_ID]
    np.testing.assert_allclose(xyxy[0], [160.0, 240.0, 480.0, 480.0])
    np.testing.assert_allclose(s, [0.9], atol=1e-6)


@pytest.mark.slow  # creating the onnxruntime session takes 10 s on an idle 2-core machine, 45 s when busy
def test_detector_finds_two_persons_and_chairs_in_a_real_walking_frame(detector: Detector, walking_rgb: np.ndarray) -> None:
    dets = detector.detect(walking_rgb, stamp_ns=1341846313553992000)
    assert detector.layout == "ssd_tf"
    assert "CPUExecutionProvider" in detector.providers
    assert dets.stamp_ns == 1341846313553992000 and (dets.width, dets.height) == (640, 480)
    persons = sorted((d.score for d in dets.detections if d.class_id == PERSON_CLASS_ID), reverse=True)
    chairs = sorted((d.score for d in dets.detections if d.class_id == CHAIR_CLASS_ID), reverse=True)
    tvs = sorted((d.score for d in dets.detections if d.class_id == TV_CLASS_ID), reverse=True)
    # Reference scores from the models README: person 0.95 / 0.84, chair 0.97 / 0.83 / 0.78, tv 0.83 / 0.37.
    np.testing.assert_allclose(persons, [0.95, 0.84], atol=0.02)
    np.testing.assert_allclose(chairs, [0.97, 0.83, 0.78], atol=0.02)
    np.testing.assert_allclose(tvs, [0.83, 0.37], atol=0.02)
    # The two persons: one on the left half, one filling the right side of the image.
    boxes = sorted((d.box_xyxy for d in dets.detections if d.class_id == PERSON_CLASS_ID), key=lambda b: b[0])
    np.testing.assert_allclose(boxes[0], [50.9, 130.8, 246.5, 461.9], atol=3.0)
    np.testing.assert_allclose(boxes[1], [468.4, 0.5, 635.9, 478.2], atol=3.0)


@pytest.mark.slow
def test_a_higher_score_threshold_keeps_only_the_confident_detections(detector: Detector, walking_rgb: np.ndarray) -> None:
    default = detector.config
    try:
        detector.set_postprocessing(replace(default, score_threshold=0.8, max_detections=4))
        strict = detector.detect(walking_rgb)
    finally:
        detector.set_postprocessing(default)
    # 0.97 chair, 0.95 person, 0.84 person, 0.83 tv (the 0.83 chair is the fifth).
    assert sorted(d.class_id for d in strict.detections) == [0, 0, 56, 62]
    assert min(d.score for d in strict.detections) >= 0.8
    with pytest.raises(ConfigError, match="need a new Detector"):
        detector.set_postprocessing(replace(default, intra_op_threads=1))


def test_class_agnostic_suppression_merges_overlapping_boxes_of_different_classes() -> None:
    boxes = np.array([[0, 0, 100, 100], [5, 5, 100, 100], [200, 200, 300, 300]], float)
    scores = np.array([0.6, 0.9, 0.5])
    classes = np.array([2, 7, 2])  # car and truck on one object, a second car elsewhere
    assert nms(boxes, scores, 0.7, classes).tolist() == [1, 0, 2]
    assert nms(boxes, scores, 0.7).tolist() == [1, 2]


def test_missing_model_path_names_the_file(tmp_path) -> None:
    with pytest.raises(ConfigError, match="nope.onnx: no such ONNX model file"):
        Detector(DetectorConfig(model_path=str(tmp_path / "nope.onnx")))


def test_unknown_layout_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match="detector.layout"):
        DetectorConfig(layout="detr")
