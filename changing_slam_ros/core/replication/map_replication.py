"""Map replication between processes: one owner of the metric map, replicas fed by deltas.

The split graph has one writer of the map, `local_mapping`; `tracking` and `loop_closing` keep replicas.
Three packets cross processes (mirrored by the messages Keyframe, MapUpdate, LoopCorrection):

- `KeyframePacket` (tracking -> local_mapping, loop_closing): the new keyframe, the point counters tracking
  incremented since its last packet, and for the object layer the keyframe's depth and short-term objects.
- `MapUpdate` (local_mapping -> tracking, loop_closing): the `MapDelta` local mapping (and the object layer)
  made to the map for one keyframe, or the delta of applying a loop correction.
- `LoopResult` (loop_closing -> local_mapping, tracking): one per keyframe, closed or not; when closed, the
  delta the correction made to loop closing's replica and the `core.slam.loop_closing.LoopCorrection`.

Ids: keyframe ids are allocated by tracking only (`Tracker.next_kf_id`) and map point ids by the map owner
only (`PointStore.add`); replicas never create either, so ids cannot collide between processes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.dynamic.dynamic_objects import ObjectMotion, ObjectState
from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.map.map_point import PointStore
from changing_slam_ros.core.map.slam_map import Atlas, RemovedKeyframe, SlamMap
from changing_slam_ros.errors import SlamError

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

# PointStore columns a delta carries, with their per-row shape and dtype (the store's own schema).
POINT_COLUMNS: tuple[tuple[str, tuple[int, ...], Any], ...] = PointStore.column_specs()


class ReplicationError(SlamError):
    """A delta or packet does not fit the replica it is applied to (missing keyframe, wrong map)."""


def _i64(values: Any = ()) -> I64:
    return np.asarray(values, dtype=np.int64).reshape(-1)


def _ragged(lists: list[list[int]]) -> tuple[I64, I64]:
    """Lists of ints -> (counts (K,), concatenated values)."""
    counts = _i64([len(v) for v in lists])
    flat = _i64([x for v in lists for x in v])
    return counts, flat


def _split(counts: I64, flat: npt.NDArray[Any], what: str) -> list[list[Any]]:
    """`flat` cut into Python lists of `counts` items each (a list slice per entry: one numpy array per entry, as
    np.split makes, costs more than the dict or set it fills); `what` names the arrays when they do not add up."""
    items, sizes = flat.tolist(), counts.tolist()
    if sum(sizes) != len(items):
        raise ReplicationError(f"map update: {what}: {len(items)} items, counts add up to {sum(sizes)}")
    out, end = [], 0
    for n in sizes:
        start, end = end, end + n
        out.append(items[start:end])
    return out


# -- packets -------------------------------------------------------------------------------------------
@dataclass
class PointRows:
    """Full state of M map points: `ids` (M,), one array per `POINT_COLUMNS` entry (M, ...), and the
    observations flattened in insertion order: `obs_counts` (M,), `obs_kf_ids`, `obs_kp_indices` (sum,)."""

    ids: I64
    columns: dict[str, npt.NDArray[Any]]
    obs_counts: I64
    obs_kf_ids: I64
    obs_kp_indices: I64

    @staticmethod
    def empty() -> PointRows:
        cols = {name: np.zeros((0,) + shape, dtype) for name, shape, dtype in POINT_COLUMNS}
        return PointRows(_i64(), cols, _i64(), _i64(), _i64())

    @staticmethod
    def of(points: PointStore, ids: I64) -> PointRows:
        cols = points.column_arrays(ids)
        obs = [points.observations[i] for i in ids.tolist()]
        return PointRows(ids.copy(), cols, _i64([len(o) for o in obs]),
                         _i64([k for o in obs for k in o]), _i64([v for o in obs for v in o.values()]))  # fmt: skip

    def __len__(self) -> int:
        return len(self.ids)


@dataclass
class KeyframeRows:
    """Full replicated state of K keyframes (their features do not change and are not carried).

    `poses` (K, 4, 4) T_world_cam; `n_keypoints` (K,) and, concatenated over keyframes, `point_ids`,
    `kp_classes` (int8), `object_ids`; covisibility links in order (`cov_counts` (K,), `cov_ids`,
    `cov_weights`); `parents` (K,) (-1 none); `child_counts`/`child_ids`; `loop_counts`/`loop_ids`.
    """

    ids: I64
    poses: F64
    n_keypoints: I64
    point_ids: I64
    kp_classes: npt.NDArray[np.int8]
    object_ids: I64
    cov_counts: I64
    cov_ids: I64
    cov_weights: I64
    parents: I64
    child_counts: I64
    child_ids: I64
    loop_counts: I64
    loop_ids: I64

    @staticmethod
    def of(m: SlamMap, ids: list[int]) -> KeyframeRows:
        kfs = [m.keyframes[k] for k in ids]
        cov = [list(m.covisibility.get(k, {}).items()) for k in ids]
        cc, cids = _ragged([[a for a, _ in c] for c in cov])
        _, cw = _ragged([[w for _, w in c] for c in cov])
        chc, chi = _ragged([sorted(m.children.get(k, set())) for k in ids])
        lc, li = _ragged([sorted(m.loop_edges.get(k, set())) for k in ids])
        cat = (lambda arrs, dt: np.concatenate(arrs).astype(dt) if arrs else np.zeros(0, dt))  # noqa: E731
        return KeyframeRows(
            _i64(ids), np.array([kf.T_world_cam for kf in kfs], np.float64).reshape(-1, 4, 4),
            _i64([len(kf) for kf in kfs]), cat([kf.point_ids for kf in kfs], np.int64),
            cat([kf.kp_classes for kf in kfs], np.int8), cat([kf.object_ids for kf in kfs], np.int64),
            cc, cids, cw, _i64([m.parent.get(k, -1) for k in ids]), chc, chi, lc, li,
        )  # fmt: skip

    def __len__(self) -> int:
        return len(self.ids)


@dataclass
class RemovedRows:
    """Keyframes culled: `ids` (R,), `parents` (R,), `T_parent_kf` (R, 4, 4) (see `slam_map.RemovedKeyframe`)."""

    ids: I64
    parents: I64
    T_parent_kf: F64

    def __len__(self) -> int:
        return len(self.ids)


@dataclass
class MapDelta:
    """What changed in map `map_id`; `n_points` is the owner's point-store size after the change."""

    map_id: int
    origin_kf_id: int
    n_points: int
    keyframes: KeyframeRows
    removed: RemovedRows
    points: PointRows

    @property
    def empty(self) -> bool:
        return len(self.keyframes) == 0 and len(self.removed) == 0 and len(self.points) == 0


