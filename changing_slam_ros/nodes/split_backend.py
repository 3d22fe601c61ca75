"""The SLAM system split over three processes, ROS-free: tracking, the map owner (local mapping), loop closing.

Each side is what one node runs; the nodes only convert messages (`core.replication.map_replication` packets)
and call these. Chained synchronously (`feed` order below, as `changing-slam graph` does in lossless mode; in one
process: `nodes.split_chains`), they give the offline `SlamSystem`'s trajectory, because every step runs on the
same state in the same order:

    tracking  : frame -> SlamSystem (no local mapping / loop closing in it) -> KeyframePacket
    map owner : packet -> LocalMapper.process (+ object layer) -> MapUpdate (the map's delta)
    loop side : packet + update -> keyframe database, LoopCloser -> LoopResult (closed: its replica's delta)
    map owner : LoopResult -> applies it -> MapUpdate (the delta of applying it; tracking and loop side follow)

The map owner is the only writer of the map; tracking and the loop side keep replicas fed by its MapUpdates.
Multi-session: every side loads the same map file itself (`start_from_map`); the three maps agree at once.
"""

from __future__ import annotations

import copy
import dataclasses
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.objects.object_layer import ObjectLayer
from changing_slam_ros.core.slam.local_mapping import LocalMapper, MappingStats
from changing_slam_ros.core.replication.map_replication import (
    CounterTracker,
    KeyframePacket,
    LoopResult,
    MapDelta,
    MapUpdate,
    PointCounters,
    ReplicationError,
    apply_counters,
    apply_delta,
    apply_merge,
    check_keyframe,
    diff,
    ensure_map,
    full_delta,
    insert_keyframe,
    restore,
    snapshot,
)
from changing_slam_ros.core.replication.merge_in_flight import MergeLog, combine_counters, move_counters, move_keyframe, move_packet
from changing_slam_ros.core.slam.provisional_points import HeldRows, ProvisionalPoints
from changing_slam_ros.core.features.rgbd_frame import RgbdFrame
from changing_slam_ros.core.map.slam_map import Atlas, SlamMap
from changing_slam_ros.core.system import FrameOutput, SlamSystem
from changing_slam_ros.io.map_file import LoadedMap
from changing_slam_ros.nodes.slam_backend import Backend, BackendConfig, build_backend


def object_layer_for(cfg: BackendConfig, objects: str = "config") -> ObjectLayer | None:
    """The map owner's object layer as `cfg` and the `objects` switch build it (None when off)."""
    return build_backend(cfg, loop=False, dynamic="off", objects=objects).objects


def replica_point_flags(layer: ObjectLayer | None, loaded: LoadedMap) -> None:
    """On a replica's copy of a loaded map: the active point flags the owner's object layer sets when it loads
    the saved objects (`ObjectLayer.load_objects`; `layer` is a scratch one, None = object layer off). The same
    file and config give the same flags, so the replicas agree with the owner without a message."""
    if layer is None:
        return
    for map_id, saved in loaded.objects.items():
        layer.load_objects(map_id, saved, loaded.next_keyframe_id, loaded.atlas.maps[map_id].points)


class _ReplicaInsert:
    """Stands in for `SlamSystem.mapper` in the tracking process: a new keyframe goes into the replica only;
    the map owner maps it and sends the result back. With `provisional` (real time), the keyframe's depth
    keypoints also become provisional points at once (`core.provisional_points`), as ORB-SLAM's RGB-D
    `CreateNewKeyFrame` does, so tracking never waits for the owner's points."""

    def __init__(self, atlas: Atlas, provisional: ProvisionalPoints | None = None) -> None:
        self.atlas = atlas
        self.provisional = provisional

    def process(self, kf: Keyframe) -> MappingStats:
        m = insert_keyframe(self.atlas, kf)
        n = 0 if self.provisional is None else self.provisional.create(m, kf)
        return MappingStats(new_points=n)


