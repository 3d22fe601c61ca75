"""`random_dynamic`: a family of randomised dynamic scenes, one per seed, and each seed's control.

A seed draws (`draw_params`) a room (`random_room`), a camera (TUM-like hand-held sway, roll-pitch-yaw,
half-sphere, a tripod, or a wheeled robot driving back and forth), 1-4 movers (`random_movers`) placed
0.6-3 m ahead of the camera, and a sensor (`sensor_model.draw_sensor`): exact, Kinect- or RealSense-like.
`random_dynamic_control` renders the same seed with the movers left out: the same room, path and sensor.
The drawn values go to `scenario.json` beside the frames; `RANGES` holds every range they come from.
Default length 10 s at 30 Hz (300 frames), short enough to benchmark many seeds on two cores.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from changing_slam_ros.sim.camera_path import look_at, optical_from_body
from changing_slam_ros.sim.draws import within
from changing_slam_ros.sim.random_movers import MOVER_RANGES, MoverDraw, MoverRanges, Stage, build_mover, draw_mover
from changing_slam_ros.sim.random_room import ROOM_RANGES, RoomDraw, RoomRanges, build_room, draw_room, furniture_actors
from changing_slam_ros.sim.scenarios import Scenario
from changing_slam_ros.sim.sensor_model import SensorModel, draw_sensor
from changing_slam_ros.sim.track import Track, function_track, pose_xyz_rpy

F64 = npt.NDArray[np.float64]

CAMERA_KINDS = ("xyz", "rpy", "halfsphere", "static", "robot")
DEFAULT_DURATION_S = 10.0
DEFAULT_FPS = 30.0


@dataclass(frozen=True)
class CameraRanges:
    """Closed ranges of the camera draw. Sway amplitudes and periods span TUM fr3's hand-held speeds
    (walking_static 0.01 m/s to walking_halfsphere 0.22 m/s, up to 24 deg/s) and beyond."""

    wall_distance_m: tuple[float, float] = (3.2, 4.5)  # eye to the wall it faces (capped by the room)
    eye_height_m: tuple[float, float] = (1.0, 1.6)
    robot_height_m: tuple[float, float] = (0.3, 1.0)
    target_height_m: tuple[float, float] = (0.6, 1.3)
    sway_m: tuple[float, float] = (0.08, 0.35)
    turn_deg: tuple[float, float] = (6.0, 30.0)
    sphere_radius_m: tuple[float, float] = (0.25, 0.6)
    period_s: tuple[float, float] = (4.0, 12.0)
    jitter_m: tuple[float, float] = (0.0, 0.004)
    jitter_deg: tuple[float, float] = (0.0, 0.8)
    robot_speed_m_s: tuple[float, float] = (0.1, 0.5)


CAMERA_RANGES = CameraRanges()


@dataclass(frozen=True)
class Ranges:
    room: RoomRanges = ROOM_RANGES
    camera: CameraRanges = CAMERA_RANGES
    movers: MoverRanges = MOVER_RANGES


RANGES = Ranges()


@dataclass(frozen=True)
class CameraDraw:
    kind: str
    facing: str  # the wall it looks at: north, south, east, west
    wall_distance_m: float
    lateral_m: float  # eye offset along the facing wall
    eye_height_m: float
    target_height_m: float
    target_lateral_m: float
    amplitude: float  # sway metres, turn degrees, or sphere radius metres, by kind
    period_s: float
    phase_rad: float
    jitter_m: float
    jitter_deg: float
    robot_speed_m_s: float


@dataclass(frozen=True)
class RandomDynamicParams:
    """Everything one seed draws; `as_dict()` is what `scenario.json` holds."""

    seed: int
    duration_s: float
    fps: float
    room: RoomDraw
    camera: CameraDraw
    movers: tuple[MoverDraw, ...]
    sensor: SensorModel

    def as_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["sensor"] = self.sensor.as_dict()
        return d


FACING = {"north": (0.0, 1.0), "south": (0.0, -1.0), "east": (1.0, 0.0), "west": (-1.0, 0.0)}


def draw_camera(rng: np.random.Generator, room: RoomDraw, r: CameraRanges = CAMERA_RANGES) -> CameraDraw:
    kind = str(rng.choice(CAMERA_KINDS))
    facing = str(rng.choice(list(FACING)))
    depth = 2 * (room.half_y_m if facing in ("north", "south") else room.half_x_m)
    width = 2 * (room.half_x_m if facing in ("north", "south") else room.half_y_m)
    dist = min(within(rng, r.wall_distance_m), depth - 0.5)
    amplitude = {"xyz": r.sway_m, "rpy": r.turn_deg, "halfsphere": r.sphere_radius_m}.get(kind, (0.0, 0.0))
    hand_held = kind in ("xyz", "rpy", "halfsphere")
    return CameraDraw(
        kind=kind, facing=facing, wall_distance_m=dist, lateral_m=float(rng.uniform(-0.25, 0.25)) * width,
        eye_height_m=within(rng, r.robot_height_m if kind == "robot" else r.eye_height_m),
        target_height_m=within(rng, r.target_height_m), target_lateral_m=float(rng.uniform(-0.6, 0.6)),
        amplitude=within(rng, amplitude), period_s=within(rng, r.period_s), phase_rad=float(rng.uniform(0, 2 * np.pi)),
        jitter_m=within(rng, r.jitter_m) if hand_held else 0.0, jitter_deg=within(rng, r.jitter_deg) if hand_held else 0.0,
        robot_speed_m_s=within(rng, r.robot_speed_m_s) if kind == "robot" else 0.0,
    )


def draw_params(seed: int, duration_s: float = DEFAULT_DURATION_S, fps: float = DEFAULT_FPS,
                ranges: Ranges = RANGES) -> RandomDynamicParams:
    """All of one seed's random choices, drawn in a fixed order from one Generator."""
    rng = np.random.default_rng([0x0D1A, int(seed)])
    room = draw_room(rng, ranges.room)
    camera = draw_camera(rng, room, ranges.camera)
    n = int(rng.integers(ranges.movers.count[0], ranges.movers.count[1] + 1))
    movers = tuple(draw_mover(rng, ranges.movers) for _ in range(n))
    sensor = draw_sensor(rng)
    return RandomDynamicParams(int(seed), duration_s, fps, room, camera, movers, sensor)


