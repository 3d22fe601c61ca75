"""local_mapping in real time (no wait for loop verdicts) applies an Atlas merge and maps the keyframes of the
merged-away map that come after it, all through its messages.

The owner's work is taken from the in-process real-time chain (`DelayedChain`, owner updates 30 frames late) on
7-Scenes redkitchen 0-319 + 400-699 with `lost_frames_new_map` 5: the keyframe packets in the order the owner
mapped them, and loop closing's merge verdict where the owner took it. The node gets the same packets and the
verdict as messages, in that order, and must end with the chain owner's map."""

from __future__ import annotations

import copy

import numpy as np
import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]

pytest.importorskip("rclpy")
msgs = pytest.importorskip("changing_slam_msgs.msg", reason="interfaces not built (tools/build_interfaces.sh)")
if not hasattr(msgs, "MapDelta"):
    pytest.skip("interfaces older than msg_defs (run tools/build_interfaces.sh)", allow_module_level=True)

from rclpy.parameter import Parameter  # noqa: E402

from changing_slam_ros.nodes.local_mapping_node import LocalMappingNode  # noqa: E402
from changing_slam_ros.nodes.replication_conversions import (  # noqa: E402
    loop_result_to_msg,
    packet_to_msg,
    update_from_msg,
)
from helpers import REDKITCHEN, require  # noqa: E402

LAG = 30


@pytest.fixture(scope="module")
def owner_jobs():
    """The chain owner's jobs in order: ("packet", KeyframePacket as received) or ("verdict", LoopResult) for
    verdicts that change the map (a merge or a closed loop); and the chain itself after the run."""
    from changing_slam_ros.io.dataset import open_dataset
    from changing_slam_ros.nodes.slam_backend import BackendConfig, load_backend_config
    from changing_slam_ros.nodes.split_chains import DelayedChain

    base = load_backend_config("7scenes")
    data = copy.deepcopy(base.data)
    data.setdefault("tracking", {})["lost_frames_new_map"] = 5
    chain = DelayedChain.build(BackendConfig(data, base.where), LAG, provisional=True, dynamic="off", objects="off",
                               loop=True)  # fmt: skip
    jobs: list[tuple[str, object]] = []
    on_keyframe, on_loop = chain.owner.on_keyframe, chain.owner.on_loop

    def keyframe_spy(packet):  # noqa: ANN001, ANN202
        jobs.append(("packet", copy.deepcopy(packet)))
        return on_keyframe(packet)

    def loop_spy(result):  # noqa: ANN001, ANN202
        if result.merge is not None or result.closed:
            jobs.append(("verdict", copy.deepcopy(result)))
        return on_loop(result)

    chain.owner.on_keyframe = keyframe_spy  # type: ignore[method-assign]
    chain.owner.on_loop = loop_spy  # type: ignore[method-assign]
    source = open_dataset(require(REDKITCHEN), "7scenes")
    for i, rgbd in enumerate(source):
        if i >= 700:
            break
        if i < 320 or i >= 400:
            chain.process(rgbd)
    chain.finish()
    return jobs, chain


def test_local_mapping_applies_a_merge_in_real_time_and_maps_late_keyframes_of_the_merged_away_map(
        ros_context, owner_jobs) -> None:  # fmt: skip
    jobs, chain = owner_jobs
    merge_at = next(i for i, (kind, job) in enumerate(jobs) if kind == "verdict" and job.merge is not None)
    late = [job for kind, job in jobs[merge_at:] if kind == "packet" and job.keyframe.map_id == 1]
    assert late, "the run has no packet of map 1 after the merge: nothing in flight to test"
    node = LocalMappingNode(context=ros_context, parameter_overrides=[
        Parameter("config", value="7scenes"), Parameter("objects", value="off"), Parameter("resync_timeout_s", value=0.0),
        Parameter("wait_for_loop_results", value=False), Parameter("ba_yields_to_keyframes", value=False)])  # fmt: skip
    published = []
    node.update_pub.publish = published.append
    try:
        for kind, job in jobs:
            if kind == "packet":
                node._enqueue(packet_to_msg(job, "map"))
                node.map_keyframe(node.queue.popleft())
            else:
                map_id = job.merge.query_map_id if job.merge is not None else job.delta.map_id
                node.on_loop_correction(loop_result_to_msg(job, 1, "map", map_id))
        stats = node.stats()
        assert stats["merges_applied"] == 1 and stats["merges_skipped"] == 0
        assert stats["keyframes_rejected"] == 0 and stats["keyframes_mapped"] == len(chain.sent)
        assert stats["late_keyframes_moved_by_merges"] == len(late)
        # The merge went out as one update with `merged` set, and every update after it is of map 0.
        updates = [update_from_msg(msg, "t") for msg in published]
        k = next(i for i, u in enumerate(updates) if u.merge is not None)
        assert updates[k].merge.from_map_id == 1 and updates[k].merge.into_map_id == 0
        assert {u.delta.map_id for u in updates[k:]} == {0}
        # The node's map is the chain owner's.
        atlas, want = node.owner.atlas, chain.owner.atlas.maps[0]
        assert [m.id for m in atlas.live_maps()] == [0] and atlas.merged_into == {1: 0}
        m = atlas.maps[0]
        assert list(m.keyframes) == list(want.keyframes)
        for kf_id, kf in want.keyframes.items():
            np.testing.assert_allclose(m.keyframes[kf_id].T_world_cam, kf.T_world_cam, atol=1e-9, rtol=0)
            np.testing.assert_array_equal(m.keyframes[kf_id].point_ids, kf.point_ids)
        n = want.points.size
        assert m.points.size == n
        np.testing.assert_allclose(m.points.column_arrays()["positions"], want.points.column_arrays()["positions"], atol=1e-9, rtol=0)
    finally:
        node.destroy_node()
