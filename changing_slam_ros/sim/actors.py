"""Actors: people and COCO-class objects built from textured boxes, cylinders and ellipsoids, each on its own track.

An actor's frame has z up, origin at the centre of its footprint on the floor, front facing +x. Parts are
given in that frame. Class ids are COCO 0-based (the 80-class list: person 0, suitcase 28, cup 41,
chair 56, potted plant 58, dining table 60, tv 62, teddy bear 77); -1 marks an object of no COCO class.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.dynamic.detector import COCO80_NAMES
from changing_slam_ros.sim.track import Track

F64 = npt.NDArray[np.float64]

UNKNOWN_CLASS_ID = -1


def coco_name(class_id: int) -> str:
    """Name of a 0-based COCO class id; "unknown" for -1."""
    return COCO80_NAMES[class_id] if 0 <= class_id < len(COCO80_NAMES) else "unknown"


class Shape(Enum):
    BOX = "box"
    CYLINDER = "cylinder"  # axis along z; radius = half_size_m[0]
    ELLIPSOID = "ellipsoid"  # semi-axes = half_size_m; the texture wraps once around z, its centre facing +x


@dataclass(frozen=True)
class Part:
    """One textured solid. `half_size_m` (x, y, z) half extents; `offset_m` its centre in the parent frame.

    `tile_m`: metres per texture repeat (tiled surfaces); None stretches the texture once over each face.
    `pitch_rad`: the part turned by this angle about the parent's y axis, about its own centre (a leg or an
    arm swung forward: positive moves its bottom towards +x). `yaw_rad`: then turned about the parent's z
    axis, about its own centre (a leaf pointing out of a plant, a wheel's axle along y).
    """

    half_size_m: tuple[float, float, float]
    offset_m: tuple[float, float, float]
    texture: str
    tile_m: float | None = None
    shape: Shape = Shape.BOX
    pitch_rad: float = 0.0
    yaw_rad: float = 0.0

    def rotation(self) -> F64:
        """(3, 3) rotation of the part in the parent frame: about y by -`pitch_rad`, then about z by `yaw_rad`."""
        c, s = np.cos(self.pitch_rad), np.sin(self.pitch_rad)
        r = np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])
        if self.yaw_rad:
            cy, sy = np.cos(self.yaw_rad), np.sin(self.yaw_rad)
            r = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]]) @ r
        return r

    def corners_m(self) -> F64:
        """The 8 corners (8, 3) of the part's bounding box, in the parent frame."""
        h = np.asarray(self.half_size_m)
        if self.shape is Shape.CYLINDER:
            h = np.array([h[0], h[0], h[2]])
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)
        return np.asarray(self.offset_m) + (signs * h) @ self.rotation().T


def limb(top_m: tuple[float, float, float], length_m: float, radius_m: float, texture: str, tile_m: float | None,
         pitch_rad: float = 0.0) -> Part:
    """A cylinder hanging from the joint `top_m` (a hip or a shoulder), swung by `pitch_rad` (bottom forward)."""
    half = length_m / 2.0
    centre = (top_m[0] + half * np.sin(pitch_rad), top_m[1], top_m[2] - half * np.cos(pitch_rad))
    return Part((radius_m, radius_m, half), (float(centre[0]), float(centre[1]), float(centre[2])), texture, tile_m,
                Shape.CYLINDER, pitch_rad)


class ChangeKind(Enum):
    MOVED = "moved"
    REMOVED = "removed"
    ADDED = "added"
    REPLACED = "replaced"  # this object was removed and another one put in its place


@dataclass(frozen=True)
class Change:
    """A scene change at `t_s`: what happened to actor `actor`; `other` names the replacement."""

    t_s: float
    actor: str
    kind: ChangeKind
    other: str = ""


@dataclass(frozen=True)
class Actor:
    """A movable thing with ground truth: name, COCO class (0-based, -1 = none), parts and track."""

    name: str
    class_id: int
    parts: tuple[Part, ...]
    track: Track
    moving: bool = False  # moves continuously (people, hand-held objects) rather than only by changes
    tags: tuple[str, ...] = field(default=())

    @property
    def class_name(self) -> str:
        return coco_name(self.class_id)

    def box_m(self) -> tuple[F64, F64]:
        """Axis-aligned bounds (min (3,), max (3,)) of all parts, in the actor frame."""
        corners = np.concatenate([p.corners_m() for p in self.parts])
        return corners.min(axis=0), corners.max(axis=0)


# --- Catalogue of shapes. Each returns the parts; scenarios pick tracks. ---

# Clothing per person: (shirt, trousers, head texture: a face photo wrapped on the front, hair around it).
OUTFITS: dict[str, tuple[str, str, str]] = {
    "astronaut": ("shirt_red", "denim", "head_astronaut"),
    "cameraman": ("shirt_blue", "fabric_dark", "head_grey"),
}


def _outfit(photo: str) -> tuple[str, str, str]:
    return OUTFITS.get(photo, OUTFITS["astronaut"])


