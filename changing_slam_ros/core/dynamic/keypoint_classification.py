"""Keypoint classification and feature repopulation (Changing-SLAM §4.1).

Keypoints inside a person box are *a priori* dynamic, inside another object's box movable, elsewhere static;
all keypoints of one object share one class (paper Fig. 2). Feature repopulation keeps the background seen
*through* a box: from the box's depth statistics (areas where other boxes overlap it left out), a keypoint
deeper than the box's minimum depth plus a class-dependent margin is background, hence static. When something
occludes the detected object the statistics cannot separate object from background, and the paper leaves the
object's keypoints out (`KeypointClass.UNUSED`) when "the standard deviation of the depths is too high, or the
median depth is higher than the depth of the centre of the bounding box". Read literally the second test fires
on any object before a far background, so it applies with a tolerance (`centre_occlusion_margin_m`); the
optional converse check (`check_centre_in_object_band`, off) is described on `KeypointClassificationConfig`.
A person's box left out this way still gives back the background seen around the person when its centre depth
is the person's (`centre_on_object`, `repopulate_occluded_class_ids`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.dynamic.detector import PERSON_CLASS_ID, Detection, iou_matrix
from changing_slam_ros.core.map.keyframe import KeypointClass
from changing_slam_ros.errors import ConfigError

F64 = npt.NDArray[np.float64]

# KeypointClass values as plain ints for the per-frame arrays, here and in the object tracker (an IntEnum member
# costs a lookup through enum's __getattr__ on every use)
KP_STATIC, KP_MOVABLE, KP_DYNAMIC, KP_UNUSED = (int(c) for c in (KeypointClass.STATIC, KeypointClass.MOVABLE,
                                                                  KeypointClass.DYNAMIC, KeypointClass.UNUSED))


@dataclass(frozen=True)
class KeypointClassificationConfig:
    """`keypoint_classification` config section (the paper names these thresholds but gives no values).

    - `dynamic_class_ids`: classes whose keypoints are a priori dynamic (paper: person).
    - `min_detection_score`: detections below it are ignored here.
    - `repopulation`: feature repopulation on/off (off = every keypoint in a box takes the box's class).
    - `background_margin_m` / `default_background_margin_m`: class-dependent margin added to the box's
      minimum depth; deeper keypoints are background. A walking person seen from the side spans more
      than 0.5 m in depth (arms, stride): on the simulated walking scenarios a 0.5 m margin let 1.2-1.6 %
      of the persons' keypoints through as background, 0.8 m none beyond missed detections
      (`bench/eval_dynamic_filtering_sim.py`).
    - `min_depth_percentile`: percentile used as the box's "minimum" depth (0 = the paper's minimum;
      raise it a little for noisy sensors).
    - `max_depth_std_m`: depth spread above which the object's keypoints are not used.
    - `centre_occlusion_margin_m`: the box centre closer than the median depth by more than this =
      occluded centre (paper: median depth higher than the centre depth).
    - `check_centre_in_object_band`: also require the centre depth within min + margin (else the nearest
      layer of the box is something other than the object, e.g. a table in front of a sitting person, which
      would make the object itself "background"); off by default: it also fires on open objects (a table seen through its legs) and made no
      difference to the leak of dynamic keypoints on the simulated scenarios.
    - `centre_patch_fraction`: side of the centre patch whose median is the centre depth, as a fraction of
      the box side.
    - `exclude_overlaps`: leave other boxes' overlapping areas out of the statistics.
    - `stats_stride_px`: depth pixels sampled every this many pixels for the statistics.
    - `min_valid_depth_fraction`: fewer valid depth samples than this fraction of the box = no statistics,
      so no repopulation for it (its keypoints all take the box's class).
    - `invalid_depth_is_object`: keypoints without depth inside a box belong to the object (conservative).
    - `keypoint_depth_window_px`: a keypoint's depth for the object/background test is the nearest valid
      depth within this radius (a corner on an object's silhouette samples the background behind it but
      its descriptor patch straddles the object; the nearest depth keeps it with the object).
    - `box_margin_px`: a keypoint within this distance outside a box is tested as inside it (the depth test
      still decides object or background). Corners on a silhouette sit on its edge: a tight box (the
      simulator's oracle boxes span the visible pixels' indices, half a pixel short of the silhouette's
      left and top edges in continuous coordinates) leaves them outside, and they were tracked as static.
      On the old flat simulated people (sitting_xyz, oracle boxes, ground-truth poses, first 60 frames)
      all 67 person keypoints used for tracking lay within 0.5 px left of a person box. The margin widens
      only boxes of `dynamic_class_ids`: a leaked corner of a person poisons tracking, while a movable object's
      edge keypoints are background or go through the EKF anyway; widening every box took the PUC-like
      `static` run (eleven movable objects, oracle boxes) from 3.15 to 12.66 cm ATE.
    - `repopulate_occluded_class_ids`: a box of these classes left out by the tests above still gives back the
      background seen through it when its centre depth is the object's (`centre_on_object`): keypoints deeper
      than the centre by the class margin are static, the others stay out. The centre test fires on any object
      before a far background that fills most of its box (a person close to the camera in a room: more than
      half of the oracle person boxes on seven random_dynamic seeds), and without this every keypoint of the
      room seen around that person is dropped. Person boxes only by default: given back behind furniture boxes too, the
      background changed static scenes for the worse (7-Scenes redkitchen, 300 frames: 2.34 -> 3.25 cm ATE),
      while behind person boxes it lowered the random_dynamic evaluation seeds' ATE p90 / worst from 16.1 /
      32.5 to 14.3 / 16.4 cm and raised moving-keypoint precision from 0.55 to 0.65 at about the same recall
      (`docs/results.md`).
    - `near_layer_edge_fraction`: with the centre nearer than the median, the centre is the object's when the
      pixels within the class margin of the centre depth reach each side of the box to within this fraction
      of its side (a box is fitted to its object; an occluder across the object leaves sides to the object).
    """

    dynamic_class_ids: tuple[int, ...] = (PERSON_CLASS_ID,)
    min_detection_score: float = 0.0
    repopulation: bool = True
    background_margin_m: dict[int, float] = field(default_factory=lambda: {PERSON_CLASS_ID: 0.8, 56: 0.6})
    default_background_margin_m: float = 0.5
    min_depth_percentile: float = 0.0
    max_depth_std_m: float = 1.5
    centre_occlusion_margin_m: float = 0.3
    check_centre_in_object_band: bool = False
    centre_patch_fraction: float = 0.1
    exclude_overlaps: bool = True
    stats_stride_px: int = 4
    min_valid_depth_fraction: float = 0.2
    invalid_depth_is_object: bool = True
    keypoint_depth_window_px: int = 2
    box_margin_px: float = 2.0
    repopulate_occluded_class_ids: tuple[int, ...] = (PERSON_CLASS_ID,)
    near_layer_edge_fraction: float = 0.1

    def __post_init__(self) -> None:
        if self.box_margin_px < 0.0:
            raise ConfigError(f"keypoint_classification.box_margin_px: expected >= 0, got {self.box_margin_px}")
        if not 0.0 <= self.min_depth_percentile < 50.0:
            raise ConfigError(f"keypoint_classification.min_depth_percentile: expected [0, 50), got {self.min_depth_percentile}")
        if self.stats_stride_px < 1:
            raise ConfigError(f"keypoint_classification.stats_stride_px: expected >= 1, got {self.stats_stride_px}")
        if not 0.0 <= self.near_layer_edge_fraction < 0.5:
            raise ConfigError(f"keypoint_classification.near_layer_edge_fraction: expected [0, 0.5), got {self.near_layer_edge_fraction}")
        if not 0.0 < self.centre_patch_fraction <= 1.0:
            raise ConfigError("keypoint_classification.centre_patch_fraction: expected a value in (0, 1]")

    def margin_m(self, class_id: int) -> float:
        return self.background_margin_m.get(class_id, self.default_background_margin_m)


@dataclass(frozen=True)
class BoxDepthStats:
    """Depth statistics of one box in metres, over its valid samples outside other boxes' overlaps."""

    median_m: float
    mean_m: float
    min_m: float
    max_m: float
    std_m: float
    centre_m: float  # median depth of the centre patch, NaN when it has no valid depth
    n_samples: int
    valid_fraction: float


@dataclass(frozen=True)
class KeypointClassification:
    """Result for one frame with N keypoints and M detections.

    - `kp_classes` (N,) int8 `KeypointClass`;
    - `kp_object_class_ids` (N,) int64 COCO class of the object a keypoint belongs to, -1 background;
    - `kp_box_index` (N,) int64 index of that detection in the input sequence, -1 background;
    - `box_stats` (M,) `BoxDepthStats` or None (too little depth);
    - `box_usable` (M,) bool, False when the object's keypoints are not used (occluded / spread);
    - `box_background_depth_m` (M,) keypoints deeper are background (inf without repopulation);
    - `iou` (M, M) IoU matrix of the boxes.
    """

    kp_classes: npt.NDArray[np.int8]
    kp_object_class_ids: npt.NDArray[np.int64]
    kp_box_index: npt.NDArray[np.int64]
    box_stats: tuple[BoxDepthStats | None, ...]
    box_usable: npt.NDArray[np.bool_]
    box_background_depth_m: F64
    iou: F64

    def static_mask(self) -> npt.NDArray[np.bool_]:
        """(N,) keypoints usable for camera tracking before any object-motion evidence (static only)."""
        return np.asarray(self.kp_classes == KeypointClass.STATIC)


def box_pixels(shape: tuple[int, ...], box_xyxy: tuple[float, float, float, float] | F64) -> tuple[int, int, int, int]:
    """The pixel range (x0, y0, x1, y1), max exclusive, that a box covers in an image of `shape` (H, W), clipped."""
    h, w = shape[:2]
    x0, y0 = max(math.floor(box_xyxy[0]), 0), max(math.floor(box_xyxy[1]), 0)
    return x0, y0, min(math.ceil(box_xyxy[2]), w), min(math.ceil(box_xyxy[3]), h)


def box_depth_stats(
    depth_m: npt.NDArray[np.float32],
    box_xyxy: tuple[float, float, float, float] | F64,
    others_xyxy: F64,
    config: KeypointClassificationConfig,
) -> BoxDepthStats | None:
    """Statistics of depth image (H, W) metres (0 = invalid) inside a box, without the areas where the
    boxes `others_xyxy` (K, 4) overlap it; None when too few valid samples remain."""
    x0, y0, x1, y1 = box_pixels(depth_m.shape, box_xyxy)
    if x1 - x0 < 1 or y1 - y0 < 1:
        return None
    s = config.stats_stride_px
    patch = depth_m[y0:y1:s, x0:x1:s]
    keep = patch > 0.0
    if config.exclude_overlaps and len(others_xyxy):
        xs = np.arange(x0, x1, s, dtype=np.float64)[: patch.shape[1]] + 0.5
        ys = np.arange(y0, y1, s, dtype=np.float64)[: patch.shape[0]] + 0.5
        o = np.asarray(others_xyxy, dtype=np.float64).reshape(-1, 4)
        in_x = (xs[None, :] >= o[:, 0:1]) & (xs[None, :] < o[:, 2:3])  # (K, columns) inside each other box
        in_y = (ys[None, :] >= o[:, 1:2]) & (ys[None, :] < o[:, 3:4])  # (K, rows)
        overlap = (in_y[:, :, None] & in_x[:, None, :]).any(axis=0)  # samples inside any of them
        if (keep & ~overlap).sum() >= config.min_valid_depth_fraction * patch.size:
            keep &= ~overlap  # a box covered by others keeps all its samples rather than none
    vals = patch[keep].astype(np.float64)
    if vals.size == 0 or vals.size < config.min_valid_depth_fraction * patch.size:
        return None
    lo = float(np.percentile(vals, config.min_depth_percentile)) if config.min_depth_percentile > 0 else float(vals.min())
    mean = float(vals.mean())
    return BoxDepthStats(
        median_m=median_1d(vals),
        mean_m=mean,
        min_m=lo,
        max_m=float(vals.max()),
        std_m=float(np.sqrt(max(float(np.dot(vals, vals)) / vals.size - mean * mean, 0.0))),
        centre_m=_centre_depth(depth_m, (x0, y0, x1, y1), config.centre_patch_fraction),
        n_samples=int(vals.size),
        valid_fraction=float(vals.size / patch.size),
    )


def median_1d(vals: F64) -> float:
    """Median of a non-empty 1-D array without NaN (np.median's value, bit for bit: the same partition, and the
    mean of the middle pair is their sum halved; without np.median's NaN checks, which dominate on small arrays)."""
    k = vals.size // 2
    part = np.partition(vals, [k - 1, k] if vals.size % 2 == 0 and k > 0 else [k])
    return float(0.5 * (part[k - 1] + part[k])) if vals.size % 2 == 0 and k > 0 else float(part[k])


def _centre_depth(depth_m: npt.NDArray[np.float32], box: tuple[int, int, int, int], fraction: float) -> float:
    x0, y0, x1, y1 = box
    cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    hw = max(1.0, 0.5 * fraction * (x1 - x0))
    hh = max(1.0, 0.5 * fraction * (y1 - y0))
    patch = depth_m[int(cy - hh) : math.ceil(cy + hh), int(cx - hw) : math.ceil(cx + hw)]
    vals = patch[patch > 0.0].astype(np.float64)
    return median_1d(vals) if vals.size else float("nan")


def nearest_depth_around(depth_m: npt.NDArray[np.float32], keypoints_px: F64, radius_px: int) -> F64:
    """Per keypoint (N, 2) the smallest valid depth (N,) metres within a (2r + 1)^2 window; 0 when none."""
    n = len(keypoints_px)
    if n == 0:
        return np.zeros(0)
    h, w = depth_m.shape
    u = np.rint(keypoints_px[:, 0]).astype(np.int64)
    v = np.rint(keypoints_px[:, 1]).astype(np.int64)
    r = max(int(radius_px), 0)
    offs = np.arange(-r, r + 1)
    cols = np.clip(u[:, None] + offs[None, :], 0, w - 1)  # (N, 2r + 1)
    rows = np.clip(v[:, None] + offs[None, :], 0, h - 1) * w
    flat = (rows[:, :, None] + cols[:, None, :]).reshape(n, -1)  # one flat gather: ~25 % less CPU than [vv, uu]
    d = np.ravel(depth_m).take(flat)  # in the image's float dtype: its minimum converts exactly
    if not np.issubdtype(d.dtype, np.floating):
        d = d.astype(np.float64)
    d[d <= 0.0] = np.inf
    out: F64 = np.asarray(d.min(axis=1), dtype=np.float64)
    out[~np.isfinite(out)] = 0.0
    return out


def is_occluded(stats: BoxDepthStats, margin_m: float, config: KeypointClassificationConfig) -> bool:
    """True when an unlabelled object is in front (spread too high, centre nearer than the median, or the
    centre outside the object's depth band); NaN centre depth disables the centre tests."""
    if stats.std_m > config.max_depth_std_m:
        return True
    if np.isnan(stats.centre_m):
        return False
    if stats.centre_m < stats.median_m - config.centre_occlusion_margin_m:
        return True
    return config.check_centre_in_object_band and stats.centre_m > stats.min_m + margin_m


def near_layer_spans_box(depth_m: npt.NDArray[np.float32], box_xyxy: tuple[float, float, float, float],
                         limit_m: float, config: KeypointClassificationConfig) -> bool:
    """True when the pixels of the box nearer than `limit_m` reach every side of the box (within
    `near_layer_edge_fraction` of its width / height): a detector's box is fitted to its object, so a near layer
    that spans it is the object, while an unlabelled occluder in front of the object leaves sides of the box
    to the object behind it."""
    x0, y0, x1, y1 = box_pixels(depth_m.shape, box_xyxy)
    s = config.stats_stride_px
    patch = depth_m[y0:y1:s, x0:x1:s]
    near = (patch > 0.0) & (patch <= limit_m)
    if not near.any():
        return False
    rows, cols = np.flatnonzero(near.any(axis=1)), np.flatnonzero(near.any(axis=0))
    fr, fc = config.near_layer_edge_fraction * near.shape[0], config.near_layer_edge_fraction * near.shape[1]
    reaches_rows = rows[0] <= fr and rows[-1] >= near.shape[0] - 1 - fr
    return bool(reaches_rows and cols[0] <= fc and cols[-1] >= near.shape[1] - 1 - fc)


def centre_on_object(depth_m: npt.NDArray[np.float32], box_xyxy: tuple[float, float, float, float],
                     stats: BoxDepthStats, margin_m: float, config: KeypointClassificationConfig) -> bool:
    """For a box `is_occluded` called occluded: True when its centre depth is still the object's, so that what
    lies deeper than the centre by the class margin is background (`repopulate_occluded_class_ids`). That holds
    when the spread alone fired (the centre tests passed), or when the centre lies nearer than the median but the
    near layer spans the box (`near_layer_spans_box`): an object before a far background that fills most of
    its box, as a person seen close before a room, not an occluder across it."""
    if np.isnan(stats.centre_m) or (config.check_centre_in_object_band and stats.centre_m > stats.min_m + margin_m):
        return False
    if stats.centre_m >= stats.median_m - config.centre_occlusion_margin_m:
        return True
    return near_layer_spans_box(depth_m, box_xyxy, stats.centre_m + margin_m, config)


def classify_keypoints(
    keypoints_px: npt.NDArray[np.floating],
    depth_m: npt.NDArray[np.float32],
    detections: tuple[Detection, ...] | list[Detection],
    config: KeypointClassificationConfig | None = None,
    keypoint_depths_m: npt.NDArray[np.floating] | None = None,
) -> KeypointClassification:
    """Classify keypoints (N, 2) pixels of a frame with depth image (H, W) metres and its detections.

    `keypoint_depths_m` (N,) overrides the depth sampled at each keypoint (0 = none).
    """
    cfg = config or KeypointClassificationConfig()
    kps = np.asarray(keypoints_px, dtype=np.float64).reshape(-1, 2)
    n = len(kps)
    given_depth_m = None
    if keypoint_depths_m is not None:
        given_depth_m = np.asarray(keypoint_depths_m, dtype=np.float64).reshape(-1)
        if len(given_depth_m) != n:
            raise ValueError(f"classify_keypoints: {n} keypoints but {len(given_depth_m)} depths")
    dets = [d for d in detections if d.score >= cfg.min_detection_score]
    index_of = [i for i, d in enumerate(detections) if d.score >= cfg.min_detection_score]
    m = len(dets)
    boxes = np.array([d.box_xyxy for d in dets], dtype=np.float64).reshape(-1, 4)
    iou = iou_matrix(boxes, boxes)

    stats: list[BoxDepthStats | None] = []
    usable = np.ones(m, dtype=bool)
    bg_depth = np.full(m, np.inf)
    for b, det in enumerate(dets):
        others = boxes[[j for j in range(m) if j != b and iou[b, j] > 0.0]]
        st = box_depth_stats(depth_m, det.box_xyxy, others, cfg) if cfg.repopulation else None
        stats.append(st)
        if st is None:
            continue
        margin = cfg.margin_m(det.class_id)
        if is_occluded(st, margin, cfg):
            usable[b] = False
            repopulate = det.class_id in cfg.repopulate_occluded_class_ids
            if repopulate and centre_on_object(depth_m, det.box_xyxy, st, margin, cfg):
                bg_depth[b] = st.centre_m + margin  # the object's keypoints stay out, the background comes back
        else:
            bg_depth[b] = st.min_m + margin

    kp_classes = np.full(n, KP_STATIC, dtype=np.int8)
    kp_object = np.full(n, -1, dtype=np.int64)
    kp_box = np.full(n, -1, dtype=np.int64)
    if m and n:
        # the margin widens a priori dynamic boxes only (see `box_margin_px`)
        g = np.array([cfg.box_margin_px if d.class_id in cfg.dynamic_class_ids else 0.0 for d in dets])[None, :]
        inside = (
            (kps[:, None, 0] >= boxes[None, :, 0] - g) & (kps[:, None, 0] < boxes[None, :, 2] + g)
            & (kps[:, None, 1] >= boxes[None, :, 1] - g) & (kps[:, None, 1] < boxes[None, :, 3] + g)
        )  # fmt: skip
        if given_depth_m is not None:
            kp_depth = given_depth_m
        else:  # only a keypoint inside a box needs its depth (the object / background test)
            kp_depth = np.zeros(n)
            in_box = inside.any(axis=1)
            kp_depth[in_box] = nearest_depth_around(depth_m, kps[in_box], cfg.keypoint_depth_window_px)
        valid = kp_depth > 0.0
        fg = np.where(valid[:, None], kp_depth[:, None] <= bg_depth[None, :], cfg.invalid_depth_is_object)
        member = inside & (fg | (~usable & np.isinf(bg_depth))[None, :])
        # Priority when a keypoint belongs to several boxes: unusable, then dynamic classes, then the
        # nearest object (smallest minimum depth).
        dyn = np.array([d.class_id in cfg.dynamic_class_ids for d in dets])
        near = np.array([s.min_m if s is not None else np.inf for s in stats])
        rank = np.lexsort((near, ~dyn, usable))  # best box first
        by_rank = member[:, rank]
        first = by_rank.argmax(axis=1)  # per keypoint, its best box among those it belongs to
        has = by_rank[np.arange(n), first]
        best = rank[first[has]]
        kp_box[has] = np.asarray(index_of, dtype=np.int64)[best]
        kp_object[has] = np.array([d.class_id for d in dets], dtype=np.int64)[best]
        box_class = np.where(~usable, KP_UNUSED, np.where(dyn, KP_DYNAMIC, KP_MOVABLE)).astype(np.int8)
        kp_classes[has] = box_class[best]
    full_usable = np.ones(len(detections), dtype=bool)
    full_bg = np.full(len(detections), np.inf)
    full_stats: list[BoxDepthStats | None] = [None] * len(detections)
    for b, i in enumerate(index_of):
        full_usable[i], full_bg[i], full_stats[i] = usable[b], bg_depth[b], stats[b]
    if m == len(detections):  # every detection passed the score test: the IoU matrix is the one above
        all_iou = iou
    else:
        all_boxes = np.array([d.box_xyxy for d in detections], dtype=np.float64).reshape(-1, 4)
        all_iou = iou_matrix(all_boxes, all_boxes)
    return KeypointClassification(
        kp_classes=kp_classes,
        kp_object_class_ids=kp_object,
        kp_box_index=kp_box,
        box_stats=tuple(full_stats),
        box_usable=full_usable,
        box_background_depth_m=full_bg,
        iou=all_iou,
    )


# Colours in RGB order (paper Fig. 2): dynamic red, movable yellow, static green, unused grey.
CLASS_COLOURS_RGB: dict[int, tuple[int, int, int]] = {
    int(KeypointClass.DYNAMIC): (255, 0, 0),
    int(KeypointClass.MOVABLE): (255, 255, 0),
    int(KeypointClass.STATIC): (0, 255, 0),
    int(KeypointClass.UNUSED): (128, 128, 128),
}


def draw_keypoint_classes(
    rgb: npt.NDArray[np.uint8],
    keypoints_px: npt.NDArray[np.floating],
    kp_classes: npt.NDArray[np.integer],
    detections: tuple[Detection, ...] | list[Detection] = (),
    radius_px: int = 3,
) -> npt.NDArray[np.uint8]:
    """Debug image (H, W, 3) uint8 RGB: a copy of `rgb` with keypoints (N, 2) coloured by class and boxes drawn."""
    import cv2

    from changing_slam_ros.core.dynamic.detector import class_name

    out = np.ascontiguousarray(rgb.copy())
    for det in detections:
        x0, y0, x1, y1 = (int(round(c)) for c in det.box_xyxy)
        colour = (255, 0, 0) if det.class_id == PERSON_CLASS_ID else (255, 255, 0)
        cv2.rectangle(out, (x0, y0), (x1, y1), colour, 1)
        cv2.putText(out, f"{class_name(det.class_id)} {det.score:.2f}", (x0 + 2, max(y0 + 12, 12)),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.4, colour, 1, cv2.LINE_AA)  # fmt: skip
    for (u, v), c in zip(np.asarray(keypoints_px).reshape(-1, 2), np.asarray(kp_classes).reshape(-1)):
        cv2.circle(out, (int(round(u)), int(round(v))), radius_px, CLASS_COLOURS_RGB.get(int(c), (255, 255, 255)), 1, cv2.LINE_8)
    return out
