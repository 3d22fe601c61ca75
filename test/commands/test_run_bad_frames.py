"""`run` over a bag holding one malformed colour image: the frame is skipped with a warning naming topic and stamp
and counted in metrics.json; `--strict` stops there with one line naming the same."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from changing_slam_ros.cli import main as cli_main
from changing_slam_ros.io.dataset import open_dataset

REPO = Path(__file__).resolve().parents[2]
BAG = REPO / "bags" / "tum_fr1_xyz_first10.mcap"
BAD_INDEX = 4


def write_bag_with_one_bad_image(path: Path, bad_index: int = BAD_INDEX, frames: int = 6) -> int:
    """The first `frames` frames of the fr1 sample bag, the colour image of frame `bad_index` cut to 10 bytes of
    pixel data (its step and size still claim 640x480). Returns that frame's stamp in nanoseconds."""
    from changing_slam_ros.io.mcap_writer import CAMERA_INFO, IMAGE, RgbdMcapWriter
    from changing_slam_ros.io.camera_info import camera_info_fields
    from changing_slam_ros.io.image_codec import depth_image_fields

    source = open_dataset(BAG, "tum_fr1")
    stamp = 0
    with RgbdMcapWriter(path) as w:
        for i, frame in enumerate(source):
            if i == frames:
                break
            if i != bad_index:
                w.write_frame(frame)
                continue
            t, stamp = w.typestore.types, frame.stamp_ns
            header = t["std_msgs/msg/Header"](t["builtin_interfaces/msg/Time"](*divmod(stamp, 10**9)), "camera")
            info = t[CAMERA_INFO](header, **camera_info_fields(frame.camera), binning_x=0, binning_y=0,
                                  roi=t["sensor_msgs/msg/RegionOfInterest"](0, 0, 0, 0, False))  # fmt: skip
            w.write_message(w.info_topic, CAMERA_INFO, info, stamp)
            w.write_message(w.rgb_topic, IMAGE, t[IMAGE](header, 480, 640, "rgb8", 0, 640 * 3, np.zeros(10, np.uint8)), stamp)
            w.write_message(w.depth_topic, IMAGE, t[IMAGE](header, **depth_image_fields(frame.depth_m, "32FC1")), stamp)
    return stamp


def test_a_malformed_image_is_skipped_with_topic_and_stamp_and_counted(tmp_path: Path, capsys) -> None:
    bag = tmp_path / "one_bad.mcap"
    stamp = write_bag_with_one_bad_image(bag)
    stamp_text = f"{stamp // 10**9}.{stamp % 10**9 // 1000:06d}"
    out = tmp_path / "out"
    rc = cli_main(["run", str(bag), "--out", str(out), "--config", "tum_fr1", "--quiet", "--no-plot", "--no-loop"])
    err = capsys.readouterr().err
    assert rc == 0 and "Traceback" not in err
    said = [ln for ln in err.splitlines() if "skipped a malformed message" in ln]
    assert said == [f"run: warning: skipped a malformed message on /camera/rgb/image_color at stamp {stamp_text} s: "
                    "image data has 10 bytes, expected step*height = 1920*480 = 921600"]  # fmt: skip
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["frames"] == 5 and metrics["frames_tracked"] == 5
    assert metrics["skipped_messages"]["count"] == 1
    assert metrics["skipped_messages"]["by_topic"] == {"/camera/rgb/image_color": 1}
    assert metrics["skipped_messages"]["first"][0]["stamp_ns"] == stamp
    assert "1 malformed message(s) skipped (1 on /camera/rgb/image_color)" in metrics["warnings"][-1]


def test_strict_stops_at_the_malformed_image_naming_topic_and_stamp(tmp_path: Path, capsys) -> None:
    bag = tmp_path / "one_bad.mcap"
    stamp = write_bag_with_one_bad_image(bag)
    rc = cli_main(["run", str(bag), "--out", str(tmp_path / "out"), "--config", "tum_fr1", "--quiet", "--strict"])
    err = capsys.readouterr().err
    assert rc == 1 and "Traceback" not in err
    (line,) = [ln for ln in err.splitlines() if ": error: " in ln]
    assert f"one_bad.mcap: /camera/rgb/image_color at stamp {stamp // 10**9}." in line and "10 bytes" in line
    assert not (tmp_path / "out").exists() or not (tmp_path / "out" / "metrics.json").exists()