def person_parts(photo: str = "astronaut", stride_rad: float = 0.3) -> tuple[Part, ...]:
    """A standing person, 1.76 m, facing +x, caught mid-stride: legs apart by `stride_rad` each way (left
    forward), arms swung the other way, shoes, hips, torso with shoulders, neck and a head whose front shows
    a face photo (hair around it). Clothing per `photo` (`OUTFITS`)."""
    shirt, trousers, head = _outfit(photo)
    E = Shape.ELLIPSOID
    parts: list[Part] = []
    leg_len = 0.84
    hip_z = 0.07 + leg_len * float(np.cos(stride_rad))  # the feet on the floor
    for sy, side in ((1.0, 1.0), (-1.0, -1.0)):  # left (+y) leg forward, right arm forward
        leg = side * stride_rad
        arm = -side * 0.6 * stride_rad
        parts += [
            Part((0.12, 0.05, 0.035), (leg_len * float(np.sin(leg)) + 0.04, sy * 0.1, 0.035), "shoe", 0.2),
            limb((0.0, sy * 0.1, hip_z), 0.44, 0.078, trousers, 0.25, leg),  # thigh
            limb((0.44 * float(np.sin(leg)), sy * 0.1, hip_z - 0.44 * float(np.cos(leg))), 0.4, 0.058,
                 trousers, 0.25, leg),  # shin
            limb((0.0, sy * 0.27, 1.45), 0.3, 0.048, shirt, 0.25, arm),  # upper arm
            limb((0.3 * float(np.sin(arm)), sy * 0.28, 1.45 - 0.3 * float(np.cos(arm))), 0.27, 0.04, "skin", 0.2,
                 arm + 0.15),  # forearm, elbow a little bent
        ]
        elbow = (0.3 * np.sin(arm), 1.45 - 0.3 * np.cos(arm))
        hand = (elbow[0] + 0.31 * np.sin(arm + 0.15), elbow[1] - 0.31 * np.cos(arm + 0.15))
        parts.append(Part((0.035, 0.03, 0.07), (float(hand[0]), sy * 0.28, float(hand[1])), "skin", 0.2, E))
    parts += [
        Part((0.12, 0.19, 0.1), (0.0, 0.0, 0.93), trousers, 0.25, E),  # hips
        Part((0.1, 0.18, 0.25), (0.0, 0.0, 1.2), shirt, 0.3),  # torso
        Part((0.1, 0.24, 0.065), (0.0, 0.0, 1.44), shirt, 0.3, E),  # shoulders
        Part((0.05, 0.05, 0.05), (0.0, 0.0, 1.53), "skin", 0.2, Shape.CYLINDER),  # neck
        Part((0.105, 0.09, 0.12), (0.0, 0.0, 1.645), head, None, E),  # head, face to +x
    ]
    return tuple(parts)


def sitting_person_parts(photo: str = "astronaut") -> tuple[Part, ...]:
    """A person sitting on a chair (placed by the scenario, seat top at 0.5 m), facing +x, 1.42 m tall:
    feet on the floor, shins, thighs forward on the seat, torso, arms resting on the thighs, head."""
    shirt, trousers, head = _outfit(photo)
    E, C = Shape.ELLIPSOID, Shape.CYLINDER
    parts: list[Part] = []
    for sy in (-1.0, 1.0):
        parts += [
            Part((0.12, 0.05, 0.035), (0.36, sy * 0.1, 0.035), "shoe", 0.2),
            Part((0.058, 0.058, 0.22), (0.32, sy * 0.1, 0.29), trousers, 0.25, C),  # shin
            Part((0.21, 0.075, 0.07), (0.13, sy * 0.1, 0.57), trousers, 0.25),  # thigh, forward on the seat
            Part((0.048, 0.048, 0.14), (-0.06, sy * 0.26, 0.96), shirt, 0.25, C),  # upper arm
            Part((0.13, 0.04, 0.04), (0.06, sy * 0.22, 0.76), "skin", 0.2),  # forearm on the thigh
            Part((0.05, 0.03, 0.035), (0.22, sy * 0.19, 0.74), "skin", 0.2, E),  # hand
        ]
    parts += [
        Part((0.12, 0.19, 0.09), (-0.06, 0.0, 0.62), trousers, 0.25, E),  # hips
        Part((0.11, 0.19, 0.3), (-0.06, 0.0, 0.86), shirt, 0.3, E),  # torso
        Part((0.1, 0.24, 0.065), (-0.06, 0.0, 1.09), shirt, 0.3, E),  # shoulders
        Part((0.05, 0.05, 0.05), (-0.06, 0.0, 1.18), "skin", 0.2, C),  # neck
        Part((0.105, 0.09, 0.12), (-0.06, 0.0, 1.295), head, None, E),  # head
    ]
    return tuple(parts)


def chair_parts(texture: str = "leather") -> tuple[Part, ...]:
    legs = tuple(
        Part((0.02, 0.02, 0.22), (sx * 0.18, sy * 0.18, 0.22), "wood", 0.2)
        for sx in (-1, 1) for sy in (-1, 1)
    )
    return legs + (
        Part((0.22, 0.22, 0.03), (0.0, 0.0, 0.47), texture, 0.3),
        Part((0.03, 0.22, 0.26), (-0.19, 0.0, 0.76), texture, 0.3),
    )


