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

from changing_slam_ros.core.movers.object_tracking import (
    FrameObjectMeasurements,
    ObjectTracker,
    ObjectTrackingConfig,
    objects_from_segmentation,
)
from changing_slam_ros.core.movers.point_correlation import CorrelationWindow, SegmentationConfig, segment
from changing_slam_ros.core.geometry.se3 import invert, transform_points


@dataclass(frozen=True)
class SimWindow:
    window: CorrelationWindow
    on_box: np.ndarray  # (M,) bool: the point lies on the carried box (moving or not)
    mover_displacement_m: float  # mean displacement of the box's points over the window
    world0: np.ndarray  # (M, 3) the points in the world at the first time
    instance: np.ndarray  # (M,) 0 room, i + 1 actor i, at the first time
    actor_poses0: list  # actor poses at the first time


def render_at(renderer, scenario, t_s: float):  # type: ignore[no-untyped-def]
    """(T_world_cam, actor poses, rendered frame) at time t_s."""
    T_world_cam = scenario.camera.pose_at(t_s)
    poses = [a.track.pose_at(t_s) for a in scenario.actors]
    return T_world_cam, poses, renderer.render(T_world_cam, poses)


def moved_points(world0: np.ndarray, instance: np.ndarray, poses0: list, poses: list) -> np.ndarray:
    """Points (M, 3) carried from the first time to now by the ground-truth motion of what they lie on."""
    world = world0.copy()
    for actor in np.unique(instance[instance > 0]):
        on = instance == actor
        before, now = poses0[actor - 1], poses[actor - 1]
        if before is not None and now is not None:
            world[on] = transform_points(now @ invert(before), world0[on])
    return world


def measure(camera, frame, T_world_cam: np.ndarray, world: np.ndarray, rng: np.random.Generator):  # type: ignore[no-untyped-def]
    """Noisy pixels (M, 2) and depths (M,) of world points (M, 3), NaN where occluded or out of view."""
    cam_pts = transform_points(invert(T_world_cam), world)
    proj = camera.project(cam_pts)
    c, r = np.round(proj).astype(int).T
    inside = (c >= 0) & (c < camera.width) & (r >= 0) & (r < camera.height) & (cam_pts[:, 2] > 0.1)
    rendered = np.zeros(len(world))
    rendered[inside] = frame.depth_m[r[inside], c[inside]]
    visible = inside & (np.abs(rendered - cam_pts[:, 2]) < 0.03)
    pixels = np.full((len(world), 2), np.nan)
    depths = np.full(len(world), np.nan)
    pixels[visible] = proj[visible] + rng.normal(0.0, 0.5, (int(visible.sum()), 2))
    depths[visible] = cam_pts[visible, 2] + rng.normal(0.0, 1.425e-3 * cam_pts[visible, 2] ** 2)
    return pixels, depths


def oracle_window(renderer, scenario, times_s: list[float], rng: np.random.Generator, n_features: int = 1000) -> SimWindow:  # type: ignore[no-untyped-def]
    """A correlation window over rendered frames at `times_s` with oracle correspondences."""
    mover = scenario.actor_index("parcel")
    cam = renderer.camera
    rendered = [render_at(renderer, scenario, t) for t in times_s]
    T_world_cam0, poses0, first = rendered[0]
    keypoints = cv2.ORB_create(n_features).detect(cv2.cvtColor(first.rgb, cv2.COLOR_RGB2GRAY), None)
    uv = np.array([kp.pt for kp in keypoints])
    col, row = np.round(uv).astype(int).T
    depth = first.depth_m[row, col].astype(np.float64)
    instance = first.instance_ids[row, col].astype(int)
    ok = depth > 0
    uv, depth, instance = uv[ok], depth[ok], instance[ok]
    world0 = transform_points(T_world_cam0, cam.backproject(uv, depth))
    n, k = len(world0), len(times_s)
    pixels, depths = np.full((k, n, 2), np.nan), np.full((k, n), np.nan)
    world = world0
    for j, (T_world_cam, poses, frame) in enumerate(rendered):
        world = moved_points(world0, instance, poses0, poses)
        pixels[j], depths[j] = measure(cam, frame, T_world_cam, world, rng)
    on_box = instance == mover + 1
    disp = float(np.linalg.norm(world[on_box] - world0[on_box], axis=1).mean()) if on_box.any() else 0.0
    T_all = np.stack([r[0] for r in rendered])
    window = CorrelationWindow.from_pixels(np.arange(n), pixels, depths, T_all, cam)
    return SimWindow(window, on_box, disp, world0, instance, poses0)


