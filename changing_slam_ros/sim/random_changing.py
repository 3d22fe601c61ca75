"""The randomised changing-room family: `random_changing` (changed between laps) and its control.

A seed draws a room (size, wall and floor photos, lights), pictures on the walls (photos a COCO detector may
name: plants, people, clocks, screens, a cat, a cup), 3-8 objects of COCO classes, each in one of several
styles built to look like its class (`sim/furniture.py`: chairs, couches, potted plants, suitcases, monitors
and bottles on an optional table, a round clock or a screen hung on a wall), a wheeled robot's square loop of
2-3 laps facing each wall in turn, and 1-4 changes between laps: moved a short or a long way and turned,
removed, added, replaced by another class, two of different classes swapped. A change happens while neither
its old nor its new place is in view, after the old place was seen and before both places are seen again, so
that each change can be observed. The control (`random_changing_control`) is the same draw with no change
applied. The drawn parameters and the ground truth per lap (`changing_truth.json`, see
`sim/changing_truth.py`) are written beside the render.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import numpy.typing as npt

from changing_slam_ros.errors import SimError
from changing_slam_ros.sim import actors as cat
from changing_slam_ros.sim.actors import Actor, Change, ChangeKind, Part
from changing_slam_ros.sim.camera_path import RobotLoop, robot_loop
from changing_slam_ros.sim.draws import between
from changing_slam_ros.sim.furniture import draw_look
from changing_slam_ros.sim.motions import changed
from changing_slam_ros.sim.path_views import OUT_OF_VIEW_MARGIN_PX, PathViews
from changing_slam_ros.sim.renderer import fovy_for_focal
from changing_slam_ros.sim.scenarios import DEFAULT_FY_PX, DEFAULT_HEIGHT, Scenario, check_changes_out_of_view
from changing_slam_ros.sim.scene import Light, Room
from changing_slam_ros.sim.sensor_model import EXACT, SensorModel, draw_sensor
from changing_slam_ros.sim.track import pose_xyz_rpy

F64 = npt.NDArray[np.float64]

FAMILY_FPS = 5.0  # at most 6 cm and 4.4 deg between frames (docs/changing_bench.md)
WALL_T_M = 0.05
WALL_PHOTOS = ("brick", "brick_grey", "plaster", "wallpaper", "stucco")
FLOOR_PHOTOS = ("gravel", "wood")
# photos hung as pictures, and what a COCO detector may see in them ("" = nothing in particular)
PICTURE_PHOTOS: dict[str, str] = {
    "grass": "potted plant", "astronaut": "person", "cameraman": "person", "clock": "clock", "rocket": "screen",
    "hubble": "screen", "chelsea": "cat", "coffee": "cup", "retina": "sports ball", "coins": "", "ihc": "",
    "text": "",
}
FLOOR_KINDS = ("chair", "couch", "potted_plant", "suitcase")
TABLE_KINDS = ("monitor", "bottle")
WALL_KINDS = ("wall_clock", "wall_tv")
KIND_CLASS = {"chair": 56, "couch": 57, "potted_plant": 58, "suitcase": 28, "monitor": 62, "bottle": 39,
              "wall_clock": 74, "wall_tv": 62}  # catalogue kind -> COCO class id
CHANGE_KINDS = ("moved_short", "moved_long", "removed", "added", "replaced", "swapped")
PATH_CLEARANCE_M = 0.4  # floor objects keep this far from the robot's square


@dataclass(frozen=True)
class Picture:
    """A photo hung flat on a wall: centre (3,), width and height (m), the wall's inward normal, the photo."""

    name: str
    wall: str
    centre_w: tuple[float, float, float]
    size_m: tuple[float, float]
    normal_w: tuple[float, float, float]
    texture: str
    depicts: str


@dataclass(frozen=True)
class Item:
    """One object of a COCO class: catalogue kind, class, parts, support ("floor", "table", "wall")."""

    name: str
    kind: str
    class_id: int
    parts: tuple[Part, ...]
    support: str
    style: str = ""  # the look (`furniture.LOOKS`), "" for the plain catalogue shape


