"""Intrinsics the data ships against the config's camera: 7-Scenes' camera-intrinsics.txt, a TUM folder's
camera_info.yaml, a bag's CameraInfo."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from helpers import FR1_XYZ_10, require

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.errors import DatasetError
from changing_slam_ros.io.camera_check import compare_cameras, read_intrinsics_txt
from changing_slam_ros.io.camera_info import write_camera_info_yaml
from changing_slam_ros.io.dataset import open_dataset

REPO = Path(__file__).resolve().parents[2]
SEVEN_SCENES = CameraIntrinsics(640, 480, 585.0, 585.0, 320.0, 240.0)
FR1 = CameraIntrinsics(640, 480, 517.3, 516.5, 318.6, 255.3, (0.2624, -0.9531, -0.0054, 0.0026, 1.1633))


def test_cameras_within_calibration_noise_agree_and_others_are_named_field_by_field() -> None:
    near = CameraIntrinsics(640, 480, 585.0 * 1.009, 585.0, 320.0 + 6.0, 240.0)  # 0.9 % focal, 6 px < 6.4 px
    assert compare_cameras(SEVEN_SCENES, near) == []
    assert compare_cameras(SEVEN_SCENES, FR1) == [
        "fx 517.3 vs 585", "fy 516.5 vs 585", "cy 255.3 vs 240",
        "dist [0.2624, -0.9531, -0.0054, 0.0026, 1.1633] vs [0.0, 0.0, 0.0, 0.0, 0.0]",
    ]  # fmt: skip
    half = CameraIntrinsics(320, 240, 292.5, 292.5, 160.0, 120.0)
    assert compare_cameras(half, SEVEN_SCENES) == []  # the same camera at half size
    assert compare_cameras(half, SEVEN_SCENES, scale=False) == ["size 640x480 vs 320x240"]
    assert compare_cameras(CameraIntrinsics(320, 240, 262.5, 262.5, 160.0, 120.0), SEVEN_SCENES) == [
        "fx 292.5 vs 262.5", "fy 292.5 vs 262.5", "640x480 values scaled to 320x240"]  # fmt: skip
    assert compare_cameras(CameraIntrinsics(640, 360, 585, 585, 320, 180), SEVEN_SCENES) == ["size 640x480 vs 640x360"]


def test_intrinsics_txt_is_read_and_a_malformed_one_is_named(tmp_path: Path) -> None:
    good = tmp_path / "camera-intrinsics.txt"
    good.write_text("5.85e+02 0 3.2e+02\n0 5.85e+02 2.4e+02\n0 0 1\n")
    assert read_intrinsics_txt(good, 640, 480) == SEVEN_SCENES
    good.write_text("585 0 320\n0 585 240\n")
    with pytest.raises(DatasetError, match="camera-intrinsics.txt: expected a 3x3 camera matrix"):
        read_intrinsics_txt(good, 640, 480)
    good.write_text("585 0 320\n0 five 240\n0 0 1\n")
    with pytest.raises(DatasetError, match=r"camera-intrinsics.txt:2: camera matrix values must be numbers"):
        read_intrinsics_txt(good, 640, 480)
    good.write_bytes(b"585 0 320\n0 585 240\n0 0 1\xff\n")
    with pytest.raises(DatasetError, match=r"camera-intrinsics.txt:3: not UTF-8"):
        read_intrinsics_txt(good, 640, 480)


@pytest.fixture
def fr1_copy(tmp_path: Path) -> Path:
    folder = tmp_path / "fr1"
    shutil.copytree(require(FR1_XYZ_10), folder)
    return folder


def test_a_tum_folder_names_the_shipped_intrinsics_the_config_disagrees_with(fr1_copy: Path) -> None:
    assert open_dataset(fr1_copy, "tum_fr1").camera_mismatch is None
    (fr1_copy / "camera-intrinsics.txt").write_text("585 0 320\n0 585 240\n0 0 1\n")
    src = open_dataset(fr1_copy, "tum_fr1")
    m = src.camera_mismatch
    assert m is not None and src.camera == FR1  # the config's camera is still the one used
    assert m.data == SEVEN_SCENES and m.other == FR1 and m.used.startswith("the camera of") and "tum_fr1" in m.used
    assert m.message().startswith("camera of ") and "camera-intrinsics.txt: fx 517.3 vs 585" in m.message()
    assert open_dataset(fr1_copy, "7scenes").camera_mismatch is None
    write_camera_info_yaml(fr1_copy / "camera_info.yaml", SEVEN_SCENES)  # preferred over the config's camera
    src = open_dataset(fr1_copy, "tum_fr1")
    assert src.camera == SEVEN_SCENES and src.camera_mismatch is not None
    assert src.camera_mismatch.used == "camera_info.yaml" and src.camera_mismatch.other == FR1


def test_a_bags_camera_info_is_compared_with_the_config_either_way() -> None:
    sim = REPO / "bags" / "sim_walking_changing.mcap"  # CameraInfo 320x240 fx 262.5
    assert open_dataset(sim, "sim").camera_mismatch is None  # sim.yaml is the same camera at 640x480
    m = open_dataset(sim, "7scenes").camera_mismatch
    assert m is not None and m.differences[:2] == ("fx 292.5 vs 262.5", "fy 292.5 vs 262.5")
    assert m.used.startswith("the CameraInfo") and "on /camera/rgb/camera_info of" in m.data_source
    tum = REPO / "bags" / "tum_fr1_xyz_first10.mcap"  # CameraInfo: the fr1 calibration
    assert open_dataset(tum, "tum_fr1").camera_mismatch is None
    assert open_dataset(tum, "7scenes").camera_mismatch is not None
