"""Geometric verification of a place-recognition candidate with depth (RGB-D): the relative SE(3) pose of two views.

Steps (the RGB-D counterpart of ORB-SLAM's Sim3 solver + guided search, scale fixed because depth is metric):
1. match descriptors between the two views, both keypoints having valid depth (brute force, Lowe ratio test);
2. RANSAC over 3-point samples: Horn/Umeyama (Kabsch) SE(3) from the 3D-3D pairs, all hypotheses solved and
   scored at once; a pair is an inlier when it reprojects within `inlier_px` (times the keypoint's pyramid
   scale) in *both* images;
3. refine: re-estimate from all inliers (depth-weighted Kabsch), then search by projection for more matches
   (keypoints of b projected into a, nearest descriptor within a radius) and re-estimate once more;
4. accept only with `min_inliers` inliers spread over the image: they must fall in at least
   `min_inlier_cells` cells of a `spread_grid` grid in *both* views. A candidate from another place yields few
   consistent pairs and is rejected; a few dozen pairs bunched on one patch (a repeated wallpaper motif, one
   printed object) do not describe a place and are rejected too.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares
from scipy.spatial import cKDTree

from changing_slam_ros.core.geometry.camera import CameraIntrinsics

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


class FeatureView(Protocol):
    """What verification needs of a keyframe (or a frame): `core.keyframe.Keyframe` satisfies it."""

    keypoints_px: npt.NDArray[np.float32]
    octaves: npt.NDArray[np.int8]
    descriptors: npt.NDArray[np.uint8]
    depths_m: npt.NDArray[np.float32]
    camera: CameraIntrinsics


@dataclass(frozen=True)
class VerificationConfig:
    """YAML section `loop.verification`. Pixel thresholds are at pyramid level 0."""

    ratio: float = 0.8  # Lowe ratio test of the brute-force match
    max_hamming: int = 80  # ORB descriptor distance accepted in brute-force matching (bits of 256)
    projection_max_hamming: int = 50  # stricter distance for matches found by projection (ORB-SLAM TH_LOW)
    projection_radius_px: float = 8.0
    ransac_iterations: int = 300
    inlier_px: float = 3.0  # ~ sqrt(chi2(2 dof, 95 %)=5.99) px at level 0, scaled by 1.2**octave
    scale_factor: float = 1.2  # pyramid scale, for the per-octave threshold
    min_ransac_inliers: int = 15
    min_inliers: int = 40  # ORB-SLAM accepts a loop with >= 40 matched points
    spread_grid: tuple[int, int] = (8, 6)  # (columns, rows) of the image grid for the spread test
    min_inlier_cells: int = 8  # inliers must occupy at least this many grid cells in each view (1/6 of 8 x 6)
    min_depth_m: float = 0.1
    max_depth_m: float = 8.0
    seed: int = 0


@dataclass(frozen=True)
class Verification:
    """An accepted candidate: `T_a_b` (4, 4) maps points from camera b's frame into camera a's
    (so T_world_b = T_world_a @ T_a_b); `matches` (M, 2) int64 inlier keypoint indices (in a, in b);
    `rmse_px` the RMS reprojection error in a of the inliers."""

    T_a_b: F64
    matches: I64
    rmse_px: float

    @property
    def num_inliers(self) -> int:
        return len(self.matches)


def verify(
    a: FeatureView,
    b: FeatureView,
    config: VerificationConfig = VerificationConfig(),
    mask_a: npt.NDArray[np.bool_] | None = None,
    mask_b: npt.NDArray[np.bool_] | None = None,
) -> Verification | None:
    """Estimate T_a_b between two RGB-D views, or None when they do not show the same place.

    `mask_a` / `mask_b` (N,) bool exclude keypoints (dynamic, inactive objects) from matching.
    """
    pa, va = _points(a, config, mask_a)
    pb, vb = _points(b, config, mask_b)
    if va.sum() < 3 or vb.sum() < 3:
        return None
    matches = match_descriptors(a.descriptors, b.descriptors, va, vb, config.ratio, config.max_hamming)
    if len(matches) < config.min_ransac_inliers:
        return None
    rng = np.random.default_rng(config.seed)
    T, inl = _ransac(a, b, pa, pb, matches, config, rng)
    if T is None or inl.sum() < config.min_ransac_inliers:
        return None
    matches = matches[inl]
    T = kabsch(pa[matches[:, 0]], pb[matches[:, 1]], 1.0 / pa[matches[:, 0], 2] ** 2)
    # 3. guided search by projection, then a final estimate over everything consistent with T
    matches = _merge(matches, _search_by_projection(a, b, pb, va, vb, T, matches, config))
    for _ in range(2):
        keep = _inliers(a, b, pa, pb, matches, T[None], config)[0]
        matches = matches[keep]
        if len(matches) < 3:
            return None
        T = kabsch(pa[matches[:, 0]], pb[matches[:, 1]], 1.0 / pa[matches[:, 0], 2] ** 2)
    keep = _inliers(a, b, pa, pb, matches, T[None], config)[0]
    matches = matches[keep]
    if len(matches) < config.min_inliers:
        return None
    # 4. 3D-3D alignment trusts depth, whose noise grows with z^2; finish on the symmetric reprojection error
    T = refine_reprojection(a, b, pa, pb, matches, T, config)
    keep = _inliers(a, b, pa, pb, matches, T[None], config)[0]
    matches = matches[keep]
    if len(matches) < config.min_inliers:
        return None
    if min(inlier_cells(a, matches[:, 0], config.spread_grid), inlier_cells(b, matches[:, 1], config.spread_grid)) \
            < config.min_inlier_cells:
        return None
    pred = a.camera.project(_apply(T, pb[matches[:, 1]]))
    rmse = float(np.sqrt(np.mean(np.sum((pred - a.keypoints_px[matches[:, 0]]) ** 2, axis=1))))
    return Verification(T, matches.astype(np.int64), rmse)


def inlier_cells(view: FeatureView, indices: I64, grid: tuple[int, int]) -> int:
    """How many cells of a (columns, rows) grid over the image the keypoints `indices` of `view` occupy."""
    cols, rows = grid
    kp = np.asarray(view.keypoints_px, np.float64)[np.asarray(indices, np.int64)]
    cx = np.clip((kp[:, 0] * cols / view.camera.width).astype(np.int64), 0, cols - 1)
    cy = np.clip((kp[:, 1] * rows / view.camera.height).astype(np.int64), 0, rows - 1)
    return int(len(np.unique(cy * cols + cx)))


def match_descriptors(
    desc_a: npt.NDArray[np.uint8],
    desc_b: npt.NDArray[np.uint8],
    valid_a: npt.NDArray[np.bool_],
    valid_b: npt.NDArray[np.bool_],
    ratio: float,
    max_hamming: int,
) -> I64:
    """Brute-force Hamming matches a -> b among valid keypoints with Lowe's ratio test, one-to-one.

    Returns (M, 2) int64 indices into the full arrays (in a, in b)."""
    ia = np.nonzero(valid_a)[0]
    ib = np.nonzero(valid_b)[0]
    if len(ia) == 0 or len(ib) < 2:
        return np.zeros((0, 2), np.int64)
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
    knn = matcher.knnMatch(np.ascontiguousarray(desc_a[ia]), np.ascontiguousarray(desc_b[ib]), k=2)
    best: dict[int, tuple[int, float]] = {}  # index in b -> (index in a, distance), to keep it one-to-one
    for pair in knn:
        if len(pair) < 2:
            continue
        m, n = pair
        if m.distance > max_hamming or m.distance >= ratio * n.distance:
            continue
        j = int(ib[m.trainIdx])
        if j not in best or m.distance < best[j][1]:
            best[j] = (int(ia[m.queryIdx]), m.distance)
    if not best:
        return np.zeros((0, 2), np.int64)
    out = np.array([(i, j) for j, (i, _) in best.items()], np.int64)
    return out[np.argsort(out[:, 0], kind="stable")]


def kabsch(p_a: F64, p_b: F64, weights: F64 | None = None) -> F64:
    """Rigid T_a_b (4, 4) minimising sum w |p_a - (R p_b + t)|^2 over points (N, 3) (Horn / Umeyama, no scale)."""
    w = np.ones(len(p_a)) if weights is None else np.asarray(weights, np.float64)
    w = w / w.sum()
    ca = w @ p_a
    cb = w @ p_b
    cov = ((p_b - cb) * w[:, None]).T @ (p_a - ca)  # (3, 3) sum w (b - cb)(a - ca)^T
    u, _, vt = np.linalg.svd(cov)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    t = np.eye(4)
    t[:3, :3] = r
    t[:3, 3] = ca - r @ cb
    return t


def refine_reprojection(
    a: FeatureView, b: FeatureView, pa: F64, pb: F64, matches: I64, T_a_b: F64, config: VerificationConfig
) -> F64:
    """Gauss-Newton (scipy LM-style trust region, Huber) on the reprojection error of the matched points in
    both images, each residual divided by its keypoint's pyramid scale; starts from `T_a_b` (4, 4)."""
    qa, qb = pa[matches[:, 0]], pb[matches[:, 1]]
    ka = np.asarray(a.keypoints_px, np.float64)[matches[:, 0]]
    kb = np.asarray(b.keypoints_px, np.float64)[matches[:, 1]]
    sa = config.scale_factor ** np.asarray(a.octaves, np.float64)[matches[:, 0]]
    sb = config.scale_factor ** np.asarray(b.octaves, np.float64)[matches[:, 1]]
    r0 = T_a_b[:3, :3]
    t0 = T_a_b[:3, 3]

    def residuals(x: F64) -> F64:
        r = cv2.Rodrigues(x[:3])[0] @ r0
        t = x[3:] + t0
        b_in_a = qb @ r.T + t
        a_in_b = (qa - t) @ r
        za = np.maximum(b_in_a[:, 2], 1e-3)
        zb = np.maximum(a_in_b[:, 2], 1e-3)
        ea = np.stack([a.camera.fx * b_in_a[:, 0] / za + a.camera.cx - ka[:, 0],
                       a.camera.fy * b_in_a[:, 1] / za + a.camera.cy - ka[:, 1]], axis=1) / sa[:, None]
        eb = np.stack([b.camera.fx * a_in_b[:, 0] / zb + b.camera.cx - kb[:, 0],
                       b.camera.fy * a_in_b[:, 1] / zb + b.camera.cy - kb[:, 1]], axis=1) / sb[:, None]
        return np.concatenate([ea.ravel(), eb.ravel()])

    sol = least_squares(residuals, np.zeros(6), loss="huber", f_scale=config.inlier_px, max_nfev=50)
    out = np.eye(4)
    out[:3, :3] = cv2.Rodrigues(sol.x[:3])[0] @ r0
    out[:3, 3] = sol.x[3:] + t0
    return out


