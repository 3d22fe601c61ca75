"""The registry of named scenarios (`SCENARIOS`, each entry with its description), modelled on the papers' sequences.

- TUM fr3-like (`walking_*`, `sitting_xyz`; `office_xyz` without people, their control): people between a
  hand-held camera and an office corner (`_tum_like`).
- PUC-USP-like (`static`, `one_chair`, `vanishing`, `changing`, `shift`, `replacing`, `one_chair_closeup`,
  and the `*_static` controls): a camera on a wheeled robot driving a square loop while objects change
  out of view (`_puc_like`); `one_chair_closeup` is the paper's wrong-loop case (`_one_chair_closeup_plan`).
- Dai-like movers of no COCO class: `unknown_mover` (carried by hand), `slow_mover` (pushed slowly, for the
  local-mapping segmentation), each with a `_control`.
- `walking_changing` (the sample bag); `random_dynamic` and `random_changing` (one randomised scene per seed,
  each with a `_control`).

A seed jitters placements, walking paths, speeds and motion phases; the same seed gives the same scenario.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.se3 import invert
from changing_slam_ros.errors import SimError
from changing_slam_ros.sim import actors as cat
from changing_slam_ros.sim.actors import Actor, Change, ChangeKind
from changing_slam_ros.sim.camera_path import (
    HandHeld, RobotLoop, half_sphere, look_at, nearly_static, robot_loop, rotate_rpy, sway_xyz,
)
from changing_slam_ros.sim.motions import carried_by_hand, changed, seated, walking
from changing_slam_ros.sim.renderer import fovy_for_focal, intrinsics_for
from changing_slam_ros.sim.room import default_room
from changing_slam_ros.sim.scene import Room
from changing_slam_ros.sim.sensor_model import EXACT, SensorModel
from changing_slam_ros.sim.track import PoseKey, Track, pose_xyz_rpy, function_track

F64 = npt.NDArray[np.float64]

DEFAULT_WIDTH = 640
DEFAULT_HEIGHT = 480
DEFAULT_FY_PX = 525.0  # the ROS default for TUM bags: fx = fy = 525, cx = 319.5, cy = 239.5 at 640x480


@dataclass(frozen=True)
class Scenario:
    """A scene over time: room, actors (each with a track), camera track, changes, length and rate."""

    name: str
    description: str
    room: Room
    actors: tuple[Actor, ...]
    camera: Track
    changes: tuple[Change, ...]
    duration_s: float
    fps: float
    fovy_deg: float = fovy_for_focal(DEFAULT_HEIGHT, DEFAULT_FY_PX)
    preview_t_s: float = 5.0  # a representative moment, for contact sheets
    sensor: SensorModel = EXACT  # how the scene is seen (RenderOptions.sensor overrides it)
    parameters: Mapping[str, Any] = field(default_factory=dict, compare=False)  # drawn values, written out
    extra_files: tuple[tuple[str, str], ...] = ()  # (file name, text) written beside the render (more ground truth)

    def n_frames(self) -> int:
        return int(np.floor(self.duration_s * self.fps + 1e-9))

    def frame_time_s(self, index: int) -> float:
        return index / self.fps

    def actor_index(self, name: str) -> int:
        for i, a in enumerate(self.actors):
            if a.name == name:
                return i
        raise SimError(f"scenario {self.name}: no actor named {name!r}")


# --- placement helpers ---

def _on(base: F64, dz: float, dx: float = 0.0, dy: float = 0.0, dyaw: float = 0.0) -> F64:
    """Pose of something standing on `base` at height `dz`, offset in the base's frame."""
    return base @ pose_xyz_rpy(dx, dy, dz, yaw=dyaw)


def _jit(rng: np.random.Generator, scale: float) -> float:
    return float(rng.uniform(-scale, scale))


def _static(name: str, class_id: int, parts: tuple[cat.Part, ...], pose: F64) -> Actor:
    return Actor(name, class_id, parts, Track.static(pose))


def _office(rng: np.random.Generator) -> list[Actor]:
    """The TUM-like office corner: table against the north wall, monitor, cup, two chairs, a plant."""
    table = pose_xyz_rpy(_jit(rng, 0.1), 1.9, 0.0)
    return [
        _static("table", 60, cat.table_parts(), table),
        _static("monitor", 62, cat.tv_parts("rocket"), _on(table, 0.77, -0.05, -0.3, -np.pi / 2)),
        _static("cup", 41, cat.cup_parts(), _on(table, 0.77, -0.2, 0.35)),
        _static("chair_left", 56, cat.chair_parts(), pose_xyz_rpy(-1.5, 1.7 + _jit(rng, 0.1), 0.0,
                                                                  yaw=-0.6 + _jit(rng, 0.3))),
        _static("chair_right", 56, cat.chair_parts(), pose_xyz_rpy(1.45, 1.65, 0.0, yaw=-2.4 + _jit(rng, 0.3))),
        _static("plant", 58, cat.potted_plant_parts(), pose_xyz_rpy(2.55, 2.1, 0.0)),
    ]


