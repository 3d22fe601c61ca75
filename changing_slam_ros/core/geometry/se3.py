"""Small SE(3) / quaternion helpers on numpy arrays. Quaternions are (x, y, z, w) as in TUM and ROS."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]


def quat_to_rot(q_xyzw: F64) -> F64:
    """Unit quaternion(s) (..., 4) in (x, y, z, w) order to rotation matrices (..., 3, 3)."""
    q = np.asarray(q_xyzw, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    r = np.empty(q.shape[:-1] + (3, 3))
    r[..., 0, 0] = 1 - 2 * (y * y + z * z)
    r[..., 0, 1] = 2 * (x * y - z * w)
    r[..., 0, 2] = 2 * (x * z + y * w)
    r[..., 1, 0] = 2 * (x * y + z * w)
    r[..., 1, 1] = 1 - 2 * (x * x + z * z)
    r[..., 1, 2] = 2 * (y * z - x * w)
    r[..., 2, 0] = 2 * (x * z - y * w)
    r[..., 2, 1] = 2 * (y * z + x * w)
    r[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return r


def rot_to_quat(r: F64) -> F64:
    """Rotation matrix (3, 3) to a unit quaternion (x, y, z, w) with w >= 0."""
    m = np.asarray(r, dtype=np.float64)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = np.sqrt(tr + 1.0) * 2
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        q = [0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s]
    elif m[1, 1] > m[2, 2]:
        s = np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        q = [(m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s]
    else:
        s = np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        q = [(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s]
    qa = np.array(q, dtype=np.float64)
    qa /= np.linalg.norm(qa)
    return qa if qa[3] >= 0 else -qa


def make_pose(rotation: F64, translation: F64) -> F64:
    """4x4 homogeneous transform from a rotation (3, 3) and a translation (3,)."""
    t = np.eye(4)
    t[:3, :3] = rotation
    t[:3, 3] = translation
    return t


def invert(t: F64) -> F64:
    """Inverse of a rigid transform (4, 4)."""
    r = t[:3, :3]
    out = np.eye(4)
    out[:3, :3] = r.T
    out[:3, 3] = -r.T @ t[:3, 3]
    return out


def transform_points(t: F64, points: F64) -> F64:
    """Apply a rigid transform (4, 4) to points (N, 3)."""
    return points @ t[:3, :3].T + t[:3, 3]


def rotation_angle_rad(r: F64) -> float:
    """Angle of a rotation matrix, radians in [0, pi]."""
    c = (np.trace(r) - 1.0) / 2.0
    return float(np.arccos(np.clip(c, -1.0, 1.0)))



def _left_jacobian(rvec: F64) -> F64:
    """SO(3)'s left Jacobian V(w): the SE(3) exponential's translation is V(w) u."""
    theta = float(np.linalg.norm(rvec))
    w = np.array([[0.0, -rvec[2], rvec[1]], [rvec[2], 0.0, -rvec[0]], [-rvec[1], rvec[0], 0.0]])
    if theta < 1e-6:
        return np.eye(3) + 0.5 * w + w @ w / 6.0
    return (np.eye(3) + (1.0 - np.cos(theta)) / theta**2 * w + (theta - np.sin(theta)) / theta**3 * (w @ w))


def scale_motion(t: F64, k: float) -> F64:
    """The rigid motion `t` (4, 4) raised to the power `k` (k >= 0, fractional allowed): exp(k log t) on SE(3),
    the same screw motion continued k times as long (k = 2 gives t @ t)."""
    import cv2

    rvec = cv2.Rodrigues(np.ascontiguousarray(t[:3, :3], dtype=np.float64))[0].ravel()
    u = np.linalg.solve(_left_jacobian(rvec), t[:3, 3])
    r_k = cv2.Rodrigues(rvec * float(k))[0]
    return make_pose(r_k, _left_jacobian(rvec * float(k)) @ (u * float(k)))
