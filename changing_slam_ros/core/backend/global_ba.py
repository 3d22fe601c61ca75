"""Global bundle adjustment with gtsam after a loop closure (ORB-SLAM's `RunGlobalBundleAdjustment`, RGB-D).

The pose graph moved keyframes and points rigidly; global BA then refines every keyframe pose and every
map point seen at least twice against the keypoint measurements themselves. It reuses the local BA's
measurement model (`backend.local_ba`: `GenericStereoFactor3D` for keypoints with depth as virtual stereo, the
depth weighted by `stereo_noise`, `GenericProjectionFactorCal3_S2` without, sigma = pyramid scale in px, Huber kernels).
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
import numpy.typing as npt
from gtsam.symbol_shorthand import L, X

from changing_slam_ros.core.backend.local_ba import (
    add_reprojection_factors,
    gather_observations,
    reprojection_chi2,
)
from changing_slam_ros.core.map.slam_map import SlamMap

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class GlobalBAConfig:
    """`iterations`: Levenberg-Marquardt iterations (ORB-SLAM runs 10); `bf_m_px`: virtual stereo baseline * fx;
    `level_scales`: pyramid scales, from the feature config; `disparity_sigma_ratio`: the depth's weight, as in local
    BA (`local_ba.stereo_noise`)."""

    iterations: int = 10
    bf_m_px: float = 40.0
    level_scales: tuple[float, ...] = tuple(1.2**i for i in range(8))
    disparity_sigma_ratio: float = 1.0


@dataclass(frozen=True)
class GlobalBAResult:
    n_keyframes: int
    n_points: int
    n_observations: int
    rms_before_px: float
    rms_after_px: float


def global_bundle_adjust(slam_map: SlamMap, cfg: GlobalBAConfig = GlobalBAConfig()) -> GlobalBAResult:
    """Refine all keyframe poses and map points of `slam_map` in place (its first keyframe held fixed)."""
    scales = np.asarray(cfg.level_scales)
    kf_ids = sorted(slam_map.keyframes)
    if len(kf_ids) < 2:
        return GlobalBAResult(len(kf_ids), 0, 0, 0.0, 0.0)
    usable = slam_map.points.usable()
    point_ids = np.flatnonzero(usable).astype(np.int64)
    obs = gather_observations(slam_map, kf_ids, point_ids, cfg.bf_m_px)
    # 1. Points seen by one keyframe only carry no constraint between poses: leave them out.
    n_per_point = np.bincount(np.searchsorted(point_ids, obs.point_ids), minlength=len(point_ids))
    keep_pts = point_ids[n_per_point >= 2]
    obs = obs.of_points(keep_pts)
    if len(keep_pts) == 0:
        return GlobalBAResult(len(kf_ids), 0, 0, 0.0, 0.0)
    cam = slam_map.keyframes[kf_ids[0]].camera
    poses = {k: slam_map.keyframes[k].T_world_cam for k in kf_ids}
    e2_before, _ = reprojection_chi2(poses, slam_map.points.positions, obs, cam.fx, cam.fy, cam.cx, cam.cy, cfg.bf_m_px, scales)

    # 2. Variables: every keyframe pose X(k) (camera-to-world) and point L(p).
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for k in kf_ids:
        values.insert(X(k), gtsam.Pose3(poses[k]))
    for pid in keep_pts.tolist():
        values.insert(L(pid), slam_map.points.positions[pid])
    # 3. Gauge: reprojection factors are invariant to moving the whole map rigidly, so the map's first
    #    keyframe is held where it is (an equality constraint, as local BA holds its fixed keyframes).
    origin = slam_map.origin_kf_id if slam_map.origin_kf_id in slam_map.keyframes else kf_ids[0]
    graph.add(gtsam.NonlinearEqualityPose3(X(origin), gtsam.Pose3(poses[origin])))
    # 4. Measurements: (u_l, u_r, v) or (u, v) in pixels, sigma = pyramid level scale, Huber kernels.
    add_reprojection_factors(graph, obs, cam, cfg.bf_m_px, scales, cfg.disparity_sigma_ratio)
    # 5. Levenberg-Marquardt; on failure (cheirality, indeterminate system) the map stays as it was.
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(cfg.iterations)
    try:
        result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    except RuntimeError:
        rms = float(np.sqrt(e2_before.mean()))
        return GlobalBAResult(len(kf_ids), len(keep_pts), len(obs.kf_ids), rms, rms)
    for k in kf_ids:
        slam_map.keyframes[k].T_world_cam = result.atPose3(X(k)).matrix()
    slam_map.points.positions[keep_pts] = np.array([result.atPoint3(L(p)) for p in keep_pts.tolist()])
    # 6. Points seen once were not optimised: they move rigidly with their reference keyframe.
    single = np.setdiff1d(point_ids, keep_pts)
    refs = slam_map.points.ref_kf[single]
    for ref in np.unique(refs).tolist():
        if ref not in poses:
            continue
        delta = slam_map.keyframes[ref].T_world_cam @ np.linalg.inv(poses[ref])
        sel = single[refs == ref]
        slam_map.points.positions[sel] = slam_map.points.positions[sel] @ delta[:3, :3].T + delta[:3, 3]
    poses = {k: slam_map.keyframes[k].T_world_cam for k in kf_ids}
    e2_after, _ = reprojection_chi2(poses, slam_map.points.positions, obs, cam.fx, cam.fy, cam.cx, cam.cy, cfg.bf_m_px, scales)
    return GlobalBAResult(
        len(kf_ids), len(keep_pts), len(obs.kf_ids), float(np.sqrt(e2_before.mean())), float(np.sqrt(e2_after.mean()))
    )
