"""The displacement vote that re-aims a motion-model prediction (`core.slam.rotation_vote`): the rotation it
finds among copies of a repeated pattern, and a robot that starts to turn in front of a brick wall."""

from __future__ import annotations

import math
from dataclasses import replace

import cv2
import numpy as np
import pytest

from changing_slam_ros.core.features.rgbd_frame import RgbdFrame
from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.geometry.se3 import make_pose
from changing_slam_ros.core.slam.rotation_vote import RotationVoteConfig, vote_rotation
from changing_slam_ros.core.slam.tracking_config import TrackingConfig
from changing_slam_ros.core.system import SlamSystem, SystemConfig
from changing_slam_ros.sim.sensor_model import kinect_like
from changing_slam_ros.sim.textures import load_texture

CAM = CameraIntrinsics(width=320, height=240, fx=250.0, fy=250.0, cx=159.5, cy=119.5)
VGA = CameraIntrinsics(width=640, height=480, fx=525.0, fy=525.0, cx=319.5, cy=239.5)


def _rot(yaw_deg: float, pitch_deg: float) -> np.ndarray:
    r, _ = cv2.Rodrigues(np.deg2rad(np.array([pitch_deg, yaw_deg, 0.0])))
    return r


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.rad2deg(np.linalg.norm(cv2.Rodrigues(a.T @ b)[0])))


def test_vote_finds_the_rotation_among_the_copies_of_a_repeated_pattern() -> None:
    rng = np.random.default_rng(4)
    n = 150
    pts = np.column_stack([rng.uniform(-1.2, 1.2, n), rng.uniform(-0.8, 0.8, n), rng.uniform(1.8, 2.6, n)])
    desc = rng.integers(0, 256, (n, 32), dtype=np.uint8)
    truth = _rot(4.0, -1.0)
    seen = CAM.project(pts @ truth.T)
    # Every point shows twice more, one pattern period (40 px) to either side: its neighbours in the pattern,
    # whose descriptors differ from its own by a few more bits than its own view does (8 against 4 of 256).
    def flipped(d: np.ndarray, bits: int) -> np.ndarray:
        out = np.unpackbits(d, axis=1)
        for row in out:
            row[rng.choice(256, bits, replace=False)] ^= 1
        return np.packbits(out, axis=1)

    kps = np.concatenate([seen, seen + [40.0, 0.0], seen - [40.0, 0.0]]) + rng.normal(0, 0.7, (3 * n, 2))
    kdesc = np.concatenate([flipped(desc, 4), flipped(desc, 8), flipped(desc, 8)])
    vote = vote_rotation(RotationVoteConfig(), CAM, pts, desc, kps.astype(np.float32), kdesc)
    assert vote is not None
    assert _angle_deg(vote.R_delta, truth) < 0.2
    assert vote.shift_px[0] == pytest.approx(4.0 / 180 * math.pi * 250, abs=3.0)  # ~17 px to the right
    assert vote.votes >= 0.9 * n


def test_no_vote_without_enough_agreeing_matches() -> None:
    rng = np.random.default_rng(5)
    pts = np.column_stack([rng.uniform(-1, 1, 40), rng.uniform(-1, 1, 40), rng.uniform(1.5, 3, 40)])
    desc = rng.integers(0, 256, (40, 32), dtype=np.uint8)
    # Unrelated keypoints and descriptors: the displacements spread, no bin holds min_votes matches.
    kps = rng.uniform([0, 0], [320, 240], (300, 2)).astype(np.float32)
    kdesc = rng.integers(0, 256, (300, 32), dtype=np.uint8)
    assert vote_rotation(RotationVoteConfig(max_hamming=256), CAM, pts, desc, kps, kdesc) is None
    assert vote_rotation(RotationVoteConfig(), CAM, pts[:10], desc[:10], kps, kdesc) is None


# A robot before a brick wall --------------------------------------------------------------------------------------
WALL_Z_M = 1.8
SIDE_X_M = 1.2
TILE_M = 1.2  # the brick photo covers 1.2 m x 1.2 m of wall and repeats (as `random_changing`'s walls)
BRICKS = cv2.cvtColor(load_texture("brick"), cv2.COLOR_RGB2GRAY)
PX_PER_M = BRICKS.shape[1] / TILE_M
KINECT = kinect_like()