def _kabsch_batch(p_a: F64, p_b: F64) -> F64:
    """Kabsch for H samples at once: p_a, p_b (H, S, 3) -> T_a_b (H, 4, 4)."""
    ca = p_a.mean(axis=1, keepdims=True)
    cb = p_b.mean(axis=1, keepdims=True)
    cov = np.einsum("hsi,hsj->hij", p_b - cb, p_a - ca)
    u, _, vt = np.linalg.svd(cov)
    v = np.transpose(vt, (0, 2, 1))
    ut = np.transpose(u, (0, 2, 1))
    d = np.sign(np.linalg.det(v @ ut))
    diag = np.tile(np.eye(3), (len(p_a), 1, 1))
    diag[:, 2, 2] = d
    r = v @ diag @ ut
    t = np.tile(np.eye(4), (len(p_a), 1, 1))
    t[:, :3, :3] = r
    t[:, :3, 3] = ca[:, 0] - np.einsum("hij,hj->hi", r, cb[:, 0])
    return t


def _points(v: FeatureView, config: VerificationConfig, mask: npt.NDArray[np.bool_] | None) -> tuple[F64, npt.NDArray[np.bool_]]:
    depth = np.asarray(v.depths_m, np.float64)
    valid = (depth >= config.min_depth_m) & (depth <= config.max_depth_m)
    if mask is not None:
        valid &= np.asarray(mask, bool)
    pts = v.camera.backproject(np.asarray(v.keypoints_px, np.float64), depth)
    return pts, valid


