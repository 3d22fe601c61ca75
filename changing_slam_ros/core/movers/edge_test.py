"""Two-frame point-correlation segmentation in closed form: a vectorised test of each edge's rigidity.

With two frames, eq. 5 of Dai et al. 2021 (`point_correlation`) has a near closed-form answer: at the
optimum a point sits midway between its two world-frame measurements, so an edge between points i and j
leaves each frame a residual of half the change of their relative vector. The paper removes an edge when
both residuals are outliers (chi2 > `outlier_chi2` each); here that is tested directly on

    e_ij = (p_i - p_j) - R (q_i - q_j),   chi2_ij = e_ij^T S_ij^-1 e_ij > 2 * outlier_chi2

with p, q the back-projected keypoints of the current and the earlier frame (camera frames), R the
rotation between the two cameras and S_ij the sum of the four points' covariances (pixel noise and the
depth model of `SegmentationConfig`). Only R enters: a pose error moves all points rigidly. The graph is
the 2D Delaunay triangulation of the current keypoints (cheaper than the paper's 3D tetrahedralisation);
triangle support and the static component by volume are as in `segment`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import scipy.sparse as sp  # type: ignore[import-untyped]
from scipy.sparse.csgraph import connected_components  # type: ignore[import-untyped]
from scipy.spatial import Delaunay, QhullError, cKDTree  # type: ignore[import-untyped]

from changing_slam_ros.core.features.matcher import hamming
from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.movers.correlation_window import SegmentationConfig
from changing_slam_ros.core.movers.delaunay_graph import hull_volume_m3

F64 = npt.NDArray[np.float64]
CHI2_3_MEDIAN = 2.366  # median of chi2 with 3 degrees of freedom
MIN_EDGES_FOR_NOISE = 30  # fewer edges: the model's noise as it is
I64 = npt.NDArray[np.int64]
BoolArr = npt.NDArray[np.bool_]
U8 = npt.NDArray[np.uint8]


@dataclass(frozen=True)
class EdgeTestResult:
    """Outcome for M matched points: `moving` (M,) on an object target; `edges` (E, 2) of the 2D Delaunay
    graph with `consistent` (E,); `n_targets` the number of object targets."""

    moving: BoolArr
    edges: I64
    consistent: BoolArr
    n_targets: int


def match_nearby(
    px_now: F64, desc_now: U8, px_past: F64, desc_past: U8, predicted_px: F64,
    radius_px: float, max_hamming: int, k: int = 24,
) -> tuple[I64, I64]:
    """Mutual best descriptor matches between the current keypoints and an earlier frame's (indices q, t).

    Each current keypoint is compared with the `k` earlier keypoints nearest to `predicted_px` (N, 2), its
    expected position in the earlier image (NaN: compare around its own position), within `radius_px`; a
    pair is kept when the earlier keypoint is the current one's best candidate, no other current keypoint
    chose it with a smaller distance, and the Hamming distance is <= `max_hamming`. The cost is N * k
    descriptor distances instead of the N * N of brute force.
    """
    empty = np.zeros(0, np.int64)
    n, m = len(px_now), len(px_past)
    if n == 0 or m == 0:
        return empty, empty
    centre = np.where(np.isfinite(predicted_px), predicted_px, px_now)
    k = min(k, m)
    dist_px, nn = cKDTree(px_past).query(centre, k=k, distance_upper_bound=radius_px)
    dist_px, nn = dist_px.reshape(n, k), nn.reshape(n, k)
    found = np.isfinite(dist_px)
    # Hamming distances of all (n, k) candidates at once; a missing neighbour (index m) reads row 0 and is
    # then set out of reach.
    d = hamming(desc_now[:, None, :], desc_past[np.where(found, nn, 0)])
    d[~found] = 1 << 20
    col = d.argmin(axis=1)
    rows = np.arange(n)
    best_d, best = d[rows, col], nn[rows, col]
    ok = best_d <= max_hamming
    rows, best, best_d = rows[ok], best[ok], best_d[ok]
    if rows.size == 0:  # no candidate within max_hamming (a textureless or fully changed view)
        return empty, empty
    # Mutual best: among the current keypoints choosing the same earlier one, the closest descriptor wins.
    order = np.lexsort((best_d, best))
    first = np.r_[True, best[order][1:] != best[order][:-1]]
    return rows[order][first].astype(np.int64), best[order][first].astype(np.int64)


def _point_covariances(points_cam: F64, camera: CameraIntrinsics, cfg: SegmentationConfig) -> F64:
    """(M, 3, 3) covariance of back-projected keypoints (M, 3): pixel noise `sigma_px` and depth noise
    `depth_sigma_coeff_per_m` z^2 (at least `depth_sigma_min_m`), through x = (u - cx) z / fx."""
    x, y, z = points_cam[:, 0], points_cam[:, 1], points_cam[:, 2]
    var_z = np.maximum(cfg.depth_sigma_coeff_per_m * z * z, cfg.depth_sigma_min_m) ** 2
    var_u = (cfg.sigma_px * z / camera.fx) ** 2
    var_v = (cfg.sigma_px * z / camera.fy) ** 2
    ax, ay = x / z, y / z  # d x / d z and d y / d z
    cov = np.empty((len(z), 3, 3))
    cov[:, 0, 0] = var_u + ax * ax * var_z
    cov[:, 1, 1] = var_v + ay * ay * var_z
    cov[:, 2, 2] = var_z
    cov[:, 0, 1] = cov[:, 1, 0] = ax * ay * var_z
    cov[:, 0, 2] = cov[:, 2, 0] = ax * var_z
    cov[:, 1, 2] = cov[:, 2, 1] = ay * var_z
    return cov


def _triangulation(px: F64) -> npt.NDArray[np.int64] | None:
    try:
        return np.asarray(Delaunay(px).simplices, dtype=np.int64)
    except (QhullError, ValueError):
        return None


def edge_test_segment(
    pixels: F64, depths_m: F64, T_world_cam: F64, camera: CameraIntrinsics, cfg: SegmentationConfig,
    min_outlier_neighbours: int = 2,
) -> EdgeTestResult:
    """Segment M points matched in two frames: pixels (2, M, 2) and depths (2, M) (earlier frame first, all
    depths > 0), camera-to-world poses (2, 4, 4). Moving: the points of a connected rigid group other than
    the static one (largest `cfg.static_volume`) with at least `cfg.min_target_points` points, and the
    outliers of the static group's fitted motion (same chi2 bound) with `min_outlier_neighbours` outlier
    neighbours in the graph (0 = that second step off)."""
    m = pixels.shape[1]
    none = EdgeTestResult(np.zeros(m, bool), np.empty((0, 2), np.int64), np.empty(0, bool), 0)
    if m < 4:
        return none
    simplices = _triangulation(pixels[1])
    if simplices is None or len(simplices) == 0:
        return none
    q = camera.backproject(pixels[0], depths_m[0])
    p = camera.backproject(pixels[1], depths_m[1])
    R = T_world_cam[1, :3, :3].T @ T_world_cam[0, :3, :3]  # earlier camera -> current camera
    # Edges of the triangulation, each coded i * m + j (i < j); `tri_edges` the three sides of each triangle.
    tri = np.sort(simplices, axis=1)
    sides = np.stack([tri[:, 0] * m + tri[:, 1], tri[:, 0] * m + tri[:, 2], tri[:, 1] * m + tri[:, 2]], axis=1)
    codes, inverse = np.unique(sides, return_inverse=True)
    tri_edges = inverse.reshape(-1, 3)
    i, j = codes // m, codes % m
    e = (p[i] - p[j]) - (q[i] - q[j]) @ R.T
    cov_p, cov_q = _point_covariances(p, camera, cfg), _point_covariances(q, camera, cfg)
    cov = cov_p[i] + cov_p[j] + R @ (cov_q[i] + cov_q[j]) @ R.T
    chi2 = np.einsum("ea,ea->e", e, np.linalg.solve(cov, e[:, :, None])[:, :, 0])
    if cfg.noise_from_edges and len(chi2) >= MIN_EDGES_FOR_NOISE:
        scale = max(1.0, float(np.median(chi2)) / CHI2_3_MEDIAN)  # the sensor's noise against the model's
        chi2 = chi2 / scale
        cov_p, cov_q = cov_p * scale, cov_q * scale
    consistent = chi2 <= 2.0 * cfg.outlier_chi2
    if cfg.min_supporting_triangles > 0:  # an edge of the 2D graph lies on at most two triangles
        on = np.bincount(tri_edges.ravel(), minlength=len(codes))
        good = np.all(consistent[tri_edges], axis=1)
        support = np.bincount(tri_edges[good].ravel(), minlength=len(codes))
        consistent &= support >= np.minimum(on, cfg.min_supporting_triangles)
    kept = np.flatnonzero(consistent)
    adjacency = sp.coo_matrix((np.ones(len(kept)), (i[kept], j[kept])), shape=(m, m))
    n_comp, comp = connected_components(adjacency, directed=False)
    sizes = np.bincount(comp, minlength=n_comp)
    candidates = np.flatnonzero(sizes >= max(4, cfg.min_target_points))
    edges = np.stack([i, j], axis=1)
    if len(candidates) == 0:
        return EdgeTestResult(np.zeros(m, bool), edges, consistent, 0)
    static = int(candidates[0])
    if len(candidates) > 1:
        world = p @ T_world_cam[1, :3, :3].T + T_world_cam[1, :3, 3]
        apex = T_world_cam[:, :3, 3] if cfg.static_volume == "view_cone" else np.empty((0, 3))
        volumes = np.array([hull_volume_m3(np.vstack([world[comp == c], apex])) for c in candidates])
        static = int(candidates[np.lexsort((sizes[candidates], volumes))[-1]])
    targets = candidates[candidates != static]
    moving = np.isin(comp, targets)
    # Points that no rigid group holds (their edges all broke) are tested against the static scene's
    # motion instead: outliers of the relative pose fitted to the static component, with at least
    # `min_outlier_neighbours` graph neighbours outliers too (a wrong match is alone).
    fitted = _fit_rigid(q[comp == static], p[comp == static])
    if fitted is not None and min_outlier_neighbours > 0:
        R_f, t_f = fitted
        r = p - (q @ R_f.T + t_f)
        chi2_pt = np.einsum("ma,ma->m", r, np.linalg.solve(cov_p + R_f @ cov_q @ R_f.T, r[:, :, None])[:, :, 0])
        outlier = chi2_pt > 2.0 * cfg.outlier_chi2
        both = outlier[i] & outlier[j]
        n_out = np.bincount(i[both], minlength=m) + np.bincount(j[both], minlength=m)
        moving |= outlier & (n_out >= min_outlier_neighbours)
    return EdgeTestResult(moving, edges, consistent, len(targets))


def _fit_rigid(q: F64, p: F64) -> tuple[F64, F64] | None:
    """Least-squares rotation and translation with p ~ R q + t (Kabsch) for points (N, 3); None if N < 6."""
    if len(q) < 6:
        return None
    qc, pc = q.mean(axis=0), p.mean(axis=0)
    u, _, vt = np.linalg.svd((q - qc).T @ (p - pc))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    R = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return R, pc - R @ qc
