"""A tree of timestamped rigid transforms, as tf2 keeps it: each frame has one parent; a lookup composes the
transforms along the path between two frames at one stamp, interpolating each moving edge between the two
samples around that stamp (translation linearly, rotation by slerp). Static edges (a robot's URDF) hold at
every stamp. Lookups never extrapolate: a stamp past the newest sample of an edge raises `ExtrapolationError`
with `future=True` (waiting for the next sample may help), one before the oldest kept sample with `future=False`.

Naming follows the rest of the package: `T_a_b` maps points from frame b into frame a, so the transform stored
for the edge parent -> child is `T_parent_child` (a ROS TransformStamped with header.frame_id = parent).
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.se3 import invert, make_pose, quat_to_rot, rot_to_quat
from changing_slam_ros.errors import SlamError

F64 = npt.NDArray[np.float64]


class TransformError(SlamError):
    """No transform between two frames at a stamp: no path in the tree, or no sample near the stamp."""


class ExtrapolationError(TransformError):
    """The stamp lies outside the samples of an edge on the path; `future`: past the newest one."""

    def __init__(self, message: str, future: bool) -> None:
        super().__init__(message)
        self.future = future


def slerp_xyzw(q0: F64, q1: F64, alpha: float) -> F64:
    """Spherical interpolation between unit quaternions (x, y, z, w) at `alpha` in [0, 1], the shorter way."""
    a, b = np.asarray(q0, np.float64), np.asarray(q1, np.float64)
    dot = float(a @ b)
    if dot < 0.0:
        b, dot = -b, -dot
    if dot > 0.9995:  # nearly equal: linear interpolation is exact to double precision and avoids 0/0
        q = a + alpha * (b - a)
        return q / np.linalg.norm(q)
    theta = np.arccos(dot)
    return (np.sin((1.0 - alpha) * theta) * a + np.sin(alpha * theta) * b) / np.sin(theta)


def interpolate_pose(T_a: F64, T_b: F64, alpha: float) -> F64:  # noqa: N803
    """The rigid transform `alpha` of the way from `T_a` (alpha 0) to `T_b` (alpha 1): translation linear,
    rotation by slerp (tf2's interpolation)."""
    t = (1.0 - alpha) * T_a[:3, 3] + alpha * T_b[:3, 3]
    q = slerp_xyzw(rot_to_quat(T_a[:3, :3]), rot_to_quat(T_b[:3, :3]), alpha)
    return make_pose(quat_to_rot(q), t)


@dataclass
class _Edge:
    """The transforms parent -> child: one for a static edge, time-sorted samples for a moving one."""

    parent: str
    static: bool
    stamps_ns: list[int] = field(default_factory=list)
    poses: list[F64] = field(default_factory=list)

    def at(self, child: str, stamp_ns: int) -> F64:
        """T_parent_child at `stamp_ns` (0: the newest sample)."""
        if self.static or stamp_ns == 0:
            return self.poses[-1]
        i = bisect.bisect_left(self.stamps_ns, stamp_ns)
        if i < len(self.stamps_ns) and self.stamps_ns[i] == stamp_ns:
            return self.poses[i]
        if i == len(self.stamps_ns):
            raise ExtrapolationError(
                f"{self.parent} -> {child}: asked at {stamp_ns * 1e-9:.3f} s, newest sample "
                f"{self.stamps_ns[-1] * 1e-9:.3f} s ({(stamp_ns - self.stamps_ns[-1]) * 1e-6:.1f} ms later)", future=True)
        if i == 0:
            raise ExtrapolationError(
                f"{self.parent} -> {child}: asked at {stamp_ns * 1e-9:.3f} s, oldest kept sample "
                f"{self.stamps_ns[0] * 1e-9:.3f} s", future=False)
        t0, t1 = self.stamps_ns[i - 1], self.stamps_ns[i]
        return interpolate_pose(self.poses[i - 1], self.poses[i], (stamp_ns - t0) / (t1 - t0))


class TransformTree:
    """Frames and their parents, with `cache_s` seconds of samples kept per moving edge (counted back from the
    edge's newest sample). `parent_changes` lists (child, old parent, new parent) each time a frame was given a
    second parent: in REP-105 every frame has exactly one, so the node warns about each."""

    def __init__(self, cache_s: float = 10.0) -> None:
        self.cache_ns = round(cache_s * 1e9)
        self._edges: dict[str, _Edge] = {}
        self.parent_changes: list[tuple[str, str, str]] = []

    def set_transform(self, parent: str, child: str, stamp_ns: int, T_parent_child: F64,  # noqa: N803
                      static: bool = False) -> None:  # fmt: skip
        """Add one sample of the edge parent -> child (a static one replaces the edge's transform)."""
        if parent == child:
            raise TransformError(f"transform {parent} -> {child}: a frame cannot be its own parent")
        T = np.asarray(T_parent_child, np.float64)  # noqa: N806
        edge = self._edges.get(child)
        if edge is None or edge.parent != parent or edge.static != static:
            if edge is not None and edge.parent != parent:
                self.parent_changes.append((child, edge.parent, parent))
            edge = self._edges[child] = _Edge(parent, static)
        if static:
            edge.stamps_ns, edge.poses = [stamp_ns], [T]
            return
        i = bisect.bisect_left(edge.stamps_ns, stamp_ns)
        if i < len(edge.stamps_ns) and edge.stamps_ns[i] == stamp_ns:
            edge.poses[i] = T
        else:
            edge.stamps_ns.insert(i, stamp_ns)
            edge.poses.insert(i, T)
        cut = bisect.bisect_left(edge.stamps_ns, edge.stamps_ns[-1] - self.cache_ns)
        if cut:
            del edge.stamps_ns[:cut], edge.poses[:cut]

    def parent(self, frame: str) -> str | None:
        edge = self._edges.get(frame)
        return None if edge is None else edge.parent

    def frames(self) -> set[str]:
        return set(self._edges) | {e.parent for e in self._edges.values()}

    def _chain(self, frame: str) -> list[str]:
        """`frame`, its parent, the parent's parent, ... up to the root."""
        chain = [frame]
        while (p := self.parent(chain[-1])) is not None:
            if p in chain:
                raise TransformError(f"frames {' -> '.join(chain + [p])} form a cycle")
            chain.append(p)
        return chain

    def lookup(self, target: str, source: str, stamp_ns: int) -> F64:
        """T_target_source at `stamp_ns` (0: each edge's newest sample): maps points in `source` into `target`.
        Raises `TransformError` when the frames are not connected, `ExtrapolationError` when an edge on the path
        has no samples around the stamp."""
        if target == source:
            return np.eye(4)
        up_source, up_target = self._chain(source), self._chain(target)
        common = next((f for f in up_source if f in set(up_target)), None)
        if common is None:
            known = "" if self.frames() & {source, target} else " (neither frame has been received)"
            raise TransformError(f"no transform between {target} and {source}: their trees have roots "
                                 f"{up_target[-1]} and {up_source[-1]}{known}")  # fmt: skip
        return invert(self._to_ancestor(target, common, stamp_ns)) @ self._to_ancestor(source, common, stamp_ns)

    def _to_ancestor(self, frame: str, ancestor: str, stamp_ns: int) -> F64:
        """T_ancestor_frame: the edges from `frame` up to `ancestor` composed at `stamp_ns`."""
        T = np.eye(4)  # noqa: N806
        while frame != ancestor:
            edge = self._edges[frame]
            T = edge.at(frame, stamp_ns) @ T  # noqa: N806
            frame = edge.parent
        return T
