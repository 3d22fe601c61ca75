"""The YOLO path of the detector: a tiny ONNX model built here with onnx.helper, and the post-processing."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from changing_slam_ros.core.dynamic.detector import Detector, DetectorConfig, Letterbox, letterbox, postprocess_yolo

onnx = pytest.importorskip("onnx")
from onnx import TensorProto, helper, numpy_helper  # noqa: E402


def _yolo_candidates(rows: list[tuple[float, float, float, float, int, float]], n: int = 8) -> np.ndarray:
    """(1, 84, n) output: rows of (cx, cy, w, h, class, score) in network input pixels, the rest empty."""
    out = np.zeros((1, 84, n), np.float32)
    for j, (cx, cy, w, h, c, s) in enumerate(rows):
        out[0, :4, j] = (cx, cy, w, h)
        out[0, 4 + c, j] = s
    return out


def _tiny_yolo_model(path: Path, constant_output: np.ndarray, size_px: int, transpose: bool = False) -> Path:
    """An ONNX graph with the YOLOv8 interface: images (1, 3, S, S) float32 -> output0 = constant + 0 * mean(images)."""
    const = constant_output.transpose(0, 2, 1).copy() if transpose else constant_output
    nodes = [
        helper.make_node("ReduceMean", ["images"], ["m"], keepdims=0),
        helper.make_node("Mul", ["m", "zero"], ["mz"]),
        helper.make_node("Add", ["cand", "mz"], ["output0"]),
    ]
    graph = helper.make_graph(
        nodes,
        "tiny_yolo",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, size_px, size_px])],
        [helper.make_tensor_value_info("output0", TensorProto.FLOAT, list(const.shape))],
        initializer=[numpy_helper.from_array(const, "cand"), numpy_helper.from_array(np.zeros((), np.float32), "zero")],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    model.ir_version = 9
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def test_letterbox_scales_and_pads_a_landscape_image_into_a_square() -> None:
    rgb = np.zeros((96, 128, 3), np.uint8)
    tensor, lb = letterbox(rgb, 64)
    assert tensor.shape == (1, 3, 64, 64) and tensor.dtype == np.float32
    assert (lb.scale, lb.pad_x, lb.pad_y) == (0.5, 0.0, 8.0)
    assert tensor[0, 0, 0, 0] == pytest.approx(114 / 255) and tensor[0, 0, 32, 32] == 0.0


def test_yolo_postprocessing_undoes_the_letterbox_and_applies_per_class_nms() -> None:
    lb = Letterbox(scale=0.5, pad_x=0.0, pad_y=8.0, size_px=64)
    out = _yolo_candidates([
        (32, 32, 20, 16, 0, 0.9),   # person at image (44..84, 32..64)
        (33, 32, 20, 16, 0, 0.6),   # duplicate of it: suppressed
        (33, 32, 20, 16, 56, 0.7),  # a chair on the same spot: other class, kept
        (10, 20, 4, 4, 62, 0.2),    # below threshold
    ])  # fmt: skip
    boxes, scores, classes = postprocess_yolo(out, lb, 128, 96, score_threshold=0.3, nms_iou_threshold=0.45)
    assert classes.tolist() == [0, 56]
    np.testing.assert_allclose(scores, [0.9, 0.7], atol=1e-6)
    np.testing.assert_allclose(boxes[0], [44.0, 32.0, 84.0, 64.0])
    # The transposed layout (1, N, 84) gives the same result.
    boxes_t, _, classes_t = postprocess_yolo(out.transpose(0, 2, 1), lb, 128, 96, 0.3, 0.45)
    np.testing.assert_allclose(boxes_t, boxes)
    assert classes_t.tolist() == [0, 56]


@pytest.mark.parametrize("transpose", [False, True])
def test_a_yolo_onnx_model_is_detected_by_layout_and_run_end_to_end(tmp_path: Path, transpose: bool) -> None:
    cand = _yolo_candidates([(32, 32, 20, 16, 0, 0.9), (48, 40, 8, 8, 77, 0.5), (33, 32, 20, 16, 0, 0.8)])
    path = _tiny_yolo_model(tmp_path / "tiny_yolo.onnx", cand, 64, transpose)
    det = Detector(DetectorConfig(model_path=str(path), intra_op_threads=1))
    assert det.layout == "yolo" and det.yolo_input_size_px == 64
    res = det.detect(np.full((96, 128, 3), 40, np.uint8), stamp_ns=7)
    assert res.stamp_ns == 7 and [d.class_id for d in res.detections] == [0, 77]
    np.testing.assert_allclose(res.detections[0].box_xyxy, [44.0, 32.0, 84.0, 64.0], atol=1e-4)
    np.testing.assert_allclose(res.detections[1].box_xyxy, [88.0, 56.0, 104.0, 72.0], atol=1e-4)
    assert res.detections[1].score == pytest.approx(0.5)


def test_gpu_providers_are_used_only_when_onnxruntime_has_them(tmp_path: Path) -> None:
    import onnxruntime as ort

    path = _tiny_yolo_model(tmp_path / "tiny_yolo.onnx", _yolo_candidates([]), 64)
    det = Detector(DetectorConfig(model_path=str(path), intra_op_threads=1))
    available = set(ort.get_available_providers())
    expected = [p for p in ("TensorrtExecutionProvider", "CUDAExecutionProvider") if p in available]
    assert det.providers[: len(expected)] == tuple(expected)
    assert det.providers[-1] == "CPUExecutionProvider"
    cpu_only = Detector(DetectorConfig(model_path=str(path), providers=("CPUExecutionProvider",)))
    assert cpu_only.providers == ("CPUExecutionProvider",)
    assert len(cpu_only.detect(np.zeros((48, 64, 3), np.uint8))) == 0


def test_yolov5_rows_with_objectness_multiply_it_into_the_class_scores() -> None:
    lb = Letterbox(scale=1.0, pad_x=0.0, pad_y=0.0, size_px=64)
    rows = np.zeros((1, 3, 85), np.float32)
    rows[0, 0, :5] = (20, 20, 10, 10, 0.9)
    rows[0, 0, 5 + 56] = 0.8  # chair, 0.72 after objectness
    rows[0, 1, :5] = (40, 40, 10, 10, 0.3)
    rows[0, 1, 5 + 0] = 0.9  # person, 0.27 after objectness: below 0.3
    boxes, scores, classes = postprocess_yolo(rows, lb, 64, 64, score_threshold=0.3, nms_iou_threshold=0.45)
    assert classes.tolist() == [56]
    np.testing.assert_allclose(scores, [0.72], atol=1e-6)
    np.testing.assert_allclose(boxes[0], [15.0, 15.0, 25.0, 25.0])
