"""`run --keypoint-log`: the log holds every frame's keypoints and verdicts, and leaves the run unchanged."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from changing_slam_ros.cli import main as cli_main
from changing_slam_ros.sim.scenarios import build_scenario
from changing_slam_ros.sim.sequence import RenderOptions, simulate


@pytest.mark.slow
def test_keypoint_log_records_each_frame_and_changes_no_pose(tmp_path: Path) -> None:
    seq = tmp_path / "seq"
    simulate(build_scenario("walking_xyz", 1), seq, RenderOptions(320, 240, frames=12), seed=1)
    base = ["run", str(seq), "--quiet", "--no-plot", "--no-loop", "--detections", "oracle"]
    assert cli_main(base + ["--out", str(tmp_path / "a")]) == 0
    assert cli_main(base + ["--out", str(tmp_path / "b"), "--keypoint-log", str(tmp_path / "kp.npz")]) == 0
    assert (tmp_path / "a" / "trajectory.txt").read_bytes() == (tmp_path / "b" / "trajectory.txt").read_bytes()
    log = np.load(tmp_path / "kp.npz")
    assert len(log["stamps_ns"]) == 12 and log["offsets"][-1] == len(log["keep"]) == len(log["keypoints_px"])
    assert (~log["keep"]).any()  # the walkers' boxes dropped some keypoints
    assert set(np.unique(log["kp_classes"])) <= {0, 1, 2, 3}
