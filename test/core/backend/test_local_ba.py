"""Local bundle adjustment (gtsam) on a synthetic map with known ground truth."""

from __future__ import annotations

import numpy as np

from changing_slam_ros.core.backend.local_ba import LocalBAConfig, local_bundle_adjust
from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.geometry.pose_optimizer import se3_exp_left
from changing_slam_ros.core.geometry.se3 import invert, make_pose, rotation_angle_rad
from changing_slam_ros.core.map.slam_map import SlamMap

CAM = CameraIntrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)
BF = 40.0


def _build_map(rng: np.random.Generator, pose_noise: float, point_noise_m: float):
    """Five keyframes moving sideways past 400 points; returns (map, true poses, true points)."""
    pts_true = np.column_stack([rng.uniform(-2, 2, 400), rng.uniform(-1.5, 1.5, 400), rng.uniform(2, 5, 400)])
    poses_true = [make_pose(np.eye(3), np.array([0.1 * k, 0.02 * k, 0.0])) for k in range(5)]
    m = SlamMap(0)
    m.points.add(
        pts_true + rng.normal(0, point_noise_m, pts_true.shape), np.zeros((400, 32), np.uint8), 0,
        np.arange(400), np.zeros(3), np.zeros(400, np.int64), np.array([1.2**i for i in range(8)]),
    )
    for k, T in enumerate(poses_true):
        pc = (pts_true - T[:3, 3]) @ T[:3, :3]
        uv = CAM.project(pc) + rng.normal(0, 0.5, (400, 2))
        depth = pc[:, 2].astype(np.float32)
        depth[::3] = 0.0  # a third monocular
        T_est = T if k < 2 else se3_exp_left(rng.normal(0, pose_noise, 6)) @ T
        kf = Keyframe(k, k, T_est, CAM, uv.astype(np.float32), np.zeros(400, np.int8),
                      np.zeros((400, 32), np.uint8), depth, np.arange(400, dtype=np.int64))
        m.add_keyframe(kf)
    for k in range(5):
        m.update_connections(k)
    return m, poses_true, pts_true


def _pose_errors(m: SlamMap, poses_true: list[np.ndarray]) -> tuple[float, float]:
    t, r = [], []
    for k, T in enumerate(poses_true):
        d = invert(T) @ m.keyframes[k].T_world_cam
        t.append(np.linalg.norm(d[:3, 3]))
        r.append(np.degrees(rotation_angle_rad(d[:3, :3])))
    return max(t), max(r)


def test_local_ba_lowers_reprojection_error_and_recovers_perturbed_poses() -> None:
    rng = np.random.default_rng(3)
    m, poses_true, pts_true = _build_map(rng, pose_noise=0.02, point_noise_m=0.02)
    t_before, _ = _pose_errors(m, poses_true)
    res = local_bundle_adjust(m, 4, LocalBAConfig(n_window=10, iterations=15, bf_m_px=BF))
    t_after, r_after = _pose_errors(m, poses_true)
    assert res.n_fixed >= 1  # the gauge is fixed by at least one keyframe
    assert res.rms_after_px < 0.5 * res.rms_before_px
    assert res.rms_after_px < 1.5
    assert t_before > 0.02 and t_after < 0.005 and r_after < 0.1
    err_pts = np.linalg.norm(m.points.positions[:400] - pts_true, axis=1)
    assert np.median(err_pts) < 0.04  # depth is weak at 2-5 m with a 7.6 cm virtual baseline


def test_local_ba_erases_gross_outlier_observations() -> None:
    rng = np.random.default_rng(4)
    m, poses_true, _ = _build_map(rng, pose_noise=0.005, point_noise_m=0.005)
    kf = m.keyframes[3]
    kf.keypoints_px[:20] += 40.0  # 20 wrong matches
    res = local_bundle_adjust(m, 4, LocalBAConfig(n_window=10, iterations=15, bf_m_px=BF))
    assert res.n_outliers_removed >= 20
    assert (kf.point_ids[:20] == -1).all()
    assert (kf.point_ids[20:] >= 0).mean() > 0.95
    t_after, _ = _pose_errors(m, poses_true)
    assert t_after < 0.005


