"""Levenberg-Marquardt for local BA in numpy, the points eliminated by the Schur complement.

The problem is local BA's gtsam graph (`local_ba`): free poses T_world_cam, fixed poses, points, one robust
reprojection residual per observation (stereo (u_l, u_r, v) or mono (u, v), whitened by the keypoint's noise,
Huber kernel on the whitened norm). The cost is gtsam's: sum of Huber losses rho(|r|) (r^2 / 2 inside k,
k |r| - k^2 / 2 outside); each iteration linearises the way gtsam's robust noise model does (every
observation's whitened rows scaled by sqrt(w), w = min(1, k / |r|)) and runs gtsam's LM policy (lambda * I on
every variable from `lambda_initial`, divided by `lambda_factor` after an accepted step, multiplied after a
rejected one; a step is accepted when the actual over the linearised cost decrease exceeds `min_model_fidelity`;
stop after `iterations`, or when the error decreases by less than `relative_tol` / `absolute_tol`). A point
behind its camera gets gtsam's stand-in residual (2 fx on every component, no Jacobian). Fixed poses are
constants (gtsam holds them with 1e-6 priors, which move them by ~1e-12). The linear algebra: `solve`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import scipy.sparse

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


@dataclass(frozen=True)
class LMSettings:
    """gtsam's `LevenbergMarquardtParams` defaults, `iterations` from the BA config."""

    iterations: int = 5
    lambda_initial: float = 1e-5
    lambda_factor: float = 10.0
    lambda_upper: float = 1e5
    min_model_fidelity: float = 1e-3
    relative_tol: float = 1e-5
    absolute_tol: float = 1e-5


@dataclass(frozen=True)
class BAProblem:
    """E observations of P points from F free then G fixed poses.

    `T_world_cam` (F + G, 4, 4), the free ones first; `points` (P, 3); `pose_idx`, `point_idx` (E,);
    `uv` (E, 2); `u_right` (E,) (< 0: mono); `sigma_px` (E,) (the level scale); camera fx fy cx cy and
    `bf` (baseline * fx, px m); `disparity_sigma_ratio` as `local_ba.stereo_noise`; Huber thresholds
    `k_stereo`, `k_mono` on the whitened norm."""

    T_world_cam: F64
    n_free: int
    points: F64
    pose_idx: I64
    point_idx: I64
    uv: F64
    u_right: F64
    sigma_px: F64
    fx: float
    fy: float
    cx: float
    cy: float
    bf: float
    disparity_sigma_ratio: float
    k_stereo: float
    k_mono: float


@dataclass(frozen=True)
class LMResult:
    T_world_cam: F64  # (F, 4, 4) the free poses
    points: F64  # (P, 3)
    error_before: float
    error_after: float
    iterations: int
    stopped: bool


def _so3_exp(w: F64) -> F64:
    """Rodrigues, (N, 3) -> (N, 3, 3)."""
    th = np.linalg.norm(w, axis=1)
    small = th < 1e-10
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0, np.sin(ths) / ths)
    b = np.where(small, 0.5, (1.0 - np.cos(ths)) / ths**2)
    K = _skew_cm(w.T).transpose(2, 0, 1)  # (N, 3, 3) cross-product matrices
    return np.eye(3) + a[:, None, None] * K + b[:, None, None] * (K @ K)


class _Whitening:
    """Per observation the whitening W (E, 3, 3) with W^T W = Sigma^-1 on (u_l, u_r, v) (mono: the u_r row zero)."""

    def __init__(self, p: BAProblem) -> None:
        stereo = p.u_right >= 0
        rho = p.disparity_sigma_ratio
        if rho > 0:  # u_l, the disparity u_l - u_r (sigma rho s), v
            Ws = np.array([[1.0, 0.0, 0.0], [1.0 / rho, -1.0 / rho, 0.0], [0.0, 0.0, 1.0]])
        else:
            Ws = np.eye(3)
        Wm = np.diag([1.0, 0.0, 1.0])
        self.W = np.where(stereo[:, None, None], Ws, Wm) / p.sigma_px[:, None, None]
        self.W_cm = np.ascontiguousarray(self.W.transpose(1, 2, 0))  # (3, 3, E)
        self.k = np.where(stereo, p.k_stereo, p.k_mono)
        self.stereo = stereo


