"""Randomly drawn movers for the random dynamic-scene family: people walking, sitting down and standing up,
and rigid objects carried, pushed or dragged, all placed relative to where the camera looks.

Every mover shuttles along a path drawn in the camera's "stage" frame (distance ahead of the eye along the
viewing direction, lateral offset to its right), so that its distance to the camera, and thus how much of
the image it covers, is what was drawn. It stops and starts again: a start delay, pauses along each leg
and at its ends. People are the catalogue's articulated figures scaled to a drawn height; objects are
boxes, flat boards, carts (no COCO class), chairs and suitcases with photo textures.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from changing_slam_ros.sim import actors as cat
from changing_slam_ros.sim.actors import Actor, Part, Shape
from changing_slam_ros.sim.draws import within
from changing_slam_ros.sim.motions import seated
from changing_slam_ros.sim.track import PoseKey, Track, function_track, pose_xyz_rpy

F64 = npt.NDArray[np.float64]

MOVER_KINDS = ("walker", "walker", "sitter", "carried", "pushed", "dragged")
OBJECT_SHAPES = ("box", "board", "cart", "chair", "suitcase")
OBJECT_CLASS = {"box": cat.UNKNOWN_CLASS_ID, "board": cat.UNKNOWN_CLASS_ID, "cart": cat.UNKNOWN_CLASS_ID,
                "chair": 56, "suitcase": 28}
OBJECT_TEXTURES = ("plastic_blue", "leather", "wood", "fabric_dark", "coins", "hubble", "rocket", "coffee",
                   "text", "clock", "retina", "ihc", "page", "grass", "brick", "stucco")
PATHS = ("cross", "approach", "diagonal")
PERSON_HEIGHT_M = 1.76  # the catalogue figure's height


@dataclass(frozen=True)
class MoverRanges:
    """Closed ranges every mover parameter is drawn from."""

    count: tuple[int, int] = (1, 4)
    distance_m: tuple[float, float] = (0.6, 3.0)  # from the camera, along its viewing direction
    half_length_m: tuple[float, float] = (0.5, 2.2)  # half the length of a shuttle path
    person_speed_m_s: tuple[float, float] = (0.3, 1.5)
    object_speed_m_s: tuple[float, float] = (0.1, 1.0)
    start_delay_s: tuple[float, float] = (0.0, 3.0)
    pause_s: tuple[float, float] = (0.0, 2.5)
    stops_per_leg: tuple[int, int] = (0, 2)
    person_height_m: tuple[float, float] = (1.55, 1.95)
    object_size_m: tuple[float, float] = (0.25, 0.9)  # the object's largest extent


MOVER_RANGES = MoverRanges()


@dataclass(frozen=True)
class MoverDraw:
    """One mover: what it is, where it moves (stage frame: `distance_m` ahead, `lateral_m` to the right),
    how fast, and when it stops."""

    kind: str  # walker, sitter, carried, pushed, dragged
    shape: str  # person for walkers / sitters, else one of OBJECT_SHAPES
    class_id: int
    path: str  # cross, approach, diagonal (sitters: cross, towards the chair)
    distance_m: float
    lateral_m: float
    half_length_m: float
    speed_m_s: float
    start_delay_s: float
    end_pause_s: float
    stops: tuple[tuple[float, float], ...]  # (fraction of a leg, pause s)
    person_height_m: float
    outfit: str
    object_half_m: tuple[float, float, float]
    texture: str
    with_person: bool
    yaw_rad: float  # the object's yaw relative to its path; the chair's facing for sitters


@dataclass(frozen=True)
class Stage:
    """Where the camera looks: eye position on the floor plane, unit forward and right (world xy), and the
    room's half sizes for clamping paths inside it."""

    eye_xy: tuple[float, float]
    forward_xy: tuple[float, float]
    half_x_m: float
    half_y_m: float

    def world_xy(self, ahead_m: float, right_m: float) -> F64:
        f = np.asarray(self.forward_xy)
        r = np.array([f[1], -f[0]])  # right of forward, z up
        p = np.asarray(self.eye_xy) + ahead_m * f + right_m * r
        return np.clip(p, [-self.half_x_m + 0.3, -self.half_y_m + 0.3], [self.half_x_m - 0.3, self.half_y_m - 0.3])

    def yaw(self) -> float:
        return float(np.arctan2(self.forward_xy[1], self.forward_xy[0]))


