"""The free-space check on synthetic depth: a wall, a static pillar in front of it, the camera moving, and a box
that moved into space the earlier frame saw empty."""

from __future__ import annotations

import numpy as np
import pytest

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.movers.free_space_check import FreeSpaceConfig, free_space_violations, near_surface
from changing_slam_ros.errors import ConfigError

CAM = CameraIntrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)
WALL_Z = 3.0
PILLAR = (-0.6, -0.3, 1.5)  # x from, x to, depth (m): a static pillar in front of the wall


def _pose(x: float = 0.0, z: float = 0.0) -> np.ndarray:
    T = np.eye(4)
    T[0, 3], T[2, 3] = x, z
    return T


def _depth(T_world_cam: np.ndarray, noise_m: float = 0.0, seed: int = 0) -> np.ndarray:
    """Depth image of the wall (z = 3 in the world) and the pillar, seen from a camera translated by T."""
    v, u = np.mgrid[0:CAM.height, 0:CAM.width].astype(np.float64)
    rays = np.stack([(u - CAM.cx) / CAM.fx, (v - CAM.cy) / CAM.fy], axis=-1)
    cx, cz = T_world_cam[0, 3], T_world_cam[2, 3]
    depth = np.full((CAM.height, CAM.width), WALL_Z - cz)
    d_pillar = PILLAR[2] - cz
    x_at_pillar = cx + rays[..., 0] * d_pillar
    on_pillar = (x_at_pillar >= PILLAR[0]) & (x_at_pillar <= PILLAR[1])
    depth[on_pillar] = d_pillar
    depth += np.random.default_rng(seed).normal(0.0, noise_m, depth.shape) * depth**2
    return depth.astype(np.float32)


def _keypoints(depth: np.ndarray, step: int = 16) -> tuple[np.ndarray, np.ndarray]:
    v, u = np.mgrid[8:CAM.height:step, 8:CAM.width:step]
    px = np.stack([u.ravel(), v.ravel()], axis=1).astype(np.float64)
    return px, depth[v.ravel(), u.ravel()].astype(np.float64)


def test_a_static_scene_seen_while_the_camera_moves_flags_nothing_even_on_silhouettes():
    then, now = _pose(), _pose(x=0.10, z=0.15)  # 10 cm sideways, 15 cm closer: parallax around the pillar
    near = near_surface(_depth(then, noise_m=0.002), 640, FreeSpaceConfig().window_px)
    depth_now = _depth(now, noise_m=0.002, seed=1)
    px, z = _keypoints(depth_now, step=4)
    flags = free_space_violations(px, z, now, near, then, CAM, FreeSpaceConfig())
    assert len(z) > 15000 and flags.sum() == 0


def test_a_box_that_moved_into_empty_space_is_flagged_and_the_background_is_not():
    then, now = _pose(), _pose(x=0.05)
    near = near_surface(_depth(then), 640, FreeSpaceConfig().window_px)
    depth_now = _depth(now)
    box = np.zeros_like(depth_now, dtype=bool)
    box[100:300, 380:560] = True  # a box 1.2 m away, where the wall was seen before
    depth_now[box] = 1.2
    px, z = _keypoints(depth_now)
    on_box = box[px[:, 1].astype(int), px[:, 0].astype(int)]
    flags = free_space_violations(px, z, now, near, then, CAM, FreeSpaceConfig())
    assert flags[on_box].mean() > 0.95 and not flags[~on_box].any()


def test_what_the_earlier_frame_could_not_see_is_not_flagged():
    """A mover behind the earlier surface, outside the earlier image, or where it had no depth is left alone."""
    then, now = _pose(), _pose()
    depth_then = _depth(then)
    depth_then[:, :100] = 0.0  # no reading there then
    near = near_surface(depth_then, 640, FreeSpaceConfig().window_px)
    px = np.array([[50.0, 240.0], [52.0, 244.0], [48.0, 236.0],  # in front, but no depth then
                   [160.0, 240.0], [164.0, 244.0], [156.0, 236.0]])  # behind the pillar (occluded then)
    z = np.array([1.0, 1.0, 1.0, 2.5, 2.5, 2.5])
    assert not free_space_violations(px, z, now, near, then, CAM, FreeSpaceConfig()).any()
    behind_camera_then = _pose(z=2.0)  # the earlier camera stood 2 m further in: the points lay behind it
    near_far = near_surface(_depth(behind_camera_then), 640, 8)
    assert not free_space_violations(px, z, now, near_far, behind_camera_then, CAM, FreeSpaceConfig()).any()


def test_an_isolated_flag_needs_flagged_neighbours():
    then = now = _pose()
    near = near_surface(_depth(then), 640, 8)
    px, z = _keypoints(_depth(now))
    z = z.copy()
    z[len(z) // 2 + 7] = 1.0  # one wrong depth on the wall
    assert not free_space_violations(px, z, now, near, then, CAM, FreeSpaceConfig()).any()
    assert free_space_violations(px, z, now, near, then, CAM, FreeSpaceConfig(min_neighbours=0)).sum() == 1


def test_the_window_scales_with_the_image_width_and_bad_settings_are_refused():
    d = np.full((240, 320), 3.0, np.float32)
    d[100, 100] = 1.0
    near = near_surface(d, 640, 8)  # 4 px at 320 wide
    assert near[104, 104] == 1.0 and near[105, 100] == 3.0
    assert np.isinf(near_surface(np.zeros((10, 10), np.float32), 640, 8)).all()
    with pytest.raises(ConfigError):
        FreeSpaceConfig(min_neighbours=7, neighbours=6)
