"""Actor motions: people walking along waypoints, people sitting and fidgeting, an object carried by hand,
and the instantaneous moves / removals / additions of changing scenes. Each returns a `Track`."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from changing_slam_ros.sim.track import PoseKey, Track, interpolate_pose, pose_xyz_rpy, function_track

F64 = npt.NDArray[np.float64]


def walking(waypoints_xy: list[tuple[float, float]], duration_s: float, speed_m_s: float = 0.9,
            turn_s: float = 0.6, pause_s: float = 0.5, start_s: float = 0.0,
            watch: Callable[[float], F64] | None = None) -> Track:
    """A person walking the closed polyline `waypoints_xy` over and over, facing the walking direction,
    turning in place at each waypoint, with a 2 cm vertical bob at the step frequency (about 2 Hz).

    Before `start_s` the person stands at the first waypoint facing the first leg. With `watch`, a
    function of time giving a world point (the camera), the person keeps facing that point (+-15 deg)
    while walking, as people who look at the camera do; detectors see their front or back that way.
    """
    pts = [np.asarray(p, dtype=np.float64) for p in waypoints_xy]
    keys: list[tuple[float, float, float, float]] = []  # (t, x, y, yaw) at which the walker is "moving"
    moving: list[tuple[float, float]] = []  # intervals of walking, for the bob
    t = start_s
    i = 0
    heading = float(np.arctan2(*(pts[1] - pts[0])[::-1]))
    keys.append((0.0, pts[0][0], pts[0][1], heading))
    while t < duration_s + 1.0:
        a, b = pts[i % len(pts)], pts[(i + 1) % len(pts)]
        leg = b - a
        new_heading = float(np.arctan2(leg[1], leg[0]))
        turn = (new_heading - heading + np.pi) % (2 * np.pi) - np.pi
        keys.append((t, a[0], a[1], heading))
        t += turn_s
        heading += turn
        keys.append((t, a[0], a[1], heading))
        t_leg = float(np.linalg.norm(leg)) / speed_m_s
        moving.append((t, t + t_leg))
        t += t_leg
        keys.append((t, b[0], b[1], heading))
        t += pause_s
        i += 1
    coarse = Track([PoseKey(k[0], pose_xyz_rpy(k[1], k[2], 0.0, yaw=k[3])) for k in keys])

    def fn(t_s: float) -> F64:
        pose = coarse.pose_at(t_s)
        assert pose is not None
        pose = pose.copy()
        if any(t0 <= t_s <= t1 for t0, t1 in moving):
            pose[2, 3] += 0.02 * abs(np.sin(2 * np.pi * t_s))
        if watch is not None:
            d = watch(t_s)[:2] - pose[:2, 3]
            yaw = float(np.arctan2(d[1], d[0])) + np.radians(15.0) * np.sin(2 * np.pi * t_s / 6.0)
            pose[:3, :3] = pose_xyz_rpy(0.0, 0.0, 0.0, yaw=yaw)[:3, :3]
        return pose

    return function_track(fn, duration_s)


def seated(x: float, y: float, yaw: float, duration_s: float, phase: float = 0.0) -> Track:
    """A seated person (TUM `sitting_*`): leans, turns and shifts a little on the chair, slowly."""

    def fn(t_s: float) -> F64:
        lean = 0.12 * np.sin(2 * np.pi * t_s / 7.0 + phase)
        turn = 0.25 * np.sin(2 * np.pi * t_s / 11.0 + 2 * phase)
        dx = 0.05 * np.sin(2 * np.pi * t_s / 5.0 + phase)
        return pose_xyz_rpy(x + dx * np.cos(yaw), y + dx * np.sin(yaw), 0.0, pitch=lean, yaw=yaw + turn)

    return function_track(fn, duration_s)


def carried_by_hand(rest_from: F64, rest_to: F64, centre_m: F64, duration_s: float, pick_s: float,
                    put_s: float, phase: float = 0.0) -> Track:
    """An object resting at `rest_from`, picked up at `pick_s`, waved around `centre_m` (translation
    up to ~0.35 m, rotation up to ~50 deg, ~40 deg/s), and put down at `rest_to` at `put_s`."""
    def fn(t_s: float) -> F64:
        if t_s <= pick_s:
            return rest_from
        if t_s >= put_s:
            return rest_to
        u = (t_s - pick_s) / (put_s - pick_s)
        ramp = min(1.0, u / 0.15, (1.0 - u) / 0.15)
        weight = ramp * ramp * (3.0 - 2.0 * ramp)  # smoothstep: lift off and set down gently
        tt = t_s - pick_s
        wave = pose_xyz_rpy(
            centre_m[0] + 0.3 * np.sin(2 * np.pi * tt / 5.0 + phase),
            centre_m[1] + 0.12 * np.sin(2 * np.pi * tt / 3.7),
            centre_m[2] + 0.15 * np.sin(2 * np.pi * tt / 4.3 + 0.5 * phase),
            roll=0.5 * np.sin(2 * np.pi * tt / 4.0), pitch=0.4 * np.sin(2 * np.pi * tt / 6.0 + phase),
            yaw=0.9 * np.sin(2 * np.pi * tt / 7.0),
        )
        return interpolate_pose(interpolate_pose(rest_from, rest_to, u), wave, weight)

    return function_track(fn, duration_s)


def changed(initial: F64 | None, changes: list[tuple[float, F64 | None]]) -> Track:
    """Still object whose pose jumps at each (t_s, new pose or None for removed) — moved, removed or
    added out of the camera's view. `initial` None means the object appears only at its first change."""
    keys = [PoseKey(0.0, initial)]
    keys += [PoseKey(t, pose, jump=True) for t, pose in changes]
    return Track(keys)
