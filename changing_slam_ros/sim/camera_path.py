"""Camera trajectories (optical frame: x right, y down, z forward) modelled on the papers' sequences.

TUM fr3 walking/sitting: a hand-held camera that sways along x/y/z, stays put, rotates about its own
axes, or moves on a small half-sphere. PUC-USP: a wheeled robot driving at about 0.07 m/s and turning in
place at 15-45 deg/s around a loop. Every path returns a `Track` of `T_world_cam` (4, 4).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.se3 import make_pose
from changing_slam_ros.sim.track import PoseKey, Track, pose_xyz_rpy, function_track

F64 = npt.NDArray[np.float64]
WORLD_UP = np.array([0.0, 0.0, 1.0])


def _cross(a: F64, b: F64) -> F64:
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def look_at(eye_m: F64, target_m: F64, roll_rad: float = 0.0) -> F64:
    """Optical-frame pose at `eye_m` looking at `target_m`, image x horizontal, then rolled about z."""
    z = np.asarray(target_m, dtype=np.float64) - np.asarray(eye_m, dtype=np.float64)
    z /= np.linalg.norm(z)
    x = _cross(z, WORLD_UP)
    x /= np.linalg.norm(x)
    y = _cross(z, x)
    r = np.stack([x, y, z], axis=1)
    if roll_rad:
        c, s = np.cos(roll_rad), np.sin(roll_rad)
        r = r @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return make_pose(r, np.asarray(eye_m, dtype=np.float64))


def optical_from_body(T_world_body: F64) -> F64:
    """Optical frame of a camera looking along the body's +x with the body's z up."""
    r_body_opt = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    return T_world_body @ make_pose(r_body_opt, np.zeros(3))


@dataclass(frozen=True)
class HandHeld:
    """A hand-held camera at `eye_m` looking at `target_m`; motion amplitudes and periods."""

    eye_m: tuple[float, float, float]
    target_m: tuple[float, float, float]
    phase: float = 0.0  # radians, varies with the seed


def sway_xyz(h: HandHeld, duration_s: float, amp_m: tuple[float, float, float] = (0.25, 0.12, 0.1)) -> Track:
    """TUM `*_xyz`: translation along the three axes, orientation nearly constant (<= 2 deg wobble)."""
    eye0, tgt0 = np.array(h.eye_m), np.array(h.target_m)
    fwd = (tgt0 - eye0) / np.linalg.norm(tgt0 - eye0)
    right = np.cross(fwd, WORLD_UP)
    right /= np.linalg.norm(right)

    def fn(t: float) -> F64:
        off = (amp_m[0] * np.sin(2 * np.pi * t / 9.0 + h.phase) * right
               + amp_m[1] * np.sin(2 * np.pi * t / 13.0 + 1.3 * h.phase) * fwd
               + amp_m[2] * np.sin(2 * np.pi * t / 7.0 + 0.7 * h.phase) * WORLD_UP)
        wob = 0.02 * np.sin(2 * np.pi * t / 5.0 + h.phase)
        return look_at(eye0 + off, tgt0 + off + 0.5 * wob * WORLD_UP, roll_rad=wob)

    return function_track(fn, duration_s)


def nearly_static(h: HandHeld, duration_s: float) -> Track:
    """TUM `*_static`: a camera held still (a few mm, a fraction of a degree of hand tremor)."""
    eye0, tgt0 = np.array(h.eye_m), np.array(h.target_m)

    def fn(t: float) -> F64:
        off = 0.004 * np.array([np.sin(2.1 * t + h.phase), np.sin(1.7 * t), np.sin(2.9 * t + 1.0)])
        return look_at(eye0 + off, tgt0 + 3 * off, roll_rad=0.004 * np.sin(1.3 * t + h.phase))

    return function_track(fn, duration_s)


def rotate_rpy(h: HandHeld, duration_s: float, amp_deg: tuple[float, float, float] = (12.0, 15.0, 25.0)) -> Track:
    """TUM `*_rpy`: rotation about roll, pitch and yaw in turn, position almost fixed."""
    base = look_at(np.array(h.eye_m), np.array(h.target_m))
    a = np.radians(amp_deg)

    def fn(t: float) -> F64:
        roll = a[0] * np.sin(2 * np.pi * t / 6.0 + h.phase)
        pitch = a[1] * np.sin(2 * np.pi * t / 8.0 + 0.5 * h.phase)
        yaw = a[2] * np.sin(2 * np.pi * t / 11.0 + 0.3 * h.phase)
        # optical axes: z forward (roll), x right (pitch), y down (yaw)
        r = pose_xyz_rpy(0.0, 0.0, 0.0, roll=pitch, pitch=yaw, yaw=roll)
        t_pose = base @ r
        t_pose[:3, 3] += 0.01 * np.array([np.sin(t), np.cos(1.3 * t), 0.0])
        return t_pose

    return function_track(fn, duration_s)


def half_sphere(h: HandHeld, duration_s: float, radius_m: float = 0.5) -> Track:
    """TUM `*_halfsphere`: the camera moves over a half-sphere of about 1 m diameter facing the scene,
    keeping the scene centre in view."""
    eye0, tgt0 = np.array(h.eye_m), np.array(h.target_m)
    fwd = (tgt0 - eye0) / np.linalg.norm(tgt0 - eye0)
    right = np.cross(fwd, WORLD_UP)
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)

    def fn(t: float) -> F64:
        az = 1.1 * np.sin(2 * np.pi * t / 14.0 + h.phase)  # around the sphere's axis (backwards)
        el = 0.6 * np.sin(2 * np.pi * t / 9.0 + 0.5 * h.phase)
        d = np.cos(el) * (np.cos(az) * -fwd + np.sin(az) * right) + np.sin(el) * up
        centre = eye0 + radius_m * fwd
        return look_at(centre + radius_m * d, tgt0)

    return function_track(fn, duration_s)


@dataclass(frozen=True)
class RobotLoop:
    """A wheeled robot's square loop: starts at `start_xy` heading `start_yaw`, drives `side_m`,
    turns +90 deg in place, and so on, `n_sides` times; camera at `height_m` looking forward."""

    start_xy: tuple[float, float] = (-0.4, -0.4)
    start_yaw_rad: float = 0.0
    side_m: float = 0.8
    n_sides: int = 6
    speed_m_s: float = 0.07
    turn_deg_s: float = 30.0
    height_m: float = 0.75
    tilt_deg: float = 4.0  # camera pitched slightly down
    vibration: bool = True  # floor irregularities: ~0.5 mm and ~0.15 deg of shake, as the paper notes
    pause_s: float = 0.0  # the robot stands still this long at the end of each side, before it turns


def robot_loop(loop: RobotLoop) -> tuple[Track, list[tuple[float, float, float]]]:
    """The robot's camera track, and the segments as (t_start_s, t_end_s, heading_rad) while driving."""
    x, y = loop.start_xy
    yaw = loop.start_yaw_rad
    t = 0.0
    tilt = np.radians(loop.tilt_deg)
    keys: list[PoseKey] = []
    segments: list[tuple[float, float, float]] = []

    def cam(px: float, py: float, heading: float) -> F64:
        return optical_from_body(pose_xyz_rpy(px, py, loop.height_m, pitch=tilt, yaw=heading))

    keys.append(PoseKey(t, cam(x, y, yaw)))
    drive_s = loop.side_m / loop.speed_m_s
    turn_s = 90.0 / loop.turn_deg_s
    for _ in range(loop.n_sides):
        x2, y2 = x + loop.side_m * np.cos(yaw), y + loop.side_m * np.sin(yaw)
        segments.append((t, t + drive_s, yaw))
        t += drive_s
        keys.append(PoseKey(t, cam(x2, y2, yaw)))
        if loop.pause_s > 0:
            t += loop.pause_s
            keys.append(PoseKey(t, cam(x2, y2, yaw)))
        x, y = x2, y2
        # turn in place, in 3 steps so the slerp follows the +90 deg direction
        for k in range(1, 4):
            keys.append(PoseKey(t + turn_s * k / 3, cam(x, y, yaw + np.pi / 2 * k / 3)))
        t += turn_s
        yaw += np.pi / 2
    smooth = Track(keys)
    if not loop.vibration:
        return smooth, segments

    def shaken(t_s: float) -> F64:
        base = smooth.pose_at(t_s)
        assert base is not None
        shake = pose_xyz_rpy(0.0, 0.0, 0.0005 * np.sin(2 * np.pi * 1.7 * t_s),
                             roll=np.radians(0.15) * np.sin(2 * np.pi * 2.3 * t_s + 1.0),
                             pitch=np.radians(0.15) * np.sin(2 * np.pi * 1.3 * t_s))
        return base @ shake

    return function_track(shaken, t), segments
