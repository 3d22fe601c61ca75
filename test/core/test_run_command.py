"""`changing-slam run` end to end on the TUM fr1_xyz frames: outputs, accuracy, map file round trip."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers import FR1_XYZ_10, require

from changing_slam_ros.cli import main as cli_main
from changing_slam_ros.commands.run import MAP_FORMAT_VERSION, load_map_arrays
from changing_slam_ros.errors import MapFileError
from changing_slam_ros.io.tum_trajectory import read_tum_trajectory


def test_run_writes_every_output_and_meets_the_fr1_ate_bound(tmp_path) -> None:
    out = tmp_path / "run"
    rc = cli_main(["run", str(require(FR1_XYZ_10)), "--out", str(out), "--config", "tum_fr1", "--quiet"])
    assert rc == 0
    for name in ("trajectory.txt", "trajectory_online.txt", "keyframes.txt", "map.npz", "metrics.json", "timing.json", "trajectory.png"):
        assert (out / name).is_file(), name
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["frames"] == metrics["frames_tracked"] == 9
    assert metrics["ate_rmse_m"] <= 0.005
    assert metrics["evaluation"]["ate"]["associated_poses"] == 9
    assert len(read_tum_trajectory(out / "trajectory.txt")) == 9
    timing = json.loads((out / "timing.json").read_text())
    assert timing["tracking"]["count"] == 9 and timing["tracking"]["p50"] > 0
    arrays = load_map_arrays(out / "map.npz")
    assert int(arrays["format_version"]) == MAP_FORMAT_VERSION
    assert len(arrays["m0_kf_ids"]) == metrics["keyframes"]
    assert len(arrays["m0_point_positions"]) >= metrics["map_points"] > 300
    # Observations reference stored points and keyframes only.
    assert np.isin(arrays["m0_obs"][:, 0], arrays["m0_point_ids"]).all()
    assert np.isin(arrays["m0_obs"][:, 1], arrays["m0_kf_ids"]).all()


def test_map_file_of_another_version_is_refused(tmp_path) -> None:
    path = tmp_path / "map.npz"
    np.savez(path, format_version=np.array(MAP_FORMAT_VERSION + 1))
    with pytest.raises(MapFileError, match="version"):
        load_map_arrays(path)
    with pytest.raises(MapFileError, match="cannot read"):
        load_map_arrays(tmp_path / "missing.npz")


def test_run_on_a_missing_source_fails_with_one_line(tmp_path, capsys) -> None:
    rc = cli_main(["run", str(tmp_path / "nope"), "--out", str(tmp_path / "o"), "--quiet"])
    assert rc == 1
    assert "no such file or folder" in capsys.readouterr().err


def test_run_rejects_unknown_config_keys(tmp_path, capsys) -> None:
    cfg = tmp_path / "bad.yaml"
    cfg.write_text("tracking:\n  radius_px: 3\n")
    rc = cli_main(["run", str(require(FR1_XYZ_10)), "--out", str(tmp_path / "o"), "--config", str(cfg), "--quiet"])
    assert rc == 1
    assert "tracking" in capsys.readouterr().err
