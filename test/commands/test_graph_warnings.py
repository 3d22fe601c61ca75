"""What `graph` warns about before it starts and records in graph_summary.json: a config whose camera disagrees
with the bag's CameraInfo, a --map-in map made with another camera, and a run that tracked no frame."""

from __future__ import annotations

from pathlib import Path

from changing_slam_ros.commands.graph_outputs import camera_mismatches, graph_warnings
from changing_slam_ros.io.map_file import load_map

REPO = Path(__file__).resolve().parents[2]
SIM_BAG = str(REPO / "bags" / "sim_walking_changing.mcap")
TUM_BAG = str(REPO / "bags" / "tum_fr1_xyz_first10.mcap")


def test_the_bags_camera_info_and_a_maps_camera_are_compared_with_the_nodes_camera(tmp_path: Path) -> None:
    from changing_slam_ros.cli import main as cli_main

    assert camera_mismatches(SIM_BAG, str(REPO / "config" / "sim.yaml"), "", None) == []
    (found,) = camera_mismatches(SIM_BAG, "7scenes", "", None)
    assert found.data.fx == 262.5 and found.used.startswith("the CameraInfo")
    assert camera_mismatches(str(tmp_path / "missing.mcap"), "", "", None) == []  # the nodes say why
    assert cli_main(["run", TUM_BAG, "--out", str(tmp_path / "m"), "--config", "tum_fr1", "--quiet", "--no-plot",
                     "--max-frames", "2", "--no-loop"]) == 0  # fmt: skip
    loaded = load_map(tmp_path / "m" / "map.npz")
    assert camera_mismatches(TUM_BAG, "tum_fr1", "m/map.npz", loaded) == []
    (found,) = camera_mismatches(SIM_BAG, "sim", "m/map.npz", loaded)  # 320x240 images, a 640x480 map
    assert found.message() == ("camera of this run disagrees with the loaded map m/map.npz: size 320x240 vs "
                               "640x480; using this run's camera")  # fmt: skip


def test_graph_warns_of_a_run_that_tracked_no_frame() -> None:
    (mismatch,) = camera_mismatches(SIM_BAG, "7scenes", "", None)
    assert graph_warnings({"colour_frames_in_bag": 225, "frames_tracked": 225}, []) == []
    assert graph_warnings({"colour_frames_in_bag": 225, "frames_tracked": 0}, [mismatch]) == [
        mismatch.message(), "0 of 225 colour frames tracked: check the config's camera and dataset against the bag, "
        "and logs/tracking.log"]  # fmt: skip
    assert graph_warnings({"colour_frames_in_bag": 225, "frames_tracked": None}, [])[0].startswith("0 of 225")
