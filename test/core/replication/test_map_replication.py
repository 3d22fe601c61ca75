"""Map replication: replicas fed only by keyframe packets and map updates equal the owner's map."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from helpers import FR1_XYZ_10, REDKITCHEN, require

from changing_slam_ros.core.replication.map_replication import (
    CounterTracker,
    KeyframePacket,
    ReplicationError,
    apply_counters,
    apply_delta,
    diff,
    insert_keyframe,
    snapshot,
)
from changing_slam_ros.core.map.slam_map import Atlas, SlamMap
from changing_slam_ros.core.system import SlamSystem
from changing_slam_ros.core.slam.tracking import TrackingState
from changing_slam_ros.io.dataset import open_dataset
from changing_slam_ros.nodes.slam_backend import build_backend, load_backend_config
from changing_slam_ros.nodes.split_chains import ChainedGraph


def _assert_maps_equal(a: SlamMap, b: SlamMap) -> None:
    assert sorted(a.keyframes) == sorted(b.keyframes)
    for k, kf in a.keyframes.items():
        np.testing.assert_allclose(b.keyframes[k].T_world_cam, kf.T_world_cam, atol=1e-9, rtol=0)
        np.testing.assert_array_equal(b.keyframes[k].point_ids, kf.point_ids)
        assert a.covisibility[k] == b.covisibility[k]
        assert a.parent.get(k) == b.parent.get(k)
    assert sorted(a.removed) == sorted(b.removed)
    n = a.points.size
    assert b.points.size == n
    # By id; a culled point reads as gone in both, whether or not its store has compacted its row yet.
    ca, cb = a.points.column_arrays(), b.points.column_arrays()
    np.testing.assert_allclose(cb["positions"], ca["positions"], atol=1e-9, rtol=0)
    np.testing.assert_array_equal(cb["bad"], ca["bad"])
    np.testing.assert_array_equal(cb["active"], ca["active"])
    assert [list(o.items()) for o in b.points.observations[:n]] == [list(o.items()) for o in a.points.observations[:n]]


@pytest.fixture(scope="module")
def kitchen_chained():
    """7-Scenes redkitchen, first 60 frames, through the split sides (lossless order) and the offline system."""
    source = open_dataset(require(REDKITCHEN), "7scenes")
    cfg = load_backend_config("7scenes")
    chained = ChainedGraph.build(cfg)
    offline = build_backend(cfg).system
    outs = []
    for i, rgbd in enumerate(source):
        if i >= 60:
            break
        outs.append(chained.process(rgbd))
        offline.process(rgbd)
    return chained, offline, outs


def test_kitchen_replicas_equal_the_owner_map_to_1e9(kitchen_chained) -> None:
    chained, _, outs = kitchen_chained
    assert sum(o.keyframe is not None for o in outs) >= 2  # the window actually moved keyframes
    owner = chained.owner.atlas.current
    assert owner.points.size > 500
    _assert_maps_equal(owner, chained.tracking.system.atlas.current)
    assert chained.loop is not None
    _assert_maps_equal(owner, chained.loop.atlas.current)


def test_kitchen_split_trajectory_is_the_offline_trajectory(kitchen_chained) -> None:
    chained, offline, outs = kitchen_chained
    assert all(o.state == TrackingState.OK for o in outs)
    a, b = chained.tracking.system.final_trajectory(), offline.final_trajectory()
    np.testing.assert_array_equal(a.stamps_s, b.stamps_s)
    np.testing.assert_allclose(np.array(a.poses()), np.array(b.poses()), atol=1e-12, rtol=0)
    _assert_maps_equal(offline.atlas.current, chained.owner.atlas.current)


def test_local_ba_moves_keyframes_and_the_update_carries_them() -> None:
    """One mapped keyframe after two: the delta names the moved keyframe poses and the new points."""
    source = open_dataset(require(REDKITCHEN), "7scenes")
    system = SlamSystem()
    replica = Atlas()
    mapper = system.mapper
    system.mapper = _Capture(mapper, replica)  # type: ignore[assignment]
    for i, rgbd in enumerate(source):
        if i >= 40:
            break
        system.process(rgbd)
    deltas = system.mapper.deltas
    assert len(deltas) >= 2
    later = deltas[-1]
    assert len(later.points) > 0 and later.n_points == system.atlas.current.points.size
    assert len(later.keyframes) >= 2  # the new keyframe and at least one moved or relinked neighbour
    _assert_maps_equal(system.atlas.current, replica.current)


class _Capture:
    """Wraps the offline mapper: diffs around each call and feeds a replica with copies of keyframe and delta."""

    def __init__(self, mapper, replica: Atlas) -> None:  # noqa: ANN001
        self.mapper, self.replica, self.deltas = mapper, replica, []

    def process(self, kf):  # noqa: ANN001, ANN201
        m = self.mapper.map
        before = snapshot(m)
        sent = copy.deepcopy(kf)  # as tracking made it: the packet
        stats = self.mapper.process(kf)
        delta = diff(before, m)
        self.deltas.append(delta)
        insert_keyframe(self.replica, sent)
        apply_delta(self.replica, copy.deepcopy(delta))
        return stats


def test_update_for_a_keyframe_the_replica_never_got_is_rejected() -> None:
    owner = Atlas()
    source = open_dataset(require(FR1_XYZ_10), "tum_fr1")
    system = SlamSystem()
    cap = _Capture(system.mapper, Atlas())
    system.mapper = cap  # type: ignore[assignment]
    for i, rgbd in enumerate(source):
        system.process(rgbd)
        if i >= 2:
            break
    with pytest.raises(ReplicationError, match="keyframe 0 is not in the replica"):
        apply_delta(owner, cap.deltas[0])


def test_counter_increments_survive_an_update_and_reach_the_owner() -> None:
    m = SlamMap(0)
    pts = m.points
    pts.add(np.zeros((4, 3)) + 1.0, np.zeros((4, 32), np.uint8), 0, np.arange(4), np.zeros(3), np.zeros(4, np.int64),
            np.ones(8))  # fmt: skip
    owner = copy.deepcopy(m)
    replica = Atlas()
    replica.maps[0] = copy.deepcopy(m)
    replica.current = replica.maps[0]
    ct = CounterTracker()
    ct.take(replica.current)
    replica.current.points.n_visible[[1, 2]] += 3
    replica.current.points.n_found[2] += 1
    sent = ct.take(replica.current)
    assert sent.ids.tolist() == [1, 2] and sent.n_visible.tolist() == [3, 3] and sent.n_found.tolist() == [0, 1]
    replica.current.points.n_visible[2] += 5  # tracking goes on before the owner's update arrives
    apply_counters(owner.points, sent)
    before = snapshot(owner)
    owner.points.positions[2] += 0.5  # the owner's BA moves point 2
    ct.apply_keeping_increments(replica, diff(before, owner))
    assert replica.current.points.n_visible[2] == 1 + 3 + 5
    np.testing.assert_allclose(replica.current.points.positions[2], owner.points.positions[2])
    assert ct.take(replica.current).n_visible.tolist() == [5]


# -- loops: the drifting room of test_loop_closing.py (ground truth; a loop a turn after the start) -----------
def drifting_room_steps(n_kf: int = 58, n_per_turn: int = 48):
    """Yield (packet keyframe copy, owner step) per keyframe of a drifting owner that re-uses points of its last 3
    keyframes only; the step, called with the owner's map, maps the keyframe and returns the MapUpdate."""
    from core.slam.test_loop_closing import SyntheticRoom, _rot_y

    from changing_slam_ros.core.replication.map_replication import MapUpdate
    from changing_slam_ros.core.features.orb_features import FeatureConfig
    from changing_slam_ros.core.geometry.se3 import invert, make_pose

    room, scales = SyntheticRoom(seed=1), FeatureConfig().level_scales()
    last_seen: dict[int, tuple[int, int]] = {}
    truth: dict[int, np.ndarray] = {}
    for k in range(n_kf):
        truth[k] = room.pose(k, n_per_turn)

        def step(m: SlamMap, k=k):  # noqa: ANN202 - a closure per keyframe
            rel = invert(truth[k - 1]) @ truth[k] if k else np.eye(4)
            online = truth[0].copy() if k == 0 else \
                m.keyframes[k - 1].T_world_cam @ make_pose(_rot_y(np.radians(1.0)) @ rel[:3, :3], rel[:3, 3])  # fmt: skip
            kf, seen = room.keyframe(k, truth[k], online)
            sent = copy.deepcopy(kf)
            before = snapshot(m)
            m.add_keyframe(kf)
            rows = []
            for row, w in enumerate(seen.tolist()):
                known = last_seen.get(w)
                if known is not None and k - known[1] <= 3 and not m.points.bad[known[0]]:
                    m.add_observation(known[0], k, row)
                    last_seen[w] = (known[0], k)
                else:
                    rows.append(row)
            r = np.array(rows, np.int64)
            pc = kf.camera.backproject(kf.keypoints_px[r].astype(np.float64), kf.depths_m[r].astype(np.float64))
            ids = m.points.add(pc @ online[:3, :3].T + online[:3, 3], kf.descriptors[r], k, r, online[:3, 3],
                               np.zeros(len(r), np.int64), scales)  # fmt: skip
            kf.point_ids[r] = ids
            for pid, row in zip(ids.tolist(), r.tolist(), strict=True):
                last_seen[int(seen[row])] = (pid, k)
            m.update_connections(k)
            return sent, MapUpdate(k, diff(before, m))

        yield k, truth, step