TUM_EYE = (0.0, -1.3, 1.35)
TUM_TARGET = (0.0, 1.5, 0.85)


def _walkers(rng: np.random.Generator, duration_s: float, camera: Track) -> list[Actor]:
    """Two people walking between the camera and the table; one of them keeps looking at the camera."""
    j = lambda s: _jit(rng, s)  # noqa: E731

    def camera_xyz(t: float) -> F64:
        pose = camera.pose_at(t)
        assert pose is not None
        return pose[:3, 3]

    a = walking([(-2.2 + j(0.2), 0.55 + j(0.15)), (2.2 + j(0.2), 0.7 + j(0.15))], duration_s,
                speed_m_s=0.8 + j(0.1), start_s=abs(j(1.0)), watch=camera_xyz)
    b = walking([(1.7 + j(0.2), 1.25), (-0.9 + j(0.2), 1.25), (-1.1 + j(0.2), 0.1 + j(0.1)),
                 (0.9 + j(0.2), -0.1 + j(0.1))], duration_s, speed_m_s=0.75 + j(0.1), start_s=1.0 + abs(j(1.0)))
    return [
        Actor("person_astronaut", 0, cat.person_parts("astronaut"), a, moving=True),
        Actor("person_cameraman", 0, cat.person_parts("cameraman"), b, moving=True),
    ]


def _tum_like(name: str, description: str, camera_fn: Callable[[HandHeld, float], Track], sitting: bool,
              seed: int, duration_s: float = 30.0, fps: float = 30.0, people: bool = True) -> Scenario:
    """TUM fr3-like: two people walk (or sit) between a hand-held camera and an office corner with a table,
    a monitor and chairs (`people` False: nobody, the control)."""
    rng = np.random.default_rng(seed)
    actors = _office(rng)
    hand = HandHeld(TUM_EYE, TUM_TARGET, phase=float(rng.uniform(0, 2 * np.pi)))
    camera = camera_fn(hand, duration_s)
    if not people:
        pass
    elif sitting:
        for k, (x, photo) in enumerate(((-0.55, "astronaut"), (0.55, "cameraman"))):
            chair = pose_xyz_rpy(x + _jit(rng, 0.05), 1.05, 0.0, yaw=-np.pi / 2 + _jit(rng, 0.15))
            actors.append(_static(f"chair_seat{k}", 56, cat.chair_parts(), chair))
            yaw = float(np.arctan2(chair[1, 0], chair[0, 0]))
            actors.append(Actor(f"person_{photo}", 0, cat.sitting_person_parts(photo),
                                seated(chair[0, 3], chair[1, 3], yaw, duration_s, phase=float(rng.uniform(0, 6))),
                                moving=True))
    else:
        actors += _walkers(rng, duration_s, camera)
    return Scenario(name, description, default_room(), tuple(actors), camera, (), duration_s, fps)


# --- PUC-USP-like: the robot loop and object zones ---

ZONE_EAST = pose_xyz_rpy(2.1, -0.4, 0.0, yaw=np.pi)  # objects face the robot's start (west)
ZONE_WEST = pose_xyz_rpy(-2.1, 0.4, 0.0, yaw=0.0)
ZONE_SOUTH = pose_xyz_rpy(0.3, -1.9, 0.0, yaw=np.pi / 2)
ROBOT_LOOP = RobotLoop()
# when the robot faces each wall during its loop (s), from robot_loop(ROBOT_LOOP): E 0-11.4, N 14.4-25.8,
# W 28.8-40.2, S 43.2-54.6, E 57.6-69.0, N 72.0-83.4, W 86.4-97.8, S 100.8-112.2
T_FACING_W1, T_FACING_S1, T_FACING_E2, T_FACING_N2 = 34.0, 49.0, 63.0, 78.0


def _printed_chair(seat: str, back: str) -> tuple[cat.Part, ...]:
    """A chair whose seat cushion and backrest carry prints (a photo stretched once over each face), as real
    office chairs with patterned covers or a poster taped to the back do: enough texture for place recognition
    to latch onto the chair itself, which is what makes a moved chair dangerous for loop closing."""
    plain = cat.chair_parts()
    legs = plain[:4]
    seat_part, back_part = plain[4], plain[5]
    return legs + (cat.Part(seat_part.half_size_m, seat_part.offset_m, seat, None),
                   cat.Part(back_part.half_size_m, back_part.offset_m, back, None))


