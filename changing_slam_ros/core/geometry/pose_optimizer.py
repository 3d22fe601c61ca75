"""Motion-only pose optimisation (ORB-SLAM `PoseOptimization`) in numpy: Gauss-Newton on SE(3).

Each match is a map point (fixed) and a keypoint observation: monocular (u, v) or, when the keypoint
has depth, RGB-D "virtual stereo" (u, v, u_r) with u_r = u - bf / z. Residuals are weighted by the
inverse variance of the keypoint's pyramid level and a Huber kernel (delta = sqrt of the 95 % chi2
quantile: 2 dof 5.991, 3 dof 7.815). Four rounds: after each, matches over the chi2 threshold are
flagged outliers and left out of the next round (they may come back); the last rounds run without
the kernel. The pose is updated on the left: T_cam_world <- exp(delta) T_cam_world, delta = (omega, rho).
"""

from __future__ import annotations

from dataclasses import dataclass

import math

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]

CHI2_MONO = 5.991
CHI2_STEREO = 7.815

_DAMPING = 1e-9 * np.eye(6)
_DAMPING.flags.writeable = False


@dataclass(frozen=True)
class PoseObservations:
    """N matches: `points_w` (N, 3) metres; `uv_px` (N, 2) undistorted; `u_right_px` (N,), < 0 for
    monocular; `inv_sigma2` (N,) 1 / (level scale^2)."""

    points_w: F64
    uv_px: F64
    u_right_px: F64
    inv_sigma2: F64


@dataclass(frozen=True)
class PinholeStereo:
    """fx, fy, cx, cy in pixels; bf = virtual baseline (m) * fx."""

    fx: float
    fy: float
    cx: float
    cy: float
    bf: float


@dataclass(frozen=True)
class PoseResult:
    T_cam_world: F64
    inliers: npt.NDArray[np.bool_]
    chi2: F64

    @property
    def n_inliers(self) -> int:
        return int(self.inliers.sum())


def se3_exp_left(delta: F64) -> F64:
    """Retraction (4, 4) of delta = (omega, rho) (6,): rotation exp(omega), translation rho.

    The rotation is Rodrigues' formula written out in scalars, R = cos(theta) I + b w w^T + a [w]x with
    a = sin(theta) / theta, b = (1 - cos(theta)) / theta^2: one array built per Gauss-Newton iteration.
    """
    w0, w1, w2, r0, r1, r2 = np.asarray(delta, dtype=np.float64).tolist()
    t2 = w0 * w0 + w1 * w1 + w2 * w2
    theta = math.sqrt(t2)
    if theta < 1e-10:
        c, a, b = 1.0, 1.0, 0.0  # first order: I + [w]x
    else:
        c, a, b = math.cos(theta), math.sin(theta) / theta, (1.0 - math.cos(theta)) / t2
    aw0, aw1, aw2 = a * w0, a * w1, a * w2
    bw01, bw02, bw12 = b * w0 * w1, b * w0 * w2, b * w1 * w2
    return np.array([
        [c + b * w0 * w0, bw01 - aw2, bw02 + aw1, r0],
        [bw01 + aw2, c + b * w1 * w1, bw12 - aw0, r1],
        [bw02 - aw1, bw12 + aw0, c + b * w2 * w2, r2],
        [0.0, 0.0, 0.0, 1.0],
    ])


def orthonormalised(T: F64) -> F64:
    """The rigid transform (4, 4) nearest to T: its rotation block projected onto SO(3) (SVD).

    Chained products of poses drift off SO(3) in floating point; `se3.invert` assumes they do not.
    """
    u, _, vt = np.linalg.svd(T[:3, :3])
    r = u @ vt
    if np.linalg.det(r) < 0:
        r = u @ np.diag([1.0, 1.0, -1.0]) @ vt
    out = np.array(T, dtype=np.float64)
    out[:3, :3] = r
    out[3] = (0.0, 0.0, 0.0, 1.0)
    return out


def residuals(T_cam_world: F64, obs: PoseObservations, cam: PinholeStereo) -> tuple[F64, F64, F64]:
    """Errors (N, 3) (observation - projection; third column 0 for monocular), points in camera (N, 3),
    and chi2 (N,) weighted by `inv_sigma2`."""
    system = _NormalEquations(obs, cam)
    chi2 = system.linearise(T_cam_world)
    n, e_all = system.n, system.e
    e = np.stack([e_all[:n], e_all[n : 2 * n], e_all[2 * n :]], axis=1)
    pc = obs.points_w @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
    return e, pc, chi2


