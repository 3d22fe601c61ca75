"""A randomly drawn room for the random dynamic-scene family: size, wall / floor / poster photos, furniture
and lights, all drawn from `RoomRanges` with one numpy Generator.

Walls often get repetitive, low-distinctiveness photos (brick, gravel-like stucco) and few posters, as
real offices and corridors have. The room spans x in [-half_x, half_x], y in [-half_y, half_y],
z in [0, height] (world z up, origin at the floor centre, as every scenario). Furniture with a COCO
class is returned as static `Actor`s so that it appears in the instance masks; shelves are structure.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from changing_slam_ros.sim import actors as cat
from changing_slam_ros.sim.actors import Actor, Part
from changing_slam_ros.sim.draws import within
from changing_slam_ros.sim.scene import Light, Room
from changing_slam_ros.sim.track import Track, pose_xyz_rpy

F64 = npt.NDArray[np.float64]
WALL_T_M = 0.05

WALL_TEXTURES = ("brick", "brick_grey", "stucco", "plaster", "wallpaper", "moon", "gravel")
REPETITIVE_WALLS = ("brick", "brick_grey", "stucco", "gravel")  # low-distinctiveness, self-similar photos
FLOOR_TEXTURES = ("gravel", "wood", "fabric_dark", "grass", "stucco")
CEILING_TEXTURES = ("moon", "plaster")
POSTER_TEXTURES = ("hubble", "rocket", "coins", "coffee", "text", "clock", "retina", "ihc", "page", "chelsea")
WALLS = ("north", "south", "east", "west")


@dataclass(frozen=True)
class RoomRanges:
    """Closed ranges every room parameter is drawn from (metres, counts, light levels)."""

    half_x_m: tuple[float, float] = (2.5, 4.5)
    half_y_m: tuple[float, float] = (2.0, 3.5)
    height_m: tuple[float, float] = (2.4, 3.2)
    posters: tuple[int, int] = (0, 4)
    furniture: tuple[int, int] = (0, 6)
    lights: tuple[int, int] = (2, 5)
    light_level: tuple[float, float] = (0.6, 1.2)
    light_tilt_rad: tuple[float, float] = (0.0, 0.7)  # from straight down
    ambient: tuple[float, float] = (0.38, 0.6)
    repetitive_wall_prob: float = 0.5  # chance that all four walls use repetitive photos


ROOM_RANGES = RoomRanges()


@dataclass(frozen=True)
class PosterDraw:
    wall: str
    along_m: float
    z_m: float
    width_m: float
    height_m: float
    texture: str


@dataclass(frozen=True)
class FurnitureDraw:
    kind: str  # table, chair, plant, suitcase, shelf
    x_m: float
    y_m: float
    yaw_rad: float


@dataclass(frozen=True)
class LightDraw:
    x_m: float
    y_m: float
    level: float
    tint: tuple[float, float, float]
    tilt_rad: float
    tilt_dir_rad: float


@dataclass(frozen=True)
class RoomDraw:
    """One drawn room; `walls` in the order north, south, east, west."""

    half_x_m: float
    half_y_m: float
    height_m: float
    walls: tuple[str, str, str, str]
    wall_tile_m: tuple[float, float, float, float]
    floor: str
    ceiling: str
    posters: tuple[PosterDraw, ...]
    furniture: tuple[FurnitureDraw, ...]
    lights: tuple[LightDraw, ...]
    ambient: float


def _wall_length(draw_hx: float, draw_hy: float, wall: str) -> float:
    return 2 * draw_hx if wall in ("north", "south") else 2 * draw_hy


def draw_room(rng: np.random.Generator, r: RoomRanges = ROOM_RANGES) -> RoomDraw:
    """Draw a room's parameters within `r`."""
    hx, hy, hz = within(rng, r.half_x_m), within(rng, r.half_y_m), within(rng, r.height_m)
    pool = REPETITIVE_WALLS if rng.random() < r.repetitive_wall_prob else WALL_TEXTURES
    walls = tuple(str(rng.choice(pool)) for _ in WALLS)
    tiles = tuple(float(rng.uniform(0.7, 1.8)) for _ in WALLS)
    posters = []
    for _ in range(int(rng.integers(r.posters[0], r.posters[1] + 1))):
        wall = str(rng.choice(WALLS))
        w, h = float(rng.uniform(0.4, 1.1)), float(rng.uniform(0.3, 0.8))
        half_len = _wall_length(hx, hy, wall) / 2 - w / 2 - 0.1
        posters.append(PosterDraw(wall, float(rng.uniform(-half_len, half_len)), float(rng.uniform(1.2, 1.9)),
                                  w, h, str(rng.choice(POSTER_TEXTURES))))
    furniture = []
    for _ in range(int(rng.integers(r.furniture[0], r.furniture[1] + 1))):
        kind = str(rng.choice(["table", "chair", "plant", "suitcase", "shelf"]))
        side = str(rng.choice(WALLS))  # furniture stands along a wall, 0.3-0.7 m from it
        off = float(rng.uniform(0.3, 0.7))
        if side in ("north", "south"):
            x, y = float(rng.uniform(-hx + 0.6, hx - 0.6)), (hy - off) * (1 if side == "north" else -1)
        else:
            x, y = (hx - off) * (1 if side == "east" else -1), float(rng.uniform(-hy + 0.6, hy - 0.6))
        furniture.append(FurnitureDraw(kind, x, y, float(rng.uniform(-np.pi, np.pi))))
    lights = []
    for _ in range(int(rng.integers(r.lights[0], r.lights[1] + 1))):
        tint = tuple(float(v) for v in rng.uniform(0.8, 1.0, 3))
        lights.append(LightDraw(float(rng.uniform(-hx + 0.5, hx - 0.5)), float(rng.uniform(-hy + 0.5, hy - 0.5)),
                                within(rng, r.light_level), (tint[0], tint[1], tint[2]), within(rng, r.light_tilt_rad),
                                float(rng.uniform(-np.pi, np.pi))))
    return RoomDraw(hx, hy, hz, (walls[0], walls[1], walls[2], walls[3]),
                    (tiles[0], tiles[1], tiles[2], tiles[3]), str(rng.choice(FLOOR_TEXTURES)),
                    str(rng.choice(CEILING_TEXTURES)), tuple(posters), tuple(furniture), tuple(lights),
                    within(rng, r.ambient))


