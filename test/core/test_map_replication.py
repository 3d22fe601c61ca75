"""Map replication: replicas fed only by keyframe packets and map updates equal the owner's map."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from helpers import FR1_XYZ_10, REDKITCHEN, require

from changing_slam_ros.core.map_replication import (
    CounterTracker,
    ReplicationError,
    apply_counters,
    apply_delta,
    diff,
    insert_keyframe,
    snapshot,
)
from changing_slam_ros.core.slam_map import Atlas, SlamMap
from changing_slam_ros.core.system import SlamSystem
from changing_slam_ros.core.tracking import TrackingState
from changing_slam_ros.io.dataset import open_dataset
from changing_slam_ros.nodes.slam_backend import build_backend, load_backend_config
from changing_slam_ros.nodes.split_backend import ChainedGraph


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
    np.testing.assert_allclose(b.points.positions[:n], a.points.positions[:n], atol=1e-9, rtol=0)
    np.testing.assert_array_equal(b.points.bad[:n], a.points.bad[:n])
    np.testing.assert_array_equal(b.points.active[:n], a.points.active[:n])
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
