"""The random dynamic-scene family: each seed's draws lie within the stated ranges, seeds differ, a seed is
reproducible, the control keeps everything but the movers, and a rendered seed's ground truth is consistent
(static depth re-projects across frames with the ground-truth poses; movers' pixels fall in their boxes)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from changing_slam_ros.core.geometry.se3 import invert, make_pose, quat_to_rot
from changing_slam_ros.io.camera_info import read_camera_info_yaml
from changing_slam_ros.io.tum_trajectory import read_tum_trajectory
from changing_slam_ros.sim.random_dynamic import CAMERA_KINDS, RANGES, build_random_dynamic, draw_params
from changing_slam_ros.sim.random_movers import MOVER_KINDS, OBJECT_SHAPES
from changing_slam_ros.sim.scenarios import build_scenario
from changing_slam_ros.sim.sensor_model import EXACT
from changing_slam_ros.sim.sequence import RenderOptions, simulate

W, H = 160, 120
GT_SEED = 25  # hand-held xyz sway; four movers (people carrying a box, a suitcase and a board, a walker)


def _within(v: float, lo_hi: tuple[float, float]) -> bool:
    return lo_hi[0] - 1e-9 <= v <= lo_hi[1] + 1e-9


def test_every_drawn_parameter_lies_within_its_range() -> None:
    r = RANGES
    kinds, cameras = set(), set()
    for seed in range(40):
        p = draw_params(seed)
        assert _within(p.room.half_x_m, r.room.half_x_m) and _within(p.room.half_y_m, r.room.half_y_m)
        assert _within(p.room.height_m, r.room.height_m) and _within(p.room.ambient, r.room.ambient)
        assert _within(len(p.room.posters), r.room.posters) and _within(len(p.room.furniture), r.room.furniture)
        assert _within(len(p.room.lights), r.room.lights)
        assert all(_within(li.level, r.room.light_level) for li in p.room.lights)
        c = p.camera
        assert c.kind in CAMERA_KINDS and c.wall_distance_m <= r.camera.wall_distance_m[1]
        assert _within(c.eye_height_m, r.camera.robot_height_m if c.kind == "robot" else r.camera.eye_height_m)
        assert _within(c.period_s, r.camera.period_s)
        assert _within(len(p.movers), r.movers.count)
        for m in p.movers:
            assert m.kind in MOVER_KINDS and (m.shape == "person" or m.shape in OBJECT_SHAPES)
            assert _within(m.distance_m, r.movers.distance_m)
            assert _within(m.speed_m_s, r.movers.person_speed_m_s if m.kind in ("walker", "sitter", "carried")
                           else r.movers.object_speed_m_s)
            assert _within(m.person_height_m, r.movers.person_height_m)
            assert all(_within(pause, r.movers.pause_s) for _, pause in m.stops)
            kinds.add(m.kind)
        p.sensor.validate()
        cameras.add(c.kind)
    assert kinds == set(MOVER_KINDS) and cameras == set(CAMERA_KINDS)  # 40 seeds reach every kind


def test_the_same_seed_draws_the_same_scene_and_two_seeds_differ() -> None:
    assert draw_params(7).as_dict() == draw_params(7).as_dict()
    assert draw_params(7).as_dict() != draw_params(8).as_dict()
    a, b = build_random_dynamic(7), build_random_dynamic(7)
    for t in (0.0, 2.5, 9.0):
        assert np.array_equal(a.camera.pose_at(t), b.camera.pose_at(t))


def test_the_control_keeps_room_path_and_sensor_and_drops_the_movers() -> None:
    scene, control = build_scenario("random_dynamic", 3), build_scenario("random_dynamic_control", 3)
    assert control.room == scene.room and control.sensor == scene.sensor
    for t in (0.0, 4.0, 9.5):
        assert np.array_equal(control.camera.pose_at(t), scene.camera.pose_at(t))
    assert not any(a.moving for a in control.actors)
    assert {a.name for a in control.actors} == {a.name for a in scene.actors if not a.moving}
    assert any(a.moving for a in scene.actors)
    assert control.parameters["control"] and not scene.parameters["control"]


def test_movers_move_at_the_drawn_speeds_and_stop_sometimes() -> None:
    scene = build_scenario("random_dynamic", GT_SEED)
    params = scene.parameters["movers"]
    for actor in scene.actors:
        if not actor.moving or not actor.name.endswith("_person"):
            continue
        drawn = params[int(actor.name[len("mover"):].split("_")[0])]["speed_m_s"]
        xy = np.array([actor.track.pose_at(k / 30.0)[:2, 3] for k in range(300)])
        speed = np.linalg.norm(np.diff(xy, axis=0), axis=1) * 30.0
        assert speed.max() == pytest.approx(drawn, rel=0.05)
        assert (speed < 0.01).any()  # it stands still at some point (start delay, stops, ends of its path)


@pytest.fixture(scope="module")
def rendered(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """GT_SEED, 8 frames 0.5 s apart at 160x120 with an exact sensor."""
    out = tmp_path_factory.mktemp("random_dynamic")
    simulate(build_scenario("random_dynamic", GT_SEED), out,
             RenderOptions(W, H, frames=8, fps=2.0, sensor=EXACT), seed=GT_SEED)
    return out


def _load(folder: Path) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray, dict]:
    lines = [ln.split() for ln in (folder / "associations.txt").read_text().splitlines()]
    depths = [cv2.imread(str(folder / d), cv2.IMREAD_UNCHANGED).astype(np.float64) / 5000.0 for _, _, _, d in lines]
    masks = [cv2.imread(str(folder / "masks" / Path(r).name), cv2.IMREAD_UNCHANGED) for _, r, _, _ in lines]
    poses = read_tum_trajectory(folder / "groundtruth.txt").poses()
    return depths, masks, poses, json.loads((folder / "objects.json").read_text())


def test_static_depth_of_a_random_seed_lands_on_the_same_points_across_frames(rendered: Path) -> None:
    depths, masks, poses, _ = _load(rendered)
    cam = read_camera_info_yaml(rendered / "camera_info.yaml")
    assert np.linalg.norm(poses[0][:3, 3] - poses[-1][:3, 3]) > 0.02  # the camera moved
    for i, j in ((0, 4), (3, 7), (6, 1)):
        v, u = np.nonzero((masks[j] == 0) & (depths[j] > 0))
        pts = cam.backproject(np.c_[u, v].astype(float), depths[j][v, u])
        T_i_j = invert(poses[i]) @ poses[j]
        p = pts @ T_i_j[:3, :3].T + T_i_j[:3, 3]
        uv = np.rint(cam.project(p)).astype(int)
        ok = (p[:, 2] > 0.1) & (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
        ok[ok] &= masks[i][uv[ok, 1], uv[ok, 0]] == 0
        err = np.abs(depths[i][uv[ok, 1], uv[ok, 0]] - p[ok, 2])
        assert ok.sum() > 0.3 * W * H
        assert np.median(err) < 0.01  # rounding to the nearest pixel: a centimetre on slanted floors


def test_object_pixels_of_a_random_seed_back_project_into_their_boxes(rendered: Path) -> None:
    depths, masks, poses, objects = _load(rendered)
    cam = read_camera_info_yaml(rendered / "camera_info.yaml")
    checked = set()
    for k in range(len(masks)):
        for obj in objects["objects"]:
            v, u = np.nonzero(masks[k] == obj["id"])
            if u.size < 30 or obj["poses"][k] is None:
                continue
            pose = obj["poses"][k]
            T_world_obj = make_pose(quat_to_rot(np.array(pose[3:])), np.array(pose[:3]))
            pts = cam.backproject(np.c_[u, v].astype(float), depths[k][v, u])
            T_obj_cam = invert(T_world_obj) @ poses[k]
            p = pts @ T_obj_cam[:3, :3].T + T_obj_cam[:3, 3]
            lo, hi = np.array(obj["box_min_m"]) - 0.01, np.array(obj["box_max_m"]) + 0.01
            assert np.all((p >= lo) & (p <= hi), axis=1).mean() > 0.99, f"{obj['name']} frame {k}"
            checked.add(obj["name"])
    assert {"mover0_carried_box", "mover1_walker_person"} <= checked


def test_a_seed_renders_through_its_sensor_and_writes_what_it_drew(tmp_path: Path) -> None:
    scene = build_scenario("random_dynamic", 4)  # a Kinect-like sensor
    assert scene.sensor.name == "kinect"
    simulate(scene, tmp_path, RenderOptions(W, H, frames=2), seed=4)
    doc = json.loads((tmp_path / "scenario.json").read_text())
    assert doc["seed"] == 4 and doc["parameters"]["sensor"]["name"] == "kinect"
    assert json.loads((tmp_path / "sensor.json").read_text())["name"] == "kinect"
    depth = cv2.imread(str(next((tmp_path / "depth").glob("*.png"))), cv2.IMREAD_UNCHANGED)
    assert 0.0 < (depth == 0).mean() < 0.5  # holes, but most pixels read


def test_simulate_control_flag_renders_the_control_or_names_the_missing_one(tmp_path: Path,
                                                                              capsys: pytest.CaptureFixture[str]) -> None:
    from changing_slam_ros.cli import main as cli_main

    out = tmp_path / "c"
    assert cli_main(["simulate", "random_dynamic", "--seed", "5", "--control", "--frames", "1", "--width", "64",
                     "--height", "48", "--quiet", "--out", str(out)]) == 0
    doc = json.loads((out / "scenario.json").read_text())
    assert doc["scenario"] == "random_dynamic_control" and doc["parameters"]["control"]
    assert cli_main(["simulate", "sitting_xyz", "--control", "--out", str(tmp_path / "x")]) == 1
    assert "sitting_xyz_control is not a scenario" in capsys.readouterr().err