def _poster(d: PosterDraw, hx: float, hy: float) -> Part:
    t = 0.006
    if d.wall == "north":
        return Part((d.width_m / 2, t, d.height_m / 2), (d.along_m, hy - t, d.z_m), d.texture)
    if d.wall == "south":
        return Part((d.width_m / 2, t, d.height_m / 2), (d.along_m, -hy + t, d.z_m), d.texture)
    if d.wall == "east":
        return Part((t, d.width_m / 2, d.height_m / 2), (hx - t, d.along_m, d.z_m), d.texture)
    return Part((t, d.width_m / 2, d.height_m / 2), (-hx + t, d.along_m, d.z_m), d.texture)


def build_room(d: RoomDraw) -> Room:
    """The room's static structure (walls, floor, ceiling, posters, shelves) and lights."""
    hx, hy, hz, t = d.half_x_m, d.half_y_m, d.height_m, WALL_T_M
    parts = [
        Part((hx + t, hy + t, t), (0.0, 0.0, -t), d.floor, 1.2),
        Part((hx + t, hy + t, t), (0.0, 0.0, hz + t), d.ceiling, 1.6),
        Part((hx, t, hz / 2), (0.0, hy + t, hz / 2), d.walls[0], d.wall_tile_m[0]),
        Part((hx, t, hz / 2), (0.0, -hy - t, hz / 2), d.walls[1], d.wall_tile_m[1]),
        Part((t, hy, hz / 2), (hx + t, 0.0, hz / 2), d.walls[2], d.wall_tile_m[2]),
        Part((t, hy, hz / 2), (-hx - t, 0.0, hz / 2), d.walls[3], d.wall_tile_m[3]),
    ]
    parts += [_poster(p, hx, hy) for p in d.posters]
    for f in d.furniture:
        if f.kind == "shelf":  # a bookcase, axis-aligned against the nearest wall
            along_x = abs(abs(f.y_m) - hy) < abs(abs(f.x_m) - hx)
            half = (0.5, 0.18, 0.9) if along_x else (0.18, 0.5, 0.9)
            parts.append(Part(half, (f.x_m, f.y_m, 0.9), "wood", 0.6))
    lights = []
    for ld in d.lights:
        s = np.sin(ld.tilt_rad)
        direction = (float(s * np.cos(ld.tilt_dir_rad)), float(s * np.sin(ld.tilt_dir_rad)), float(-np.cos(ld.tilt_rad)))
        colour = tuple(ld.level * c for c in ld.tint)
        lights.append(Light((ld.x_m, ld.y_m, hz - 0.1), (colour[0], colour[1], colour[2]), dir=direction))
    return Room(parts=tuple(parts), lights=tuple(lights), size_m=(2 * hx, 2 * hy, hz), ambient=d.ambient)


def furniture_actors(d: RoomDraw) -> list[Actor]:
    """The drawn furniture that has a COCO class, as static actors (shelves are part of the room)."""
    out: list[Actor] = []
    for i, f in enumerate(d.furniture):
        pose = pose_xyz_rpy(f.x_m, f.y_m, 0.0, yaw=f.yaw_rad)
        if f.kind == "table":
            out.append(Actor(f"table_{i}", 60, cat.table_parts(1.2, 0.7), Track.static(pose)))
        elif f.kind == "chair":
            out.append(Actor(f"chair_{i}", 56, cat.chair_parts(), Track.static(pose)))
        elif f.kind == "plant":
            out.append(Actor(f"plant_{i}", 58, cat.potted_plant_parts(), Track.static(pose)))
        elif f.kind == "suitcase":
            out.append(Actor(f"suitcase_{i}", 28, cat.suitcase_parts(), Track.static(pose)))
    return out
