"""Eq. 5 of the point-correlation segmentation (Dai et al. 2021): point positions from relative measurements.

    z_ijk = y_ik - y_jk                                          (eq. 4)
    min_P  sum_ijk || z_ijk - [g(T_k p_i) - g(T_k p_j)] ||_huber  (eq. 5)

with y = g(p_cam) = [u, v, d] (or [x, y, z]) the RGB-D observation and T_k the known world-to-camera pose
of frame k. Iteratively reweighted Gauss-Newton over all points at once: the measurements are flattened
to one row per (edge, frame) (`_Problem`), each step solves one block-sparse (3M x 3M) system
(`_NormalEquations`) by block-Jacobi preconditioned conjugate gradients, and after each round the
measurements whose whitened error exceeds the outlier threshold are left out of the next.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt
import scipy.sparse as sp  # type: ignore[import-untyped]
from scipy.sparse.linalg import cg  # type: ignore[import-untyped]

from changing_slam_ros.core.geometry.camera import CameraIntrinsics

from changing_slam_ros.core.movers.correlation_window import CorrelationWindow, SegmentationConfig

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
BoolArr = npt.NDArray[np.bool_]


def _observation(points_cam: F64, camera: CameraIntrinsics, model: str) -> F64:
    """The RGB-D observation g(p) (N, 3) of points (N, 3) in the camera frame: [u, v, d] or [x, y, z]."""
    if model == "point_3d":
        return points_cam.copy()
    x, y, z = points_cam[:, 0], points_cam[:, 1], points_cam[:, 2]
    return np.stack([camera.fx * x / z + camera.cx, camera.fy * y / z + camera.cy, z], axis=1)


def _observation_sigma(points_cam: F64, camera: CameraIntrinsics, cfg: SegmentationConfig) -> F64:
    """Per-component std (N, 3) of y = g(p) for measured points (N, 3), in the units of the model."""
    z = points_cam[:, 2]
    sigma_d = np.maximum(cfg.depth_sigma_coeff_per_m * z * z, cfg.depth_sigma_min_m)
    if cfg.observation_model == "point_3d":
        return np.stack([cfg.sigma_px * z / camera.fx, cfg.sigma_px * z / camera.fy, sigma_d], axis=1)
    return np.stack([np.full_like(z, cfg.sigma_px), np.full_like(z, cfg.sigma_px), sigma_d], axis=1)


@dataclass
class _Problem:
    """The measurements of eq. 4, flattened: one row per (edge, frame) with both points observed."""

    edge: I64  # (Q,) edge index
    i: I64  # (Q,) first point (index into the optimised points)
    j: I64  # (Q,) second point
    z_meas: F64  # (Q, 3) y_ik - y_jk
    whiten: F64  # (Q, 3) 1 / std of each component of z_ijk
    frame: I64  # (Q,) frame of the measurement
    R_cam_world: F64  # (K, 3, 3) world-to-camera rotation of each frame
    t_cam_world: F64  # (K, 3)


def _jacobian_world(points_cam: F64, r_cam_world: F64, camera: CameraIntrinsics, model: str) -> F64:
    """d g(R p + t) / d p (Q, 3, 3) = dg/dp_cam R for camera-frame points (Q, 3) and rotations (Q, 3, 3).

    Written row by row: the pixel rows of dg/dp_cam have two non-zeros each, the depth row is (0, 0, 1).
    """
    if model == "point_3d":
        return r_cam_world
    inv_z = 1.0 / points_cam[:, 2:3]
    r0, r1, r2 = r_cam_world[:, 0, :], r_cam_world[:, 1, :], r_cam_world[:, 2, :]
    row0 = camera.fx * inv_z * (r0 - points_cam[:, 0:1] * inv_z * r2)
    row1 = camera.fy * inv_z * (r1 - points_cam[:, 1:2] * inv_z * r2)
    return np.stack([row0, row1, r2], axis=1)


def _residuals(points_world: F64, prob: _Problem, camera: CameraIntrinsics, model: str) -> tuple[F64, F64, F64]:
    """Whitened residuals r (Q, 3) of eq. 5 and their Jacobians wrt p_i and p_j, each (Q, 3, 3)."""
    # Camera-frame point, observation and Jacobian once per (frame, point), then gathered per measurement:
    # a point takes part in about seven edges, so this is several times less work than per measurement.
    m = len(points_world)
    p_cam = (np.einsum("kab,mb->kma", prob.R_cam_world, points_world) + prob.t_cam_world[:, None, :]).reshape(-1, 3)
    with np.errstate(divide="ignore", invalid="ignore"):  # points behind a frame they are not measured in
        g = _observation(p_cam, camera, model)
        jac = _jacobian_world(p_cam, np.repeat(prob.R_cam_world, m, axis=0), camera, model)
    qi, qj = prob.frame * m + prob.i, prob.frame * m + prob.j
    w = prob.whiten[:, :, None]
    res = prob.whiten * (prob.z_meas - (g[qi] - g[qj]))
    d_pi = -w * jac[qi]
    d_pj = w * jac[qj]
    return res, d_pi, d_pj


class _NormalEquations:
    """The (3M, 3M) normal matrix of eq. 5 plus anchors, in 3x3 blocks (BSR): one diagonal block per point
    and two off-diagonal blocks per edge. The block layout, and the sparse 0/1 matrices that sum the
    per-measurement blocks into it, are fixed per problem and built once."""

    def __init__(self, edges: I64, prob: _Problem, m: int) -> None:
        n_edges = len(edges)
        block_row = np.concatenate([np.arange(m), edges[:, 0], edges[:, 1]])
        block_col = np.concatenate([np.arange(m), edges[:, 1], edges[:, 0]])
        self.order = np.lexsort((block_col, block_row))
        self.indices = block_col[self.order].astype(np.int32)
        self.indptr = np.searchsorted(block_row[self.order], np.arange(m + 1)).astype(np.int32)
        self.m, self.n_edges = m, n_edges
        self.i, self.j, self.edge = prob.i, prob.j, prob.edge
        q = len(prob.edge)
        ones, rows = np.ones(q), np.arange(q)
        # (size, Q) summation matrices: one sparse product replaces nine bincounts per block sum.
        self.sum_i = sp.csr_matrix((ones, (prob.i, rows)), shape=(m, q))
        self.sum_j = sp.csr_matrix((ones, (prob.j, rows)), shape=(m, q))
        self.sum_edge = sp.csr_matrix((ones, (prob.edge, rows)), shape=(n_edges, q))

    def matrix(self, d_pi: F64, d_pj: F64, weights: F64, anchor_info: F64) -> tuple[sp.bsr_matrix, F64]:
        """H = sum_q w_q J_q^T J_q + diag(anchor information) for Jacobian blocks (Q, 3, 3), weights (Q,).

        Also returns H's diagonal blocks (M, 3, 3), the block-Jacobi preconditioner.
        """
        wd_pi_t = np.swapaxes(weights[:, None, None] * d_pi, 1, 2)
        q = len(weights)
        ii = np.matmul(wd_pi_t, d_pi).reshape(q, 9)
        jj = np.matmul(np.swapaxes(weights[:, None, None] * d_pj, 1, 2), d_pj).reshape(q, 9)
        ij = np.matmul(wd_pi_t, d_pj).reshape(q, 9)
        diag = np.asarray(self.sum_i @ ii + self.sum_j @ jj).reshape(self.m, 3, 3)
        diag += anchor_info[:, None, None] * np.eye(3)
        off = np.asarray(self.sum_edge @ ij).reshape(self.n_edges, 3, 3)
        blocks = np.concatenate([diag, off, np.swapaxes(off, 1, 2)])[self.order]
        shape = (3 * self.m, 3 * self.m)
        return sp.bsr_matrix((blocks, self.indices, self.indptr), shape=shape), diag

    def gradient(self, d_pi: F64, d_pj: F64, weighted_res: F64) -> F64:
        """sum_q J_q^T w_q r_q per point (M, 3) for weighted residuals (Q, 3)."""
        g_i = np.einsum("qai,qa->qi", d_pi, weighted_res)
        g_j = np.einsum("qai,qa->qi", d_pj, weighted_res)
        return np.asarray(self.sum_i @ g_i + self.sum_j @ g_j)


def _gauss_newton_step(
    points_world: F64,
    anchor_world: F64,
    anchor_info: F64,
    prob: _Problem,
    normal: _NormalEquations,
    residuals: tuple[F64, F64, F64],
    weights: F64,
    rtol: float = 1e-3,
) -> F64:
    """One IRLS Gauss-Newton update of all points (M, 3) for the weighted residuals plus the anchors.

    `anchor_world` (M, 3) and `anchor_info` (M,) (isotropic information, 1/m^2) are the point anchors;
    `residuals` is `_residuals` at `points_world`, `weights` (Q,) the IRLS weights.
    """
    m = len(points_world)
    res, d_pi, d_pj = residuals
    hessian, block_diag = normal.matrix(d_pi, d_pj, weights, anchor_info)
    gradient = normal.gradient(d_pi, d_pj, weights[:, None] * res)
    gradient += anchor_info[:, None] * (points_world - anchor_world)
    # H is symmetric positive definite (the anchors make it so) and well conditioned once each point's
    # 3x3 block is inverted: block-Jacobi preconditioned conjugate gradients beat a sparse LU here.
    inv_blocks = np.linalg.inv(block_diag)
    precond = sp.bsr_matrix((inv_blocks, np.arange(m), np.arange(m + 1)), shape=hessian.shape)
    delta, _ = cg(hessian, -gradient.ravel(), M=precond, rtol=rtol, maxiter=500)
    return np.asarray(points_world + delta.reshape(m, 3), dtype=np.float64)


def _huber_weights(chi: F64, delta: float) -> F64:
    """IRLS weights of the Huber norm for whitened residual norms (Q,)."""
    return np.where(chi <= delta, 1.0, delta / np.maximum(chi, 1e-12))


def _build_problem(window: CorrelationWindow, keep: I64, edges: I64, cfg: SegmentationConfig) -> _Problem:
    """Measurements of every edge (indices into `keep`) in every frame where both points are seen."""
    obs = window.observed[:, keep]  # (K, M')
    both = obs[:, edges[:, 0]] & obs[:, edges[:, 1]]  # (K, E)
    frame, edge = np.nonzero(both)
    i, j = edges[edge, 0], edges[edge, 1]
    pts = window.points_cam[:, keep]
    pi, pj = pts[frame, i], pts[frame, j]
    gi = _observation(pi, window.camera, cfg.observation_model)
    gj = _observation(pj, window.camera, cfg.observation_model)
    var = _observation_sigma(pi, window.camera, cfg) ** 2 + _observation_sigma(pj, window.camera, cfg) ** 2
    T_cam_world = np.linalg.inv(window.T_world_cam)
    return _Problem(
        edge=edge.astype(np.int64),
        i=i,
        j=j,
        z_meas=gi - gj,
        whiten=1.0 / np.sqrt(var),
        frame=frame.astype(np.int64),
        R_cam_world=np.ascontiguousarray(T_cam_world[:, :3, :3]),
        t_cam_world=np.ascontiguousarray(T_cam_world[:, :3, 3]),
    )


def _anchor_information(window: CorrelationWindow, keep: I64, cfg: SegmentationConfig) -> F64:
    """Isotropic information (M',) in 1/m^2 of each point's measured position: K_i / mean 3D variance."""
    cfg = replace(cfg, observation_model="point_3d")
    pts = window.points_cam[:, keep]
    obs = window.observed[:, keep]
    flat = np.where(obs[..., None], pts, 1.0).reshape(-1, 3)
    var = (_observation_sigma(flat, window.camera, cfg) ** 2).mean(axis=1).reshape(obs.shape)
    mean_var = np.where(obs, var, 0.0).sum(axis=0) / np.maximum(obs.sum(axis=0), 1)
    return np.asarray(obs.sum(axis=0) / mean_var, dtype=np.float64)


def median_world(world: F64, observed: BoolArr) -> F64:
    """Per-coordinate median over frames of measured world points (K, M, 3) where observed (K, M)."""
    masked = np.where(observed[..., None], world, np.nan)
    return np.asarray(np.nanmedian(masked, axis=0), dtype=np.float64)


def optimise_correlations(
    window: CorrelationWindow, keep: I64, edges: I64, cfg: SegmentationConfig
) -> tuple[F64, F64, I64]:
    """Solve eq. 5 for the points `keep` (indices into the window) connected by `edges` (E, 2).

    Returns the optimised world positions (M', 3), the per-edge inlier fraction (E,) after the last
    round, and the number of measurements per edge (E,).
    """
    world = window.points_world()[:, keep]
    obs = window.observed[:, keep]
    # Per-coordinate median of the measured world positions (the mean for two frames): robust to one bad
    # measurement when K >= 3, and for two frames it puts a moving point midway, where both measurements
    # of an edge to a static neighbour are equally (in)consistent.
    init = median_world(world, obs)
    anchor_info = cfg.anchor_weight * _anchor_information(window, keep, cfg)
    prob = _build_problem(window, keep, edges, cfg)
    normal = _NormalEquations(edges, prob, len(keep))
    n_meas = np.bincount(prob.edge, minlength=len(edges)).astype(np.int64)
    points = init.copy()
    active = np.ones(len(prob.edge), dtype=bool)
    residuals = _residuals(points, prob, window.camera, cfg.observation_model)
    for _ in range(cfg.rounds):
        for _ in range(cfg.iterations_per_round):
            weights = _huber_weights(np.linalg.norm(residuals[0], axis=1), cfg.huber_delta) * active
            points = _gauss_newton_step(points, init, anchor_info, prob, normal, residuals, weights, cfg.cg_rtol)
            residuals = _residuals(points, prob, window.camera, cfg.observation_model)
        chi2 = np.einsum("qa,qa->q", residuals[0], residuals[0])
        if cfg.outlier_dof_correction:
            n = n_meas[prob.edge]
            chi2 = chi2 * n / np.maximum(n - 1, 1)
        active = chi2 <= cfg.outlier_chi2
    inliers = np.bincount(prob.edge, weights=active.astype(float), minlength=len(edges))
    fraction = inliers / np.maximum(n_meas, 1)
    return points, fraction, n_meas
