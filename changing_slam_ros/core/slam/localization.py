"""Localisation-only mode: track a mapped room without changing its map, and report which of its objects are
seen where they were mapped.

In `Mode.LOCALIZATION` the system (`core/system.py`) reads the map and never writes it: tracking makes no
keyframes, starts no new map and leaves the points' statistics alone; a lost frame only tries relocalisation;
local mapping, the object layer, loop closing and map merging do not run. The object beliefs are therefore not
updated either (they change only with keyframes, Algorithm 1's observations); instead `Sightings` checks, per
tracked frame, each MapObject's points against the frame's depth: where they project into the image, does the
camera measure a surface at their predicted depth (present at its mapped place), or see past them (missing)?
"""

from __future__ import annotations

import enum
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.geometry.se3 import invert, transform_points
from changing_slam_ros.core.objects.map_object import MapObject
from changing_slam_ros.errors import ConfigError

F64 = npt.NDArray[np.float64]


class Mode(enum.Enum):
    """`mapping`: SLAM (the map grows and is corrected); `localization`: tracking in a fixed map."""

    MAPPING = "mapping"
    LOCALIZATION = "localization"

    @classmethod
    def parse(cls, text: str) -> Mode:
        try:
            return cls(text)
        except ValueError as err:
            raise ConfigError(f"mode '{text}' unknown; expected mapping or localization") from err


@dataclass
class ObjectSighting:
    """One MapObject as the localisation frames saw it: in `frames_in_view` frames enough of its points were in
    the image with a depth reading; in `frames_present` the surface was where the points are (the object is at
    its mapped place), in `frames_missing` the camera saw past them (something farther: it is gone or moved)."""

    object_id: int
    class_id: int
    centroid_w: tuple[float, float, float]
    n_points: int
    frames_in_view: int = 0
    frames_present: int = 0
    frames_missing: int = 0
    last_present_stamp_ns: int = 0

    def as_dict(self) -> dict[str, object]:
        return {"id": self.object_id, "class_id": self.class_id, "centroid_w": list(self.centroid_w),
                "n_points": self.n_points, "frames_in_view": self.frames_in_view,
                "frames_present": self.frames_present, "frames_missing": self.frames_missing,
                "last_present_stamp_ns": self.last_present_stamp_ns}  # fmt: skip


@dataclass(frozen=True)
class SightingConfig:
    """`min_points`: an object counts as in view with this many of its points projecting into the image with a
    depth reading; a point agrees when the measured depth is within `tolerance_m` + `tolerance_rel` * depth of
    its predicted depth and is passed when the measurement is farther; `fraction`: share of the points in view
    that must agree (present) or be passed (missing) for a verdict (else occluded or unclear: none)."""

    min_points: int = 10
    tolerance_m: float = 0.05
    tolerance_rel: float = 0.03
    fraction: float = 0.5


class Sightings:
    """Per tracked frame, which mapped objects are present at their mapped place, by their points' depth."""

    def __init__(self, config: SightingConfig | None = None) -> None:
        self.config = config or SightingConfig()
        self.by_object: dict[int, ObjectSighting] = {}

    def update(self, stamp_ns: int, T_world_cam: F64, camera: CameraIntrinsics,  # noqa: N803
               depth_m: npt.NDArray[np.floating], objects: Iterable[MapObject]) -> list[int]:  # fmt: skip
        """Record one frame (pose T_world_cam (4, 4), depth (H, W) metres with 0 = none); returns the ids of the
        objects present in it, ascending."""
        cfg = self.config
        T_cam_world = invert(np.asarray(T_world_cam, np.float64))  # noqa: N806
        present = []
        for obj in sorted(objects, key=lambda o: o.id):
            if obj.n_points < cfg.min_points:
                continue
            p = transform_points(T_cam_world, obj.points_w)
            z = p[:, 2]
            front = z > 0.1
            u = np.full(len(p), -1.0)
            v = np.full(len(p), -1.0)
            u[front] = camera.fx * p[front, 0] / z[front] + camera.cx
            v[front] = camera.fy * p[front, 1] / z[front] + camera.cy
            ui, vi = np.round(u).astype(np.int64), np.round(v).astype(np.int64)
            inside = front & (ui >= 0) & (ui < depth_m.shape[1]) & (vi >= 0) & (vi < depth_m.shape[0])
            measured = np.zeros(len(p))
            measured[inside] = depth_m[vi[inside], ui[inside]]
            in_view = inside & (measured > 0)
            n = int(in_view.sum())
            if n < cfg.min_points:
                continue
            tol = cfg.tolerance_m + cfg.tolerance_rel * z[in_view]
            diff = measured[in_view] - z[in_view]
            s = self.by_object.get(obj.id)
            if s is None:
                c = obj.centroid_w
                s = self.by_object[obj.id] = ObjectSighting(obj.id, obj.class_id, (float(c[0]), float(c[1]), float(c[2])),
                                                            obj.n_points)  # fmt: skip
            s.frames_in_view += 1
            if float((np.abs(diff) <= tol).mean()) >= cfg.fraction:
                s.frames_present += 1
                s.last_present_stamp_ns = stamp_ns
                present.append(obj.id)
            elif float((diff > tol).mean()) >= cfg.fraction:
                s.frames_missing += 1
        return present