def test_points_only_the_moved_keyframe_sees_follow_it() -> None:
    """A keyframe's own new points (one observation: left out of the BA) move with it when the BA moves it.

    Local mapping back-projects a new keyframe's points from its tracked pose; when the BA then corrects that
    pose, points left behind would disagree with it (frames tracked on those points end up stored against a
    keyframe that is elsewhere; regression test for the simulated one_chair scene).
    """
    rng = np.random.default_rng(5)
    m, poses_true, _ = _build_map(rng, pose_noise=0.03, point_noise_m=0.005)
    kf = m.keyframes[4]
    lone_true = np.column_stack([rng.uniform(-1, 1, 150), rng.uniform(-1, 1, 150), rng.uniform(1.5, 3, 150)])
    T_true = poses_true[4]
    pc = (lone_true - T_true[:3, 3]) @ T_true[:3, :3]  # camera frame of the true pose: what the keyframe measures
    lone_est = pc @ kf.T_world_cam[:3, :3].T + kf.T_world_cam[:3, 3]  # back-projected from the (wrong) tracked pose
    ids = m.points.add(lone_est, np.zeros((150, 32), np.uint8), 4, np.arange(400, 550), kf.T_world_cam[:3, 3],
                       np.zeros(150, np.int64), np.array([1.2**i for i in range(8)]))
    kf.point_ids = np.concatenate([kf.point_ids, ids])
    kf.keypoints_px = np.concatenate([kf.keypoints_px, CAM.project(pc).astype(np.float32)])
    kf.octaves = np.concatenate([kf.octaves, np.zeros(150, np.int8)])
    kf.descriptors = np.concatenate([kf.descriptors, np.zeros((150, 32), np.uint8)])
    kf.depths_m = np.concatenate([kf.depths_m, pc[:, 2].astype(np.float32)])
    for i, pid in zip(range(400, 550), ids.tolist()):
        m.points.observations[pid] = {4: i}
    err_before = np.linalg.norm(m.points.positions[ids] - lone_true, axis=1)
    normals_cam = m.points.normals[ids] @ kf.T_world_cam[:3, :3]
    local_bundle_adjust(m, 4, LocalBAConfig(n_window=10, iterations=15, bf_m_px=BF))
    err_after = np.linalg.norm(m.points.positions[ids] - lone_true, axis=1)
    assert np.median(err_before) > 0.03  # the tracked pose was off by a few centimetres
    assert np.max(err_after) < 0.01  # the BA corrected the pose and the points came along
    T = kf.T_world_cam
    np.testing.assert_allclose((m.points.positions[ids] - T[:3, 3]) @ T[:3, :3], pc, atol=1e-9)
    np.testing.assert_allclose(m.points.normals[ids] @ T[:3, :3], normals_cam, atol=1e-9)


SIM_CAM = CameraIntrinsics(320, 240, 262.5, 262.5, 159.5, 119.5)


def _rot_y(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])


