"""System test of issue 6 on `one_chair_closeup`: the object layer keeps loop closing off a moved object.

`one_chair_closeup` (sim/scenarios.py) shows the printed chair with the teddy bear close-up at A (the robot's first
corner) and, after an out-of-view move, close-up at B (the second corner, second lap), against different walls: an
engine that uses the chair's points can verify a loop B -> A on the chair alone, 90 deg and about a metre off the
truth (`bench/closeup_wrong_loop.py` measures it at 15 fps). Here the scenario is rendered at 7.5 fps (320x240) with
a keyframe at least every 15 frames (the 2 s spacing of the 15 fps runs), the drift gate is switched off so that
the object layer is the only guard, and the engine runs with oracle detections, the dynamic filter and the layer.
Asserted: the plain engine (no detections, no dynamic filter, no layer) closes a wrong loop (> 10 cm or 5 deg from
the ground-truth relative pose) on the chair; with the layer no accepted loop is wrong.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from changing_slam_ros.commands.objects_options import LoopLog
from changing_slam_ros.core.dynamic_filter import DynamicFilter
from changing_slam_ros.core.loop_closing import LoopCloser, LoopConfig, SlamMapLoopClosing
from changing_slam_ros.core.object_layer import ObjectLayer
from changing_slam_ros.core.place_recognition import DriftGateConfig
from changing_slam_ros.core.system import SlamSystem, SystemConfig
from changing_slam_ros.core.tracking import TrackingConfig
from changing_slam_ros.core.vocabulary import Vocabulary
from changing_slam_ros.io.dataset import open_dataset
from changing_slam_ros.io.detections_file import find_detections_file, read_detections_file

pytestmark = pytest.mark.slow

FPS = 7.5


@pytest.fixture(scope="module")
def closeup(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from changing_slam_ros.errors import SimError
    from changing_slam_ros.sim import renderer  # noqa: F401 - sets MUJOCO_GL before mujoco loads
    from changing_slam_ros.sim.scenarios import build_scenario
    from changing_slam_ros.sim.sequence import RenderOptions, simulate

    out = tmp_path_factory.mktemp("one_chair_closeup")
    scenario = build_scenario("one_chair_closeup", 0)
    try:
        simulate(scenario, out, RenderOptions(width=320, height=240, frames=int(scenario.duration_s * FPS), fps=FPS), 0)
    except SimError as err:
        pytest.skip(f"no offscreen rendering here: {err}")
    return out


def _loops(folder: Path, layer: bool) -> dict:  # type: ignore[type-arg]
    """Run the engine on `folder` with the drift gate off; `layer`: oracle detections, dynamic filter and object
    layer, else the plain engine (no detections, no dynamic filter, no layer). Returns LoopLog's evaluation."""
    source = open_dataset(folder, "sim")
    oracle = read_detections_file(find_detections_file(folder))
    closing = SlamMapLoopClosing(LoopCloser(LoopConfig(drift_gate=DriftGateConfig(enabled=False)), Vocabulary.load()))
    config = SystemConfig(tracking=replace(TrackingConfig(), max_frames_between_keyframes=15))
    system = SlamSystem(config, loop_closer=closing, keyframe_index=closing,
                        dynamic_filter=DynamicFilter() if layer else None, object_layer=ObjectLayer() if layer else None)
    loops = LoopLog()
    for rgbd in source:
        if system.process(rgbd, oracle.for_stamp(rgbd.stamp_ns) if layer else None).loop_corrected:
            loops.record(closing, system)
    assert source.groundtruth is not None
    report: dict = loops.evaluate(source.groundtruth)  # type: ignore[type-arg]
    return report


def test_plain_engine_closes_a_wrong_loop_on_the_moved_chair(closeup: Path) -> None:
    """Without detections, dynamic filter and layer (and with the gate off) the chair's close-up views at A and B
    are verified as one place: the failure the layer is there to prevent does occur on this scenario."""
    report = _loops(closeup, layer=False)
    assert report["wrong"] >= 1, report
    worst = max(report["loops"], key=lambda x: x["error_deg"])
    assert worst["error_deg"] > 45.0  # the chair's move: about 80 cm and 80-90 deg


def test_layer_closes_no_loop_on_the_moved_chair_without_the_drift_gate(closeup: Path) -> None:
    report = _loops(closeup, layer=True)
    assert report["wrong"] == 0, report
