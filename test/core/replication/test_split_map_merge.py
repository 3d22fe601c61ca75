"""Map merging in the split graph (tracking / map owner / loop closing as separate sides, lossless order):
loop closing finds the merge on its replica, the map owner applies it, the replicas take the merged map, and
the trajectory is the offline runner's."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from helpers import REDKITCHEN, require

from changing_slam_ros.core.replication.map_replication import ReplicationError, apply_merge, full_delta
from changing_slam_ros.core.map.slam_map import Atlas, SlamMap
from changing_slam_ros.nodes.slam_backend import BackendConfig, build_backend, load_backend_config
from changing_slam_ros.nodes.split_chains import ChainedGraph


def _lost_and_revisit_config() -> BackendConfig:
    cfg = load_backend_config("7scenes")
    data = copy.deepcopy(cfg.data)
    data.setdefault("tracking", {})["lost_frames_new_map"] = 5
    return BackendConfig(data, cfg.where + " (tracking.lost_frames_new_map 5)")


def _kitchen_frames():
    """7-Scenes redkitchen frames 0-319, then a jump to 400-699 (as test_map_merging's slow test): tracking is
    lost, a new map starts, and the camera later revisits what the first map holds."""
    from changing_slam_ros.io.dataset import open_dataset

    source = open_dataset(require(REDKITCHEN), "7scenes")
    frames = []
    for i, frame in enumerate(source):
        if i >= 700:
            break
        if i < 320 or i >= 400:
            frames.append(frame)
    return source, frames


def _assert_same_map(a: SlamMap, b: SlamMap, atol: float = 0.0) -> None:
    """Same keyframes, graph and points; poses and positions within `atol` (0: bit for bit)."""
    assert list(a.keyframes) == list(b.keyframes)  # same ids in the same order
    for k, kf in a.keyframes.items():
        np.testing.assert_allclose(b.keyframes[k].T_world_cam, kf.T_world_cam, rtol=0.0, atol=atol)
        np.testing.assert_array_equal(b.keyframes[k].point_ids, kf.point_ids)
        assert b.covisibility[k] == a.covisibility[k] and b.parent.get(k) == a.parent.get(k)
        assert b.keyframes[k].map_id == a.id
    n = a.points.size
    assert b.points.size == n
    np.testing.assert_allclose(b.points.column_arrays()["positions"], a.points.column_arrays()["positions"], rtol=0.0,
                               atol=atol)
    np.testing.assert_array_equal(b.points.column_arrays()["bad"], a.points.column_arrays()["bad"])


@pytest.mark.slow
def test_split_graph_applies_the_merge_and_matches_the_offline_runner() -> None:
    from changing_slam_ros.eval.ate import ate

    cfg = _lost_and_revisit_config()
    source, frames = _kitchen_frames()
    chained = ChainedGraph.build(cfg)
    offline = build_backend(cfg).system
    for rgbd in frames:
        chained.process(rgbd)
        offline.process(rgbd)
    tracking = chained.tracking.system
    # A second map was started, and merged back, on every side.
    assert len(offline.merges) == 1 and len(tracking.atlas.maps) == 2
    assert len(chained.owner.merges) == 1 and chained.tracking.n_merges == 1 and len(tracking.merges) == 1
    assert chained.owner.merges[0].from_map_id == offline.merges[0].from_map_id == 1
    for atlas in (chained.owner.atlas, tracking.atlas, chained.loop.atlas):
        assert [m.id for m in atlas.live_maps()] == [0] and atlas.merged_into == {1: 0}
    assert {r.map_id for r in tracking.records} == {0}
    # The replicas hold the owner's map bit for bit, which is the offline map up to rounding (the two processes'
    # arrays may sum in another order on CPUs with wider vector units); the trajectory is the offline one.
    _assert_same_map(offline.atlas.maps[0], chained.owner.atlas.maps[0], atol=1e-12)
    _assert_same_map(chained.owner.atlas.maps[0], tracking.atlas.maps[0])
    _assert_same_map(chained.owner.atlas.maps[0], chained.loop.atlas.maps[0])
    a, b = tracking.final_trajectory(), offline.final_trajectory()
    np.testing.assert_array_equal(a.stamps_s, b.stamps_s)
    np.testing.assert_allclose(np.array(a.poses()), np.array(b.poses()), rtol=0.0, atol=1e-12)
    assert len(a) >= 610
    rmse = ate(source.groundtruth, a).stats.rmse
    assert rmse < 0.06, rmse  # one alignment over both maps' frames; two unrelated maps give ~0.3 m


def _map_with(map_id: int, kf_ids: list[int]) -> tuple[SlamMap, list]:
    from changing_slam_ros.core.geometry.camera import CameraIntrinsics
    from changing_slam_ros.core.map.keyframe import Keyframe

    cam = CameraIntrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)
    m = SlamMap(map_id)
    kfs = []
    for k in kf_ids:
        kf = Keyframe(k, k, np.eye(4), cam, np.zeros((2, 2), np.float32), np.zeros(2, np.int8),
                      np.zeros((2, 32), np.uint8), np.ones(2, np.float32), np.full(2, -1, np.int64))
        m.add_keyframe(kf)
        kfs.append(kf)
    return m, kfs


def test_apply_merge_moves_the_replica_keyframes_into_the_merged_map() -> None:
    """A replica with maps 0 (keyframes 0, 1) and 1 (keyframes 5, 6) takes the owner's merged map 0."""
    owner = Atlas()
    owner.maps[0], _ = _map_with(0, [0, 1, 5, 6])
    owner.maps.append(SlamMap(1))
    T = np.eye(4)
    T[:3, 3] = [1.0, 2.0, 3.0]
    for k in (5, 6):
        owner.maps[0].keyframes[k].T_world_cam = T.copy()
    delta = full_delta(owner.maps[0])

    replica = Atlas()
    replica.maps[0], kfs0 = _map_with(0, [0, 1])
    m1 = replica.new_map()
    replica.maps[1], kfs1 = _map_with(1, [5, 6])
    assert m1 is not replica.maps[1] and replica.current is m1
    merged = apply_merge(replica, 1, delta)
    assert replica.current is merged and replica.maps[0] is merged
    assert list(merged.keyframes) == [0, 1, 5, 6] and not replica.maps[1].keyframes
    assert replica.merged_into == {1: 0} and replica.resolve(1) is merged
    assert merged.keyframes[5] is kfs1[0] and kfs1[0].map_id == 0  # the same Keyframe objects, moved
    np.testing.assert_array_equal(kfs1[1].T_world_cam, T)
    with pytest.raises(ReplicationError, match="into itself"):
        apply_merge(replica, 0, delta)
    with pytest.raises(ReplicationError, match="missing"):  # the owner's map names a keyframe the replica lacks
        apply_merge(Atlas(), 1, delta)