@dataclass(frozen=True)
class TrackedWindow:
    window: CorrelationWindow
    on_box: np.ndarray  # (M,) bool, from the instance mask of the first frame
    corrupted: np.ndarray  # (M,) bool: some measurement is > 3 cm from the truth (mismatch, silhouette depth)


def tracked_window(renderer, scenario, times_s: list[float], rng: np.random.Generator, n_features: int = 1500) -> TrackedWindow:  # type: ignore[no-untyped-def]
    """A window over ORB feature tracks: each track's latest descriptor is matched into the next frame
    (brute force, Hamming, Lowe ratio 0.8); depth is read from the rendered depth at the matched keypoint."""
    mover = scenario.actor_index("parcel")
    cam = renderer.camera
    rendered = [render_at(renderer, scenario, t) for t in times_s]
    orb = cv2.ORB_create(n_features)
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
    T_world_cam0, poses0, first = rendered[0]
    kps, desc = orb.detectAndCompute(cv2.cvtColor(first.rgb, cv2.COLOR_RGB2GRAY), None)
    uv = np.array([kp.pt for kp in kps])
    col, row = np.round(uv).astype(int).T
    depth = first.depth_m[row, col].astype(np.float64)
    instance = first.instance_ids[row, col].astype(int)
    ok = depth > 0
    uv, depth, instance, desc = uv[ok], depth[ok], instance[ok], desc[ok].copy()
    n, k_frames = len(uv), len(times_s)
    pixels, depths = np.full((k_frames, n, 2), np.nan), np.full((k_frames, n), np.nan)
    pixels[0], depths[0] = uv, depth + rng.normal(0.0, 1.425e-3 * depth**2)
    alive = np.ones(n, dtype=bool)
    for k in range(1, k_frames):
        frame = rendered[k][2]
        kps_k, desc_k = orb.detectAndCompute(cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY), None)
        uv_k = np.array([kp.pt for kp in kps_k])
        tracks = np.flatnonzero(alive)
        alive = np.zeros(n, dtype=bool)
        for pair in matcher.knnMatch(desc[tracks], desc_k, k=2):
            if len(pair) < 2 or pair[0].distance >= 0.8 * pair[1].distance:
                continue
            i, j = tracks[pair[0].queryIdx], pair[0].trainIdx
            c, r = np.round(uv_k[j]).astype(int)
            z = float(frame.depth_m[r, c])
            if z > 0:
                pixels[k, i], depths[k, i] = uv_k[j], z + rng.normal(0.0, 1.425e-3 * z * z)
                desc[i], alive[i] = desc_k[j], True
    window = CorrelationWindow.from_pixels(np.arange(n), pixels, depths, np.stack([r[0] for r in rendered]), cam)
    world0 = transform_points(T_world_cam0, cam.backproject(uv, depth))
    measured = window.points_world()
    corrupted = np.zeros(n, dtype=bool)
    for k, (_, poses, _) in enumerate(rendered):
        err = np.linalg.norm(measured[k] - moved_points(world0, instance, poses0, poses), axis=1)
        corrupted |= np.isfinite(err) & (err > 0.03)
    return TrackedWindow(window, instance == mover + 1, corrupted)


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


