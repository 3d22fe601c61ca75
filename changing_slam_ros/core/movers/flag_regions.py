"""From moving keypoints to moving regions: the rest of a mover that the point-wise cues left unflagged.

The class-agnostic cues (the two-frame segmentation, the free-space check) flag single keypoints, each on its own
evidence: a matched edge that stretched, a point in space seen empty. On a person or a box that fills much of the
view they flag a part of it, often under half (unmatched keypoints, keypoints whose earlier view was occluded,
a mover moving along the ray); the rest keeps feeding tracking and pulls the pose along. A detector box does the
completing for detected classes; this module does it for any mover:

1. The flagged keypoints with depth are grouped: two are linked when they lie within `link_px` in the image and
   within `link_depth_m` in depth (one surface, one mover). Groups with fewer than `min_flags` keypoints are left
   as they are (a few flags are as likely noise as a mover).
2. Each group spans a region: its keypoints' bounding box grown by `pad_px`, and its depth range grown by
   `depth_margin_m`. Every keypoint with depth inside both is flagged too: the mover's unflagged keypoints lie
   there, the background behind it is beyond the depth range, and a nearer occluder in front of it is not.

What it cannot do: a group's box is a box, so the floor beside a walking person's feet within the depth range is
flagged with them; and a mover with no flagged keypoint at all stays unseen. Pixel distances are given for a
640-wide image and scaled with the image width.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from changing_slam_ros.errors import ConfigError

F64 = npt.NDArray[np.float64]
BoolArr = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class FlagRegionConfig:
    """`dynamic.flag_region` section.

    - `link_px`: two flagged keypoints this close in the image (pixels of a 640-wide image) can be one mover's.
    - `link_depth_m`: and this close in depth.
    - `min_flags`: a group needs this many flagged keypoints to span a region.
    - `pad_px`: the group's bounding box grows by this much per side (640-wide pixels).
    - `depth_margin_m`: the group's depth range grows by this much on either side.
    """

    link_px: float = 24.0
    link_depth_m: float = 0.25
    min_flags: int = 6
    pad_px: float = 8.0
    depth_margin_m: float = 0.15

    def __post_init__(self) -> None:
        for name in ("link_px", "link_depth_m", "pad_px", "depth_margin_m"):
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0:
                raise ConfigError(f"dynamic.flag_region.{name}: expected a finite value >= 0, got {v}")
        if self.min_flags < 1:
            raise ConfigError(f"dynamic.flag_region.min_flags: expected >= 1, got {self.min_flags}")


def flag_groups(pixels: F64, depths_m: F64, link_px: float, link_depth_m: float) -> npt.NDArray[np.int64]:
    """Connected components of points (N, 2) with depths (N,): linked within `link_px` and `link_depth_m`.
    Returns a group label per point (0..G-1)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree  # type: ignore[import-untyped]

    n = len(pixels)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    pairs = cKDTree(pixels).query_pairs(link_px, output_type="ndarray")
    if len(pairs):
        pairs = pairs[np.abs(depths_m[pairs[:, 0]] - depths_m[pairs[:, 1]]) <= link_depth_m]
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n)) if len(pairs) else \
        coo_matrix((n, n))  # fmt: skip
    _, labels = connected_components(graph, directed=False)
    return labels.astype(np.int64)


def grow_flags(moving: BoolArr, keypoints_px: F64, depths_m: F64, image_width: int, cfg: FlagRegionConfig) -> BoolArr:
    """(N,) `moving` plus every keypoint with depth inside a region spanned by a group of flagged keypoints."""
    scale = image_width / 640.0
    seeds = np.flatnonzero(moving & (depths_m > 0))
    if len(seeds) < cfg.min_flags:
        return moving
    px = np.asarray(keypoints_px, dtype=np.float64)
    labels = flag_groups(px[seeds], depths_m[seeds], cfg.link_px * scale, cfg.link_depth_m)
    out = moving.copy()
    has_depth = depths_m > 0
    pad = cfg.pad_px * scale
    for g in np.flatnonzero(np.bincount(labels) >= cfg.min_flags):
        members = seeds[labels == g]
        lo, hi = px[members].min(axis=0) - pad, px[members].max(axis=0) + pad
        z = depths_m[members]
        inside = (
            has_depth & (px[:, 0] >= lo[0]) & (px[:, 0] <= hi[0]) & (px[:, 1] >= lo[1]) & (px[:, 1] <= hi[1])
            & (depths_m >= z.min() - cfg.depth_margin_m) & (depths_m <= z.max() + cfg.depth_margin_m)
        )  # fmt: skip
        out |= inside
    return out
