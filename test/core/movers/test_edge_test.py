"""`edge_test.edge_test_segment` on a synthetic two-frame scene: a mover in front of a static room, seen
through a depth sensor noisier than the segmentation's model (sigma_z = 0.004 z^2, the noisiest RealSense-like
sensor of the simulator, against the model's Kinect 1.425e-3 z^2)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.movers.correlation_window import SegmentationConfig
from changing_slam_ros.core.movers.edge_test import edge_test_segment

CAM = CameraIntrinsics(320, 240, 260.0, 260.0, 160.0, 120.0)


def _scene(seed: int, k_per_m: float, step_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixels (2, M, 2), depths (2, M) of a static room (up to 400 points, 2-5 m, less what the mover hides) and a box-shaped mover (80 points,
    1.2-1.5 m) that moves `step_m` sideways between the two frames; a still camera; depth noise k z^2 and
    0.5 px of keypoint noise. Returns pixels, depths and the truth (M,) of the mover's points."""
    rng = np.random.default_rng(seed)
    room = np.column_stack([rng.uniform(-2.0, 2.0, 400), rng.uniform(-1.2, 1.2, 400), rng.uniform(2.0, 5.0, 400)])
    mover = np.column_stack([rng.uniform(-0.3, 0.2, 80), rng.uniform(-0.3, 0.4, 80), rng.uniform(1.2, 1.5, 80)])
    # room points that the mover hides in either frame are not seen
    lo = np.array([(-0.3 - 0.02) / 1.2, (-0.3 - 0.02) / 1.2])
    hi = np.array([(0.2 + step_m + 0.02) / 1.2, (0.4 + 0.02) / 1.2])
    ray = room[:, :2] / room[:, 2:3]
    room = room[~np.all((ray >= lo) & (ray <= hi), axis=1)]
    before = np.vstack([room, mover])
    after = before.copy()
    after[len(room):, 0] += step_m
    pixels, depths = [], []
    for pts in (before, after):
        z = pts[:, 2] + rng.normal(0.0, 1.0, len(pts)) * k_per_m * pts[:, 2] ** 2
        uv = np.column_stack([CAM.fx * pts[:, 0] / pts[:, 2] + CAM.cx, CAM.fy * pts[:, 1] / pts[:, 2] + CAM.cy])
        pixels.append(uv + rng.normal(0.0, 0.5, uv.shape))
        depths.append(z)
    truth = np.zeros(len(before), bool)
    truth[len(room):] = True
    return np.stack(pixels), np.stack(depths), truth


def _rates(cfg: SegmentationConfig, k_per_m: float, step_m: float) -> tuple[float, float]:
    """(false alarms among static points, recall of the mover's points) over five scenes."""
    poses = np.stack([np.eye(4), np.eye(4)])
    false_alarms, hits, n_static, n_moving = 0, 0, 0, 0
    for seed in range(5):
        pixels, depths, truth = _scene(seed, k_per_m, step_m)
        moving = edge_test_segment(pixels, depths, poses, CAM, cfg).moving
        false_alarms += int((moving & ~truth).sum())
        hits += int((moving & truth).sum())
        n_static += int((~truth).sum())
        n_moving += int(truth.sum())
    return false_alarms / n_static, hits / n_moving


def test_a_sensor_noisier_than_the_model_raises_few_false_alarms_when_the_noise_is_read_off_the_edges() -> None:
    fixed = SegmentationConfig.two_frame()
    adaptive = replace(fixed, noise_from_edges=True)
    fa_fixed, _ = _rates(fixed, 0.004, 0.1)
    fa_adaptive, recall = _rates(adaptive, 0.004, 0.1)
    assert fa_fixed > 0.1  # the Kinect model flags static points of a RealSense-like sensor
    assert fa_adaptive < 0.02
    assert recall > 0.9  # a mover 10 cm away from where it was is still found


def test_the_model_stays_the_floor_on_a_clean_sensor() -> None:
    """With depth as clean as the model's the scale stays 1: the same flags with and without it."""
    fixed = SegmentationConfig.two_frame()
    for seed in range(3):
        pixels, depths, _ = _scene(seed, 0.0005, 0.05)
        poses = np.stack([np.eye(4), np.eye(4)])
        a = edge_test_segment(pixels, depths, poses, CAM, fixed).moving
        b = edge_test_segment(pixels, depths, poses, CAM, replace(fixed, noise_from_edges=True)).moving
        np.testing.assert_array_equal(a, b)