@dataclass
class TrackingSide:
    """Features, dynamic filter and tracking against a replica of the map (tracking node)."""

    backend: Backend
    counters: CounterTracker = field(default_factory=CounterTracker)
    index: Any | None = None  # its own keyframe database (relocalisation), fed like the loop side's
    n_updates: int = 0
    n_loops: int = 0
    n_merges: int = 0
    waiting_for_map: int = -1  # the first keyframe of a new map, until its update brings the map's first points
    n_skipped: int = 0  # frames not tracked while waiting for it (real time only; lossless never waits here)
    unacked: dict[int, KeyframePacket] = field(default_factory=dict)  # sent, its map update not in yet
    n_moved_keyframes: int = 0  # keyframes without their update yet when a merge came, moved into the merged map
    n_moved_provisional: int = 0  # provisional points of those keyframes, moved with them

    # the map owner runs the object layer or keeps grid scans: packets carry depth and the dynamic stage's objects
    ship_objects: bool = True
    # Real time only: tracking's own points for keyframes not mapped yet (None = wait for the owner's points)
    provisional: ProvisionalPoints | None = None
    # provisional: packets held back, oldest first, while they name another keyframe's provisional points
    outbox: deque[KeyframePacket] = field(default_factory=deque)

    @staticmethod
    def build(cfg: BackendConfig, loop: bool = True, dynamic: str = "config", objects: str = "config",
              provisional: bool = False) -> TrackingSide:
        """`provisional`: track against provisional points of keyframes whose update has not come (real time;
        never with a caller that waits for every update, as the lossless graph does)."""
        ship = build_backend(cfg, loop=False, dynamic="off", objects=objects).objects is not None
        backend = build_backend(cfg, loop=loop, dynamic=dynamic, objects="off")
        system = backend.system
        ship = ship or system.config.grid.enabled
        system.keep_grid_scans = False  # the map owner keeps them
        system.owns_map = False  # nor does the replica forget points (`dynamic.forget_moving_points`)
        index = backend.loop_closing  # same class as the loop side's: relocalisation candidates only here
        system.loop_closer = None
        system.keyframe_index = None
        system.object_layer = None
        prov = None
        if provisional:
            prov = ProvisionalPoints(system.mapper.scales, system.config.mapping.max_new_point_depth_m)
        system.mapper = _ReplicaInsert(system.atlas, prov)  # type: ignore[assignment]
        if index is not None:
            system.tracker.candidates = index
        backend.loop_closing = None
        return TrackingSide(backend, index=index, ship_objects=ship, provisional=prov)

    @property
    def system(self) -> SlamSystem:
        return self.backend.system

    def start_from_map(self, loaded: LoadedMap, layer: ObjectLayer | None) -> None:
        """Multi-session: the replica becomes the loaded Atlas (point flags as the owner sets them, `layer` a
        scratch object layer or None), its keyframes go into the relocalisation index, and tracking
        relocalises against the loaded current map first (`SlamSystem.start_from_map`)."""
        replica_point_flags(layer, loaded)
        self.system.start_from_map(loaded.atlas, loaded.next_keyframe_id)  # no object layer, no index here
        if self.index is not None:
            for m in self.system.atlas.maps:
                for k in sorted(m.keyframes):
                    self.index.add(m.keyframes[k])
                self.index.refresh_active_points(m)

    def process(self, rgbd: RgbdFrame, detections: Any = None) -> tuple[FrameOutput | None, KeyframePacket | None]:
        """Track one frame; returns its output and the keyframe packet to send now, if any.

        Without provisional points: (None, None) when the frame is skipped because a new map has no points
        here yet (its points come from the map owner: tracking on, with none, would lose the map at once and
        start another). With them: never skipped; a keyframe packet that names another keyframe's provisional
        points is held back (None now) and comes out of `apply_update` once that keyframe's update is in."""
        if self.waiting_for_map >= 0:
            self.n_skipped += 1
            return None, None
        if self.provisional is not None:  # real time: the map owner is busy while a keyframe of ours is not mapped
            self.system.tracker.mapping_idle = not (self.unacked or self.outbox)
        out = self.system.process(rgbd, detections)
        if out.keyframe is None:
            return out, None
        kf = out.keyframe
        m = self.system.atlas.maps[kf.map_id]
        counters = self._take_counters(m)
        others = {}
        for other in self.system.atlas.maps:
            if other is not m and other.points.size > 0:
                c = self._take_counters(other)
                if len(c.ids):
                    others[other.id] = c
        if kf.id == m.origin_kf_id and self.provisional is None:
            self.waiting_for_map = kf.id
        packet = KeyframePacket(kf, counters, rgbd.depth_m, ()) if self.ship_objects else KeyframePacket(kf, counters)
        packet.other_counters = others
        if self.ship_objects and out.dynamic is not None:
            packet.objects = tuple(out.dynamic.objects)
        if self.provisional is None:
            self.unacked[kf.id] = copy.deepcopy(packet)  # re-sent to a map owner that restarts before mapping it
            return out, packet
        self.outbox.append(packet)
        ready = self._flush()
        assert len(ready) <= 1  # only an update can release packets held before this one
        return out, ready[0] if ready else None

    def _flush(self) -> list[KeyframePacket]:
        """Held packets that may go now, oldest first: their provisional ids blanked (the owner makes those
        points from the same keypoints), each kept in `unacked` as sent."""
        assert self.provisional is not None
        ready = []
        while self.outbox:
            kf = self.outbox[0].keyframe
            m = self.system.atlas.maps[kf.map_id]
            if kf.id in m.keyframes and self.provisional.foreign_refs(m, kf) > 0:
                break
            packet = self.outbox.popleft()
            sent = copy.deepcopy(packet)
            sent.keyframe.point_ids = self.provisional.packet_ids(m, kf)
            self.unacked[kf.id] = sent
            ready.append(sent)
        return ready

    def apply_update(self, update: MapUpdate) -> list[KeyframePacket]:
        """The owner's delta into the replica (keeping tracking's newer counter increments), the keyframe
        database as `SlamSystem` feeds it, then the last frame re-anchored on its moved reference keyframe.
        With provisional points: they are taken out around the delta and put back (those of the mapped
        keyframe become the owner's points); returns the held packets this releases (send them now)."""
        if update.merge is not None:
            self._apply_merge(update)
            return self._flush() if self.provisional is not None else []
        atlas = self.system.atlas
        held = None
        if self.provisional is not None and update.delta.map_id < len(atlas.maps):
            held = self.provisional.strip(atlas.maps[update.delta.map_id])
        m = self.counters.apply_keeping_increments(atlas, update.delta)
        if update.keyframe_id == self.waiting_for_map:
            self.waiting_for_map = -1
        self.unacked.pop(update.keyframe_id, None)
        if self.provisional is not None and held is not None:
            waiting = set(self.unacked) | {p.keyframe.id for p in self.outbox}
            remap = self.provisional.reattach(m, held, waiting)
            last = self.system.tracker.last_frame
            if last is not None and atlas.current is m and len(last.point_ids) and len(remap):
                ids = last.point_ids
                sel = ids >= held.first
                ids[sel] = remap[ids[sel] - held.first]
        if self.index is not None:
            for k in update.culled_keyframes.tolist():
                self.index.erase(k)
            kf = m.keyframes.get(update.keyframe_id)  # a keyframe is never culled in its own mapping step
            if kf is not None:
                self.index.add(kf)
            if update.active_flags_changed:
                self.index.refresh_active_points(m)
        self.n_updates += 1
        if self.system.records:
            self.system._reanchor_last_frame()  # noqa: SLF001 - SlamSystem's own re-anchoring, reused
        return self._flush() if self.provisional is not None else []

    def _take_counters(self, m: SlamMap) -> PointCounters:
        """Tracking's counter increments in map `m` since its last packet, on the owner's points only."""
        if self.provisional is None:
            return self.counters.take(m)
        with self.provisional.hidden(m):
            return self.counters.take(m)

    def _apply_merge(self, update: MapUpdate) -> None:
        """The owner merged map A into map B: the replica takes the merged map (`apply_merge`), then what
        `SlamSystem` moves offline: frame records, the last frame and the relocalisation index
        (`SlamSystem.follow_merge`).

        In real time the owner merged without the keyframes tracking made since (sent or held, no update yet)
        and without tracking's provisional points. Those keyframes are expressed in B (`move_keyframe`: pose by
        `T_into_from`, point ids shifted) and inserted into the merged map again, as a new keyframe is, so the
        owner's update for each (it moves the late packet the same way: `MergeLog`) applies here; their
        provisional points move with them and go back above the owner's rows (`reattach`), and the ids the last
        frame holds follow. Tracking's counter increments since its last packet are kept (renamed into B) and go
        with the next packet; the packets held or kept for a resend are moved too."""
        r = update.merge
        atlas = self.system.atlas
        src, dst = ensure_map(atlas, r.from_map_id), ensure_map(atlas, r.into_map_id)
        tracked_in = atlas.current.id
        waiting = set(self.unacked) | {p.keyframe.id for p in self.outbox}
        late = sorted((kf for mm in (dst, src) for k, kf in mm.keyframes.items() if k in waiting), key=lambda kf: kf.id)
        # 1. Provisional points out of both maps (keyframe entries naming them set to -1), ids noted.
        held_src = held_dst = None
        if self.provisional is not None:
            held_dst = self.provisional.strip(dst)
            held_src = self.provisional.strip(src)
        last = self.system.tracker.last_frame
        last_ids = last.point_ids.copy() if last is not None else None
        # 2. Tracking's counter increments since its last packet (owner rows only now), to be kept.
        inc_src = self.counters.take(src) if src.points.size else PointCounters()
        inc_dst = self.counters.take(dst) if dst.points.size else PointCounters()
        # 3. Packets not mapped yet (held, or kept for a resend) into B; held ones share the replica's keyframes.
        for p in [*self.outbox, *self.unacked.values()]:
            move_packet(p, r)
        # 4. The owner's merged map, with tracking's increments on top of its counters.
        m = apply_merge(atlas, r.from_map_id, update.delta)
        self.counters.bases.pop(r.from_map_id, None)
        self.counters.rebase(m)
        inc = combine_counters(inc_dst, move_counters(inc_src, r))
        pts = m.points
        pts.add_counters(inc.ids, inc.n_visible, inc.n_found, inc.last_seen_frame)
        # 5. The waiting keyframes into the merged map again, in the order they were made (the owner's order).
        for kf in late:
            if kf.map_id == r.from_map_id:
                move_keyframe(kf, r)
            check_keyframe(m, kf)
            m.add_keyframe(kf)
        self.n_moved_keyframes += len(late)
        self.n_moved_provisional += sum(len(h) for h in (held_src, held_dst) if h is not None)
        # 6. Their provisional points, B's rows first, then A's moved into B's frame.
        remap = np.zeros(0, np.int64)
        n_dst = 0 if held_dst is None else len(held_dst)
        if self.provisional is not None:
            moved_src = held_src.moved(r.T_into_from, m.id) if held_src is not None else None
            remap = self.provisional.reattach(m, HeldRows.join(held_dst, moved_src), waiting)
        if self.index is not None:
            self.index.maps_merged(r.moved_keyframes, r.into_map_id)
        # 7. Records, last frame and last good pose, as offline; provisional ids of the last frame remapped.
        if tracked_in == r.from_map_id:
            self.system.follow_merge(r)
        else:  # tracking is in B (or a newer map): only the records of A move
            self.system.records.rename_map(r.from_map_id, r.into_map_id)
            self.system.merges.append(r)
        if last is not None and last_ids is not None and len(remap):
            held = held_src if tracked_in == r.from_map_id else held_dst if tracked_in == r.into_map_id else None
            if held is not None:
                base = n_dst if held is held_src else 0
                sel = last_ids >= held.first
                last.point_ids[sel] = remap[base + last_ids[sel] - held.first]
        self.n_updates += 1
        self.n_merges += 1
        if self.system.records:
            self.system._reanchor_last_frame()  # noqa: SLF001 - as offline after a merge

    def snapshot(self) -> list[tuple[list[Keyframe], MapDelta]]:
        """Every map of the replica as (keyframes, full delta), for a map owner or loop closing that restarted:
        the map as the owner last mapped it, i.e. without the keyframes still waiting for their update (their
        insertion is undone on a copy; `unacked` packets are sent again after the snapshot)."""
        out = []
        held = [p.keyframe.id for p in self.outbox]
        for m in self.system.atlas.maps:
            waiting = [k for k in list(self.unacked) + held if k in m.keyframes]
            if self.provisional is not None and self.provisional.count(m) > 0:
                m = self.provisional.without(m)  # a copy: undo below does not touch the replica
            elif waiting:
                m = copy.deepcopy(m)
            if waiting:
                for k in sorted(waiting, reverse=True):  # newest first: undo the replica insertions
                    kf = m.keyframes.pop(k)
                    for pid in kf.point_ids[kf.point_ids >= 0].tolist():
                        m.points.observations[pid].pop(k, None)
                    m.covisibility.pop(k, None)
                    m.children.pop(k, None)
                    if m.origin_kf_id == k:
                        m.origin_kf_id = -1
            if m.keyframes:
                out.append((list(m.keyframes.values()), full_delta(m)))
        return out

    def resend(self) -> list[KeyframePacket]:
        """The packets whose map update has not come, oldest first (after a snapshot, for a restarted owner)."""
        return [self.unacked[k] for k in sorted(self.unacked)]


