"""The RGB-D sensor model: depth noise grows with the square of the distance, holes where a structured-light
sensor has them (projector shadow and mixed pixels at depth edges, outside the range), blur only when the
camera moves, and a fixed output for a fixed seed."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from changing_slam_ros.errors import SimError
from changing_slam_ros.sim.renderer import RenderedFrame, intrinsics_for
from changing_slam_ros.sim.sensor_model import (
    EXACT, SensorModel, draw_sensor, frame_rng, kinect_like, preset, projector_shadow, realsense_like,
)
from changing_slam_ros.sim.track import pose_xyz_rpy

W, H = 320, 240
CAMERA = intrinsics_for(W, H, 49.1)


def _frame(depth_m: np.ndarray, grey: int = 128) -> RenderedFrame:
    rgb = np.full((*depth_m.shape, 3), grey, dtype=np.uint8)
    return RenderedFrame(rgb, depth_m.astype(np.float32), np.zeros(depth_m.shape, dtype=np.uint16))


def test_depth_noise_on_a_flat_wall_grows_with_the_square_of_the_distance() -> None:
    noise_only = SensorModel(name="noise", inv_depth_sigma_per_m=0.0015, max_range_m=10.0)
    stds = {}
    for z in (1.0, 2.0, 4.0):
        out = noise_only.depth(np.full((H, W), z, np.float32), np.zeros((H, W, 3), np.uint8), CAMERA, frame_rng(1, 0))
        stds[z] = float(np.std(out[out > 0]))
        assert stds[z] == pytest.approx(0.0015 * z * z, rel=0.05)  # sigma_z = k z^2
    assert stds[4.0] / stds[1.0] == pytest.approx(16.0, rel=0.1)


def test_kinect_quantisation_and_noise_together_still_grow_about_quadratically() -> None:
    kinect = dataclasses.replace(kinect_like(), dropout_prob=0.0, dark_hole_prob=0.0)
    stds = []
    for z in (1.0, 2.0, 4.0):
        out = kinect.depth(np.full((H, W), z, np.float32), np.full((H, W, 3), 128, np.uint8), CAMERA, frame_rng(2, 0))
        stds.append(float(np.std(out[out > 0])))
        assert abs(float(np.mean(out[out > 0])) - z) < 0.01 * z * z  # unbiased to within a tenth of a quantum
    assert 3.0 < stds[1] / stds[0] < 5.0 and 3.0 < stds[2] / stds[1] < 5.0


def test_projector_shadow_beside_a_near_surface_has_the_triangulation_width() -> None:
    depth = np.full((H, W), 3.0)
    depth[:, :150] = 1.0  # a near surface on the left, the wall 2 m behind it
    shadow = projector_shadow(depth, CAMERA.fx * 0.075)
    expected_px = CAMERA.fx * 0.075 * (1.0 / 1.0 - 1.0 / 3.0)
    row = shadow[H // 2]
    assert not row[:150].any()
    assert abs(int(row.sum()) - expected_px) <= 1.5
    assert row[150:150 + int(expected_px) - 1].all()


def test_holes_lie_along_depth_edges_and_nowhere_else_without_dropouts() -> None:
    sensor = dataclasses.replace(kinect_like(), dropout_prob=0.0, dark_hole_prob=0.0, inv_depth_sigma_per_m=0.0)
    depth = np.full((H, W), 3.0, np.float32)
    depth[60:180, 100:200] = 1.2  # a box in front of a wall
    out = sensor.depth(depth, np.full((H, W, 3), 128, np.uint8), CAMERA, frame_rng(3, 0))
    holes = out == 0
    cols = np.flatnonzero(holes[H // 2])
    assert cols.size > 0
    shadow_px = CAMERA.fx * 0.075 * (1 / 1.2 - 1 / 3.0)
    assert cols.min() >= 100 - sensor.edge_hole_px  # mixed pixels at the left edge
    assert cols.max() <= 200 + shadow_px + sensor.edge_hole_px + 1  # the shadow right of the right edge
    assert not holes[:40].any() and not holes[:, :90].any()  # far from any edge: every pixel reads


def test_nothing_is_read_outside_the_range() -> None:
    # a wall receding from 5 cm to 9 m along the image rows; no shadow or edge holes on such a ramp
    sensor = dataclasses.replace(realsense_like(max_range_m=5.0), dropout_prob=0.0, dark_hole_prob=0.0,
                                 baseline_m=0.0, edge_jump_rel=0.0)
    ramp = np.tile(np.linspace(0.05, 9.0, W, dtype=np.float32), (H, 1))
    out = sensor.depth(ramp, np.full((H, W, 3), 128, np.uint8), CAMERA, frame_rng(4, 0))
    read = out[out > 0]
    assert read.min() >= sensor.min_range_m and read.max() <= sensor.max_range_m
    assert (out[:, ramp[0] > 5.3] == 0).all() and (out[:, ramp[0] < 0.18] == 0).all()
    assert (out[:, (ramp[0] > 0.5) & (ramp[0] < 4.0)] > 0).mean() > 0.95


def test_dark_surfaces_lose_depth_and_bright_ones_keep_it() -> None:
    sensor = SensorModel(name="dark", dark_level=30.0, dark_hole_prob=0.5, max_range_m=10.0)
    depth = np.full((H, W), 2.0, np.float32)
    rgb = np.full((H, W, 3), 200, np.uint8)
    rgb[:, : W // 2] = 10
    out = sensor.depth(depth, rgb, CAMERA, frame_rng(5, 0))
    dark_holes, bright_holes = (out[:, : W // 2] == 0).mean(), (out[:, W // 2:] == 0).mean()
    assert 0.3 < dark_holes < 0.7 and bright_holes == 0.0


def test_motion_blur_only_when_the_camera_moves() -> None:
    sensor = SensorModel(name="blur", exposure_s=0.02)
    rng = np.random.default_rng(0)
    frame = RenderedFrame(rng.integers(0, 255, (H, W, 3), dtype=np.uint8), np.full((H, W), 2.0, np.float32),
                          np.zeros((H, W), np.uint16))
    still = sensor.apply(frame, CAMERA, frame_rng(6, 1), 0.1, np.eye(4), np.eye(4), 1 / 30)
    turned = sensor.apply(frame, CAMERA, frame_rng(6, 1), 0.1, pose_xyz_rpy(0, 0, 0, pitch=np.radians(1.5)),
                          np.eye(4), 1 / 30)  # 45 deg/s pan: about 6 px during a 20 ms exposure at f = 262 px
    assert np.array_equal(still.rgb, frame.rgb)
    grad = lambda im: float(np.abs(np.diff(im.astype(np.float64), axis=1)).mean())  # noqa: E731
    assert grad(turned.rgb) < 0.6 * grad(frame.rgb)


def test_same_seed_same_frame_and_another_seed_differs() -> None:
    sensor = kinect_like()
    frame = _frame(np.full((H, W), 2.5))
    a = sensor.apply(frame, CAMERA, frame_rng(7, 3), 0.1)
    b = sensor.apply(frame, CAMERA, frame_rng(7, 3), 0.1)
    c = sensor.apply(frame, CAMERA, frame_rng(8, 3), 0.1)
    assert np.array_equal(a.depth_m, b.depth_m) and np.array_equal(a.rgb, b.rgb)
    assert not np.array_equal(a.depth_m, c.depth_m)
    assert np.array_equal(a.instance_ids, frame.instance_ids)  # ground truth untouched


def test_the_exact_sensor_changes_nothing() -> None:
    frame = _frame(np.full((H, W), 2.5))
    assert EXACT.is_exact() and EXACT.apply(frame, CAMERA, frame_rng(0, 0), 0.0) is frame


def test_drawn_sensors_are_exact_or_within_their_preset_ranges() -> None:
    rng = np.random.default_rng(11)
    names = set()
    for _ in range(40):
        s = draw_sensor(rng)
        s.validate()
        names.add(s.name)
        if s.name == "kinect":
            assert 0.0012 <= s.inv_depth_sigma_per_m <= 0.0019 and 4.5 <= s.max_range_m <= 6.0
        elif s.name == "realsense":
            assert 0.002 <= s.inv_depth_sigma_per_m <= 0.004 and 5.0 <= s.max_range_m <= 8.0
    assert names == {"exact", "kinect", "realsense"}


def test_bad_parameters_and_names_raise_one_line_errors() -> None:
    with pytest.raises(SimError, match="dropout_prob"):
        SensorModel(name="x", dropout_prob=1.5).validate()
    with pytest.raises(SimError, match="inv_depth_sigma_per_m"):
        SensorModel(name="x", inv_depth_sigma_per_m=-1.0).validate()
    with pytest.raises(SimError, match="unknown; known: exact, kinect, realsense"):
        preset("lidar")