@dataclass
class PointCounters:
    """Tracking's increments since its last packet: `ids` (M,), `n_visible` / `n_found` deltas (M,) and the
    absolute `last_seen_frame` (M,)."""

    ids: I64 = field(default_factory=_i64)
    n_visible: I64 = field(default_factory=_i64)
    n_found: I64 = field(default_factory=_i64)
    last_seen_frame: I64 = field(default_factory=_i64)


@dataclass
class KeyframePacket:
    """tracking -> local_mapping / loop_closing. `depth_m` (H, W) metres (0 = none) and `objects` feed the
    object layer; both may be empty when it is off. `other_counters`: map id -> tracking's increments in another
    map of the Atlas since that map's last packet (frames tracked there before a new map started, or after a
    relocalisation), so that the owner's counters of every map stay tracking's (a merge fuses on them)."""

    keyframe: Keyframe
    counters: PointCounters = field(default_factory=PointCounters)
    depth_m: npt.NDArray[np.float32] | None = None
    objects: tuple[ObjectState, ...] = ()
    other_counters: dict[int, PointCounters] = field(default_factory=dict)


@dataclass
class MapUpdate:
    """local_mapping -> tracking / loop_closing. `keyframe_id`: the keyframe this update maps (-1 for the delta
    of a loop correction, then `loop_query_kf_id` names the correction's query keyframe)."""

    keyframe_id: int
    delta: MapDelta
    culled_keyframes: I64 = field(default_factory=_i64)
    active_flags_changed: bool = False
    objects_ran: bool = False
    loop_query_kf_id: int = -1
    # A map merge the owner applied (core.map_merging.MergeResult, its `ba` left out): then `keyframe_id` is -1,
    # `loop_query_kf_id` the merge's query keyframe and `delta` the whole merged map (`full_delta`), which a
    # replica takes with `apply_merge`.
    merge: Any | None = None


