"""The detector's session options: the SSD graph cut before its NMS (numpy NMS), the prepared-graph cache."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from helpers import FR3_WALKING_FRAMES, require

from changing_slam_ros.core.dynamic.detector import (
    CHAIR_CLASS_ID,
    DEFAULT_MODEL_PATH,
    PERSON_CLASS_ID,
    Detector,
    DetectorConfig,
    postprocess_ssd_head,
)
from changing_slam_ros.core.dynamic.detector_session import SSD_HEAD_OUTPUTS
from changing_slam_ros.errors import ConfigError


def _scores(n_anchors: int, entries: dict[tuple[int, int], float]) -> np.ndarray:
    """(A, 91) sigmoid scores, background column 0, original COCO ids as columns."""
    s = np.full((n_anchors, 91), 0.01, np.float32)
    for (a, coco91), v in entries.items():
        s[a, coco91] = v
    return s


def test_ssd_head_postprocessing_suppresses_per_class_and_keeps_other_classes() -> None:
    boxes = np.array([
        [0.10, 0.10, 0.50, 0.30],   # person
        [0.11, 0.10, 0.51, 0.30],   # the same person again, lower score: suppressed (IoU ~0.95)
        [0.10, 0.10, 0.50, 0.30],   # a chair on the same spot: another class, kept
        [0.60, 0.60, 0.90, 0.90],   # person scoring exactly 0.3: the graph's filter is strict, dropped
        [1.20, 0.20, 1.50, 0.40],   # below the image after clipping: empty, dropped
        [0.20, 0.70, 0.40, 0.90],   # COCO id 12 (no 80-class id): dropped
    ], np.float32)  # fmt: skip
    scores = _scores(6, {(0, 1): 0.9, (1, 1): 0.8, (2, 62): 0.7, (3, 1): 0.3, (4, 1): 0.95, (5, 12): 0.99})
    xyxy, s, c = postprocess_ssd_head(boxes, scores, 640, 480, 0.3, 0.6, 100)
    assert c.tolist() == [PERSON_CLASS_ID, CHAIR_CLASS_ID]
    np.testing.assert_allclose(s, [0.9, 0.7], atol=1e-6)
    np.testing.assert_allclose(xyxy[0], [64.0, 48.0, 192.0, 240.0], atol=1e-3)
    # A looser IoU threshold keeps the duplicate; the cap keeps the best ones only, counting the id-12 box
    # (0.99) before it is dropped, as the graph does.
    _, s2, _ = postprocess_ssd_head(boxes, scores, 640, 480, 0.3, 0.97, 100)
    np.testing.assert_allclose(s2, [0.9, 0.8, 0.7], atol=1e-6)
    _, s3, _ = postprocess_ssd_head(boxes, scores, 640, 480, 0.3, 0.97, 3)
    np.testing.assert_allclose(s3, [0.9, 0.8], atol=1e-6)


def test_ssd_head_postprocessing_of_an_empty_frame_returns_empty_arrays() -> None:
    xyxy, s, c = postprocess_ssd_head(np.zeros((4, 4), np.float32), _scores(4, {}), 640, 480, 0.3, 0.6, 100)
    assert xyxy.shape == (0, 4) and s.shape == (0,) and c.shape == (0,)


def test_bad_session_options_are_config_errors() -> None:
    with pytest.raises(ConfigError, match="detector.nms"):
        DetectorConfig(nms="tensorrt")
    with pytest.raises(ConfigError, match="detector.graph_optimization"):
        DetectorConfig(graph_optimization="max")
    with pytest.raises(ConfigError, match="detector.ssd_nms_iou_threshold"):
        DetectorConfig(ssd_nms_iou_threshold=1.5)


def _yolo_like_model(path):  # noqa: ANN001, ANN202
    """A one-node ONNX graph with a YOLO-shaped output (1, 84, 8) and no SSD tensors."""
    onnx = pytest.importorskip("onnx")
    from onnx import TensorProto, helper

    graph = helper.make_graph(
        [helper.make_node("Identity", ["images"], ["output0"])], "yolo_like",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 84, 8])],
        [helper.make_tensor_value_info("output0", TensorProto.FLOAT, [1, 84, 8])],
    )  # fmt: skip
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    model.ir_version = 9
    onnx.save(model, str(path))
    return path


def test_numpy_nms_needs_an_ssd_graph_and_auto_falls_back_to_the_graph(tmp_path) -> None:
    path = _yolo_like_model(tmp_path / "yolo_like.onnx")
    with pytest.raises(ConfigError, match="yolo_like.onnx has none"):
        Detector(DetectorConfig(model_path=str(path), nms="numpy", cache_dir=str(tmp_path / "cache")))
    det = Detector(DetectorConfig(model_path=str(path), nms="auto", cache_dir=str(tmp_path / "cache")))
    assert det.layout == "yolo" and det.ssd_nms_in_graph


@pytest.mark.slow  # the graph-NMS session takes 20-45 s to create on the shared 2-core machine
def _assert_same_detections(got, want) -> None:  # noqa: ANN001
    """Same classes in the same order, scores within 1e-6, boxes within 1e-3 px."""
    assert [d.class_id for d in got] == [d.class_id for d in want]
    np.testing.assert_allclose([d.score for d in got], [d.score for d in want], atol=1e-6)
    np.testing.assert_allclose([d.box_xyxy for d in got], [d.box_xyxy for d in want], atol=1e-3)


def test_numpy_nms_gives_the_graphs_detections_and_a_second_start_loads_the_cached_graph(tmp_path) -> None:
    if not DEFAULT_MODEL_PATH.is_file():
        pytest.skip("shipped model missing")
    frames = [require(FR3_WALKING_FRAMES / "1341846313.553992.png"), require(FR3_WALKING_FRAMES / "walking_frame_b.png")]
    graph = Detector(DetectorConfig(nms="graph", model_cache=False))
    first = Detector(DetectorConfig(cache_dir=str(tmp_path)))
    second = Detector(DetectorConfig(cache_dir=str(tmp_path)))
    assert graph.ssd_nms_in_graph and graph.cache_path is None
    assert not first.ssd_nms_in_graph and not first.cache_hit and second.cache_hit
    assert first.cache_path == second.cache_path and first.cache_path is not None
    assert first.cache_path.name.startswith("7b86a6018a079704-ort") and first.cache_path.parent == tmp_path
    assert [o.name for o in second._session.get_outputs()] == list(SSD_HEAD_OUTPUTS)
    assert [p.name for p in tmp_path.iterdir()] == [first.cache_path.name]  # no temporary file left behind
    for path in frames:
        rgb = np.ascontiguousarray(cv2.imread(str(path), cv2.IMREAD_COLOR)[:, :, ::-1])
        want = graph.detect(rgb).detections
        for det in (first, second):
            _assert_same_detections(det.detect(rgb).detections, want)
        assert len(want) >= 4  # two persons and chairs on the first frame, a person and a chair on the second


def test_an_unreadable_cached_graph_is_prepared_again(tmp_path) -> None:
    path = _yolo_like_model(tmp_path / "yolo_like.onnx")
    cache = tmp_path / "cache"
    first = Detector(DetectorConfig(model_path=str(path), cache_dir=str(cache)))
    assert first.cache_path is not None and not first.cache_hit
    first.cache_path.write_bytes(b"not an onnx graph")
    again = Detector(DetectorConfig(model_path=str(path), cache_dir=str(cache)))
    assert not again.cache_hit and again.layout == "yolo"
    assert again.cache_path is not None and again.cache_path.read_bytes() != b"not an onnx graph"


def test_ssd_head_postprocessing_reads_a_slimmed_graphs_columns_as_their_coco_ids() -> None:
    boxes = np.array([[0.10, 0.10, 0.50, 0.30], [0.60, 0.60, 0.90, 0.90], [0.11, 0.10, 0.51, 0.30]], np.float32)
    # Two columns, no background: COCO id 62 (chair) then 1 (person).
    scores = np.array([[0.8, 0.1], [0.2, 0.7], [0.75, 0.2]], np.float32)
    xyxy, s, c = postprocess_ssd_head(boxes, scores, 640, 480, 0.3, 0.6, 100, column_ids=(62, 1))
    assert c.tolist() == [CHAIR_CLASS_ID, PERSON_CLASS_ID]  # the second chair box is suppressed
    np.testing.assert_allclose(s, [0.8, 0.7], atol=1e-6)
    np.testing.assert_allclose(xyxy[1], [384.0, 288.0, 576.0, 432.0], atol=1e-3)


def test_the_slimmed_graph_gives_the_unslimmed_heads_detections_on_real_frames(tmp_path) -> None:
    """The slimmed SSD head (no preprocessing loop, 80 score channels) against the head as cut: the same
    detections, scores and boxes (the kept channels' arithmetic is untouched)."""
    onnx = pytest.importorskip("onnx")
    if not DEFAULT_MODEL_PATH.is_file():
        pytest.skip("shipped model missing")
    frames = [require(FR3_WALKING_FRAMES / "1341846313.553992.png"), require(FR3_WALKING_FRAMES / "walking_frame_b.png")]
    slim = Detector(DetectorConfig(cache_dir=str(tmp_path)))
    head = Detector(DetectorConfig(cache_dir=str(tmp_path), slim_graph=False))
    again = Detector(DetectorConfig(cache_dir=str(tmp_path)))
    assert slim.cache_path is not None and head.cache_path is not None and slim.cache_path != head.cache_path
    assert "-slim80." in slim.cache_path.name and again.cache_hit and again.score_columns == slim.score_columns
    assert slim.score_columns is not None and len(slim.score_columns) == 80 and head.score_columns is None
    model = onnx.load(str(slim.cache_path))
    assert not [n for n in model.graph.node if n.op_type == "Loop"]  # the preprocessing loop is gone
    assert model.graph.input[0].type.tensor_type.shape.dim[0].dim_value == 1
    assert [o.shape[-1] for o in slim._session.get_outputs()] == [4, 80]
    found = 0
    for path in frames:
        rgb = np.ascontiguousarray(cv2.imread(str(path), cv2.IMREAD_COLOR)[:, :, ::-1])
        want = head.detect(rgb).detections
        for det in (slim, again):
            _assert_same_detections(det.detect(rgb).detections, want)
        found += len(want)
    assert found >= 6  # persons, chairs, a tv and keyboards on the first frame, a person and a chair on the second


def test_slimming_leaves_a_graph_without_the_tf_od_preprocessing_loop_alone() -> None:
    from changing_slam_ros.core.dynamic.detector_session import slim_ssd_head

    onnx = pytest.importorskip("onnx")
    from onnx import TensorProto, helper

    graph = helper.make_graph(
        [helper.make_node("Identity", ["x"], ["y"])], "plain",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 4])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 4])],
    )  # fmt: skip
    assert slim_ssd_head(helper.make_model(graph).SerializeToString(), (1, 2)) is None
    assert onnx is not None


def test_negative_spin_duration_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match="detector.spin_duration_us"):
        DetectorConfig(spin_duration_us=-1)
