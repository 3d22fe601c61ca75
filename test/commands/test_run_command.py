"""`changing-slam run` end to end on the TUM fr1_xyz frames: outputs, accuracy, map file round trip."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers import FR1_XYZ_10, REDKITCHEN, require

from changing_slam_ros.cli import main as cli_main
from changing_slam_ros.io.map_file import MAP_FORMAT_VERSION, load_map, read_map_arrays
from changing_slam_ros.errors import MapFileError
from changing_slam_ros.io.tum_trajectory import read_tum_trajectory

REPO = Path(__file__).resolve().parents[2]


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
    arrays = read_map_arrays(out / "map.npz")
    assert int(arrays["format_version"]) == MAP_FORMAT_VERSION
    assert len(arrays["m0_kf_ids"]) == metrics["keyframes"]
    usable = ~arrays["m0_pt_bad"] & arrays["m0_pt_active"]
    assert usable.sum() == metrics["map_points"] > 300
    # Observations reference stored points and keyframes only.
    assert (arrays["m0_pt_obs"][:, 0] < int(arrays["m0_pt_size"])).all()
    assert np.isin(arrays["m0_pt_obs"][:, 1], arrays["m0_kf_ids"]).all()
    # the occupancy grid, as Nav2's map_server reads it
    from changing_slam_ros.io.nav2_map import read_nav2_map

    grid = read_nav2_map(out / "grid.yaml")
    assert grid.occupancy.shape == (metrics["grid"]["height"], metrics["grid"]["width"])
    assert (grid.occupancy == 0).sum() == metrics["grid"]["free_cells"] > 0
    assert (grid.occupancy == 100).sum() == metrics["grid"]["occupied_cells"] > 0


@pytest.mark.slow
def test_second_run_starts_from_the_saved_map(tmp_path, capsys) -> None:
    """--map-in: the second run relocalises in the first run's map at its first frame, keeps its keyframes and
    reports its trajectory in that map's frame (the same frames: poses within 2 cm of the first run's)."""
    first, second = tmp_path / "first", tmp_path / "second"
    data = str(require(FR1_XYZ_10))
    assert cli_main(["run", data, "--out", str(first), "--config", "tum_fr1", "--quiet", "--no-plot"]) == 0
    assert cli_main(["run", data, "--out", str(second), "--config", "tum_fr1", "--quiet", "--no-plot",
                     "--map-in", str(first / "map.npz")]) == 0
    m1 = json.loads((first / "metrics.json").read_text())
    m2 = json.loads((second / "metrics.json").read_text())
    assert m2["multi_session"]["relocalised"] and m2["multi_session"]["relocalised_frame"] == 0
    assert m2["multi_session"]["relocalised_after_s"] == 0.0
    assert m2["maps"] == 1 and m2["keyframes"] >= m1["keyframes"]
    t1, t2 = read_tum_trajectory(first / "trajectory.txt"), read_tum_trajectory(second / "trajectory.txt")
    assert len(t2) == len(t1) == 9
    assert np.abs(t1.positions - t2.positions).max() < 0.02
    assert len(load_map(second / "map.npz").atlas.maps[0].keyframes) == m2["keyframes"]
    rc = cli_main(["run", data, "--out", str(tmp_path / "third"), "--config", "tum_fr1", "--quiet",
                   "--map-in", str(tmp_path / "missing.npz")])
    assert rc == 1 and "missing.npz: cannot read map" in capsys.readouterr().err


def test_map_file_of_another_version_is_refused(tmp_path) -> None:
    path = tmp_path / "map.npz"
    np.savez(path, format_version=np.array(MAP_FORMAT_VERSION + 1))
    with pytest.raises(MapFileError, match="version"):
        read_map_arrays(path)
    with pytest.raises(MapFileError, match="cannot read"):
        read_map_arrays(tmp_path / "missing.npz")


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


def test_a_config_that_disagrees_with_the_datas_intrinsics_is_said_and_recorded(tmp_path, capsys) -> None:
    """tum_fr1 on 7-Scenes: the console names both cameras before the first frame; metrics.json records it."""
    out = tmp_path / "o"
    rc = cli_main(["run", str(require(REDKITCHEN)), "--out", str(out), "--config", "tum_fr1", "--quiet", "--no-plot",
                   "--max-frames", "2"])  # fmt: skip
    err = capsys.readouterr().err
    assert rc == 0
    warnings = [ln for ln in err.splitlines() if ln.startswith("run: warning: camera of ")]
    assert len(warnings) == 1 and "tum_fr1.yaml disagrees with" in warnings[0]
    assert "camera-intrinsics.txt: fx 517.3 vs 585, fy 516.5 vs 585" in warnings[0]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["warnings"] == [warnings[0].removeprefix("run: warning: ")]
    (m,) = metrics["camera_mismatch"]
    assert m["data"]["fx"] == 585.0 and m["other"]["fx"] == 517.3 and m["used"].startswith("the camera of")


def test_a_loaded_map_made_with_another_camera_is_said_and_recorded(tmp_path, capsys) -> None:
    data = str(require(FR1_XYZ_10))
    assert cli_main(["run", data, "--out", str(tmp_path / "first"), "--config", "tum_fr1", "--quiet", "--no-plot",
                     "--max-frames", "3", "--no-loop"]) == 0  # fmt: skip
    other = tmp_path / "other_camera.yaml"
    other.write_text((REPO / "config" / "tum_fr1.yaml").read_text().replace("fx: 517.3", "fx: 540.0"))
    capsys.readouterr()
    cli_main(["run", data, "--out", str(tmp_path / "second"), "--config", str(other), "--quiet", "--no-plot",
              "--max-frames", "3", "--no-loop", "--map-in", str(tmp_path / "first" / "map.npz")])  # fmt: skip
    err = capsys.readouterr().err
    assert "Traceback" not in err
    line = next(ln for ln in err.splitlines() if "disagrees with the loaded map" in ln)
    assert line.startswith("run: warning: camera of this run disagrees with the loaded map ")
    assert line.endswith("map.npz: fx 540 vs 517.3; using this run's camera")
    metrics = json.loads((tmp_path / "second" / "metrics.json").read_text())
    assert metrics["camera_mismatch"][0]["other"]["fx"] == 540.0
    assert line.removeprefix("run: warning: ") in metrics["warnings"]
