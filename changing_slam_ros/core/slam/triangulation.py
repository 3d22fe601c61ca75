"""Map points by two-view triangulation, for keypoints that have no usable depth.

RGB-D keypoints with a valid depth become map points directly (local mapping back-projects them);
keypoints on far walls, dark or reflective surfaces or beyond the sensor's range have none. Following
the idea of ORB-SLAM3's `LocalMapping::CreateNewMapPoints`, a new keyframe's depth-less keypoints are
matched with those of a covisible keyframe and triangulated (`triangulate_pair` has the steps).
The functions here are pure (arrays in, arrays out); `LocalMapper` turns the survivors into map points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.features.matcher import hamming
from changing_slam_ros.core.geometry.se3 import invert

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


@dataclass(frozen=True)
class TriangulationConfig:
    """YAML section `mapping: triangulation:`.

    - `enabled`: create points by triangulation at all (off by default: on 7-Scenes redkitchen it costs ATE).
    - `neighbours`: best covisible keyframes paired with each new keyframe.
    - `min_baseline_m`: skip pairs whose camera centres are closer (ORB-SLAM RGB-D: the virtual stereo baseline).
    - `max_hamming`, `ratio`: descriptor acceptance (ORB-SLAM TH_LOW = 50) and Lowe ratio to the second best.
    - `epipolar_chi2`: 1-dof chi2 bound on the squared point-to-epipolar-line distance, in sigma^2 units (3.84).
    - `reprojection_chi2`: 2-dof chi2 bound on the squared reprojection error per view, sigma^2 units (5.991).
    - `min_parallax_deg`: smallest angle between the two viewing rays.
    - `scale_ratio_factor`: tolerance on distance ratio vs octave scale ratio (ORB-SLAM 1.5 * scale factor).
    - `max_distance_m`: drop points farther than this from the new keyframe (0 = no limit).
    - `min_observations`: a triangulated point still seen by fewer keyframes two keyframes later is culled
      (it starts with two monocular observations; ORB-SLAM's threshold of 3 for that case).
    """

    enabled: bool = False
    neighbours: int = 5
    min_baseline_m: float = 0.05
    max_hamming: int = 50
    ratio: float = 0.7
    epipolar_chi2: float = 3.84
    reprojection_chi2: float = 5.991
    min_parallax_deg: float = 1.0
    scale_ratio_factor: float = 1.8
    max_distance_m: float = 20.0
    min_observations: int = 3


@dataclass(frozen=True)
class TwoView:
    """One keyframe's side of a pair: camera-to-world pose (4, 4), camera matrix (3, 3), and for the N
    candidate keypoints their undistorted pixels (N, 2), octaves (N,) and ORB descriptors (N, 32)."""

    T_world_cam: F64
    K: F64
    px: F64
    octaves: I64
    descriptors: npt.NDArray[np.uint8]


@dataclass(frozen=True)
class Triangulated:
    """Accepted points: rows into view 1's and view 2's candidates (M,) each, world positions (M, 3)."""

    rows1: I64
    rows2: I64
    points_w: F64


def fundamental_matrix(T_world_1: F64, T_world_2: F64, K1: F64, K2: F64) -> F64:
    """F21 (3, 3) with x2^T F21 x1 = 0 for pixels (homogeneous) of one world point in cameras 1 and 2."""
    T_21 = invert(T_world_2) @ T_world_1
    R, t = T_21[:3, :3], T_21[:3, 3]
    tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    F: F64 = np.linalg.inv(K2).T @ tx @ R @ np.linalg.inv(K1)
    return F


def epipolar_sq_distance(F21: F64, px1: F64, px2: F64) -> F64:
    """Squared pixel distance (N1, N2) of every keypoint of view 2 to the epipolar line of every keypoint of view 1."""
    x1 = np.column_stack([px1, np.ones(len(px1))])
    lines = x1 @ F21.T  # (N1, 3): a, b, c of the line in image 2
    num = lines[:, :2] @ px2.T + lines[:, 2:3]
    den = np.maximum((lines[:, :2] ** 2).sum(axis=1), 1e-12)
    d2: F64 = num**2 / den[:, None]
    return d2


def match_epipolar(v1: TwoView, v2: TwoView, sigma2: F64, cfg: TriangulationConfig) -> tuple[I64, I64]:
    """One-to-one descriptor matches between the candidates of two views that respect the epipolar
    constraint; returns (rows into v1, rows into v2)."""
    empty = np.zeros(0, np.int64)
    if len(v1.px) == 0 or len(v2.px) == 0:
        return empty, empty
    F21 = fundamental_matrix(v1.T_world_cam, v2.T_world_cam, v1.K, v2.K)
    ok = epipolar_sq_distance(F21, v1.px, v2.px) < cfg.epipolar_chi2 * sigma2[v2.octaves][None, :]
    big = 1 << 20
    dist = np.where(ok, hamming(v1.descriptors[:, None, :], v2.descriptors[None, :, :]), big)
    if dist.shape[1] == 1:
        best_j = np.zeros(len(dist), np.int64)
        best = dist[:, 0]
        second = np.full(len(dist), big)
    else:
        part = np.argpartition(dist, 1, axis=1)[:, :2]
        d01 = np.take_along_axis(dist, part, 1)
        first_is_best = d01[:, 0] <= d01[:, 1]
        best_j = np.where(first_is_best, part[:, 0], part[:, 1])
        best = np.minimum(d01[:, 0], d01[:, 1])
        second = np.maximum(d01[:, 0], d01[:, 1])
    accept = (best <= cfg.max_hamming) & (best < cfg.ratio * second)
    i1 = np.flatnonzero(accept)
    i2 = best_j[i1]
    d = best[i1]
    # One match per keypoint of view 2: the lowest distance wins (ties: the lower row of view 1).
    order = np.lexsort((i1, d, i2))
    first = np.ones(len(order), bool)
    first[1:] = i2[order][1:] != i2[order][:-1]
    keep = order[first]
    return i1[keep].astype(np.int64), i2[keep].astype(np.int64)


def triangulate_dlt(T_cw1: F64, T_cw2: F64, xn1: F64, xn2: F64) -> tuple[F64, F64]:
    """Linear triangulation of N correspondences in normalised image coordinates (N, 2) each, with
    world-to-camera poses (4, 4). Returns world points (N, 3) and |w| of the homogeneous solution (N,)
    (near 0: a point at infinity)."""
    P1, P2 = T_cw1[:3, :], T_cw2[:3, :]
    A = np.stack([
        xn1[:, 0:1] * P1[2] - P1[0],
        xn1[:, 1:2] * P1[2] - P1[1],
        xn2[:, 0:1] * P2[2] - P2[0],
        xn2[:, 1:2] * P2[2] - P2[1],
    ], axis=1)  # (N, 4, 4)
    _, _, vt = np.linalg.svd(A)
    X = vt[:, -1, :]
    w = X[:, 3]
    safe = np.where(np.abs(w) < 1e-12, 1e-12, w)
    return X[:, :3] / safe[:, None], np.abs(w)


def _normalised(K: F64, px: F64) -> F64:
    return np.column_stack([(px[:, 0] - K[0, 2]) / K[0, 0], (px[:, 1] - K[1, 2]) / K[1, 1]])


def triangulate_matches(
    v1: TwoView, v2: TwoView, rows1: I64, rows2: I64, level_scales: F64, cfg: TriangulationConfig
) -> Triangulated:
    """Triangulate matched candidates and keep those passing every check of the module docstring."""
    empty = np.zeros(0, np.int64)
    if len(rows1) == 0:
        return Triangulated(empty, empty, np.zeros((0, 3)))
    T_cw1, T_cw2 = invert(v1.T_world_cam), invert(v2.T_world_cam)
    xn1 = _normalised(v1.K, v1.px[rows1])
    xn2 = _normalised(v2.K, v2.px[rows2])
    X, w = triangulate_dlt(T_cw1, T_cw2, xn1, xn2)
    ok = w > 1e-9
    # Parallax between the two viewing rays (world frame).
    r1 = np.column_stack([xn1, np.ones(len(xn1))]) @ v1.T_world_cam[:3, :3].T
    r2 = np.column_stack([xn2, np.ones(len(xn2))]) @ v2.T_world_cam[:3, :3].T
    cos_par = np.einsum("ij,ij->i", r1, r2) / (np.linalg.norm(r1, axis=1) * np.linalg.norm(r2, axis=1))
    ok &= (cos_par > 0) & (cos_par < np.cos(np.radians(cfg.min_parallax_deg)))
    sigma2 = level_scales**2
    o1, o2 = v1.octaves[rows1], v2.octaves[rows2]
    dists = []
    for view, T_cw, rows, octs in ((v1, T_cw1, rows1, o1), (v2, T_cw2, rows2, o2)):
        pc = X @ T_cw[:3, :3].T + T_cw[:3, 3]
        z = pc[:, 2]
        ok &= z > 0
        zs = np.where(z > 1e-9, z, 1e-9)
        u = view.K[0, 0] * pc[:, 0] / zs + view.K[0, 2]
        v = view.K[1, 1] * pc[:, 1] / zs + view.K[1, 2]
        e2 = (u - view.px[rows, 0]) ** 2 + (v - view.px[rows, 1]) ** 2
        ok &= e2 < cfg.reprojection_chi2 * sigma2[octs]
        dists.append(np.linalg.norm(pc, axis=1))
    d1, d2 = dists
    ok &= (d1 > 0) & (d2 > 0)
    if cfg.max_distance_m > 0:
        ok &= d1 <= cfg.max_distance_m
    # Scale consistency: the distance ratio must follow the pyramid-scale ratio of the two keypoints.
    ratio_dist = d2 / np.maximum(d1, 1e-12)
    ratio_oct = level_scales[o1] / level_scales[o2]
    ok &= (ratio_dist * cfg.scale_ratio_factor >= ratio_oct) & (ratio_dist <= ratio_oct * cfg.scale_ratio_factor)
    keep = np.flatnonzero(ok)
    return Triangulated(rows1[keep], rows2[keep], X[keep])


def triangulate_pair(v1: TwoView, v2: TwoView, level_scales: F64, cfg: TriangulationConfig) -> Triangulated:
    """Match (epipolar-constrained) and triangulate the candidates of two views.

    1. candidate pairs must satisfy the epipolar constraint of the two known poses
       (squared distance to the epipolar line < `epipolar_chi2` * sigma^2 of the keypoint's level);
    2. among them, the best ORB descriptor (Hamming <= `max_hamming`, Lowe ratio `ratio`, one-to-one);
    3. linear (DLT) triangulation in normalised coordinates;
    4. a point is kept only when it lies in front of both cameras, the two rays make at least
       `min_parallax_deg`, its reprojection error in each view is under `reprojection_chi2` * sigma^2, and the
       ratio of its distances to the two cameras agrees with the ratio of the keypoints' pyramid scales
       (within `scale_ratio_factor`).
    """
    baseline = float(np.linalg.norm(v1.T_world_cam[:3, 3] - v2.T_world_cam[:3, 3]))
    if baseline < cfg.min_baseline_m:
        empty = np.zeros(0, np.int64)
        return Triangulated(empty, empty, np.zeros((0, 3)))
    rows1, rows2 = match_epipolar(v1, v2, level_scales**2, cfg)
    return triangulate_matches(v1, v2, rows1, rows2, level_scales, cfg)
