"""Where the camera of a scenario looks: which places are seen, or in view, at each frame time.

The changing-room family uses it to place objects where the robot sees them and to time changes while their
places are out of view. A place is *seen* when its centre lies in the inner 80 % of the image between 0.3 and
4.5 m; it is *in view* when any corner of its box projects inside the image grown by 40 px, the test of
`scenarios.check_changes_out_of_view`. Checks use the family's 640x480 field of view at any render size.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.se3 import invert
from changing_slam_ros.sim.actors import Part
from changing_slam_ros.sim.renderer import intrinsics_for
from changing_slam_ros.sim.scenarios import DEFAULT_HEIGHT, DEFAULT_WIDTH
from changing_slam_ros.sim.track import Track

F64 = npt.NDArray[np.float64]
SEEN_DEPTH_M = (0.3, 4.5)
OUT_OF_VIEW_MARGIN_PX = 40.0  # as check_changes_out_of_view


class Item(Protocol):
    """Anything made of parts (an actor or a catalogue item)."""

    @property
    def parts(self) -> tuple[Part, ...]: ...


@dataclass(frozen=True)
class PathViews:
    """The camera at every frame time `times_s` (N,): T_cam_world (N, 4, 4)."""

    times_s: F64
    T_cam_world: F64

    @staticmethod
    def of(camera: Track, fps: float) -> "PathViews":
        """The views of `camera` at `fps` over its whole track."""
        n = int(np.floor(camera.end_s * fps + 1e-9))
        times = np.arange(n) / fps
        poses = []
        for t in times:
            T = camera.pose_at(float(t))
            assert T is not None
            poses.append(invert(T))
        return PathViews(times, np.array(poses))

    def project(self, pts_w: F64, fovy_deg: float) -> tuple[F64, F64]:
        """Pixels (N, P, 2) and depths (N, P) of world points (P, 3) in every frame."""
        cam = intrinsics_for(DEFAULT_WIDTH, DEFAULT_HEIGHT, fovy_deg)
        pc = np.einsum("nij,pj->npi", self.T_cam_world[:, :3, :3], pts_w) + self.T_cam_world[:, None, :3, 3]
        z = pc[..., 2]
        zs = np.where(z > 1e-3, z, 1e-3)
        uv = np.stack([cam.fx * pc[..., 0] / zs + cam.cx, cam.fy * pc[..., 1] / zs + cam.cy], axis=-1)
        return uv, z

    def seen(self, item: Item, pose: F64, fovy_deg: float) -> npt.NDArray[np.bool_]:
        """Frames where the item's box centre lies in the inner 80 % of the image within SEEN_DEPTH_M."""
        return self.seen_point(world_corners(item, pose).mean(axis=0), fovy_deg)

    def seen_point(self, p_w: F64, fovy_deg: float) -> npt.NDArray[np.bool_]:
        """Frames where the world point `p_w` (3,) lies in the inner 80 % of the image within SEEN_DEPTH_M."""
        uv, z = self.project(np.asarray(p_w, float)[None], fovy_deg)
        w, h = DEFAULT_WIDTH, DEFAULT_HEIGHT
        return ((z[:, 0] > SEEN_DEPTH_M[0]) & (z[:, 0] < SEEN_DEPTH_M[1]) & (uv[:, 0, 0] > 0.1 * w)
                & (uv[:, 0, 0] < 0.9 * w) & (uv[:, 0, 1] > 0.1 * h) & (uv[:, 0, 1] < 0.9 * h))

    def in_view(self, item: Item, pose: F64, fovy_deg: float) -> npt.NDArray[np.bool_]:
        """Frames where any corner of the item's box projects within the image grown by the margin (the test of
        `check_changes_out_of_view`)."""
        uv, z = self.project(world_corners(item, pose), fovy_deg)
        m = OUT_OF_VIEW_MARGIN_PX
        inside = ((z > 0.05) & (uv[..., 0] > -m) & (uv[..., 0] < DEFAULT_WIDTH + m) & (uv[..., 1] > -m)
                  & (uv[..., 1] < DEFAULT_HEIGHT + m))
        return np.asarray(inside.any(axis=1))


def world_corners(item: Item, pose: F64) -> F64:
    """The 8 corners (8, 3) of the item's box at `pose` (4, 4), in the world."""
    corners = np.concatenate([p.corners_m() for p in item.parts])
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    box = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    return np.asarray(box @ pose[:3, :3].T + pose[:3, 3])
