"""The indoor room every scenario plays in: photo-textured walls, floor, ceiling, posters, shelves, lights.

World frame: z up, origin at the floor centre; the room spans x in [-3, 3], y in [-2.5, 2.5], z in
[0, 2.7] m. Walls: north is +y, east is +x. Only structure lives here; anything with a COCO class
(tables, chairs, monitors) is an `Actor` so that it appears in the instance masks.
"""

from __future__ import annotations

from changing_slam_ros.sim.actors import Part
from changing_slam_ros.sim.scene import Light, Room

ROOM_HALF_X_M = 3.0
ROOM_HALF_Y_M = 2.5
ROOM_HEIGHT_M = 2.7
WALL_T_M = 0.05


def _poster_on_wall(wall: str, along_m: float, z_m: float, w_m: float, h_m: float, texture: str) -> Part:
    """A thin picture hung on a wall; `along_m` is the horizontal coordinate along the wall."""
    t = 0.006
    if wall == "north":
        return Part((w_m / 2, t, h_m / 2), (along_m, ROOM_HALF_Y_M - t, z_m), texture)
    if wall == "south":
        return Part((w_m / 2, t, h_m / 2), (along_m, -ROOM_HALF_Y_M + t, z_m), texture)
    if wall == "east":
        return Part((t, w_m / 2, h_m / 2), (ROOM_HALF_X_M - t, along_m, z_m), texture)
    return Part((t, w_m / 2, h_m / 2), (-ROOM_HALF_X_M + t, along_m, z_m), texture)


def default_room() -> Room:
    """The standard room: brick walls, gravel-like floor, plaster ceiling, posters, two shelves, rug."""
    hx, hy, hz, t = ROOM_HALF_X_M, ROOM_HALF_Y_M, ROOM_HEIGHT_M, WALL_T_M
    parts = [
        Part((hx + t, hy + t, t), (0.0, 0.0, -t), "gravel", 1.3),  # floor, top face at z = 0
        Part((hx + t, hy + t, t), (0.0, 0.0, hz + t), "moon", 1.6),  # ceiling
        Part((hx, t, hz / 2), (0.0, hy + t, hz / 2), "brick", 1.1),  # north wall
        # every wall its own photo, so no two walls share a pattern (a tiled photo repeated on all four
        # walls makes places look alike to a bag of words, which no real room does)
        Part((hx, t, hz / 2), (0.0, -hy - t, hz / 2), "wallpaper", 0.9),  # south wall
        Part((t, hy, hz / 2), (hx + t, 0.0, hz / 2), "plaster", 1.7),  # east wall
        Part((t, hy, hz / 2), (-hx - t, 0.0, hz / 2), "stucco", 1.2),  # west wall
        Part((1.0, 0.7, 0.004), (0.6, -0.4, 0.004), "grass", 0.7),  # rug
        # posters and boards
        _poster_on_wall("north", -1.6, 1.55, 0.9, 0.78, "hubble"),
        _poster_on_wall("north", 1.5, 1.6, 1.0, 0.67, "rocket"),
        _poster_on_wall("north", 0.1, 1.9, 0.6, 0.4, "coins"),
        _poster_on_wall("east", -1.0, 1.5, 0.9, 0.6, "coffee"),
        _poster_on_wall("east", 1.2, 1.45, 1.1, 0.42, "text"),
        _poster_on_wall("east", 0.2, 2.1, 0.5, 0.38, "clock"),
        _poster_on_wall("south", 0.8, 1.5, 0.9, 0.45, "page"),
        _poster_on_wall("south", -1.4, 1.6, 0.7, 0.7, "retina"),
        _poster_on_wall("west", 0.9, 1.5, 0.8, 0.8, "ihc"),
        # shelves: a low cabinet on the west wall, a bookcase in the south-east corner
        Part((0.22, 0.7, 0.45), (-hx + 0.22, -0.6, 0.45), "wood", 0.5),
        Part((0.2, 0.65, 0.012), (-hx + 0.2, -0.6, 0.915), "page", None),
        Part((0.5, 0.18, 0.9), (hx - 0.8, -hy + 0.18, 0.9), "wood", 0.6),
        Part((0.46, 0.005, 0.8), (hx - 0.8, -hy + 0.365, 0.9), "text", 0.5),
    ]
    lights = (
        Light((-1.5, 1.2, 2.6), (0.75, 0.7, 0.6), cast_shadow=True),
        Light((1.6, 1.0, 2.6), (0.5, 0.52, 0.62)),
        Light((1.4, -1.3, 2.6), (0.65, 0.6, 0.5)),
        Light((-1.4, -1.2, 2.6), (0.4, 0.4, 0.45)),
    )
    return Room(parts=tuple(parts), lights=lights, size_m=(2 * hx, 2 * hy, hz))
