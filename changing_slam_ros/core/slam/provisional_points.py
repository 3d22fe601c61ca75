"""Provisional map points: tracking's own depth points for keyframes the map owner has not mapped yet.

In the split graph tracking holds a replica of the map and the map owner (local mapping) creates every map
point, so a new keyframe's points reach the replica only once the owner's MapUpdate has come back: in real
time hundreds of milliseconds to seconds later, and right after a new map is started tracking has nothing to
track against. ORB-SLAM's RGB-D tracking does not wait for this (`Tracking::CreateNewKeyFrame` back-projects
the new keyframe's close keypoints itself); this module does the same on the replica. `create` makes them with
`LocalMapper._create_points`'s rule (so the owner later makes a point from exactly these keypoints) as rows
past the owner's store size; `strip` and `reattach` take them out around an owner delta and put them back or
replace them by the owner's points; `packet_ids` keeps their ids out of keyframe packets.

Nothing here runs when the caller waits for every update before the next frame (lossless graph): then the
owner's points are always in before tracking needs them.
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.map.map_point import PointStore
from changing_slam_ros.core.geometry.se3 import transform_points
from changing_slam_ros.core.map.slam_map import SlamMap

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


@dataclass
class HeldRows:
    """Provisional rows taken out of map `map_id` by `strip`: old ids `first`..`first + len - 1`, every column
    (`columns`, by `PointStore.COLUMNS` name), observations, and the keyframe entries that named them
    (`ref_kf_ids`, `ref_kp_indices`, `ref_rows`: row index into this block)."""

    map_id: int
    first: int
    columns: dict[str, npt.NDArray[np.generic]]
    observations: list[dict[int, int]]
    ref_kf_ids: I64
    ref_kp_indices: I64
    ref_rows: I64

    def __len__(self) -> int:
        return len(self.observations)

    def creators(self) -> I64:
        """(R,) the keyframe that created each row."""
        return np.asarray(self.columns["first_kf"], np.int64)

    def moved(self, T_into_from: F64, into_map_id: int) -> HeldRows:
        """The same rows expressed in another map's world frame (a map merge: positions moved, viewing
        directions rotated by `T_into_from` (4, 4); the other columns do not depend on the frame)."""
        T = np.asarray(T_into_from, np.float64)
        cols = dict(self.columns)
        cols["positions"] = np.asarray(self.columns["positions"], np.float64) @ T[:3, :3].T + T[:3, 3]
        cols["normals"] = np.asarray(self.columns["normals"], np.float64) @ T[:3, :3].T
        return dataclasses.replace(self, map_id=into_map_id, columns=cols)

    @staticmethod
    def join(a: HeldRows | None, b: HeldRows | None) -> HeldRows | None:
        """Rows of `a`, then those of `b`, as one block (of `a`'s map and first id; `b`'s rows follow)."""
        if a is None or b is None:
            return a if b is None else b
        cols = {name: np.concatenate([a.columns[name], b.columns[name]]) for name in a.columns}
        return HeldRows(a.map_id, a.first, cols, a.observations + b.observations,
                        np.concatenate([a.ref_kf_ids, b.ref_kf_ids]),
                        np.concatenate([a.ref_kp_indices, b.ref_kp_indices]),
                        np.concatenate([a.ref_rows, b.ref_rows + len(a)]))  # fmt: skip


class ProvisionalPoints:
    """Provisional points of one tracking replica (one instance per `TrackingSide`).

    `level_scales` (L,) ORB pyramid scale per level, `max_depth_m` the owner's `max_new_point_depth_m`.
    """

    def __init__(self, level_scales: F64, max_depth_m: float) -> None:
        self.level_scales = np.asarray(level_scales, np.float64)
        self.max_depth_m = float(max_depth_m)
        self._owner_size: dict[int, int] = {}  # map id -> owner's store size, while the map holds provisional rows
        self.n_created = 0
        self.n_replaced = 0  # provisional points replaced by the owner's point at the same keypoint
        self.n_dropped = 0  # provisional points the owner has no point for (culled, fused away, no keyframe)

    # -- bookkeeping -------------------------------------------------------------------------------
    def owner_size(self, m: SlamMap) -> int:
        """Rows of `m`'s store that are the owner's (provisional ones come after)."""
        return self._owner_size.get(m.id, m.points.size)

    def count(self, m: SlamMap) -> int:
        """Provisional points in `m` now."""
        return m.points.size - self.owner_size(m)

    def is_provisional(self, m: SlamMap, ids: I64) -> npt.NDArray[np.bool_]:
        """(N,) which of `ids` (point ids, -1 allowed) are provisional rows of `m`."""
        return np.asarray(ids) >= self.owner_size(m)

    # -- 1. create --------------------------------------------------------------------------------
    def create(self, m: SlamMap, kf: Keyframe) -> int:
        """Back-project `kf`'s unmatched keypoints with depth in (0, max_depth_m] into provisional points of `m`
        (`kf` is in `m` already); returns how many."""
        d = kf.depths_m.astype(np.float64)
        idx = np.flatnonzero((kf.point_ids < 0) & (d > 0) & (d <= self.max_depth_m))
        if len(idx) == 0:
            return 0
        self._owner_size.setdefault(m.id, m.points.size)
        pc = kf.camera.backproject(kf.keypoints_px[idx].astype(np.float64), d[idx])
        pw = transform_points(kf.T_world_cam, pc)
        ids = m.points.add(pw, kf.descriptors[idx], kf.id, idx, kf.T_world_cam[:3, 3],
                           kf.octaves[idx].astype(np.int64), self.level_scales)  # fmt: skip
        kf.point_ids[idx] = ids
        self.n_created += len(ids)
        return len(ids)

    # -- 2. around an owner delta ------------------------------------------------------------------
    def strip(self, m: SlamMap) -> HeldRows | None:
        """Take every provisional point out of `m` (store cut back to the owner's size, keyframe entries that
        named them set to -1); None when there is none. Done before an owner delta is applied: the rows past the
        owner's size are the owner's to allocate."""
        return _cut(m, self._owner_size.pop(m.id, m.points.size))

    def without(self, m: SlamMap) -> SlamMap:
        """A copy of `m` without its provisional points (what the owner's map looks like to a restarted owner)."""
        c = copy.deepcopy(m)
        _cut(c, self.owner_size(m))
        return c

    def reattach(self, m: SlamMap, held: HeldRows | None, waiting: set[int]) -> I64:
        """After the owner's delta went into `m`: the held rows of keyframes in `waiting` (no update yet) are
        appended again, the others become the owner's point at their keypoint (or -1). Keyframe entries of
        waiting keyframes that named held rows are set again; re-appended rows get new ids and keep their
        counters, replaced ones carry their tracking counters over to the owner's point. Returns (len(held),)
        old row -> new id or -1, for the caller to fix the ids it holds (tracking's last frame)."""
        if held is None:
            return np.zeros(0, np.int64)
        pts = m.points
        creators = held.creators()
        again = np.array([k in waiting and k in m.keyframes for k in creators.tolist()], bool)
        remap = np.full(len(held), -1, np.int64)
        # 1. Rows of keyframes the owner has mapped: its point at the same keypoint, with tracking's counts.
        usable = pts.usable()
        for j in np.flatnonzero(~again).tolist():
            k = int(creators[j])
            kp = held.observations[j].get(k, -1)
            kf = m.keyframes.get(k)
            pid = int(kf.point_ids[kp]) if kf is not None and kp >= 0 else -1
            if pid >= 0 and usable[pid]:
                remap[j] = pid
                pts.n_visible[pid] += int(held.columns["n_visible"][j]) - 1  # provisional rows start at 1 / 1
                pts.n_found[pid] += int(held.columns["n_found"][j]) - 1
                pts.last_seen_frame[pid] = max(int(pts.last_seen_frame[pid]), int(held.columns["last_seen_frame"][j]))
                self.n_replaced += 1
            else:
                self.n_dropped += 1
        # 2. Rows of keyframes still waiting: appended again after the owner's rows.
        rows = np.flatnonzero(again)
        if len(rows):
            n0 = pts.size
            self._owner_size[m.id] = n0
            new_ids = pts.extend_ids(n0 + len(rows))
            for name in PointStore.COLUMNS:
                getattr(pts, name)[new_ids] = held.columns[name][rows]
            for pid, j in zip(new_ids.tolist(), rows.tolist(), strict=True):
                pts.observations[pid] = {k: v for k, v in held.observations[j].items() if k in waiting}
            remap[rows] = new_ids
        # 3. Entries of waiting keyframes that named held rows.
        for k, kp, j in zip(held.ref_kf_ids.tolist(), held.ref_kp_indices.tolist(), held.ref_rows.tolist(), strict=True):
            kf = m.keyframes.get(k)
            new = int(remap[j])
            if kf is None or k not in waiting or new < 0 or kf.point_ids[kp] >= 0:
                continue
            if again[j]:
                kf.point_ids[kp] = new  # its observation came back with the row
            elif k not in pts.observations[new]:  # an owner point: observed here too (as insert_keyframe does)
                kf.point_ids[kp] = new
                pts.observations[new][k] = kp
        return remap

    # -- 3. what leaves the replica ----------------------------------------------------------------
    def packet_ids(self, m: SlamMap, kf: Keyframe) -> I64:
        """`kf.point_ids` as a keyframe packet carries them: provisional ids -> -1 (provisional ids never leave
        the replica; the owner creates those points from the same keypoints)."""
        ids = kf.point_ids.copy()
        ids[ids >= self.owner_size(m)] = -1
        return ids

    def foreign_refs(self, m: SlamMap, kf: Keyframe) -> int:
        """How many of `kf`'s entries name provisional points another keyframe created (the packet must wait
        until that keyframe's update turns them into the owner's points)."""
        ids = kf.point_ids
        prov = ids[ids >= self.owner_size(m)]
        return int((m.points.first_kf[prov] != kf.id).sum())

    @contextmanager
    def hidden(self, m: SlamMap) -> Iterator[None]:
        """The store at the owner's size for the duration (tracking's counter increments are taken on the
        owner's rows only)."""
        n = m.points.size
        m.points.size = self.owner_size(m)
        try:
            yield
        finally:
            m.points.size = n


def _cut(m: SlamMap, n0: int) -> HeldRows | None:
    """Rows `n0`.. of `m`'s store out (columns, observations, keyframe entries naming them -> -1)."""
    pts = m.points
    n1 = pts.size
    if n1 <= n0:
        return None
    cols = {name: getattr(pts, name)[n0:n1].copy() for name in PointStore.COLUMNS}
    obs = [dict(o) for o in pts.observations[n0:n1]]
    kf_ids, kps, rows = [], [], []
    for k, kf in m.keyframes.items():
        sel = np.flatnonzero(kf.point_ids >= n0)
        if len(sel):
            kf_ids.append(np.full(len(sel), k, np.int64))
            kps.append(sel.astype(np.int64))
            rows.append(kf.point_ids[sel] - n0)
            kf.point_ids[sel] = -1
    pts.truncate(n0)
    cat = lambda a: np.concatenate(a) if a else np.zeros(0, np.int64)  # noqa: E731
    return HeldRows(m.id, n0, cols, obs, cat(kf_ids), cat(kps), cat(rows))
