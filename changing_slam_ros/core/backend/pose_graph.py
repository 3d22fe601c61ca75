"""SE(3) pose-graph optimisation over keyframes with GTSAM (ORB-SLAM's essential graph, metric scale for RGB-D).

The graph has one `Pose3` variable X(id) per keyframe (camera-to-world, optical frame) and a
`BetweenFactorPose3` per edge. Odometry-like edges (spanning tree, strong covisibility) measure the
relative pose the keyframes had *before* the loop was found, so they resist bending the map; loop edges
measure the relative pose geometric verification found. Optimising spreads the loop's discrepancy over
the whole chain. Map points then follow their reference keyframe (`correct_points`).
"""

from __future__ import annotations

import enum
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import gtsam
import numpy as np
import numpy.typing as npt
from gtsam.symbol_shorthand import X

from changing_slam_ros.core.geometry.se3 import invert

F64 = npt.NDArray[np.float64]


class EdgeKind(enum.IntEnum):
    SPANNING_TREE = 0
    COVISIBILITY = 1
    LOOP = 2


@dataclass(frozen=True)
class PoseGraphEdge:
    """Measured relative pose `T_i_j` (4, 4): pose of keyframe j in keyframe i's camera frame."""

    i: int
    j: int
    T_i_j: F64
    kind: EdgeKind


@dataclass(frozen=True)
class PoseGraphConfig:
    """YAML section `loop.pose_graph`. Sigmas of `BetweenFactorPose3`, rotation (rad) then translation (m)."""

    odometry_sigma_rad: float = 0.01
    odometry_sigma_m: float = 0.01
    loop_sigma_rad: float = 0.01
    loop_sigma_m: float = 0.01
    huber_k_loop: float = 0.0  # > 0 wraps loop edges in a Huber kernel (whitened units)
    min_covisibility_weight: int = 100  # ORB-SLAM's essential graph keeps covisibility edges with >= 100 shared points
    max_iterations: int = 30
    relative_error_tol: float = 1e-6


def relative_edges(poses: Mapping[int, F64], pairs: Iterable[tuple[int, int]], kind: EdgeKind) -> list[PoseGraphEdge]:
    """Edges (i, j) measured from the current poses T_world_cam: T_i_j = T_world_i^-1 T_world_j."""
    out = []
    for i, j in pairs:
        if i in poses and j in poses and i != j:
            out.append(PoseGraphEdge(i, j, invert(poses[i]) @ poses[j], kind))
    return out


def essential_graph_edges(
    poses: Mapping[int, F64],
    spanning_parent: Mapping[int, int | None],
    covisibility: Mapping[int, Mapping[int, int] | Iterable[int]],
    min_covisibility_weight: int,
) -> list[PoseGraphEdge]:
    """Spanning-tree edges (parent, child) and covisibility edges from current poses, each pair once.

    `covisibility` maps id -> {neighbour id: shared points} (edges kept when weight >= min_covisibility_weight)
    or id -> iterable of neighbour ids (all kept: the caller already chose the strong ones)."""
    pairs_tree = [(p, c) for c, p in spanning_parent.items() if p is not None and p >= 0]
    seen = {tuple(sorted(p)) for p in pairs_tree}
    pairs_cov = []
    for i, nbrs in covisibility.items():
        if isinstance(nbrs, Mapping):
            strong = [j for j, w in nbrs.items() if w >= min_covisibility_weight]
        else:
            strong = list(nbrs)
        for j in strong:
            key = (min(i, j), max(i, j))
            if key not in seen:
                seen.add(key)
                pairs_cov.append(key)
    return relative_edges(poses, pairs_tree, EdgeKind.SPANNING_TREE) + relative_edges(
        poses, pairs_cov, EdgeKind.COVISIBILITY
    )