def draw_mover(rng: np.random.Generator, r: MoverRanges = MOVER_RANGES) -> MoverDraw:
    """Draw one mover within `r`."""
    kind = str(rng.choice(MOVER_KINDS))
    shape = "person" if kind in ("walker", "sitter") else str(rng.choice(OBJECT_SHAPES))
    person = kind in ("walker", "sitter") or kind == "carried" or bool(rng.random() < 0.6)
    speed = within(rng, r.person_speed_m_s) if kind in ("walker", "sitter", "carried") else within(rng, r.object_speed_m_s)
    size = within(rng, r.object_size_m)
    if shape == "board":
        half = (float(rng.uniform(0.008, 0.02)), size / 2, float(rng.uniform(0.15, 0.45)))
    elif shape == "box":
        half = (float(rng.uniform(0.1, size / 2)), size / 2, float(rng.uniform(0.1, size / 2)))
    elif shape == "cart":
        half = (size / 2, float(rng.uniform(0.18, 0.3)), float(rng.uniform(0.1, 0.25)))
    else:
        half = (0.25, 0.25, 0.45)
    n_stops = int(rng.integers(r.stops_per_leg[0], r.stops_per_leg[1] + 1))
    stops = tuple(sorted((float(rng.uniform(0.2, 0.8)), within(rng, r.pause_s)) for _ in range(n_stops)))
    path = "cross" if kind == "sitter" else str(rng.choice(PATHS))
    distance = within(rng, r.distance_m)
    lateral = float(rng.uniform(-0.9, 0.9)) * distance * 0.6  # up to about the image border at that distance
    return MoverDraw(
        kind=kind, shape=shape, class_id=0 if shape == "person" else OBJECT_CLASS[shape], path=path,
        distance_m=distance, lateral_m=lateral, half_length_m=within(rng, r.half_length_m), speed_m_s=speed,
        start_delay_s=within(rng, r.start_delay_s), end_pause_s=within(rng, r.pause_s), stops=stops,
        person_height_m=within(rng, r.person_height_m), outfit=str(rng.choice(sorted(cat.OUTFITS))),
        object_half_m=(float(half[0]), float(half[1]), float(half[2])), texture=str(rng.choice(OBJECT_TEXTURES)),
        with_person=person, yaw_rad=float(rng.uniform(-np.pi, np.pi)),
    )


# --- geometry of the movers ---

def scaled_parts(parts: tuple[Part, ...], s: float) -> tuple[Part, ...]:
    """The parts scaled uniformly by `s` about the actor's floor origin (a taller or shorter person)."""
    return tuple(Part(tuple(float(v * s) for v in p.half_size_m), tuple(float(v * s) for v in p.offset_m),  # type: ignore[arg-type]
                      p.texture, p.tile_m, p.shape, p.pitch_rad) for p in parts)


def object_parts(m: MoverDraw) -> tuple[Part, ...]:
    """The rigid object's parts, standing on the floor (z from 0), front +x."""
    hx, hy, hz = m.object_half_m
    if m.shape == "chair":
        return cat.chair_parts(m.texture)
    if m.shape == "suitcase":
        return cat.suitcase_parts()
    if m.shape == "cart":
        wheel = 0.06
        body = Part((hx, hy, hz), (0.0, 0.0, 2 * wheel + hz), m.texture, None)
        wheels = tuple(Part((wheel, wheel, 0.02), (sx * (hx - 0.08), sy * (hy - 0.02), wheel), "fabric_dark", 0.2,
                            Shape.CYLINDER) for sx in (-1, 1) for sy in (-1, 1))
        handle = Part((0.015, hy, 0.3), (-hx, 0.0, 2 * wheel + 2 * hz + 0.25), "fabric_dark", 0.2)
        return (body,) + wheels + (handle,)
    return (Part((hx, hy, hz), (0.0, 0.0, hz), m.texture, None),)  # box, board


