"""A tracked pose that leaves the constant-velocity prediction by more than `motion_max_jump_m` is refused
(`Tracker._jumped`), as the motion gate refuses one: on a repeated wall pattern the few matches left at the start
of a turn can agree on a shifted copy of the wall, 0.4-1.2 m off."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from changing_slam_ros.core.features.orb_features import FeatureConfig
from changing_slam_ros.core.geometry.se3 import make_pose
from changing_slam_ros.core.map.slam_map import Atlas
from changing_slam_ros.core.slam.tracking import Tracker
from changing_slam_ros.core.slam.tracking_config import TrackingConfig
from changing_slam_ros.errors import ConfigError

PREDICTED = make_pose(np.eye(3), np.array([1.0, 0.0, 2.0]))


def _frame(offset_m: float) -> SimpleNamespace:
    return SimpleNamespace(T_world_cam=make_pose(np.eye(3), PREDICTED[:3, 3] + [offset_m, 0.0, 0.0]))


def _tracker(cfg: TrackingConfig, predicted: bool) -> Tracker:
    tracker = Tracker(Atlas(), FeatureConfig(), cfg)
    tracker._T_wc_pred, tracker._predicted = PREDICTED, predicted
    return tracker


def test_a_pose_far_from_the_prediction_is_refused_and_counted() -> None:
    tracker = _tracker(TrackingConfig(motion_max_jump_m=0.15), predicted=True)
    assert not tracker._jumped(_frame(0.1))  # an acceleration the prediction missed
    assert tracker._jumped(_frame(0.6))  # a wall tile away
    assert tracker.n_jumps_refused == 1
    # without a velocity the prediction is only the last pose: no verdict
    assert not _tracker(TrackingConfig(motion_max_jump_m=0.15), predicted=False)._jumped(_frame(0.6))


def test_the_check_is_off_by_default_and_refuses_a_negative_bound() -> None:
    assert not _tracker(TrackingConfig(), predicted=True)._jumped(_frame(5.0))
    with pytest.raises(ConfigError, match="motion_max_jump_m"):
        TrackingConfig(motion_max_jump_m=-0.1)
