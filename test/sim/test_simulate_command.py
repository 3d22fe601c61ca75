"""`changing-slam simulate` end to end, and the scenario folder as an mcap that reads back."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from changing_slam_ros.cli import main
from changing_slam_ros.io.dataset import open_dataset
from changing_slam_ros.io.tum_trajectory import read_tum_trajectory
from changing_slam_ros.sim.bag import sim_frames, write_sim_mcap
from changing_slam_ros.sim.scenarios import build_scenario


def test_list_names_every_scenario(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["simulate", "--list"]) == 0
    out = capsys.readouterr().out
    for name in ("walking_xyz", "sitting_xyz", "one_chair", "replacing", "unknown_mover"):
        assert f"\n{name} " in "\n" + out


def test_unknown_scenario_and_missing_out_are_one_line_errors(capsys: pytest.CaptureFixture[str],
                                                              tmp_path: Path) -> None:
    assert main(["simulate", "kitchen", "--out", str(tmp_path / "x")]) == 1
    err = capsys.readouterr().err
    assert "error: scenario 'kitchen': unknown; known: walking_xyz" in err and err.count("\n") == 1
    assert main(["simulate", "static"]) == 1
    assert "--out DIR is required" in capsys.readouterr().err


def test_simulate_writes_a_tum_folder_and_an_mcap_that_reads_back(tmp_path: Path) -> None:
    out, bag = tmp_path / "shift", tmp_path / "shift.mcap"
    rc = main(["simulate", "shift", "--out", str(out), "--frames", "4", "--fps", "5", "--width", "96",
               "--height", "72", "--quiet", "--seed", "2"])
    assert rc == 0
    rgb_files = sorted((out / "rgb").glob("*.png"))
    assert len(rgb_files) == 4 and cv2.imread(str(rgb_files[0])).shape == (72, 96, 3)
    assert len(list((out / "masks").glob("*.png"))) == 4
    doc = json.loads((out / "objects.json").read_text())
    scenario = build_scenario("shift", 2)
    assert [(c["t_s"], c["object"], c["kind"]) for c in doc["changes"]] == [
        (c.t_s, c.actor, c.kind.value) for c in scenario.changes]
    for c in doc["changes"]:
        assert doc["objects"][c["object_id"] - 1]["name"] == c["object"]
        assert c["stamp_ns"] == doc["stamps_ns"][0] + round(c["t_s"] * 1e9)
    chair = next(o for o in doc["objects"] if o["name"] == "chair")
    T0 = scenario.actors[scenario.actor_index("chair")].track.pose_at(0.0)
    assert np.allclose(chair["poses"][0][:3], T0[:3, 3], atol=1e-9)
    assert chair["class_id"] == 56 and chair["class_name"] == "chair"
    n = write_sim_mcap(out, bag, compress=False)
    assert n == 4
    gt = read_tum_trajectory(out / "groundtruth.txt").poses()
    expected = list(sim_frames(out))
    got = list(open_dataset(bag, "sim"))
    assert len(got) == 4
    for e, g, T in zip(expected, got, gt):
        assert g.stamp_ns == e.stamp_ns
        assert np.array_equal(g.rgb, e.rgb)
        assert np.allclose(g.depth_m, e.depth_m, atol=1e-6)
        assert g.T_world_cam_gt is not None and np.abs(g.T_world_cam_gt - T).max() < 1e-6
        assert (g.camera.fx, g.camera.cx) == pytest.approx((525.0 * 96 / 640, 47.5))