@dataclass
class MapOwner:
    """Owns the metric map: applies keyframe packets, runs `LocalMapper` and the object layer (local_mapping).

    The object layer runs here: it needs the mapped keyframe's points (before loop closing, as in `SlamSystem`),
    the keyframe's depth and the dynamic stage's objects, which the keyframe packet carries. Loop closing
    corrects its own replica first (`SlamMapLoopClosing.process`), and the owner applies that delta exactly when
    it has mapped nothing since (lossless mode); otherwise (real time: keyframes mapped while the loop was
    verified) it applies the correction itself (`core.slam.loop_closing.apply_correction`: poses, point
    positions, fusion) to its newer map. Either way the owner's delta of that step reaches every replica.
    """

    backend: Backend
    mapper: LocalMapper
    last_kf_id: int = -1
    timings_ms: dict[str, list[float]] = field(default_factory=lambda: {"mapping": [], "objects": [], "diff": []})
    last_objects: Any | None = None
    merges: list[Any] = field(default_factory=list)  # core.map_merging.MergeResult, in order
    log: MergeLog = field(default_factory=MergeLog)  # to move packets that name a merged-away map (real time)
    n_loops_dropped: int = 0  # closed loops on a map merged away before their verdict came (real time)

    @staticmethod
    def build(cfg: BackendConfig, objects: str = "config") -> MapOwner:
        backend = build_backend(cfg, loop=False, dynamic="off", objects=objects)
        return MapOwner(backend, backend.system.mapper)

    @property
    def atlas(self) -> Atlas:
        return self.backend.system.atlas

    def start_from_map(self, loaded: LoadedMap) -> None:
        """Multi-session: the map and, with the object layer on, the saved objects (decayed beliefs, point flags)."""
        self.backend.system.start_from_map(loaded.atlas, loaded.next_keyframe_id, loaded.objects)

    def on_keyframe(self, packet: KeyframePacket) -> MapUpdate:
        """Map one keyframe; returns the update for the replicas. A packet tracking made before a merge this
        owner applied (real time) is first expressed in the merged map (`MergeLog.resolve`)."""
        self.log.resolve(packet)
        kf = packet.keyframe
        m = ensure_map(self.atlas, kf.map_id)
        check_keyframe(m, kf)
        self.atlas.current = m
        apply_counters(m.points, packet.counters)
        for map_id, counters in packet.other_counters.items():  # tracking's increments in other maps
            if map_id != m.id:
                apply_counters(ensure_map(self.atlas, map_id).points, counters)  # keeps the current map
        before = snapshot(m)
        t0 = time.perf_counter()
        stats = self.mapper.process(kf)
        t1 = time.perf_counter()
        active_changed, ran = False, False
        layer = self.backend.objects
        self.last_objects = None
        if layer is not None and kf.id in m.keyframes:
            res = self.last_objects = layer.after_keyframe(kf, m, packet.depth_m, packet.objects)
            active_changed, ran = bool(res.active_flags_changed), True
        if kf.id in m.keyframes and self.backend.system.keep_grid_scans:
            self.backend.system.keep_grid_scan(m.keyframes[kf.id], packet.depth_m, packet.objects, self.last_objects)
        t2 = time.perf_counter()
        delta = diff(before, m)
        t3 = time.perf_counter()
        self.timings_ms["mapping"].append((t1 - t0) * 1e3)
        self.timings_ms["objects"].append((t2 - t1) * 1e3)
        self.timings_ms["diff"].append((t3 - t2) * 1e3)
        self.last_kf_id = kf.id
        culled = np.asarray(stats.culled_keyframes, np.int64)
        return MapUpdate(kf.id, delta, culled, active_changed, ran)

    def restore(self, keyframes: list[Keyframe], delta: MapDelta) -> None:
        """After a restart: the map rebuilt from tracking's replica (recent-point culling starts afresh)."""
        m = restore(self.atlas, keyframes, delta)
        self.atlas.current = m
        self.last_kf_id = max(m.keyframes, default=self.last_kf_id)

    def on_loop(self, result: LoopResult) -> MapUpdate | None:
        """Apply a closed loop; returns the delta of doing so for the replicas (None when nothing to apply)."""
        if result.merge is not None:
            return self.on_merge(result.merge)
        if not result.closed or result.delta is None:
            return None
        if result.delta.map_id in self.atlas.merged_into:  # real time: found on a map merged away meanwhile
            self.n_loops_dropped += 1
            return None
        m = ensure_map(self.atlas, result.delta.map_id)
        before = snapshot(m)
        if result.query_kf_id == self.last_kf_id:
            apply_delta(self.atlas, result.delta)  # the loop side corrected the very map we hold
        elif result.correction is not None:  # keyframes were mapped meanwhile: correct our newer map
            from changing_slam_ros.core.slam.loop_closing import apply_correction

            corr = result.correction
            if not corr.pose_corrections:  # from a message: T_new @ T_old^-1 against our own poses
                corr = dataclasses.replace(corr, pose_corrections={
                    k: T @ np.linalg.inv(m.keyframes[k].T_world_cam) for k, T in corr.corrected_poses.items()
                    if k in m.keyframes})  # fmt: skip
            apply_correction(m, corr)
        else:
            raise ReplicationError(f"loop result for keyframe {result.query_kf_id}: stale and without a correction")
        return MapUpdate(-1, diff(before, m), loop_query_kf_id=result.query_kf_id)


    def on_merge(self, merge: Any) -> MapUpdate | None:
        """Apply a map merge loop closing found (`core.loop_closing.MapMerge`) as `SlamSystem` does offline
        (`SlamSystem.apply_merge`: `merge_maps`, local mapping's recent points); returns the update that carries
        the whole merged map to the replicas (None when the merge no longer fits this map: a map already merged
        away or a seam keyframe culled meanwhile, possible in real time)."""
        atlas = self.atlas
        if (merge.query_map_id in atlas.merged_into or merge.match_map_id in atlas.merged_into
                or merge.query_map_id >= len(atlas.maps) or merge.match_map_id >= len(atlas.maps)
                or merge.query_kf_id not in atlas.maps[merge.query_map_id].keyframes
                or merge.match_kf_id not in atlas.maps[merge.match_map_id].keyframes):  # fmt: skip
            return None
        result = self.backend.system.apply_merge(merge)
        self.merges.append(result)
        self.log.record(result)
        self.last_kf_id = -1  # a loop verdict computed before the merge is no delta of this map any more
        light = dataclasses.replace(result, ba=None)
        return MapUpdate(-1, full_delta(atlas.maps[result.into_map_id]), loop_query_kf_id=merge.query_kf_id, merge=light)


