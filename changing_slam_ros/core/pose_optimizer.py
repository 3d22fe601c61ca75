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

_EYE3 = np.eye(3)
_EYE3.flags.writeable = False
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


def so3_exp(omega: F64) -> F64:
    """Rotation matrix (3, 3) of a rotation vector (3,) (Rodrigues)."""
    theta = math.sqrt(omega.dot(omega))  # = np.linalg.norm(omega), without its dispatch
    w0, w1, w2 = omega.tolist()
    k = np.array([[0.0, -w2, w1], [w2, 0.0, -w0], [-w1, w0, 0.0]])
    if theta < 1e-10:
        return _EYE3 + k
    a = np.sin(theta) / theta
    b = (1 - np.cos(theta)) / theta**2
    return _EYE3 + a * k + b * (k @ k)


def se3_exp_left(delta: F64) -> F64:
    """Retraction (4, 4) of delta = (omega, rho) (6,): rotation exp(omega), translation rho."""
    t = np.eye(4)
    t[:3, :3] = so3_exp(delta[:3])
    t[:3, 3] = delta[3:]
    return t


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
    lin = _Linearisation(T_cam_world, obs, cam, obs.u_right_px >= 0)
    return lin.e, lin.pc, lin.chi2


class _Linearisation:
    """Residuals at one pose, with the terms the Jacobian shares with them (computed once)."""

    def __init__(self, T_cam_world: F64, obs: PoseObservations, cam: PinholeStereo, stereo: npt.NDArray[np.bool_]) -> None:
        pc = obs.points_w @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
        x, y, z_raw = pc[:, 0], pc[:, 1], pc[:, 2]
        z = np.where(np.abs(z_raw) < 1e-6, 1e-6, z_raw)
        self.fxx = cam.fx * x
        self.fyy = cam.fy * y
        u = self.fxx / z + cam.cx
        v = self.fyy / z + cam.cy
        e = np.zeros((len(pc), 3))
        e[:, 0] = obs.uv_px[:, 0] - u
        e[:, 1] = obs.uv_px[:, 1] - v
        e[:, 2] = np.where(stereo, obs.u_right_px - (u - cam.bf / z), 0.0)
        chi2 = (e * e).sum(axis=1) * obs.inv_sigma2
        self.chi2 = np.where(z_raw > 0, chi2, 1e9)
        self.e, self.pc, self.z = e, pc, z

    def jacobian(self, cam: PinholeStereo) -> F64:
        """d(error)/d(delta) (N, 3, 6), as `_jacobian` (same operations, shared terms reused)."""
        pc, z, fxx, fyy = self.pc, self.z, self.fxx, self.fyy
        x, y = pc[:, 0], pc[:, 1]
        iz = 1.0 / z
        iz2 = iz * iz
        fx, fy, bf = cam.fx, cam.fy, cam.bf
        fxy_iz = fx * y * iz
        mfx_iz = -fx * iz
        mfyx = -fy * x
        j = np.empty((len(pc), 3, 6))
        j[:, 0, 0] = fxx * y * iz2
        j[:, 0, 1] = -fx * (1.0 + x * x * iz2)
        j[:, 0, 2] = fxy_iz
        j[:, 0, 3] = mfx_iz
        j[:, 0, 4] = 0.0
        j[:, 0, 5] = fxx * iz2
        j[:, 1, 0] = fy * (1.0 + y * y * iz2)
        j[:, 1, 1] = mfyx * y * iz2
        j[:, 1, 2] = mfyx * iz
        j[:, 1, 3] = 0.0
        j[:, 1, 4] = -fy * iz
        j[:, 1, 5] = fyy * iz2
        c = (bf - fxx) * iz2
        j[:, 2, 0] = -c * y
        j[:, 2, 1] = -(fx - c * x)
        j[:, 2, 2] = fxy_iz
        j[:, 2, 3] = mfx_iz
        j[:, 2, 4] = 0.0
        j[:, 2, 5] = -c
        return j


def _jacobian(pc: F64, cam: PinholeStereo) -> F64:
    """d(error)/d(delta) (N, 3, 6) for the left perturbation delta = (omega, rho).

    Rows u, v, u_r; written out from d(projection)/d(pc) @ [-[pc]x | I], negated (error = obs - proj).
    """
    x, y, z = pc[:, 0], pc[:, 1], pc[:, 2]
    z = np.where(np.abs(z) < 1e-6, 1e-6, z)
    iz = 1.0 / z
    iz2 = iz * iz
    fx, fy, bf = cam.fx, cam.fy, cam.bf
    j = np.empty((len(pc), 3, 6))
    # u = fx x / z + cx
    j[:, 0, 0] = fx * x * y * iz2
    j[:, 0, 1] = -fx * (1.0 + x * x * iz2)
    j[:, 0, 2] = fx * y * iz
    j[:, 0, 3] = -fx * iz
    j[:, 0, 4] = 0.0
    j[:, 0, 5] = fx * x * iz2
    # v = fy y / z + cy
    j[:, 1, 0] = fy * (1.0 + y * y * iz2)
    j[:, 1, 1] = -fy * x * y * iz2
    j[:, 1, 2] = -fy * x * iz
    j[:, 1, 3] = 0.0
    j[:, 1, 4] = -fy * iz
    j[:, 1, 5] = fy * y * iz2
    # u_r = u - bf / z
    c = (bf - fx * x) * iz2
    j[:, 2, 0] = -c * y
    j[:, 2, 1] = -(fx - c * x)
    j[:, 2, 2] = fx * y * iz
    j[:, 2, 3] = -fx * iz
    j[:, 2, 4] = 0.0
    j[:, 2, 5] = -c
    return j


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
    row_mask = np.ones((n, 3))
    row_mask[~stereo, 2] = 0.0
    sqrt_th = np.sqrt(th)
    # The residuals at the current pose: computed once per pose, shared by the next iteration and the
    # end-of-round outlier test (which evaluate the same pose).
    lin = _Linearisation(T, obs, cam, stereo)
    chi2 = lin.chi2
    for rnd in range(rounds):
        robust = rnd < robust_rounds
        for _ in range(iterations):
            e, chi2 = lin.e, lin.chi2
            w = obs.inv_sigma2 * inliers
            if robust:
                r = np.sqrt(chi2)
                w = w * np.where(r <= sqrt_th, 1.0, sqrt_th / np.maximum(r, 1e-12))
            # Normal equations with the 3 rows of every match stacked: (3N, 6) Jacobian, BLAS products.
            J = lin.jacobian(cam).reshape(-1, 6)
            wr = (w[:, None] * row_mask).reshape(-1)
            Jw = J * wr[:, None]
            H = Jw.T @ J
            b = Jw.T @ e.reshape(-1)
            try:
                step = np.linalg.solve(H + _DAMPING, -b)
            except np.linalg.LinAlgError:
                break
            T = se3_exp_left(step) @ T
            lin = _Linearisation(T, obs, cam, stereo)
            if step @ step < 1e-10:
                break
        chi2 = lin.chi2
        inliers = chi2 <= th
        if inliers.sum() < 10:
            break
    return PoseResult(orthonormalised(T), inliers, chi2)
