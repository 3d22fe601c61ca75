"""The three sides of the split graph (`nodes.split_backend`) chained in one process: tests and benchmarks.

`ChainedGraph` calls them in the graph's lossless order (it gives the offline `SlamSystem`'s trajectory);
`DelayedChain` in real-time order, the owner's updates (and the loop side's relays) reaching tracking a fixed
number of frames late, as a map owner that needs that long per keyframe would. Packets are copied when sent, as
over the wire (`copy_packet`).
"""

from __future__ import annotations

import copy
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from changing_slam_ros.core.replication.map_replication import KeyframePacket, LoopResult, MapUpdate
from changing_slam_ros.core.features.rgbd_frame import RgbdFrame
from changing_slam_ros.core.system import FrameOutput
from changing_slam_ros.nodes.slam_backend import BackendConfig
from changing_slam_ros.nodes.split_backend import LoopSide, MapOwner, TrackingSide, object_layer_for


def copy_packet(packet: KeyframePacket) -> KeyframePacket:
    """What a receiver gets over the wire: its own copy (in-process chains must not share Keyframe objects)."""
    return copy.deepcopy(packet)


@dataclass
class ChainedGraph:
    """The three sides called in the graph's lossless order in one process (tests, benchmarks)."""

    tracking: TrackingSide
    owner: MapOwner
    loop: LoopSide | None

    @staticmethod
    def build(cfg: BackendConfig, loop: bool = True, dynamic: str = "config", objects: str = "config") -> ChainedGraph:
        return ChainedGraph(TrackingSide.build(cfg, loop, dynamic, objects), MapOwner.build(cfg, objects),
                            LoopSide.build(cfg) if loop else None)  # fmt: skip

    def start_from_map(self, path: str | Path, cfg: BackendConfig, objects: str = "config") -> None:
        """Every side loads the map file itself, as the nodes do."""
        from changing_slam_ros.io.map_file import load_map

        self.owner.start_from_map(load_map(path))
        self.tracking.start_from_map(load_map(path), object_layer_for(cfg, objects))
        if self.loop is not None:
            self.loop.start_from_map(load_map(path), object_layer_for(cfg, objects))

    def process(self, rgbd: RgbdFrame, detections: Any = None) -> FrameOutput:
        out, packet = self.tracking.process(rgbd, detections)
        assert out is not None  # in this synchronous chain every update is in before the next frame
        if packet is None:
            return out
        update = self.owner.on_keyframe(copy_packet(packet))
        if self.loop is not None:
            self.loop.on_keyframe(copy_packet(packet))
        self.tracking.apply_update(copy.deepcopy(update))
        if self.loop is not None:
            result = self.loop.on_update(copy.deepcopy(update))
            relay = self.owner.on_loop(copy.deepcopy(result)) if result is not None else None
            if relay is not None:
                self.tracking.apply_update(copy.deepcopy(relay))
                self.loop.on_update(copy.deepcopy(relay))
                self.tracking.n_loops += int(relay.merge is None)
        return out


@dataclass
class DelayedChain:
    """Tracking and the map owner in one process in real-time order, deterministically (tests, benchmarks): the
    owner maps one keyframe at a time and its update reaches tracking `delay_frames` frames after it started
    mapping it, as a map owner that needs that long per keyframe would. Tracking never waits for it.

    With a loop side (`loop`): it gets every packet when tracking sends it and every update when tracking does,
    and gives its verdict at once; the owner takes verdicts before its next keyframe, and the update of applying
    a closed loop or a map merge (the relay) reaches tracking and the loop side `delay_frames` frames later,
    like a keyframe's. Keyframes tracking made meanwhile are in flight across the merge, as in the real-time
    graph. Without it, no loop closing (its verdicts are what the lossless order waits for)."""

    tracking: TrackingSide
    owner: MapOwner
    delay_frames: int
    loop: LoopSide | None = None
    frame: int = 0
    queue: deque[KeyframePacket] = field(default_factory=deque)  # sent, not mapped yet
    in_flight: tuple[int, MapUpdate] | None = None  # (frame it arrives before, update)
    verdicts: deque[LoopResult] = field(default_factory=deque)  # the loop side's, not taken by the owner yet
    sent: list[int] = field(default_factory=list)  # keyframe ids tracking sent, in order
    mapped: list[int] = field(default_factory=list)  # keyframe ids the owner mapped, in order

    @staticmethod
    def build(cfg: BackendConfig, delay_frames: int, provisional: bool, dynamic: str = "config",
              objects: str = "config", loop: bool = False) -> DelayedChain:
        """`loop`: with the loop side (and tracking's relocalisation index, as `ChainedGraph` has it)."""
        return DelayedChain(TrackingSide.build(cfg, loop=loop, dynamic=dynamic, objects=objects,
                                               provisional=provisional),
                            MapOwner.build(cfg, objects), delay_frames,
                            LoopSide.build(cfg) if loop else None)  # fmt: skip

    def _send(self, packets: list[KeyframePacket]) -> None:
        for packet in packets:  # each receiver gets its copy when it is sent, as over the wire
            self.sent.append(packet.keyframe.id)
            self.queue.append(copy_packet(packet))
            if self.loop is not None:
                self.loop.on_keyframe(copy_packet(packet))

    def _owner_step(self) -> None:
        """Deliver an update that is due, start the owner's next job when it is free (verdicts first)."""
        if self.in_flight is not None and self.in_flight[0] <= self.frame:
            update = self.in_flight[1]
            self.in_flight = None
            released = self.tracking.apply_update(copy.deepcopy(update))
            if self.loop is not None:  # before the packets this releases, which may name the update's points
                result = self.loop.on_update(copy.deepcopy(update))
                if result is not None:
                    self.verdicts.append(result)
            self._send(released)
        while self.in_flight is None and self.verdicts:
            relay = self.owner.on_loop(copy.deepcopy(self.verdicts.popleft()))
            if relay is not None:
                self.in_flight = (self.frame + self.delay_frames, relay)
                self.tracking.n_loops += int(relay.merge is None)
        if self.in_flight is None and self.queue:
            packet = self.queue.popleft()
            self.mapped.append(packet.keyframe.id)
            update = self.owner.on_keyframe(packet)
            self.in_flight = (self.frame + self.delay_frames, update)

    def process(self, rgbd: RgbdFrame, detections: Any = None) -> FrameOutput | None:
        """One frame; None when tracking skipped it (a new map waiting for its first points)."""
        self._owner_step()
        self._owner_step()  # an update delivered may free the owner for the next packet at once
        out, packet = self.tracking.process(rgbd, detections)
        if packet is not None:
            self._send([packet])
        self.frame += 1
        return out

    def finish(self) -> None:
        """Map and deliver everything still pending (the end of a replay)."""
        while self.queue or self.in_flight is not None or self.verdicts:
            self.frame = max(self.frame, self.in_flight[0] if self.in_flight is not None else self.frame)
            self._owner_step()