@dataclass
class LoopResult:
    """loop_closing's verdict on one keyframe; when `closed`, the delta on its replica and the correction."""

    query_kf_id: int
    closed: bool
    delta: MapDelta | None = None
    correction: Any | None = None  # core.loop_closing.LoopCorrection
    merge: Any | None = None  # not closed, but a place of another map seen: core.loop_closing.MapMerge


# -- diffing ---------------------------------------------------------------------------------------------
@dataclass
class MapSnapshot:
    """The replicated state of one map at a moment (`snapshot`), to diff against later."""

    map_id: int
    origin_kf_id: int
    keyframes: dict[int, tuple[Any, ...]]
    removed: frozenset[int]
    n_points: int
    ids: I64  # the points that had a storage row, sorted (others were compacted away: gone for good)
    columns: dict[str, npt.NDArray[Any]]  # rows of `ids`
    observations: list[tuple[tuple[int, int], ...]]  # of `ids`


def _kf_state(m: SlamMap, k: int) -> tuple[Any, ...]:
    kf = m.keyframes[k]
    return (kf.T_world_cam.copy(), kf.point_ids.copy(), kf.kp_classes.copy(), kf.object_ids.copy(),
            tuple(m.covisibility.get(k, {}).items()), m.parent.get(k, -1), frozenset(m.children.get(k, set())),
            frozenset(m.loop_edges.get(k, set())))  # fmt: skip


def _kf_equal(a: tuple[Any, ...], b: tuple[Any, ...]) -> bool:
    return (np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1]) and np.array_equal(a[2], b[2])
            and np.array_equal(a[3], b[3]) and a[4:] == b[4:])  # fmt: skip


def snapshot(m: SlamMap) -> MapSnapshot:
    pts = m.points
    ids = pts.live_ids()
    obs = pts.observations
    return MapSnapshot(
        m.id, m.origin_kf_id, {k: _kf_state(m, k) for k in m.keyframes}, frozenset(m.removed), pts.size, ids,
        pts.column_arrays(ids), [tuple(obs[i].items()) for i in ids.tolist()],
    )


def diff(before: MapSnapshot, m: SlamMap) -> MapDelta:
    """The delta that turns a replica equal to `before` into `m` (the same map, later).

    Found by diffing, so it does not depend on what the step did inside: every keyframe whose pose, point ids,
    labels, covisibility links, spanning-tree parent/children or loop edges changed, every keyframe removed,
    and every point row that is new or changed in any column or in its observations (in insertion order, which
    later iteration depends on)."""
    if before.map_id != m.id:
        raise ReplicationError(f"diff: snapshot of map {before.map_id} compared with map {m.id}")
    kf_ids = [k for k in m.keyframes if k not in before.keyframes or not _kf_equal(before.keyframes[k], _kf_state(m, k))]
    new_removed = [k for k in m.removed if k not in before.removed]
    pts = m.points
    n0, n1 = before.n_points, pts.size
    old = before.ids  # an id compacted before the snapshot is gone in both
    now = pts.column_arrays(old)
    changed = np.zeros(len(old), bool)
    for name, _, _ in POINT_COLUMNS:
        ne = before.columns[name] != now[name]
        changed |= ne.any(axis=1) if ne.ndim > 1 else ne
    obs = pts.observations
    for j in np.flatnonzero(~changed).tolist():
        o = obs[int(old[j])]
        if len(o) != len(before.observations[j]) or tuple(o.items()) != before.observations[j]:
            changed[j] = True
    ids = np.concatenate([old[changed], np.arange(n0, n1)]).astype(np.int64)
    rem = [m.removed[k] for k in new_removed]
    return MapDelta(
        m.id, m.origin_kf_id, n1, KeyframeRows.of(m, kf_ids),
        RemovedRows(_i64(new_removed), _i64([r.parent_id for r in rem]),
                    np.array([r.T_parent_kf for r in rem], np.float64).reshape(-1, 4, 4)),
        PointRows.of(pts, ids),
    )  # fmt: skip


def empty_snapshot(map_id: int) -> MapSnapshot:
    """The snapshot of a map with nothing in it: `diff(empty_snapshot(m.id), m)` is all of map `m`."""
    cols = {name: np.zeros((0,) + shape, dtype) for name, shape, dtype in POINT_COLUMNS}
    return MapSnapshot(map_id, -1, {}, frozenset(), 0, _i64(), cols, [])