def teddy_bear_parts() -> tuple[Part, ...]:
    return (
        Part((0.12, 0.15, 0.14), (0.0, 0.0, 0.14), "chelsea", None),
        Part((0.1, 0.1, 0.09), (0.0, 0.0, 0.37), "chelsea", None),
        Part((0.03, 0.03, 0.03), (0.0, -0.08, 0.48), "chelsea", None),
        Part((0.03, 0.03, 0.03), (0.0, 0.08, 0.48), "chelsea", None),
    )


def tv_parts(screen: str = "rocket") -> tuple[Part, ...]:
    """A monitor on a stand, screen facing +x, 0.62 m tall (stand on a table top at z=0)."""
    return (
        Part((0.08, 0.1, 0.01), (0.0, 0.0, 0.01), "fabric_dark", 0.2),
        Part((0.02, 0.03, 0.1), (0.0, 0.0, 0.12), "fabric_dark", 0.2),
        Part((0.025, 0.32, 0.2), (0.0, 0.0, 0.41), "fabric_dark", 0.2),
        Part((0.003, 0.3, 0.18), (0.027, 0.0, 0.41), screen, None),
    )


def suitcase_parts() -> tuple[Part, ...]:
    return (
        Part((0.11, 0.24, 0.33), (0.0, 0.0, 0.35), "leather", 0.25),
        Part((0.02, 0.07, 0.025), (0.0, 0.0, 0.705), "fabric_dark", 0.2),
    )


def cup_parts() -> tuple[Part, ...]:
    return (Part((0.045, 0.045, 0.055), (0.0, 0.0, 0.055), "coffee", None, Shape.CYLINDER),)


def potted_plant_parts() -> tuple[Part, ...]:
    return (
        Part((0.14, 0.14, 0.15), (0.0, 0.0, 0.15), "leather", 0.2, Shape.CYLINDER),
        Part((0.22, 0.22, 0.3), (0.0, 0.0, 0.6), "grass", 0.3, Shape.CYLINDER),
    )


def table_parts(length_m: float = 1.4, width_m: float = 0.8) -> tuple[Part, ...]:
    hx, hy = length_m / 2, width_m / 2
    legs = tuple(
        Part((0.03, 0.03, 0.36), (sx * (hx - 0.06), sy * (hy - 0.06), 0.36), "wood", 0.2)
        for sx in (-1, 1) for sy in (-1, 1)
    )
    return legs + (Part((hx, hy, 0.025), (0.0, 0.0, 0.745), "wood", 0.4),)


def book_parts() -> tuple[Part, ...]:
    """A closed book lying flat (0.24 x 0.17 x 0.03 m), printed pages on every face."""
    return (Part((0.12, 0.085, 0.015), (0.0, 0.0, 0.015), "page", None),)


def unknown_object_parts() -> tuple[Part, ...]:
    """A hand-held box of no COCO class (a parcel with a printed pattern)."""
    return (Part((0.09, 0.12, 0.08), (0.0, 0.0, 0.0), "plastic_blue", None),)


def couch_parts(texture: str = "leather", length_m: float = 1.6) -> tuple[Part, ...]:
    """A two- or three-seat couch facing +x: seat block, backrest and two armrests (0.85 m deep, 0.85 m tall)."""
    hy = length_m / 2
    return (
        Part((0.38, hy - 0.1, 0.2), (0.04, 0.0, 0.2), texture, 0.35),  # seat
        Part((0.1, hy, 0.42), (-0.32, 0.0, 0.42), texture, 0.35),  # backrest
        Part((0.38, 0.1, 0.3), (0.04, hy - 0.1, 0.3), texture, 0.35),  # armrests
        Part((0.38, 0.1, 0.3), (0.04, -hy + 0.1, 0.3), texture, 0.35),
    )


def bottle_parts(texture: str = "plastic_blue") -> tuple[Part, ...]:
    """A 0.3 m bottle: body and neck (stands on whatever its pose puts it on)."""
    return (
        Part((0.04, 0.04, 0.1), (0.0, 0.0, 0.1), texture, None, Shape.CYLINDER),
        Part((0.015, 0.015, 0.05), (0.0, 0.0, 0.25), "fabric_dark", 0.1, Shape.CYLINDER),
    )


def wall_clock_parts(half_m: float = 0.15) -> tuple[Part, ...]:
    """A square wall clock, 6 cm deep, its dial facing +x; the frame's origin is its back centre on the wall."""
    return (Part((0.03, half_m, half_m), (0.03, 0.0, 0.0), "clock", None),)


def wall_tv_parts(screen: str = "rocket", half_w_m: float = 0.4) -> tuple[Part, ...]:
    """A flat screen hung on a wall (5 cm deep): bezel and picture facing +x, origin at its back centre."""
    half_h = 0.6 * half_w_m
    return (
        Part((0.025, half_w_m, half_h), (0.025, 0.0, 0.0), "fabric_dark", 0.2),
        Part((0.003, half_w_m - 0.02, half_h - 0.02), (0.052, 0.0, 0.0), screen, None),
    )
