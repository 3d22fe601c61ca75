"""`local_mapping`: owns the metric map. Keyframes in, map updates (and the semantic map, map cloud) out.

    python -m changing_slam_ros.nodes.local_mapping_node --ros-args -p config:=tum_fr1

Per keyframe packet from tracking, the map owner (`nodes/split_backend.py`, `MapOwner`) maps it with
`core.slam.local_mapping.LocalMapper` and runs the object layer on it; the diff of the map goes out as a
MapUpdate (`core/replication/map_replication.py`). Loop corrections from loop_closing are applied and
published the same way, so tracking's and loop closing's replicas follow this map only. The node also saves
and loads whole maps (`map_out`, `map_file`, ~/save_map, ~/load_map: `nodes/map_load.py`) and gets the map
back from tracking after a restart (`nodes/map_resync.py`).
Topics, services, parameters and the ordering rules: docs/nodes.md#local_mapping.

With `wait_for_loop_results` every mapped keyframe gets loop closing's verdict before the next is mapped, also
when loop_closing restarts: its replica then comes from tracking's, which may hold the awaited keyframe
already, and the update that asked for the verdict went to the process that died (or out before the new one
subscribed). A loop_closing announces on the latched /loop_closing/ready when its map is in place; while a
verdict is awaited, each announcement makes this node send that keyframe's update again on
~/verdict_requests, once a second until the verdict comes (a request may go out before the new process's
subscription is matched; loop_closing answers a keyframe once and drops repeats). The new process decides the
keyframe on its restored map (see nodes/loop_closing_node.py), so the verdict is a real loop check, and
neither the mapping of the next keyframe nor the stop waits for a verdict that would never come. Without
`wait_for_loop_results` (real time) nothing is awaited, and keyframes a restarted loop_closing restored go
unchecked.
"""

from __future__ import annotations

import json
import os
import time
from collections import deque
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from rclpy._rclpy_pybind11 import RCLError  # a publish after the context shut down
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import QoSProfile
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header

from changing_slam_msgs.msg import Keyframe as KeyframeMsg
from changing_slam_msgs.msg import LoopCorrection, MapObjectArray, MapUpdate, ObjectStateArray
from changing_slam_msgs.srv import LoadMap, SaveMap
from changing_slam_ros.core.replication.map_replication import KeyframePacket, LoopResult
from changing_slam_ros.errors import SlamError
from changing_slam_ros.nodes.conversions import make_header
from changing_slam_ros.nodes.diagnostics import NodeDiagnostics, summarise_ms
from changing_slam_ros.nodes.grid_output import GRID_PARAMETERS, GridOutput
from changing_slam_ros.nodes.map_load import LoadEpochs, LoadMarker, marker_of, update_marker
from changing_slam_ros.nodes.node_help import NodeHelp, ParamSpec, first_line
from changing_slam_ros.nodes.node_runner import declare_parameters, run_node
from changing_slam_ros.nodes.qos_profiles import LATCHED
from changing_slam_ros.nodes.replication_conversions import loop_result_from_msg, packet_from_msg, update_to_msg

PROFILE_ENV = "CHANGING_SLAM_PROFILE_LOCAL_MAPPING"  # a path: cProfile the node's process into it (pstats file)
KEYFRAME_QOS = QoSProfile(depth=100)  # reliable, volatile: every keyframe counts


def points_to_cloud(positions_w: np.ndarray, stamp_ns: int, frame_id: str) -> PointCloud2:
    """(N, 3) metres -> PointCloud2 with float32 x, y, z."""
    xyz = np.ascontiguousarray(positions_w, dtype=np.float32).reshape(-1, 3)
    fields = [PointField(name=n, offset=4 * i, datatype=PointField.FLOAT32, count=1) for i, n in enumerate("xyz")]
    return PointCloud2(header=make_header(stamp_ns, frame_id), height=1, width=len(xyz), fields=fields,
                       is_bigendian=False, point_step=12, row_step=12 * len(xyz), data=xyz.tobytes(), is_dense=True)  # fmt: skip