def _owner(atlas: Atlas, last_kf_id: int):  # noqa: ANN202
    """A MapOwner whose map is `atlas` (its mapper is not used by `on_loop`)."""
    from types import SimpleNamespace

    from changing_slam_ros.nodes.split_backend import MapOwner

    return MapOwner(SimpleNamespace(system=SimpleNamespace(atlas=atlas)), None, last_kf_id)  # type: ignore[arg-type]


@pytest.mark.parametrize("stale", [False, True])
def test_a_loop_closed_on_the_replica_reaches_owner_and_tracking(stale: bool) -> None:
    """Loop closing corrects its replica; the owner applies the result (exactly, or as a correction when it
    mapped meanwhile) and its delta brings tracking's replica to the owner's map; the drift is corrected."""
    from changing_slam_ros.core.slam.loop_closing import LoopCloser, LoopConfig, SlamMapLoopClosing
    from changing_slam_ros.core.features.vocabulary import Vocabulary
    from changing_slam_ros.nodes.split_backend import LoopSide

    owner_atlas, tracking = Atlas(), Atlas()
    loop = LoopSide(SlamMapLoopClosing(LoopCloser(LoopConfig(), Vocabulary.load())))
    closed = None
    for k, truth, step in drifting_room_steps():
        sent, update = step(owner_atlas.current)
        loop.on_keyframe(copy.deepcopy(KeyframePacket(sent)))
        insert_keyframe(tracking, copy.deepcopy(sent))
        apply_delta(tracking, copy.deepcopy(update.delta))
        result = loop.on_update(copy.deepcopy(update))
        if result is not None and result.closed:
            closed = result
            break
    assert closed is not None and closed.query_kf_id >= 45 and closed.correction.match_kf_id < 5
    owner = _owner(owner_atlas, closed.query_kf_id + (1 if stale else 0))
    relay = owner.on_loop(copy.deepcopy(closed))
    assert relay is not None and relay.loop_query_kf_id == closed.query_kf_id and len(relay.delta.keyframes) > 40
    apply_delta(tracking, copy.deepcopy(relay.delta))
    m, t, r = owner_atlas.current, tracking.current, loop.atlas.current
    _assert_maps_equal(m, t)  # tracking follows the owner, whichever way the owner applied it
    if not stale:
        _assert_maps_equal(m, r)  # exact: the owner's map is loop closing's corrected replica
    q = closed.query_kf_id
    T_new = closed.correction.corrected_poses[q]
    T_old = np.linalg.inv(closed.correction.pose_corrections[q]) @ T_new  # the drifted pose before the loop
    np.testing.assert_allclose(m.keyframes[q].T_world_cam, T_new, atol=1e-9)
    before, after = (float(np.linalg.norm(T[:3, 3] - truth[q][:3, 3])) for T in (T_old, m.keyframes[q].T_world_cam))
    assert after < 0.25 * before  # the query keyframe's drift corrected in the owner's map
    for dup, keep in closed.correction.fused_points[:50]:
        assert m.points.bad[dup] and not m.points.bad[keep]