def stage_of(p: RandomDynamicParams) -> Stage:
    """The camera's initial viewpoint on the floor plane (where the movers are placed from)."""
    c, room = p.camera, p.room
    f = np.array(FACING[c.facing])
    wall = np.array([room.half_x_m, room.half_y_m]) * np.abs(f) * np.sign(f)  # the faced wall's coordinate
    right = np.array([f[1], -f[0]])
    eye = wall - f * c.wall_distance_m + right * c.lateral_m
    return Stage((float(eye[0]), float(eye[1])), (float(f[0]), float(f[1])), room.half_x_m, room.half_y_m)


def _jitter(c: CameraDraw, t: float) -> F64:
    """Hand-held tremor: a few millimetres and a fraction of a degree at 3-7 Hz."""
    w = 2 * np.pi * t
    j, a = c.jitter_m, math.radians(c.jitter_deg)
    return pose_xyz_rpy(j * np.sin(w * 4.1 + c.phase_rad), j * np.sin(w * 5.3), j * np.sin(w * 3.7 + 1.0),
                        roll=a * np.sin(w * 6.1), pitch=a * np.sin(w * 4.7 + 2.0), yaw=a * np.sin(w * 3.3 + c.phase_rad))


def camera_track(p: RandomDynamicParams) -> Track:
    """T_world_cam (optical frame) over [0, duration_s]."""
    c, stage = p.camera, stage_of(p)
    f = np.array([*stage.forward_xy, 0.0])
    right = np.array([f[1], -f[0], 0.0])
    up = np.array([0.0, 0.0, 1.0])
    eye = np.array([*stage.eye_xy, c.eye_height_m])
    target = eye + c.wall_distance_m * f + c.target_lateral_m * right
    target[2] = c.target_height_m
    w, ph, amp = 2 * np.pi / c.period_s, c.phase_rad, c.amplitude
    if c.kind == "robot":
        return _robot_track(p, eye, stage.yaw())

    def fn(t: float) -> F64:
        if c.kind == "xyz":
            off = amp * (np.sin(w * t + ph) * right + 0.5 * np.sin(w * t / 1.4 + 1.3 * ph) * f
                         + 0.4 * np.sin(w * t / 0.8 + 0.7 * ph) * up)
            pose = look_at(eye + off, target + off)
        elif c.kind == "rpy":
            a = math.radians(amp)
            turn = pose_xyz_rpy(0.0, 0.0, 0.0, roll=0.6 * a * np.sin(w * t / 1.3 + ph),
                                pitch=a * np.sin(w * t + 0.5 * ph), yaw=0.5 * a * np.sin(w * t / 1.8 + 0.3 * ph))
            pose = look_at(eye, target) @ turn  # optical axes: roll about x (tilt), pitch about y (pan)
        elif c.kind == "halfsphere":
            az = 1.0 * np.sin(w * t + ph)
            el = 0.5 * np.sin(w * t / 0.7 + 0.5 * ph)
            centre = eye + amp * f
            d = np.cos(el) * (np.cos(az) * -f + np.sin(az) * right) + np.sin(el) * up
            pose = look_at(centre + amp * d, target)
        else:  # a tripod: still
            pose = look_at(eye, target)
        return pose @ _jitter(c, t) if c.kind != "static" else pose

    return function_track(fn, p.duration_s)


