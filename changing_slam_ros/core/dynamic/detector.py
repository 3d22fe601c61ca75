"""Object detector (Changing-SLAM's detection thread): an ONNX model run with onnxruntime.

Two model layouts, told apart from the model's outputs (`DetectorConfig.layout = "auto"`):
- `ssd_tf`: TensorFlow Object Detection API exports such as the shipped `models/ssd_mobilenet_v2_coco.onnx`:
  uint8 (1, H, W, 3) RGB in; `detection_boxes` (1, K, 4) normalised (ymin, xmin, ymax, xmax),
  `detection_scores`, `detection_classes` (original COCO ids 1..90), `num_detections` out; NMS in the graph.
- `yolo`: YOLO (v8 and later) exports, one output (1, 4 + C, N) or its transpose, boxes (cx, cy, w, h) in
  input pixels and C class scores; YOLOv5-style (1, N, 5 + C) with objectness when 5 + C = 85. Float32
  (1, 3, S, S) RGB in [0, 1] after letterboxing; NMS here.
Class ids are the 80-class 0-based COCO ids the paper uses (person 0, chair 56, tv 62, teddy bear 77); -1 means
background (keypoints, never emitted detections).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.dynamic.detector_session import (
    GRAPH_OPTIMIZATIONS,
    NMS_MODES,
    SessionSettings,
    default_cache_dir,
    prepare_session,
)
from changing_slam_ros.errors import ConfigError

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]

MODELS_DIR = Path(__file__).resolve().parents[2] / "models"
DEFAULT_MODEL_PATH = MODELS_DIR / "ssd_mobilenet_v2_coco.onnx"
# Detectors shipped in `models/` (see models/PROVENANCE.md), by the name `DetectorConfig.model` takes. The INT8
# one is the fp32 graph cut before its NMS, slimmed and statically quantised (tools/quantize_detector.py): about
# 0.4x the CPU per detection, for the real-time graph; offline accuracy is measured with the fp32 default.
SHIPPED_MODELS: dict[str, Path] = {
    "ssd_mobilenet_v2_coco": DEFAULT_MODEL_PATH,
    "ssd_mobilenet_v2_coco_int8": MODELS_DIR / "ssd_mobilenet_v2_coco_int8.onnx",
}

BACKGROUND_CLASS_ID = -1
PERSON_CLASS_ID = 0
CHAIR_CLASS_ID = 56
TV_CLASS_ID = 62

# Original COCO category ids (1..90 with gaps) of the 80 classes, in the order of the 0-based ids.
COCO91_IDS: tuple[int, ...] = (
    1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 13, 14, 15, 16, 17, 18, 19, 20, 21,
    22, 23, 24, 25, 27, 28, 31, 32, 33, 34, 35, 36, 37, 38, 39, 40, 41, 42, 43, 44,
    46, 47, 48, 49, 50, 51, 52, 53, 54, 55, 56, 57, 58, 59, 60, 61, 62, 63, 64, 65,
    67, 70, 72, 73, 74, 75, 76, 77, 78, 79, 80, 81, 82, 84, 85, 86, 87, 88, 89, 90,
)  # fmt: skip

COCO80_NAMES: tuple[str, ...] = (
    "person", "bicycle", "car", "motorcycle", "airplane", "bus", "train", "truck", "boat",
    "traffic light", "fire hydrant", "stop sign", "parking meter", "bench", "bird", "cat", "dog",
    "horse", "sheep", "cow", "elephant", "bear", "zebra", "giraffe", "backpack", "umbrella",
    "handbag", "tie", "suitcase", "frisbee", "skis", "snowboard", "sports ball", "kite",
    "baseball bat", "baseball glove", "skateboard", "surfboard", "tennis racket", "bottle",
    "wine glass", "cup", "fork", "knife", "spoon", "bowl", "banana", "apple", "sandwich", "orange",
    "broccoli", "carrot", "hot dog", "pizza", "donut", "cake", "chair", "couch", "potted plant",
    "bed", "dining table", "toilet", "tv", "laptop", "mouse", "remote", "keyboard", "cell phone",
    "microwave", "oven", "toaster", "sink", "refrigerator", "book", "clock", "vase", "scissors",
    "teddy bear", "hair drier", "toothbrush",
)  # fmt: skip

# Lookup table: original COCO id (index) -> 0-based id, -1 for ids that are not one of the 80 classes.
_COCO91_TO_80 = np.full(92, BACKGROUND_CLASS_ID, dtype=np.int64)
_COCO91_TO_80[list(COCO91_IDS)] = np.arange(len(COCO91_IDS))

LAYOUTS = ("auto", "ssd_tf", "yolo")


def coco91_to_80(ids: npt.ArrayLike) -> npt.NDArray[np.int64]:
    """Map original COCO ids (any shape, ints or floats) to 0-based 80-class ids; unknown -> -1."""
    a = np.rint(np.asarray(ids, dtype=np.float64)).astype(np.int64)
    out = np.full(a.shape, BACKGROUND_CLASS_ID, dtype=np.int64)
    ok = (a >= 0) & (a < len(_COCO91_TO_80))
    out[ok] = _COCO91_TO_80[a[ok]]
    return out


def class_name(class_id: int) -> str:
    """Human-readable name of a 0-based COCO id ('background' for -1)."""
    if 0 <= class_id < len(COCO80_NAMES):
        return COCO80_NAMES[class_id]
    return "background" if class_id == BACKGROUND_CLASS_ID else f"class{class_id}"


def box_area_px(box_xyxy: tuple[float, float, float, float]) -> float:
    """Area in pixels of an (x_min, y_min, x_max, y_max) box, 0 for an empty one."""
    x0, y0, x1, y1 = box_xyxy
    return max(0.0, x1 - x0) * max(0.0, y1 - y0)


@dataclass(frozen=True)
class Detection:
    """One detected object: `box_xyxy` (x_min, y_min, x_max, y_max) in pixels of the input image,
    `class_id` 0-based COCO (-1 background), `score` in [0, 1]."""

    box_xyxy: tuple[float, float, float, float]
    class_id: int
    score: float

    @property
    def centre_px(self) -> tuple[float, float]:
        x0, y0, x1, y1 = self.box_xyxy
        return (0.5 * (x0 + x1), 0.5 * (y0 + y1))

    @property
    def area_px(self) -> float:
        return box_area_px(self.box_xyxy)


@dataclass(frozen=True)
class DetectionSet:
    """All detections of one image, stamped with the image's `stamp_ns` (mirrors the detections message)."""

    stamp_ns: int
    detections: tuple[Detection, ...] = ()
    width: int = 0
    height: int = 0

    def __len__(self) -> int:
        return len(self.detections)

    def boxes_xyxy(self) -> F64:
        """Boxes (M, 4) float64 pixels."""
        if not self.detections:
            return np.zeros((0, 4))
        return np.array([d.box_xyxy for d in self.detections], dtype=np.float64)

    def class_ids(self) -> npt.NDArray[np.int64]:
        """Class ids (M,)."""
        return np.array([d.class_id for d in self.detections], dtype=np.int64)

    def scores(self) -> F64:
        """Scores (M,)."""
        return np.array([d.score for d in self.detections], dtype=np.float64)


