"""The tracking node's split-backend inputs: map updates, loop verdicts and map loads into the replica.

local_mapping owns the map and sends MapUpdates, loop_closing sends verdicts; in lossless mode the
acknowledgement of a keyframe frame is held until its update and verdict (and a loop's relay) are in.
A load marker (local_mapping's ~/load_map) replaces the replica with the marker's map file.
Mixed into `TrackingNode`, whose `__init__` sets the state these methods use.
"""

from __future__ import annotations

import time

from changing_slam_msgs.msg import LoopCorrection, MapUpdate

from changing_slam_ros.errors import SlamError
from changing_slam_ros.nodes.map_load import LoadMarker, keyframe_marker, marker_of


class ReplicaInputs:
    """Methods of `TrackingNode` (see the module docstring)."""

    def on_map_update(self, msg: MapUpdate) -> None:
        """Split backend: local_mapping's change of the map into the replica (in publication order)."""
        if self.split is None:
            return
        marker = marker_of(msg, msg.keyframe_id)
        if marker is not None:
            self._on_marker("updates", marker)
            return
        if not self.epochs.current("updates"):
            return  # the owner's change of the map it held before ~/load_map
        from changing_slam_ros.nodes.replication_conversions import update_from_msg

        try:
            update = update_from_msg(msg, "/local_mapping/map_updates")
            released = self.split.apply_update(update)
        except (SlamError, ValueError) as err:
            self.updates_rejected += 1
            self.get_logger().warning(f"tracking: map update rejected: {err}", throttle_duration_sec=5.0)
            return
        for packet in released:  # provisional points: keyframes held until this update named their points
            self._send_packet(packet)
        self.updates_applied += 1
        sent = self._kf_sent_s.pop(update.keyframe_id, None)
        if sent is not None:
            self.update_latency_ms.append((time.monotonic() - sent) * 1e3)
        if update.loop_query_kf_id >= 0:
            self.split.n_loops += int(update.merge is None)  # a merge is counted in split.n_merges
            self._relays_seen.add(update.loop_query_kf_id)
            self._rebuild_path()
        self._settle(update=update.keyframe_id, relay=update.loop_query_kf_id)

    def _resend_unmapped(self, asker: str) -> None:
        """After a map snapshot: keyframes sent but not mapped (local_mapping was down) go out again. A restarted
        loop_closing has the keyframe whose verdict the held ack waits for in its snapshot, and decides a restored
        keyframe only when local_mapping asks for it (`wait_for_loop_results`, nodes/local_mapping_node.py), which
        tracking cannot tell: the ack goes without that verdict, which reaches the map when it comes."""
        for packet in self.split.resend():
            self._send_packet(packet, resend=True)
        a = self._awaiting
        if a is not None:  # sent again until its update comes (`_check_wait`); a receiver that has it drops it
            a["resend_at"] = time.monotonic() + self.params["map_update_resend_s"]
            self._arm_drain_timer()
        if asker == "loop_closing" and a is not None and not a["verdict"]:
            self.get_logger().warning(f"tracking: keyframe {a['kf']} went to loop_closing in its map snapshot; "
                                      "its frame is acknowledged without the loop verdict")  # fmt: skip
            self._settle(verdict=a["kf"])

    def on_loop_correction(self, msg: LoopCorrection) -> None:
        """Split backend: loop_closing's verdict; a closed loop reaches the replica through local_mapping's update."""
        if self.split is None:
            return
        marker = marker_of(msg, msg.query_keyframe_id)
        if marker is not None:
            self._on_marker("loops", marker)
            return
        if not self.epochs.current("loops"):
            return  # a verdict on the map before ~/load_map
        # a map merge, like a closed loop, comes back as local_mapping's update: wait for that relay too
        self._settle(verdict=int(msg.query_keyframe_id), closed=bool(msg.closed) or bool(msg.merge))

    def _on_marker(self, stream: str, marker: LoadMarker) -> None:
        """A load announced on `stream` (local_mapping's ~/load_map): the first announcement of a newer load
        replaces the replica with the marker's file (`TrackingSide.start_from_map`: relocalise in it first)."""
        if not self.epochs.on_marker(stream, marker):
            return
        from changing_slam_ros.io.map_file import load_map
        from changing_slam_ros.nodes.split_backend import TrackingSide, object_layer_for

        p, old = self.params, self.split

        def build() -> TrackingSide:
            return TrackingSide.build(self._cfg, loop=p["loop_closing"], dynamic=p["dynamic"], objects=p["objects"],
                                      provisional=old.provisional is not None)  # fmt: skip

        side = build()
        try:
            side.start_from_map(load_map(marker.path), object_layer_for(self._cfg, p["objects"]))
        except (SlamError, OSError, ValueError) as err:  # local_mapping loaded it: the file changed since
            self.get_logger().error(f"tracking: map {marker.path} not loaded ({err}); starting a new map")
            side = build()
        if old.system.records:
            self._before_load.append(old.system.online_trajectory())
        self.split, self.backend = side, side.backend
        if self.movers is not None and side.backend.dynamic is not None:
            self.movers = side.backend.dynamic.movers
        self.epochs.adopt(marker)
        self.loads += 1
        self.poses_out.replace_path([], [])  # the path goes on in the loaded map's frame
        self._kf_sent_s.clear()
        self._relays_seen.clear()
        self.keyframe_pub.publish(keyframe_marker(marker))
        atlas = side.system.atlas
        self.get_logger().info(f"tracking: {atlas.n_keyframes} keyframes in {len(atlas.maps)} maps loaded from "
                               f"{marker.path} (LoadMap); relocalising in map {atlas.current.id}")  # fmt: skip
        if self._awaiting is not None:  # its update and verdict will not come: the old map is gone
            held, self._awaiting = self._awaiting["header"], None
            self._ack(held)
        self._drain()

    def _settle(self, update: int = -2, relay: int = -2, verdict: int = -2, closed: bool = False) -> None:
        """wait_for_map_updates: tick off what the held acknowledgement waits for; send it when all is in."""
        a = self._awaiting
        if a is None:
            return
        kf = a["kf"]
        if update == kf:
            a["update"] = True
        if verdict == kf:
            a["verdict"] = True
            a["relay"] = not closed or kf in self._relays_seen
        if relay == kf:
            a["relay"] = True
        if a["update"] and a["verdict"] and a["relay"]:
            self._awaiting = None
            self._ack(a["header"])
            self._drain()

    def _check_wait(self) -> None:
        """The held ack's deadline, and after a restarted node's map snapshot the resend of the awaited keyframe
        every `map_update_resend_s` while its update has not come: the restarted node may ask for the snapshot
        before tracking's publisher has matched its new subscription, and the keyframe sent after the snapshot is
        then lost (the killed node's subscription still counts until DDS notices it is gone). Local mapping and
        loop closing drop a keyframe they have already."""
        a = self._awaiting
        now = time.monotonic()
        if a is not None and not a["update"] and "resend_at" in a and a["resend_at"] <= now <= a["deadline"]:
            packet = self.split.unacked.get(a["kf"]) if self.split is not None else None
            if packet is not None:
                self._send_packet(packet, resend=True)
                self.keyframes_resent += 1
            a["resend_at"] = now + self.params["map_update_resend_s"]
        if a is not None and now > a["deadline"]:
            self.get_logger().warning(f"tracking: no map update / loop verdict for keyframe {a['kf']} after "
                                      f"{self.params['map_update_timeout_s']} s; going on")  # fmt: skip
            self._awaiting = None
            self.map_update_waits_timed_out += 1
            self._ack(a["header"])