def full_delta(m: SlamMap) -> MapDelta:
    """All of map `m` as one delta (a replica restarted empty gets it with `restore`)."""
    return diff(empty_snapshot(m.id), m)


# -- applying ------------------------------------------------------------------------------------------
def ensure_map(atlas: Atlas, map_id: int) -> SlamMap:
    """The atlas's map `map_id`, creating maps up to it (ids are dense, as `Atlas.new_map` makes them)."""
    if map_id < 0:
        raise ReplicationError(f"map id {map_id} is negative")
    current = atlas.current
    while len(atlas.maps) <= map_id:
        atlas.new_map()
    atlas.current = current
    return atlas.maps[map_id]


def check_keyframe(m: SlamMap, kf: Keyframe) -> None:
    """ReplicationError when a keyframe names map points map `m` does not have (or that are gone)."""
    ids = kf.point_ids[kf.point_ids >= 0]
    if len(ids) and int(ids.max()) >= m.points.size:
        raise ReplicationError(f"keyframe {kf.id} names map point {int(ids.max())}; map {m.id} has {m.points.size}")


def insert_keyframe(atlas: Atlas, kf: Keyframe) -> SlamMap:
    """A replica receives a new keyframe (before the owner's delta for it): inserted with its tracked points'
    observations, as `SlamMap.add_keyframe` does in the owner. Makes its map the current one."""
    m = ensure_map(atlas, kf.map_id)
    check_keyframe(m, kf)
    atlas.current = m
    if kf.id not in m.keyframes:
        m.add_keyframe(kf)
    return m


def apply_delta(atlas: Atlas, delta: MapDelta) -> SlamMap:
    """Write a delta into the replica's map `delta.map_id`, in place. Keyframes it names must be there.

    Rows are overwritten in place (Keyframe objects keep their identity: the keyframe database holds them), so a
    replica fed every delta in order equals the owner bit for bit."""
    m = ensure_map(atlas, delta.map_id)
    m.origin_kf_id = delta.origin_kf_id
    # 1. Points: every column, then observations in the owner's order.
    pts = m.points
    pts.extend_ids(delta.n_points)  # rows the owner allocated
    pr = delta.points
    if len(pr):
        pts.revive(pr.ids[~pr.columns["bad"]])  # a live point this replica had compacted (it had it bad)
        for name, _, _ in POINT_COLUMNS:
            getattr(pts, name)[pr.ids] = pr.columns[name]
        kfs = _split(pr.obs_counts, pr.obs_kf_ids, f"map {m.id}: observation keyframe ids")
        kps = _split(pr.obs_counts, pr.obs_kp_indices, f"map {m.id}: observation keypoint indices")
        for pid, kf_ids, kp_indices in zip(pr.ids.tolist(), kfs, kps, strict=True):
            pts.observations[pid] = dict(zip(kf_ids, kp_indices))
    # 2. Keyframes: pose, per-keypoint ids and labels, links.
    kr = delta.keyframes
    offsets = np.concatenate([[0], np.cumsum(kr.n_keypoints)]).astype(np.int64)
    cov = zip(_split(kr.cov_counts, kr.cov_ids, "covisibility ids"), _split(kr.cov_counts, kr.cov_weights,
              "covisibility weights"), strict=True)  # fmt: skip
    children = _split(kr.child_counts, kr.child_ids, "spanning-tree children")
    loops = _split(kr.loop_counts, kr.loop_ids, "loop edges")
    for j, (k, (cid, cw)) in enumerate(zip(kr.ids.tolist(), cov, strict=True)):
        kf = m.keyframes.get(k)
        if kf is None:
            raise ReplicationError(f"map update for map {m.id}: keyframe {k} is not in the replica "
                                   "(its keyframe packet was not applied first)")  # fmt: skip
        if len(kf) != int(kr.n_keypoints[j]):
            raise ReplicationError(f"map update: keyframe {k} has {len(kf)} keypoints, the update {kr.n_keypoints[j]}")
        s = slice(int(offsets[j]), int(offsets[j + 1]))
        kf.T_world_cam = kr.poses[j].copy()
        kf.point_ids = kr.point_ids[s].copy()
        kf.kp_classes = kr.kp_classes[s].copy()
        kf.object_ids = kr.object_ids[s].copy()
        m.covisibility[k] = dict(zip(cid, cw, strict=True))
        if kr.parents[j] >= 0:
            m.parent[k] = int(kr.parents[j])
        else:
            m.parent.pop(k, None)
        m.children[k] = set(children[j])
        if len(loops[j]):
            m.loop_edges[k] = set(loops[j])
        else:
            m.loop_edges.pop(k, None)
    # 3. Culled keyframes.
    rr = delta.removed
    for k, par, T in zip(rr.ids.tolist(), rr.parents.tolist(), rr.T_parent_kf, strict=True):
        m.removed[k] = RemovedKeyframe(par, T.copy())
        m.keyframes.pop(k, None)
        m.covisibility.pop(k, None)
        m.children.pop(k, None)
        m.parent.pop(k, None)
    return m