LOCAL_MAPPING_PARAMETERS: tuple[ParamSpec, ...] = (
    ("config", "tum_fr1", "config name or YAML path (features, mapping, objects sections)"),
    ("objects", "config", "object layer (MapObjects, beliefs, active flags): config, on, off"),
    ("map_frame", "map", "frame of the published map"),
    ("map_cloud_period_s", 1.0, "shortest time between two map_cloud messages"),
    ("wait_for_loop_results", False, "map a keyframe only after loop closing answered for the previous "
                                     "one (lossless graph: the offline order of work)"),
    ("diagnostics_period_s", 5.0, "seconds between /diagnostics reports (0 = off)"),
    ("output_dir", "", "write semantic_map.json and local_mapping_stats.json here on shutdown"),
    ("map_out", "", "on shutdown, save the whole map here (map.npz format of `changing-slam run`, atomic) and "
                    "its occupancy grid beside it (<stem>_grid.yaml / .pgm, Nav2 map_server); also the default "
                    "path of ~/save_map"),
    ("map_dir", "", "folder the paths of ~/save_map and ~/load_map requests must lie in (names ending .npz; "
                    "an existing file is replaced only when it is a map file); empty = request paths refused"),
    ("resync", True, "at start, ask tracking for its map (a node restarted beside a running tracking); false: "
                     "start empty (started together with tracking, as `changing-slam graph` does at first)"),
    ("resync_timeout_s", 20.0, "at start, how long to wait for tracking's map snapshot (a restart)"),
    ("update_subscribers", 0, "map a keyframe only once ~/map_updates has this many subscribers (graph: "
                              "tracking and loop_closing), so that a (re)started node loses no update"),
    ("update_subscribers_wait_s", 15.0, "update_subscribers: after this long since start, map without them"),
    ("ba_solver", "", "local BA's solver: gtsam or schur (numpy Schur-complement LM, same cost, ~0.35x the "
                      "solver's CPU); empty = the config's mapping.ba_solver (gtsam unless set)"),
    ("ba_yields_to_keyframes", True, "real time (wait_for_loop_results false): local BA ends early when a "
                                     "new keyframe arrives meanwhile (ORB-SLAM's abort; checked between "
                                     "solver iterations); never in the lossless graph"),
    ("map_file", "", "multi-session: start from this map file of `changing-slam run` (DIR/map.npz: the "
                     "Atlas and the saved objects; tracking and loop_closing load the same file; the map is then not asked of tracking, so a node restarted "
                     "in a running graph is started without it and gets the current map from tracking)"),
    *GRID_PARAMETERS,
)  # fmt: skip


