"""Local bundle adjustment (ORB-SLAM `LocalBundleAdjustment`, RGB-D as virtual stereo), posed as a gtsam graph.

Variables: poses X(k) (gtsam `Pose3` = camera-to-world) of the local keyframes (the new keyframe and
its covisible neighbours) and positions L(p) of every usable map point they see. Keyframes outside
the window that also observe those points enter as fixed poses (held by tight priors).
Factors: `GenericStereoFactor3D` for keypoints with depth (u_l, u_r, v in pixels, sigma = level scale
px on each, or with `disparity_sigma_ratio` > 0 the depth weighted by its own sigma: `stereo_noise`),
`GenericProjectionFactorCal3_S2` for keypoints without (u, v), both with a Huber kernel
on the whitened error (k = sqrt(7.815) stereo, sqrt(5.991) mono). Afterwards observations whose
chi2 exceeds those thresholds are erased from the map (ORB-SLAM's outlier removal). Points seen by one
keyframe only are left out of the graph and move rigidly with it (`carry_lone_points`).
Solved by gtsam's Levenberg-Marquardt on the factor graph (default) or by `schur_lm` (the same cost and gtsam's LM
policy in numpy, ~0.35x gtsam's CPU; the real-time graph's choice) (`LocalBAConfig.solver`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import gtsam
import numpy as np
import numpy.typing as npt
from gtsam.symbol_shorthand import X

from changing_slam_ros.core.backend import schur_lm
from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.geometry.pose_optimizer import CHI2_MONO, CHI2_STEREO
from changing_slam_ros.core.map.slam_map import SlamMap

F64 = npt.NDArray[np.float64]


_X_BASE = ord("x") << 56  # gtsam Symbol keys: the character in the top byte, the index below
_L_BASE = ord("l") << 56


def pose_keys(kf_ids: npt.NDArray[np.int64]) -> npt.NDArray[np.uint64]:
    """gtsam keys X(k) of keyframe ids (the same integers as `gtsam.symbol_shorthand.X`), vectorised."""
    return np.asarray(kf_ids, dtype=np.uint64) + np.uint64(_X_BASE)


def point_keys(point_ids: npt.NDArray[np.int64]) -> npt.NDArray[np.uint64]:
    """gtsam keys L(p) of map point ids (`gtsam.symbol_shorthand.L`), vectorised."""
    return np.asarray(point_ids, dtype=np.uint64) + np.uint64(_L_BASE)


@dataclass(frozen=True)
class LocalBAConfig:
    """`n_window`: covisible keyframes optimised with the new one; `max_fixed`: fixed keyframes kept
    (most observations first); `iterations`: Levenberg-Marquardt iterations; `max_points`: points
    optimised at most, those with the most observations in the window first (the solver's cost grows
    with the number of variables: gtsam spends ~0.1 ms per variable per linear solve here); `level_scales`: pyramid
    scales, set by the caller from the feature config; `bf_m_px`: virtual stereo baseline * fx;
    `disparity_sigma_ratio`: sigma of the depth as disparity, in units of the keypoint's sigma (`stereo_noise`);
    `solver`: "gtsam" (default: its Levenberg-Marquardt on the factor graph) or "schur" (`schur_lm`: gtsam's cost
    and LM policy in numpy, points eliminated by the Schur complement; ~0.35x gtsam's CPU, not bit-identical:
    final errors within ~1e-8 of gtsam's)."""

    n_window: int = 10
    max_fixed: int = 10
    iterations: int = 5
    max_points: int = 3000
    bf_m_px: float = 40.0
    level_scales: tuple[float, ...] = tuple(1.2**i for i in range(8))
    disparity_sigma_ratio: float = 1.0
    solver: str = "gtsam"

    def __post_init__(self) -> None:
        if self.solver not in SOLVERS:
            raise ValueError(f"local BA solver {self.solver!r}: expected one of {SOLVERS}")


SOLVERS = ("gtsam", "schur")


@dataclass(frozen=True)
class Observations:
    """E observations: keyframe ids (E,), point ids (E,), u v (E, 2), u_right (E,) (< 0 mono), level (E,), kp index (E,)."""

    kf_ids: npt.NDArray[np.int64]
    point_ids: npt.NDArray[np.int64]
    uv: F64
    u_right: F64
    level: npt.NDArray[np.int64]
    kp_index: npt.NDArray[np.int64]

    def of_points(self, point_ids: npt.NDArray[np.int64]) -> "Observations":
        """The observations of the given points only."""
        keep = np.isin(self.point_ids, point_ids)
        return Observations(self.kf_ids[keep], self.point_ids[keep], self.uv[keep], self.u_right[keep],
                            self.level[keep], self.kp_index[keep])


@dataclass(frozen=True)
class LocalBAResult:
    n_local: int
    n_fixed: int
    n_points: int
    n_observations: int
    rms_before_px: float
    rms_after_px: float
    n_outliers_removed: int
    iterations: int = -1  # Levenberg-Marquardt iterations run (-1: not counted, gtsam's own loop ran)
    stopped: bool = False  # cut short by `stop` (a new keyframe waits; real time only)


def gather_observations(slam_map: SlamMap, kf_ids: list[int], point_ids: npt.NDArray[np.int64], bf: float) -> Observations:
    """Every observation of `point_ids` (sorted) in keyframes `kf_ids`, as flat arrays."""
    parts = []
    for k in kf_ids:
        kf = slam_map.keyframes[k]
        idx = np.flatnonzero(kf.point_ids >= 0)
        pids = kf.point_ids[idx]
        pos = np.searchsorted(point_ids, pids)
        pos = np.minimum(pos, max(len(point_ids) - 1, 0))
        keep = point_ids[pos] == pids if len(point_ids) else np.zeros(len(pids), bool)
        idx, pids = idx[keep], pids[keep]
        d = kf.depths_m[idx].astype(np.float64)
        uv = kf.keypoints_px[idx].astype(np.float64)
        ur = np.where(d > 0, uv[:, 0] - bf / np.maximum(d, 1e-9), -1.0)
        parts.append((np.full(len(idx), k, np.int64), pids, uv, ur, kf.octaves[idx].astype(np.int64), idx))
    if not parts:
        z = np.zeros(0, np.int64)
        return Observations(z, z, np.zeros((0, 2)), np.zeros(0), z, z)
    cols = list(zip(*parts))
    return Observations(*(np.concatenate(c) for c in cols))  # type: ignore[arg-type]


def reprojection_chi2(
    poses_wc: dict[int, F64], positions: dict[int, F64] | F64, obs: Observations, fx: float, fy: float, cx: float, cy: float,
    bf: float, scales: F64, disparity_sigma_ratio: float = 0.0,
) -> tuple[F64, F64]:
    """Per observation: squared pixel error (E,) and level-weighted chi2 (E,). `positions` (P, 3) is indexed by point id.

    `disparity_sigma_ratio` > 0: keypoints with depth are weighed by `stereo_noise` (u, v and the disparity
    bf / depth, the latter with sigma = ratio * level scale); 0: ORB-SLAM's (u_l, u_r, v), each with the level scale."""
    # Each observation's camera-from-world rotation and translation, gathered per distinct keyframe.
    kf_u, kf_of_obs = np.unique(obs.kf_ids, return_inverse=True)
    T_cw = np.stack([np.linalg.inv(poses_wc[k]) for k in kf_u.tolist()]) if len(kf_u) else np.zeros((0, 4, 4))
    R = np.ascontiguousarray(T_cw[kf_of_obs, :3, :3])
    t = np.ascontiguousarray(T_cw[kf_of_obs, :3, 3])
    pw = np.asarray(positions[obs.point_ids], np.float64)  # an array, or a PointStore column, by point id
    pc = np.einsum("nij,nj->ni", R, pw) + t
    z = np.where(np.abs(pc[:, 2]) < 1e-6, 1e-6, pc[:, 2])
    u = fx * pc[:, 0] / z + cx
    v = fy * pc[:, 1] / z + cy
    e_u = obs.uv[:, 0] - u
    e2_uv = e_u**2 + (obs.uv[:, 1] - v) ** 2
    stereo = obs.u_right >= 0
    e_r = obs.u_right - (u - bf / z)
    e2 = e2_uv + np.where(stereo, e_r**2, 0.0)
    chi2 = e2 / scales[obs.level] ** 2
    if disparity_sigma_ratio > 0:
        e_d = e_u - e_r  # measured minus predicted disparity
        chi2 = np.where(stereo, (e2_uv + (e_d / disparity_sigma_ratio) ** 2) / scales[obs.level] ** 2, chi2)
    chi2 = np.where(pc[:, 2] > 0, chi2, 1e9)
    return e2, chi2


def stereo_noise(sigma_px: float, disparity_sigma_ratio: float) -> gtsam.noiseModel.Base:
    """Noise of an RGB-D keypoint as gtsam's (u_l, u_r, v) with u_r = u_l - bf / depth: u_l and v carry the
    keypoint's `sigma_px`, the disparity bf / depth its own `disparity_sigma_ratio * sigma_px` (the depth
    sensor's noise), so u_r = u_l - d is correlated with u_l. ratio 0: ORB-SLAM's three independent sigmas."""
    if disparity_sigma_ratio <= 0:
        return gtsam.noiseModel.Isotropic.Sigma(3, sigma_px)
    s2, d2 = sigma_px**2, (disparity_sigma_ratio * sigma_px) ** 2
    cov = np.array([[s2, s2, 0.0], [s2, s2 + d2, 0.0], [0.0, 0.0, s2]])
    return gtsam.noiseModel.Gaussian.Covariance(cov)


class FactorCache:
    """The reprojection factors of the last local BA, for the next one (successive windows share most of their
    observations). A factor is a function of its keys, measurement and level alone once the calibration and the
    noise settings are fixed, so it is looked up by exactly those, (X key, L key, u, v, u_right, level), and the
    whole cache is dropped when the settings change: a factor taken from it equals the one that would be built.
    Only the factors the last BA used are kept. gtsam factors are immutable, so two graphs may share one."""

    def __init__(self) -> None:
        self.settings: tuple[float, ...] = ()
        self.factors: dict[tuple[int, int, float, float, float, int], gtsam.NonlinearFactor] = {}
        self.reused = 0  # factors taken from the cache so far (for benchmarks)


def add_reprojection_factors(
    graph: gtsam.NonlinearFactorGraph, obs: Observations, cam: CameraIntrinsics, bf_m_px: float, scales: npt.ArrayLike,
    disparity_sigma_ratio: float = 0.0, cache: FactorCache | None = None,
) -> None:
    """Add one robust reprojection factor X(k)-L(p) per observation to `graph` (local and global BA).

    Keypoints with depth give a stereo factor on (u_l, u_r, v), the others a monocular one on (u, v);
    sigma = the keypoint's pyramid level scale (`scales[level]`) in pixels; Huber kernels at the chi-square
    95 % thresholds of the pose optimiser (`CHI2_STEREO`, `CHI2_MONO`). With a `cache` (local BA) the factors
    of the previous call are reused where they are the same (`FactorCache`) and this call's are kept.
    """
    k_stereo = gtsam.Cal3_S2Stereo(cam.fx, cam.fy, 0.0, cam.cx, cam.cy, bf_m_px / cam.fx)
    k_mono = gtsam.Cal3_S2(cam.fx, cam.fy, 0.0, cam.cx, cam.cy)
    huber_s = gtsam.noiseModel.mEstimator.Huber.Create(float(np.sqrt(CHI2_STEREO)))
    huber_m = gtsam.noiseModel.mEstimator.Huber.Create(float(np.sqrt(CHI2_MONO)))
    noise_s = [gtsam.noiseModel.Robust.Create(huber_s, stereo_noise(float(s), disparity_sigma_ratio)) for s in np.asarray(scales)]
    noise_m = [gtsam.noiseModel.Robust.Create(huber_m, gtsam.noiseModel.Isotropic.Sigma(2, float(s))) for s in np.asarray(scales)]
    settings = (cam.fx, cam.fy, cam.cx, cam.cy, float(bf_m_px), float(disparity_sigma_ratio),
                *(float(x) for x in np.asarray(scales)))  # fmt: skip
    old: dict[tuple[int, int, float, float, float, int], gtsam.NonlinearFactor] = {}
    if cache is not None and cache.settings == settings:
        old = cache.factors
    new: dict[tuple[int, int, float, float, float, int], gtsam.NonlinearFactor] = {}
    # One pybind11 call per factor and measurement: keys computed in numpy (`pose_keys`, `point_keys`), the
    # constructors bound to locals. The factors and their order are those of a loop calling X(k) and L(p).
    add, stereo, stereo_pt, mono = graph.add, gtsam.GenericStereoFactor3D, gtsam.StereoPoint2, gtsam.GenericProjectionFactorCal3_S2
    get, n_built = old.get, 0
    for key in zip(
        pose_keys(obs.kf_ids).tolist(), point_keys(obs.point_ids).tolist(), obs.uv[:, 0].tolist(), obs.uv[:, 1].tolist(),
        obs.u_right.tolist(), obs.level.tolist(),
    ):  # fmt: skip
        factor = get(key)
        if factor is None:
            n_built += 1
            xk, lp, u, v, ur, lv = key
            if ur >= 0:
                factor = stereo(stereo_pt(u, ur, v), noise_s[lv], xk, lp, k_stereo)
            else:
                factor = mono(np.array([u, v]), noise_m[lv], xk, lp, k_mono)
        add(factor)
        new[key] = factor
    if cache is not None:
        cache.reused += len(obs.kf_ids) - n_built
        cache.settings, cache.factors = settings, new


def carry_lone_points(slam_map: SlamMap, poses_before: dict[int, F64]) -> int:
    """Move the map points that only one keyframe observes rigidly with that keyframe's pose change.

    The BA leaves such points out (one observation constrains nothing), but in ORB-SLAM3's BA they are
    variables whose optimum keeps them where their keyframe sees them, i.e. they follow it. Left behind,
    a moved keyframe and the points it created disagree: tracking, which matches points, keeps frames
    where the points are while the keyframe they are stored against sits elsewhere. `poses_before`: keyframe
    id -> camera-to-world pose before the keyframe moved (current poses are read from the map). Inactive
    points follow too (their place stays right for when they become active). Returns the points moved.
    """
    pts = slam_map.points
    n = 0
    for k, T_old in poses_before.items():
        kf = slam_map.keyframes.get(k)
        if kf is None:
            continue
        delta = kf.T_world_cam @ np.linalg.inv(T_old)
        if np.allclose(delta, np.eye(4), atol=1e-12):
            continue
        ids = kf.point_ids[kf.point_ids >= 0]
        ids = ids[~pts.bad[ids]]
        lone = ids[pts.n_obs(ids) == 1]
        if len(lone) == 0:
            continue
        pts.positions[lone] = pts.positions[lone] @ delta[:3, :3].T + delta[:3, 3]
        pts.normals[lone] = pts.normals[lone] @ delta[:3, :3].T
        n += len(lone)
    return n


def fixed_keyframes(slam_map: SlamMap, point_ids: npt.NDArray[np.int64], local: set[int], max_fixed: int) -> list[int]:
    """Keyframes outside `local` that observe `point_ids`, most observations first, at most `max_fixed`; ties
    in the order they are first met walking the points in order and each point's observations in insertion
    order (the order of a dict counting them)."""
    obs = slam_map.points.observations
    seen = np.fromiter((k for pid in point_ids.tolist() for k in obs[pid]), np.int64)
    if len(seen) == 0:
        return []
    outside = ~np.isin(seen, np.fromiter(local, np.int64, len(local)))
    outside &= np.isin(seen, np.fromiter(slam_map.keyframes, np.int64, len(slam_map.keyframes)))
    kfs, first, counts = np.unique(seen[outside], return_index=True, return_counts=True)
    order = np.lexsort((first, -counts))[:max_fixed]
    return kfs[order].tolist()


class _BAStopped(Exception):
    """Raised by the iteration hook of `optimise` to leave gtsam's loop (a keyframe waits)."""


def optimise(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, params: gtsam.LevenbergMarquardtParams,
             stop: Callable[[], bool] | None = None) -> tuple[gtsam.Values, int, bool]:
    """Levenberg-Marquardt (gtsam's `optimize()`); returns (values, iterations run (-1 without `stop`), stopped).

    With `stop` (ORB-SLAM's real-time rule: local BA gives way when a new keyframe waits) it is asked before
    the first iteration and, through gtsam's iteration hook (set on `params`), after each iteration but the
    last; when it says yes the hook raises out of gtsam's loop and the values of the last finished iteration
    are returned (each accepted LM step lowered the error, so they are never worse than the start). The loop
    is gtsam's own either way, so while `stop()` says no the result is `optimize()`'s bit for bit (a loop of
    `iterate()` calls from Python would cost ~15 % more: every call hands back the linearised graph)."""
    if stop is None:
        return gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize(), -1, False
    if stop():
        return values, 0, True
    max_iterations = params.getMaxIterations()

    def hook(iteration: int, error_before: float, error_after: float) -> None:
        if iteration < max_iterations and stop():
            raise _BAStopped

    params.iterationHook = hook
    opt = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    try:
        result = opt.optimize()
    except _BAStopped:
        return opt.values(), opt.iterations(), True
    return result, opt.iterations(), False


def local_bundle_adjust(slam_map: SlamMap, kf_id: int, cfg: LocalBAConfig,
                        stop: Callable[[], bool] | None = None, factors: FactorCache | None = None) -> LocalBAResult:
    """Optimise the window around keyframe `kf_id` in place; erase outlier observations.

    `stop` (real time): asked between solver iterations (`optimise`); when it returns True the BA ends with
    what it reached (outliers are still erased against it). `factors`: reuse the previous BA's factors (same
    result, less building; `FactorCache`)."""
    scales = np.asarray(cfg.level_scales)
    # 1. Local keyframes: the new one and its best covisible neighbours.
    local = [kf_id] + [k for k in slam_map.covisible(kf_id, cfg.n_window) if k in slam_map.keyframes]
    local_set = set(local)
    point_ids = slam_map.local_point_ids(local)
    # 2. Fixed keyframes: others seeing those points, most observations first.
    fixed = fixed_keyframes(slam_map, point_ids, local_set, cfg.max_fixed)
    if not fixed:
        # Fix the gauge: the oldest local keyframe stays where it is.
        oldest = min(local)
        if len(local) == 1:
            return LocalBAResult(1, 0, len(point_ids), 0, 0.0, 0.0, 0)
        local.remove(oldest)
        fixed = [oldest]
    all_kfs = local + fixed
    cam = slam_map.keyframes[kf_id].camera
    obs = gather_observations(slam_map, all_kfs, point_ids, cfg.bf_m_px)
    # Points seen only once in the window carry no constraint: leave them out.
    n_per_point = np.bincount(np.searchsorted(point_ids, obs.point_ids), minlength=len(point_ids))
    keep_pts = point_ids[n_per_point >= 2]
    if len(keep_pts) > cfg.max_points:
        counts_kept = n_per_point[n_per_point >= 2]
        order = np.lexsort((keep_pts, -counts_kept))[: cfg.max_points]
        keep_pts = np.sort(keep_pts[order])
    obs = obs.of_points(keep_pts)
    if len(keep_pts) == 0:
        return LocalBAResult(len(local), len(fixed), 0, 0, 0.0, 0.0, 0)
    poses = {k: slam_map.keyframes[k].T_world_cam for k in all_kfs}
    e2_before, _ = reprojection_chi2(poses, slam_map.points.positions, obs, cam.fx, cam.fy, cam.cx, cam.cy, cfg.bf_m_px, scales)
    if cfg.solver == "schur":
        problem = schur_problem(slam_map, local, fixed, keep_pts, obs, cam, cfg)
        res = schur_lm.solve(problem, schur_lm.LMSettings(iterations=cfg.iterations), stop)
        before = {k: slam_map.keyframes[k].T_world_cam for k in local}
        for i, k in enumerate(local):
            slam_map.keyframes[k].T_world_cam = res.T_world_cam[i]
        slam_map.points.positions[keep_pts] = res.points
        iterations, stopped = res.iterations, res.stopped
    else:
        before, iterations, stopped = _solve_gtsam(slam_map, local, fixed, keep_pts, obs, cam, cfg, stop, factors)
        if before is None:  # gtsam failed: the map is as it was
            return LocalBAResult(len(local), len(fixed), len(keep_pts), len(obs.kf_ids), 0.0, 0.0, 0)
    carry_lone_points(slam_map, before)
    poses = {k: slam_map.keyframes[k].T_world_cam for k in all_kfs}
    e2_after, chi2 = reprojection_chi2(poses, slam_map.points.positions, obs, cam.fx, cam.fy, cam.cx, cam.cy, cfg.bf_m_px, scales,
                                       cfg.disparity_sigma_ratio)
    th = np.where(obs.u_right >= 0, CHI2_STEREO, CHI2_MONO)
    bad = np.flatnonzero(chi2 > th)
    for i in bad.tolist():
        slam_map.erase_observation(int(obs.kf_ids[i]), int(obs.kp_index[i]))
    return LocalBAResult(
        len(local), len(fixed), len(keep_pts), len(obs.kf_ids),
        float(np.sqrt(e2_before.mean())), float(np.sqrt(e2_after.mean())), len(bad), iterations, stopped,
    )


def schur_problem(slam_map: SlamMap, local: list[int], fixed: list[int], keep_pts: npt.NDArray[np.int64], obs: Observations,
                  cam: CameraIntrinsics, cfg: LocalBAConfig) -> schur_lm.BAProblem:
    """The window as `schur_lm`'s problem: the same variables, measurements and noise as the gtsam graph."""
    all_kfs = np.asarray(local + fixed, np.int64)
    order = np.argsort(all_kfs, kind="stable")
    pose_idx = order[np.searchsorted(all_kfs[order], obs.kf_ids)]
    return schur_lm.BAProblem(
        np.stack([slam_map.keyframes[k].T_world_cam for k in all_kfs.tolist()]), len(local),
        slam_map.points.positions[keep_pts].astype(np.float64), pose_idx, np.searchsorted(keep_pts, obs.point_ids),
        obs.uv, obs.u_right, np.asarray(cfg.level_scales, np.float64)[obs.level], cam.fx, cam.fy, cam.cx, cam.cy,
        cfg.bf_m_px, cfg.disparity_sigma_ratio, float(np.sqrt(CHI2_STEREO)), float(np.sqrt(CHI2_MONO)),
    )


def _solve_gtsam(slam_map: SlamMap, local: list[int], fixed: list[int], keep_pts: npt.NDArray[np.int64], obs: Observations,
                 cam: CameraIntrinsics, cfg: LocalBAConfig, stop: Callable[[], bool] | None,
                 factors: FactorCache | None) -> tuple[dict[int, F64] | None, int, bool]:
    """gtsam's LM on the window's factor graph; writes the result into the map. Returns (poses of `local` before,
    or None when gtsam failed and nothing was written, iterations, stopped)."""
    scales = np.asarray(cfg.level_scales)
    all_kfs = local + fixed
    poses = {k: slam_map.keyframes[k].T_world_cam for k in all_kfs}

    # 3. Graph: fixed poses (they fix the gauge), robust reprojection factors.
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for k in all_kfs:
        values.insert(X(k), gtsam.Pose3(poses[k]))
    # Fixed keyframes: a very tight prior (1e-6 rad / m; rotation first) instead of a hard
    # NonlinearEquality, whose constrained noise model forces gtsam onto its slow QR path.
    fixed_noise = gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)
    for k in fixed:
        graph.add(gtsam.PriorFactorPose3(X(k), gtsam.Pose3(poses[k]), fixed_noise))
    l_keys = point_keys(keep_pts).tolist()
    insert_point, positions = values.insertPoint3, slam_map.points.positions
    for key, pid in zip(l_keys, keep_pts.tolist()):
        insert_point(key, positions[pid])
    add_reprojection_factors(graph, obs, cam, cfg.bf_m_px, scales, cfg.disparity_sigma_ratio, factors)

    # 4. Optimise.
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(cfg.iterations)
    try:
        result, iterations, stopped = optimise(graph, values, params, stop)
    except RuntimeError:
        # Cheirality or an indeterminate system: keep the map as it was.
        return None, -1, False

    # 5. Write back (the caller erases outlier observations).
    before = {k: slam_map.keyframes[k].T_world_cam for k in local}
    for k in local:
        slam_map.keyframes[k].T_world_cam = result.atPose3(X(k)).matrix()
    at_point = result.atPoint3
    new_pos = np.array([at_point(key) for key in l_keys])
    slam_map.points.positions[keep_pts] = new_pos
    return before, iterations, stopped
