"""LoadMap in a running split graph: the owner loads a map file, tracking and loop closing follow, stale messages are dropped.

    local_mapping ~/load_map(path)  ->  owner loads the file (validated first; a bad file changes nothing)
      -> marker on /local_mapping/map_updates      (MapUpdate, keyframe_id LOAD_MARKER_ID)
    tracking, loop_closing on that marker: each loads the same file itself (their `start_from_map`)
      -> tracking's marker on /tracking/keyframes   (Keyframe, id LOAD_MARKER_ID)
      -> loop closing's marker on /loop_closing/loop_corrections (LoopCorrection, query_keyframe_id LOAD_MARKER_ID)

A marker's header carries the load: stamp = the load's epoch (wall clock of the owner's load, ns), frame_id =
the map file's path. Messages made before their sender loaded are dropped (`LoadEpochs`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from std_msgs.msg import Header

from changing_slam_msgs.msg import Keyframe as KeyframeMsg
from changing_slam_msgs.msg import LoopCorrection, MapUpdate
from changing_slam_ros.nodes.conversions import make_header, stamp_to_ns

LOAD_MARKER_ID = -3  # keyframe id of a marker message (-1: loop relay / snapshot, -2: empty snapshot)


@dataclass(frozen=True)
class LoadMarker:
    """One load: its epoch (ns, increasing from load to load) and the map file all nodes load."""

    epoch_ns: int
    path: str

    def header(self) -> Header:
        return make_header(self.epoch_ns, self.path)


def update_marker(marker: LoadMarker) -> MapUpdate:
    return MapUpdate(header=marker.header(), map_id=-1, keyframe_id=LOAD_MARKER_ID, loop_query_keyframe_id=-1)


def keyframe_marker(marker: LoadMarker) -> KeyframeMsg:
    return KeyframeMsg(header=marker.header(), id=LOAD_MARKER_ID, map_id=-1)


def loop_marker(marker: LoadMarker) -> LoopCorrection:
    return LoopCorrection(header=marker.header(), map_id=-1, query_keyframe_id=LOAD_MARKER_ID, match_keyframe_id=-1)


def marker_of(msg: Any, kf_id: int) -> LoadMarker | None:
    """The load a message announces (`kf_id`: its keyframe-id field), None for an ordinary message."""
    if int(kf_id) != LOAD_MARKER_ID:
        return None
    return LoadMarker(stamp_to_ns(msg.header.stamp), str(msg.header.frame_id))


@dataclass
class LoadEpochs:
    """This node's epoch and the epoch of each of its input streams.

    Every node keeps its own epoch (the last load it reset to, 0 = none) and, per input stream (topic), the epoch
    of the last marker on it. Messages on one topic from one publisher arrive in order (reliable QoS), so a
    message is of the node's epoch exactly when the last marker on its topic is: messages of a stream whose
    marker has not come yet were made before that sender reset (keyframe packets of the old map, updates of
    the old owner, verdicts on the old replica) and are dropped. A node that (re)starts has epoch 0 and never
    saw a marker, so it takes every message until the next load.
    """

    streams: dict[str, int] = field(default_factory=dict)
    epoch_ns: int = 0
    path: str = ""  # the file of the last load ("" = none)
    dropped: int = 0  # stale messages dropped

    @staticmethod
    def of(*streams: str) -> LoadEpochs:
        return LoadEpochs({s: 0 for s in streams})

    def on_marker(self, stream: str, marker: LoadMarker) -> bool:
        """A marker on `stream`: True when it announces a load newer than this node's (reset to it, then `adopt`)."""
        self.streams[stream] = marker.epoch_ns
        return marker.epoch_ns > self.epoch_ns

    def adopt(self, marker: LoadMarker) -> None:
        """This node now holds the marker's map."""
        self.epoch_ns = marker.epoch_ns
        self.path = marker.path

    def current(self, stream: str) -> bool:
        """A message on `stream` belongs to this node's map (else count it dropped: the caller drops it)."""
        if self.streams.get(stream, 0) == self.epoch_ns:
            return True
        self.dropped += 1
        return False
