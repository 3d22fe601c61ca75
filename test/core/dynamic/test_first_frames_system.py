"""System tests of the first frames of a dynamic scene, on two small simulator scenes built here.

- `mover_from_start`: a photo-textured board of no COCO class (0.7 x 0.6 m, ~40 % of the image) is carried
  across the view 1.1 m ahead of the camera from the first frame on, while the camera drifts sideways. The
  map must not anchor on the board: the default engine (segmentation on, no detector) must keep the camera
  ATE small. It does not yet (expected failure).
- `box_fills_view`: the camera starts 0.65 m in front of a still suitcase (a COCO class, oracle boxes)
  that fills most of the image, holds still for a second, then backs away. Its keypoints are movable and
  have no EKF verdict yet; they must serve initialisation (`DynamicConfig.min_kept_keypoints`) rather than
  block it: the first frame gets a pose (filtered a priori, as in the paper, no frame of the 3 s does).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from changing_slam_ros.core.dynamic.dynamic_filter import DynamicConfig, DynamicFilter
from changing_slam_ros.core.system import SlamSystem
from changing_slam_ros.eval.ate import ate
from changing_slam_ros.io.dataset import open_dataset
from changing_slam_ros.io.detections_file import find_detections_file, read_detections_file
from changing_slam_ros.sim.actors import Actor, Part
from changing_slam_ros.sim.camera_path import look_at
from changing_slam_ros.sim.room import default_room
from changing_slam_ros.sim.scenarios import Scenario, _office
from changing_slam_ros.sim.sequence import RenderOptions, simulate
from changing_slam_ros.sim.track import PoseKey, Track, function_track, pose_xyz_rpy

pytestmark = pytest.mark.slow

BOARD_HALF_M = (0.05, 0.35, 0.3)  # thin along its x, which is turned to face the camera
SUITCASE_CLASS_ID = 28  # COCO (0-based): movable, not always dynamic


def mover_from_start(seed: int = 0, duration_s: float = 3.0) -> Scenario:
    """A board carried from x = -0.45 to +0.45 m at 0.3 m/s, 1.1 m ahead of a camera drifting at 5 cm/s."""
    rng = np.random.default_rng(seed)
    actors = _office(rng)
    yaw = np.pi / 2  # the board's +x (its front) towards -y, where the camera is
    board = Track([PoseKey(0.0, pose_xyz_rpy(-0.45, -0.2, 0.95, yaw=-yaw)),
                   PoseKey(duration_s, pose_xyz_rpy(0.45, -0.2, 0.95, yaw=-yaw))])
    parts = (Part(BOARD_HALF_M, (0.0, 0.0, 0.3), "hubble", None),)
    actors.append(Actor("board", -1, parts, board, moving=True))

    def camera(t: float) -> np.ndarray:
        eye = np.array([0.1 - 0.05 * t, -1.3, 1.3])
        return look_at(eye, eye + np.array([0.0, 2.8, -0.45]))

    return Scenario("mover_from_start", "a board carried across the view from the first frame", default_room(),
                    tuple(actors), function_track(camera, duration_s), (), duration_s, 30.0)


def box_fills_view(seed: int = 0, duration_s: float = 3.0) -> Scenario:
    """A suitcase 0.65 m ahead of the camera, which holds still for 1 s, then backs away at 0.2 m/s."""
    rng = np.random.default_rng(seed)
    actors = _office(rng)
    suitcase = pose_xyz_rpy(0.0, 0.2, 0.0, yaw=-np.pi / 2)
    parts = (Part((0.2, 0.7, 0.6), (0.0, 0.0, 0.6), "rocket", None),)
    actors.append(Actor("suitcase", SUITCASE_CLASS_ID, parts, Track.static(suitcase)))

    def camera(t: float) -> np.ndarray:
        back = 0.2 * max(t - 1.0, 0.0)
        eye = np.array([0.05 * back, -0.65 - back, 0.75])
        return look_at(eye, eye + np.array([0.0, 1.0, -0.05]))

    return Scenario("box_fills_view", "a still suitcase fills the first view", default_room(), tuple(actors),
                    function_track(camera, duration_s), (), duration_s, 30.0)


@pytest.fixture(scope="module")
def rendered(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    out = {}
    for build in (mover_from_start, box_fills_view):
        folder = tmp_path_factory.mktemp(build.__name__)
        simulate(build(0), folder, RenderOptions(width=640, height=480), 0)
        out[build.__name__] = folder
    return out


def _run(folder: Path, config: DynamicConfig | None, oracle: bool) -> tuple[SlamSystem, float]:
    source = open_dataset(folder, "sim")
    dets = read_detections_file(find_detections_file(folder)) if oracle else None
    system = SlamSystem(dynamic_filter=DynamicFilter(config) if config is not None else None)
    for rgbd in source:
        system.process(rgbd, dets.for_stamp(rgbd.stamp_ns) if dets is not None else None)
    assert source.groundtruth is not None
    if system.n_tracked() < 3:
        return system, float("inf")
    return system, ate(source.groundtruth, system.online_trajectory()).stats.rmse


@pytest.mark.xfail(strict=True, reason="tracking follows the board, which carries 50-70 % of the keypoints from frame 0: "
                   "32 cm against 28 cm plain; the two-frame test rarely flags it (3 cm in 0.1 s at 1.1 m before a "
                   "wall at 3 m), the long-gap option flags ~60 % of it from frame 12 and the rest still anchor the pose")
def test_a_mover_present_from_the_first_frame_does_not_become_the_map(rendered: dict[str, Path]) -> None:
    plain, plain_ate = _run(rendered["mover_from_start"], None, oracle=False)
    system, ate_m = _run(rendered["mover_from_start"], DynamicConfig(), oracle=False)
    assert system.n_tracked() == len(system.records)
    assert ate_m < 0.01, (ate_m, plain_ate)
    assert ate_m < 0.5 * plain_ate, (ate_m, plain_ate)


def test_a_still_box_filling_the_first_view_does_not_block_initialisation(rendered: dict[str, Path]) -> None:
    folder = rendered["box_fills_view"]
    system, ate_m = _run(folder, DynamicConfig(), oracle=True)
    assert system.records[0].T_world_cam_online is not None  # the first frame starts the map
    assert system.n_tracked() == len(system.records)
    assert ate_m < 0.01
    paper, _ = _run(folder, dataclasses.replace(DynamicConfig(), min_kept_keypoints=0), oracle=True)
    first = next((k for k, r in enumerate(paper.records) if r.T_world_cam_online is not None), len(paper.records))
    assert first > 30  # filtered a priori, the suitcase's keypoints wait for an EKF verdict that never comes