def _render(T_world_cam: np.ndarray, index: int) -> RgbdFrame:  # noqa: N803
    """A room corner of brick: the wall z = WALL_Z_M ahead and the wall x = SIDE_X_M to the right."""
    u, v = np.meshgrid(np.arange(VGA.width, dtype=np.float64), np.arange(VGA.height, dtype=np.float64))
    rays = np.stack([(u - VGA.cx) / VGA.fx, (v - VGA.cy) / VGA.fy, np.ones_like(u)], axis=-1) @ T_world_cam[:3, :3].T
    c = T_world_cam[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        s_front = np.where(rays[..., 2] > 1e-6, (WALL_Z_M - c[2]) / rays[..., 2], np.inf)
        s_side = np.where(rays[..., 0] > 1e-6, (SIDE_X_M - c[0]) / rays[..., 0], np.inf)
    side = s_side < s_front
    s = np.where(side, s_side, s_front)
    points = c + s[..., None] * rays
    across = np.where(side, points[..., 2] + 3.0, points[..., 0] + 2.0)  # the side wall's texture runs along z
    map_x = (across * PX_PER_M).astype(np.float32)
    map_y = ((points[..., 1] + 1.5) * PX_PER_M).astype(np.float32)
    grey = cv2.remap(BRICKS, np.mod(map_x, BRICKS.shape[1]), np.mod(map_y, BRICKS.shape[0]), cv2.INTER_LINEAR)
    depth = np.einsum("hwc,c->hw", points - c, T_world_cam[:3, 2])  # along the optical axis
    rng = np.random.default_rng(index)  # a Kinect-like sensor: depth noise, holes at edges, colour noise
    rgb = KINECT.colour(np.repeat(grey[..., None], 3, axis=2), rng, index * 0.2)
    depth = KINECT.depth(depth.astype(np.float32), rgb, VGA, rng)
    return RgbdFrame(stamp_ns=index * 200_000_000, rgb=rgb, depth_m=depth, camera=VGA, index=index)


def _robot_path() -> list[np.ndarray]:
    """5 frames per second: 8 frames driving 4 cm per frame along the wall, then a turn in place at 4.5 deg per
    frame (22.5 deg/s, ~40 px of image motion) that starts between two frames, then 6 frames straight on again.
    The randomised changing family's robots change their turn rate by up to 4.5 deg per frame."""
    poses, x, yaw = [], -0.2, 0.0
    for i in range(26):
        if i < 8 or i >= 20:
            x += 0.04 * math.cos(math.radians(yaw))
        else:
            yaw += 4.5
        poses.append(make_pose(_rot(yaw, 0.0), np.array([x, 0.0, 0.0])))
    return poses


def _track(vote: bool) -> tuple[int, float, int]:
    cfg = SystemConfig()
    cfg = replace(cfg, tracking=replace(cfg.tracking, rotation_vote=replace(TrackingConfig().rotation_vote, enabled=vote)))
    system = SlamSystem(cfg)
    path = _robot_path()
    err = 0.0
    for i, T in enumerate(path):
        out = system.process(_render(T, i))
        if out.T_world_cam is not None:  # the map's frame is the first camera's
            truth = np.linalg.inv(path[0]) @ T
            err = max(err, float(np.linalg.norm(out.T_world_cam[:3, 3] - truth[:3, 3])))
    return system.n_tracked(), err, system.tracker.n_vote_aimed


def test_a_turn_that_starts_between_two_frames_keeps_its_track_before_a_brick_wall() -> None:
    n_frames = len(_robot_path())
    tracked, err, aimed = _track(vote=True)
    assert tracked == n_frames
    assert err < 0.03
    assert aimed >= 1  # the turn's first frame was tracked from the re-aimed prediction
    # Without the vote the search window cannot follow the turn's first frame: the track is lost.
    tracked_off, _, _ = _track(vote=False)
    assert tracked_off < n_frames
