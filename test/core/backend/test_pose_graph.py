"""Pose-graph optimisation removes an injected loop drift (synthetic square loop, ground truth known)."""

from __future__ import annotations

import numpy as np

from changing_slam_ros.core.backend.pose_graph import (
    EdgeKind,
    PoseGraphEdge,
    correct_points,
    essential_graph_edges,
    graph_error,
    optimise_pose_graph,
    relative_edges,
)
from changing_slam_ros.core.geometry.se3 import invert, make_pose, rotation_angle_rad


def _rot_y(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def square_loop(n_per_side: int = 10, side_m: float = 4.0) -> dict[int, np.ndarray]:
    """Ground-truth camera-to-world poses walking a square in the x-z plane, turning 90 deg at corners, back to start."""
    poses, kf_id = {}, 0
    pos = np.zeros(3)
    yaw = 0.0
    step = side_m / n_per_side
    for _side in range(4):
        for _ in range(n_per_side):
            poses[kf_id] = make_pose(_rot_y(yaw), pos.copy())
            kf_id += 1
            pos = pos + _rot_y(yaw) @ np.array([0.0, 0.0, step])  # optical z forward
        yaw += np.pi / 2
    return poses


def drifted(truth: dict[int, np.ndarray], yaw_bias_rad: float, scale_bias: float, seed: int = 0) -> dict[int, np.ndarray]:
    """Chain the true relative motions with a yaw bias and a length bias per step (dead reckoning)."""
    rng = np.random.default_rng(seed)
    ids = sorted(truth)
    out = {ids[0]: truth[ids[0]].copy()}
    for a, b in zip(ids, ids[1:]):
        rel = invert(truth[a]) @ truth[b]
        noisy = make_pose(_rot_y(yaw_bias_rad + rng.normal(0, 0.002)) @ rel[:3, :3], rel[:3, 3] * scale_bias)
        out[b] = out[a] @ noisy
    return out


def position_errors(est: dict[int, np.ndarray], truth: dict[int, np.ndarray]) -> np.ndarray:
    return np.array([np.linalg.norm(est[k][:3, 3] - truth[k][:3, 3]) for k in sorted(truth)])


def test_pose_graph_removes_injected_loop_drift_on_a_square():
    truth = square_loop()
    est = drifted(truth, yaw_bias_rad=np.radians(0.6), scale_bias=1.03)
    ids = sorted(truth)
    first, last = ids[0], ids[-1]
    edges = relative_edges(est, zip(ids, ids[1:]), EdgeKind.SPANNING_TREE)
    # the loop: the last keyframe sees the first again; verification measures the true relative pose
    edges.append(PoseGraphEdge(first, last, invert(truth[first]) @ truth[last], EdgeKind.LOOP))
    before = position_errors(est, truth)
    corrected = optimise_pose_graph(est, edges, fixed_id=first)
    after = position_errors(corrected, truth)
    # drift of several decimetres at the loop end; afterwards the loop end is where it should be
    assert before[-1] > 0.5
    assert after[-1] < 0.05 * before[-1]
    rmse_before = float(np.sqrt(np.mean(before**2)))
    rmse_after = float(np.sqrt(np.mean(after**2)))
    print(f"square loop: end error {before[-1]:.3f} -> {after[-1]:.3f} m, RMSE {rmse_before:.3f} -> {rmse_after:.3f} m")
    assert rmse_after < 0.35 * rmse_before, (rmse_before, rmse_after)
    # the fixed keyframe has not moved, the loop edge is satisfied
    np.testing.assert_allclose(corrected[first], est[first], atol=1e-6)
    loop_err = invert(invert(corrected[first]) @ corrected[last]) @ (invert(truth[first]) @ truth[last])
    assert np.linalg.norm(loop_err[:3, 3]) < 0.02
    assert rotation_angle_rad(loop_err[:3, :3]) < np.radians(1.0)  # 1/40 of the 23 deg yaw drift stays on the loop edge
    assert graph_error(corrected, edges) < 0.05 * graph_error(est, edges)


def test_pose_graph_without_loop_edge_keeps_the_odometry():
    truth = square_loop(n_per_side=5)
    est = drifted(truth, np.radians(1.0), 1.02)
    ids = sorted(est)
    edges = relative_edges(est, zip(ids, ids[1:]), EdgeKind.SPANNING_TREE)
    out = optimise_pose_graph(est, edges, fixed_id=ids[0])
    for k in ids:
        np.testing.assert_allclose(out[k], est[k], atol=1e-6)


def test_essential_graph_keeps_strong_covisibility_once_and_the_tree():
    poses = {i: make_pose(np.eye(3), np.array([i, 0.0, 0.0])) for i in range(4)}
    parent = {0: None, 1: 0, 2: 1, 3: 2}
    cov = {0: {1: 300, 2: 120, 3: 20}, 1: {0: 300, 2: 200}, 2: {0: 120, 1: 200}, 3: {0: 20}}
    edges = essential_graph_edges(poses, parent, cov, min_covisibility_weight=100)
    pairs = sorted((min(e.i, e.j), max(e.i, e.j), e.kind) for e in edges)
    assert pairs == [
        (0, 1, EdgeKind.SPANNING_TREE),
        (0, 2, EdgeKind.COVISIBILITY),
        (1, 2, EdgeKind.SPANNING_TREE),
        (2, 3, EdgeKind.SPANNING_TREE),
    ]
    e02 = next(e for e in edges if (e.i, e.j) == (0, 2))
    np.testing.assert_allclose(e02.T_i_j[:3, 3], [2.0, 0.0, 0.0])


def test_points_follow_their_reference_keyframe_correction():
    before = {0: np.eye(4), 1: make_pose(np.eye(3), np.array([1.0, 0, 0]))}
    after = {0: np.eye(4), 1: make_pose(_rot_y(np.pi / 2), np.array([1.0, 0, 1.0]))}
    pts = {10: np.array([1.0, 0.0, 2.0]), 11: np.array([0.0, 0.0, 1.0]), 12: np.array([5.0, 5.0, 5.0])}
    out = correct_points(pts, {10: 1, 11: 0}, before, after)
    # point 10 is 2 m ahead of keyframe 1; after the correction keyframe 1 looks along +x from (1, 0, 1)
    np.testing.assert_allclose(out[10], [3.0, 0.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(out[11], pts[11])
    np.testing.assert_allclose(out[12], pts[12])


def test_keyframes_not_connected_to_the_fixed_one_keep_their_pose_and_do_not_break_the_solve():
    truth = square_loop(n_per_side=4)
    est = drifted(truth, np.radians(1.0), 1.02)
    ids = sorted(est)
    edges = relative_edges(est, zip(ids[:8], ids[1:8]), EdgeKind.SPANNING_TREE)  # 0..7 chained
    edges += relative_edges(est, zip(ids[9:], ids[10:]), EdgeKind.SPANNING_TREE)  # 9..15: a floating island
    edges.append(PoseGraphEdge(0, 7, invert(truth[0]) @ truth[7], EdgeKind.LOOP))
    out = optimise_pose_graph(est, edges, fixed_id=0)
    for k in [8, *ids[9:]]:
        np.testing.assert_array_equal(out[k], est[k])
    assert np.linalg.norm(out[7][:3, 3] - truth[7][:3, 3]) < 0.5 * np.linalg.norm(est[7][:3, 3] - truth[7][:3, 3])