# The chairs of the PUC-USP-like scenes carry prints (see `_printed_chair`); the TUM-like office's do not. Their
# photos appear nowhere else in these scenes (the wall posters use the other photos), so a match on a chair is a
# match on that chair, not aliasing with a poster.
PUC_CHAIR = _printed_chair("astronaut", "astronaut")
PUC_CHAIR_2 = _printed_chair("cameraman", "cameraman")


def _puc_objects(rng: np.random.Generator) -> dict[str, tuple[int, tuple[cat.Part, ...], F64]]:
    """The initial PUC-USP-like layout: name -> (class, parts, pose)."""
    east = ZONE_EAST @ pose_xyz_rpy(_jit(rng, 0.1), _jit(rng, 0.15), 0.0, yaw=_jit(rng, 0.3))
    west = ZONE_WEST @ pose_xyz_rpy(_jit(rng, 0.1), _jit(rng, 0.15), 0.0, yaw=_jit(rng, 0.2))
    south = ZONE_SOUTH @ pose_xyz_rpy(_jit(rng, 0.1), _jit(rng, 0.15), 0.0, yaw=_jit(rng, 0.3))
    table = pose_xyz_rpy(_jit(rng, 0.1), 1.9, 0.0)
    return {
        "chair": (56, PUC_CHAIR, east),
        "teddy_bear": (77, cat.teddy_bear_parts(), _on(east, 0.5, 0.02)),
        "table": (60, cat.table_parts(), table),
        "monitor": (62, cat.tv_parts("rocket"), _on(table, 0.77, -0.05, -0.3, -np.pi / 2)),
        "cup": (41, cat.cup_parts(), _on(table, 0.77, -0.2, 0.35)),
        "suitcase": (28, cat.suitcase_parts(), west),
        "monitor_2": (62, cat.tv_parts("hubble"), _on(west, 0.73, 0.0, -0.06)),
        "cup_2": (41, cat.cup_parts(), _on(west, 0.73, 0.0, 0.17)),
        "chair_2": (56, PUC_CHAIR_2, south),
        "book": (73, cat.book_parts(), _on(south, 0.5, 0.0, 0.0, 0.4)),
        "plant": (58, cat.potted_plant_parts(), pose_xyz_rpy(2.55, 2.1, 0.0)),
    }


def _puc_like(name: str, description: str, seed: int, keep: list[str],
              plan: Callable[[dict[str, F64], np.random.Generator], list[tuple[float, str, ChangeKind, F64 | None, str]]],
              extra: dict[str, tuple[int, tuple[cat.Part, ...]]] | None = None, n_sides: int = 7,
              fps: float = 15.0,
              place: Callable[[np.random.Generator], dict[str, F64]] | None = None,
              pause_s: float = 0.0) -> Scenario:
    """Build a robot-loop scenario with the objects `keep` of the standard layout and the changes
    `plan(initial_poses, rng)` returns as (t_s, actor, kind, new pose or None, other actor).
    `extra` declares actors that appear only through an ADDED / REPLACED change; `place(rng)` overrides the
    standard layout's initial poses of some actors (drawn after the layout, before the plan); `pause_s`: the
    robot stands still that long at the end of each side (`RobotLoop.pause_s`).

    PUC-USP-like: a camera on a wheeled robot (0.07 m/s, turning 30 deg/s in place) drives 7 or 8 sides of a
    0.8 m square, facing the walls in turn so that each changed place is seen before and after its change (101 or
    115 s, 15 Hz); objects are moved, removed, replaced or added while the robot faces away, and every change is
    checked to be out of view when it happens.
    """
    rng = np.random.default_rng(seed)
    layout = _puc_objects(rng)
    if place is not None:
        for k, pose in place(rng).items():
            layout[k] = (layout[k][0], layout[k][1], pose)
    initial = {k: layout[k][2] for k in keep}
    changes = plan(initial, rng)
    loop = RobotLoop(n_sides=n_sides, start_xy=(-0.4 + _jit(rng, 0.05), -0.4 + _jit(rng, 0.05)), pause_s=pause_s)
    camera, _ = robot_loop(loop)
    duration_s = camera.end_s
    per_actor: dict[str, list[tuple[float, F64 | None]]] = {}
    change_records: list[Change] = []
    for t_s, actor, kind, pose, other in changes:
        per_actor.setdefault(actor, []).append((t_s, pose))
        change_records.append(Change(t_s, actor, kind, other))
    actors = []
    for k in keep:
        class_id, parts, pose = layout[k]
        track = changed(pose, per_actor.get(k, []))
        actors.append(Actor(k, class_id, parts, track))
    for k, (class_id, parts) in (extra or {}).items():
        actors.append(Actor(k, class_id, parts, changed(None, per_actor.get(k, []))))
    scenario = Scenario(name, description, default_room(), tuple(actors), camera,
                        tuple(sorted(change_records, key=lambda c: c.t_s)), duration_s, fps,
                        preview_t_s=T_FACING_E2 - 1.0)
    check_changes_out_of_view(scenario)
    return scenario


