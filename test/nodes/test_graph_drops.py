"""`changing-slam graph` on a bag with one malformed colour image: tracking skips that frame, and the summary and
the final line give it as the one drop, under its reason."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]

pytest.importorskip("rclpy")
pytest.importorskip("changing_slam_msgs.msg", reason="interfaces not built (tools/build_interfaces.sh)")


def test_a_malformed_image_is_counted_as_the_one_drop_under_its_reason(tmp_path):
    from helpers import REPO, write_bag_with_one_bad_image

    from changing_slam_ros.commands.graph_outputs import DROP_REASONS

    bag = tmp_path / "one_bad.mcap"
    write_bag_with_one_bad_image(bag)  # 6 frames, the 5th cut to 10 bytes of pixels
    out = tmp_path / "graph"
    proc = subprocess.run(
        [sys.executable, "-m", "changing_slam_ros", "graph", str(bag), "--out", str(out), "--config", "tum_fr1",
         "--lossless", "--no-detection", "--no-object-map", "--timeout", "300"],
        cwd=REPO, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    s = json.loads((out / "graph_summary.json").read_text())
    assert (s["colour_frames_in_bag"], s["poses_published"], s["drops"]) == (6, 5, 1)
    assert s["drops_by_reason"] == {**{reason: 0 for reason in DROP_REASONS}, "malformed": 1, "unaccounted": 0}
    assert "5/6 frames with a pose (1 dropped: 1 malformed)" in proc.stdout
    assert "frame rejected" in (out / "logs" / "tracking.log").read_text()
