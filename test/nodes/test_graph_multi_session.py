"""Multi-session in the split graph: a map saved by `changing-slam run` (the simulator's `static`, 150 frames,
320x240 at 15 fps, oracle or no detections), then `shift` (the same room with objects moved, the same start)
continued from it.

In-process, the three sides (tracking replica, map owner, loop side) each load the file and run in the graph's
lossless order: the trajectory equals `SlamSystem.start_from_map`'s, with the saved objects and their point
flags. As processes, `changing-slam graph BAG --map-in` gives byte for byte the trajectory of
`changing-slam run BAG --map-in` (measured: 90/90 frames, relocalised at frame 0, 0.21 cm ATE in the saved map's
frame; the first session's ATE 0.26 cm).
"""

from __future__ import annotations

import itertools
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]

FPS, WIDTH, HEIGHT = 15.0, 320, 240
FRAMES = {"static": 150, "shift": 90}


@pytest.fixture(scope="module")
def saved_runs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Both scenes rendered (folders and mcaps) and the first session run with oracle detections and without."""
    from changing_slam_ros.cli import main as cli_main
    from changing_slam_ros.io.dataset import open_dataset
    from changing_slam_ros.io.mcap_writer import write_rgbd_mcap
    from changing_slam_ros.sim.scenarios import build_scenario
    from changing_slam_ros.sim.sequence import RenderOptions, simulate

    root = tmp_path_factory.mktemp("graph_multi_session")
    for name, n in FRAMES.items():
        simulate(build_scenario(name, 0), root / name, RenderOptions(width=WIDTH, height=HEIGHT, frames=n, fps=FPS), 0)
        write_rgbd_mcap(root / f"{name}.mcap", itertools.islice(iter(open_dataset(root / name, "sim")), n))
    for out, source, dets in (("first_oracle", root / "static", "oracle"), ("first", root / "static.mcap", "none")):
        rc = cli_main(["run", str(source), "--out", str(root / out), "--config", "sim", "--no-plot", "--quiet",
                       "--detections", dets])  # fmt: skip
        assert rc == 0 and (root / out / "map.npz").is_file()
    return root


def test_the_split_sides_started_from_a_saved_map_track_as_the_offline_system(saved_runs):
    from changing_slam_ros.io.dataset import open_dataset
    from changing_slam_ros.io.detections_file import find_detections_file, read_detections_file
    from changing_slam_ros.io.map_file import load_map
    from changing_slam_ros.nodes.slam_backend import build_backend, load_backend_config
    from changing_slam_ros.nodes.split_chains import ChainedGraph

    cfg = load_backend_config("sim")
    map_file = saved_runs / "first_oracle" / "map.npz"
    offline = build_backend(cfg).system
    loaded = load_map(map_file)
    offline.start_from_map(loaded.atlas, loaded.next_keyframe_id, loaded.objects)
    graph = ChainedGraph.build(cfg)
    graph.start_from_map(map_file, cfg)
    assert loaded.objects and graph.owner.backend.objects is not None
    n_loaded = loaded.atlas.n_keyframes
    assert graph.tracking.system.atlas.n_keyframes == graph.loop.atlas.n_keyframes == n_loaded
    oracle = read_detections_file(find_detections_file(saved_runs / "shift"))
    for rgbd in open_dataset(saved_runs / "shift", "sim"):
        dets = oracle.for_stamp(rgbd.stamp_ns)
        offline.process(rgbd, dets)
        graph.process(rgbd, dets)
    a, b = offline.online_trajectory(), graph.tracking.system.online_trajectory()
    assert len(a) == len(b) == FRAMES["shift"]
    np.testing.assert_array_equal(a.poses(), b.poses())
    assert graph.owner.atlas.n_keyframes == offline.atlas.n_keyframes > n_loaded  # new keyframes in the old map
    assert len(graph.owner.atlas.maps) == len(offline.atlas.maps) == 1  # relocalised: no new map
    # The three maps agree on which points are active (the replicas set the loaded objects' flags themselves); by
    # id, a culled point reading as gone whether or not its store has compacted its row yet.
    flags = [m.points.column_arrays()["active"] for m in
             (graph.owner.atlas.maps[0], graph.tracking.system.atlas.maps[0], graph.loop.atlas.maps[0])]  # fmt: skip
    for f in flags[1:]:
        np.testing.assert_array_equal(f, flags[0])
    np.testing.assert_array_equal(flags[0], offline.atlas.maps[0].points.column_arrays()["active"])
    owner_objs = graph.owner.backend.objects.objects(0)
    assert [(o.id, o.belief, o.active) for o in owner_objs] == \
        [(o.id, o.belief, o.active) for o in offline.object_layer.objects(0)]  # fmt: skip


def test_graph_with_map_in_continues_the_saved_map_as_the_offline_runner(saved_runs, tmp_path):
    from changing_slam_ros.cli import main as cli_main
    from helpers import REPO

    pytest.importorskip("rclpy")
    pytest.importorskip("changing_slam_msgs.msg", reason="interfaces not built (tools/build_interfaces.sh)")
    map_file = saved_runs / "first" / "map.npz"
    offline = tmp_path / "offline"
    assert cli_main(["run", str(saved_runs / "shift.mcap"), "--out", str(offline), "--config", "sim", "--no-plot",
                     "--quiet", "--detections", "none", "--map-in", str(map_file)]) == 0  # fmt: skip
    out = tmp_path / "graph"
    proc = subprocess.run(
        [sys.executable, "-m", "changing_slam_ros", "graph", str(saved_runs / "shift.mcap"), "--out", str(out),
         "--config", "sim", "--lossless", "--no-detection", "--map-in", str(map_file), "--timeout", "600"],
        cwd=REPO, capture_output=True, text=True, timeout=900,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    s = json.loads((out / "graph_summary.json").read_text())
    assert s["map_in"] == str(map_file) and (s["poses_published"], s["drops"]) == (FRAMES["shift"], 0)
    for node in ("tracking", "local_mapping", "loop_closing"):
        assert f"loaded from {map_file}" in (out / "logs" / f"{node}.log").read_text()
    # In the saved map's frame (no new map), byte for byte the offline --map-in run.
    metrics = json.loads((offline / "metrics.json").read_text())
    assert metrics["multi_session"]["relocalised_frame"] == 0 and metrics["maps"] == 1
    for name in ("trajectory.txt", "trajectory_online.txt"):
        assert (out / name).read_text() == (offline / name).read_text(), name
    assert s["ate_rmse_m"] < 0.02