def check_changes_out_of_view(scenario: Scenario, margin_px: float = 40.0) -> None:
    """Raise SimError if any change happens while the object (before or after) is in the camera's view."""
    cam = intrinsics_for(DEFAULT_WIDTH, DEFAULT_HEIGHT, scenario.fovy_deg)
    for change in scenario.changes:
        actor = scenario.actors[scenario.actor_index(change.actor)]
        lo, hi = actor.box_m()
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        T_world_cam = scenario.camera.pose_at(change.t_s)
        assert T_world_cam is not None
        for t_s in (change.t_s - 1e-6, change.t_s + 1e-6):
            pose = actor.track.pose_at(t_s)
            if pose is None:
                continue
            pts = (invert(T_world_cam) @ pose @ np.c_[corners, np.ones(8)].T).T[:, :3]
            front = pts[:, 2] > 0.05
            if not front.any():
                continue
            uv = cam.project(pts[front])
            inside = ((uv[:, 0] > -margin_px) & (uv[:, 0] < cam.width + margin_px)
                      & (uv[:, 1] > -margin_px) & (uv[:, 1] < cam.height + margin_px))
            if inside.any():
                raise SimError(f"scenario {scenario.name}: change of {change.actor} at {change.t_s:.1f} s "
                               "happens in the camera's view")


def _moved(base: F64, dx: float, dy: float, dyaw: float) -> F64:
    """`base` moved by (dx, dy) in the world and turned by dyaw about its own vertical."""
    out = base @ pose_xyz_rpy(0.0, 0.0, 0.0, yaw=dyaw)
    out[0, 3] += dx
    out[1, 3] += dy
    return out


ALL_PUC = ["chair", "teddy_bear", "table", "monitor", "cup", "suitcase", "monitor_2", "cup_2", "chair_2", "book",
           "plant"]
M, R, A, P = ChangeKind.MOVED, ChangeKind.REMOVED, ChangeKind.ADDED, ChangeKind.REPLACED


def _static_plan(p: dict[str, F64], rng: np.random.Generator) -> list:
    return []


def _one_chair_plan(p: dict[str, F64], rng: np.random.Generator) -> list:
    chair = _moved(p["chair"], -0.2 + _jit(rng, 0.1), 1.0 + _jit(rng, 0.15), 0.6)
    return [(T_FACING_W1, "chair", M, chair, ""), (T_FACING_W1, "teddy_bear", M, _on(chair, 0.5, 0.02), "")]


def _one_chair_static_plan(p: dict[str, F64], rng: np.random.Generator) -> list:
    """No change, but the same random draws as `_one_chair_plan`: the same layout and the same robot path."""
    _one_chair_plan(p, rng)
    return []


# one_chair_closeup: the printed chair (with the teddy bear) stands on the robot's path, CLOSEUP_M in front of
# the first corner (A, the robot faces east there), and is moved while the robot faces west to CLOSEUP_M in front
# of the second corner (B, facing north). The robot sees A empty on its second east side (57.6-69.0 s) and then
# drives up to the chair at B (72.0-83.4 s): its last views there show the chair as large, and from the same
# distance and angle, as the last views of the first east side did, against another wall.
CLOSEUP_M = 0.7  # chair front to the robot's stopping point, roughly; the robot turns in place 0.7 m from it
# The robot stops CLOSEUP_PAUSE_S at each corner before turning (a cautious robot in front of an obstacle): with a
# keyframe every 2 s, the 6 s of close-up approach alone give 3 keyframes, one short of loop closing's 4
# consecutive consistent queries (consistency_threshold 3); the pause adds two.
CLOSEUP_PAUSE_S = 4.0
_SIDE_S = ROBOT_LOOP.side_m / ROBOT_LOOP.speed_m_s + CLOSEUP_PAUSE_S + 90.0 / ROBOT_LOOP.turn_deg_s
T_CLOSEUP_MOVE = 2 * _SIDE_S + 0.5 * ROBOT_LOOP.side_m / ROBOT_LOOP.speed_m_s  # half-way along the first west side