class LocalMappingNode(Node):
    def __init__(self, keyframe_qos: QoSProfile = KEYFRAME_QOS, output_qos: QoSProfile | int = 10,
                 **node_kwargs: Any) -> None:  # fmt: skip
        super().__init__("local_mapping", **node_kwargs)
        self.params = p = declare_parameters(self, LOCAL_MAPPING_PARAMETERS)
        from changing_slam_ros.nodes.slam_backend import load_backend_config
        from changing_slam_ros.nodes.split_backend import MapOwner

        self.cfg = load_backend_config(p["config"])
        if p["ba_solver"]:
            self.cfg = self.cfg.with_mapping(ba_solver=p["ba_solver"], why="parameter ba_solver")
        self.owner = MapOwner.build(self.cfg, objects=p["objects"])
        self._set_ba_stop()
        if p["map_file"]:
            from changing_slam_ros.io.map_file import load_map

            self.owner.start_from_map(load_map(p["map_file"]))
            self.get_logger().info(f"local_mapping: {self.owner.atlas.n_keyframes} keyframes, "
                                   f"{len(self.owner.atlas.maps)} maps loaded from {p['map_file']}")  # fmt: skip
        self.keyframes_in = 0
        self.keyframes_duplicate = 0  # received again after being mapped or queued (dropped)
        self.keyframes_rejected = 0
        self.loops_applied = 0
        self.merges_applied = 0  # Atlas map merges found by loop_closing and applied here
        # found, not applied: the merge no longer fits the map (its maps merged already, a seam keyframe culled
        # meanwhile: real time, MapOwner.on_merge)
        self.merges_skipped = 0
        self.awaiting_loop_for = -1  # keyframe id whose loop verdict the next keyframe waits for
        self._awaited_update: MapUpdate | None = None  # its update, sent again to a restarted loop_closing
        self.verdict_requests = 0  # updates sent again on ~/verdict_requests (see the module doc)
        self.queue: deque[KeyframePacket] = deque()
        self.process_ms: list[float] = []
        self.process_cpu_ms: list[float] = []  # process CPU time per keyframe (load-independent)
        # Thread CPU per keyframe on the executor's thread (the DDS threads left out): the map owner's step
        # (counters, LocalMapper, object layer, snapshot and diff) and the node's messages (MapUpdate, semantic
        # map, cloud: building and publishing).
        self.owner_cpu_ms: list[float] = []
        self.messages_cpu_ms: list[float] = []
        self.queue_ms: list[float] = []
        self._last_cloud_s = -1e9
        self._finished = False
        self.epochs = LoadEpochs.of("keyframes", "loops")  # ~/load_map: which messages belong to the loaded map
        self.loads = 0
        self.ba_stops = 0  # local BAs ended early because a keyframe arrived (ba_yields_to_keyframes)
        self.keyframe_sub = self.create_subscription(KeyframeMsg, "/tracking/keyframes", self.on_keyframe, keyframe_qos)
        self.loop_sub = self.create_subscription(LoopCorrection, "/loop_closing/loop_corrections",
                                                 self.on_loop_correction, keyframe_qos)  # fmt: skip
        self.create_subscription(ObjectStateArray, "/object_map/object_states", self.on_object_states, 10)
        self.create_subscription(Header, "/loop_closing/ready", self.on_loop_closing_ready, LATCHED)
        self.update_pub = self.create_publisher(MapUpdate, "~/map_updates", keyframe_qos)
        self.verdict_request_pub = self.create_publisher(MapUpdate, "~/verdict_requests", keyframe_qos)
        self.semantic_pub = self.create_publisher(MapObjectArray, "~/semantic_map", LATCHED)
        self.candidate_pub = self.create_publisher(MapObjectArray, "~/object_candidates", output_qos)
        self.cloud_pub = self.create_publisher(PointCloud2, "~/map_cloud", output_qos)
        self.grid = GridOutput(self, p, p["map_frame"], lambda: self.owner)  # ~/grid, transient local
        from changing_slam_ros.nodes.map_resync import ResyncClient

        # After a restart the map comes back from tracking's replica; keyframes wait for it (see map_resync).
        # (not with a map file: the map comes from the file, not from tracking's replica of it; see map_file)
        self.resync = ResyncClient(self, self._restore, give_up_s=p["resync_timeout_s"],
                                   ask=p["resync"] and not p["map_file"])  # fmt: skip
        self._started_s = time.monotonic()
        # Retries a queue that cannot be mapped yet (map resync, update subscribers); armed only while the queue
        # holds something: every executor wake-up costs ~0.5-1 ms of CPU, and 10 a second for nothing add up.
        self._drain_timer = self.create_timer(0.1, self._drain, clock=Clock(clock_type=ClockType.STEADY_TIME))
        # Repeats a verdict request until the verdict comes; armed only then (see the module doc).
        self._request_timer = self.create_timer(1.0, self._request_verdict, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._request_timer.cancel()
        self.create_service(SaveMap, "~/save_map", self.on_save_map)
        self.create_service(LoadMap, "~/load_map", self.on_load_map)
        self.diagnostics = NodeDiagnostics(self, p["diagnostics_period_s"])
        self.diagnostics.set_source(self.stats)
        if p["map_file"]:  # object_map starts from the loaded objects; Nav2 from the loaded grid
            self._publish_semantic_map(0)
            self.grid.on_change(0, force=True)
        layer = "on" if self.owner.backend.objects is not None else "off"
        self.get_logger().info(f"local_mapping: started (owns the map; object layer {layer}; "
                               f"wait_for_loop_results {p['wait_for_loop_results']})")  # fmt: skip

    # -- inputs ---------------------------------------------------------------------------------
    def on_keyframe(self, msg: KeyframeMsg) -> None:
        self._enqueue(msg)
        self._drain()

    def _enqueue(self, msg: KeyframeMsg) -> None:
        marker = marker_of(msg, msg.id)
        if marker is not None:  # tracking loaded the map: its packets from here on are of the loaded map
            self.epochs.on_marker("keyframes", marker)
            return
        if not self.epochs.current("keyframes"):
            return  # made on the map before ~/load_map
        try:
            packet = packet_from_msg(msg, "/tracking/keyframes")
        except (SlamError, ValueError) as err:
            self.keyframes_rejected += 1
            self.get_logger().warning(f"local_mapping: keyframe rejected: {err}", throttle_duration_sec=5.0)
            return
        self.keyframes_in += 1
        kf_id = packet.keyframe.id
        if self.owner.atlas.map_of_keyframe(kf_id) is not None or any(q.keyframe.id == kf_id for q in self.queue):
            # sent twice (tracking re-sends what it has no update for after a resync): mapping it again would
            # add its points a second time
            self.keyframes_duplicate += 1
            self.get_logger().info(f"local_mapping: keyframe {kf_id} received again; mapped or queued already")
            return
        packet.received_s = time.monotonic()  # type: ignore[attr-defined]
        self.queue.append(packet)

    def _set_ba_stop(self) -> None:
        """Real time with `ba_yields_to_keyframes`: the mapper's local BA asks `_keyframe_waiting` between iterations."""
        on = self.params["ba_yields_to_keyframes"] and not self.params["wait_for_loop_results"]
        self.owner.mapper.ba_stop = self._keyframe_waiting if on else None

    def _keyframe_waiting(self) -> bool:
        """Whether a keyframe is waiting to be mapped. The executor is busy in this node's callback, so keyframes
        that arrived meanwhile are taken off the subscription here (as the executor would, in order) and queued."""
        sub = self.keyframe_sub
        while True:
            with sub.handle:
                taken = sub.handle.take_message(sub.msg_type, sub.raw)
            if taken is None:
                break
            self._enqueue(taken[0])
        if self.queue:
            self.ba_stops += 1
            return True
        return False

    def on_loop_correction(self, msg: LoopCorrection) -> None:
        marker = marker_of(msg, msg.query_keyframe_id)
        if marker is not None:
            self.epochs.on_marker("loops", marker)
            return
        if not self.epochs.current("loops"):
            return  # a verdict on loop closing's replica of the map before ~/load_map
        try:
            result = loop_result_from_msg(msg, "/loop_closing/loop_corrections")
        except (SlamError, ValueError) as err:
            self.get_logger().warning(f"local_mapping: loop correction rejected: {err}", throttle_duration_sec=5.0)
            return
        self.apply_loop(result, msg.header.stamp)
        if result.query_kf_id == self.awaiting_loop_for:
            self._stop_awaiting()
        self._drain()

    def on_loop_closing_ready(self, msg: Header) -> None:
        """A loop_closing has its map: if a verdict is awaited, its update goes to it again (see the module doc)."""
        if self.awaiting_loop_for < 0 or self._awaited_update is None:
            return
        self.get_logger().info(f"local_mapping: {msg.frame_id or 'loop_closing'} is ready; asking it for the "
                               f"verdict on keyframe {self.awaiting_loop_for}")  # fmt: skip
        self._request_verdict()
        if self._request_timer.is_canceled():
            self._request_timer.reset()

    def _request_verdict(self) -> None:
        if self.awaiting_loop_for < 0 or self._awaited_update is None:
            self._request_timer.cancel()
            return
        self.verdict_requests += 1
        self.verdict_request_pub.publish(self._awaited_update)

    def _stop_awaiting(self) -> None:
        self.awaiting_loop_for = -1
        self._awaited_update = None
        self._request_timer.cancel()

    def on_object_states(self, msg: ObjectStateArray) -> None:
        pass  # beliefs and active flags are the object layer's, which runs here (see the module doc)

    def _request_path(self, name: str, for_write: bool) -> Path:
        """A SaveMap / LoadMap path: a name confined to `map_dir` (`io.map_dir`: any peer may call the services)."""
        from changing_slam_ros.io.map_dir import MapDir, is_metric_map

        service = "SaveMap" if for_write else "LoadMap"
        return MapDir(self.params["map_dir"], (".npz",), is_metric_map, service).resolve(name, for_write)

    def on_save_map(self, request: Any, response: Any) -> Any:
        if not request.path and not self.params["map_out"]:
            response.success, response.message = False, "local_mapping: no path given and no map_out parameter"
            return response
        path = request.path or self.params["map_out"]
        try:
            target = self._request_path(request.path, for_write=True) if request.path else Path(path)
            self.save_map(target)
            response.success = True
            response.message = f"local_mapping: saved {self.owner.atlas.n_keyframes} keyframes to {target}"
        except (SlamError, OSError) as err:
            response.success, response.message = False, f"local_mapping: map not saved to {path}: {err}"
            self.get_logger().warning(response.message)
        return response

    def on_load_map(self, request: Any, response: Any) -> Any:
        """~/load_map: continue from a saved map (see the module doc)."""
        path = request.path
        try:
            if not path:
                raise SlamError("LoadMap request: path is empty")
            path = str(self._request_path(path, for_write=False))
            self.load_map(path)
        except (SlamError, OSError, ValueError) as err:
            response.success, response.message = False, f"local_mapping: map not loaded (running map kept): {err}"
            self.get_logger().error(response.message)
            return response
        atlas = self.owner.atlas
        response.success = True
        response.message = (f"local_mapping: {atlas.n_keyframes} keyframes in {len(atlas.maps)} maps loaded from "
                            f"{path}; tracking and loop_closing load it on the marker")  # fmt: skip
        self.get_logger().info(response.message)
        return response

    def load_map(self, path: str) -> None:
        """Replace the map with the file's (checked into a new owner first: on error nothing changes), then
        announce the load to tracking and loop_closing and publish the loaded semantic map and cloud."""
        from changing_slam_ros.io.map_file import load_map
        from changing_slam_ros.nodes.split_backend import MapOwner

        if not path:
            raise SlamError("LoadMap request: path is empty")
        owner = MapOwner.build(self.cfg, objects=self.params["objects"])
        owner.start_from_map(load_map(path))
        self.owner = owner
        self._set_ba_stop()
        self.queue.clear()  # keyframes of the replaced map
        self._stop_awaiting()
        if not self.resync.ready:
            self.resync.skip()
        marker = LoadMarker(max(time.time_ns(), self.epochs.epoch_ns + 1), str(path))
        self.epochs.adopt(marker)
        self.loads += 1
        self.update_pub.publish(update_marker(marker))
        self._publish_semantic_map(0)
        self._last_cloud_s = -1e9
        self._publish_cloud(0)
        self.grid.on_change(0, force=True)

    def _publish_semantic_map(self, stamp_ns: int) -> None:
        if self.owner.backend.objects is None:
            return
        from changing_slam_ros.nodes.object_map_node import semantic_map_to_msg

        smap = self.owner.backend.objects.semantic_map(self.owner.atlas.current.id, include_inactive=True)
        self.semantic_pub.publish(semantic_map_to_msg(smap, make_header(stamp_ns, self.params["map_frame"])))

    def save_map(self, path: Path) -> None:
        """The owner's Atlas and object layer (MapObjects, beliefs), atomically (`io.map_file.save_map`), and the
        occupancy grid beside it as a Nav2 map_server pair (`<stem>_grid.yaml` and `.pgm`, `io.nav2_map`)."""
        from changing_slam_ros.io.map_file import save_map

        path.parent.mkdir(parents=True, exist_ok=True)
        save_map(path, self.owner.atlas, self.owner.backend.objects)
        self.grid.save_beside(self.owner, path)

    # -- work -----------------------------------------------------------------------------------
    def _restore(self, keyframes: list[Any], delta: Any) -> None:
        self.owner.restore(keyframes, delta)
        self._drain()

    def _subscribers_ready(self) -> bool:
        p = self.params
        return (self.update_pub.get_subscription_count() >= p["update_subscribers"]
                or time.monotonic() - self._started_s > p["update_subscribers_wait_s"])  # fmt: skip

    def _drain(self) -> None:
        while self.queue and self.awaiting_loop_for < 0 and self.resync.ready and self._subscribers_ready():
            packet = self.queue.popleft()
            m = self.owner.atlas.maps[packet.keyframe.map_id] if packet.keyframe.map_id < len(self.owner.atlas.maps) else None
            if m is not None and (packet.keyframe.id in m.keyframes or packet.keyframe.id in m.removed):
                continue  # already in the map restored from tracking's replica
            self.map_keyframe(packet)
        if self.queue:
            if self._drain_timer.is_canceled():
                self._drain_timer.reset()
        elif not self._drain_timer.is_canceled():
            self._drain_timer.cancel()

    def map_keyframe(self, packet: KeyframePacket) -> None:
        t0 = time.monotonic()
        c0 = time.process_time()
        th0 = time.thread_time()
        kf = packet.keyframe
        try:
            update = self.owner.on_keyframe(packet)
        except SlamError as err:
            self.keyframes_rejected += 1
            self.get_logger().warning(f"local_mapping: keyframe {kf.id} not mapped: {err}", throttle_duration_sec=5.0)
            return
        th1 = time.thread_time()
        frame = self.params["map_frame"]
        update_msg = update_to_msg(update, kf.stamp_ns, frame)
        self.update_pub.publish(update_msg)
        if self.params["wait_for_loop_results"]:
            self.awaiting_loop_for = kf.id
            self._awaited_update = update_msg
        if update.objects_ran:
            self._publish_semantic_map(kf.stamp_ns)
        self._publish_cloud(kf.stamp_ns)
        self.grid.on_change(kf.stamp_ns)
        now = time.monotonic()
        self.process_ms.append((now - t0) * 1e3)
        self.process_cpu_ms.append((time.process_time() - c0) * 1e3)
        self.owner_cpu_ms.append((th1 - th0) * 1e3)
        self.messages_cpu_ms.append((time.thread_time() - th1) * 1e3)
        self.queue_ms.append((t0 - getattr(packet, "received_s", t0)) * 1e3)

    def apply_loop(self, result: LoopResult, stamp: Any) -> None:
        # In real time too: keyframe packets of the merged-away map that arrive later are moved into the merged
        # map (MapOwner.on_keyframe), and tracking and loop_closing move what they hold of it that is not mapped
        # yet (core/replication/merge_in_flight.py).
        try:
            relay = self.owner.on_loop(result)
        except SlamError as err:
            self.get_logger().warning(f"local_mapping: loop correction not applied: {err}")
            return
        if relay is None:
            if result.merge is not None:
                self.merges_skipped += 1
                self.get_logger().warning(f"local_mapping: map merge at keyframe {result.query_kf_id} not applied: it "
                                          "no longer fits the map (maps merged already or a seam keyframe culled)")  # fmt: skip
            return
        from changing_slam_ros.nodes.conversions import stamp_to_ns

        self.update_pub.publish(update_to_msg(relay, stamp_to_ns(stamp), self.params["map_frame"]))
        self.grid.on_change(stamp_to_ns(stamp))
        if relay.merge is not None:
            self.merges_applied += 1
            r = relay.merge
            self.get_logger().info(f"local_mapping: map {r.from_map_id} merged into map {r.into_map_id} at keyframe "
                                   f"{result.query_kf_id} ({len(r.moved_keyframes)} keyframes moved, {r.n_fused} points "
                                   "fused)")  # fmt: skip
            return
        self.loops_applied += 1
        self.get_logger().info(f"local_mapping: loop at keyframe {result.query_kf_id} applied "
                               f"({len(relay.delta.keyframes)} keyframes, {len(relay.delta.points)} points changed)")  # fmt: skip

    def _publish_cloud(self, stamp_ns: int) -> None:
        now = time.monotonic()
        if now - self._last_cloud_s < self.params["map_cloud_period_s"] or self.cloud_pub.get_subscription_count() == 0:
            return
        self._last_cloud_s = now
        pts = self.owner.atlas.current.points
        xyz = pts.positions[: pts.size][pts.usable()]
        self.cloud_pub.publish(points_to_cloud(xyz, stamp_ns, self.params["map_frame"]))

    # -- outputs --------------------------------------------------------------------------------
    def stats(self) -> dict[str, Any]:
        t = self.owner.timings_ms
        out: dict[str, Any] = {
            "keyframes_received": self.keyframes_in, "keyframes_rejected": self.keyframes_rejected,
            "keyframes_duplicate": self.keyframes_duplicate,
            "keyframes_mapped": len(t["mapping"]), "keyframes_queued": len(self.queue), "loops_applied": self.loops_applied,
            "merges_applied": self.merges_applied, "merges_skipped": self.merges_skipped,
            "late_keyframes_moved_by_merges": self.owner.log.n_moved,
            "loops_dropped_merged_map": self.owner.n_loops_dropped,
            "map_points": int(self.owner.atlas.current.points.usable().sum()),
            "keyframes_in_map": self.owner.atlas.n_keyframes, "restored_keyframes": self.resync.restored_keyframes,
            "map_loads": self.loads, "dropped_before_load": self.epochs.dropped, "ba_stopped_early": self.ba_stops,
            "verdict_requests": self.verdict_requests,
        }  # fmt: skip
        out.update(self.grid.stats())
        out.update(summarise_ms(self.process_ms, "keyframe"))
        out.update(summarise_ms(self.process_cpu_ms, "keyframe_cpu"))
        out.update(summarise_ms(self.owner_cpu_ms, "owner_thread_cpu"))
        out.update(summarise_ms(self.messages_cpu_ms, "messages_thread_cpu"))
        for name, v in (("keyframe_cpu", self.process_cpu_ms), ("owner_thread_cpu", self.owner_cpu_ms),
                        ("messages_thread_cpu", self.messages_cpu_ms)):  # fmt: skip
            out[f"{name}_ms_mean"] = float(np.mean(v)) if v else None  # x keyframes = the total, unlike the median
        out.update(summarise_ms(self.queue_ms, "queue_wait"))
        out.update(summarise_ms(t["mapping"], "local_ba_and_mapping"))
        out.update(summarise_ms(t["diff"], "diff"))
        return out

    def work_pending(self) -> str:
        """What a stop still waits for (`node_runner.drain_work`): queued keyframes, and the loop verdict the
        last mapped keyframe awaits (wait_for_loop_results) while loop_closing is there to give it, so that every
        keyframe received is mapped and every verdict applied before the map and stats are written; "" when
        nothing."""
        parts = [f"{len(self.queue)} queued keyframes"] if self.queue else []
        if self.awaiting_loop_for >= 0 and self.count_publishers(self.loop_sub.topic_name) > 0:  # loop_closing up
            parts.append(f"the loop verdict on keyframe {self.awaiting_loop_for}")
        return " and ".join(parts)

    def finish(self) -> list[Path]:
        if self._finished:
            return []
        self._finished = True
        while self.queue:
            packet = self.queue.popleft()
            try:
                self.map_keyframe(packet)
            except RCLError as err:  # shut down: mapped into the map saved below, only its update is not sent
                self.get_logger().warning(f"local_mapping: keyframe {packet.keyframe.id} mapped at shutdown, its "
                                          f"update not published ({err})")  # fmt: skip
        if self.params["map_out"]:
            try:
                self.save_map(Path(self.params["map_out"]))
                self.get_logger().info(f"local_mapping: map saved to {self.params['map_out']}")
            except (SlamError, OSError) as err:
                self.get_logger().error(f"local_mapping: map not saved to {self.params['map_out']}: {err}")
        if not self.params["output_dir"]:
            return []
        from changing_slam_ros.io.atomic import atomic_write_text

        out = Path(self.params["output_dir"])
        out.mkdir(parents=True, exist_ok=True)
        written = []
        layer = self.owner.backend.objects
        if layer is not None and len(self.process_ms):
            from changing_slam_ros.io.semantic_map_file import write_semantic_map

            write_semantic_map(out / "semantic_map.json", layer.semantic_map(self.owner.atlas.current.id))
            written.append(out / "semantic_map.json")
        atomic_write_text(out / "local_mapping_stats.json", json.dumps(self.stats(), indent=2) + "\n")
        written.append(out / "local_mapping_stats.json")
        self.get_logger().info(f"local_mapping: wrote {', '.join(p.name for p in written)} to {out}")
        return written

    def destroy_node(self) -> None:
        try:
            self.finish()
        finally:
            super().destroy_node()


NODE_HELP = NodeHelp("local_mapping", first_line(__doc__), LOCAL_MAPPING_PARAMETERS)


def main(args: Sequence[str] | None = None) -> int:
    profile_out = os.environ.get(PROFILE_ENV, "")
    if not profile_out:
        return run_node(lambda argv: LocalMappingNode(), args, node_help=NODE_HELP)
    import cProfile

    # CPU time of the executor's thread (every callback of the node), not wall time: the machine may be shared.
    profiler = cProfile.Profile(time.thread_time)
    profiler.enable()
    try:
        return run_node(lambda argv: LocalMappingNode(), args, node_help=NODE_HELP)
    finally:
        profiler.disable()
        profiler.dump_stats(profile_out)


if __name__ == "__main__":
    raise SystemExit(main())