def _after_a_turn(rng: np.random.Generator) -> tuple[SlamMap, list[np.ndarray]]:
    """Three keyframes facing a wall 3.1-3.7 m away (the simulator's 320x240 camera, exact depth, 0.6 px keypoint
    noise): 0 (the gauge), 1 turned 10 deg, 2 turned a further 35 deg and 6 cm on, so that 2 shares with 1 only
    the wall on one side of its image; every keyframe at its true pose."""
    poses = [make_pose(np.eye(3), np.zeros(3)), make_pose(_rot_y(-10), np.array([0.1, 0.0, 0.05])),
             make_pose(_rot_y(25), np.array([0.13, 0.0, 0.1]))]
    cand = np.column_stack([rng.uniform(-3, 3, 6000), rng.uniform(-1.2, 1.2, 6000), rng.uniform(3.1, 3.7, 6000)])
    vis = []
    for T in poses:
        pc = (cand - T[:3, 3]) @ T[:3, :3]
        uv = SIM_CAM.project(pc)
        vis.append((pc[:, 2] > 0.3) & (uv[:, 0] >= 0) & (uv[:, 0] < 320) & (uv[:, 1] >= 0) & (uv[:, 1] < 240))
    a = cand[vis[0] & vis[1] & ~vis[2]][:200]
    b = cand[vis[1] & vis[2]][:260]
    pts = np.vstack([a, b])
    seen = [np.arange(len(a)), np.arange(len(pts)), np.arange(len(a), len(pts))]
    m = SlamMap(0)
    m.points.add(pts.copy(), np.zeros((len(pts), 32), np.uint8), 0, np.arange(len(pts)), np.zeros(3),
                 np.zeros(len(pts), np.int64), np.array([1.2**i for i in range(8)]))
    for k, T in enumerate(poses):
        idx = seen[k]
        pc = (pts[idx] - T[:3, 3]) @ T[:3, :3]
        uv = SIM_CAM.project(pc) + rng.normal(0, 0.6, (len(idx), 2))
        m.add_keyframe(Keyframe(k, k, T.copy(), SIM_CAM, uv.astype(np.float32), np.zeros(len(idx), np.int8),
                                np.zeros((len(idx), 32), np.uint8), pc[:, 2].astype(np.float32), idx.astype(np.int64)))
    for k in range(3):
        m.update_connections(k)
    return m, poses


def test_a_keyframe_after_a_turn_stays_where_its_depth_puts_it() -> None:
    """Regression test (keyframe 19 of the simulated one_chair scene): after a turn the new keyframe shares a narrow part of its
    view, all at ~3.4 m, with its neighbour. The bearings alone leave a valley (sideways shift traded for rotation);
    only the depth closes it. Weighted as ORB-SLAM's virtual stereo (`disparity_sigma_ratio` 0: 1 px on u_r with
    bf 40, 28 cm of depth at 3.4 m), the BA slides keyframes started at their true poses 6-18 cm along it on this
    exact depth; weighing the depth as what it is (ratio 0.25, config/sim.yaml) keeps them within a few cm."""
    err_exact, err_orb = [], []
    for seed in range(4):
        for ratio, out in ((0.25, err_exact), (0.0, err_orb)):
            m, poses = _after_a_turn(np.random.default_rng(seed))
            res = local_bundle_adjust(m, 2, LocalBAConfig(bf_m_px=BF, disparity_sigma_ratio=ratio))
            assert (res.n_local, res.n_fixed) == (2, 1)
            out.append(max(np.linalg.norm((invert(poses[k]) @ m.keyframes[k].T_world_cam)[:3, 3]) for k in (1, 2)))
    assert max(err_exact) < 0.04
    assert np.mean(err_orb) > 0.08  # the same data, Kinect weighting: the slide this test would catch


def test_the_chi2_of_outlier_removal_is_the_factor_graph_s_own() -> None:
    """`reprojection_chi2` (outlier test) and `stereo_noise` (the BA's factors) weigh an RGB-D keypoint alike."""
    import gtsam
    from gtsam.symbol_shorthand import L, X

    from changing_slam_ros.core.backend.local_ba import Observations, reprojection_chi2, stereo_noise

    T = make_pose(_rot_y(7), np.array([0.1, -0.05, 0.2]))
    p = np.array([[0.4, -0.3, 3.2]])
    meas_u, meas_v, meas_ur = 190.3, 70.2, 175.9  # off the prediction in u, v and disparity
    scales = np.array([1.2**i for i in range(8)])
    for ratio in (0.0, 0.25, 1.0):
        for level in (0, 3):
            obs = Observations(np.array([0]), np.array([0]), np.array([[meas_u, meas_v]]), np.array([meas_ur]),
                               np.array([level]), np.array([0]))
            _, chi2 = reprojection_chi2({0: T}, p, obs, SIM_CAM.fx, SIM_CAM.fy, SIM_CAM.cx, SIM_CAM.cy, BF, scales, ratio)
            k = gtsam.Cal3_S2Stereo(SIM_CAM.fx, SIM_CAM.fy, 0.0, SIM_CAM.cx, SIM_CAM.cy, BF / SIM_CAM.fx)
            f = gtsam.GenericStereoFactor3D(gtsam.StereoPoint2(meas_u, meas_ur, meas_v),
                                            stereo_noise(float(scales[level]), ratio), X(0), L(0), k)
            values = gtsam.Values()
            values.insert(X(0), gtsam.Pose3(T))
            values.insert(L(0), p[0])
            assert chi2[0] > 1.0
            np.testing.assert_allclose(2.0 * f.error(values), chi2[0], rtol=1e-6)