def test_carried_box_is_segmented_then_tracked_within_3_cm(unknown_mover) -> None:  # type: ignore[no-untyped-def]
    """Segmentation (5 keyframes) creates the target; eq. 7 and eq. 11 track it for 2 s at 30 Hz."""
    scenario, renderer = unknown_mover
    rng = np.random.default_rng(3)
    times = [8.0 + 0.2 * i for i in range(5)]
    sim = oracle_window(renderer, scenario, times, rng)
    result = segment(sim.window, SegmentationConfig.multi_frame())
    assert result.num_targets == 1
    # 1. The object target, created in the last keyframe of the window from its measured points.
    last = len(times) - 1
    (obj,) = objects_from_segmentation(result, sim.window, int(times[last] * 1e9), first_id=1)
    created = obj.keyposes[0]
    ids = obj.point_ids
    assert np.all(sim.on_box[ids])
    # 2. Track it: its points follow the box's true motion and are measured where visible.
    tracker = ObjectTracker(renderer.camera, ObjectTrackingConfig())
    mover = scenario.actor_index("parcel")
    truth = {created.stamp_ns: scenario.actors[mover].track.pose_at(times[last])}
    for j in range(1, 61):
        t = times[last] + j / 30.0
        T_world_cam, poses, frame = render_at(renderer, scenario, t)
        world = moved_points(sim.world0[ids], sim.instance[ids], sim.actor_poses0, poses)
        pixels, depths = measure(renderer.camera, frame, T_world_cam, world, rng)
        seen = np.isfinite(depths)
        points_cam = renderer.camera.backproject(pixels[seen], depths[seen])
        stamp = int(round(t * 1e9))
        step = tracker.track(obj, FrameObjectMeasurements(stamp, T_world_cam, ids[seen], points_cam))
        if step.tracked:
            truth[stamp] = poses[mover]
            if step.is_keypose:
                tracker.optimise(obj)
    # 3. Error against the box's true pose; the object frame (centre of the target's points) differs from
    #    the box's by a fixed offset, taken at creation as in ATE alignment.
    offset = invert(truth[created.stamp_ns]) @ obj.poses[created.stamp_ns]
    err = [np.linalg.norm(obj.poses[s][:3, 3] - (truth[s] @ offset)[:3, 3]) for s in truth]
    travel = np.linalg.norm(truth[max(truth)][:3, 3] - truth[created.stamp_ns][:3, 3])
    assert len(truth) >= 55 and travel > 0.2
    assert float(np.sqrt(np.mean(np.square(err)))) < 0.03  # Dai et al. report 3.3 cm


def test_keyframe_window_on_orb_feature_tracks_finds_the_box_without_false_positives(unknown_mover) -> None:  # type: ignore[no-untyped-def]
    """Real matching: ~6 % of matches are wrong and corners on the box's outline read background depth.

    Windows of 5 frames 0.1 s apart; where the box moved at least 5 cm over the window it must be found
    (at 11 s it turns around and moves 2.7 cm: not required, but nothing may be flagged wrongly)."""
    scenario, renderer = unknown_mover
    rng = np.random.default_rng(4)
    box_track = scenario.actors[scenario.actor_index("parcel")].track
    tp = fp = n_box = n_clean = tp_clean = 0
    for t in (6.0, 9.0, 11.0, 13.0, 15.0, 17.0):
        times = [t + 0.1 * i for i in range(5)]
        sim = tracked_window(renderer, scenario, times, rng)
        result = segment(sim.window, SegmentationConfig.multi_frame())
        fp += int(np.sum(result.dynamic_mask & ~sim.on_box))
        moved_m = np.linalg.norm(box_track.pose_at(times[-1])[:3, 3] - box_track.pose_at(times[0])[:3, 3])
        if moved_m < 0.05:
            continue
        box = sim.on_box & (sim.window.observed.sum(axis=0) >= 2)
        assert result.num_targets >= 1, t
        tp += int(np.sum(result.dynamic_mask & box))
        n_box += int(box.sum())
        n_clean += int(np.sum(box & ~sim.corrupted))
        tp_clean += int(np.sum(result.dynamic_mask & box & ~sim.corrupted))
    assert tp / (tp + fp) >= 0.95
    assert tp_clean / n_clean >= 0.9, tp_clean / n_clean  # points whose measurements are all right
    assert tp / n_box >= 0.8, tp / n_box  # all tracked box points, corrupted ones included
