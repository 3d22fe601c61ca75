"""`changing-slam convert`: round trips from a TUM folder and a ROS 1 bag, and its error handling."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import FR1_XYZ_10, REPO, require

from changing_slam_ros.cli import main as cli_main
from changing_slam_ros.io.bag_messages import BagKind, BagMessages
from changing_slam_ros.io.dataset import open_dataset


def test_convert_tum_folder_round_trip(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    root = require(FR1_XYZ_10)
    out = tmp_path / "fr1.mcap"
    assert cli_main(["convert", str(root), str(out), "--config", "tum_fr1"]) == 0
    printed = capsys.readouterr().out
    assert f"wrote {out}: 9 frames, 60 ground-truth poses, raw (rgb8 + 32FC1)" in printed
    with BagMessages(out) as bag:
        assert bag.kind is BagKind.MCAP
        assert {t: c.msgtype for t, c in bag.topics.items()} == {
            "/camera/rgb/image_color": "sensor_msgs/msg/Image",
            "/camera/depth/image": "sensor_msgs/msg/Image",
            "/camera/rgb/camera_info": "sensor_msgs/msg/CameraInfo",
            "/ground_truth/pose": "geometry_msgs/msg/PoseStamped",
        }
    mask = os.umask(0o022)
    os.umask(mask)
    assert out.stat().st_mode & 0o777 == 0o666 & ~mask  # as open() would create it, not mkstemp's 0600
    folder = open_dataset(root, "tum_fr1")
    back = open_dataset(out, None)  # no config: intrinsics come from the written CameraInfo
    assert back.camera == folder.camera
    for a, b in zip(folder, back, strict=True):
        assert a.stamp_ns == b.stamp_ns
        np.testing.assert_array_equal(a.rgb, b.rgb)
        np.testing.assert_array_equal(a.depth_m, b.depth_m)
        np.testing.assert_allclose(a.T_world_cam_gt, b.T_world_cam_gt, atol=1e-12)


def test_convert_compressed_is_smaller_and_close(tmp_path: Path) -> None:
    root = require(FR1_XYZ_10)
    raw, small = tmp_path / "raw.mcap", tmp_path / "small.mcap"
    assert cli_main(["convert", str(root), str(raw), "--config", "tum_fr1"]) == 0
    assert cli_main(["convert", str(root), str(small), "--config", "tum_fr1", "--compress"]) == 0
    assert small.stat().st_size < raw.stat().st_size / 3
    for a, b in zip(open_dataset(raw, None), open_dataset(small, None), strict=True):
        assert a.stamp_ns == b.stamp_ns
        assert np.abs(a.rgb.astype(int) - b.rgb).mean() < 4.0
        assert np.abs(a.depth_m - b.depth_m).max() <= 0.0005 + 1e-6


def test_convert_ros1_bag_round_trip(ros1_tum_bag: Path, tmp_path: Path) -> None:
    out = tmp_path / "from_ros1.mcap"
    assert cli_main(["convert", str(ros1_tum_bag), str(out), "--config", "tum_fr1"]) == 0
    bag = open_dataset(ros1_tum_bag, "tum_fr1")
    back = open_dataset(out, None)
    assert back.camera == bag.camera and back.camera.fx == 517.3
    for a, b in zip(bag, back, strict=True):
        assert a.stamp_ns == b.stamp_ns
        np.testing.assert_array_equal(a.rgb, b.rgb)
        np.testing.assert_array_equal(a.depth_m, b.depth_m)
        np.testing.assert_allclose(a.T_world_cam_gt, b.T_world_cam_gt, atol=1e-12)
    gt_a, gt_b = bag.groundtruth, back.groundtruth
    assert gt_a is not None and gt_b is not None and len(gt_a) == len(gt_b) > 30
    np.testing.assert_array_equal(gt_a.stamps_s, gt_b.stamps_s)
    np.testing.assert_allclose(gt_a.positions, gt_b.positions, atol=1e-12)


def _run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "changing_slam_ros", *args], cwd=REPO, capture_output=True, text=True, timeout=120
    )


def test_cli_errors_are_one_line_without_traceback(tmp_path: Path) -> None:
    missing = _run_cli("convert", str(tmp_path / "nothere"), str(tmp_path / "o.mcap"))
    assert missing.returncode == 1
    assert missing.stderr.strip().count("\n") == 0 and "Traceback" not in missing.stderr
    assert "nothere: no such file or folder" in missing.stderr
    (tmp_path / "junk.bag").write_bytes(b"#ROSBAG V2.0\n" + b"\x00" * 100)
    corrupt = _run_cli("convert", str(tmp_path / "junk.bag"), str(tmp_path / "o.mcap"))
    assert corrupt.returncode == 1 and "Traceback" not in corrupt.stderr
    assert "junk.bag: cannot open ros1 bag" in corrupt.stderr and corrupt.stderr.strip().count("\n") == 0
    assert not (tmp_path / "o.mcap").exists()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["{empty}", "{out}"], r"empty: neither a ROS 2 bag folder .* nor a TUM-layout folder"),
        (["{fr1}", "{out_txt}"], r"o\.txt: output must be an \.mcap file"),
        (["{fr1}", "{out}", "--config", "nope"], r"nope: no such config file"),
        (["{fr1}", "{out}", "--jpeg-quality", "0"], r"--jpeg-quality 0: expected 1\.\.100"),
    ],
)
def test_cli_bad_input_messages(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], message: str
) -> None:
    fr1 = require(FR1_XYZ_10)
    (tmp_path / "empty").mkdir()
    subs = {"{empty}": str(tmp_path / "empty"), "{out}": str(tmp_path / "o.mcap"),
            "{out_txt}": str(tmp_path / "o.txt"), "{fr1}": str(fr1)}  # fmt: skip
    assert cli_main(["convert", *[subs.get(a, a) for a in args]]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    import re

    assert re.search(message, err[-1]), err[-1]
    assert err[-1].startswith("changing-slam convert: error: ")


def test_failed_conversion_keeps_the_existing_output(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    root = require(FR1_XYZ_10)
    copy = tmp_path / "fr1"
    shutil.copytree(root, copy)
    for p in copy.rglob("*"):
        p.chmod(0o755 if p.is_dir() else 0o644)
    out = tmp_path / "keep.mcap"
    out.write_bytes(b"precious")
    last_depth = sorted((copy / "depth").glob("*.png"))[-1]
    last_depth.write_bytes(last_depth.read_bytes()[:1000])  # truncated: fails after 8 good frames
    assert cli_main(["convert", str(copy), str(out), "--config", "tum_fr1"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "depth image is truncated" in err[0]
    assert out.read_bytes() == b"precious"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fr1", "keep.mcap"]  # no temp file left


def test_dataset_config_in_a_yaml_file_is_used(
    tmp_path: Path, ros1_tum_bag: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cfg = tmp_path / "my.yaml"
    cfg.write_text("dataset:\n  max_time_diff_s: 0.001\n")
    out = tmp_path / "o.mcap"
    # with 1 ms slop no colour frame has a depth frame: the error names the config's value
    assert cli_main(["convert", str(ros1_tum_bag), str(out), "--config", str(cfg)]) == 1
    assert "message within 0.001 s" in capsys.readouterr().err
    assert not out.exists()


def test_written_mcap_is_a_ros2_profile_file_other_readers_accept(tmp_path: Path) -> None:
    """What Foxglove relies on: ros2 profile, cdr channels, ros2msg schemas with the MSG: blocks."""
    from mcap.reader import make_reader
    from rosbags.highlevel import AnyReader

    out = tmp_path / "fr1.mcap"
    assert cli_main(["convert", str(require(FR1_XYZ_10)), str(out), "--config", "tum_fr1", "--compress"]) == 0
    with out.open("rb") as fh:
        reader = make_reader(fh)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert summary is not None and summary.statistics.message_count == 9 * 3 + 60
        schemas = {s.name: s for s in summary.schemas.values()}
        assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
        assert schemas["sensor_msgs/msg/CompressedImage"].encoding == "ros2msg"
        assert b"MSG: std_msgs/Header" in schemas["sensor_msgs/msg/CompressedImage"].data
        log_times = [m.log_time for _, _, m in reader.iter_messages(log_time_order=False)]
        assert log_times == sorted(log_times)  # written in time order
    with AnyReader([out]) as any_reader:  # rosbags builds its types from the embedded schemas
        conn = next(c for c in any_reader.connections if c.topic.endswith("image_color/compressed"))
        _, stamp, raw = next(any_reader.messages(connections=[conn]))
        msg = any_reader.deserialize(raw, conn.msgtype)
        assert msg.format == "rgb8; jpeg compressed bgr8" and stamp == 1305031102_175304000