def test_stop_that_never_fires_gives_gtsams_optimize_bit_for_bit() -> None:
    """`optimise` with a `stop` (asked through gtsam's iteration hook, real time) equals `optimize()` while stop says no."""
    maps = [_build_map(np.random.default_rng(5), pose_noise=0.02, point_noise_m=0.02)[0] for _ in range(2)]
    asked: list[int] = []
    a = local_bundle_adjust(maps[0], 4, LocalBAConfig(n_window=10, iterations=15, bf_m_px=BF, solver="gtsam"))
    b = local_bundle_adjust(maps[1], 4, LocalBAConfig(n_window=10, iterations=15, bf_m_px=BF, solver="gtsam"),
                            stop=lambda: asked.append(1) is not None)  # always False
    assert not b.stopped and b.iterations >= 2 and len(asked) == b.iterations + 1  # before, and after each
    assert a.rms_after_px == b.rms_after_px
    for k in range(5):
        assert maps[0].keyframes[k].T_world_cam.tobytes() == maps[1].keyframes[k].T_world_cam.tobytes()
    assert maps[0].points.positions[:].tobytes() == maps[1].points.positions[:].tobytes()


def test_stop_cuts_the_ba_short_with_what_it_reached() -> None:
    """A keyframe waiting (stop says yes) ends the BA after the iterations run so far: the error is lowered
    less than by the full BA, never raised; stopped before the first iteration nothing moves."""
    rng_seed = 3
    full_map, poses_true, _ = _build_map(np.random.default_rng(rng_seed), pose_noise=0.02, point_noise_m=0.02)
    full = local_bundle_adjust(full_map, 4, LocalBAConfig(n_window=10, iterations=15, bf_m_px=BF, solver="gtsam"))
    calls = iter([False, True])  # one iteration, then a keyframe arrives
    m1, _, _ = _build_map(np.random.default_rng(rng_seed), pose_noise=0.02, point_noise_m=0.02)
    one = local_bundle_adjust(m1, 4, LocalBAConfig(n_window=10, iterations=15, bf_m_px=BF, solver="gtsam"), stop=lambda: next(calls))
    assert one.stopped and one.iterations == 1 and full.iterations == -1
    assert full.rms_after_px < one.rms_after_px < one.rms_before_px
    m0, _, _ = _build_map(np.random.default_rng(rng_seed), pose_noise=0.02, point_noise_m=0.02)
    poses0 = [m0.keyframes[k].T_world_cam.copy() for k in range(5)]
    none = local_bundle_adjust(m0, 4, LocalBAConfig(n_window=10, iterations=15, bf_m_px=BF, solver="gtsam"), stop=lambda: True)
    assert none.stopped and none.iterations == 0
    assert all(np.array_equal(poses0[k], m0.keyframes[k].T_world_cam) for k in range(5))


def test_factor_cache_reuses_the_previous_bas_factors_with_the_same_result() -> None:
    """Successive BAs with a `FactorCache` (local mapping) take most factors from the previous one and end
    bit for bit where BAs building every factor end; a changed setting (bf) empties it."""
    from changing_slam_ros.core.backend.local_ba import FactorCache

    maps = [_build_map(np.random.default_rng(8), pose_noise=0.02, point_noise_m=0.02)[0] for _ in range(2)]
    cache = FactorCache()
    cfg = LocalBAConfig(n_window=10, iterations=15, bf_m_px=BF, solver="gtsam")
    for kf_id in (4, 3, 4):
        local_bundle_adjust(maps[0], kf_id, cfg)
        local_bundle_adjust(maps[1], kf_id, cfg, factors=cache)
    assert cache.reused > 1000  # ~1200 observations per BA, the 2nd and 3rd BA reuse them
    for k in range(5):
        assert maps[0].keyframes[k].T_world_cam.tobytes() == maps[1].keyframes[k].T_world_cam.tobytes()
    assert maps[0].points.positions[:].tobytes() == maps[1].points.positions[:].tobytes()
    reused = cache.reused
    local_bundle_adjust(maps[1], 4, LocalBAConfig(n_window=10, iterations=15, bf_m_px=BF * 2, solver="gtsam"), factors=cache)
    assert cache.reused == reused