def _closeup_place(rng: np.random.Generator) -> dict[str, F64]:
    """Place A: on the line of the first (east) side, facing the robot (west)."""
    chair = pose_xyz_rpy(0.4 + CLOSEUP_M + _jit(rng, 0.05), -0.4 + _jit(rng, 0.05), 0.0, yaw=np.pi + _jit(rng, 0.1))
    return {"chair": chair, "teddy_bear": _on(chair, 0.5, 0.02)}


def _closeup_b(rng: np.random.Generator) -> F64:
    """Place B: on the line of the north sides (x = 0.4), facing the robot (south)."""
    return pose_xyz_rpy(0.4 + _jit(rng, 0.05), 0.4 + CLOSEUP_M + _jit(rng, 0.05), 0.0,
                        yaw=-np.pi / 2 + _jit(rng, 0.1))


def _one_chair_closeup_plan(p: dict[str, F64], rng: np.random.Generator) -> list:
    """The paper's wrong-loop case made explicit (6 sides, stopping 4 s at each corner, 110.6 s).

    The printed chair with the teddy bear stands 0.7 m ahead of the first corner (facing east) and is moved
    while the robot faces west to 0.7 m ahead of the second corner (facing north). The robot's last views
    before each corner show it as large and from the same side (more than 30 % of the image) against different
    walls; it sees the old place empty (second east side) before it reaches the new one (second north side).
    """
    chair = _closeup_b(rng)
    return [(T_CLOSEUP_MOVE, "chair", M, chair, ""), (T_CLOSEUP_MOVE, "teddy_bear", M, _on(chair, 0.5, 0.02), "")]


def _one_chair_closeup_static_plan(p: dict[str, F64], rng: np.random.Generator) -> list:
    """No change, the same random draws as `_one_chair_closeup_plan` (same layout, same robot path)."""
    _one_chair_closeup_plan(p, rng)
    return []


def _vanishing_plan(p: dict[str, F64], rng: np.random.Generator) -> list:
    chair = _moved(p["chair"], -0.3, 1.0 + _jit(rng, 0.1), -0.4)
    return [
        (T_FACING_W1, "teddy_bear", R, None, ""),
        (T_FACING_W1, "chair", M, chair, ""),
        (T_FACING_S1, "cup", R, None, ""),
        (T_FACING_S1, "monitor", M, _moved(p["monitor"], 0.55, 0.0, 0.3), ""),
        (T_FACING_E2, "suitcase", R, None, ""),
        (T_FACING_E2, "monitor_2", R, None, ""),
        (T_FACING_E2, "cup_2", R, None, ""),
        (T_FACING_N2, "book", R, None, ""),
    ]


def _changing_plan(p: dict[str, F64], rng: np.random.Generator) -> list:
    added = pose_xyz_rpy(1.2 + _jit(rng, 0.1), 1.95, 0.0, yaw=-np.pi / 2)
    return [
        (T_FACING_W1, "teddy_bear", M, _on(p["chair_2"], 0.5, 0.02), ""),  # to the other chair
        (T_FACING_S1, "cup", R, None, ""),
        (T_FACING_S1, "suitcase_new", A, added, ""),
        (T_FACING_E2, "monitor_2", P, None, "plant_new"),
        (T_FACING_E2, "plant_new", A, _on(p["suitcase"], 0.73, 0.0, -0.06), ""),
    ]


def _shift_plan(p: dict[str, F64], rng: np.random.Generator) -> list:
    chair = _moved(p["chair"], -0.1, 1.1 + _jit(rng, 0.1), 0.5)
    dy = -1.0 + _jit(rng, 0.1)
    return [
        (T_FACING_W1, "chair", M, chair, ""),
        (T_FACING_W1, "teddy_bear", M, _on(chair, 0.5, 0.02), ""),
        (T_FACING_S1, "monitor", M, _moved(p["monitor"], 0.6, 0.0, 0.0), ""),
        (T_FACING_E2, "suitcase", M, _moved(p["suitcase"], 0.0, dy, 0.0), ""),
        (T_FACING_E2, "monitor_2", M, _moved(p["monitor_2"], 0.0, dy, 0.0), ""),
        (T_FACING_E2, "cup_2", M, _moved(p["cup_2"], 0.0, dy, 0.0), ""),
    ]