def _path_ends(m: MoverDraw, stage: Stage) -> tuple[F64, F64]:
    """Ends A and B (world xy) of the mover's shuttle path."""
    d, c, L = m.distance_m, m.lateral_m, m.half_length_m
    if m.path == "approach":  # towards and away from the camera, near the image border at times
        near = max(0.5, d - L)
        return stage.world_xy(near, c), stage.world_xy(d + L, c)
    if m.path == "diagonal":
        return stage.world_xy(max(0.5, d - 0.5 * L), c - L), stage.world_xy(d + 0.5 * L, c + L)
    return stage.world_xy(d, c - L), stage.world_xy(d, c + L)


def shuttle_keys(a: F64, b: F64, m: MoverDraw, duration_s: float, face_motion: bool,
                 fixed_yaw: float) -> list[tuple[float, F64, float]]:
    """(t_s, xy, yaw) keys of a mover going A -> B -> A ... at `m.speed_m_s`, pausing at the drawn stops and
    at the ends, turning in place (0.5 s) at the ends when it faces its motion."""
    keys: list[tuple[float, F64, float]] = []
    turn_s = 0.5 if face_motion else 0.0
    t = m.start_delay_s
    here, there = a, b
    heading = float(np.arctan2(*(b - a)[::-1])) if face_motion else fixed_yaw
    keys.append((0.0, here, heading))
    while t < duration_s + 1.0:
        new_heading = float(np.arctan2(*(there - here)[::-1])) if face_motion else fixed_yaw
        if face_motion:
            turn = (new_heading - heading + np.pi) % (2 * np.pi) - np.pi
            keys.append((t, here, heading))
            t += turn_s
            heading = heading + turn
        keys.append((t, here, heading))
        leg = float(np.linalg.norm(there - here))
        done = 0.0
        for frac, pause in m.stops:
            p = here + frac * (there - here)
            t += (frac - done) * leg / m.speed_m_s
            keys.append((t, p, heading))
            t += pause
            keys.append((t, p, heading))
            done = frac
        t += (1.0 - done) * leg / m.speed_m_s
        keys.append((t, there, heading))
        t += m.end_pause_s
        here, there = there, here
    return keys


def _track(keys: list[tuple[float, F64, float]], z_m: float = 0.0) -> Track:
    return Track([PoseKey(t, pose_xyz_rpy(float(p[0]), float(p[1]), z_m, yaw=yaw)) for t, p, yaw in keys])


def _follow(base: Track, offset: F64, duration_s: float) -> Track:
    """A track rigidly attached to `base` at `offset` (4, 4) in its frame."""
    def fn(t_s: float) -> F64 | None:
        pose = base.pose_at(t_s)
        return None if pose is None else pose @ offset

    return function_track(fn, duration_s)  # type: ignore[arg-type]


def _person(name: str, m: MoverDraw, track: Track, stride_rad: float = 0.3) -> Actor:
    parts = scaled_parts(cat.person_parts(m.outfit, stride_rad), m.person_height_m / PERSON_HEIGHT_M)
    return Actor(name, 0, parts, track, moving=True)


def build_mover(i: int, m: MoverDraw, stage: Stage, duration_s: float) -> tuple[list[Actor], list[Actor]]:
    """(moving actors, static actors that stay in the control) of mover `i`."""
    a, b = _path_ends(m, stage)
    name = f"mover{i}_{m.kind}"
    if m.kind == "walker":
        return [_person(f"{name}_person", m, _track(shuttle_keys(a, b, m, duration_s, True, 0.0)))], []
    if m.kind == "sitter":
        return _sitter(name, m, stage, duration_s)
    axis = b - a
    axis_yaw = float(np.arctan2(axis[1], axis[0]))
    parts = object_parts(m)
    if m.kind == "carried":  # held in front of the chest by a walking person
        person_track = _track(shuttle_keys(a, b, m, duration_s, True, 0.0))
        s = m.person_height_m / PERSON_HEIGHT_M
        lift = 1.05 * s - m.object_half_m[2] if m.shape in ("box", "board") else 0.25
        offset = pose_xyz_rpy(0.3 * s + m.object_half_m[0] + 0.05, 0.0, max(0.05, lift))
        obj = Actor(f"{name}_{m.shape}", m.class_id, parts, _follow(person_track, offset, duration_s), moving=True)
        return [_person(f"{name}_person", m, person_track, stride_rad=0.2), obj], []
    # pushed / dragged over the floor, the object turned by its drawn yaw relative to the path
    obj_track = _track(shuttle_keys(a, b, m, duration_s, False, axis_yaw + m.yaw_rad))
    out = [Actor(f"{name}_{m.shape}", m.class_id, parts, obj_track, moving=True)]
    if m.with_person:
        reach = float(np.max(np.abs(m.object_half_m[:2]))) + 0.35
        # pushed: the person is on A's side facing B; dragged: on B's side facing A (pulling it towards B)
        side, facing = (-1.0, 0.0) if m.kind == "pushed" else (1.0, np.pi)
        offset = pose_xyz_rpy(side * reach, 0.0, 0.0, yaw=facing)
        path_frame = _track(shuttle_keys(a, b, m, duration_s, False, axis_yaw))
        out.append(_person(f"{name}_person", m, _follow(path_frame, offset, duration_s), stride_rad=0.2))
    return out, []