def _outlier_map(seed: int) -> SlamMap:
    """`_build_map` with 15 wrong matches in keyframe 3 (the Huber kernel at work, outliers to erase)."""
    m, _, _ = _build_map(np.random.default_rng(seed), pose_noise=0.02, point_noise_m=0.02)
    m.keyframes[3].keypoints_px[:15] += 25.0
    return m


def test_schur_solver_ends_where_gtsam_does() -> None:
    """The numpy Schur-complement LM (`schur_lm`) solves local BA's problem as gtsam's LM does: same iterations,
    same outliers erased, truth recovered, for the three noise settings (ORB-SLAM's, Kinect-class depth, exact
    depth). The full window (4 poses, 1 fixed; 4-5 iterations) ends within 1e-7 m (poses) and 1e-5 m (points) of
    gtsam; a 2-keyframe window with 2 fixed (9-15 iterations, ~500 observations erased: a weak problem) within
    1e-5 m and 0.5 mm (points 2-5 m deep on a 7.6 cm virtual baseline)."""
    for ratio in (0.0, 1.0, 0.25):
        for kf_id, window in ((4, 10), (4, 2)):
            maps = [_outlier_map(11), _outlier_map(11)]
            poses_true = _build_map(np.random.default_rng(11), 0.02, 0.02)[1]
            res = [local_bundle_adjust(m, kf_id, LocalBAConfig(n_window=window, iterations=15, bf_m_px=BF,
                                                              disparity_sigma_ratio=ratio, solver=s), stop=lambda: False)
                   for m, s in zip(maps, ("gtsam", "schur"))]  # fmt: skip
            g, s = res
            assert s.iterations == g.iterations >= 2
            assert (s.n_local, s.n_fixed, s.n_points, s.n_outliers_removed) == (g.n_local, g.n_fixed, g.n_points, g.n_outliers_removed)
            assert g.n_outliers_removed >= 15
            tol_pose, tol_point = (1e-7, 1e-5) if window == 10 else (1e-5, 5e-4)
            np.testing.assert_allclose(s.rms_after_px, g.rms_after_px, rtol=1e-5)
            for k in range(5):
                d = invert(maps[0].keyframes[k].T_world_cam) @ maps[1].keyframes[k].T_world_cam
                assert np.linalg.norm(d[:3, 3]) < tol_pose and rotation_angle_rad(d[:3, :3]) < tol_pose
            assert np.abs(maps[0].points.positions[:] - maps[1].points.positions[:]).max() < tol_point
            if window == 10:
                assert _pose_errors(maps[1], poses_true)[0] < 0.005


def test_schur_cost_is_the_factor_graphs_error() -> None:
    """`schur_lm`'s cost of a window equals gtsam's error of the same graph: stereo and mono factors, the Huber
    kernel active (wrong matches), a point behind a camera (gtsam's stand-in residual), each noise setting."""
    import gtsam
    from gtsam.symbol_shorthand import L, X

    from changing_slam_ros.core.backend import schur_lm
    from changing_slam_ros.core.backend.local_ba import add_reprojection_factors, gather_observations, schur_problem

    for ratio in (0.0, 0.25, 1.0):
        m = _outlier_map(12)
        m.points.positions[7] = m.keyframes[2].T_world_cam[:3, 3] - np.array([0.0, 0.0, 1.0])  # behind the cameras
        cfg = LocalBAConfig(bf_m_px=BF, disparity_sigma_ratio=ratio)
        pids = np.arange(400, dtype=np.int64)
        obs = gather_observations(m, [1, 2, 3, 4, 0], pids, BF)
        problem = schur_problem(m, [1, 2, 3, 4], [0], pids, obs, CAM, cfg)
        wh = schur_lm._Whitening(problem)
        R_cw = np.transpose(problem.T_world_cam[:, :3, :3], (0, 2, 1))
        t_cw = -np.einsum("nij,nj->ni", R_cw, problem.T_world_cam[:, :3, 3])
        r, _, front = schur_lm._residuals(problem, wh, R_cw, t_cw, problem.points)
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        add_reprojection_factors(graph, obs, CAM, BF, cfg.level_scales, ratio)
        for k in range(5):
            values.insert(X(k), gtsam.Pose3(m.keyframes[k].T_world_cam))
        for p in pids.tolist():
            values.insert(L(p), m.points.positions[p])
        assert (~front).sum() >= 4 and (np.linalg.norm(r, axis=1) > wh.k).sum() >= 15 + 4
        np.testing.assert_allclose(schur_lm._cost(r, wh.k), graph.error(values), rtol=1e-9)


