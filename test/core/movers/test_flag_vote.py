"""The vote that carries the segmentation's flags to the keypoints it did not test."""

from __future__ import annotations

import numpy as np
import pytest

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.movers.flag_vote import FlagVoteConfig, vote_flags
from changing_slam_ros.errors import ConfigError

CAM = CameraIntrinsics(320, 240, 262.0, 262.0, 160.0, 120.0)
ON = FlagVoteConfig(radius_m=0.25)


def _scene(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Keypoints (pixels, depths) of a wall 3 m away, a floor and a person-sized box 1.5 m away standing on it.
    Returns pixels (N, 2), depths (N,), the box's keypoints (N,) bool."""
    wall = np.column_stack([rng.uniform(-1.5, 1.5, 300), rng.uniform(-1.0, 0.6, 300), np.full(300, 3.0)])
    floor = np.column_stack([rng.uniform(-1.0, 1.0, 200), np.full(200, 0.9), rng.uniform(1.0, 2.9, 200)])
    box = np.column_stack([rng.uniform(-0.2, 0.2, 200), rng.uniform(-0.8, 0.9, 200), rng.uniform(1.45, 1.6, 200)])
    pts = np.vstack([wall, floor, box])
    pixels = np.column_stack([CAM.fx * pts[:, 0] / pts[:, 2] + CAM.cx, CAM.fy * pts[:, 1] / pts[:, 2] + CAM.cy])
    on_box = np.zeros(len(pts), dtype=bool)
    on_box[500:] = True
    return pixels, pts[:, 2].copy(), on_box


def test_untested_keypoints_of_a_mover_follow_their_tested_neighbours() -> None:
    rng = np.random.default_rng(3)
    pixels, depths, on_box = _scene(rng)
    tested = rng.random(len(depths)) < 0.5  # the segmentation matched about half of every surface
    moving = tested & on_box & (rng.random(len(depths)) < 0.8)  # and missed a fifth of the box's tested ones
    moving |= tested & ~on_box & (rng.random(len(depths)) < 0.05)  # with a few false alarms elsewhere
    voted = vote_flags(moving, tested, pixels, depths, CAM, ON)
    untested_box = on_box & ~tested
    assert voted[untested_box].mean() > 0.95
    assert not voted[tested].any()  # a tested keypoint keeps its own verdict
    assert not voted[:300].any()  # the wall 1.4 m behind, with its few false alarms, stays
    # the floor stays but where the box stands on it: a few keypoints within the radius of its base
    pts = CAM.backproject(pixels, depths)
    to_box = np.min(np.linalg.norm(pts[300:500, None] - pts[None, on_box], axis=2), axis=1)
    floor_voted = voted[300:500]
    assert floor_voted.sum() <= 0.1 * np.count_nonzero(~tested[300:500])
    assert np.all(to_box[floor_voted] < ON.radius_m)


def test_no_vote_without_depth_or_enough_voters() -> None:
    rng = np.random.default_rng(4)
    pixels, depths, on_box = _scene(rng)
    tested = on_box & (np.arange(len(depths)) % 2 == 0)
    moving = tested.copy()
    depths[~tested & on_box] = 0.0  # the untested box keypoints have no depth
    assert not vote_flags(moving, tested, pixels, depths, CAM, ON)[on_box].any()
    _, depths, _ = _scene(np.random.default_rng(4))
    two = np.zeros(len(depths), dtype=bool)
    two[500:502] = True  # two flagged voters: fewer than min_votes (3)
    assert not vote_flags(two, two, pixels, depths, CAM, ON).any()
    assert vote_flags(two, two, pixels, depths, CAM, FlagVoteConfig(radius_m=2.0, min_votes=2)).any()


def test_off_by_default_and_checked() -> None:
    rng = np.random.default_rng(5)
    pixels, depths, on_box = _scene(rng)
    assert not vote_flags(on_box, on_box, pixels, depths, CAM, FlagVoteConfig()).any()
    with pytest.raises(ConfigError, match="radius_m"):
        FlagVoteConfig(radius_m=-1.0)
    with pytest.raises(ConfigError, match="min_votes"):
        FlagVoteConfig(neighbours=4, min_votes=5)
    with pytest.raises(ConfigError, match="moving_fraction"):
        FlagVoteConfig(moving_fraction=0.0)
