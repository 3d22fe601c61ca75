"""core/slam/initial_pose.py with the tracker: in a room whose wall texture repeats every 2.5 m, a frame seen
from either copy looks the same; an initial pose 0.3 m / 20 deg off the truth relocalises it at the copy it
names, in a map saved and loaded again (localisation mode)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from wall_scene import S, localiser, map_wall, off_by, render, truth

from changing_slam_ros.core.geometry.se3 import make_pose, rotation_angle_rad
from changing_slam_ros.core.slam.initial_pose import HintedCandidates, PoseHint, hint_from_covariance
from changing_slam_ros.core.system import SlamSystem
from changing_slam_ros.errors import ConfigError
from changing_slam_ros.io.map_file import load_map


@pytest.fixture(scope="module")
def saved_map(tmp_path_factory: pytest.TempPathFactory):  # noqa: ANN201
    return map_wall(tmp_path_factory.mktemp("wall") / "map.npz")


@pytest.mark.parametrize("copy", [0, 1])
def test_an_initial_pose_0_3_m_and_20_deg_off_relocalises_at_the_copy_it_names(saved_map, copy) -> None:
    system = localiser(saved_map)
    T_true = truth(copy)  # noqa: N806
    hint = PoseHint(off_by(T_true, 0.3, 20.0), radius_m=0.6, angle_rad=math.radians(35.0))
    assert hint.offset(T_true) == pytest.approx((0.3, math.radians(20.0)), abs=1e-9)
    system.set_pose_hint(hint)
    out = system.process(render(T_true, 100 * S, 0))
    assert out.relocalised and out.T_world_cam is not None
    assert np.linalg.norm(out.T_world_cam[:3, 3] - T_true[:3, 3]) < 0.03
    assert math.degrees(rotation_angle_rad(out.T_world_cam[:3, :3].T @ T_true[:3, :3])) < 2.0
    assert system.tracker.pose_hint is None  # used up: the next loss searches the whole map


def test_without_a_hint_the_same_view_relocalises_at_one_copy_only(saved_map) -> None:
    """The scene is ambiguous: the same frame rendered at either copy gets the same pose without a hint."""
    poses = []
    for copy in (0, 1):
        out = localiser(saved_map).process(render(truth(copy), 100 * S, 0))
        assert out.relocalised and out.T_world_cam is not None
        poses.append(out.T_world_cam[:3, 3])
    assert np.linalg.norm(poses[0] - poses[1]) < 0.03
    assert np.linalg.norm(poses[0] - truth(0)[:3, 3]) > 2.0  # the view of copy 0 is placed at copy 1


def test_a_hint_far_from_any_keyframe_keeps_the_tracker_lost_until_it_times_out(saved_map) -> None:
    system = localiser(saved_map)
    system.set_pose_hint(PoseHint(make_pose(np.eye(3), np.array([10.0, 0.0, 0.0])), 0.5, math.radians(30.0)))
    timeout_s = system.config.tracking.initial_pose_timeout_s
    first = system.process(render(truth(0), 100 * S, 0))
    assert not first.relocalised and first.T_world_cam is None
    later = system.process(render(truth(0), 100 * S + int((timeout_s + 0.5) * S), 1))
    assert later.relocalised and system.tracker.pose_hint is None  # timed out: the whole map again


def test_hinted_candidates_put_appearance_candidates_near_the_hint_first(saved_map) -> None:
    atlas = load_map(saved_map).atlas
    m = atlas.current
    hint = PoseHint(truth(1), 0.6, math.radians(35.0))
    near = hint.keyframes_near(m)
    assert near and all(hint.admits(m.keyframes[k].T_world_cam, 2.0) for k in near)
    assert all(not hint.admits(kf.T_world_cam, 2.0) for k, kf in m.keyframes.items() if k not in near)

    class Appearance:
        def candidates(self, frame, slam_map):  # noqa: ANN001, ANN201
            return [min(slam_map.keyframes), near[-1]]  # the first keyframe (copy 0) is far from the hint

    picked = HintedCandidates(Appearance(), hint, 4).candidates(None, m)  # type: ignore[arg-type]
    assert picked[0] == near[-1] and min(m.keyframes) not in picked and len(picked) == min(4, len(near))


def test_hint_from_covariance_and_bad_hints() -> None:
    cov = np.zeros((6, 6))
    cov[0, 0] = cov[1, 1] = 0.25  # RViz's 2D pose estimate: 0.5 m in x and y, 0.26 rad in yaw
    cov[5, 5] = 0.06853891909122467
    hint = hint_from_covariance(np.eye(4), cov, min_radius_m=0.3, min_angle_rad=0.2)
    assert hint.radius_m == pytest.approx(1.5) and hint.angle_rad == pytest.approx(3 * math.sqrt(cov[5, 5]))
    tight = hint_from_covariance(np.eye(4), np.zeros(36), min_radius_m=0.3, min_angle_rad=0.2)
    assert (tight.radius_m, tight.angle_rad) == (0.3, 0.2)
    with pytest.raises(ConfigError, match="not a rotation"):
        PoseHint(np.diag([2.0, 1.0, 1.0, 1.0]), 0.5, 0.5)
    with pytest.raises(ConfigError, match="radius must be > 0"):
        PoseHint(np.eye(4), 0.0, 0.5)
    with pytest.raises(ConfigError, match="no map to relocalise in"):
        SlamSystem().set_pose_hint(PoseHint(np.eye(4), 0.5, 0.5))