def _residuals(p: BAProblem, wh: _Whitening, R_cw: F64, t_cw: F64, points: F64) -> tuple[F64, F64, F64]:
    """Whitened residuals r (E, 3), camera-frame points pc (E, 3), in-front mask (E,); per pose R_cw (N, 3, 3)."""
    pc = np.einsum("nij,nj->ni", R_cw[p.pose_idx], points[p.point_idx]) + t_cw[p.pose_idx]
    front = pc[:, 2] > 0
    z = np.where(front, pc[:, 2], 1.0)
    u = p.fx * pc[:, 0] / z + p.cx
    e = np.stack([u - p.uv[:, 0], (u - p.bf / z) - np.where(wh.stereo, p.u_right, 0.0),
                  p.fy * pc[:, 1] / z + p.cy - p.uv[:, 1]], 1)  # fmt: skip
    e = np.where(front[:, None], e, 2.0 * p.fx)  # gtsam's residual for a point behind the camera
    return np.einsum("nij,nj->ni", wh.W, e), pc, front


class _Sums:
    """Per-observation blocks, stored component-major (..., E), summed by point and by free pose (sparse 0/1
    matrix products: no BLAS, see `_reduce`), and H_lx scattered densely; all built once per problem (the
    structure of the problem does not change between iterations)."""

    def __init__(self, point_idx: I64, pose_idx: I64, free: npt.NDArray[np.bool_], P: int, F: int) -> None:
        E = len(point_idx)
        self.P, self.F = P, F
        self._by_point = scipy.sparse.csr_matrix((np.ones(E), (point_idx, np.arange(E))), shape=(P, E))
        self._by_pose = scipy.sparse.csr_matrix(  # fixed poses' observations dropped
            (np.ones(int(free.sum())), (pose_idx[free], np.flatnonzero(free))), shape=(F, E))
        self._free = np.flatnonzero(free)
        rows = (3 * point_idx[free])[None, None, :] + np.arange(3)[:, None, None]
        cols = (6 * pose_idx[free])[None, None, :] + np.arange(6)[None, :, None]
        self._lx = (rows * (6 * F) + cols).ravel()
        pairs = point_idx[free] * max(F, 1) + pose_idx[free]
        self._lx_unique = len(np.unique(pairs)) == len(pairs)  # no keyframe sees a point twice

    def by_point(self, vals: F64) -> F64:
        """(..., E) -> (P, ...)."""
        shape = vals.shape[:-1]
        return np.asarray(self._by_point @ vals.reshape(-1, vals.shape[-1]).T).reshape(self.P, *shape)

    def by_pose(self, vals: F64) -> F64:
        """(..., E) -> (F, ...): sums over the observations of each free pose."""
        shape = vals.shape[:-1]
        return np.asarray(self._by_pose @ vals.reshape(-1, vals.shape[-1]).T).reshape(self.F, *shape)

    def lx_blocks(self, blocks: F64) -> F64:
        """(3, 6, E) blocks (those of free poses used) -> H_lx (P, 3, 6F)."""
        vals = blocks.reshape(18, -1)[:, self._free].ravel()
        if self._lx_unique:
            out = np.zeros(3 * self.P * 6 * self.F)
            out[self._lx] = vals
        else:
            out = np.bincount(self._lx, vals, minlength=3 * self.P * 6 * self.F)
        return out.reshape(self.P, 3, 6 * self.F)


def _mm(A: F64, B: F64) -> F64:
    """Per-observation 3x3 @ 3xk products, component-major: (3, 3, E) @ (3, k, E) -> (3, k, E)."""
    out = np.empty((3, B.shape[1], A.shape[2]))
    for i in range(3):
        out[i] = A[i, 0] * B[0] + A[i, 1] * B[1] + A[i, 2] * B[2]
    return out


# OpenBLAS runs a matrix product on one thread below M N K = 2**18; a second thread only spins on this 2-core
# machine (the graph sets OPENBLAS_NUM_THREADS=1, `changing-slam run` does not): ~40x slower under load for the
# (6F, 3P) @ (3P, 6F) product. So it is summed in blocks of points below that size.
_BLAS_ONE_THREAD_MNK = 2**18


