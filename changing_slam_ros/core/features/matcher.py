"""Descriptor matching: vectorised projection search and brute-force matching with a ratio test.

Hamming distances use `np.bitwise_count` on XOR-ed 32-byte ORB descriptors. Thresholds follow
ORB-SLAM (TH_HIGH = 100, TH_LOW = 50, ratio 0.8 for projection and 0.75 for brute force).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.features.frame import Frame

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

TH_HIGH = 100
TH_LOW = 50


def hamming(a: npt.NDArray[np.uint8], b: npt.NDArray[np.uint8]) -> I64:
    """Hamming distance between descriptors a (..., 32) and b (..., 32), broadcast; result (...)."""
    if _as_words(a) and _as_words(b):  # the same bit count over 64-bit words: a quarter of the elements
        a, b = a.view(np.uint64), b.view(np.uint64)
    return np.bitwise_count(np.bitwise_xor(a, b)).sum(axis=-1, dtype=np.int64)


def _as_words(d: npt.NDArray[np.uint8]) -> bool:
    """Whether the bytes of `d`'s last axis can be viewed as 64-bit words (contiguous, whole words)."""
    return (d.dtype == np.uint8 and d.ndim >= 1 and d.shape[-1] % 8 == 0 and d.strides[-1] == 1
            and all(s % 8 == 0 for s in d.strides[:-1]))


@dataclass(frozen=True)
class ProjectionQuery:
    """Map points to look for, M rows: world positions (M, 3), descriptors (M, 32), ids (M,),
    mean viewing directions (M, 3), scale-invariance distances (M,) min / max, metres."""

    positions_w: F64
    descriptors: npt.NDArray[np.uint8]
    ids: I64
    normals: F64
    min_dist: F64
    max_dist: F64


@dataclass(frozen=True)
class ProjectionResult:
    """Matches found: keypoint indices (K,), query rows (K,), Hamming distances (K,);
    `n_visible`: how many query points projected inside the image (for found ratios);
    `visible_rows`: their query rows."""

    kp_indices: I64
    rows: I64
    distances: I64
    visible_rows: I64


