"""Ground truth from a TF tree: pose of a camera frame in a world frame over time.

TUM RGB-D bags carry the motion-capture pose as `/world -> /kinect` on `/tf` (100 Hz) plus constant
transforms `/kinect -> /openni_camera -> /openni_rgb_frame -> /openni_rgb_optical_frame` republished
on `/tf` (ROS 2 bags put such constants on `/tf_static`). The pose of the rgb optical frame in the
world, which is what TUM's groundtruth.txt lists, is the product along that chain. Exactly one edge
of the chain may move; its stamps become the ground-truth stamps.

Frame names are compared without a leading '/', so ROS 1 (`/world`) and ROS 2 (`world`) names match.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from changing_slam_ros.errors import BagError
from changing_slam_ros.io.groundtruth import GroundTruth, pose_matrix

F64 = npt.NDArray[np.float64]


def frame_name(name: str) -> str:
    return name.lstrip("/")


@dataclass
class TfEdge:
    """Samples of T_parent_child (pose of child in parent), each (stamp_ns, (4, 4))."""

    parent: str
    child: str
    stamps_ns: list[int] = field(default_factory=list)
    transforms: list[F64] = field(default_factory=list)
    from_static_topic: bool = False

    def is_constant(self, tol: float = 1e-9) -> bool:
        if self.from_static_topic or len(self.transforms) <= 1:
            return True
        first = self.transforms[0]
        return all(np.abs(t - first).max() <= tol for t in self.transforms[1:])


@dataclass
class TfBuffer:
    """All transforms of a bag, keyed by child frame (a TF tree gives each child one parent)."""

    source: str
    edges: dict[str, TfEdge] = field(default_factory=dict)

    def add(self, parent: str, child: str, stamp_ns: int, T_parent_child: F64, static: bool = False) -> None:
        parent, child = frame_name(parent), frame_name(child)
        edge = self.edges.get(child)
        if edge is None:
            edge = self.edges[child] = TfEdge(parent, child, from_static_topic=static)
        elif edge.parent != parent:
            raise BagError(
                f"{self.source}: frame '{child}' has two parents in TF ('{edge.parent}' and '{parent}')"
            )
        edge.stamps_ns.append(int(stamp_ns))
        edge.transforms.append(np.asarray(T_parent_child, dtype=np.float64))

    def frames(self) -> list[str]:
        return sorted({e.parent for e in self.edges.values()} | set(self.edges))

    def chain(self, world: str, camera: str) -> list[TfEdge]:
        """Edges from `world` down to `camera`, in that order."""
        world, camera = frame_name(world), frame_name(camera)
        path: list[TfEdge] = []
        node = camera
        seen = {node}
        while node != world:
            edge = self.edges.get(node)
            if edge is None:
                raise BagError(
                    f"{self.source}: no TF chain from '{world}' to '{camera}' (stuck at '{node}'); "
                    f"frames in the bag: {', '.join(self.frames()) or 'none'}; "
                    "set dataset.gt_world_frame / gt_camera_frame"
                )
            path.append(edge)
            node = edge.parent
            if node in seen:
                raise BagError(f"{self.source}: TF has a cycle through '{node}'")
            seen.add(node)
        return path[::-1]

    def groundtruth(self, world: str, camera: str) -> GroundTruth:
        """T_world_camera at the stamps of the one moving edge of the chain."""
        chain = self.chain(world, camera)
        if not chain:
            raise BagError(f"{self.source}: ground-truth world and camera frame are both '{frame_name(world)}'")
        moving = [e for e in chain if not e.is_constant()]
        if len(moving) > 1:
            names = ", ".join(f"{e.parent}->{e.child}" for e in moving)
            raise BagError(
                f"{self.source}: TF chain {frame_name(world)}->{frame_name(camera)} has {len(moving)} moving "
                f"transforms ({names}); expected exactly one (the motion-capture pose)"
            )
        driver = moving[0] if moving else chain[0]
        i = chain.index(driver)
        before = np.eye(4)
        for e in chain[:i]:
            before = before @ e.transforms[0]
        after = np.eye(4)
        for e in chain[i + 1 :]:
            after = after @ e.transforms[0]
        poses = [before @ T @ after for T in driver.transforms]
        stamps = list(driver.stamps_ns)
        # keep one pose per stamp (a transform can be republished with the same stamp)
        uniq: dict[int, F64] = {}
        for s, p in zip(stamps, poses):
            uniq.setdefault(s, p)
        return GroundTruth.from_poses(list(uniq), list(uniq.values()))


def transform_matrix(translation: tuple[float, float, float], rotation_xyzw: tuple[float, float, float, float]) -> F64:
    """geometry_msgs/Transform values -> 4x4 (quaternion normalised)."""
    q = np.asarray(rotation_xyzw, dtype=np.float64)
    n = float(np.linalg.norm(q))
    if not np.isfinite(n) or n < 1e-9:
        raise ValueError("zero or non-finite quaternion")
    return pose_matrix(np.asarray(translation, dtype=np.float64), q / n)
