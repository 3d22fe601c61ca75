"""`core.slam.still_camera`: a still camera keeps to the background its last pose explains while a close mover
that holds most matches would pull the pose away; a camera that moves is left alone."""

from __future__ import annotations

import numpy as np

from changing_slam_ros.core.geometry.pose_optimizer import PinholeStereo, PoseObservations, optimize_pose
from changing_slam_ros.core.slam.still_camera import StillCamera, StillCameraConfig

CAM = PinholeStereo(262.5, 262.5, 159.5, 119.5, 20.0)  # 320x240, 0.08 m virtual baseline
ON = StillCameraConfig(enabled=True)


def observe(T_cam_world: np.ndarray, mover_shift_m: float, seed: int = 0) -> PoseObservations:
    """A wall 4 m off (150 map points) and a mover 1.2 m off (250 map points), seen from `T_cam_world`; the mover
    now stands `mover_shift_m` to the right of where the map has it."""
    rng = np.random.default_rng(seed)
    wall = np.c_[rng.uniform(-2.4, 2.4, 150), rng.uniform(-1.8, 1.8, 150), np.full(150, 4.0)]
    mover = np.c_[rng.uniform(-0.35, 0.35, 250), rng.uniform(-0.6, 0.6, 250), rng.uniform(1.1, 1.3, 250)]
    points_w = np.r_[wall, mover]
    now = points_w.copy()
    now[150:, 0] += mover_shift_m
    pc = now @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
    uv = np.c_[CAM.fx * pc[:, 0] / pc[:, 2] + CAM.cx, CAM.fy * pc[:, 1] / pc[:, 2] + CAM.cy] + rng.normal(0, 0.5, (400, 2))
    return PoseObservations(points_w, uv, uv[:, 0] - CAM.bf / pc[:, 2], np.ones(400))


def still_for(frames: int) -> StillCamera:
    still = StillCamera(ON)
    for _ in range(frames):
        still.accept(np.eye(4), np.eye(4))  # at rest at the identity
    return still


def test_a_still_camera_is_held_against_a_close_mover() -> None:
    obs = observe(np.eye(4), 0.08)
    full = optimize_pose(np.eye(4), obs, CAM)
    assert np.linalg.norm(full.T_cam_world[:3, 3]) > 0.03  # premise: the mover pulls the pose
    held = still_for(5).check(obs, CAM, full, 6)
    assert np.linalg.norm(held.T_cam_world[:3, 3]) < 0.015  # the wall alone: 0.5 px noise on far points
    assert held.inliers[:150].mean() > 0.9 and held.inliers[150:].mean() < 0.1
    assert still_for(4).check(obs, CAM, full, 6) is full  # not still long enough yet


def test_a_camera_that_moves_is_left_alone() -> None:
    T = np.eye(4)  # noqa: N806
    T[0, 3] = -0.06  # the camera went 6 cm to the right: nothing the last pose explains is left
    obs = observe(T, 0.0)
    full = optimize_pose(np.eye(4), obs, CAM)
    assert np.abs(full.T_cam_world[:3, 3] - T[:3, 3]).max() < 0.005
    assert still_for(10).check(obs, CAM, full, 6) is full


def test_motion_restarts_the_count() -> None:
    still = still_for(6)
    step = np.eye(4)
    step[2, 3] = 0.01
    still.accept(step, np.eye(4))
    assert still.n_still == 0 and still.anchor_cw is None
    still.accept(None, np.eye(4))
    assert still.n_still == 0


def test_a_held_frame_keeps_the_anchor_and_the_count() -> None:
    obs = observe(np.eye(4), 0.08)
    still = still_for(5)
    held = still.check(obs, CAM, optimize_pose(np.eye(4), obs, CAM), 6)
    step = np.linalg.inv(held.T_cam_world)  # the held frame moved a few millimetres from the anchor
    still.accept(step, held.T_cam_world)
    assert still.n_still == 6 and np.array_equal(still.anchor_cw, np.eye(4))