def test_schur_solver_stops_like_gtsams_loop() -> None:
    """`stop` with the Schur solver: asked before the first iteration (yes: nothing moves) and after each but
    the last, as gtsam's iteration hook; while it says no the result is the one without `stop`."""
    def fresh() -> SlamMap:
        return _build_map(np.random.default_rng(13), pose_noise=0.02, point_noise_m=0.02)[0]

    m = fresh()
    poses0 = [m.keyframes[k].T_world_cam.copy() for k in range(5)]
    cfg = LocalBAConfig(n_window=10, iterations=15, bf_m_px=BF, solver="schur")
    none = local_bundle_adjust(m, 4, cfg, stop=lambda: True)
    assert none.stopped and none.iterations == 0
    assert all(np.array_equal(poses0[k], m.keyframes[k].T_world_cam) for k in range(5))
    calls = iter([False, True])
    one = local_bundle_adjust(fresh(), 4, cfg, stop=lambda: next(calls))
    full = local_bundle_adjust(fresh(), 4, cfg)
    asked: list[int] = []
    never = local_bundle_adjust(fresh(), 4, cfg, stop=lambda: asked.append(1) is not None)  # always False
    assert not never.stopped and len(asked) == never.iterations + 1  # before, and after each (as gtsam's hook)
    assert never.rms_after_px == full.rms_after_px
    assert one.stopped and one.iterations == 1 and not full.stopped and full.iterations >= 2
    assert full.rms_after_px < one.rms_after_px < one.rms_before_px


def test_unknown_solver_is_refused() -> None:
    import pytest

    with pytest.raises(ValueError, match="solver 'ceres'"):
        LocalBAConfig(solver="ceres")


def test_schur_solver_sums_a_point_seen_twice_by_one_keyframe() -> None:
    """Two keypoints of one keyframe holding the same point are two residuals in gtsam's graph; the Schur
    solver sums both into the point-pose block too (its scatter path for repeated pairs) and ends where gtsam does."""
    maps = [_outlier_map(14), _outlier_map(14)]
    for m in maps:
        kf = m.keyframes[3]
        kf.point_ids[1] = kf.point_ids[4]  # keypoint 1 now holds point 4 as well (and loses point 1 in keyframe 3)
        kf.keypoints_px[1] = kf.keypoints_px[4] + np.float32(0.7)
        kf.depths_m[1] = kf.depths_m[4]
    res = [local_bundle_adjust(m, 4, LocalBAConfig(n_window=10, iterations=15, bf_m_px=BF, solver=s), stop=lambda: False)
           for m, s in zip(maps, ("gtsam", "schur"))]  # fmt: skip
    assert res[0].iterations == res[1].iterations >= 2
    np.testing.assert_allclose(res[1].rms_after_px, res[0].rms_after_px, rtol=1e-6)
    for k in range(5):
        d = invert(maps[0].keyframes[k].T_world_cam) @ maps[1].keyframes[k].T_world_cam
        assert np.linalg.norm(d[:3, 3]) < 1e-7
    assert np.abs(maps[0].points.positions[:] - maps[1].points.positions[:]).max() < 1e-5
