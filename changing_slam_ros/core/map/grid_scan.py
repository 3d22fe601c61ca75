"""A keyframe's depth kept for the occupancy grid (`occupancy_grid.py`): a decimated point set in its camera frame.

Keypoint depths are too sparse for free space and too biased toward texture for walls, so a keyframe keeps
a small regular sample of its depth image instead (`scan_from_depth`): the nearest valid reading of each
block of pixels, so that a thin leg in a block is kept rather than averaged away. The points stay in the
keyframe's camera frame; the grid places them with the keyframe's current pose, so a loop correction or a
bundle adjustment moves them with it.

Two labels decide what may become an obstacle: `dynamic` (the point lies on a dynamic detection: a person or
anything the dynamic stage saw moving, `mark_dynamic`) and `object_ids` (the MapObject the point belongs to,
`label_objects`), which the grid checks against the objects' beliefs when it is built.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.camera import CameraIntrinsics

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
BoxXyxy = tuple[float, float, float, float]


@dataclass
class GridScan:
    """K depth samples of one keyframe: `points_cam` (K, 3) float32 in the keyframe's optical frame (metres),
    `dynamic` (K,) bool (on a dynamic detection: never an obstacle), `object_ids` (K,) int64 (MapObject id,
    -1 for none)."""

    points_cam: F32
    dynamic: npt.NDArray[np.bool_]
    object_ids: npt.NDArray[np.int64]

    def __post_init__(self) -> None:
        self.points_cam = np.asarray(self.points_cam, np.float32).reshape(-1, 3)
        k = len(self.points_cam)
        self.dynamic = np.asarray(self.dynamic, bool).reshape(-1)
        self.object_ids = np.asarray(self.object_ids, np.int64).reshape(-1)
        if len(self.dynamic) != k or len(self.object_ids) != k:
            raise ValueError(f"GridScan: {k} points, {len(self.dynamic)} dynamic flags, "
                             f"{len(self.object_ids)} object ids")  # fmt: skip

    def __len__(self) -> int:
        return len(self.points_cam)

    @staticmethod
    def empty() -> GridScan:
        return GridScan(np.zeros((0, 3), np.float32), np.zeros(0, bool), np.zeros(0, np.int64))


def scan_from_depth(depth_m: npt.NDArray[np.floating], camera: CameraIntrinsics, columns: int,
                    max_range_m: float) -> GridScan:
    """Sample `depth_m` (H, W) metres (0 or non-finite = no reading) on a grid of about `columns` blocks across:
    per block the nearest valid reading, back-projected through the block's centre pixel; readings beyond
    `max_range_m` are dropped. The camera's intrinsics are scaled when the depth image has another size."""
    d = np.asarray(depth_m, np.float32)
    h, w = d.shape
    if (w, h) != (camera.width, camera.height):
        camera = camera.scaled(w, h)
    step = max(1, int(round(w / max(1, columns))))
    rows, cols = h // step, w // step
    if rows == 0 or cols == 0:
        return GridScan.empty()
    blocks = d[: rows * step, : cols * step].reshape(rows, step, cols, step)
    valid = np.isfinite(blocks) & (blocks > 0) & (blocks <= max_range_m)
    nearest = np.where(valid, blocks, np.inf).min(axis=(1, 3))
    ok = np.isfinite(nearest)
    r, c = np.nonzero(ok)
    px = np.stack([(c + 0.5) * step - 0.5, (r + 0.5) * step - 0.5], axis=1).astype(np.float64)
    pts = camera.backproject(px, nearest[ok].astype(np.float64))
    n = len(pts)
    return GridScan(pts.astype(np.float32), np.zeros(n, bool), np.full(n, -1, np.int64))


def _in_box(pixels: F64, box: BoxXyxy) -> npt.NDArray[np.bool_]:
    x0, y0, x1, y1 = box
    return (pixels[:, 0] >= x0) & (pixels[:, 0] < x1) & (pixels[:, 1] >= y0) & (pixels[:, 1] < y1)


def _pixels(scan: GridScan, camera: CameraIntrinsics) -> F64:
    """The points' pixels, rounded to 1/1000 px: a point sampled on the image's first row projects back a hair
    above it (float32 positions)."""
    pts = scan.points_cam.astype(np.float64)
    return np.round(camera.project(pts), 3) if len(pts) else np.zeros((0, 2))


def mark_dynamic(scan: GridScan, camera: CameraIntrinsics, boxes: Sequence[BoxXyxy], band_m: float) -> int:
    """Flag the points of dynamic detections (boxes in the keyframe's pixels): inside a box, every point nearer
    than the box's median depth + `band_m`. A box also holds the background past the mover; its median depth
    lies on the mover when the mover fills most of the box, and the band keeps the far background (a wall
    behind a person) usable. Returns how many points were flagged."""
    if not len(scan) or not boxes:
        return 0
    px = _pixels(scan, camera)
    z = scan.points_cam[:, 2]
    before = int(scan.dynamic.sum())
    for box in boxes:
        inside = _in_box(px, box)
        if inside.any():
            scan.dynamic |= inside & (z <= float(np.median(z[inside])) + band_m)
    return int(scan.dynamic.sum()) - before


@dataclass(frozen=True)
class ObjectView:
    """A MapObject seen in a keyframe: its box there (pixels) and its 3-D box in the map frame (centre, size)."""

    object_id: int
    box_xyxy: BoxXyxy
    box_center_w: F64
    box_size_m: F64


def label_objects(scan: GridScan, camera: CameraIntrinsics, T_world_cam: F64, views: Sequence[ObjectView],
                  margin_m: float) -> int:
    """Give the points that lie inside an object's image box and inside its 3-D box (grown by `margin_m` on every
    side) that object's id (the later view wins where two overlap). Returns how many points were labelled."""
    if not len(scan) or not views:
        return 0
    px = _pixels(scan, camera)
    pts_w = scan.points_cam.astype(np.float64) @ T_world_cam[:3, :3].T + T_world_cam[:3, 3]
    labelled = np.zeros(len(scan), bool)
    for v in views:
        half = np.asarray(v.box_size_m, float).reshape(3) / 2.0 + margin_m
        near = np.all(np.abs(pts_w - np.asarray(v.box_center_w, float).reshape(3)) <= half, axis=1)
        sel = _in_box(px, v.box_xyxy) & near
        scan.object_ids[sel] = v.object_id
        labelled |= sel
    return int(labelled.sum())
