"""The LoadMap marker protocol (`nodes/map_load.py`): markers round-trip through their messages, and a node
drops exactly the messages of a stream made before that stream's sender loaded, in the orders real time gives."""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.ros

pytest.importorskip("rclpy")
pytest.importorskip("changing_slam_msgs.msg", reason="interfaces not built (tools/build_interfaces.sh)")

from changing_slam_msgs.msg import Keyframe as KeyframeMsg  # noqa: E402
from changing_slam_msgs.msg import MapUpdate  # noqa: E402
from changing_slam_ros.nodes.map_load import (  # noqa: E402
    LoadEpochs,
    LoadMarker,
    keyframe_marker,
    loop_marker,
    marker_of,
    update_marker,
)

LOAD = LoadMarker(1_795_000_000_123_456_789, "/maps/first/map.npz")


def test_markers_round_trip_through_the_three_message_types():
    update, keyframe, loop = update_marker(LOAD), keyframe_marker(LOAD), loop_marker(LOAD)
    assert marker_of(update, update.keyframe_id) == LOAD
    assert marker_of(keyframe, keyframe.id) == LOAD
    assert marker_of(loop, loop.query_keyframe_id) == LOAD
    # Ordinary messages, a loop relay (-1) and an empty snapshot (-2) are no markers.
    for kf_id in (0, 17, -1, -2):
        assert marker_of(MapUpdate(keyframe_id=kf_id), kf_id) is None
    assert marker_of(KeyframeMsg(id=5), 5) is None


def test_the_owner_drops_packets_until_trackings_marker_then_takes_them():
    """Owner: loads (adopts), packets tracking sent before it loaded keep arriving, then its marker, then new."""
    owner = LoadEpochs.of("keyframes", "loops")
    assert owner.current("keyframes")  # no load yet: everything counts
    owner.adopt(LOAD)
    assert [owner.current("keyframes") for _ in range(3)] == [False] * 3  # in flight from the old map
    assert not owner.on_marker("keyframes", LOAD)  # the owner's own load: no reset
    assert owner.current("keyframes") and not owner.current("loops")  # loop closing has not loaded yet
    assert owner.dropped == 4


def test_a_replica_resets_on_the_first_marker_of_a_newer_load_whichever_stream_brings_it():
    """loop_closing: tracking's marker may come before the owner's; the first one resets, both gate their stream."""
    loop = LoadEpochs.of("keyframes", "updates")
    assert loop.on_marker("keyframes", LOAD)  # tracking's marker first: reset now
    loop.adopt(LOAD)
    assert loop.current("keyframes") and not loop.current("updates")  # updates of the old owner still to come
    assert not loop.on_marker("updates", LOAD)  # the owner's marker of the same load: no second reset
    assert loop.current("updates") and loop.path == LOAD.path


def test_an_older_marker_never_resets_and_a_later_load_resets_again():
    node = LoadEpochs.of("updates")
    node.adopt(LOAD)
    older = LoadMarker(LOAD.epoch_ns - 5, "/maps/old.npz")
    assert not node.on_marker("updates", older) and not node.current("updates")
    later = LoadMarker(LOAD.epoch_ns + 5, "/maps/second.npz")
    assert node.on_marker("updates", later)
    node.adopt(later)
    assert node.current("updates") and node.path == later.path


def test_a_node_started_after_a_load_takes_every_message_until_the_next_load():
    """A restarted node saw no marker: epoch 0 and streams 0 agree, so its senders' messages count."""
    restarted = LoadEpochs.of("keyframes", "loops")
    assert all(restarted.current(s) for s in ("keyframes", "loops")) and restarted.dropped == 0
