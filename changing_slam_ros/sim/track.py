"""A ground-truth 6-DoF track: pose keys over time, interpolated, with jumps and absences.

Both the camera and every actor move along a `Track`. Between two keys the pose is interpolated
(linear in translation, slerp in rotation) unless the later key is a `jump`: then the earlier pose is
held until the later key's time and changes at once, which is how objects are moved, removed or added
"while nobody looks". A key whose pose is None means the object is absent from the scene from then on.
"""

from __future__ import annotations

import bisect
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.se3 import make_pose, quat_to_rot, rot_to_quat

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class PoseKey:
    """Pose `T_world_obj` (4, 4) at `t_s` seconds, or None when the object is absent.

    `jump`: reach this key instantly at `t_s` (hold the previous pose until then) instead of
    interpolating towards it.
    """

    t_s: float
    T_world_obj: F64 | None
    jump: bool = False


def pose_xyz_rpy(x: float, y: float, z: float, roll: float = 0.0, pitch: float = 0.0,
                 yaw: float = 0.0) -> F64:
    """4x4 pose from a position (m) and roll/pitch/yaw (rad), R = Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    return make_pose(rz @ ry @ rx, np.array([x, y, z], dtype=np.float64))


def slerp(q0_xyzw: F64, q1_xyzw: F64, a: float) -> F64:
    """Spherical interpolation between unit quaternions (x, y, z, w), `a` in [0, 1]."""
    q0 = np.asarray(q0_xyzw, dtype=np.float64)
    q1 = np.asarray(q1_xyzw, dtype=np.float64)
    dot = float(np.dot(q0, q1))
    if dot < 0.0:
        q1, dot = -q1, -dot
    if dot > 0.9995:
        q = q0 + a * (q1 - q0)
        return q / np.linalg.norm(q)
    theta = np.arccos(dot)
    s = np.sin(theta)
    return (np.sin((1 - a) * theta) * q0 + np.sin(a * theta) * q1) / s


def interpolate_pose(t0: F64, t1: F64, a: float) -> F64:
    """Pose a fraction `a` of the way from `t0` to `t1` (both (4, 4))."""
    q = slerp(rot_to_quat(t0[:3, :3]), rot_to_quat(t1[:3, :3]), a)
    return make_pose(quat_to_rot(q), (1 - a) * t0[:3, 3] + a * t1[:3, 3])


class Track:
    """Poses over time from sorted `PoseKey`s. Before the first key the first pose holds; after the
    last key the last pose holds."""

    def __init__(self, keys: list[PoseKey]) -> None:
        if not keys:
            raise ValueError("Track needs at least one key")
        times = [k.t_s for k in keys]
        if any(b < a for a, b in zip(times, times[1:])):
            raise ValueError("Track keys must be sorted by time")
        self.keys = list(keys)
        self._times = times

    @classmethod
    def static(cls, T_world_obj: F64) -> "Track":
        return cls([PoseKey(0.0, np.asarray(T_world_obj, dtype=np.float64))])

    def pose_at(self, t_s: float) -> F64 | None:
        """T_world_obj (4, 4) at `t_s`, or None if the object is absent then."""
        i = bisect.bisect_right(self._times, t_s) - 1
        if i < 0:
            return self.keys[0].T_world_obj
        k0 = self.keys[i]
        if i + 1 >= len(self.keys):
            return k0.T_world_obj
        k1 = self.keys[i + 1]
        if k1.jump or k0.T_world_obj is None or k1.T_world_obj is None:
            return k0.T_world_obj
        span = k1.t_s - k0.t_s
        a = 0.0 if span <= 0 else (t_s - k0.t_s) / span
        return interpolate_pose(k0.T_world_obj, k1.T_world_obj, a)

    @property
    def end_s(self) -> float:
        return self._times[-1]


class FunctionTrack(Track):
    """A Track that evaluates a smooth pose function `fn(t_s) -> (4, 4)` on demand, clamped to
    [0, end_s]; exact at every frame time, and free to build."""

    def __init__(self, fn: Callable[[float], F64], end_s: float) -> None:
        self._fn = fn
        self._end_s = float(end_s)
        self.keys = [PoseKey(0.0, fn(0.0)), PoseKey(self._end_s, fn(self._end_s))]
        self._times = [0.0, self._end_s]

    def pose_at(self, t_s: float) -> F64 | None:
        return self._fn(min(max(t_s, 0.0), self._end_s))


def function_track(fn: Callable[[float], F64], t_end_s: float) -> Track:
    """A Track following the pose function `fn` on [0, t_end_s] (see `FunctionTrack`)."""
    return FunctionTrack(fn, t_end_s)
