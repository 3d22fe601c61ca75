"""Fusion of duplicated map points between a new keyframe and its neighbours (ORB-SLAM `SearchInNeighbors`).

Tracking misses some existing points, so a new keyframe creates duplicates of them from depth.
Projecting the keyframe's points into its covisible neighbours (and theirs into it) finds them:
a keypoint without a point gains an observation, a keypoint holding another point gets the two
points merged (the one with more observations survives). Then the descriptor and viewing
direction of every touched point are refreshed from all of its observations.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.features.frame import Frame
from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.features.matcher import ProjectionQuery, hamming, search_by_projection
from changing_slam_ros.core.features.orb_features import Features
from changing_slam_ros.core.geometry.se3 import invert
from changing_slam_ros.core.map.slam_map import SlamMap

I64 = npt.NDArray[np.int64]


def keyframe_as_frame(kf: Keyframe, bf_m_px: float) -> Frame:
    """A `Frame` view of a keyframe's keypoints (for projection search into it)."""
    px = kf.keypoints_px.astype(np.float64)
    d = kf.depths_m.astype(np.float64)
    ur = np.where(d > 0, px[:, 0] - bf_m_px / np.maximum(d, 1e-9), -1.0)
    n = len(kf)
    feats = Features(px, px, kf.octaves.astype(np.int64), np.zeros(n), np.zeros(n), kf.descriptors, d, ur)
    return Frame(kf.stamp_ns, -1, kf.camera, feats, point_ids=kf.point_ids.copy(), T_world_cam=kf.T_world_cam)


def fuse_into(slam_map: SlamMap, target: Keyframe, ids: I64, level_scales: npt.NDArray[np.float64],
              bf_m_px: float, radius_px: float = 3.0) -> tuple[int, int]:
    """Project points `ids` into keyframe `target`; returns (observations added, points merged)."""
    pts = slam_map.points
    ids = ids[pts.usable()[ids]]
    if len(ids) == 0:
        return 0, 0
    frame = keyframe_as_frame(target, bf_m_px)
    q = ProjectionQuery(pts.positions[ids], pts.descriptors[ids], ids, pts.normals[ids], pts.min_dist[ids], pts.max_dist[ids])
    res = search_by_projection(frame, invert(target.T_world_cam), q, radius_px, level_scales, max_distance=50,
                               skip_matched=False, bf_m_px=bf_m_px)
    added = merged = 0
    for kp, pid in zip(res.kp_indices.tolist(), ids[res.rows].tolist()):
        if pts.bad[pid]:
            continue
        existing = int(target.point_ids[kp])
        if existing == pid:
            continue
        if existing >= 0 and not pts.bad[existing]:
            keep, drop = (existing, pid) if len(pts.observations[existing]) >= len(pts.observations[pid]) else (pid, existing)
            replace_point(slam_map, drop, keep)
            merged += 1
        elif target.id not in pts.observations[pid]:
            slam_map.add_observation(pid, target.id, kp)
            added += 1
    return added, merged


def replace_point(slam_map: SlamMap, old: int, new: int) -> None:
    """Move every observation of point `old` to point `new` and mark `old` bad."""
    pts = slam_map.points
    for kf_id, i in list(pts.observations[old].items()):
        kf = slam_map.keyframes.get(kf_id)
        if kf is None:
            continue
        if kf_id in pts.observations[new]:
            kf.point_ids[i] = -1
        else:
            pts.observations[new][kf_id] = i
            kf.point_ids[i] = new
    pts.observations[old] = {}
    pts.n_visible[new] += pts.n_visible[old]
    pts.n_found[new] += pts.n_found[old]
    pts.set_bad(np.array([old]))


def refresh_points(slam_map: SlamMap, ids: I64, level_scales: npt.NDArray[np.float64]) -> None:
    """Distinctive descriptor (least median Hamming distance to the others) and mean viewing
    direction / scale distances of each point, from all of its observations (vectorised per batch)."""
    pts = slam_map.points
    kfs = slam_map.keyframes
    ids = ids[~pts.bad[ids]]
    # 1. Flatten the observations, point by point in insertion order: (point row, keyframe id, keypoint index).
    obs = pts.observations
    flat = [(r, k, i) for r, pid in enumerate(ids.tolist()) for k, i in obs[pid].items() if k in kfs]
    if not flat:
        return
    row, kf_of, kp = (np.array(c, np.int64) for c in zip(*flat))
    # Per keyframe: its centre, and its keypoints' descriptors and octaves, gathered in one indexing each.
    n = len(row)
    centres = np.empty((n, 3))
    descs = np.empty((n, 32), np.uint8)
    octs = np.empty(n, np.int64)
    kf_u, kf_idx = np.unique(kf_of, return_inverse=True)
    for j, k in enumerate(kf_u.tolist()):
        at = np.flatnonzero(kf_idx == j)
        kf = kfs[k]
        centres[at] = kf.T_world_cam[:3, 3]
        descs[at] = kf.descriptors[kp[at]]
        octs[at] = kf.octaves[kp[at]]
    rays = pts.positions[ids[row]] - centres
    dist = np.linalg.norm(rays, axis=1)
    # 2. Mean viewing direction.
    acc = np.zeros((len(ids), 3))
    np.add.at(acc, row, rays / np.maximum(dist, 1e-9)[:, None])
    norm = np.linalg.norm(acc, axis=1)
    seen = norm > 0
    pts.normals[ids[seen]] = acc[seen] / norm[seen, None]
    # 3. Scale-invariance distances from the reference observation (ORB-SLAM `UpdateNormalAndDepth`).
    ref_mask = kf_of == pts.ref_kf[ids[row]]
    r_ref = row[ref_mask]
    max_d = dist[ref_mask] * level_scales[octs[ref_mask]]
    pts.max_dist[ids[r_ref]] = max_d
    pts.min_dist[ids[r_ref]] = max_d / level_scales[-1]
    # 4. Distinctive descriptor for points seen at least three times, all points with the same number of
    # observations at once: (P, c, c) distances, the row with the least median per point.
    starts = np.searchsorted(row, np.arange(len(ids)))
    counts = np.bincount(row, minlength=len(ids))
    for c in np.unique(counts[counts > 2]).tolist():
        rs = np.flatnonzero(counts == c)
        d = descs[starts[rs][:, None] + np.arange(c)]  # (P, c, 32)
        ham = hamming(d[:, :, None, :], d[:, None, :, :])  # (P, c, c)
        best = np.argmin(np.median(ham, axis=2), axis=1)
        pts.descriptors[ids[rs]] = d[np.arange(len(rs)), best]