class _NormalEquations:
    """The Gauss-Newton system of one pose's N matches, laid out for few numpy calls per iteration.

    The 3N residuals are stored by kind, `e` = (u errors | v errors | u_r errors), and the Jacobian
    transposed, `a` (6, 3N) in the same column order: its always-zero entries (du/d rho_y, dv/d rho_x,
    du_r/d rho_y) are written once, and monocular matches' u_r columns get weight 0. `linearise(T)`
    fills both at pose T and returns chi2; `solve(w)` returns the step for per-match weights w (N,).
    """

    def __init__(self, obs: PoseObservations, cam: PinholeStereo) -> None:
        n = len(obs.points_w)
        self.n = n
        self.cam = cam
        self.points_t = np.ascontiguousarray(obs.points_w.T)  # (3, N)
        self.u_obs = np.ascontiguousarray(obs.uv_px[:, 0])
        self.v_obs = np.ascontiguousarray(obs.uv_px[:, 1])
        stereo = obs.u_right_px >= 0
        self.stereo_w = stereo.astype(np.float64)
        self.ur_obs = np.where(stereo, obs.u_right_px, 0.0)
        self.inv_sigma2 = obs.inv_sigma2
        self.e = np.empty(3 * n)
        self.a = np.zeros((6, 3 * n))
        self.wr = np.empty(3 * n)
        self._terms: tuple[F64, ...] = ()

    def linearise(self, T_cam_world: F64) -> F64:
        """Residuals and Jacobian terms at T_cam_world; chi2 (N,) (1e9 for points behind the camera)."""
        n, cam, e = self.n, self.cam, self.e
        pc = T_cam_world[:3, :3] @ self.points_t + T_cam_world[:3, 3:4]
        x, y, z_raw = pc
        z = np.where(np.abs(z_raw) < 1e-6, 1e-6, z_raw)
        iz = 1.0 / z
        xi = x * iz
        yi = y * iz
        u = cam.fx * xi + cam.cx
        e[:n] = self.u_obs - u
        e[n : 2 * n] = self.v_obs - (cam.fy * yi + cam.cy)
        e[2 * n :] = self.stereo_w * (self.ur_obs - (u - cam.bf * iz))
        e2 = e * e
        chi2 = (e2[:n] + e2[n : 2 * n] + e2[2 * n :]) * self.inv_sigma2
        self._terms = (x, y, iz, xi, yi)
        return np.where(z_raw > 0, chi2, 1e9)

    def _fill_jacobian(self) -> None:
        """d(error)/d(delta), delta = (omega, rho) on the left: -d(projection)/d(pc) @ [-[pc]x | I]."""
        n, cam = self.n, self.cam
        x, y, iz, xi, yi = self._terms
        fx, fy, bf = cam.fx, cam.fy, cam.bf
        ju, jv, jr = self.a[:, :n], self.a[:, n : 2 * n], self.a[:, 2 * n :]
        xy = xi * yi
        ju[0] = fx * xy  # u = fx x / z + cx
        ju[1] = -fx * (1.0 + xi * xi)
        ju[2] = fx * yi
        ju[3] = -fx * iz
        ju[5] = fx * xi * iz
        jv[0] = fy * (1.0 + yi * yi)  # v = fy y / z + cy
        jv[1] = -fy * xy
        jv[2] = -fy * xi
        jv[4] = -fy * iz
        jv[5] = fy * yi * iz
        c = (bf * iz - fx * xi) * iz  # u_r = u - bf / z
        jr[0] = -c * y
        jr[1] = c * x - fx
        jr[2] = ju[2]
        jr[3] = ju[3]
        jr[5] = -c

    def solve(self, w: F64) -> F64 | None:
        """The Gauss-Newton step (6,) at the last linearisation for match weights w (N,); None if singular."""
        n = self.n
        self._fill_jacobian()
        wr = self.wr
        wr[:n] = w
        wr[n : 2 * n] = w
        wr[2 * n :] = w * self.stereo_w
        aw = self.a * wr
        try:
            return np.linalg.solve(aw @ self.a.T + _DAMPING, -(aw @ self.e))
        except np.linalg.LinAlgError:
            return None


def optimize_pose(
    T_cam_world: F64,
    obs: PoseObservations,
    cam: PinholeStereo,
    rounds: int = 4,
    iterations: int = 6,
    robust_rounds: int = 2,
) -> PoseResult:
    """Refine T_cam_world (4, 4) from N matches; return the pose, an inlier mask (N,) and chi2 (N,)."""
    n = len(obs.points_w)
    T = orthonormalised(T_cam_world)
    stereo = obs.u_right_px >= 0
    th = np.where(stereo, CHI2_STEREO, CHI2_MONO)
    inliers = np.ones(n, bool)
    if n < 3:
        return PoseResult(T, np.zeros(n, bool), np.full(n, np.inf))
    sqrt_th = np.sqrt(th)
    system = _NormalEquations(obs, cam)
    # chi2 at the current pose: computed once per pose, shared by the next iteration and the
    # end-of-round outlier test (which evaluate the same pose).
    chi2 = system.linearise(T)
    for rnd in range(rounds):
        robust = rnd < robust_rounds
        for _ in range(iterations):
            w = obs.inv_sigma2 * inliers
            if robust:
                r = np.sqrt(chi2)
                w = w * np.where(r <= sqrt_th, 1.0, sqrt_th / np.maximum(r, 1e-12))
            step = system.solve(w)
            if step is None:
                break
            T = se3_exp_left(step) @ T
            chi2 = system.linearise(T)
            if step @ step < 1e-10:
                break
        inliers = chi2 <= th
        if inliers.sum() < 10:
            break
    return PoseResult(orthonormalised(T), inliers, chi2)
