"""`run` over a bag holding one malformed colour image: the frame is skipped with a warning naming topic and stamp
and counted in metrics.json; `--strict` stops there with one line naming the same."""

from __future__ import annotations

import json
from pathlib import Path

from helpers import write_bag_with_one_bad_image

from changing_slam_ros.cli import main as cli_main


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
