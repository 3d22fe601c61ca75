"""The metric map: keyframes, map points, covisibility graph and spanning tree; and the Atlas of maps.

Keyframes are `core.keyframe.Keyframe` records; `Keyframe.point_ids[i]` is the map point seen at
keypoint i (or -1) and `PointStore.observations[pid]` is the reverse index. Both are kept in step by
`add_observation` / `erase_observation` only.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.map.map_point import PointStore
from changing_slam_ros.core.geometry.se3 import invert

F64 = npt.NDArray[np.float64]


@dataclass
class RemovedKeyframe:
    """A culled keyframe, kept so frames anchored on it still get a final pose: T_world_kf = T_world_parent @ T_parent_kf."""

    parent_id: int
    T_parent_kf: F64


@dataclass
class SlamMap:
    """One map of the Atlas."""

    id: int
    keyframes: dict[int, Keyframe] = field(default_factory=dict)
    points: PointStore = field(default_factory=PointStore)
    covisibility: dict[int, dict[int, int]] = field(default_factory=dict)
    parent: dict[int, int] = field(default_factory=dict)
    children: dict[int, set[int]] = field(default_factory=dict)
    removed: dict[int, RemovedKeyframe] = field(default_factory=dict)
    loop_edges: dict[int, set[int]] = field(default_factory=dict)
    origin_kf_id: int = -1

    # 1. Keyframes ---------------------------------------------------------------------------------
    def add_keyframe(self, kf: Keyframe) -> None:
        """Insert a keyframe; its existing `point_ids` become observations."""
        kf.map_id = self.id
        self.keyframes[kf.id] = kf
        self.covisibility[kf.id] = {}
        self.children[kf.id] = set()
        if self.origin_kf_id < 0:
            self.origin_kf_id = kf.id
        idx = np.flatnonzero(kf.point_ids >= 0)
        obs = self.points.observations
        for i, pid in zip(idx.tolist(), kf.point_ids[idx].tolist()):
            obs[pid][kf.id] = i

    def remove_keyframe(self, kf_id: int) -> bool:
        """Cull a keyframe: erase its observations, re-attach its children to its parent.

        Returns False (and keeps it) for the map origin or a keyframe with nothing to attach to.
        """
        kf = self.keyframes[kf_id]
        par = self.parent.get(kf_id, -1)
        if par < 0 or par not in self.keyframes:
            par = self._best_covisible(kf_id, exclude=kf_id)
        if par < 0 or kf_id == self.origin_kf_id:
            return False
        for i in np.flatnonzero(kf.point_ids >= 0).tolist():
            self.erase_observation(kf_id, i)
        for other in list(self.covisibility.get(kf_id, {})):
            self.covisibility.get(other, {}).pop(kf_id, None)
        self.covisibility.pop(kf_id, None)
        grand = self.parent.get(kf_id, -1)
        for child in self.children.pop(kf_id, set()):
            if child == par:  # the new parent was a child: it inherits the grandparent
                if grand >= 0 and grand in self.keyframes:
                    self.parent[par] = grand
                    self.children.setdefault(grand, set()).add(par)
                else:
                    self.parent.pop(par, None)
                continue
            self.parent[child] = par
            self.children.setdefault(par, set()).add(child)
        self.children.get(par, set()).discard(kf_id)
        self.removed[kf_id] = RemovedKeyframe(par, invert(self.keyframes[par].T_world_cam) @ kf.T_world_cam)
        self.parent.pop(kf_id, None)
        del self.keyframes[kf_id]
        return True

    def pose_of(self, kf_id: int) -> F64:
        """Camera-to-world (4, 4) of a keyframe, following parents for culled keyframes."""
        chain = np.eye(4)
        while kf_id not in self.keyframes:
            rem = self.removed[kf_id]
            chain = rem.T_parent_kf @ chain
            kf_id = rem.parent_id
        return self.keyframes[kf_id].T_world_cam @ chain

    # 2. Observations ------------------------------------------------------------------------------
    def add_observation(self, pid: int, kf_id: int, kp_index: int) -> None:
        self.points.observations[pid][kf_id] = kp_index
        self.keyframes[kf_id].point_ids[kp_index] = pid

    def erase_observation(self, kf_id: int, kp_index: int) -> None:
        kf = self.keyframes[kf_id]
        pid = int(kf.point_ids[kp_index])
        if pid < 0:
            return
        kf.point_ids[kp_index] = -1
        obs = self.points.observations[pid]
        obs.pop(kf_id, None)
        if len(obs) == 0:
            self.points.set_bad(np.array([pid]))
        elif self.points.ref_kf[pid] == kf_id:
            self.points.ref_kf[pid] = next(iter(obs))

    def erase_point(self, pid: int) -> None:
        for kf_id, i in list(self.points.observations[pid].items()):
            if kf_id in self.keyframes:
                self.keyframes[kf_id].point_ids[i] = -1
        self.points.observations[pid] = {}
        self.points.set_bad(np.array([pid]))

    # 3. Covisibility graph and spanning tree ------------------------------------------------------
    def update_connections(self, kf_id: int, min_shared: int = 15) -> None:
        """Recount shared points of `kf_id` with every keyframe; link when >= min_shared (or the best one)."""
        kf = self.keyframes[kf_id]
        counts: Counter[int] = Counter()
        obs = self.points.observations
        bad = self.points.bad
        for pid in kf.point_ids[kf.point_ids >= 0].tolist():
            if bad[pid]:
                continue
            counts.update(obs[pid].keys())
        counts.pop(kf_id, None)
        if not counts:
            return
        links = {k: w for k, w in counts.items() if w >= min_shared and k in self.keyframes}
        if not links:
            best = max((k for k in counts if k in self.keyframes), key=lambda k: counts[k], default=-1)
            if best < 0:
                return
            links = {best: counts[best]}
        for other in list(self.covisibility[kf_id]):
            if other not in links:
                self.covisibility.get(other, {}).pop(kf_id, None)
        self.covisibility[kf_id] = links
        for other, w in links.items():
            self.covisibility[other][kf_id] = w
        if kf_id not in self.parent and kf_id != self.origin_kf_id:
            best = max(links, key=lambda k: links[k])
            self.parent[kf_id] = best
            self.children.setdefault(best, set()).add(kf_id)

    def covisible(self, kf_id: int, n: int | None = None, min_weight: int = 0) -> list[int]:
        """Keyframes sharing points with `kf_id`, most shared first."""
        links = self.covisibility.get(kf_id, {})
        ranked = sorted((k for k, w in links.items() if w >= min_weight), key=lambda k: -links[k])
        return ranked if n is None else ranked[:n]

    def _best_covisible(self, kf_id: int, exclude: int) -> int:
        ranked = [k for k in self.covisible(kf_id) if k != exclude]
        return ranked[0] if ranked else -1

    # 4. Queries -----------------------------------------------------------------------------------
    def order_spanning_tree(self) -> None:
        """The spanning tree's entries in keyframe order, then any others as they were (after a map merge: the
        order the pose graph adds its factors in, the same offline and in the split graph's replicas)."""
        parent = {k: self.parent[k] for k in self.keyframes if k in self.parent}
        parent.update((k, v) for k, v in self.parent.items() if k not in parent)
        self.parent = parent

    def local_point_ids(self, kf_ids: list[int]) -> npt.NDArray[np.int64]:
        """Usable map points seen by any of `kf_ids`, unique, sorted."""
        arrays = [self.keyframes[k].point_ids for k in kf_ids if k in self.keyframes]
        if not arrays:
            return np.zeros(0, np.int64)
        ids = np.concatenate(arrays)
        seen = np.zeros(self.points.size, dtype=bool)  # a mark per point: unique and sorted without a sort
        seen[ids[ids >= 0]] = True
        return np.flatnonzero(seen & self.points.usable()).astype(np.int64, copy=False)

    def n_tracked_points(self, kf_id: int, min_obs: int = 1) -> int:
        """Usable points of a keyframe that at least `min_obs` keyframes observe."""
        ids = self.keyframes[kf_id].point_ids
        ids = ids[ids >= 0]
        ids = ids[self.points.usable()[ids]]
        if min_obs <= 1:
            return len(ids)
        return int((self.points.n_obs(ids) >= min_obs).sum())


