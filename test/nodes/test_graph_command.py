"""`changing-slam graph` end to end: the bundled bags through bag_player, detection, tracking, local_mapping,
loop_closing and object_map as separate processes (the split backend), with object_map killed mid-run."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]

pytest.importorskip("rclpy")
pytest.importorskip("changing_slam_msgs.msg", reason="interfaces not built (tools/build_interfaces.sh)")


def test_graph_replays_the_fr1_bag_losslessly_within_offline_accuracy_and_restarts_a_killed_node(tmp_path):
    from helpers import REPO, require

    bag = require(REPO / "bags" / "tum_fr1_xyz_first10.mcap")
    out = tmp_path / "graph"
    proc = subprocess.run(
        [sys.executable, "-m", "changing_slam_ros", "graph", str(bag), "--out", str(out), "--config", "tum_fr1",
         "--lossless", "--kill", "object_map@1", "--timeout", "600"],
        cwd=REPO, capture_output=True, text=True, timeout=900,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    s = json.loads((out / "graph_summary.json").read_text())
    # Lossless: each of the 9 colour frames paired, tracked and published as a pose; detections for every one.
    assert (s["colour_frames_in_bag"], s["poses_published"], s["drops"]) == (9, 9, 0)
    assert s["detection_node"] and s["frames_without_detections"] == 0
    # Offline `changing-slam run` on this bag: ATE 0.36 cm; the graph runs the same system on the same frames.
    assert s["ate_rmse_m"] < 0.01
    assert "9/9 frames with a pose (0 dropped)" in proc.stdout
    # object_map was killed (SIGKILL) 1 s into the replay, restarted once, and everything stopped cleanly.
    assert s["restarts"] == {"object_map": 1}
    assert "object_map: started" in (out / "logs" / "object_map.1.log").read_text()
    assert s["exit_codes"] == {"tracking": 0, "local_mapping": 0, "loop_closing": 0, "detection": 0, "object_map": 0,
                               "bag_player": 0}  # fmt: skip
    for name in ("trajectory.txt", "trajectory_online.txt", "keyframes.txt", "tracking_stats.json", "semantic_map.json",
                 "local_mapping_stats.json"):  # fmt: skip
        assert (out / name).is_file(), name
    # The map was built in local_mapping: every keyframe tracking sent was mapped and its update applied.
    lm = s["local_mapping"]
    assert s["backend"] == "split" and lm["keyframes_mapped"] == lm["keyframes_received"] - lm["keyframes_duplicate"]
    assert lm["keyframes_mapped"] >= s["keyframes"] >= 1
    assert s["map_updates_applied"] >= s["keyframes"]
    from changing_slam_ros.io.bag_messages import BagMessages

    with BagMessages(out / "outputs.mcap") as recorded:  # for evo_ape bag2 / Foxglove
        counts = {k: v.msgcount for k, v in recorded.topics.items()}
    assert counts["/tracking/pose"] == 9 and counts["/ground_truth/pose"] >= 9


def test_graph_without_detections_reproduces_the_offline_runner_byte_for_byte(tmp_path):
    """Same code, two transports: lossless replay through the split processes (tracking, local_mapping,
    loop_closing exchanging keyframe packets and map updates) gives the offline trajectory exactly."""
    from helpers import REPO, require

    bag = require(REPO / "bags" / "tum_fr1_xyz_first10.mcap")
    offline, graph = tmp_path / "offline", tmp_path / "graph"
    run = subprocess.run(
        [sys.executable, "-m", "changing_slam_ros", "run", str(bag), "--out", str(offline), "--config", "tum_fr1",
         "--detections", "none", "--no-plot", "--quiet"], cwd=REPO, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    proc = subprocess.run(
        [sys.executable, "-m", "changing_slam_ros", "graph", str(bag), "--out", str(graph), "--config", "tum_fr1",
         "--lossless", "--no-detection", "--no-object-map"], cwd=REPO, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    for name in ("trajectory.txt", "trajectory_online.txt", "keyframes.txt"):
        text = (graph / name).read_text()
        assert len(text.splitlines()) >= 2 and text == (offline / name).read_text(), name
    # local_mapping saved the map it owns at shutdown (map.npz, the offline format): the same keyframes, points,
    # descriptors, objects and graph as the offline map, all but tracking's per-point counters since the last
    # keyframe (they reach the owner with the next keyframe packet, and there is none after the last).
    import numpy as np

    counters = {"pt_n_found", "pt_n_visible", "pt_last_seen_frame"}
    with np.load(graph / "map.npz") as g, np.load(offline / "map.npz") as o:
        assert sorted(g.files) == sorted(o.files)
        for name in g.files:
            if name.split("_", 1)[1] in counters:
                assert g[name].shape == o[name].shape and np.all(g[name] <= o[name]), name
            else:
                np.testing.assert_array_equal(g[name], o[name], err_msg=name)
        assert not np.array_equal(g["m0_pt_n_visible"], o["m0_pt_n_visible"])  # 8 frames after the one keyframe
    summary = json.loads((graph / "graph_summary.json").read_text())
    assert summary["poses_published"] == 9
    # CPU per process during playback: tracking tracked 9 frames of 640x480 (~30 ms each), local mapping mapped
    # (the player's own play() figure, from its log line, is there too); the total is the sum per bag frame.
    cpu, per_frame = summary["cpu_s_during_play"], summary["cpu_ms_per_bag_frame"]
    assert set(cpu) == {"tracking", "local_mapping", "loop_closing", "bag_player"}
    assert 0.1 < cpu["tracking"] < 30.0 and cpu["local_mapping"] > 0.0 and cpu["bag_player"] < 5.0
    frames = summary["colour_frames_in_bag"]
    assert abs(per_frame["total"] - 1e3 * sum(cpu.values()) / frames) < 0.05 * len(cpu)


def test_graph_on_the_simulated_changing_scene_builds_the_semantic_map(tmp_path):
    """The bundled simulated bag (person walking, chair and cup moved) through detection, tracking and object_map."""
    from helpers import REPO, require

    bag = require(REPO / "bags" / "sim_walking_changing.mcap")
    out = tmp_path / "graph"
    proc = subprocess.run(
        [sys.executable, "-m", "changing_slam_ros", "graph", str(bag), "--out", str(out), "--config", "sim", "--lossless"],
        cwd=REPO, capture_output=True, text=True, timeout=1500,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    s = json.loads((out / "graph_summary.json").read_text())
    assert (s["poses_published"], s["drops"]) == (225, 0)
    assert s["frames_without_detections"] == 0, s["frames_without_detections"]
    # Measured on the re-rendered sample (articulated people the detector finds): 1.64 cm, as `changing-slam run
    # --config sim` on the bag (the old flat-photo walker gave 13.6 cm); the bound leaves room for core changes.
    assert s["ate_rmse_m"] < 0.04
    # every keyframe mapped in local_mapping once (some culled later: >= the final count); started with tracking,
    # local_mapping asks for no map snapshot, so no keyframe comes twice and none is restored from tracking's replica
    lm = s["local_mapping"]
    assert s["backend"] == "split" and lm["keyframes_mapped"] == lm["keyframes_received"], lm
    assert (lm["keyframes_duplicate"], lm["restored_keyframes"]) == (0, 0), lm
    assert lm["keyframes_mapped"] >= s["keyframes"]
    assert s["lossless_incomplete"] == []  # no ack or map-update wait timed out, every keyframe came back mapped
    # What object_map received from local_mapping's object layer (/local_mapping/semantic_map, autosaved): the
    # monitor (COCO tv) on the table, confirmed, where the simulator put it (map aligned to ground truth by the
    # trajectory). A second tv may be the rocket poster on the wall, which the SSD calls tv (score 0.3-0.53)
    # while the image top cuts it.
    import numpy as np

    from changing_slam_ros.eval.object_alignment import trajectory_alignment
    from changing_slam_ros.eval.object_metrics import load_ground_truth_objects
    from changing_slam_ros.io.tum_trajectory import read_tum_trajectory

    gt_dir = REPO / "bags" / "sim_walking_changing_gt"
    T = trajectory_alignment(read_tum_trajectory(gt_dir / "groundtruth.txt"), read_tum_trajectory(out / "trajectory.txt"))
    truth = load_ground_truth_objects(gt_dir / "objects.json")
    box = next(o for o in truth.objects if o.name == "monitor").box_at(len(truth.stamps_ns) - 1)
    monitor = (box[0] + box[1]) / 2.0
    objects = json.loads((out / "semantic_map_node.json").read_text())["objects"]
    tvs = [o for o in objects if o["class_name"] == "tv" and o["active"]]
    dist = [float(np.linalg.norm(T[:3, :3] @ np.asarray(o["box_center_m"]) + T[:3, 3] - monitor)) for o in tvs]
    near = [o for o, d in zip(tvs, dist) if d < 0.15]
    assert len(near) == 1 and near[0]["belief"] >= 0.6 and near[0]["n_points"] > 500, (dist, tvs)
    assert all(d > 1.0 for d in dist if d >= 0.15)  # nothing else called tv near the monitor


def test_a_killed_local_mapping_is_restarted_and_maps_what_it_missed(tmp_path):
    """local_mapping (the map owner) killed as the player starts a lossless replay: restarted, it asks tracking for
    the map, gets the keyframe it missed sent again (or, had the kill come after it was mapped, the map holding it),
    and the run ends as without the kill. The kill time is a race with the first keyframe on any machine (CI once
    saw the map-restore order with a kill at 1 s); both orders are correct recovery, and both are accepted."""
    from helpers import REPO, require

    bag = require(REPO / "bags" / "tum_fr1_xyz_first10.mcap")
    out = tmp_path / "graph"
    proc = subprocess.run(
        [sys.executable, "-m", "changing_slam_ros", "graph", str(bag), "--out", str(out), "--config", "tum_fr1",
         "--lossless", "--no-detection", "--no-object-map", "--kill", "local_mapping@0"],
        cwd=REPO, capture_output=True, text=True, timeout=900,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    s = json.loads((out / "graph_summary.json").read_text())
    assert s["restarts"] == {"local_mapping": 1} and s["exit_codes"]["local_mapping"] == 0
    assert (s["poses_published"], s["drops"]) == (9, 0) and s["ate_rmse_m"] < 0.01  # offline: 0.36 cm
    lm = s["local_mapping"]
    # the first keyframe reached the restarted owner either re-sent (mapped by it) or inside tracking's map snapshot
    assert lm["keyframes_mapped"] + lm["restored_keyframes"] >= 1, lm
    assert lm["keyframes_in_map"] >= 1 and lm["map_points"] > 300, lm
    assert "going on" not in (out / "logs" / "tracking.log").read_text()  # no map update was waited for in vain
