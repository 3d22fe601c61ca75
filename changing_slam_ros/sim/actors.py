"""Actors: people and COCO-class objects built from textured boxes and cylinders, each on its own track.

An actor's frame has z up, origin at the centre of its footprint on the floor, front facing +x. Parts are
given in that frame. Class ids are COCO 0-based (the 80-class list: person 0, suitcase 28, cup 41,
chair 56, potted plant 58, dining table 60, tv 62, teddy bear 77); -1 marks an object of no COCO class.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.detector import COCO80_NAMES
from changing_slam_ros.sim.track import Track

F64 = npt.NDArray[np.float64]

UNKNOWN_CLASS_ID = -1


def coco_name(class_id: int) -> str:
    """Name of a 0-based COCO class id; "unknown" for -1."""
    return COCO80_NAMES[class_id] if 0 <= class_id < len(COCO80_NAMES) else "unknown"


class Shape(Enum):
    BOX = "box"
    CYLINDER = "cylinder"  # axis along z; radius = half_size_m[0]


@dataclass(frozen=True)
class Part:
    """One textured solid. `half_size_m` (x, y, z) half extents; `offset_m` its centre in the parent frame.

    `tile_m`: metres per texture repeat (tiled surfaces); None stretches the texture once over each face.
    """

    half_size_m: tuple[float, float, float]
    offset_m: tuple[float, float, float]
    texture: str
    tile_m: float | None = None
    shape: Shape = Shape.BOX

    def corners_m(self) -> F64:
        """The 8 corners (8, 3) of the part's bounding box, in the parent frame."""
        h = np.asarray(self.half_size_m)
        if self.shape is Shape.CYLINDER:
            h = np.array([h[0], h[0], h[2]])
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)
        return np.asarray(self.offset_m) + signs * h


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

def person_parts(photo: str = "astronaut") -> tuple[Part, ...]:
    """A standing person, 1.74 m: legs, hips, arms, and a torso whose front and back show a photo of a
    person (head and shoulders); seen from the side it is a dark silhouette."""
    suit = "suit_orange" if photo == "astronaut" else "fabric_dark"
    return (
        Part((0.08, 0.08, 0.42), (0.0, -0.09, 0.42), "fabric_dark", 0.25, Shape.CYLINDER),
        Part((0.08, 0.08, 0.42), (0.0, 0.09, 0.42), "fabric_dark", 0.25, Shape.CYLINDER),
        Part((0.1, 0.19, 0.14), (0.0, 0.0, 0.98), "fabric_dark", 0.25),
        Part((0.05, 0.05, 0.3), (0.0, -0.25, 1.1), suit, 0.25, Shape.CYLINDER),
        Part((0.05, 0.05, 0.3), (0.0, 0.25, 1.1), suit, 0.25, Shape.CYLINDER),
        Part((0.1, 0.2, 0.31), (0.0, 0.0, 1.43), suit, 0.25),
        Part((0.004, 0.26, 0.31), (0.104, 0.0, 1.43), photo, None),
        Part((0.004, 0.26, 0.31), (-0.104, 0.0, 1.43), photo, None),
    )


def sitting_person_parts(photo: str = "astronaut") -> tuple[Part, ...]:
    """A person sitting (on a chair placed by the scenario), 1.3 m tall: thighs forward, upper body photo."""
    return (
        Part((0.06, 0.06, 0.23), (0.24, -0.09, 0.23), "fabric_dark", 0.25, Shape.CYLINDER),
        Part((0.06, 0.06, 0.23), (0.24, 0.09, 0.23), "fabric_dark", 0.25, Shape.CYLINDER),
        Part((0.18, 0.18, 0.06), (0.1, 0.0, 0.52), "fabric_dark", 0.25),
        Part((0.11, 0.26, 0.33), (-0.02, 0.0, 0.92), photo, None),
    )


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