def search_by_projection(
    frame: Frame,
    T_cam_world: F64,
    query: ProjectionQuery,
    radius_px: float,
    level_scales: F64,
    max_distance: int = TH_HIGH,
    ratio: float = 0.8,
    skip_matched: bool = True,
    bf_m_px: float = 0.0,
    k_nearest: int = 8,
) -> ProjectionResult:
    """Project map points into `frame` with pose `T_cam_world` (4, 4) and match them to nearby keypoints.

    Steps (ORB-SLAM `SearchByProjection`, vectorised): 1. transform and keep points in front, inside
    the image, within their scale-invariance range and seen at < 60 deg from their mean direction;
    2. predict the pyramid level from the distance; 3. take the k nearest keypoints within
    `radius_px * scale[level]`, at levels predicted-1..predicted(+1); 4. for stereo keypoints the
    projected right coordinate `u - bf_m_px / z` must agree too (skipped when `bf_m_px` is 0); 5. best Hamming distance <= `max_distance` and
    < `ratio` * second best; 6. one map point per keypoint (the closest descriptor wins).
    """
    empty = np.zeros(0, np.int64)
    cam = frame.camera
    feats = frame.features
    if len(query.ids) == 0 or len(feats) == 0:
        return ProjectionResult(empty, empty, empty, empty)
    R, t = T_cam_world[:3, :3], T_cam_world[:3, 3]
    pc = query.positions_w @ R.T + t
    z = pc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = cam.fx * pc[:, 0] / z + cam.cx
        v = cam.fy * pc[:, 1] / z + cam.cy
    centre_w = -R.T @ t
    view = query.positions_w - centre_w
    dist = np.sqrt(np.add.reduce(view * view, axis=1))  # np.linalg.norm(view, axis=1) without its wrapper
    cos_view = np.einsum("ij,ij->i", view, query.normals) / np.maximum(dist, 1e-9)
    ok = (
        (z > 0.05) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
        & (dist >= 0.8 * query.min_dist) & (dist <= 1.2 * query.max_dist) & (cos_view >= 0.5)
    )
    rows = np.flatnonzero(ok)
    m = len(rows)
    if m == 0:
        return ProjectionResult(empty, empty, empty, empty)
    n_levels = len(level_scales)
    log_scale = np.log(level_scales[1]) if n_levels > 1 else 1.0
    level = np.ceil(np.log(query.max_dist[rows] / dist[rows]) / log_scale).astype(np.int64)
    level = np.minimum(np.maximum(level, 0), n_levels - 1)
    radius = radius_px * level_scales[level]
    u_rows = u[rows]
    uv = np.stack([u_rows, v[rows]], axis=1)
    k = min(k_nearest, len(feats))
    dd, nn = frame.kd_tree().query(uv, k=k, distance_upper_bound=float(radius.max()))
    dd = dd.reshape(m, k)
    nn = nn.reshape(m, k)
    valid = dd <= radius[:, None]  # missing neighbours come back at distance inf
    nn_safe = np.where(valid, nn, 0)
    # 3.-4. The level, "already matched" and stereo tests on the in-radius candidates only (row vr, column vc).
    vr, vc = np.nonzero(valid)
    kp = nn[vr, vc]
    lv = level[vr]
    kp_level = feats.octaves[kp]
    good = (kp_level >= lv - 1) & (kp_level <= lv + 1)
    if skip_matched:
        good &= frame.point_ids[kp] < 0
    if bf_m_px > 0:
        ur_kp = feats.u_right[kp]
        ur_proj = (u_rows - bf_m_px / z[rows])[vr]
        good &= (ur_kp < 0) | (np.abs(ur_proj - ur_kp) <= radius[vr])
    vr, vc, kp = vr[good], vc[good], kp[good]
    # 5. Descriptor distances of the candidates left (most of the k are out of radius or level).
    dist_h = np.full((m, k), 1 << 20, dtype=np.int64)
    dist_h[vr, vc] = hamming(query.descriptors[rows[vr]], feats.descriptors[kp])
    # Best and second best per row in the order of a stable sort: the first minimum, then the first minimum
    # of the other columns.
    ar = np.arange(m)
    best_col = dist_h.argmin(axis=1)
    best = dist_h[ar, best_col]
    best_kp = nn_safe[ar, best_col]
    if k > 1:
        dist_h[ar, best_col] = 1 << 40
        second_col = dist_h.argmin(axis=1)
        second = dist_h[ar, second_col]
        second_kp = nn_safe[ar, second_col]
    else:
        second = np.full(m, 1 << 20)
        second_kp = best_kp
    same_level = feats.octaves[best_kp] == feats.octaves[second_kp]
    accept = (best <= max_distance) & ~(same_level & (best > ratio * second))
    sel = np.flatnonzero(accept)
    kp_idx, q_rows, dists = best_kp[sel], rows[sel], best[sel]
    # 6. One map point per keypoint: keep the lowest distance.
    order2 = np.lexsort((dists, kp_idx))
    kp_sorted = kp_idx[order2]
    first = np.ones(len(order2), bool)
    first[1:] = kp_sorted[1:] != kp_sorted[:-1]
    keep = order2[first]
    return ProjectionResult(kp_idx[keep], q_rows[keep], dists[keep], rows)


def match_brute_force(
    desc_a: npt.NDArray[np.uint8],
    desc_b: npt.NDArray[np.uint8],
    ratio: float = 0.75,
    max_distance: int = TH_LOW * 2,
) -> tuple[I64, I64]:
    """Mutual-best matches between descriptor sets a (Na, 32) and b (Nb, 32) with Lowe's ratio test.

    Returns (indices into a, indices into b), each (K,).
    """
    empty = np.zeros(0, np.int64)
    if len(desc_a) < 2 or len(desc_b) < 2:
        return empty, empty
    bf = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=False)
    knn = bf.knnMatch(desc_a, desc_b, k=2)
    ia, ib = [], []
    for pair in knn:
        if len(pair) < 2:
            continue
        m, n = pair
        if m.distance <= max_distance and m.distance < ratio * n.distance:
            ia.append(m.queryIdx)
            ib.append(m.trainIdx)
    a = np.array(ia, dtype=np.int64)
    b = np.array(ib, dtype=np.int64)
    if len(b) == 0:
        return empty, empty
    # Keep one match per b (the first, i.e. the better by construction of the ratio test is not
    # guaranteed, so prefer the lower distance).
    d = hamming(desc_a[a], desc_b[b])
    order = np.lexsort((d, b))
    first = np.ones(len(order), bool)
    first[1:] = b[order][1:] != b[order][:-1]
    keep = order[first]
    return a[keep], b[keep]