def _replacing_plan(p: dict[str, F64], rng: np.random.Generator) -> list:
    return [
        (T_FACING_W1, "chair", P, None, "plant_new"),
        (T_FACING_W1, "teddy_bear", R, None, ""),
        (T_FACING_W1, "plant_new", A, _moved(p["chair"], 0.0, 0.0, 0.0), ""),
        (T_FACING_N2, "chair_2", R, None, ""),
        (T_FACING_N2, "book", R, None, ""),
    ]


def _unknown_mover(seed: int, carried: bool = True) -> Scenario:
    """`carried` False: the control, the same scene and camera path with the box left resting on the table."""
    rng = np.random.default_rng(seed)
    duration_s = 24.0
    actors = _office(rng)
    table = actors[0].track.pose_at(0.0)
    assert table is not None
    rest_from = _on(table, 0.77 + 0.08, 0.1, 0.05 + _jit(rng, 0.05), 0.3)
    rest_to = _on(table, 0.77 + 0.08, 0.1, -0.45 + _jit(rng, 0.05), -0.5)
    eye = np.array([0.0, 0.3, 1.3])
    centre = eye + np.array([0.0, 1.0, -0.15])
    box = carried_by_hand(rest_from, rest_to, centre, duration_s, pick_s=3.0, put_s=duration_s - 4.0,
                          phase=float(rng.uniform(0, 2 * np.pi)))
    if not carried:
        box = Track.static(rest_from)
    actors.append(Actor("parcel", -1, cat.unknown_object_parts(), box, moving=carried))
    hand = HandHeld(tuple(eye), (0.0, 1.9, 0.85), phase=float(rng.uniform(0, 2 * np.pi)))
    if not carried:
        return Scenario("unknown_mover_control", "unknown_mover without the motion: the box stays on the table "
                        "(the control for unknown_mover)", default_room(), tuple(actors),
                        nearly_static(hand, duration_s), (), duration_s, 30.0, preview_t_s=8.0)
    return Scenario("unknown_mover", "a box of no COCO class picked up from the table, carried and turned "
                    "in front of a nearly still camera, and put down elsewhere (Dai et al.)", default_room(),
                    tuple(actors), nearly_static(hand, duration_s), (), duration_s, 30.0,
                    preview_t_s=8.0)


SLOW_MOVER_SPEED_M_S = 0.03  # a box pushed along the table: 1 mm per frame at 30 Hz, 3 cm per second


def _slow_mover(seed: int, pushed: bool = True) -> Scenario:
    """A box of no COCO class pushed slowly along the table (`SLOW_MOVER_SPEED_M_S`, with a slow quarter turn)
    from 4 s to 20 s in front of a nearly still camera, the rest of the time at rest. Between two frames 0.1 s
    apart it moves 3 mm (about 1.3 px at 1.6 m): below what the two-frame segmentation can tell from noise;
    across keyframes a second apart it is several centimetres. `pushed` False: the control, the box stays at
    its start."""
    rng = np.random.default_rng(seed)
    duration_s = 24.0
    actors = _office(rng)
    table = actors[0].track.pose_at(0.0)
    assert table is not None
    push_from_s, push_to_s = 4.0, 20.0
    length_m = SLOW_MOVER_SPEED_M_S * (push_to_s - push_from_s)
    half = (0.12, 0.16, 0.11)  # a larger parcel than unknown_mover's, so that it carries many keypoints
    y0 = -0.05 + _jit(rng, 0.05)
    start = _on(table, 0.77 + half[2], 0.05, y0 + 0.5 * length_m, 0.2)
    end = _on(table, 0.77 + half[2], 0.05, y0 - 0.5 * length_m, 0.2 + np.radians(25.0))
    box = Track.static(start)
    if pushed:
        box = Track([PoseKey(0.0, start), PoseKey(push_from_s, start), PoseKey(push_to_s, end),
                     PoseKey(duration_s, end)])
    actors.append(Actor("parcel", -1, (cat.Part(half, (0.0, 0.0, 0.0), "plastic_blue", None),), box,
                        moving=pushed))
    hand = HandHeld((0.0, 0.3, 1.3), (0.0, 1.9, 0.85), phase=float(rng.uniform(0, 2 * np.pi)))
    if not pushed:
        return Scenario("slow_mover_control", "slow_mover without the push: the box stays where it starts "
                        "(the control for slow_mover)", default_room(), tuple(actors),
                        nearly_static(hand, duration_s), (), duration_s, 30.0, preview_t_s=12.0)
    return Scenario("slow_mover", "a box of no COCO class pushed slowly (3 cm/s) along the table in front of a "
                    "nearly still camera: too slow for the two-frame segmentation", default_room(), tuple(actors),
                    nearly_static(hand, duration_s), (), duration_s, 30.0, preview_t_s=12.0)


