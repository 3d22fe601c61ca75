"""ORB features for RGB-D tracking: pyramid ORB spread over a grid, undistorted, with depth.

ORB-SLAM's RGB-D mode turns every keypoint with a valid depth into a "virtual stereo" observation:
the right-image coordinate is `u_r = u - bf / d`, with `bf` = baseline (m) * fx (px). The pose
optimiser and bundle adjustment then treat (u, v, u_r) exactly like a rectified stereo match.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.camera import CameraIntrinsics

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class FeatureConfig:
    """YAML section `features:`.

    - `n_features`: keypoints kept per frame after grid bucketing.
    - `scale_factor`, `n_levels`: ORB image pyramid.
    - `fast_threshold`: FAST corner threshold (intensity units); low values keep textureless areas covered.
    - `grid_cols`, `grid_rows`: bucketing grid; each cell keeps its strongest corners.
    - `oversample`: corners detected per kept keypoint before bucketing.
    - `min_depth_m`, `max_depth_m`: depth readings outside are treated as missing.
    - `bf_m_px`: virtual stereo baseline * fx (ORB-SLAM's `Stereo.bf`; 40 for a Kinect).
    - `close_depth_factor`: points closer than `close_depth_factor * bf / fx` metres are "close"
      (ORB-SLAM's `ThDepth`), trusted for translation.
    """

    n_features: int = 1000
    scale_factor: float = 1.2
    n_levels: int = 8
    fast_threshold: int = 12
    grid_cols: int = 16
    grid_rows: int = 12
    oversample: float = 2.0
    min_depth_m: float = 0.2
    max_depth_m: float = 6.0
    bf_m_px: float = 40.0
    close_depth_factor: float = 40.0

    def level_scales(self) -> F64:
        """Scale of each pyramid level (n_levels,): scale_factor ** level."""
        return np.power(self.scale_factor, np.arange(self.n_levels, dtype=np.float64))

    def level_sigma2(self) -> F64:
        """Keypoint position variance per level (n_levels,), px^2 at level 0 = 1."""
        return self.level_scales() ** 2


@dataclass
class Features:
    """Keypoints of one image, N rows.

    - `keypoints_px` (N, 2) undistorted pixels; `raw_px` (N, 2) as detected (distorted);
    - `octaves` (N,) int pyramid level; `angles_deg` (N,); `responses` (N,);
    - `descriptors` (N, 32) uint8; `depths_m` (N,) float64, 0 where missing;
    - `u_right` (N,) virtual-stereo right coordinate, -1 where depth is missing.
    """

    keypoints_px: F64
    raw_px: F64
    octaves: npt.NDArray[np.int64]
    angles_deg: F64
    responses: F64
    descriptors: npt.NDArray[np.uint8]
    depths_m: F64
    u_right: F64

    def __len__(self) -> int:
        return len(self.keypoints_px)

    def subset(self, mask: npt.NDArray[np.bool_]) -> "Features":
        """The rows where `mask` (N,) bool is True, in order (e.g. the keypoints tracking may use)."""
        m = np.asarray(mask, dtype=bool)
        return Features(
            self.keypoints_px[m], self.raw_px[m], self.octaves[m], self.angles_deg[m], self.responses[m],
            np.ascontiguousarray(self.descriptors[m]), self.depths_m[m], self.u_right[m],
        )


class OrbExtractor:
    """Detects bucketed ORB keypoints and looks up their depth. One instance per camera."""

    def __init__(self, config: FeatureConfig, camera: CameraIntrinsics) -> None:
        self.config = config
        self.camera = camera
        n_detect = int(config.n_features * config.oversample)
        self._orb = cv2.ORB_create(
            nfeatures=n_detect,
            scaleFactor=config.scale_factor,
            nlevels=config.n_levels,
            edgeThreshold=19,
            fastThreshold=config.fast_threshold,
            patchSize=31,
        )
        self._dist = np.asarray(camera.dist, dtype=np.float64)

    def extract(self, rgb: npt.NDArray[np.uint8], depth_m: npt.NDArray[np.float32]) -> Features:
        """Features of an RGB image (H, W, 3) uint8 with registered depth (H, W) metres."""
        gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY) if rgb.ndim == 3 else rgb
        kps, desc = self._orb.detectAndCompute(gray, None)
        if desc is None or len(kps) == 0:
            return _empty_features()
        # Positions through OpenCV's converter (float32, as KeyPoint stores them); the per-keypoint Python
        # attribute reads, the slow part, only for what bucketing needs (responses) and what it keeps.
        pts = cv2.KeyPoint_convert(kps).astype(np.float64).reshape(-1, 2)
        resp = np.array([k.response for k in kps], dtype=np.float64)
        keep = self._bucket(pts, resp, gray.shape[1], gray.shape[0])
        kept = [kps[i] for i in keep.tolist()]
        octv = np.array([k.octave for k in kept], dtype=np.int64)
        ang = np.array([k.angle for k in kept], dtype=np.float64)
        pts, resp, desc = pts[keep], resp[keep], desc[keep]
        und = self._undistort(pts)
        depths = self._lookup_depth(pts, depth_m)
        u_right = np.where(depths > 0, und[:, 0] - self.config.bf_m_px / np.maximum(depths, 1e-9), -1.0)
        return Features(und, pts, octv, ang, resp, np.ascontiguousarray(desc), depths, u_right)

    def _bucket(self, pts: F64, resp: F64, width: int, height: int) -> npt.NDArray[np.intp]:
        """Indices of the strongest corners per grid cell, at most `n_features` overall."""
        cfg = self.config
        n_cells = cfg.grid_cols * cfg.grid_rows
        cx = np.minimum((pts[:, 0] * cfg.grid_cols / width).astype(np.int64), cfg.grid_cols - 1)
        cy = np.minimum((pts[:, 1] * cfg.grid_rows / height).astype(np.int64), cfg.grid_rows - 1)
        cell = cy * cfg.grid_cols + cx
        order = np.lexsort((-resp, cell))
        sorted_cell = cell[order]
        starts = np.searchsorted(sorted_cell, np.arange(n_cells))
        rank = np.arange(len(order)) - starts[sorted_cell]
        # Raise the per-cell quota until the budget is met (empty cells give their share away).
        # The smallest quota >= n_features // n_cells whose capped counts reach the budget (at most the
        # fullest cell's count): all candidate quotas at once rather than one at a time.
        quota = max(1, cfg.n_features // n_cells)
        counts = np.bincount(cell, minlength=n_cells)
        top = int(counts.max())
        if top > quota:
            quotas = np.arange(quota, top + 1)
            kept = np.minimum(counts[None, :], quotas[:, None]).sum(axis=1)
            enough = np.flatnonzero(kept >= cfg.n_features)
            quota = int(quotas[enough[0]]) if len(enough) else top
        chosen = order[rank < quota]
        if len(chosen) > cfg.n_features:
            chosen = chosen[np.argsort(-resp[chosen], kind="stable")[: cfg.n_features]]
        return np.sort(chosen)

    def _undistort(self, pts: F64) -> F64:
        if not self.camera.has_distortion:
            return pts.copy()
        und = cv2.undistortPoints(pts.reshape(-1, 1, 2), self.camera.K, self._dist, P=self.camera.K)
        return und.reshape(-1, 2).astype(np.float64)

    def _lookup_depth(self, pts: F64, depth_m: npt.NDArray[np.float32]) -> F64:
        h, w = depth_m.shape[:2]
        u = np.clip(np.rint(pts[:, 0]).astype(np.int64), 0, w - 1)
        v = np.clip(np.rint(pts[:, 1]).astype(np.int64), 0, h - 1)
        d = depth_m[v, u].astype(np.float64)
        ok = np.isfinite(d) & (d >= self.config.min_depth_m) & (d <= self.config.max_depth_m)
        return np.where(ok, d, 0.0)


def _empty_features() -> Features:
    z2 = np.zeros((0, 2))
    z = np.zeros(0)
    return Features(z2, z2.copy(), np.zeros(0, np.int64), z, z.copy(), np.zeros((0, 32), np.uint8), z.copy(), z.copy())
