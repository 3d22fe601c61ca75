"""`SlamSystem.set_first_pose`: a map built in a frame chosen before the first keyframe (a robot base's frame at
the start, z up), on 40 frames of the simulator's `static` room at 320x240, whose world is z-up.

Without it the map is the first camera's optical frame, where the floor's normal is the camera's -y; with the
camera's true first pose in the z-up world as the first pose, the trajectory comes out in that world without any
alignment, and the occupancy grid lies in the map's x-y plane with its x along the map's x, as Nav2 reads a grid
(x, y and yaw of its origin only).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from changing_slam_ros.core.geometry.se3 import rotation_angle_rad
from changing_slam_ros.errors import ConfigError


@pytest.fixture(scope="module")
def static_room(tmp_path_factory: pytest.TempPathFactory) -> list:
    from changing_slam_ros.errors import SimError
    from changing_slam_ros.io.dataset import open_dataset
    from changing_slam_ros.sim import renderer  # noqa: F401 - sets MUJOCO_GL before mujoco loads
    from changing_slam_ros.sim.scenarios import build_scenario
    from changing_slam_ros.sim.sequence import RenderOptions, simulate

    root: Path = tmp_path_factory.mktemp("first_pose")
    try:
        simulate(build_scenario("static", 0), root / "static", RenderOptions(width=320, height=240, frames=40, fps=15.0), 0)
    except SimError as err:
        pytest.skip(f"no offscreen rendering here: {err}")
    return list(open_dataset(root / "static", "sim"))


def run(frames: list, first_pose: np.ndarray | None):  # noqa: ANN201
    from changing_slam_ros.commands.run import system_config_from_mapping
    from changing_slam_ros.config import find_config, load_yaml
    from changing_slam_ros.core.system import SlamSystem

    system = SlamSystem(system_config_from_mapping(load_yaml(find_config("sim")), "sim"))
    if first_pose is not None:
        system.set_first_pose(first_pose)
    for rgbd in frames:
        system.process(rgbd)
    return system


def test_a_map_started_at_a_given_pose_is_built_in_that_frame_and_its_grid_is_level(static_room: list) -> None:
    T0 = static_room[0].T_world_cam_gt  # noqa: N806
    assert T0 is not None and -T0[2, 1] > 0.9  # premise: the world is z-up and the camera's -y is nearly up

    optical = run(static_room, None)
    grid = optical.occupancy_grid()
    assert grid is not None
    up_optical = grid.origin_in_map()[:3, 2]
    assert abs(up_optical[2]) < 0.2 and up_optical[1] < -0.9  # the floor's normal is the first camera's -y

    levelled = run(static_room, T0)
    est = levelled.final_trajectory().poses()
    gt = np.array([f.T_world_cam_gt for f in static_room])
    assert len(est) == len(gt) == 40
    err = np.linalg.norm(est[:, :3, 3] - gt[:, :3, 3], axis=1)
    assert err.max() < 0.03  # no alignment: the trajectory is in the world frame it was started in
    assert max(rotation_angle_rad(e[:3, :3].T @ g[:3, :3]) for e, g in zip(est, gt, strict=True)) < np.deg2rad(1.0)

    grid = levelled.occupancy_grid()
    assert grid is not None
    origin = grid.origin_in_map()
    assert np.degrees(np.arccos(np.clip(origin[2, 2], -1, 1))) < 3.0  # the grid's normal is the map's z
    assert origin[0, 0] > 0.99  # its x runs along the map's x
    assert abs(origin[2, 3] - grid.floor.height) < 0.05 and abs(grid.floor.height) < 0.05  # the floor at z = 0


def test_the_first_pose_is_refused_once_the_map_has_keyframes(static_room: list) -> None:
    system = run(static_room[:3], None)
    with pytest.raises(RuntimeError, match="before the first keyframe"):
        system.set_first_pose(np.eye(4))
    from changing_slam_ros.core.system import SlamSystem

    with pytest.raises(ConfigError, match="finite 4x4"):
        SlamSystem().set_first_pose(np.full((4, 4), np.nan))


def run_levelled(frames: list, first_pose: np.ndarray | None = None):  # noqa: ANN201
    from changing_slam_ros.commands.run import system_config_from_mapping
    from changing_slam_ros.config import find_config, load_yaml
    from changing_slam_ros.core.system import SlamSystem

    mapping = load_yaml(find_config("sim"))
    mapping.setdefault("tracking", {})["level_from_floor"] = True
    system = SlamSystem(system_config_from_mapping(mapping, "sim"))
    if first_pose is not None:
        system.set_first_pose(first_pose)
    for rgbd in frames:
        system.process(rgbd)
    return system


def test_a_map_levelled_on_the_floor_in_view_is_z_up_at_the_camera_height(static_room: list) -> None:
    system = run_levelled(static_room)
    assert system.floor_start is not None
    est = system.final_trajectory().poses()
    gt = np.array([f.T_world_cam_gt for f in static_room])
    assert len(est) == 40
    # the map's z is the world's up: heights above the floor and the tilt of every camera as in the world
    assert np.abs(est[:, 2, 3] - gt[:, 2, 3]).max() < 0.03
    tilt = np.degrees(np.arccos(np.clip(np.einsum("ni,ni->n", est[:, 2, :3], gt[:, 2, :3]), -1, 1)))
    assert tilt.max() < 1.0
    assert est[0, :2, 3] == pytest.approx([0.0, 0.0], abs=1e-9)  # the origin is on the floor below the first camera
    grid = system.occupancy_grid()
    assert grid is not None and np.degrees(np.arccos(np.clip(grid.origin_in_map()[2, 2], -1, 1))) < 3.0


def test_a_given_first_pose_wins_over_the_floor(static_room: list) -> None:
    T0 = static_room[0].T_world_cam_gt  # noqa: N806
    system = run_levelled(static_room[:3], T0)
    assert system.floor_start is None
    assert system.final_trajectory().poses()[0] == pytest.approx(T0, abs=1e-9)