def optimise_pose_graph(
    initial_poses: Mapping[int, F64],
    edges: Iterable[PoseGraphEdge],
    fixed_id: int,
    config: PoseGraphConfig = PoseGraphConfig(),
) -> dict[int, F64]:
    """Optimise keyframe poses T_world_cam (4, 4) given relative-pose edges; returns the corrected poses.

    `initial_poses` are the starting values (typically the current poses with the loop side already moved
    by the loop correction, as ORB-SLAM propagates it before optimising). `fixed_id` is held in place.
    Keyframes not connected to `fixed_id` through edges keep their initial pose (a component without a fixed
    keyframe would have a free gauge and make the linear system singular).
    """
    if fixed_id not in initial_poses:
        raise ValueError(f"pose graph: fixed keyframe {fixed_id} has no initial pose")
    graph = gtsam.NonlinearFactorGraph()
    # 1. Noise models. Pose3 tangent order is (rx, ry, rz, tx, ty, tz): rotation sigmas (rad) first,
    #    then translation sigmas (m).
    odo_noise = gtsam.noiseModel.Diagonal.Sigmas(
        np.array([config.odometry_sigma_rad] * 3 + [config.odometry_sigma_m] * 3)
    )
    loop_noise: gtsam.noiseModel.Base = gtsam.noiseModel.Diagonal.Sigmas(
        np.array([config.loop_sigma_rad] * 3 + [config.loop_sigma_m] * 3)
    )
    if config.huber_k_loop > 0:
        loop_noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(config.huber_k_loop), loop_noise)
    # 2. Prior on one keyframe: relative-pose factors leave the whole graph free to move rigidly (a 6-DoF
    #    gauge freedom). Pinning the map's first keyframe fixes that gauge and keeps the map in the frame
    #    it was built in, so the loop correction moves the drifted end, not the origin. Depth makes scale
    #    observable, so no scale prior is needed (unlike monocular Sim(3)).
    #    A very tight diagonal prior (1e-6 rad, 1e-6 m) rather than a hard constraint, which LM handles poorly.
    prior_noise = gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)
    graph.add(gtsam.PriorFactorPose3(X(fixed_id), gtsam.Pose3(np.asarray(initial_poses[fixed_id])), prior_noise))
    # 3. One BetweenFactorPose3 per edge (measured pose of j in i's frame), over the component of fixed_id.
    kept = [e for e in edges if e.i in initial_poses and e.j in initial_poses and e.i != e.j]
    reached = _component(fixed_id, kept)
    used = {fixed_id}
    for e in kept:
        if e.i not in reached:
            continue
        noise = loop_noise if e.kind == EdgeKind.LOOP else odo_noise
        graph.add(gtsam.BetweenFactorPose3(X(e.i), X(e.j), gtsam.Pose3(np.asarray(e.T_i_j)), noise))
        used.update((e.i, e.j))
    # 4. Initial values and Levenberg-Marquardt.
    values = gtsam.Values()
    for kf_id in used:
        values.insert(X(kf_id), gtsam.Pose3(_orthonormal(initial_poses[kf_id])))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(config.max_iterations)
    params.setRelativeErrorTol(config.relative_error_tol)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    out = {k: np.array(v, dtype=np.float64, copy=True) for k, v in initial_poses.items()}
    for kf_id in used:
        out[kf_id] = result.atPose3(X(kf_id)).matrix()
    return out


def _component(start: int, edges: list[PoseGraphEdge]) -> set[int]:
    """Keyframe ids connected to `start` through edges (breadth first)."""
    adjacent: dict[int, list[int]] = {}
    for e in edges:
        adjacent.setdefault(e.i, []).append(e.j)
        adjacent.setdefault(e.j, []).append(e.i)
    seen = {start}
    frontier = [start]
    while frontier:
        nxt = []
        for k in frontier:
            for j in adjacent.get(k, ()):
                if j not in seen:
                    seen.add(j)
                    nxt.append(j)
        frontier = nxt
    return seen


def graph_error(poses: Mapping[int, F64], edges: Iterable[PoseGraphEdge]) -> float:
    """Sum of squared edge residuals (rotation rad^2 + translation m^2), unweighted: a diagnostic."""
    total = 0.0
    for e in edges:
        err = invert(e.T_i_j) @ invert(poses[e.i]) @ poses[e.j]
        total += float(np.sum(gtsam.Pose3.Logmap(gtsam.Pose3(_orthonormal(err))) ** 2))
    return total


def correct_points(
    point_positions: Mapping[int, F64],
    reference_kf: Mapping[int, int],
    poses_before: Mapping[int, F64],
    poses_after: Mapping[int, F64],
) -> dict[int, F64]:
    """Move each map point (3,) rigidly with its reference keyframe: p' = T_after T_before^-1 p.

    Points without a reference keyframe (or whose keyframe did not move) are returned unchanged."""
    if not point_positions:
        return {}
    pids = list(point_positions)
    pos = np.array([point_positions[p] for p in pids], np.float64).reshape(-1, 3)
    refs = np.array([reference_kf.get(p, -1) for p in pids], np.int64)
    out_pos = pos.copy()
    for ref in np.unique(refs).tolist():
        if ref not in poses_before or ref not in poses_after:
            continue
        corr = poses_after[ref] @ invert(poses_before[ref])
        sel = refs == ref
        out_pos[sel] = pos[sel] @ corr[:3, :3].T + corr[:3, 3]
    return {pid: out_pos[i] for i, pid in enumerate(pids)}


def _orthonormal(T: F64) -> F64:
    """Re-orthonormalise the rotation of a 4x4 pose (accumulated float error would make Pose3 complain)."""
    T = np.array(T, dtype=np.float64, copy=True)
    u, _, vt = np.linalg.svd(T[:3, :3])
    r = u @ vt
    if np.linalg.det(r) < 0:
        u[:, -1] *= -1
        r = u @ vt
    T[:3, :3] = r
    return T