def _robot_track(p: RandomDynamicParams, eye: F64, yaw0: float) -> Track:
    """A wheeled robot driving forward and back (speed v cos(w t)) while its heading swings, the position
    integrated on a 200 Hz grid; the camera looks along the robot's heading, a little down, with the
    floor's small vibrations."""
    c = p.camera
    v, w_drive = c.robot_speed_m_s, 2 * np.pi / (2.0 * c.period_s)
    dt = 1.0 / 200.0
    ts = np.arange(0.0, p.duration_s + 2 * dt, dt)
    yaw = yaw0 + np.radians(25.0) * np.sin(2 * np.pi * ts / c.period_s + c.phase_rad)
    speed = v * np.cos(w_drive * ts)
    xy = np.zeros((ts.size, 2))
    xy[1:] = np.cumsum((speed[:-1, None] * np.c_[np.cos(yaw[:-1]), np.sin(yaw[:-1])]) * dt, axis=0)
    xy += eye[:2]
    lim = np.array([p.room.half_x_m - 0.3, p.room.half_y_m - 0.3])
    xy = np.clip(xy, -lim, lim)
    tilt = math.atan2(c.eye_height_m - c.target_height_m, c.wall_distance_m)

    def fn(t: float) -> F64:
        i = min(int(t / dt), ts.size - 2)
        a = (t - ts[i]) / dt
        x, y = (1 - a) * xy[i] + a * xy[i + 1]
        heading = float((1 - a) * yaw[i] + a * yaw[i + 1])
        shake = pose_xyz_rpy(0.0, 0.0, 0.0005 * np.sin(2 * np.pi * 1.7 * t),
                             roll=np.radians(0.15) * np.sin(2 * np.pi * 2.3 * t + 1.0),
                             pitch=np.radians(0.15) * np.sin(2 * np.pi * 1.3 * t))
        return optical_from_body(pose_xyz_rpy(float(x), float(y), c.eye_height_m, pitch=tilt, yaw=heading) @ shake)

    return function_track(fn, p.duration_s)


def camera_speeds(track: Track, duration_s: float, fps: float) -> tuple[float, float]:
    """Mean translational (m/s) and angular (deg/s) speed of a camera track sampled at `fps`."""
    poses = [track.pose_at(k / fps) for k in range(int(duration_s * fps))]
    lin, ang = [], []
    for a, b in zip(poses, poses[1:]):
        assert a is not None and b is not None
        lin.append(float(np.linalg.norm(b[:3, 3] - a[:3, 3])) * fps)
        r = a[:3, :3].T @ b[:3, :3]
        ang.append(math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(r) - 1) / 2)))) * fps)
    return (float(np.mean(lin)), float(np.mean(ang))) if lin else (0.0, 0.0)


def build_random_dynamic(seed: int, control: bool = False, duration_s: float = DEFAULT_DURATION_S,
                         fps: float = DEFAULT_FPS) -> Scenario:
    """The scene of `seed`; with `control`, the same room, camera path and sensor without the movers."""
    p = draw_params(seed, duration_s, fps)
    stage = stage_of(p)
    actors = furniture_actors(p.room)
    movers = []
    for i, m in enumerate(p.movers):
        moving, static = build_mover(i, m, stage, duration_s)
        actors += static
        movers += moving
    if not control:
        actors += movers
    camera = camera_track(p)
    lin, ang = camera_speeds(camera, duration_s, fps)
    params = p.as_dict()
    params["camera_mean_speed_m_s"] = round(lin, 4)
    params["camera_mean_speed_deg_s"] = round(ang, 3)
    params["control"] = control
    name = "random_dynamic_control" if control else "random_dynamic"
    what = (f"{p.camera.kind} camera facing {p.camera.facing}, {len(p.movers)} mover(s) "
            f"({', '.join(m.kind + ':' + m.shape for m in p.movers)}), sensor {p.sensor.name}")
    description = f"seed {seed}: " + ("control, movers left out; " if control else "") + what
    return Scenario(name, description, build_room(p.room), tuple(actors), camera, (), duration_s, fps,
                    preview_t_s=duration_s / 2, sensor=p.sensor, parameters=params)
