"""Fault injection: each of the six processes of `changing-slam graph` killed (SIGKILL) in turn while the fr1 bag
plays losslessly at 0.1x; the graph restarts it and the run ends as an undisturbed one: all 9 frames with a pose
(the lossless run's count), the trajectory, the map and the semantic map written. A killed player resumes where it
was (tracking drops the frames it sends again); a killed tracking, whose trajectory and map replica die with it,
is restarted with local_mapping and loop_closing afresh and the bag replayed from its start."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]

pytest.importorskip("rclpy")
pytest.importorskip("changing_slam_msgs.msg", reason="interfaces not built (tools/build_interfaces.sh)")

PROCESSES = ("bag_player", "tracking", "local_mapping", "loop_closing", "detection", "object_map")


@pytest.mark.parametrize("name", PROCESSES)
def test_a_process_killed_mid_run_is_restarted_and_the_outputs_are_complete(tmp_path, name):
    from helpers import REPO, require

    bag = require(REPO / "bags" / "tum_fr1_xyz_first10.mcap")
    out = tmp_path / "graph"
    # 0.1x: the 0.59 s bag plays for at least 6 s, so a kill 3 s after the player starts lands mid-run
    proc = subprocess.run(
        [sys.executable, "-m", "changing_slam_ros", "graph", str(bag), "--out", str(out), "--config", "tum_fr1",
         "--lossless", "--detection", "--rate", "0.1", "--kill", f"{name}@3", "--timeout", "600"],
        cwd=REPO, capture_output=True, text=True, timeout=900,
    )  # fmt: skip
    text = proc.stdout + proc.stderr
    assert proc.returncode == 0, text
    assert f"graph: --kill: SIGKILL {name} at 3." in proc.stdout, text  # while the player played
    s = json.loads((out / "graph_summary.json").read_text())
    assert s["restarts"] == {name: 1}, text
    assert set(s["exit_codes"]) == {*PROCESSES} and set(s["exit_codes"].values()) == {0}, s["exit_codes"]
    # complete: every frame of the bag with a pose, as without the kill
    assert (s["colour_frames_in_bag"], s["poses_published"], s["drops"]) == (9, 9, 0), (
        f"{s['drops_by_reason']}, incomplete {s['lossless_incomplete']}\n{text[-4000:]}")
    assert len([ln for ln in (out / "trajectory.txt").read_text().splitlines() if not ln.startswith("#")]) == 9
    assert s["ate_rmse_m"] < 0.01  # offline: 0.36 cm
    assert s["lossless_incomplete"] == []  # no ack or map-update wait timed out
    lm = s["local_mapping"]
    assert lm["keyframes_in_map"] >= s["keyframes"] >= 1 and lm["map_points"] > 300, lm
    assert (out / "map.npz").is_file() and (out / "semantic_map_node.json").is_file()
    if name == "bag_player":
        assert "bag_player resumes in pass 1 at" in proc.stdout
    if name == "tracking":
        assert "started again from the start" in proc.stdout