@dataclass
class LoopSide:
    """Keyframe database, verification and pose graph on a replica of the map (loop_closing node)."""

    closing: Any  # core.loop_closing.SlamMapLoopClosing
    merge_enabled: bool = True  # the config's mapping.merge.enabled: look for places of other maps (Atlas)
    atlas: Atlas = field(default_factory=Atlas)
    pending: dict[int, Keyframe] = field(default_factory=dict)
    n_loops: int = 0
    log: MergeLog = field(default_factory=MergeLog)  # merges taken, to move packets made before them
    n_moved_keyframes: int = 0  # keyframes without their update yet when a merge came, moved into the merged map
    timings_ms: list[float] = field(default_factory=list)

    @staticmethod
    def build(cfg: BackendConfig) -> LoopSide | None:
        """None when the config's loop section is disabled."""
        backend = build_backend(cfg, loop=True, dynamic="off", objects="off")
        if backend.loop_closing is None:
            return None
        return LoopSide(backend.loop_closing, backend.system.config.mapping.merge.enabled)

    def start_from_map(self, loaded: LoadedMap, layer: ObjectLayer | None) -> None:
        """Multi-session: the replica becomes the loaded Atlas (point flags as the owner sets them, `layer` a
        scratch object layer or None) and every loaded keyframe goes into the database, as offline."""
        replica_point_flags(layer, loaded)
        self.atlas.adopt(loaded.atlas)
        for m in self.atlas.maps:
            for k in sorted(m.keyframes):
                self.closing.add(m.keyframes[k])
            self.closing.refresh_active_points(m)

    def restore(self, keyframes: list[Keyframe], delta: MapDelta) -> None:
        """After a restart: the replica rebuilt from tracking's, every keyframe indexed again."""
        m = restore(self.atlas, keyframes, delta)
        self.atlas.current = m
        for k in sorted(m.keyframes):
            self.closing.add(m.keyframes[k])
        self.closing.refresh_active_points(m)

    def knows(self, kf_id: int) -> bool:
        """The keyframe is in the replica already (restored) and was not sent to it as a packet."""
        return any(kf_id in m.keyframes or kf_id in m.removed for m in self.atlas.maps) and kf_id not in self.pending

    def on_keyframe(self, packet: KeyframePacket) -> None:
        kf = packet.keyframe
        if self.knows(kf.id) or kf.id in self.pending:
            return  # in the map restored from tracking's replica, or sent again after a restart
        self.log.resolve(packet)  # made before a merge this replica took (real time): into the merged map
        insert_keyframe(self.atlas, kf)
        self.pending[kf.id] = kf

    def on_update(self, update: MapUpdate) -> LoopResult | None:
        """Apply the owner's delta; for a mapped keyframe, run loop closing on it (as `SlamSystem` does after
        local mapping and the object layer) and return the verdict."""
        if update.merge is not None:  # the owner merged two maps: take the merged map, the database follows
            self._apply_merge(update)
            return None
        restored = update.keyframe_id >= 0 and self.knows(update.keyframe_id)
        m = apply_delta(self.atlas, update.delta)
        if update.keyframe_id < 0 or restored:
            return None
        kf = self.pending.pop(update.keyframe_id, None)
        if kf is None:
            raise ReplicationError(f"loop_closing: map update for keyframe {update.keyframe_id} before its keyframe")
        for k in update.culled_keyframes.tolist():
            self.closing.erase(k)
        self.closing.add(kf)
        if update.active_flags_changed:
            self.closing.refresh_active_points(m)
        if kf.id not in m.keyframes:
            return LoopResult(kf.id, False)
        return self._close(kf, m)

    def decide_restored(self, kf_id: int) -> LoopResult:
        """The verdict on a keyframe that came in a restore instead of through its update: `restore` put it in the
        database as its update would have, so loop closing runs on it as `on_update` would."""
        for m in self.atlas.maps:
            if kf_id in m.keyframes:
                return self._close(m.keyframes[kf_id], m)
        return LoopResult(kf_id, False)  # culled since: answered as `on_update` answers one

    def _apply_merge(self, update: MapUpdate) -> None:
        """The owner's merged map; keyframes inserted here whose update has not come (real time: the owner maps
        their late packets in the merged map, moved the same way) go into it again, expressed in it."""
        r = update.merge
        late = [kf for mm in (ensure_map(self.atlas, r.from_map_id), ensure_map(self.atlas, r.into_map_id))
                for k, kf in mm.keyframes.items() if k in self.pending]  # fmt: skip
        m = apply_merge(self.atlas, r.from_map_id, update.delta)
        for kf in sorted(late, key=lambda kf: kf.id):
            if kf.map_id == r.from_map_id:
                move_keyframe(kf, r)
            check_keyframe(m, kf)
            m.add_keyframe(kf)
        self.n_moved_keyframes += len(late)
        self.log.record(r)
        self.closing.maps_merged(r.moved_keyframes, r.into_map_id)

    def _close(self, kf: Keyframe, m: SlamMap) -> LoopResult:
        t0 = time.perf_counter()
        correction = self.closing.find_loop(kf, m)  # leaves the map as it is
        closed = correction is not None
        if closed:
            before = snapshot(m)  # only when there is a delta to send (a snapshot walks every point)
            self.closing.apply_loop(m, correction)
        merge = None
        if not closed and self.merge_enabled and len(self.atlas.live_maps()) > 1 and kf.id in self.atlas.current.keyframes:
            merge = self.closing.detect_merge_in(kf, self.atlas)  # as `SlamSystem._try_merge` offline
        self.timings_ms.append((time.perf_counter() - t0) * 1e3)
        if not closed:
            return LoopResult(kf.id, False, merge=merge)
        self.n_loops += 1
        return LoopResult(kf.id, True, diff(before, m), self.closing.last_correction)
