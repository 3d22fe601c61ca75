"""The graph on a live camera: frames published as a driver publishes them, poses counted (prints only).

    .venv/bin/python bench/bench_live_feed.py SEQUENCE [--frames 300] [--rate 30] [--config sim]
        [--topics realsense_jazzy] [--runs 1] [--work DIR] [-- GRAPH_OPTIONS...]

`changing-slam graph --live` starts with the full default graph (detection and object_map included; pass graph
options after `--` to change that), then this process publishes the first `--frames` frames of SEQUENCE (any
dataset `changing-slam run` reads: a bag, a TUM or simulator folder) on the preset's colour, depth and
camera_info topics at `--rate` Hz: wall-clock stamps, sensor-data QoS (best effort, depth 5), rgb8 colour and
16UC1 millimetre depth, no player and no /clock. After the last frame it waits 5 s, stops the graph with Ctrl-C
and reads its `graph_summary.json`. Per run it prints frames sent and posed, the image-to-pose latency median
(the graph's own figure: colour message received to pose published) and the rate the driver kept, and the
median over runs at the end; no ATE (the frames carry wall-clock stamps, not the sequence's). A frame the driver
sends and tracking never receives (sensor-data QoS drops the oldest when a subscriber falls behind) counts as
not posed; the frames not posed are split into those before the first posed one (the subscriber had not yet
matched the driver's publishers: discovery is matched from both ends, and best effort keeps nothing for a
late reader) and those after it.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from bench_graph_cpu import REPO, start_graph


def load_frames(sequence: str, config: str, n: int) -> tuple[list, Any]:
    """The first `n` frames (colour, depth in metres) of `sequence` and its camera."""
    from changing_slam_ros.io.dataset import open_dataset

    frames, camera = [], None
    for frame in open_dataset(sequence, config):
        frames.append((frame.rgb.copy(), frame.depth_m.copy()))
        camera = frame.camera
        if len(frames) == n:
            break
    return frames, camera


def feed(frames: list, camera: Any, out: Path, args: argparse.Namespace, graph_options: list[str]) -> dict:
    """One graph run fed `frames` at `args.rate` Hz; its summary plus what the driver saw."""
    import rclpy
    from geometry_msgs.msg import PoseStamped
    from rclpy.executors import SingleThreadedExecutor

    from changing_slam_ros.io.dataset_config import TOPIC_PRESETS
    from changing_slam_ros.nodes.camera_feed import CameraFeed

    topics = TOPIC_PRESETS[args.topics]
    domain = random.Random(os.getpid() + time.time_ns()).randint(100, 200)
    env = {"ROS_DOMAIN_ID": str(domain), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    argv = [sys.executable, "-m", "changing_slam_ros", "graph", "--live", "--topics", args.topics, "--out", str(out),
            "--config", args.config, *graph_options]  # fmt: skip
    graph, listening, log, _ = start_graph(argv, REPO, lambda line: "listening to" in line, env)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain)
    posed: list[int] = []
    try:
        if not listening.wait(300) or graph.poll() is not None:
            raise SystemExit("bench_live_feed: the graph did not start:\n" + "".join(log[-20:]))
        node = rclpy.create_node("bench_camera_driver", context=context)
        driver = CameraFeed(node, topics, camera)
        node.create_subscription(PoseStamped, "/tracking/pose",
                                 lambda m: posed.append(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec), 100)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        deadline = time.monotonic() + 120
        while not driver.ready():
            if time.monotonic() > deadline:
                raise SystemExit("bench_live_feed: tracking never subscribed to the camera topics")
            executor.spin_once(timeout_sec=0.05)
        sent, feed_s = driver.play(executor, frames, args.rate)
        end = time.monotonic() + 5.0
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
        graph.send_signal(signal.SIGINT)
        graph.wait(timeout=300)
    finally:
        if graph.poll() is None:
            graph.kill()
        context.try_shutdown()
    summary_path = out / "graph_summary.json"
    if graph.returncode != 0 or not summary_path.is_file():
        raise SystemExit(f"bench_live_feed: the graph exited {graph.returncode}:\n" + "".join(log[-20:]))
    summary = json.loads(summary_path.read_text())
    got = set(posed)
    missing = [i for i, stamp in enumerate(sent) if stamp not in got]
    leading = next((i for i, stamp in enumerate(sent) if stamp in got), len(sent))
    return {"sent": len(sent), "posed": len(got), "feed_s": feed_s, "summary": summary, "leading_missing": leading,
            "missing": missing}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sequence")
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--rate", type=float, default=30.0)
    ap.add_argument("--config", default="sim")
    ap.add_argument("--topics", default="realsense_jazzy")
    ap.add_argument("--runs", type=int, default=1)
    ap.add_argument("--work", type=Path, default=None)
    args, rest = ap.parse_known_args()
    graph_options = rest[1:] if rest[:1] == ["--"] else rest
    frames, camera = load_frames(args.sequence, args.config, args.frames)
    work = args.work or Path(tempfile.mkdtemp(prefix="bench_live_feed_"))
    rows = []
    for i in range(args.runs):
        r = feed(frames, camera, work / f"run{i}", args, graph_options)
        s = r["summary"]
        rows.append((r["posed"], s.get("latency_ms_median", float("nan"))))
        print(f"run {i}: {r['posed']}/{r['sent']} frames posed at {r['sent'] / r['feed_s']:.1f} Hz sent, latency median "
              f"{s.get('latency_ms_median', float('nan')):.1f} ms, colour received {s.get('colour_received')}; "
              f"not posed: the first {r['leading_missing']} frames, then {len(r['missing']) - r['leading_missing']}",
              flush=True)  # fmt: skip
    posed, latency = statistics.median(r[0] for r in rows), statistics.median(r[1] for r in rows)
    print(f"median over {len(rows)} runs: {posed:.0f}/{len(frames)} posed, latency median {latency:.1f} ms; outputs in {work}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
