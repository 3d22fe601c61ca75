"""`changing-slam graph BAG --out DIR`: the ROS 2 node graph over a bag, as separate processes, without ros2 launch.

    changing-slam graph BAG --out DIR [--config NAME|FILE] [--rate R] [--lossless] [--[no-]detection]
        [--[no-]object-map] [--detections-wait S] [--queue-depth N] [--detector-threads N]
        [--detector-model NAME|config] [--detection-max-hz HZ] [--ba-solver gtsam|schur|config]
        [--max-restarts N] [--timeout S] [--kill NODE@SECONDS] [--load-map MAP@SECONDS] [--loop N]
        [--backend split|in_process] [--map-in PREVIOUS/map.npz]

Starts `object_map`, `detection` (when the config's dynamic filter uses detections, or --detection),
`tracking`, `local_mapping`, `loop_closing` and `bag_player` as `python -m changing_slam_ros.nodes.<name>_node`
processes on a ROS domain of their own, plays the bag, stops the nodes, evaluates the trajectory against the
bag's ground truth and prints a summary (`Graph`). Processes: `graph_process.py`; outputs: `graph_outputs.py`;
the progress line: `graph_progress.py`; `--live` (a camera driver's topics, no bag): `graph_live.py`.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from changing_slam_ros.commands.graph_arguments import (  # noqa: F401 - add_arguments: the command's options
    BACKENDS,
    add_arguments,
    check_bag_arguments,
)
from changing_slam_ros.commands.graph_outputs import (
    camera_mismatches,
    detection_median_ms,
    drops_by_reason,
    drops_text,
    evaluate,
    graph_provenance,
    graph_warnings,
    lossless_gaps,
    read_json,
    write_outputs_mcap,
)
from changing_slam_ros.commands.graph_options import parse_kills, parse_loads, parse_nice
from changing_slam_ros.commands.graph_process import (
    NodeFailed,
    NodeProcess,
    child_env,
    node_argv,
    python_argv,
    stop_all,
)
from changing_slam_ros.commands.graph_progress import GraphProgress
from changing_slam_ros.commands.graph_source import (  # noqa: F401 - BagInfo, inspect_bag: graph_live, tests
    ACK_TOPIC,
    PLAYER_FIRST_MESSAGE,
    BagInfo,
    ResumePoint,
    inspect_bag,
    player_params,
    resume_point,
)
from changing_slam_ros.commands.process_cpu import PlayCpu, play_cpu_summary
from changing_slam_ros.errors import ConfigError, SlamError
from changing_slam_ros.io.atomic import atomic_write_text
from changing_slam_ros.io.output_dir import OutputDir

READY_MARKERS = {
    "object_map": "object_map: started",
    "detection": "detection: active",
    "tracking": "tracking: started",
    "local_mapping": "local_mapping: started",
    "loop_closing": "loop_closing: started",
}
# What nodes.map_resync logs when a (re)started map owner has its map back from tracking, or starts empty.
RESYNC_DONE_MARKERS = ("map restored from tracking's replica", "starting empty")
MAPS_DIR = "maps"  # in DIR: the map_dir of local_mapping's and object_map's SaveMap / LoadMap
# What the graph gives its nodes unless an option says otherwise, as node parameter values: (in real time, with
# --lossless). Real time: settings measured for six processes on two cores (bench/bench_graph_configs.py):
# one onnxruntime thread, the static INT8 SSD capped at 15 Hz by image stamp, tracking waiting up to 50 ms for a
# detected frame's boxes (the detector announces the frames it skips), the numpy Schur-complement BA solver.
# Lossless: the config's (-1, '' = the config's; every frame detected and waited for), so that the graph repeats
# `changing-slam run`. launch/changing_slam.launch.py takes the same as its 'auto' arguments.
MODE_DEFAULTS: dict[str, tuple[Any, Any]] = {
    "detector_threads": (1, -1),  # detection: intra_op_threads (--detector-threads)
    "detector_model": ("ssd_mobilenet_v2_coco_int8", ""),  # detection: model (--detector-model)
    "detection_max_hz": (15.0, 0.0),  # detection: max_rate_hz (--detection-max-hz; 0 = none)
    "detections_wait_s": (0.05, 10.0),  # tracking: detections_wait_s (--detections-wait)
    "ba_solver": ("schur", ""),  # local_mapping: ba_solver (--ba-solver)
}


def mode_default(name: str, lossless: bool) -> Any:
    """`MODE_DEFAULTS[name]` for real time or lossless."""
    return MODE_DEFAULTS[name][1 if lossless else 0]


def _uses_detections(config: str) -> bool:
    from changing_slam_ros.config import section
    from changing_slam_ros.core.dynamic.dynamic_filter import DynamicConfig
    from changing_slam_ros.nodes.slam_backend import load_backend_config

    cfg = load_backend_config(config)
    dyn = section(DynamicConfig, cfg.data.get("dynamic"), f"{cfg.where}: dynamic")
    return dyn.enabled and dyn.detection_filtering


class Graph:
    """The processes of one run; `run()` returns the summary dict.

    The nodes run on a random ROS_DOMAIN_ID unless ROS_DOMAIN_ID is set, discovery limited to this machine. It
    waits until each node says it is up, plays the bag, waits for the player to finish, asks tracking to write
    its outputs (SIGINT, then waits) and stops the rest (SIGINT, then SIGTERM, then SIGKILL). A node that dies
    before the end is restarted (at most --max-restarts times per node; the player resumes where it was, a
    tracking restart replays the bag from its start: `_restart`); `--kill object_map@5` kills a process on
    purpose after 5 s (fault test).

    Backends: `split` (default): tracking tracks against a replica of the map, `local_mapping` owns the map
    (local BA, object layer) and `loop_closing` closes loops, exchanging keyframe packets, map updates and loop
    results (`nodes/split_backend.py`); with --lossless tracking acknowledges a keyframe frame only once its
    map update and loop verdict are in, so the run repeats the offline order of work. `in_process`: tracking
    runs the whole `SlamSystem` itself (`nodes/slam_backend.py`) and local_mapping / loop_closing are not started.

    DIR receives: trajectory.txt (final), trajectory_online.txt, keyframes.txt, tracking_stats.json (from
    tracking), semantic_map.json, local_mapping_stats.json and map.npz (from local_mapping, the split backend's
    map owner: the whole map in `changing-slam run`'s format, for a later `--map-in`; semantic_map.json from
    tracking when in_process), outputs.mcap (the trajectories and the ground truth as PoseStamped topics, for
    evo and Foxglove, written after the run), semantic_map_node.json (object_map's saved map),
    logs/<node>.log (one per process start, `.1`, `.2` for restarts), graph_summary.json (frames, drops,
    latency, ATE, restarts, CPU seconds per process during playback: `commands/process_cpu.py`), and with the
    config's `dynamic.movers` on, moving_objects.json + moving_objects/object_<id>.txt (tracking's
    class-agnostic movers; in outputs.mcap as /moving_objects/object_<id>/pose, /tracking/moving_objects,
    /tracking/moving_object_markers). Drops: colour frames in the bag that did not become a pose, split by
    reason in `drops_by_reason` (`graph_outputs.DROP_REASONS`, docs/commands.md#drops-by-reason).

    Multi-session (`--map-in PREVIOUS/map.npz`, as `changing-slam run --map-in`): tracking, local_mapping and
    loop_closing each load the map file at start, tracking relocalises in the loaded current map first and the
    poses stay in its frame; local_mapping publishes the loaded semantic map, so object_map starts from it.
    `--load-map MAP@S` does the same mid-run: S seconds after the player's first message it calls
    local_mapping's LoadMap (`nodes/map_service_call.py`); local_mapping replaces its map, tracking and
    loop_closing follow its load marker. graph_summary.json `map_loads` holds each call's reply.
    """

    def __init__(self, args: argparse.Namespace) -> None:
        self.args = args
        self.config = str(Path(args.config).resolve()) if args.config and Path(args.config).is_file() else args.config
        if self.config:
            from changing_slam_ros.nodes.slam_backend import load_backend_config

            load_backend_config(self.config)  # a bad config fails here, before any process starts
        self.bag, self.info = self._open_source()
        self.detection = _uses_detections(self.config) if args.detection is None else args.detection
        self.kills = parse_kills(args.kill)
        self.loads = parse_loads(getattr(args, "load_map", []))
        self.load_calls: list[dict[str, Any]] = []  # one per --load-map: path, at_s, process, log
        self.map_loads: list[dict[str, Any]] = []  # their outcomes (graph_summary.json)
        self.map_in = ""
        loaded = None
        if args.map_in:
            from changing_slam_ros.io.map_file import load_map

            loaded = load_map(args.map_in)  # a bad map fails here, before any process starts
            self.map_in = str(Path(args.map_in).resolve())
        self.mismatches = camera_mismatches(self.bag, self.config or "", self.map_in, loaded) if self.bag else []
        for mismatch in self.mismatches:
            print(f"graph: warning: {mismatch.message()}", file=sys.stderr, flush=True)
        # Everything is written into a fresh folder beside --out, which replaces it when the run is complete
        # (`io.output_dir`); an interrupted run leaves --out as it was and its partial results aside.
        self.out_dir = OutputDir.prepare(Path(args.out).resolve(), "--out")
        self.out = self.out_dir.work
        self.logs = self.out / "logs"
        self.logs.mkdir(parents=True, exist_ok=True)
        self.env = child_env(dict(os.environ, **self._ros_env(), PYTHONUNBUFFERED="1",
                                  RCUTILS_LOGGING_BUFFERED_STREAM="0", ROS_LOG_DIR=str(self.logs / "ros")))  # fmt: skip
        # One OpenBLAS thread per node (unless set): six processes share the cores, and a second BLAS thread per
        # process only spins on the small products tracking and mapping do (in-process tracking + mapping on
        # the sim bag: 6.6 -> 5.9 s CPU, 9.6 -> 8.5 s wall for 150 frames).
        self.env.setdefault("OPENBLAS_NUM_THREADS", "1")
        self.nodes: dict[str, NodeProcess] = {}
        self.restarts: dict[str, int] = {}
        self._failures: dict[str, str] = {}  # node -> the error it last died with (`NodeProcess.failure`)
        self.cpu = PlayCpu()  # CPU seconds per process during playback (graph_summary.json)
        self.player: NodeProcess | None = None  # bag_player; none on live topics
        self.progress: GraphProgress | None = None
        try:
            self._build()
        except BaseException:
            shutil.rmtree(self.out, ignore_errors=True)
            raise

    def _open_source(self) -> tuple[str, BagInfo]:
        """The bag (absolute path) and what it holds; `graph_live.LiveGraph` listens to live topics instead."""
        check_bag_arguments(self.args)
        if not self.args.bag:
            raise ConfigError("no BAG given: name a bag to replay, or --live to listen to a camera driver's topics")
        bag = str(Path(self.args.bag).resolve())
        return bag, inspect_bag(bag)

    def _ros_env(self) -> dict[str, str]:
        """A domain of the run's own (unless ROS_DOMAIN_ID is set), discovery on this machine only."""
        domain = os.environ.get("ROS_DOMAIN_ID") or str(random.SystemRandom().randint(1, 99))
        return {"ROS_DOMAIN_ID": domain, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}

    def _sensor_inputs(self) -> tuple[dict[str, str], bool]:
        """Remappings of the TUM sensor topic names the nodes subscribe to, and whether the images come reliable
        (the player's, on Fast DDS across processes) rather than sensor-data best effort (a driver's)."""
        return {}, True

    def _build(self) -> None:
        a, info = self.args, self.info
        wait = a.detections_wait if a.detections_wait is not None else mode_default("detections_wait_s", a.lossless)
        split = a.backend == "split"
        if a.object_map:
            remaps = {"/tracking/semantic_map": "/local_mapping/semantic_map"} if split else None
            self.nodes["object_map"] = NodeProcess("object_map", node_argv("object_map_node", {
                "config": self.config, "map_file": str(self.out / "semantic_map_node.json"),
                "map_dir": str(self.out / MAPS_DIR)}, remaps), self.logs)  # fmt: skip
        if split:
            # Restarted, the map owner and the loop side take the current map from tracking, not the --map-in file.
            solver = a.ba_solver or mode_default("ba_solver", a.lossless)
            mapping = {"config": self.config, "output_dir": str(self.out), "wait_for_loop_results": bool(a.lossless),
                       "update_subscribers": 2, "map_out": str(self.out / "map.npz"),
                       "map_dir": str(self.out / MAPS_DIR),
                       "ba_solver": "" if solver == "config" else solver}  # fmt: skip
            # Started with tracking, they have nothing to take from it (a resync answer racing tracking's first
            # keyframe would make runs differ); restarted, they ask.
            first, restart = {"resync": False, "map_file": self.map_in}, {"resync": True, "map_file": ""}
            self.nodes["local_mapping"] = NodeProcess(
                "local_mapping", node_argv("local_mapping_node", {**mapping, **first}), self.logs,
                restart_argv=node_argv("local_mapping_node", {**mapping, **restart}))  # fmt: skip
            loop = {"config": self.config}
            self.nodes["loop_closing"] = NodeProcess(
                "loop_closing", node_argv("loop_closing_node", {**loop, **first}), self.logs,
                restart_argv=node_argv("loop_closing_node", {**loop, **restart}))  # fmt: skip
        if self.detection:
            sensor_remaps, reliable = self._sensor_inputs()
            remaps = {"image": sensor_remaps.get("/camera/rgb/image_color", "/camera/rgb/image_color"),
                      "image/compressed": "/camera/rgb/image_color/compressed"}  # fmt: skip
            threads = a.detector_threads if a.detector_threads is not None else mode_default("detector_threads", a.lossless)
            model = a.detector_model or mode_default("detector_model", a.lossless)
            from changing_slam_ros.core.dynamic.detector import SHIPPED_MODELS

            if model not in ("config", "") and model not in SHIPPED_MODELS:
                raise ConfigError(f"--detector-model {model}: not a shipped detector (shipped: "
                                  f"{', '.join(SHIPPED_MODELS)}; config: the config's)")  # fmt: skip
            max_hz = a.detection_max_hz if a.detection_max_hz is not None else mode_default("detection_max_hz", a.lossless)
            if max_hz < 0 or (max_hz > 0 and a.lossless):
                raise ConfigError(f"--detection-max-hz {max_hz}: must be >= 0, and 0 with --lossless (tracking waits "
                                  "for every frame's detections there)")  # fmt: skip
            self.nodes["detection"] = NodeProcess("detection", node_argv("detection_node", {
                "config": self.config, "compressed": info.compressed, "reliable_images": reliable,
                "intra_op_threads": int(threads), "model": "" if model == "config" else model,
                "max_rate_hz": float(max_hz),
                "output_wait_s": 120.0,  # tracking (starting beside it) subscribes first: no detection is lost
            }, remaps), self.logs)  # fmt: skip
        sensor_remaps, reliable = self._sensor_inputs()
        self.nodes["tracking"] = NodeProcess("tracking", node_argv("tracking_node", {
            "config": self.config, "output_dir": str(self.out), "compressed": info.compressed,
            "ack_topic": ACK_TOPIC, "detections_required": self.detection, "detections_wait_s": float(wait),
            "in_process_backend": not split, "wait_for_map_updates": bool(a.lossless and split),
            "reliable_images": reliable, "image_queue_depth": a.queue_depth, "map_file": self.map_in,
            "frame_policy": "all" if a.lossless else "latest", "detections_skip_late": not a.lossless,
            "stats_period_s": 1.0,  # its frame and pose counts: the progress line
        }, sensor_remaps), self.logs)  # fmt: skip
        if self.bag:
            self._build_player()
        processes = {**self.nodes, **({"bag_player": self.player} if self.player else {})}
        for name, increment in parse_nice(getattr(a, "nice", []), tuple(processes)).items():
            processes[name].nice = increment

    def _build_player(self) -> None:
        self.player_params = player_params(self.args, self.bag, self.info, self.detection)
        self.resume = ResumePoint()  # where the player started last (moved on by each restart)
        self.player = NodeProcess("bag_player", node_argv("bag_player_node", self.player_params), self.logs)

    # -- lifecycle ------------------------------------------------------------------------------
    def _start(self, node: NodeProcess, timeout_s: float) -> None:
        node.start(self.env)
        self._wait_ready(node, timeout_s)

    def _wait_ready(self, node: NodeProcess, timeout_s: float) -> None:
        marker = READY_MARKERS.get(node.name)
        deadline = time.monotonic() + timeout_s
        while marker and marker not in node.log_text():
            if not node.running():
                raise NodeFailed(node, f"exited with {node.proc.returncode if node.proc else '?'} while starting")
            if time.monotonic() > deadline:
                raise SlamError(f"graph: {node.name} not up after {timeout_s:.0f} s; see {node.log_path}")
            time.sleep(0.1)

    def _pids(self, with_player: bool = True) -> dict[str, int]:
        nodes = [*self.nodes.values(), *([self.player] if with_player and self.player else [])]
        return {n.name: n.proc.pid for n in nodes if n.proc is not None and n.proc.poll() is None}

    def _supervise(self, started_s: float) -> None:
        """Restart nodes that died (bounded), carry out --kill, until the player ends or the timeout."""
        pending_kills = list(self.kills)
        pending_loads = list(self.loads)
        first_message_s: float | None = None  # --load-map counts from the player's first message
        deadline = started_s + self.args.timeout
        while self._playing(started_s) or self._player_resumed():
            now = time.monotonic()
            if now > deadline and self.player is not None:
                raise SlamError(f"graph: still playing after --timeout {self.args.timeout:.0f} s; stopped")
            for name, at_s in list(pending_kills):
                target = self.player if name == "bag_player" else self.nodes.get(name)
                if now - started_s >= at_s and target is not None and target.running():
                    print(f"graph: --kill: SIGKILL {name} at {now - started_s:.1f} s", flush=True)
                    target.stop(signal.SIGKILL, 5.0)
                    pending_kills.remove((name, at_s))
            if pending_loads and first_message_s is None and (self.player is None or PLAYER_FIRST_MESSAGE in
                                                              self.player.log_text()):  # fmt: skip
                first_message_s = now
            for path, at_s in list(pending_loads):
                if first_message_s is not None and now - first_message_s >= at_s:
                    self._call_load_map(path, now - first_message_s)
                    pending_loads.remove((path, at_s))
            for node in self.nodes.values():
                if not node.running():
                    self._restart(node, killed=any(name == node.name for name, _ in self.kills))
            self.cpu.sample(self._pids())
            if self.progress is not None:
                self.progress.update(now)
            time.sleep(0.2)

    def _playing(self, started_s: float) -> bool:
        """Whether the run goes on: the player still plays."""
        return self.player is not None and self.player.running()

    def _player_resumed(self) -> bool:
        """A player killed by a signal (a --kill, the OOM killer) is restarted where it was (`resume_point`), within
        --max-restarts; one that exited by itself (0 at the end of the bag, else its own error, which a restart
        would repeat) ends the playback."""
        player = self.player
        if player is None or player.proc is None or player.proc.returncode is None or player.proc.returncode >= 0:
            return False
        self.resume = resume_point(player.log_text(), self.resume)
        player.restart_argv = node_argv("bag_player_node", {**self.player_params, **self.resume.params()})
        self._restart(player, killed=any(name == player.name for name, _ in self.kills))
        print(f"graph: bag_player resumes in pass {self.resume.first_pass + 1} at {self.resume.resume_at_s:.2f} s "
              "of the bag", flush=True)  # fmt: skip
        return True

    def _restart(self, node: NodeProcess, killed: bool) -> None:
        """Restart a dead node, or raise NodeFailed when that cannot help: it died more than --max-restarts
        times, or with the same error as the last time (a bad config, say: the next start fails alike).
        Tracking holds the trajectory and the map's replica, which die with it: in a bag replay it restarts with
        local_mapping and loop_closing afresh and the player from the bag's start (`_replay_from_start`)."""
        code = node.proc.returncode if node.proc is not None else -1
        node.exit_codes.append(code)
        failure = "" if killed else node.failure()
        if self.restarts.get(node.name, 0) >= self.args.max_restarts:
            raise NodeFailed(node, f"died (exit {code}) and was restarted {self.args.max_restarts} times "
                                   "(--max-restarts)")  # fmt: skip
        if failure and failure == self._failures.get(node.name):
            raise NodeFailed(node, f"died twice with the same error (exit {code}); a restart will not help")
        self._failures[node.name] = failure
        self.restarts[node.name] = self.restarts.get(node.name, 0) + 1
        print(f"graph: {node.name} died (exit {code}){': ' + failure if failure else ''}; restarting "
              f"({self.restarts[node.name]}/{self.args.max_restarts}); log {node.log_path}", flush=True)  # fmt: skip
        if node.name == "tracking" and self.player is not None:
            self._replay_from_start(node)
        else:
            self._start(node, 180.0)

    def _replay_from_start(self, tracking: NodeProcess) -> None:
        """The player and the map's other holders stopped, then tracking, local_mapping and loop_closing started as
        at the run's start (the --map-in file, if any) and the bag played again from its start: the outputs are
        then those of a run without the death (the ones before it are written over). A live graph cannot replay:
        its tracking restarts empty instead, a new map."""
        assert self.player is not None
        holders = [self.nodes[n] for n in ("local_mapping", "loop_closing") if n in self.nodes]
        stop_all([self.player, *holders], budget_s=4.0)
        for node in (tracking, *holders):
            node.start(self.env, fresh=True)
        for node in (tracking, *holders):
            self._wait_ready(node, 180.0)
        self.resume = ResumePoint()
        self.player.start(self.env, fresh=True)
        print("graph: tracking's trajectory and map died with it: local_mapping, loop_closing and the bag started "
              "again from the start", flush=True)  # fmt: skip

    def _call_load_map(self, path: str, at_s: float) -> None:
        """Start one LoadMap call (`nodes.map_service_call`) without waiting for it; `_finish_load_calls` collects it."""
        log = self.logs / f"load_map_{len(self.load_calls)}.log"
        print(f"graph: --load-map: LoadMap {path} at {at_s:.1f} s", flush=True)
        # local_mapping's LoadMap reads only inside its map_dir: the map goes there first
        name = f"load_{len(self.load_calls)}_{Path(path).name}"
        (self.out / MAPS_DIR).mkdir(parents=True, exist_ok=True)
        shutil.copyfile(path, self.out / MAPS_DIR / name)
        with open(log, "wb") as f:
            proc = subprocess.Popen([*python_argv(), "-m", "changing_slam_ros.nodes.map_service_call", "load", name,
                                     "--timeout", "60"], stdout=f, stderr=subprocess.STDOUT, env=self.env)  # fmt: skip
        self.load_calls.append({"path": path, "at_s": round(at_s, 2), "proc": proc, "log": log})

    def _finish_load_calls(self, timeout_s: float) -> list[dict[str, Any]]:
        """Wait for the LoadMap calls; their exit code (0 loaded, 1 refused, 2 no answer) and reply line."""
        done = []
        for c in self.load_calls:
            try:
                code: int | None = c["proc"].wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                c["proc"].kill()
                code = None
            lines = c["log"].read_text(errors="replace").strip().splitlines()
            done.append({"path": c["path"], "at_s": c["at_s"], "exit_code": code, "reply": lines[-1] if lines else ""})
        return done

    def _wait_resynced(self, timeout_s: float) -> None:
        """A map owner restarted near the end may not have its map back from tracking yet: wait for its resync
        (the log line `nodes.map_resync` writes when it has restored or started empty) before shutting down, so
        that what it writes at the end is the whole map, not an empty one."""
        deadline = time.monotonic() + timeout_s
        for name in ("local_mapping", "loop_closing"):
            node = self.nodes.get(name)
            if node is None or node.starts < 2:
                continue
            while node.running() and not any(m in node.log_text() for m in RESYNC_DONE_MARKERS):
                if time.monotonic() > deadline:
                    print(f"graph: {name} restarted but not resynced after {timeout_s:.0f} s; shutting down anyway",
                          flush=True)  # fmt: skip
                    return
                time.sleep(0.1)
            print(f"graph: {name} (restarted) has its map back from tracking", flush=True)

    def shutdown(self) -> dict[str, int | None]:
        """Tracking first (SIGINT: it writes its outputs), then the others; escalate to SIGTERM, SIGKILL."""
        codes: dict[str, int | None] = {}
        order = [n for n in ("tracking", "local_mapping", "loop_closing", "detection", "object_map")
                 if n in self.nodes] + (["bag_player"] if self.player else [])  # fmt: skip
        for name in order:
            node = self.player if name == "bag_player" else self.nodes[name]
            if node is None:
                continue
            code = node.stop(signal.SIGINT, 120.0 if name in ("tracking", "local_mapping") else 15.0)
            if code is None:
                code = node.stop(signal.SIGTERM, 10.0)
            if code is None:
                code = node.stop(signal.SIGKILL, 5.0)
            codes[name] = code
        return codes

    def run(self) -> dict[str, Any]:
        t0 = time.monotonic()
        try:
            for node in self.nodes.values():  # all at once: imports (gtsam, onnxruntime) take a while
                node.start(self.env)
            for node in self.nodes.values():
                self._wait_ready(node, 300.0)
            up_s = time.monotonic() - t0
            t_play = time.monotonic()
            self.cpu.start(self._pids(with_player=False))
            self.progress = GraphProgress(self.nodes["tracking"], self.player, self.info.colour_frames)  # per pass
            self._play(t_play, up_s)
            self.progress.finish()
            play_s = time.monotonic() - t_play
            if not self.args.lossless:
                time.sleep(1.0 if self.args.backend == "in_process" else 3.0)  # frames, keyframes, map updates in flight
            self.cpu.sample(self._pids(with_player=False))  # the work on the last frames counts too
            self._wait_resynced(120.0)
            self.map_loads = self._finish_load_calls(90.0)
        except NodeFailed as err:
            stop_all([*self.nodes.values(), *([self.player] if self.player else [])])
            for c in self.load_calls:
                c["proc"].kill()
            lines = err.node.last_lines(12)
            print(f"graph: {err.node.name}'s last log lines ({err.node.log_path}):\n"
                  + "\n".join(f"  {ln[:300]}" for ln in lines), file=sys.stderr, flush=True)  # fmt: skip
            raise
        except BaseException:
            if self.progress is not None:
                self.progress.finish()
            self.shutdown()
            raise
        codes = self.shutdown()
        return self._summary(play_s, up_s, codes)

    def _play(self, t_play: float, up_s: float) -> None:
        """Play the bag, supervising the nodes until the player ends."""
        assert self.player is not None
        print(f"graph: {', '.join(self.nodes)} up after {up_s:.1f} s (ROS_DOMAIN_ID {self.env['ROS_DOMAIN_ID']}); "
              f"playing {self.bag} at {self.args.rate}x{' lossless' if self.args.lossless else ''}", flush=True)
        self.player.start(self.env)
        self._supervise(t_play)
        if self.player.proc is not None and self.player.proc.returncode != 0:
            raise SlamError(f"graph: bag_player failed (exit {self.player.proc.returncode}); see {self.player.log_path}")

    # -- results --------------------------------------------------------------------------------
    def _summary(self, play_s: float, up_s: float, codes: dict[str, int | None]) -> dict[str, Any]:
        stats_path = self.out / "tracking_stats.json"
        stats = json.loads(stats_path.read_text()) if stats_path.is_file() else {}
        poses = int(stats.get("poses_published", 0))
        passes = self.args.loop if self.bag else 1
        frames_in = self.info.colour_frames * passes if self.bag else int(stats.get("colour_received") or 0)
        summary: dict[str, Any] = {
            "bag": self.bag or None, "config": self.config or "defaults", "rate": self.args.rate,
            "lossless": self.args.lossless, "colour_frames_in_bag": self.info.colour_frames if self.bag else None,
            "passes": passes, "colour_frames_played": frames_in if self.bag else None,
            "colour_received": stats.get("colour_received"),
            "frames_processed": stats.get("frames_processed"), "frames_tracked": stats.get("frames_tracked"),
            "poses_published": poses, "drops": frames_in - poses,
            "drops_by_reason": drops_by_reason(frames_in, stats) if stats else None,
            "unpaired_depth_dropped": stats.get("unpaired_depth_dropped"),
            "duplicates_dropped": {"colour": stats.get("colour_duplicates_dropped"),
                                   "depth": stats.get("depth_duplicates_dropped")},
            "latency_ms_median": stats.get("latency_ms_median"), "latency_ms_p90": stats.get("latency_ms_p90"),
            "process_ms_median": stats.get("process_ms_median"), "keyframes": stats.get("keyframes"),
            "process_cpu_ms_median": stats.get("process_cpu_ms_median"),
            "frames_skipped_waiting_for_map": stats.get("frames_skipped_waiting_for_map"),
            "provisional_points_created": stats.get("provisional_points_created"),
            "provisional_points_replaced": stats.get("provisional_points_replaced"),
            "detection_delay_ms_median": stats.get("detection_delay_ms_median"),
            "loops_closed": stats.get("loops_closed_split") if stats.get("backend") == "split" else stats.get("loops_closed"),
            "backend": self.args.backend, "map_updates_applied": stats.get("map_updates_applied"),
            "map_in": self.map_in or None,
            "map_update_latency_ms_median": stats.get("map_update_latency_ms_median"),
            "local_mapping": read_json(self.out / "local_mapping_stats.json"), "play_wall_s": play_s, "startup_s": up_s,
            "bag_duration_s": self.info.duration_s, "detection_node": self.detection,
            "frames_without_detections": stats.get("frames_without_detections"),
            "frames_with_carried_detections": stats.get("frames_with_carried_detections"),
            "frames_dropped_stale": stats.get("frames_dropped_stale"),
            "detections_skipped_received": stats.get("detections_skipped_received"),
            "frames_not_waited_for_late_detections": stats.get("frames_not_waited_for_late_detections"),
            "restarts": dict(self.restarts), "exit_codes": codes, "map_loads": self.map_loads,
            "detection_ms_median": detection_median_ms(self.nodes.get("detection")),
            "detections_received": stats.get("detections_received"),
            "detection_rate_hz": (stats.get("detections_received") or 0) / play_s if play_s > 0 else None,
        }  # fmt: skip
        summary["lossless_incomplete"] = (lossless_gaps(self.player.log_text(), stats, summary["local_mapping"])
                                          if self.args.lossless and self.player else [])  # fmt: skip
        summary.update(play_cpu_summary(self.cpu, self.player.log_text() if self.player else "", frames_in))
        summary["provenance"] = graph_provenance(self.config, self.args)
        summary.update(self._source_summary())
        summary.update(evaluate(self.bag, self.config, self.out) if self.bag else
                       {"evaluation_error": "live topics: no ground truth"})  # fmt: skip
        summary["outputs_mcap"] = write_outputs_mcap(self.bag, self.config, self.out)
        summary["map_out"] = str(self.out_dir.path_after_commit(self.out / "map.npz")) \
            if (self.out / "map.npz").is_file() else None  # fmt: skip
        movers = read_json(self.out / "moving_objects.json")
        summary["moving_objects"] = len(movers["objects"]) if movers else None
        summary["camera_mismatch"] = [m.as_dict() for m in self.mismatches]
        summary["warnings"] = graph_warnings(summary, self.mismatches)
        atomic_write_text(self.out / "graph_summary.json", json.dumps(summary, indent=2) + "\n")
        return summary


    def _source_summary(self) -> dict[str, Any]:
        """What graph_summary.json says about the input beyond the bag's path (`LiveGraph`: its topics)."""
        return {}


def _raise_interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt


def main(args: argparse.Namespace) -> int:
    if getattr(args, "live", False):
        from changing_slam_ros.commands.graph_live import LiveGraph

        graph: Graph = LiveGraph(args)
    else:
        graph = Graph(args)
    previous = signal.signal(signal.SIGTERM, _raise_interrupt)  # `timeout`/kill: still stop the children
    try:
        s = graph.run()
    except BaseException:
        kept = graph.out_dir.abandon()
        if kept is not None:
            print(f"graph: stopped; partial results kept in {kept} ({args.out} unchanged)", file=sys.stderr)
        raise
    finally:
        signal.signal(signal.SIGTERM, previous)
    graph.out_dir.commit()
    ate_text = f"ATE RMSE {s['ate_rmse_m'] * 100:.2f} cm (online {s.get('ate_online_rmse_m', float('nan')) * 100:.2f} cm)" \
        if "ate_rmse_m" in s else f"no ATE ({s.get('evaluation_error', 'no ground truth')})"  # fmt: skip
    lat = s["latency_ms_median"]
    frames = s["colour_frames_played"] if s["colour_frames_played"] is not None else (s["colour_received"] or 0)
    print(
        f"{s['poses_published']}/{frames} {'frames' if graph.bag else 'frames received'} with a pose "
        f"({drops_text(s['drops'], s['drops_by_reason'] or {})}), "
        f"{s['keyframes']} keyframes, {s['loops_closed']} loops, {ate_text}, image-to-pose latency median "
        + (f"{lat:.0f} ms" if lat is not None else "n/a")
        + (f", detection {s['detection_rate_hz']:.1f} Hz" if s.get("detection_node") and s.get("detection_rate_hz") else "")
        + (f", restarts {s['restarts']}" if s["restarts"] else "")
    )
    if s.get("lossless_incomplete"):
        print("graph: warning: lossless run incomplete: " + "; ".join(s["lossless_incomplete"]), file=sys.stderr)
    for warning in s["warnings"][len(graph.mismatches):]:  # the camera ones were said before the start
        print(f"graph: warning: {warning}", file=sys.stderr)
    cpu = s.get("cpu_ms_per_bag_frame") or {}
    if cpu:
        print("CPU ms per bag frame during playback: " + ", ".join(f"{k} {v:.1f}" for k, v in cpu.items()))
    print(f"results in {graph.out_dir.target}")
    return 1 if frames and not s["frames_tracked"] else 0  # nothing useful produced