@dataclass(frozen=True)
class DrawnChange:
    """A change at `t_s`, timed within half a lap of the start of lap `lap`: `kind` (CHANGE_KINDS) of `actor`;
    `other` the replacement or swap partner. `to_poses`: actor name -> pose (4, 4) after the change, None when it
    leaves the room."""

    t_s: float
    lap: int
    kind: str
    actor: str
    other: str
    to_poses: dict[str, F64 | None]


@dataclass(frozen=True)
class ChangingRoom:
    """One seed's draw: room, pictures, items and their initial poses, the robot loop, the changes."""

    seed: int
    half_x_m: float
    half_y_m: float
    height_m: float
    room: Room
    pictures: tuple[Picture, ...]
    items: dict[str, Item]
    initial: dict[str, F64 | None]  # None: added later
    loop: RobotLoop
    n_laps: int
    lap_s: float
    changes: tuple[DrawnChange, ...]
    params: dict[str, object] = field(default_factory=dict)
    sensor: SensorModel = EXACT

    def scenario(self, with_changes: bool = True) -> Scenario:
        """The scenario with the changes applied, or (False) the control: same room, objects and path."""
        from changing_slam_ros.sim.changing_truth import truth_document

        camera, _ = robot_loop(self.loop)
        per_actor: dict[str, list[tuple[float, F64 | None]]] = {}
        records: list[Change] = []
        for c in self.changes if with_changes else ():
            for name, pose in c.to_poses.items():
                per_actor.setdefault(name, []).append((c.t_s, pose))
            records += _change_records(c)
        actors = []
        for name, item in self.items.items():
            if self.initial[name] is None and name not in per_actor:
                continue  # an added object of the control: never in the room
            actors.append(Actor(name, item.class_id, item.parts, changed(self.initial[name], per_actor.get(name, []))))
        name = "random_changing" if with_changes else "random_changing_control"
        desc = (f"seed {self.seed}: {len(self.pictures)} pictures, {sum(p is not None for p in self.initial.values())}"
                f" objects, {self.n_laps} laps, " + (f"{len(self.changes)} changes" if with_changes else "no change"))
        s = Scenario(name, desc, self.room, tuple(actors), camera, tuple(sorted(records, key=lambda r: r.t_s)),
                     camera.end_s, FAMILY_FPS, preview_t_s=min(camera.end_s, 0.5 * self.lap_s), sensor=self.sensor,
                     parameters=self.params)
        check_changes_out_of_view(s, OUT_OF_VIEW_MARGIN_PX)
        doc = truth_document(self, s, with_changes)
        return replace(s, extra_files=(("changing_truth.json", doc),))


def _change_records(c: DrawnChange) -> list[Change]:
    M, R, A, P = ChangeKind.MOVED, ChangeKind.REMOVED, ChangeKind.ADDED, ChangeKind.REPLACED
    if c.kind in ("moved_short", "moved_long"):
        return [Change(c.t_s, c.actor, M)]
    if c.kind == "removed":
        return [Change(c.t_s, c.actor, R)]
    if c.kind == "added":
        return [Change(c.t_s, c.actor, A)]
    if c.kind == "replaced":
        return [Change(c.t_s, c.actor, P, c.other), Change(c.t_s, c.other, A)]
    return [Change(c.t_s, c.actor, M, c.other), Change(c.t_s, c.other, M, c.actor)]


# --- the room ---