def _apply(T: F64, p: F64) -> F64:
    return p @ T[:3, :3].T + T[:3, 3]


def _inliers(
    a: FeatureView, b: FeatureView, pa: F64, pb: F64, matches: I64, Ts: F64, config: VerificationConfig
) -> npt.NDArray[np.bool_]:
    """Inlier flags (H, M) of matches under each hypothesis T_a_b in Ts (H, 4, 4): reprojection in both views."""
    qa, qb = pa[matches[:, 0]], pb[matches[:, 1]]
    ka = np.asarray(a.keypoints_px, np.float64)[matches[:, 0]]
    kb = np.asarray(b.keypoints_px, np.float64)[matches[:, 1]]
    th_a = (config.inlier_px * config.scale_factor ** np.asarray(a.octaves, np.float64)[matches[:, 0]]) ** 2
    th_b = (config.inlier_px * config.scale_factor ** np.asarray(b.octaves, np.float64)[matches[:, 1]]) ** 2
    r = Ts[:, :3, :3]
    t = Ts[:, :3, 3]
    b_in_a = np.matmul(qb[None], np.transpose(r, (0, 2, 1))) + t[:, None, :]  # (H, M, 3): R p + t
    a_in_b = np.matmul(qa[None] - t[:, None, :], r)  # R^T (p - t), row-vector form
    ok = (b_in_a[..., 2] > 1e-3) & (a_in_b[..., 2] > 1e-3)
    za = np.where(ok, b_in_a[..., 2], 1.0)
    zb = np.where(ok, a_in_b[..., 2], 1.0)
    cam_a, cam_b = a.camera, b.camera
    ea = (cam_a.fx * b_in_a[..., 0] / za + cam_a.cx - ka[:, 0]) ** 2 + (cam_a.fy * b_in_a[..., 1] / za + cam_a.cy - ka[:, 1]) ** 2
    eb = (cam_b.fx * a_in_b[..., 0] / zb + cam_b.cx - kb[:, 0]) ** 2 + (cam_b.fy * a_in_b[..., 1] / zb + cam_b.cy - kb[:, 1]) ** 2
    flags: npt.NDArray[np.bool_] = ok & (ea < th_a) & (eb < th_b)
    return flags