class Atlas:
    """Several disconnected maps (ORB-SLAM3's Atlas): a new one starts when relocalisation keeps failing;
    two maps that see a common place are merged (`core.map_merging`), leaving the merged-away one empty."""

    def __init__(self) -> None:
        self.maps: list[SlamMap] = [SlamMap(0)]
        self.current: SlamMap = self.maps[0]
        self.merged_into: dict[int, int] = {}  # map id -> the map it was merged into (`core.map_merging`)

    def adopt(self, other: Atlas) -> None:
        """Take over `other`'s maps, current map and merge records (multi-session: a loaded Atlas becomes this one,
        so that everything holding a reference to this Atlas sees the loaded maps)."""
        self.maps = other.maps
        self.current = other.current
        self.merged_into = dict(other.merged_into)

    def new_map(self) -> SlamMap:
        m = SlamMap(len(self.maps))
        self.maps.append(m)
        self.current = m
        return m

    def resolve(self, map_id: int) -> SlamMap:
        """The map that now holds what map `map_id` held (itself, unless it was merged away)."""
        while map_id in self.merged_into:
            map_id = self.merged_into[map_id]
        return self.maps[map_id]

    def live_maps(self) -> list[SlamMap]:
        """Maps holding at least one keyframe."""
        return [m for m in self.maps if m.keyframes]

    def map_of_keyframe(self, kf_id: int) -> SlamMap | None:
        for m in self.maps:
            if kf_id in m.keyframes or kf_id in m.removed:
                return m
        return None

    @property
    def n_keyframes(self) -> int:
        return sum(len(m.keyframes) for m in self.maps)