def _wall_frame(wall: str, hx: float, hy: float) -> tuple[F64, F64, F64, float]:
    """(a point on the wall's inner face, along-wall unit vector, inward normal, half length) of `wall`."""
    if wall == "north":
        return np.array([0.0, hy, 0.0]), np.array([1.0, 0.0, 0.0]), np.array([0.0, -1.0, 0.0]), hx
    if wall == "south":
        return np.array([0.0, -hy, 0.0]), np.array([-1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), hx
    if wall == "east":
        return np.array([hx, 0.0, 0.0]), np.array([0.0, -1.0, 0.0]), np.array([-1.0, 0.0, 0.0]), hy
    return np.array([-hx, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0]), hy


WALLS = ("east", "north", "west", "south")


def _room_parts(rng: np.random.Generator, hx: float, hy: float, hz: float) -> tuple[list[Part], dict[str, object]]:
    walls = [str(w) for w in rng.permutation(WALL_PHOTOS)[:4]]
    tiles = [round(between(rng, 0.8, 1.8), 3) for _ in range(4)]
    floor, floor_tile = str(FLOOR_PHOTOS[int(rng.integers(len(FLOOR_PHOTOS)))]), round(between(rng, 0.8, 1.5), 3)
    t = WALL_T_M
    parts = [
        Part((hx + t, hy + t, t), (0.0, 0.0, -t), floor, floor_tile),
        Part((hx + t, hy + t, t), (0.0, 0.0, hz + t), "moon", 1.6),
        Part((hx, t, hz / 2), (0.0, hy + t, hz / 2), walls[1], tiles[1]),  # north
        Part((hx, t, hz / 2), (0.0, -hy - t, hz / 2), walls[3], tiles[3]),  # south
        Part((t, hy, hz / 2), (hx + t, 0.0, hz / 2), walls[0], tiles[0]),  # east
        Part((t, hy, hz / 2), (-hx - t, 0.0, hz / 2), walls[2], tiles[2]),  # west
    ]
    return parts, {"wall_photos": dict(zip(WALLS, walls)), "wall_tile_m": dict(zip(WALLS, tiles)),
                   "floor_photo": floor, "floor_tile_m": floor_tile}


def _lights(rng: np.random.Generator, hx: float, hy: float, hz: float) -> tuple[Light, ...]:
    out = []
    for k, (sx, sy) in enumerate(((-1, 1), (1, 1), (1, -1), (-1, -1))):
        level = between(rng, 0.4, 0.75)
        tint = (level * between(rng, 0.9, 1.05), level * between(rng, 0.9, 1.0), level * between(rng, 0.8, 1.0))
        out.append(Light((sx * hx / 2, sy * hy / 2, hz - 0.1), tint, cast_shadow=k == 0))
    return tuple(out)


def footprint_radius_m(item: Item) -> float:
    """Half the diagonal of the item's footprint (m)."""
    corners = np.concatenate([p.corners_m() for p in item.parts])
    return float(np.linalg.norm(np.max(np.abs(corners[:, :2]), axis=0)))


# --- the catalogue ---

KIND_SUPPORT = {"chair": "floor", "couch": "floor", "potted_plant": "floor", "suitcase": "floor", "monitor": "table",
                "bottle": "table", "wall_clock": "wall", "wall_tv": "wall"}


def _floor_item(rng: np.random.Generator, kind: str, name: str) -> Item:
    """An object of catalogue `kind` in one of its `furniture.LOOKS` styles; the look draws from its own stream
    (one draw of `rng` seeds it), so that a style with more parts does not shift the rest of the room's draw."""
    if kind not in KIND_SUPPORT:
        raise SimError(f"random_changing: unknown object kind {kind!r}")
    look_rng = np.random.default_rng(int(rng.integers(2**31)))
    style, parts = draw_look(kind, look_rng)
    return Item(name, kind, KIND_CLASS[kind], parts, KIND_SUPPORT[kind], style)


class _Planner:
    """Draws free places for items: the floor band between the robot's square and the walls, a table top, or a
    wall; every place must be seen from the path. Keeps every footprint ever used, so that no two objects overlap
    at any time."""

    def __init__(self, rng: np.random.Generator, hx: float, hy: float, loop_centre: F64, loop_half_m: float,
                 views: PathViews, fovy_deg: float) -> None:
        self.rng, self.hx, self.hy = rng, hx, hy
        self.centre, self.half = loop_centre, loop_half_m
        self.views, self.fovy = views, fovy_deg
        self.used: list[tuple[F64, float]] = []  # (xy, radius) on the floor
        self.wall_used: list[tuple[str, float, float]] = []  # (wall, along, half width)
        self.table: tuple[F64, float, float, float] | None = None  # (centre xy, yaw, half length, top z)
        self.table_used: list[float] = []

    def _free(self, xy: F64, r: float, extra: float = 0.2, in_room: bool = True) -> bool:
        if in_room and (abs(xy[0]) > self.hx - r - 0.05 or abs(xy[1]) > self.hy - r - 0.05):
            return False
        d = np.abs(xy - self.centre) - self.half  # outside the loop square by at least the clearance
        if np.max(d) < r + PATH_CLEARANCE_M:
            return False
        return all(np.linalg.norm(xy - q) >= r + rq + extra for q, rq in self.used)

    def floor(self, item: Item, near: F64 | None = None, dist: tuple[float, float] = (0.0, 0.0),
              tries: int = 300) -> F64 | None:
        """A floor pose for `item` facing the loop (yaw +-0.6 rad), seen from the path; `near` and `dist`: within
        that distance range of `near` instead of anywhere."""
        r = footprint_radius_m(item)
        for _ in range(tries):
            if near is None:
                xy = np.array([between(self.rng, -self.hx, self.hx), between(self.rng, -self.hy, self.hy)])
            else:
                a, d = between(self.rng, -np.pi, np.pi), between(self.rng, *dist)
                xy = near[:2] + d * np.array([np.cos(a), np.sin(a)])
            if not self._free(xy, r):
                continue
            to_c = self.centre - xy
            pose = pose_xyz_rpy(xy[0], xy[1], 0.0, yaw=float(np.arctan2(to_c[1], to_c[0])) + between(self.rng, -0.6, 0.6))
            if self.views.seen(item, pose, self.fovy).any():
                self.used.append((xy, r))
                return pose
        return None

    def place_table(self, length_m: float) -> F64 | None:
        """A table against a wall, its long side along it, seen from the path; None when none fits."""
        for _ in range(100):
            wall = WALLS[int(self.rng.integers(4))]
            origin, along, normal, half = _wall_frame(wall, self.hx, self.hy)
            s = between(self.rng, -half + length_m / 2 + 0.2, half - length_m / 2 - 0.2)
            xy = (origin + along * s + normal * 0.45)[:2]
            r = float(np.hypot(length_m / 2, 0.4))
            if not self._free(xy, r, 0.1, in_room=False):
                continue
            yaw = float(np.arctan2(along[1], along[0]))
            self.used.append((xy, r))
            self.table = (xy, yaw, length_m / 2, 0.77)
            return pose_xyz_rpy(xy[0], xy[1], 0.0, yaw=yaw)
        return None

    def on_table(self, item: Item) -> F64 | None:
        """A pose on the table top, near its room-side edge and clear of the other table items."""
        if self.table is None:
            return None
        xy, yaw, half, top = self.table
        for _ in range(50):
            s = between(self.rng, -half + 0.2, half - 0.2)
            if any(abs(s - q) < 0.45 for q in self.table_used):
                continue
            # facing the room (the table's -y side, its frame's x along the wall)
            c, sn = np.cos(yaw), np.sin(yaw)
            p = xy + s * np.array([c, sn]) + 0.1 * np.array([sn, -c])
            pose = pose_xyz_rpy(p[0], p[1], top, yaw=yaw - np.pi / 2 + between(self.rng, -0.3, 0.3))
            if self.views.seen(item, pose, self.fovy).any():
                self.table_used.append(s)
                return pose
        return None

    def on_wall(self, item: Item, half_w: float, z: float) -> F64 | None:
        """A pose on a wall at height `z` (centre) for an item `2 half_w` wide, clear of the other wall items."""
        for _ in range(100):
            wall = WALLS[int(self.rng.integers(4))]
            origin, along, normal, half = _wall_frame(wall, self.hx, self.hy)
            s = between(self.rng, -half + half_w + 0.2, half - half_w - 0.2)
            if any(w == wall and abs(s - q) < half_w + hq + 0.2 for w, q, hq in self.wall_used):
                continue
            pos = origin + along * s
            pose = pose_xyz_rpy(pos[0], pos[1], z, yaw=float(np.arctan2(normal[1], normal[0])))
            if self.views.seen(item, pose, self.fovy).any():
                self.wall_used.append((wall, s, half_w))
                return pose
        return None

    def pictures(self, n: int) -> list[Picture]:
        """Up to `n` pictures at free wall places whose centres are seen from the path."""
        out = []
        photos = list(PICTURE_PHOTOS)
        for k in range(200):
            if len(out) == n:
                break
            wall = WALLS[int(self.rng.integers(4))]
            origin, along, normal, half = _wall_frame(wall, self.hx, self.hy)
            w, h = between(self.rng, 0.4, 1.0), between(self.rng, 0.35, 0.8)
            s = between(self.rng, -half + w / 2 + 0.1, half - w / 2 - 0.1)
            if any(wu == wall and abs(s - q) < w / 2 + hq + 0.15 for wu, q, hq in self.wall_used):
                continue
            self.wall_used.append((wall, s, w / 2))
            photo = photos[int(self.rng.integers(len(photos)))]
            c = origin + along * s + normal * 0.006
            c[2] = between(self.rng, 0.95, 1.45)
            if not self.views.seen_point(c, self.fovy).any():
                self.wall_used.pop()
                continue
            out.append(Picture(f"picture_{len(out)}", wall, (float(c[0]), float(c[1]), float(c[2])), (w, h),
                               (float(normal[0]), float(normal[1]), 0.0), photo, PICTURE_PHOTOS[photo]))
        return out


def picture_part(p: Picture) -> Part:
    """The picture as a thin box (12 mm) against its wall."""
    t = 0.006
    n = np.asarray(p.normal_w)
    half = (t, p.size_m[0] / 2, p.size_m[1] / 2) if abs(n[0]) > 0.5 else (p.size_m[0] / 2, t, p.size_m[1] / 2)
    return Part(half, p.centre_w, p.texture)


# --- the draw ---

def _fovy() -> float:
    """The family's vertical field of view (degrees): the scenarios' 525 px focal length at 640x480."""
    return fovy_for_focal(DEFAULT_HEIGHT, DEFAULT_FY_PX)


def _turned(pose: F64, dyaw: float, xy: F64 | None = None) -> F64:
    out = pose @ pose_xyz_rpy(0.0, 0.0, 0.0, yaw=dyaw)
    if xy is not None:
        out[:2, 3] = xy
    return out


def _when(views: PathViews, fovy: float, lap: int, lap_s: float, fps: float, rng: np.random.Generator,
          involved: Sequence[tuple[Item, F64 | None, F64 | None]]) -> float | None:
    """A time near the start of lap `lap` at which every place involved (old and new poses) is out of view for
    two frames, each old place was seen before, and every old and new place is seen again after; None if none."""
    busy = np.zeros(len(views.times_s), bool)
    for item, old, new in involved:
        for pose in (old, new):
            if pose is not None:
                busy |= views.in_view(item, pose, fovy)
    seen = [(views.seen(item, old, fovy) if old is not None else None,
             views.seen(item, new, fovy) if new is not None else None) for item, old, new in involved]
    t0 = (lap - 0.5) * lap_s
    candidates = [k for k in range(1, len(busy)) if t0 <= views.times_s[k] <= t0 + lap_s and not busy[k - 1]
                  and not busy[k]]
    for k in rng.permutation(candidates) if candidates else ():
        ok = all((s_old is None or (s_old[:k].any() and s_old[k:].any())) and (s_new is None or s_new[k:].any())
                 for s_old, s_new in seen)
        if ok:
            return float(views.times_s[k]) - 0.5 / fps
    return None


def _plan_change(rng: np.random.Generator, kind: str, lap: int, lap_s: float, planner: _Planner,
                 items: dict[str, Item], poses: dict[str, F64 | None], free: list[str]) -> DrawnChange | None:
    """One change of `kind` among the still unchanged objects `free` (names); None when it cannot be placed."""
    views, fovy = planner.views, planner.fovy
    floor = [n for n in free if items[n].support == "floor" and poses[n] is not None]
    movable = [n for n in free if items[n].support in ("floor", "table") and poses[n] is not None]
    to: dict[str, F64 | None] = {}
    other = ""
    if kind in ("moved_short", "moved_long") and floor:
        actor = floor[int(rng.integers(len(floor)))]
        old = poses[actor]
        assert old is not None
        dist = (0.3, 0.8) if kind == "moved_short" else (1.2, 4.5)
        new = planner.floor(items[actor], near=old[:3, 3], dist=dist)
        if new is None:
            return None
        to[actor] = _turned(old, float(rng.choice([-1.0, 1.0])) * between(rng, 0.4, 1.4), new[:2, 3])
    elif kind == "removed" and movable:
        actor = movable[int(rng.integers(len(movable)))]
        to[actor] = None
    elif kind == "added":
        actor = f"added_{len(items)}"
        on_table = planner.table is not None and rng.random() < 0.3
        kinds = TABLE_KINDS if on_table else FLOOR_KINDS
        items[actor] = _floor_item(rng, kinds[int(rng.integers(len(kinds)))], actor)
        new = planner.on_table(items[actor]) if on_table else planner.floor(items[actor])
        if new is None:
            del items[actor]
            return None
        poses[actor] = None
        to[actor] = new
    elif kind == "replaced" and movable:
        actor = movable[int(rng.integers(len(movable)))]
        old_item, old = items[actor], poses[actor]
        assert old is not None
        kinds = [k for k in (TABLE_KINDS if old_item.support == "table" else FLOOR_KINDS) if k != "couch"]
        choices = [k for k in kinds if KIND_CLASS[k] != old_item.class_id]
        other = f"added_{len(items)}"
        items[other] = _floor_item(rng, choices[int(rng.integers(len(choices)))], other)
        poses[other] = None
        to[actor], to[other] = None, _turned(old, between(rng, -0.3, 0.3))
    elif kind == "swapped":
        pairs = [(a, b) for a in floor for b in floor if a < b and items[a].class_id != items[b].class_id
                 and items[a].kind != "couch" and items[b].kind != "couch"]
        if not pairs:
            return None
        actor, other = pairs[int(rng.integers(len(pairs)))]
        pa, pb = poses[actor], poses[other]
        assert pa is not None and pb is not None
        to[actor], to[other] = pb.copy(), pa.copy()
    else:
        return None
    involved = [(items[n], poses[n], p) for n, p in to.items()]
    t_s = _when(views, fovy, lap, lap_s, FAMILY_FPS, rng, involved)
    if t_s is None:
        return None
    return DrawnChange(t_s, lap, kind, actor, other, to)


def draw_changing_room(seed: int) -> ChangingRoom:
    """The family member of `seed` (deterministic): see the module docstring."""
    if seed < 0:
        raise SimError(f"random_changing: seed {seed}: expected a non-negative seed")
    rng = np.random.default_rng([seed, 20])
    hx, hy, hz = round(between(rng, 2.3, 3.3), 3), round(between(rng, 2.0, 2.8), 3), round(between(rng, 2.4, 3.0), 3)
    parts, textures = _room_parts(rng, hx, hy, hz)
    lights = _lights(rng, hx, hy, hz)
    n_laps = 3 if rng.random() < 0.35 else 2
    side, speed, turn = round(between(rng, 0.6, 1.0), 3), round(between(rng, 0.2, 0.3), 3), round(between(rng, 15.0, 22.0), 2)
    height, tilt = round(between(rng, 0.75, 1.1), 3), round(between(rng, -5.0, 2.0), 2)  # tilt > 0: pitched down
    centre = np.array([between(rng, -0.2, 0.2), between(rng, -0.2, 0.2)])
    yaw0 = float(int(rng.integers(4)) * np.pi / 2)
    d0, d1 = np.array([np.cos(yaw0), np.sin(yaw0)]), np.array([-np.sin(yaw0), np.cos(yaw0)])
    start = centre - side / 2 * (d0 + d1)
    loop = RobotLoop((round(float(start[0]), 4), round(float(start[1]), 4)), yaw0, side, 4 * n_laps, speed, turn,
                     height, tilt)
    lap_s = 4 * (side / speed + 90.0 / turn)
    camera, _ = robot_loop(loop)
    fovy = _fovy()
    planner = _Planner(rng, hx, hy, centre, side / 2, PathViews.of(camera, FAMILY_FPS), fovy)

    items: dict[str, Item] = {}
    poses: dict[str, F64 | None] = {}
    n_objects = int(rng.integers(3, 9))
    n_wall = int(rng.integers(0, 3))
    has_table = rng.random() < 0.5
    n_table = int(rng.integers(1, 3)) if has_table else 0
    for k in range(n_wall):
        kind = WALL_KINDS[int(rng.integers(2))]
        item = _floor_item(rng, kind, f"{kind}_{k}")
        z = between(rng, 1.0, 1.4)
        half_w = float(np.max(np.abs(np.concatenate([p.corners_m() for p in item.parts])[:, 1])))
        pose = planner.on_wall(item, half_w, z)
        if pose is not None:
            items[item.name], poses[item.name] = item, pose
    pictures = planner.pictures(int(rng.integers(3, 8)))
    if has_table:
        length = round(between(rng, 1.0, 1.6), 3)
        pose = planner.place_table(length)
        if pose is not None:
            items["table"] = Item("table", "table", 60, cat.table_parts(length, 0.8), "floor")
            poses["table"] = pose
            for k in range(n_table):
                kind = TABLE_KINDS[int(rng.integers(2))] if k else "monitor"
                item = _floor_item(rng, kind, f"{kind}_{k}")
                p = planner.on_table(item)
                if p is not None:
                    items[item.name], poses[item.name] = item, p
    n_couch, k = 0, 0
    while sum(it.support != "floor" or n != "table" for n, it in items.items()) < max(3, n_objects) and k < 20:
        kind = FLOOR_KINDS[int(rng.integers(len(FLOOR_KINDS)))]
        if kind == "couch":
            n_couch += 1
            kind = "chair" if n_couch > 1 else kind
        item = _floor_item(rng, kind, f"{kind}_{k}")
        k += 1
        p = planner.floor(item)
        if p is not None:
            items[item.name], poses[item.name] = item, p

    changes: list[DrawnChange] = []
    free = [n for n in items if n != "table"]
    for _ in range(int(rng.integers(1, 5))):
        for _attempt in range(6):
            kind = CHANGE_KINDS[int(rng.integers(len(CHANGE_KINDS)))]
            lap = int(rng.integers(1, n_laps))
            c = _plan_change(rng, kind, lap, lap_s, planner, items, poses, free)
            if c is not None:
                changes.append(c)
                free = [n for n in free if n not in c.to_poses]
                break
    initial = {n: poses.get(n) for n in items}
    all_parts = parts + [picture_part(p) for p in pictures]
    room = Room(tuple(all_parts), lights, (2 * hx, 2 * hy, hz))
    params: dict[str, object] = {
        "room_half_x_m": hx, "room_half_y_m": hy, "room_height_m": hz, **textures,
        "lights_rgb": [list(map(lambda v: round(v, 4), l.diffuse)) for l in lights],
        "n_laps": n_laps, "lap_s": round(lap_s, 4), "fps": FAMILY_FPS,
        "robot": {"side_m": side, "speed_m_s": speed, "turn_deg_s": turn, "camera_height_m": height,
                  "tilt_deg": tilt, "start_xy": list(loop.start_xy), "start_yaw_deg": round(np.degrees(yaw0), 1)},
        "objects": {n: it.kind for n, it in items.items()},
        "object_styles": {n: it.style for n, it in items.items() if it.style},
        "pictures": [p.texture for p in pictures],
        "changes": [{"kind": c.kind, "object": c.actor, "other": c.other, "lap": c.lap, "t_s": round(c.t_s, 4)}
                    for c in changes],
    }
    sensor = draw_sensor(np.random.default_rng([seed, 20, 1]))  # its own stream: the scene draws stay put
    params["sensor"] = sensor.as_dict()
    return ChangingRoom(seed, hx, hy, hz, room, tuple(pictures), items, initial, loop, n_laps, lap_s,
                        tuple(sorted(changes, key=lambda c: c.t_s)), params, sensor)


def random_changing(seed: int, with_changes: bool = True) -> Scenario:
    """The scenario `random_changing` (or its control) of `seed`."""
    return draw_changing_room(seed).scenario(with_changes)