def _walking_changing(seed: int) -> Scenario:
    """15 s: a person walks past the table; the camera pans to the east wall and back, and meanwhile the
    chair and the cup by the table are moved."""
    rng = np.random.default_rng(seed)
    duration_s = 15.0
    actors = _office(rng)
    eye = np.array([0.0, -0.2, 1.3])
    north, east = np.radians(90.0), np.radians(0.0)

    def yaw_at(t: float) -> float:  # hold north, pan to east at 45 deg/s, hold, pan back
        knots = [(0.0, north), (4.0, north), (6.0, east), (9.0, east), (11.0, north), (15.0, north)]
        for (t0, y0), (t1, y1) in zip(knots, knots[1:]):
            if t0 <= t <= t1:
                u = (t - t0) / (t1 - t0)
                return y0 + (y1 - y0) * (3 * u * u - 2 * u * u * u)
        return north

    def cam(t: float) -> F64:
        yaw = yaw_at(t)
        sway = 0.03 * np.array([np.sin(0.9 * t), np.sin(1.3 * t + 1.0), 0.5 * np.sin(1.7 * t)])
        return look_at(eye + sway, eye + sway + np.array([np.cos(yaw), np.sin(yaw), -0.2]))

    person = walking([(-2.0 + _jit(rng, 0.2), 0.9), (2.0 + _jit(rng, 0.2), 0.9)], duration_s,
                     speed_m_s=0.8, start_s=0.5)
    actors.append(Actor("person_astronaut", 0, cat.person_parts("astronaut"), person, moving=True))
    idx = {a.name: i for i, a in enumerate(actors)}
    chair0 = actors[idx["chair_left"]].track.pose_at(0.0)
    cup0 = actors[idx["cup"]].track.pose_at(0.0)
    assert chair0 is not None and cup0 is not None
    t_change = 7.5
    chair1 = _moved(chair0, 0.9, -0.5, 0.8)
    cup1 = _moved(cup0, 0.5, -0.1, 0.0)
    actors[idx["chair_left"]] = Actor("chair_left", 56, cat.chair_parts(), changed(chair0, [(t_change, chair1)]))
    actors[idx["cup"]] = Actor("cup", 41, cat.cup_parts(), changed(cup0, [(t_change, cup1)]))
    s = Scenario("walking_changing", "a person walks past a table while the camera pans away and back; "
                 "the chair and the cup are moved while out of view (sample bag)", default_room(), tuple(actors),
                 function_track(cam, duration_s), (Change(t_change, "chair_left", M), Change(t_change, "cup", M)),
                 duration_s, 15.0, preview_t_s=12.0)
    check_changes_out_of_view(s)
    return s


@dataclass(frozen=True)
class ScenarioInfo:
    description: str
    build: Callable[[int], Scenario]


def _puc(name: str, description: str, keep: list[str], plan: Callable[..., list],
         extra: dict[str, tuple[int, tuple[cat.Part, ...]]] | None = None, n_sides: int = 7,
         place: Callable[[np.random.Generator], dict[str, F64]] | None = None, pause_s: float = 0.0) -> ScenarioInfo:
    return ScenarioInfo(description, lambda seed: _puc_like(name, description, seed, keep, plan, extra, n_sides,
                                                            place=place, pause_s=pause_s))


def _tum(name: str, description: str, camera_fn: Callable[[HandHeld, float], Track],
         sitting: bool = False, people: bool = True) -> ScenarioInfo:
    return ScenarioInfo(description,
                        lambda seed: _tum_like(name, description, camera_fn, sitting, seed, people=people))


