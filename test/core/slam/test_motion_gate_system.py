"""The motion gate on a randomised dynamic scene: tuning seed 7 of `random_dynamic` (a robot drives towards a
cart of no COCO class pushed across its view at 1 m, among three other movers; exact depth). Near frame 104
the cart fills most of the image. With the detector's boxes as the paper uses them (no held person boxes, every
keypoint of a box its depth calls occluded left out), tracking follows it without the gate: the camera appears to
move 12 cm per frame (3.6 m/s, against the robot's 0.3 m/s) and the trajectory ends several cm off. With the gate on (it is off by default) those poses are refused and tracking
carries on from the static background. The default's held person boxes also keep tracking off the cart here: a person
box the detector reports at the left image border in frame 98, held and grown over the next frames, covers the
cart's keypoints while it comes in."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

SEED, FRAMES, W, H = 7, 150, 320, 240


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from changing_slam_ros.sim.scenarios import build_scenario
    from changing_slam_ros.sim.sequence import RenderOptions, simulate

    out = tmp_path_factory.mktemp("random_dynamic_7")
    simulate(build_scenario("random_dynamic", SEED), out, RenderOptions(width=W, height=H, frames=FRAMES), SEED)
    return out


def _run(scene: Path, out: Path, *extra: str) -> dict:
    from changing_slam_ros.cli import main as cli_main

    assert cli_main(["run", str(scene), "--out", str(out), "--no-plot", *extra]) == 0
    return json.loads((out / "metrics.json").read_text())


def test_the_gate_keeps_tracking_off_the_cart_that_fills_the_view(scene: Path, tmp_path: Path) -> None:
    no_hold = "dynamic:\n  detection_hold_frames: 0\n  objects: {classification: {repopulate_occluded_class_ids: []}}\n"
    on, off = tmp_path / "on.yaml", tmp_path / "off.yaml"
    on.write_text(no_hold + "tracking:\n  motion_gate:\n    enabled: true\n")
    off.write_text(no_hold)
    gated = _run(scene, tmp_path / "gated", "--config", str(on))
    ungated = _run(scene, tmp_path / "ungated", "--config", str(off))  # the gate off, as by default
    default = _run(scene, tmp_path / "default")
    # Measured: 0.92 cm with the gate (two frames without a pose), 5.8 cm without; the default 0.89 cm.
    assert gated["evaluation"]["ate"]["rmse"] < 0.025
    assert gated["frames_tracked"] >= FRAMES - 5
    assert ungated["evaluation"]["ate"]["rmse"] > 4 * gated["evaluation"]["ate"]["rmse"]
    assert default["evaluation"]["ate"]["rmse"] < 0.025 and default["frames_tracked"] >= FRAMES - 5