def test_a_map_owner_restarted_empty_is_restored_from_tracking_and_maps_what_it_missed() -> None:
    """7-Scenes redkitchen: the owner dies after 30 frames; tracking goes on and sends a keyframe nobody maps. A
    new owner restored from tracking's snapshot has the old owner's map exactly, then maps the re-sent keyframe,
    and tracking's replica follows it."""
    from changing_slam_ros.nodes.split_backend import MapOwner
    from changing_slam_ros.nodes.split_chains import copy_packet

    source = open_dataset(require(REDKITCHEN), "7scenes")
    cfg = load_backend_config("7scenes")
    chained = ChainedGraph.build(cfg, loop=False, objects="off")
    frames = iter(source)
    for _ in range(30):
        chained.process(next(frames))
    old_owner = chained.owner.atlas.current
    lost = None
    for rgbd in frames:  # the owner is down: packets go nowhere
        _, lost = chained.tracking.process(rgbd)
        if lost is not None:
            break
    assert lost is not None and list(chained.tracking.unacked) == [lost.keyframe.id]
    (kfs, delta), = chained.tracking.snapshot()
    assert lost.keyframe.id not in delta.keyframes.ids.tolist()
    owner = MapOwner.build(cfg, objects="off")
    owner.restore(copy.deepcopy(kfs), copy.deepcopy(delta))
    _assert_maps_equal(old_owner, owner.atlas.current)  # the map as the old owner left it
    resent = chained.tracking.resend()
    assert [p.keyframe.id for p in resent] == [lost.keyframe.id]
    update = owner.on_keyframe(copy_packet(resent[0]))
    assert len(update.delta.points) > 0 and lost.keyframe.id in owner.atlas.current.keyframes
    chained.tracking.apply_update(copy.deepcopy(update))
    assert not chained.tracking.unacked
    _assert_maps_equal(owner.atlas.current, chained.tracking.system.atlas.current)
