"""What was in flight when the map owner merged two maps of the Atlas (split graph, real time).

In real time tracking does not wait for the owner: when the owner applies a merge of map A into map B
(`core.map_merging.merge_maps`: A's keyframes moved by `T_into_from`, A's point ids shifted by
`point_id_offset`, A left empty), keyframes that tracking made in A are still on their way or queued:

- the owner gets packets that name map A after the merge: `move_packet` expresses them in B (pose, point ids,
  map id, tracking's counter increments, the dynamic stage's objects) before they are mapped;
- the replicas (tracking, loop closing) hold keyframes of A they inserted but whose update has not come yet:
  `move_keyframe` expresses each in B, and the replica inserts it into the merged map again, so that the
  owner's later update for it applies there;
- tracking's counter increments in A since its last packet: `move_counters`.

A point id i of A is `i + point_id_offset` in B (see `MergeLog`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.dynamic.dynamic_objects import ObjectState
from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.replication.map_replication import KeyframePacket, PointCounters

F64 = npt.NDArray[np.float64]


class MergeMove(Protocol):
    """What a merge did to map ids, poses and point ids (`core.map_merging.MergeResult` has these)."""

    from_map_id: int
    into_map_id: int
    T_into_from: F64
    point_id_offset: int


def move_keyframe(kf: Keyframe, merge: MergeMove) -> None:
    """A keyframe of the merged-away map, in place: pose `T_into_from @ T_world_cam`, point ids >= 0 shifted
    by the offset, map id the merged one."""
    kf.T_world_cam = np.asarray(merge.T_into_from, np.float64) @ kf.T_world_cam
    seen = kf.point_ids >= 0
    kf.point_ids[seen] += merge.point_id_offset
    kf.map_id = merge.into_map_id


def move_counters(counters: PointCounters, merge: MergeMove) -> PointCounters:
    """Counter increments on points of the merged-away map, named by their ids in the merged map."""
    return dataclasses.replace(counters, ids=counters.ids + merge.point_id_offset)


def combine_counters(a: PointCounters, b: PointCounters) -> PointCounters:
    """Increments of `a` and `b` as one set (ids sorted, unique): visible / found added, last seen the later."""
    ids = np.concatenate([a.ids, b.ids])
    if len(ids) == 0:
        return PointCounters()
    out, inv = np.unique(ids, return_inverse=True)
    vis = np.zeros(len(out), np.int64)
    found = np.zeros(len(out), np.int64)
    seen = np.full(len(out), np.iinfo(np.int64).min, np.int64)
    np.add.at(vis, inv, np.concatenate([a.n_visible, b.n_visible]))
    np.add.at(found, inv, np.concatenate([a.n_found, b.n_found]))
    np.maximum.at(seen, inv, np.concatenate([a.last_seen_frame, b.last_seen_frame]))
    return PointCounters(out.astype(np.int64), vis, found, seen)


def move_object(state: ObjectState, merge: MergeMove) -> ObjectState:
    """A short-term object of the dynamic stage, from the merged-away map's world frame into the merged one:
    position, velocity and their covariance ([x y z vx vy vz]) rotated (and the position moved)."""
    T = np.asarray(merge.T_into_from, np.float64)
    R = T[:3, :3]
    J = np.zeros((6, 6))
    J[:3, :3] = R
    J[3:, 3:] = R
    return dataclasses.replace(
        state, position_world=R @ np.asarray(state.position_world, np.float64) + T[:3, 3],
        velocity_world=R @ np.asarray(state.velocity_world, np.float64),
        covariance=J @ np.asarray(state.covariance, np.float64) @ J.T,
    )  # fmt: skip


def move_packet(packet: KeyframePacket, merge: MergeMove) -> bool:
    """A keyframe packet made before `merge`, in place: its keyframe (and objects) moved when it names the
    merged-away map, its counter increments of that map renamed and filed under the merged one (with the
    keyframe's own when the keyframe is now there). Returns whether the keyframe moved."""
    moved = packet.keyframe.map_id == merge.from_map_id
    if moved:
        move_keyframe(packet.keyframe, merge)
        packet.counters = move_counters(packet.counters, merge)
        packet.objects = tuple(move_object(s, merge) for s in packet.objects)
    else:
        c = packet.other_counters.pop(merge.from_map_id, None)
        if c is not None:
            packet.other_counters[merge.into_map_id] = combine_counters(
                packet.other_counters.get(merge.into_map_id, PointCounters()), move_counters(c, merge))
    if packet.keyframe.map_id in packet.other_counters:  # its own map's increments go with `counters`
        packet.counters = combine_counters(packet.counters, packet.other_counters.pop(packet.keyframe.map_id))
    return moved


@dataclass
class MergeLog:
    """The merges a side took, by merged-away map id, to express late packets in the map they went into.

    The owner allocates every point id and A gets no new point after the merge (it is empty), so every id a
    packet of A can name has a row in B. Points the merge fused are bad rows in B; a late keyframe naming one is
    treated as a keyframe naming a point culled while it was in flight (local mapping skips bad points). Several
    merges (A into B, later B into C) apply one after the other (`resolve`)."""

    by_from: dict[int, Any] = field(default_factory=dict)  # from_map_id -> MergeMove
    n_moved: int = 0  # packets whose keyframe was moved

    def record(self, merge: MergeMove) -> None:
        self.by_from[merge.from_map_id] = merge

    def resolve(self, packet: KeyframePacket) -> bool:
        """Move `packet` through every merge it predates (A into B, then B into C...); whether its keyframe
        moved. Counters filed under merged-away maps are moved too."""
        moved = False
        for _ in range(len(self.by_from) + 1):
            todo = [m for m in self.by_from if m == packet.keyframe.map_id or m in packet.other_counters]
            if not todo:
                break
            for map_id in sorted(todo):
                moved |= move_packet(packet, self.by_from[map_id])
        self.n_moved += int(moved)
        return moved
