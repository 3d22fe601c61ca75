"""`changing-slam graph --live` fed as a camera driver feeds it: a publisher in this process at 30 Hz, wall-clock
stamps, sensor-data QoS (best effort), rgb8 colour and 16UC1 millimetre depth on realsense2_camera's Jazzy topics,
no bag_player and no /clock; the graph runs until Ctrl-C (SIGINT) and writes its outputs."""

from __future__ import annotations

import json
import os
import queue
import random
import signal
import subprocess
import sys
import threading
import time

import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]

pytest.importorskip("rclpy")
pytest.importorskip("changing_slam_msgs.msg", reason="interfaces not built (tools/build_interfaces.sh)")

FRAMES = 150
RATE_HZ = 30.0


def _frames(n: int) -> tuple[list, object]:
    """The first n frames (colour, depth in metres) of the bundled simulated bag (320x240), and its camera."""
    from helpers import REPO, require

    from changing_slam_ros.io.dataset import open_dataset

    frames, camera = [], None
    for frame in open_dataset(require(REPO / "bags" / "sim_walking_changing.mcap"), "sim"):
        frames.append((frame.rgb.copy(), frame.depth_m.copy()))
        camera = frame.camera
        if len(frames) == n:
            break
    return frames, camera


def _lines(stream, out: queue.Queue) -> None:  # noqa: ANN001 - a text pipe
    for line in stream:
        out.put(line)


def test_live_graph_poses_most_frames_of_a_30_hz_best_effort_camera_and_publishes_tf(tmp_path, monkeypatch):
    import rclpy
    from geometry_msgs.msg import PoseStamped
    from tf2_msgs.msg import TFMessage

    from changing_slam_ros.io.dataset_config import REALSENSE_JAZZY_TOPICS as TOPICS

    frames, camera = _frames(FRAMES)
    domain = random.Random(os.getpid()).randint(100, 200)
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain))
    out = tmp_path / "live"
    from helpers import REPO, default_sigint

    graph = subprocess.Popen(
        [sys.executable, "-m", "changing_slam_ros", "graph", "--live", "--topics", "realsense_jazzy", "--out",
         str(out), "--config", "sim", "--no-detection", "--no-object-map"],
        cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, preexec_fn=default_sigint,
    )  # fmt: skip
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=_lines, args=(graph.stdout, lines), daemon=True).start()
    log: list[str] = []
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain)
    try:
        deadline = time.monotonic() + 300
        while not any("listening to" in ln for ln in log):
            assert graph.poll() is None and time.monotonic() < deadline, "".join(log)
            try:
                log.append(lines.get(timeout=1.0))
            except queue.Empty:
                pass
        from changing_slam_ros.nodes.camera_feed import CameraFeed

        node = rclpy.create_node("fake_realsense", context=context)
        driver = CameraFeed(node, TOPICS, camera)
        poses: list[int] = []
        edges: set[tuple[str, str]] = set()
        node.create_subscription(PoseStamped, "/tracking/pose",
                                 lambda m: poses.append(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec), 100)
        node.create_subscription(TFMessage, "/tf", lambda m: edges.update(
            (t.header.frame_id, t.child_frame_id) for t in m.transforms), 100)  # fmt: skip
        executor = rclpy.executors.SingleThreadedExecutor(context=context)
        executor.add_node(node)
        while not driver.ready():  # tracking has subscribed
            assert time.monotonic() < deadline
            executor.spin_once(timeout_sec=0.05)
        # the driver: each frame stamped with the wall clock as it goes out, every 1/30 s
        sent, feed_s = driver.play(executor, frames, RATE_HZ)
        end = time.monotonic() + 5.0  # the last frames, keyframes and map updates in flight
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
        graph.send_signal(signal.SIGINT)  # Ctrl-C: the run ends and the nodes write their outputs
        graph.wait(timeout=240)
    finally:
        if graph.poll() is None:
            graph.kill()
        context.try_shutdown()
    while not lines.empty():
        log.append(lines.get())
    text = "".join(log)
    assert graph.returncode == 0, text
    assert abs(feed_s - (FRAMES - 1) / RATE_HZ) < 0.5, feed_s  # the feed kept its 30 Hz
    s = json.loads((out / "graph_summary.json").read_text())
    assert s["bag"] is None and s["live"]["colour_topic"] == TOPICS.rgb and s["live"]["preset"] == "realsense_jazzy"
    # Measured on the 2-core test machine, shared with other work (load 3-4): 89, 117, 128, 137 and 142 of the 150
    # frames posed. Every frame tracking received was posed (one at most missing); the others never reached it:
    # sensor-data QoS keeps the last 5 and drops the older when tracking (~32 ms CPU per frame here) falls behind
    # 30 Hz, single frames, as a driver's frames are dropped when the cores are busy.
    posed = set(poses)
    assert posed <= set(sent) and len(posed) >= 0.5 * FRAMES, (len(posed), text)
    assert s["poses_published"] == len(posed) >= s["colour_received"] - 2
    assert {("map", "odom"), ("odom", "camera")} <= edges
    assert s["keyframes"] >= 2 and (out / "map.npz").is_file() and (out / "outputs.mcap").is_file()
    assert "graph: received " in text  # the progress line (not a tty: one every 10 s)
    assert "graph: stopping (Ctrl-C)" in text and f"{len(posed)}/{s['colour_received']} frames received with a pose" in text
    traj = (out / "trajectory_online.txt").read_text().split("\n")
    assert len([ln for ln in traj if ln and not ln.startswith("#")]) == len(posed)
    print(f"live feed: {len(posed)}/{FRAMES} frames posed, latency median {s['latency_ms_median']:.0f} ms")