def _sitter(name: str, m: MoverDraw, stage: Stage, duration_s: float) -> tuple[list[Actor], list[Actor]]:
    """A person walks in from the side, sits down on a chair in view, fidgets, stands up and walks away; the
    standing figure and the seated one are two actors, one present at a time (swapped at the chair)."""
    chair_xy = stage.world_xy(m.distance_m, m.lateral_m)
    chair_yaw = stage.yaw() + np.pi + 0.6 * np.sin(m.yaw_rad)  # roughly facing the camera
    chair = pose_xyz_rpy(float(chair_xy[0]), float(chair_xy[1]), 0.0, yaw=chair_yaw)
    front = (chair @ np.array([0.45, 0.0, 0.0, 1.0]))[:2]
    side = stage.world_xy(m.distance_m, m.lateral_m + (m.half_length_m if m.yaw_rad >= 0 else -m.half_length_m))
    walk_s = float(np.linalg.norm(front - side)) / m.speed_m_s
    t_arrive = m.start_delay_s + walk_s
    t_sit = t_arrive + 0.6
    t_stand = t_sit + 2.0 + 2.0 * m.end_pause_s
    in_yaw = float(np.arctan2(*(front - side)[::-1]))
    out_yaw = in_yaw + np.pi
    keys = [
        PoseKey(0.0, pose_xyz_rpy(float(side[0]), float(side[1]), 0.0, yaw=in_yaw)),
        PoseKey(m.start_delay_s, pose_xyz_rpy(float(side[0]), float(side[1]), 0.0, yaw=in_yaw)),
        PoseKey(t_arrive, pose_xyz_rpy(float(front[0]), float(front[1]), 0.0, yaw=in_yaw)),
        PoseKey(t_sit - 0.3, pose_xyz_rpy(float(front[0]), float(front[1]), 0.0, yaw=chair_yaw)),
        PoseKey(t_sit, None, jump=True),
        PoseKey(t_stand, pose_xyz_rpy(float(front[0]), float(front[1]), 0.0, yaw=chair_yaw), jump=True),
        PoseKey(t_stand + 0.5, pose_xyz_rpy(float(front[0]), float(front[1]), 0.0, yaw=out_yaw)),
        PoseKey(t_stand + 0.5 + walk_s, pose_xyz_rpy(float(side[0]), float(side[1]), 0.0, yaw=out_yaw)),
    ]
    fidget = seated(float(chair[0, 3]), float(chair[1, 3]), chair_yaw, duration_s, phase=m.yaw_rad)

    def seat_fn(t_s: float) -> F64 | None:
        return fidget.pose_at(t_s) if t_sit <= t_s < t_stand else None

    # the seated figure keeps the catalogue's size: its thighs must rest on the chair's seat (0.5 m)
    seated_actor = Actor(f"{name}_seated", 0, cat.sitting_person_parts(m.outfit),
                         function_track(seat_fn, duration_s), moving=True)  # type: ignore[arg-type]
    chair_actor = Actor(f"{name}_chair", 56, cat.chair_parts(), Track.static(chair))
    return [_person(f"{name}_person", m, Track(keys)), seated_actor], [chair_actor]
