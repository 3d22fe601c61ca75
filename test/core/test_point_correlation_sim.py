"""Point-correlation segmentation on the simulator's `unknown_mover` (a box of no COCO class carried by hand).

Map points are ORB keypoints of a rendered frame, back-projected with the rendered depth; their later
measurements follow the ground-truth motion of whatever they lie on (oracle correspondences: feature
matching is not under test here), are dropped where the rendered depth shows them occluded or out of
view, and carry Kinect-like depth noise and 0.5 px pixel noise. Ground truth: the instance mask.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import pytest

from changing_slam_ros.core.point_correlation import CorrelationWindow, SegmentationConfig, segment
from changing_slam_ros.core.se3 import invert, transform_points


@dataclass(frozen=True)
class SimWindow:
    window: CorrelationWindow
    on_box: np.ndarray  # (M,) bool: the point lies on the carried box (moving or not)
    mover_displacement_m: float  # mean displacement of the box's points over the window


def oracle_window(renderer, scenario, times_s: list[float], rng: np.random.Generator, n_features: int = 1000) -> SimWindow:  # type: ignore[no-untyped-def]
    """A correlation window over rendered frames at `times_s` with oracle correspondences."""
    mover = scenario.actor_index("parcel")
    cam = renderer.camera
    T_world_cam, actor_poses, frames = [], [], []
    for t in times_s:
        T_world_cam.append(scenario.camera.pose_at(t))
        actor_poses.append([a.track.pose_at(t) for a in scenario.actors])
        frames.append(renderer.render(T_world_cam[-1], actor_poses[-1]))
    first = frames[0]
    keypoints = cv2.ORB_create(n_features).detect(cv2.cvtColor(first.rgb, cv2.COLOR_RGB2GRAY), None)
    uv = np.array([kp.pt for kp in keypoints])
    col, row = np.round(uv).astype(int).T
    depth = first.depth_m[row, col].astype(np.float64)
    instance = first.instance_ids[row, col].astype(int)
    ok = depth > 0
    uv, depth, instance = uv[ok], depth[ok], instance[ok]
    world0 = transform_points(T_world_cam[0], cam.backproject(uv, depth))
    n, k = len(world0), len(times_s)
    pixels, depths = np.full((k, n, 2), np.nan), np.full((k, n), np.nan)
    moved_world = world0.copy()
    for j in range(k):
        world = world0.copy()
        for actor in np.unique(instance[instance > 0]):
            on = instance == actor
            before, now = actor_poses[0][actor - 1], actor_poses[j][actor - 1]
            if before is not None and now is not None:
                world[on] = transform_points(now @ invert(before), world0[on])
        cam_pts = transform_points(invert(T_world_cam[j]), world)
        proj = cam.project(cam_pts)
        c, r = np.round(proj).astype(int).T
        inside = (c >= 0) & (c < cam.width) & (r >= 0) & (r < cam.height) & (cam_pts[:, 2] > 0.1)
        rendered = np.zeros(n)
        rendered[inside] = frames[j].depth_m[r[inside], c[inside]]
        visible = inside & (np.abs(rendered - cam_pts[:, 2]) < 0.03)
        z = cam_pts[:, 2] + rng.normal(0.0, 1.425e-3 * cam_pts[:, 2] ** 2)
        pixels[j, visible] = proj[visible] + rng.normal(0.0, 0.5, (int(visible.sum()), 2))
        depths[j, visible] = z[visible]
        moved_world = world
    on_box = instance == mover + 1
    disp = float(np.linalg.norm(moved_world[on_box] - world0[on_box], axis=1).mean()) if on_box.any() else 0.0
    window = CorrelationWindow.from_pixels(np.arange(n), pixels, depths, np.stack(T_world_cam), cam)
    return SimWindow(window, on_box, disp)


@pytest.fixture(scope="module")
def unknown_mover():  # type: ignore[no-untyped-def]
    sim = pytest.importorskip("changing_slam_ros.sim.renderer")
    from changing_slam_ros.sim.scenarios import build_scenario
    from changing_slam_ros.sim.scene import SceneSpec

    scenario = build_scenario("unknown_mover", 0)
    spec = SceneSpec(scenario.room, scenario.actors, scenario.fovy_deg, 640, 480)
    try:
        renderer = sim.SimRenderer(spec)
        renderer.__enter__()
    except Exception as err:  # no OpenGL context on this machine
        pytest.skip(f"simulator cannot render here: {err}")
    yield scenario, renderer
    renderer.__exit__(None, None, None)


def _scores(result, truth: np.ndarray) -> tuple[float, float]:  # type: ignore[no-untyped-def]
    tp = float(np.sum(result.dynamic_mask & truth))
    return tp / max(float(result.dynamic_mask.sum()), 1.0), tp / max(float(truth.sum()), 1.0)


def test_two_frame_segmentation_separates_the_carried_box(unknown_mover) -> None:  # type: ignore[no-untyped-def]
    scenario, renderer = unknown_mover
    rng = np.random.default_rng(0)
    sim = oracle_window(renderer, scenario, [8.0, 8.0 + 2 / 30], rng)
    result = segment(sim.window, SegmentationConfig.two_frame())
    precision, recall = _scores(result, sim.on_box)
    assert sim.on_box.sum() > 100 and sim.mover_displacement_m > 0.015
    assert result.num_targets == 1
    assert precision >= 0.9 and recall >= 0.9, (precision, recall)


def test_keyframe_window_segmentation_separates_the_carried_box(unknown_mover) -> None:  # type: ignore[no-untyped-def]
    scenario, renderer = unknown_mover
    rng = np.random.default_rng(1)
    sim = oracle_window(renderer, scenario, [14.0 + 0.2 * i for i in range(5)], rng)
    result = segment(sim.window, SegmentationConfig.multi_frame())
    precision, recall = _scores(result, sim.on_box)
    assert precision >= 0.9 and recall >= 0.9, (precision, recall)
    assert np.mean(result.static_mask[~sim.on_box & (sim.window.observed.sum(axis=0) >= 2)]) >= 0.95


def test_box_resting_on_the_table_is_static(unknown_mover) -> None:  # type: ignore[no-untyped-def]
    scenario, renderer = unknown_mover
    rng = np.random.default_rng(2)
    sim = oracle_window(renderer, scenario, [0.5 + 0.2 * i for i in range(5)], rng)
    result = segment(sim.window, SegmentationConfig.multi_frame())
    assert sim.on_box.sum() > 30 and sim.mover_displacement_m < 1e-9
    assert result.num_targets == 0
    assert np.mean(result.static_mask[sim.on_box]) >= 0.9