SCENARIOS: dict[str, ScenarioInfo] = {
    "walking_xyz": _tum("walking_xyz", "two people walk; the camera translates along x, y, z", sway_xyz),
    "walking_static": _tum("walking_static", "two people walk; the camera is held still", nearly_static),
    "walking_rpy": _tum("walking_rpy", "two people walk; the camera rotates in roll, pitch, yaw", rotate_rpy),
    "walking_halfsphere": _tum("walking_halfsphere", "two people walk; the camera moves on a half-sphere",
                               half_sphere),
    "sitting_xyz": _tum("sitting_xyz", "two people sit and fidget; the camera translates along x, y, z",
                        sway_xyz, sitting=True),
    "office_xyz": _tum("office_xyz", "nobody in the office; the camera translates along x, y, z (the control "
                       "for walking_xyz)", sway_xyz, people=False),
    "static": _puc("static", "robot loop in a furnished room, nothing changes (baseline)", ALL_PUC, _static_plan),
    "one_chair": _puc("one_chair", "robot loop; a chair with a teddy bear is moved while out of view",
                      ["chair", "teddy_bear", "table"], _one_chair_plan),
    "one_chair_static": _puc("one_chair_static", "one_chair's room (chair, teddy bear, table) with nothing moved: "
                             "the control for one_chair's camera ATE", ["chair", "teddy_bear", "table"],
                             _one_chair_static_plan),
    "one_chair_closeup": _puc("one_chair_closeup", "robot loop; the printed chair with the teddy bear stands "
                              "0.7 m ahead of the first corner and is moved, out of view, 0.7 m ahead of the second: "
                              "seen close-up at both, against different walls (a wrong loop on a moved object)",
                              ["chair", "teddy_bear", "table"], _one_chair_closeup_plan, n_sides=6,
                              place=_closeup_place, pause_s=CLOSEUP_PAUSE_S),
    "one_chair_closeup_static": _puc("one_chair_closeup_static", "one_chair_closeup with nothing moved (the chair "
                                     "stays at the first corner): its control", ["chair", "teddy_bear", "table"],
                                     _one_chair_closeup_static_plan, n_sides=6, place=_closeup_place,
                                     pause_s=CLOSEUP_PAUSE_S),
    "vanishing": _puc("vanishing", "robot loop; objects are moved and removed one by one out of view",
                      ALL_PUC, _vanishing_plan, n_sides=8),
    "changing": _puc("changing", "robot loop; the teddy bear changes chair, objects are removed, replaced, added",
                     ALL_PUC, _changing_plan,
                     {"suitcase_new": (28, cat.suitcase_parts()), "plant_new": (58, cat.potted_plant_parts())}),
    "shift": _puc("shift", "robot loop; chair, monitor and the suitcase group are moved out of view", ALL_PUC,
                  _shift_plan),
    "replacing": _puc("replacing", "robot loop; the chair with the teddy bear is replaced by a plant, then the "
                      "other chair is removed", ALL_PUC, _replacing_plan,
                      {"plant_new": (58, cat.potted_plant_parts())}, n_sides=8),
    "unknown_mover": ScenarioInfo("a box of no COCO class carried by hand in front of the camera (Dai et al.)",
                                  _unknown_mover),
    "unknown_mover_control": ScenarioInfo("unknown_mover with the box left on the table (its control)",
                                          lambda seed: _unknown_mover(seed, carried=False)),
    "slow_mover": ScenarioInfo("a box of no COCO class pushed slowly along the table (local-mapping segmentation)",
                               _slow_mover),
    "slow_mover_control": ScenarioInfo("slow_mover with the box left where it starts (its control)",
                                       lambda seed: _slow_mover(seed, pushed=False)),
    "walking_changing": ScenarioInfo("15 s pan with a walker and an out-of-view move (the sample bag)",
                                     _walking_changing),
    "random_dynamic": ScenarioInfo("a randomised dynamic scene per seed: room, camera path, 1-4 people or "
                                   "objects moving 0.6-3 m away, sensor model (sim/random_dynamic.py)",
                                   lambda seed: _random_dynamic(seed, control=False)),
    "random_dynamic_control": ScenarioInfo("random_dynamic's seed with the movers left out (its control)",
                                           lambda seed: _random_dynamic(seed, control=True)),
    "random_changing": ScenarioInfo("the randomised changing-room family: a room, pictures and 3-8 objects drawn "
                                    "per seed, 2-3 robot laps, changes between laps (sim/random_changing.py)",
                                    lambda seed: _random_changing(seed, True)),
    "random_changing_control": ScenarioInfo("random_changing's seed with no change applied (its control)",
                                            lambda seed: _random_changing(seed, False)),
}


def _random_dynamic(seed: int, control: bool) -> Scenario:
    from changing_slam_ros.sim.random_dynamic import build_random_dynamic  # it builds on this module

    return build_random_dynamic(seed, control=control)


def _random_changing(seed: int, with_changes: bool) -> Scenario:
    from changing_slam_ros.sim.random_changing import random_changing

    return random_changing(seed, with_changes)


def build_scenario(name: str, seed: int = 0) -> Scenario:
    """The scenario `name` for `seed`; SimError names the known scenarios when `name` is unknown."""
    try:
        info = SCENARIOS[name]
    except KeyError as err:
        raise SimError(f"scenario {name!r}: unknown; known: {', '.join(SCENARIOS)}") from err
    return info.build(seed)