def _reduce(H_lx: F64, Hinv_lx: F64, Hinv_g: F64) -> tuple[F64, F64]:
    """sum_p H_lx_p^T H_ll_p^-1 H_lx_p (6F, 6F) and sum_p H_lx_p^T H_ll_p^-1 g_l_p (6F,), in blocks of points."""
    P, _, n = H_lx.shape
    right = np.concatenate([Hinv_lx, Hinv_g[:, :, None]], axis=2)
    step = max(1, _BLAS_ONE_THREAD_MNK // (3 * n * (n + 1)))
    out = np.zeros((n, n + 1))
    for i in range(0, P, step):
        out += H_lx[i : i + step].reshape(-1, n).T @ right[i : i + step].reshape(-1, n + 1)
    return out[:, :n], out[:, n]


def _skew_cm(v: F64) -> F64:
    """(3, E) -> (3, 3, E) cross-product matrices, component-major."""
    z = np.zeros(v.shape[1])
    return np.array([[z, -v[2], v[1]], [v[2], z, -v[0]], [-v[1], v[0], z]])


def _cost(r: F64, k: F64) -> float:
    """gtsam's Huber loss summed."""
    n = np.linalg.norm(r, axis=1)
    return float(np.sum(np.where(n <= k, 0.5 * n**2, k * n - 0.5 * k**2)))


def solve(p: BAProblem, settings: LMSettings, stop: Callable[[], bool] | None = None) -> LMResult:
    """Run LM on `p`. `stop` is asked before the first iteration and after each but the last (True: return the
    values reached, `stopped` set), as `local_ba.optimise` does with gtsam.

    The normal equations: per observation e the whitened, reweighted Jacobians A_x (3, 6) of its pose and A_l
    (3, 3) of its point; the point blocks H_ll are 3x3 and independent, so they are eliminated first
    (S = H_xx - H_xl H_ll^-1 H_lx, a (6F, 6F) dense system for F free poses), then back-substituted.
    Pose update: R <- R Exp(omega), t <- t + R v (xi = (omega, v), rotation first, as gtsam's Pose3 tangent; the
    same as gtsam's retraction to first order, which is all LM's steps need: final errors agree to ~1e-8).
    """
    F, P = p.n_free, len(p.points)
    wh = _Whitening(p)
    T = p.T_world_cam
    R_wc = T[:, :3, :3].copy()
    t_wc = T[:, :3, 3].copy()
    points = p.points.copy()

    def camera(R: F64, t: F64) -> tuple[F64, F64]:
        R_cw = np.ascontiguousarray(np.transpose(R, (0, 2, 1)))
        return R_cw, -np.einsum("nij,nj->ni", R_cw, t)

    free_obs = p.pose_idx < F
    obs_pose = np.where(free_obs, p.pose_idx, 0)
    sums = _Sums(p.point_idx, obs_pose, free_obs, P, F)
    r, pc, front = _residuals(p, wh, *camera(R_wc, t_wc), points)
    error = _cost(r, wh.k)
    error_before = error
    lam = settings.lambda_initial
    iterations, stopped = 0, False
    if settings.iterations <= 0 or (stop is not None and stop()):
        return LMResult(_poses_4x4(R_wc[:F], t_wc[:F]), points, error, error, 0, settings.iterations > 0)
    while True:
        # 1. Linearise: the whitened Jacobians of every residual, reweighted by sqrt(w) (gtsam's robust model).
        R_cw, _ = camera(R_wc, t_wc)
        n = np.linalg.norm(r, axis=1)
        sw = np.sqrt(np.where(n <= wh.k, 1.0, wh.k / np.maximum(n, 1e-300)))
        # Component-major (3, ..., E): numpy's batched 3x3 matmul costs ~2.5x the explicit sums (`_mm`).
        pcs = np.ascontiguousarray(pc.T)
        z = np.where(front, pcs[2], 1.0)
        f = front * sw / z
        zero = np.zeros(len(z))
        J = np.array([[p.fx * f, zero, -p.fx * pcs[0] * f / z], [p.fx * f, zero, -(p.fx * pcs[0] - p.bf) * f / z],
                      [zero, p.fy * f, -p.fy * pcs[1] * f / z]])  # d(u_l, u_r, v) / d pc  # fmt: skip
        C = _mm(wh.W_cm, J)  # d r / d pc, whitened and reweighted (3, 3, E)
        b = -(sw[:, None] * r)  # the linear model: minimise |A dx - b|^2
        # A_l = C R_cw, A_x = C [S, -I] with S = [pc]x (pc' = pc + [pc]x omega - v): every block of A^T A from
        # Q = C^T C, every block of A^T b from c = C^T b.
        Rg = np.ascontiguousarray(R_cw[p.pose_idx].transpose(1, 2, 0))  # (3, 3, E)
        RgT = Rg.transpose(1, 0, 2)
        Q = _mm(C.transpose(1, 0, 2), C)
        c = np.einsum("kin,nk->in", C, b)
        K = _skew_cm(pcs)  # S above
        QS = _mm(Q, K)
        H_ll = sums.by_point(_mm(RgT, _mm(Q, Rg)))
        g_l = sums.by_point(np.einsum("ijn,jn->in", RgT, c))
        H_x_obs = np.empty((6, 6, len(z)))
        H_x_obs[:3, :3] = -_mm(K, QS)  # S^T = -S
        H_x_obs[:3, 3:] = -QS.transpose(1, 0, 2)
        H_x_obs[3:, :3] = -QS
        H_x_obs[3:, 3:] = Q
        H_xx = sums.by_pose(H_x_obs)
        g_x = sums.by_pose(np.concatenate([np.cross(c.T, pc).T, -c], axis=0))  # S^T c = -(pc x c)
        # H_lx as a dense (P, 3, 6F) matrix: one 3x6 block per observation of a free pose
        H_lx_obs = np.empty((3, 6, len(z)))
        H_lx_obs[:, :3] = _mm(RgT, QS)
        H_lx_obs[:, 3:] = -_mm(RgT, Q)
        H_lx = sums.lx_blocks(H_lx_obs)
        H_xx_dense = np.zeros((6 * F, 6 * F))
        for i in range(F):
            H_xx_dense[6 * i : 6 * i + 6, 6 * i : 6 * i + 6] = H_xx[i]
        old_lin = 0.5 * float(np.sum(b**2))
        accepted = False
        while True:
            # 2. Damped system, points eliminated: S dx = rhs, then dl.
            dx = dl = None
            try:
                H_ll_inv = np.linalg.inv(H_ll + lam * np.eye(3))
                Hinv_lx = H_ll_inv @ H_lx  # (P, 3, 6F)
                Hinv_g = (H_ll_inv @ g_l[:, :, None])[:, :, 0]  # (P, 3)
                reduced, reduced_g = _reduce(H_lx, Hinv_lx, Hinv_g)
                S = H_xx_dense + lam * np.eye(6 * F) - reduced
                rhs = g_x.ravel() - reduced_g
                dx = np.linalg.solve(S, rhs).reshape(F, 6) if F else np.zeros((0, 6))
                dl = Hinv_g - np.einsum("pij,j->pi", Hinv_lx, dx.ravel())
                solved = bool(np.all(np.isfinite(dx)) and np.all(np.isfinite(dl)))
            except np.linalg.LinAlgError:
                solved = False
            stop_search = False
            if solved:
                assert dx is not None and dl is not None
                dxo = np.where(free_obs[:, None], dx[obs_pose], 0.0)
                d_pc = np.einsum("ijn,nj->in", Rg, dl[p.point_idx]) + (np.cross(pc, dxo[:, :3]) - dxo[:, 3:]).T
                lin = np.einsum("ijn,jn->ni", C, d_pc)
                lin_change = old_lin - 0.5 * float(np.sum((lin - b) ** 2))
                R_new, t_new = R_wc.copy(), t_wc.copy()
                R_new[:F] = R_wc[:F] @ _so3_exp(dx[:, :3])
                t_new[:F] = t_wc[:F] + np.einsum("nij,nj->ni", R_wc[:F], dx[:, 3:])
                pts_new = points + dl
                r_new, pc_new, front_new = _residuals(p, wh, *camera(R_new, t_new), pts_new)
                new_error = _cost(r_new, wh.k)
                if lin_change > np.finfo(float).eps * old_lin:
                    accepted = (error - new_error) / lin_change > settings.min_model_fidelity
                else:
                    stop_search = True
            if accepted:
                R_wc, t_wc, points, r, pc, front = R_new, t_new, pts_new, r_new, pc_new, front_new
                prev_error, error = error, new_error
                lam = lam / settings.lambda_factor
                break
            if stop_search or lam >= settings.lambda_upper:
                break
            lam *= settings.lambda_factor
        iterations += 1
        # gtsam's iteration hook (`local_ba.optimise`): asked after every iteration but the last, converged or not.
        if iterations < settings.iterations and stop is not None and stop():
            stopped = True
            break
        if not accepted or iterations >= settings.iterations:
            break
        decrease = prev_error - error
        if decrease <= settings.absolute_tol or decrease <= settings.relative_tol * prev_error:
            break
    return LMResult(_poses_4x4(R_wc[:F], t_wc[:F]), points, error_before, error, iterations, stopped)


def _poses_4x4(R: F64, t: F64) -> F64:
    """(N, 3, 3), (N, 3) -> (N, 4, 4)."""
    T = np.zeros((len(R), 4, 4))
    T[:, :3, :3] = R
    T[:, :3, 3] = t
    T[:, 3, 3] = 1.0
    return T