def _ransac(
    a: FeatureView, b: FeatureView, pa: F64, pb: F64, matches: I64, config: VerificationConfig, rng: np.random.Generator
) -> tuple[F64 | None, npt.NDArray[np.bool_]]:
    m = len(matches)
    h = config.ransac_iterations
    samples = np.argsort(rng.random((h, m)), axis=1)[:, :3]
    sa = pa[matches[samples, 0]]  # (H, 3, 3)
    sb = pb[matches[samples, 1]]
    # drop degenerate samples: nearly collinear or too close points give no well-defined rotation
    spread = np.linalg.norm(np.cross(sb[:, 1] - sb[:, 0], sb[:, 2] - sb[:, 0]), axis=1)
    good = spread > 1e-4
    if not good.any():
        return None, np.zeros(m, bool)
    Ts = _kabsch_batch(sa[good], sb[good])
    flags = _inliers(a, b, pa, pb, matches, Ts, config)
    best = int(flags.sum(axis=1).argmax())
    return Ts[best], flags[best]


def _search_by_projection(
    a: FeatureView,
    b: FeatureView,
    pb: F64,
    va: npt.NDArray[np.bool_],
    vb: npt.NDArray[np.bool_],
    T_a_b: F64,
    matches: I64,
    config: VerificationConfig,
) -> I64:
    """New (i_a, j_b) pairs: unmatched keypoints of b with depth projected into a, nearest unmatched
    keypoint of a within the radius whose descriptor is within `projection_max_hamming`."""
    free_a = va.copy()
    free_a[matches[:, 0]] = False
    free_b = vb.copy()
    free_b[matches[:, 1]] = False
    jb = np.nonzero(free_b)[0]
    ia = np.nonzero(free_a)[0]
    if len(jb) == 0 or len(ia) == 0:
        return np.zeros((0, 2), np.int64)
    q = _apply(T_a_b, pb[jb])
    front = q[:, 2] > 1e-3
    jb, q = jb[front], q[front]
    if len(jb) == 0:
        return np.zeros((0, 2), np.int64)
    uv = a.camera.project(q)
    ka = np.asarray(a.keypoints_px, np.float64)[ia]
    # candidate pairs (projected b, keypoint of a) within the radius, from a k-d tree over a's keypoints
    neighbours = cKDTree(ka).query_ball_point(uv, config.projection_radius_px)
    counts = np.fromiter((len(n) for n in neighbours), np.int64, len(neighbours))
    if counts.sum() == 0:
        return np.zeros((0, 2), np.int64)
    rows = np.repeat(np.arange(len(uv)), counts)
    cols = np.fromiter((c for n in neighbours for c in n), np.int64, int(counts.sum()))
    da = a.descriptors[ia[cols]].view(np.uint64)
    db = b.descriptors[jb[rows]].view(np.uint64)
    ham = np.bitwise_count(da ^ db).sum(axis=1, dtype=np.int32)
    keep = ham <= config.projection_max_hamming
    rows, cols, ham = rows[keep], cols[keep], ham[keep]
    if len(rows) == 0:
        return np.zeros((0, 2), np.int64)
    order = np.lexsort((ham, rows))  # per projected point, the closest descriptor first
    rows, cols, ham = rows[order], cols[order], ham[order]
    first = np.r_[True, rows[1:] != rows[:-1]]
    pairs = np.stack([ia[cols[first]], jb[rows[first]]], axis=1).astype(np.int64)
    # one-to-one on a: where two projected points chose the same keypoint, the closer descriptor keeps it
    by_distance = np.argsort(ham[first], kind="stable")
    _, best = np.unique(pairs[by_distance, 0], return_index=True)
    out: I64 = pairs[np.sort(by_distance[best])]
    return out


def _merge(m1: I64, m2: I64) -> I64:
    if len(m2) == 0:
        return m1
    return np.concatenate([m1, m2], axis=0)