def restore(atlas: Atlas, keyframes: list[Keyframe], delta: MapDelta) -> SlamMap:
    """Rebuild map `delta.map_id` in a replica that restarted empty, from the keyframes (features; their
    point ids are ignored) and `full_delta` of the map. Replaces what the replica had of that map."""
    missing = sorted(set(delta.keyframes.ids.tolist()) - {kf.id for kf in keyframes})
    if missing:
        raise ReplicationError(f"restore of map {delta.map_id}: keyframes {missing[:5]} missing")
    m = ensure_map(atlas, delta.map_id)
    fresh = SlamMap(m.id)
    atlas.maps[m.id] = fresh
    if atlas.current is m:
        atlas.current = fresh
    wanted = set(delta.keyframes.ids.tolist())
    for kf in sorted(keyframes, key=lambda k: k.id):
        if kf.id in wanted:
            kf.point_ids = np.full(len(kf), -1, np.int64)
            fresh.add_keyframe(kf)
    return apply_delta(atlas, delta)


def apply_merge(atlas: Atlas, from_map_id: int, delta: MapDelta) -> SlamMap:
    """A replica takes a map merge its owner applied (`core.map_merging.merge_maps`): map `delta.map_id` is
    rebuilt from the keyframes the replica holds in both maps and the owner's `full_delta` of the merged map
    (`restore`: the same Keyframe objects, now in the merged map); map `from_map_id` is left empty, recorded
    in `atlas.merged_into`, and the merged map becomes current. Keyframes the replica holds that the owner's
    map does not (sent, not mapped yet) are dropped."""
    into = delta.map_id
    if from_map_id == into:
        raise ReplicationError(f"map merge of map {into} into itself")
    src, dst = ensure_map(atlas, from_map_id), ensure_map(atlas, into)
    m = restore(atlas, [*dst.keyframes.values(), *src.keyframes.values()], delta)
    order = delta.keyframes.ids.tolist()  # the owner's keyframe order, and its spanning tree in that order
    m.keyframes = {k: m.keyframes[k] for k in order if k in m.keyframes} | m.keyframes
    m.order_spanning_tree()
    atlas.maps[from_map_id] = SlamMap(from_map_id)
    atlas.merged_into[from_map_id] = into
    atlas.current = m
    return m


