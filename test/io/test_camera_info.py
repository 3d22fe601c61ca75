"""CameraInfo messages, camera_info.yaml and the shipped camera/dataset configs."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from changing_slam_ros.config import PACKAGE_CONFIG_DIR
from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.errors import BagError, ConfigError, DatasetError
from changing_slam_ros.io.camera_info import (
    camera_info_fields,
    intrinsics_from_camera_info,
    read_camera_info_yaml,
    write_camera_info_yaml,
)
from changing_slam_ros.io.dataset_config import (
    REALSENSE_JAZZY_TOPICS,
    REALSENSE_TOPICS,
    TUM_TOPICS,
    DatasetConfig,
    TopicSet,
    load_dataset_settings,
    settings_from_mapping,
)

FR1 = CameraIntrinsics(640, 480, 517.3, 516.5, 318.6, 255.3, (0.2624, -0.9531, -0.0054, 0.0026, 1.1633))


def test_ros2_camera_info_message_gives_intrinsics() -> None:
    store = get_typestore(Stores.ROS2_JAZZY)
    t = store.types
    f = camera_info_fields(FR1)
    msg = t["sensor_msgs/msg/CameraInfo"](
        t["std_msgs/msg/Header"](t["builtin_interfaces/msg/Time"](1, 2), "cam"),
        f["height"], f["width"], f["distortion_model"], f["d"], f["k"], f["r"], f["p"], 0, 0,
        t["sensor_msgs/msg/RegionOfInterest"](0, 0, 0, 0, False),
    )  # fmt: skip
    back = store.deserialize_cdr(store.serialize_cdr(msg, "sensor_msgs/msg/CameraInfo"), "sensor_msgs/msg/CameraInfo")
    assert intrinsics_from_camera_info(back) == FR1


def test_ros1_upper_case_fields_are_accepted() -> None:
    store = get_typestore(Stores.ROS1_NOETIC)
    fields = [name for name, _ in store.fielddefs["sensor_msgs/msg/CameraInfo"][1]]
    assert "K" in fields and "D" in fields  # rosbags keeps the ROS 1 spelling
    msg = SimpleNamespace(width=640, height=480, distortion_model="plumb_bob",
                          K=[525.0, 0, 319.5, 0, 525.0, 239.5, 0, 0, 1], D=[0.0] * 5)  # fmt: skip
    assert intrinsics_from_camera_info(msg) == CameraIntrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)


def test_bad_camera_info_messages_name_the_topic() -> None:
    base = dict(width=640, height=480, distortion_model="plumb_bob", d=[0.0] * 5)
    with pytest.raises(BagError, match=r"/cam/info: camera matrix has fx=0\.0, fy=0\.0; expected a calibrated"):
        intrinsics_from_camera_info(SimpleNamespace(**base, k=[0.0] * 9), "/cam/info")
    with pytest.raises(BagError, match=r"/cam/info: distortion model 'equidistant' unsupported"):
        intrinsics_from_camera_info(
            SimpleNamespace(**{**base, "distortion_model": "equidistant", "d": [0.1, 0, 0, 0]},
                            k=[500.0, 0, 320, 0, 500.0, 240, 0, 0, 1]), "/cam/info")  # fmt: skip
    with pytest.raises(BagError, match=r"/x: not a sensor_msgs/CameraInfo"):
        intrinsics_from_camera_info(SimpleNamespace(width=1), "/x")


def test_camera_info_yaml_round_trip(tmp_path: Path) -> None:
    path = tmp_path / "camera_info.yaml"
    write_camera_info_yaml(path, FR1, "kinect_fr1")
    text = path.read_text()
    for key in ("image_width: 640", "camera_matrix:", "distortion_model: plumb_bob", "projection_matrix:"):
        assert key in text
    assert read_camera_info_yaml(path) == FR1
    rational = CameraIntrinsics(320, 240, 300.0, 301.0, 160.0, 120.0, tuple(np.linspace(0.01, 0.08, 8)))
    write_camera_info_yaml(path, rational)
    assert "rational_polynomial" in path.read_text()
    assert read_camera_info_yaml(path) == rational


def test_camera_info_yaml_as_camera_calibration_writes_it(tmp_path: Path) -> None:
    # the layout of a file written by ROS camera_calibration / camera_info_manager
    path = tmp_path / "cam.yaml"
    path.write_text(
        "image_width: 640\nimage_height: 480\ncamera_name: rgb_A00362A10391107A\n"
        "camera_matrix:\n  rows: 3\n  cols: 3\n  data: [535.4, 0, 320.1, 0, 539.2, 247.6, 0, 0, 1]\n"
        "distortion_model: plumb_bob\n"
        "distortion_coefficients:\n  rows: 1\n  cols: 5\n  data: [0, 0, 0, 0, 0]\n"
        "rectification_matrix:\n  rows: 3\n  cols: 3\n  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]\n"
        "projection_matrix:\n  rows: 3\n  cols: 4\n  data: [535.4, 0, 320.1, 0, 0, 539.2, 247.6, 0, 0, 0, 1, 0]\n"
    )
    assert read_camera_info_yaml(path) == CameraIntrinsics(640, 480, 535.4, 539.2, 320.1, 247.6)


def test_bad_camera_info_yaml_names_file_and_key(tmp_path: Path) -> None:
    path = tmp_path / "camera_info.yaml"
    with pytest.raises(DatasetError, match=r"camera_info\.yaml: cannot read"):
        read_camera_info_yaml(path)
    path.write_text("image_width: 640\nimage_height: 480\n")
    with pytest.raises(DatasetError, match=r"camera_info\.yaml: missing key 'camera_matrix'"):
        read_camera_info_yaml(path)
    path.write_text("image_width: 640\nimage_height: 480\ncamera_matrix: {rows: 3, cols: 3, data: [1, 2]}\n")
    with pytest.raises(DatasetError, match=r"camera_matrix: rows=3 cols=3 with 2 values"):
        read_camera_info_yaml(path)
    path.write_text("a: [1,\n")
    with pytest.raises(DatasetError, match=r"camera_info\.yaml:2: not valid YAML \([^\n]*\)$"):
        read_camera_info_yaml(path)


@pytest.mark.parametrize(
    ("name", "fx", "fy", "cx", "cy", "k1", "scale"),
    [
        ("tum_fr1", 517.3, 516.5, 318.6, 255.3, 0.2624, 5000.0),
        ("tum_fr2", 520.9, 521.0, 325.1, 249.7, 0.2312, 5000.0),
        ("tum_fr3", 535.4, 539.2, 320.1, 247.6, 0.0, 5000.0),
        ("7scenes", 585.0, 585.0, 320.0, 240.0, 0.0, 1000.0),
        ("realsense_d435", 615.0, 615.0, 320.0, 240.0, 0.0, 1000.0),
        ("sim", 525.0, 525.0, 319.5, 239.5, 0.0, 5000.0),
    ],
)
def test_shipped_configs_hold_the_published_calibrations(
    name: str, fx: float, fy: float, cx: float, cy: float, k1: float, scale: float
) -> None:
    assert (PACKAGE_CONFIG_DIR / f"{name}.yaml").is_file()
    s = load_dataset_settings(name)
    assert s.camera is not None
    cam = s.camera.intrinsics()
    assert (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy, cam.dist[0]) == (640, 480, fx, fy, cx, cy, k1)
    assert s.dataset.depth_scale == scale


def test_topic_presets_and_overrides() -> None:
    assert load_dataset_settings("tum_fr1").dataset.candidate_topics() == [TUM_TOPICS]
    assert load_dataset_settings("realsense_d435").dataset.candidate_topics() == [REALSENSE_JAZZY_TOPICS]
    assert REALSENSE_JAZZY_TOPICS.rgb == "/camera/camera/color/image_raw"  # realsense2_camera on Jazzy
    assert DatasetConfig().candidate_topics() == [TUM_TOPICS, REALSENSE_TOPICS, REALSENSE_JAZZY_TOPICS]  # auto
    cfg = DatasetConfig(topic_preset="realsense", depth_topic="/d")
    assert cfg.candidate_topics() == [TopicSet(REALSENSE_TOPICS.rgb, "/d", REALSENSE_TOPICS.camera_info)]
    # only the colour topic given: depth from each preset, CameraInfo beside the colour topic
    cfg = DatasetConfig(rgb_topic="/kinect2/qhd/image_color_rect/compressed")
    assert cfg.candidate_topics() == [
        TopicSet("/kinect2/qhd/image_color_rect/compressed", TUM_TOPICS.depth, "/kinect2/qhd/camera_info"),
        TopicSet("/kinect2/qhd/image_color_rect/compressed", REALSENSE_TOPICS.depth, "/kinect2/qhd/camera_info"),
        TopicSet("/kinect2/qhd/image_color_rect/compressed", REALSENSE_JAZZY_TOPICS.depth, "/kinect2/qhd/camera_info"),
    ]


def test_config_errors_name_file_and_key() -> None:
    with pytest.raises(ConfigError, match=r"x\.yaml: dataset: unknown key\(s\) depth_scal;"):
        settings_from_mapping({"dataset": {"depth_scal": 1.0}}, "x.yaml")
    with pytest.raises(ConfigError, match=r"x\.yaml: dataset\.topic_preset: 'kinect2' unknown"):
        settings_from_mapping({"dataset": {"topic_preset": "kinect2"}}, "x.yaml")
    with pytest.raises(ConfigError, match=r"x\.yaml: camera: camera needs width, height, fx, fy > 0"):
        settings_from_mapping({"camera": {"width": 640}}, "x.yaml")
    with pytest.raises(ConfigError, match=r"x\.yaml: camera\.fx: expected a number"):
        settings_from_mapping({"camera": {"fx": "five"}}, "x.yaml")