@dataclass(frozen=True)
class DetectorConfig:
    """`detector` config section.

    - `model`: which shipped detector runs when `model_path` is empty, one of `SHIPPED_MODELS`:
      "ssd_mobilenet_v2_coco" (fp32, the default) or "ssd_mobilenet_v2_coco_int8" (static INT8, cheaper).
    - `model_path`: ONNX file; empty = the shipped model named by `model`.
    - `layout`: "auto" (from the model's outputs), "ssd_tf" or "yolo".
    - `score_threshold`: detections scoring lower are dropped (the SSD graph never emits < 0.3).
    - `nms_iou_threshold`: per-class NMS IoU for layouts without NMS in the graph (YOLO).
    - `class_agnostic_nms` / `class_agnostic_iou_threshold`: also suppress overlapping boxes of
      different classes (the SSD can call one object both car and truck).
    - `yolo_input_size_px`: letterbox side when the model's input size is not fixed in the graph.
    - `max_detections`: most detections kept per image, best first.
    - `intra_op_threads`: onnxruntime intra-op thread count (0 = onnxruntime's default).
    - `providers`: execution providers in order of preference; those not present are skipped, so the
      default uses TensorRT or CUDA when onnxruntime has them and the CPU otherwise.
    - `nms`: where a TF-OD SSD's per-class suppression runs: "graph" (the exported graph, as is), "numpy"
      (the graph is cut before it, `postprocess_ssd_head`; same detections, a quarter less time), "auto"
      (numpy when the graph can be cut, e.g. the shipped model; graph otherwise, e.g. YOLO).
    - `ssd_nms_iou_threshold`: the SSD's per-class NMS IoU with `nms` numpy (0.6, the model's training config).
    - `graph_optimization`: onnxruntime level, "disable", "basic", "extended" or "all".
    - `allow_spinning`: let onnxruntime's threads busy-wait between operators (faster alone, slower when the
      cores are shared with tracking).
    - `spin_duration_us`: with `allow_spinning`, how long an idle onnxruntime thread spins before it sleeps
      (0 = onnxruntime's default).
    - `slim_graph`: with the SSD graph cut before its NMS, also replace its preprocessing loop by one resize and
      compute only the 80 classes' score channels (`detector_session.slim_ssd_head`): same detections, about
      10 % less CPU.
    - `quantize_int8`: dynamic INT8 quantisation of the graph, made at first use into the cache (opt-in).
    - `model_cache` / `cache_dir`: keep prepared graphs (cut, quantised, optimised) in `cache_dir`
      (empty = `$XDG_CACHE_HOME/changing_slam_ros/onnx`), so later start-ups only load them.
    """

    model: str = "ssd_mobilenet_v2_coco"
    model_path: str = ""
    layout: str = "auto"
    score_threshold: float = 0.3
    nms_iou_threshold: float = 0.45
    class_agnostic_nms: bool = False
    class_agnostic_iou_threshold: float = 0.7
    yolo_input_size_px: int = 640
    max_detections: int = 100
    intra_op_threads: int = 2
    providers: tuple[str, ...] = field(
        default=("TensorrtExecutionProvider", "CUDAExecutionProvider", "CPUExecutionProvider")
    )
    nms: str = "auto"
    ssd_nms_iou_threshold: float = 0.6
    graph_optimization: str = "all"
    allow_spinning: bool = False
    spin_duration_us: int = 0
    slim_graph: bool = True
    quantize_int8: bool = False
    model_cache: bool = True
    cache_dir: str = ""

    def __post_init__(self) -> None:
        if self.model not in SHIPPED_MODELS:
            raise ConfigError(f"detector.model: {self.model!r} is not one of {', '.join(SHIPPED_MODELS)}")
        if self.layout not in LAYOUTS:
            raise ConfigError(f"detector.layout: {self.layout!r} is not one of {', '.join(LAYOUTS)}")
        if self.nms not in NMS_MODES:
            raise ConfigError(f"detector.nms: {self.nms!r} is not one of {', '.join(NMS_MODES)}")
        if self.graph_optimization not in GRAPH_OPTIMIZATIONS:
            raise ConfigError(
                f"detector.graph_optimization: {self.graph_optimization!r} is not one of {', '.join(GRAPH_OPTIMIZATIONS)}"
            )
        for name in ("score_threshold", "nms_iou_threshold", "class_agnostic_iou_threshold", "ssd_nms_iou_threshold"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ConfigError(f"detector.{name}: expected a value in [0, 1], got {v}")
        if self.spin_duration_us < 0:
            raise ConfigError(f"detector.spin_duration_us: expected >= 0, got {self.spin_duration_us}")
        if self.intra_op_threads < 0:
            raise ConfigError(f"detector.intra_op_threads: expected >= 0, got {self.intra_op_threads}")
        if self.yolo_input_size_px < 32 or self.max_detections < 1:
            raise ConfigError("detector: yolo_input_size_px must be >= 32 and max_detections >= 1")


# ----------------------------------------------------------------------------------------------
# Geometry helpers shared by the post-processing and the keypoint classification
# ----------------------------------------------------------------------------------------------


def iou_matrix(boxes_a: F64, boxes_b: F64) -> F64:
    """IoU between boxes (A, 4) and (B, 4) in xyxy pixels -> (A, B)."""
    a = np.asarray(boxes_a, dtype=np.float64).reshape(-1, 4)
    b = np.asarray(boxes_b, dtype=np.float64).reshape(-1, 4)
    ix0 = np.maximum(a[:, None, 0], b[None, :, 0])
    iy0 = np.maximum(a[:, None, 1], b[None, :, 1])
    ix1 = np.minimum(a[:, None, 2], b[None, :, 2])
    iy1 = np.minimum(a[:, None, 3], b[None, :, 3])
    inter = np.clip(ix1 - ix0, 0.0, None) * np.clip(iy1 - iy0, 0.0, None)
    area_a = np.clip(a[:, 2] - a[:, 0], 0.0, None) * np.clip(a[:, 3] - a[:, 1], 0.0, None)
    area_b = np.clip(b[:, 2] - b[:, 0], 0.0, None) * np.clip(b[:, 3] - b[:, 1], 0.0, None)
    union = area_a[:, None] + area_b[None, :] - inter
    return np.where(union > 0.0, inter / np.maximum(union, 1e-12), 0.0)


def nms(boxes_xyxy: F64, scores: F64, iou_threshold: float, class_ids: npt.ArrayLike | None = None) -> npt.NDArray[np.int64]:
    """Greedy non-maximum suppression; indices kept, best score first.

    With `class_ids` (M,) boxes only suppress boxes of their own class; without, suppression is
    class-agnostic.
    """
    boxes = np.asarray(boxes_xyxy, dtype=np.float64).reshape(-1, 4)
    order = np.argsort(-np.asarray(scores, dtype=np.float64), kind="stable")
    if len(order) == 0:
        return np.zeros(0, dtype=np.int64)
    ious = iou_matrix(boxes, boxes)
    same = np.ones_like(ious, dtype=bool)
    if class_ids is not None:
        c = np.asarray(class_ids)
        same = c[:, None] == c[None, :]
    suppressed = np.zeros(len(boxes), dtype=bool)
    keep: list[int] = []
    for i in order:
        if suppressed[i]:
            continue
        keep.append(int(i))
        suppressed |= (ious[i] > iou_threshold) & same[i]
    return np.array(keep, dtype=np.int64)


@dataclass(frozen=True)
class Letterbox:
    """Resize-and-pad transform from an image to a square network input: x_in = x_img * scale + pad_x."""

    scale: float
    pad_x: float
    pad_y: float
    size_px: int


def letterbox(rgb: npt.NDArray[np.uint8], size_px: int) -> tuple[npt.NDArray[np.float32], Letterbox]:
    """Letterbox an RGB image (H, W, 3) uint8 into a (1, 3, S, S) float32 tensor in [0, 1], grey (114) padding."""
    import cv2

    h, w = rgb.shape[:2]
    scale = min(size_px / w, size_px / h)
    nw, nh = int(round(w * scale)), int(round(h * scale))
    pad_x, pad_y = (size_px - nw) // 2, (size_px - nh) // 2
    canvas = np.full((size_px, size_px, 3), 114, dtype=np.uint8)
    resized = cv2.resize(rgb, (nw, nh), interpolation=cv2.INTER_LINEAR) if (nw, nh) != (w, h) else rgb
    canvas[pad_y : pad_y + nh, pad_x : pad_x + nw] = resized
    tensor = canvas.transpose(2, 0, 1)[None].astype(np.float32) / 255.0
    return np.ascontiguousarray(tensor), Letterbox(scale, float(pad_x), float(pad_y), size_px)


# ----------------------------------------------------------------------------------------------
# Post-processing per layout (pure functions on output tensors, testable without a model)
# ----------------------------------------------------------------------------------------------


def postprocess_ssd_tf(
    boxes: F32, scores: F32, classes: F32, num: F32 | None, width: int, height: int, score_threshold: float
) -> tuple[F64, F64, npt.NDArray[np.int64]]:
    """TF-OD outputs of one image: boxes (K, 4) normalised yxyx, scores (K,), COCO-91 classes (K,), num (1,)
    -> boxes (M, 4) xyxy pixels, scores (M,), 0-based class ids (M,) for known classes above the threshold."""
    k = len(scores) if num is None else min(len(scores), int(np.asarray(num).reshape(-1)[0]))
    b = np.asarray(boxes[:k], dtype=np.float64).reshape(-1, 4)
    s = np.asarray(scores[:k], dtype=np.float64)
    c = coco91_to_80(classes[:k])
    ok = (s >= score_threshold) & (c != BACKGROUND_CLASS_ID)
    xyxy = np.stack([b[:, 1] * width, b[:, 0] * height, b[:, 3] * width, b[:, 2] * height], axis=1)
    xyxy = _clip_boxes(xyxy, width, height)
    return xyxy[ok], s[ok], c[ok]


def postprocess_ssd_head(
    boxes: F32,
    scores: F32,
    width: int,
    height: int,
    score_threshold: float,
    iou_threshold: float,
    max_detections: int,
    column_ids: tuple[int, ...] | None = None,
) -> tuple[F64, F64, npt.NDArray[np.int64]]:
    """A TF-OD SSD's suppression done here, as the graph does it: `boxes` (A, 4) decoded anchors, normalised
    yxyx; `scores` (A, 1 + C) sigmoid scores, background in column 0 -> boxes (M, 4) xyxy pixels, scores (M,),
    0-based class ids (M,), best first. With `column_ids` (the slimmed graph, `detector_session.slim_ssd_head`)
    `scores` is (A, K) and column j holds original COCO id `column_ids[j]` (no background column).

    Per class (TF's multiclass_non_max_suppression): keep scores above `score_threshold` (strictly, in float32
    like the graph), clip the boxes to the image and drop empty ones, greedy NMS at `iou_threshold`; then the
    best `max_detections` over all classes, and ids outside the 80 classes dropped.
    """
    b = np.clip(np.asarray(boxes, dtype=np.float32).reshape(-1, 4), np.float32(0.0), np.float32(1.0))
    s = np.ascontiguousarray(scores, dtype=np.float32).reshape(len(b), -1)
    flat = np.flatnonzero(s.ravel() > np.float32(score_threshold))  # one pass over the contiguous scores
    anchor, col = np.divmod(flat, s.shape[1])
    area = (b[anchor, 2] - b[anchor, 0]) * (b[anchor, 3] - b[anchor, 1])
    if column_ids is None:
        ok = (col > 0) & (area > 0.0)  # column 0 is the background
        coco91 = col
    else:
        ok = area > 0.0
        coco91 = np.asarray(column_ids, dtype=np.int64)[col]
    anchor, col, cls = anchor[ok], col[ok], coco91[ok] - 1
    cand_scores = s[anchor, col].astype(np.float64)
    kept: list[npt.NDArray[np.int64]] = []
    for c in np.unique(cls):
        idx = np.flatnonzero(cls == c)
        kept.append(idx[nms(b[anchor[idx]], cand_scores[idx], iou_threshold)[:max_detections]])
    sel = np.concatenate(kept) if kept else np.zeros(0, dtype=np.int64)
    sel = sel[np.argsort(-cand_scores[sel], kind="stable")[:max_detections]]
    yxyx = b[anchor[sel]].astype(np.float64)
    ids = coco91_to_80(cls[sel] + 1)
    ok = ids != BACKGROUND_CLASS_ID
    xyxy = np.stack([yxyx[:, 1] * width, yxyx[:, 0] * height, yxyx[:, 3] * width, yxyx[:, 2] * height], axis=1)
    return _clip_boxes(xyxy, width, height)[ok], cand_scores[sel][ok], ids[ok]


def postprocess_yolo(
    output: F32,
    lb: Letterbox,
    width: int,
    height: int,
    score_threshold: float,
    nms_iou_threshold: float,
    num_classes: int = 80,
) -> tuple[F64, F64, npt.NDArray[np.int64]]:
    """YOLO output of one image, (4 + C, N) or (N, 4 + C) (or (N, 5 + C) with objectness) -> boxes (M, 4) xyxy
    pixels of the original image, scores (M,), class ids (M,), after per-class NMS, best first."""
    out = np.asarray(output, dtype=np.float64)
    if out.ndim == 3:
        out = out[0]
    if out.ndim != 2:
        raise ConfigError(f"YOLO output: expected (4 + C, N) or (N, 4 + C), got shape {output.shape}")
    rows = _yolo_rows(out, num_classes)
    boxes_cxcywh = rows[:, :4]
    if rows.shape[1] == 5 + num_classes:  # YOLOv5 style: objectness x class probability
        cls_scores = rows[:, 5:] * rows[:, 4:5]
    else:
        cls_scores = rows[:, 4:]
    class_ids = np.argmax(cls_scores, axis=1)
    best = cls_scores[np.arange(len(rows)), class_ids]
    ok = best >= score_threshold
    boxes_cxcywh, best, class_ids = boxes_cxcywh[ok], best[ok], class_ids[ok]
    cx, cy, bw, bh = boxes_cxcywh.T
    xyxy = np.stack([cx - bw / 2, cy - bh / 2, cx + bw / 2, cy + bh / 2], axis=1)
    # Undo the letterbox: x_img = (x_in - pad) / scale.
    xyxy[:, [0, 2]] = (xyxy[:, [0, 2]] - lb.pad_x) / lb.scale
    xyxy[:, [1, 3]] = (xyxy[:, [1, 3]] - lb.pad_y) / lb.scale
    xyxy = _clip_boxes(xyxy, width, height)
    keep = nms(xyxy, best, nms_iou_threshold, class_ids)
    return xyxy[keep], best[keep], class_ids[keep].astype(np.int64)


def _yolo_rows(out: F64, num_classes: int) -> F64:
    """Candidates as rows (N, 4 + C [+1]): transpose (4 + C, N) outputs (the fewer-dimension side is channels)."""
    widths = (4 + num_classes, 5 + num_classes)
    if out.shape[1] in widths and out.shape[0] not in widths:
        return out
    if out.shape[0] in widths and out.shape[1] not in widths:
        return out.T
    return out.T if out.shape[0] < out.shape[1] else out


def _clip_boxes(xyxy: F64, width: int, height: int) -> F64:
    out = xyxy.copy()
    out[:, [0, 2]] = np.clip(out[:, [0, 2]], 0.0, float(width))
    out[:, [1, 3]] = np.clip(out[:, [1, 3]], 0.0, float(height))
    return out


# ----------------------------------------------------------------------------------------------
# The detector
# ----------------------------------------------------------------------------------------------


_SESSION_FIELDS = (
    "model", "model_path", "layout", "intra_op_threads", "providers", "nms", "graph_optimization", "allow_spinning",
    "spin_duration_us", "slim_graph", "quantize_int8", "model_cache", "cache_dir",
)  # fmt: skip


@dataclass(frozen=True)
class DetectorTiming:
    """Wall time of the last `detect` call by part: input preparation, `session.run`, output decoding (ms)."""

    preprocess_ms: float = 0.0
    run_ms: float = 0.0
    postprocess_ms: float = 0.0


class Detector:
    """Runs one ONNX detector on RGB images and returns `DetectionSet`s.

    The onnxruntime session is created in the constructor (a node does this in `on_activate`) and
    released by `close()`.
    """

    def __init__(self, config: DetectorConfig | None = None) -> None:
        self.config = config or DetectorConfig()
        path = Path(self.config.model_path) if self.config.model_path else SHIPPED_MODELS[self.config.model]
        if not path.is_file():
            raise ConfigError(f"detector.model_path: {path}: no such ONNX model file")
        self.model_path = path
        cfg = self.config
        cache_dir = (Path(cfg.cache_dir).expanduser() if cfg.cache_dir else default_cache_dir()) if cfg.model_cache else None
        prepared = prepare_session(
            path,
            SessionSettings(
                intra_op_threads=cfg.intra_op_threads,
                graph_optimization=cfg.graph_optimization,
                allow_spinning=cfg.allow_spinning,
                providers=cfg.providers,
                nms=cfg.nms,
                quantize_int8=cfg.quantize_int8,
                cache_dir=cache_dir,
                ssd_class_columns=COCO91_IDS if cfg.slim_graph else (),
                spin_duration_us=cfg.spin_duration_us,
            ),
        )
        self._session: Any = prepared.session
        self.ssd_nms_in_graph = not prepared.ssd_head
        self.score_columns = prepared.score_columns  # COCO-91 id per score column of a slimmed graph
        self.cache_path = prepared.cache_path
        self.cache_hit = prepared.cache_hit
        self.providers: tuple[str, ...] = tuple(self._session.get_providers())
        self._input = self._session.get_inputs()[0]
        self._outputs = [o.name for o in self._session.get_outputs()]
        self.layout = "ssd_tf" if prepared.ssd_head else (self._detect_layout() if cfg.layout == "auto" else cfg.layout)
        self.last_inference_ms = 0.0
        self.last_timing = DetectorTiming()

    def _detect_layout(self) -> str:
        outs = self._session.get_outputs()
        names = [o.name.split(":")[0] for o in outs]
        if {"detection_boxes", "detection_scores", "detection_classes"} <= set(names):
            return "ssd_tf"
        if len(outs) == 1 and len(outs[0].shape) == 3:
            return "yolo"
        shapes = ", ".join(f"{o.name}{list(o.shape)}" for o in outs)
        raise ConfigError(
            f"detector.model_path: {self.model_path}: cannot tell the output layout from outputs {shapes}; "
            "expected TF-OD detection_boxes/scores/classes or one YOLO output (1, 4 + C, N); set detector.layout"
        )

    @property
    def yolo_input_size_px(self) -> int:
        shape = self._input.shape
        if len(shape) == 4 and isinstance(shape[2], int) and shape[2] > 0:
            return int(shape[2])
        return self.config.yolo_input_size_px

    def detect(self, rgb: npt.NDArray[np.uint8], stamp_ns: int = 0) -> DetectionSet:
        """Detect objects in an RGB image (H, W, 3) uint8; boxes are in its pixels."""
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise ValueError(f"detect: expected an (H, W, 3) uint8 RGB image, got {rgb.shape} {rgb.dtype}")
        h, w = rgb.shape[:2]
        cfg = self.config
        t0 = time.perf_counter()
        if self.layout == "ssd_tf":
            feed = {self._input.name: np.ascontiguousarray(rgb)[None]}  # no copy for a contiguous image
            t1 = time.perf_counter()
            outputs = self._session.run(None, feed)
            t2 = time.perf_counter()
            if not self.ssd_nms_in_graph:
                boxes, scores, classes = postprocess_ssd_head(
                    outputs[0][0], outputs[1][0], w, h, cfg.score_threshold, cfg.ssd_nms_iou_threshold,
                    cfg.max_detections, self.score_columns,
                )  # fmt: skip
            else:
                get = {k.split(":")[0]: v for k, v in zip(self._outputs, outputs)}
                num = get.get("num_detections")
                boxes, scores, classes = postprocess_ssd_tf(
                    get["detection_boxes"][0], get["detection_scores"][0], get["detection_classes"][0],
                    None if num is None else num[0:1], w, h, cfg.score_threshold,
                )  # fmt: skip
        else:
            tensor, lb = letterbox(rgb, self.yolo_input_size_px)
            t1 = time.perf_counter()
            (output,) = self._session.run(None, {self._input.name: tensor})[:1]
            t2 = time.perf_counter()
            boxes, scores, classes = postprocess_yolo(
                output, lb, w, h, cfg.score_threshold, cfg.nms_iou_threshold
            )
        t3 = time.perf_counter()
        self.last_inference_ms = (t3 - t0) * 1e3
        self.last_timing = DetectorTiming((t1 - t0) * 1e3, (t2 - t1) * 1e3, (t3 - t2) * 1e3)
        if cfg.class_agnostic_nms and len(scores):
            keep = nms(boxes, scores, cfg.class_agnostic_iou_threshold)
            boxes, scores, classes = boxes[keep], scores[keep], classes[keep]
        order = np.argsort(-scores, kind="stable")[: cfg.max_detections]
        dets = tuple(
            Detection(
                (float(boxes[i, 0]), float(boxes[i, 1]), float(boxes[i, 2]), float(boxes[i, 3])),
                int(classes[i]),
                float(scores[i]),
            )
            for i in order
        )
        return DetectionSet(stamp_ns=stamp_ns, detections=dets, width=w, height=h)

    def set_postprocessing(self, config: DetectorConfig) -> None:
        """Swap thresholds / suppression settings without reloading the model (a node's parameter callback).

        The model, layout, providers and thread count must stay the same; changing them needs a new `Detector`.
        """
        fields = _SESSION_FIELDS
        if any(getattr(config, f) != getattr(self.config, f) for f in fields):
            raise ConfigError(f"detector: {', '.join(fields)} need a new Detector")
        self.config = config

    def close(self) -> None:
        """Release the onnxruntime session."""
        self._session = None