# -- tracking's counters ------------------------------------------------------------------------------
class CounterTracker:
    """Tracking's side of the point counters: what it added to `n_visible` / `n_found` since the last packet,
    per map of the atlas.

    The owner's delta overwrites counter columns with the owner's values; `apply_keeping_increments` keeps the
    increments tracking made in between on top of them, so that nothing is lost or counted twice.
    """

    def __init__(self) -> None:
        self.bases: dict[int, tuple[I64, I64, I64]] = {}  # map id -> (n_visible, n_found, last_seen_frame) sent

    def _base(self, m: SlamMap) -> tuple[I64, I64, I64]:
        pts, n = m.points, m.points.size
        vis, found, seen = self.bases.get(m.id, (_i64(), _i64(), _i64()))
        if len(vis) < n:  # rows the owner created since: their counters are the owner's
            k = len(vis)
            vis = np.concatenate([vis, pts.n_visible[k:n]])
            found = np.concatenate([found, pts.n_found[k:n]])
            seen = np.concatenate([seen, pts.last_seen_frame[k:n]])
            self.bases[m.id] = (vis, found, seen)
        return vis, found, seen

    def rebase(self, m: SlamMap) -> None:
        """Count increments in map `m` from its state now (a replica that took a whole map, e.g. a merge)."""
        n = m.points.size
        pts = m.points
        self.bases[m.id] = (pts.n_visible[:n].copy(), pts.n_found[:n].copy(), pts.last_seen_frame[:n].copy())

    def take(self, m: SlamMap) -> PointCounters:
        """The increments in map `m` since the last call (or update), and reset the base to now."""
        vis, found, seen0 = self._base(m)
        pts, n = m.points, m.points.size
        dv = pts.n_visible[:n] - vis
        df = pts.n_found[:n] - found
        seen = pts.last_seen_frame[:n]
        ids = np.flatnonzero((dv != 0) | (df != 0) | (seen != seen0)).astype(np.int64)
        out = PointCounters(ids, dv[ids].copy(), df[ids].copy(), seen[ids].copy())
        self.bases[m.id] = (pts.n_visible[:n].copy(), pts.n_found[:n].copy(), seen.copy())
        return out

    def apply_keeping_increments(self, atlas: Atlas, delta: MapDelta) -> SlamMap:
        """`apply_delta`, then re-add the increments tracking made to the delta's rows since its last packet."""
        ids = delta.points.ids
        pending = None
        if delta.map_id < len(atlas.maps) and len(ids):
            m0 = atlas.maps[delta.map_id]
            vis, found, _ = self._base(m0)
            old = ids[ids < len(vis)]
            pending = (old, m0.points.n_visible[old] - vis[old], m0.points.n_found[old] - found[old])
        m = apply_delta(atlas, delta)
        vis, found, seen = self._base(m)
        if len(ids):
            vis[ids] = m.points.n_visible[ids]
            found[ids] = m.points.n_found[ids]
            seen[ids] = m.points.last_seen_frame[ids]
        if pending is not None:
            old, dv, df = pending
            m.points.n_visible[old] += dv
            m.points.n_found[old] += df
        return m


def apply_counters(points: PointStore, counters: PointCounters) -> None:
    """The owner adds tracking's increments (ids it knows; newer ones cannot exist)."""
    ids = counters.ids
    if len(ids) and int(ids.max()) >= points.size:
        raise ReplicationError(f"point counters name point {int(ids.max())}; the map has {points.size}")
    points.add_counters(ids, counters.n_visible, counters.n_found, counters.last_seen_frame)


# -- short-term objects as flat arrays (for the Keyframe message) --------------------------------------
@dataclass
class ObjectRows:
    """`ObjectState`s as columns: ids, class_ids, boxes (K, 4), positions, velocities (K, 3), speeds, motion,
    n_updates, is_new, covariances (K, 36)."""

    ids: I64
    class_ids: I64
    boxes: F64
    positions: F64
    velocities: F64
    speeds: F64
    motion: I64
    n_updates: I64
    is_new: npt.NDArray[np.bool_]
    covariances: F64

    @staticmethod
    def of(objects: tuple[ObjectState, ...] | list[ObjectState]) -> ObjectRows:
        o = list(objects)
        f = lambda get, width: np.array([get(s) for s in o], np.float64).reshape(len(o), width)  # noqa: E731
        return ObjectRows(
            _i64([s.object_id for s in o]), _i64([s.class_id for s in o]), f(lambda s: s.box_xyxy, 4),
            f(lambda s: s.position_world, 3), f(lambda s: s.velocity_world, 3), f(lambda s: s.speed_mps, 1)[:, 0],
            _i64([int(s.motion) for s in o]), _i64([s.n_updates for s in o]), np.array([s.is_new for s in o], bool),
            f(lambda s: s.covariance, 36),
        )  # fmt: skip

    def states(self) -> tuple[ObjectState, ...]:
        return tuple(
            ObjectState(int(self.ids[i]), int(self.class_ids[i]), tuple(float(v) for v in self.boxes[i]),  # type: ignore[arg-type]
                        self.positions[i].copy(), self.velocities[i].copy(), float(self.speeds[i]),
                        ObjectMotion(int(self.motion[i])), int(self.n_updates[i]), bool(self.is_new[i]),
                        self.covariances[i].reshape(6, 6).copy())  # fmt: skip
            for i in range(len(self.ids))
        )

