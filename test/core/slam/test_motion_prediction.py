"""The constant-velocity prediction scaled by the stamp step (frames dropped in real time, gaps in a recording)."""

from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from changing_slam_ros.core.features.orb_features import FeatureConfig
from changing_slam_ros.core.geometry.se3 import make_pose, scale_motion
from changing_slam_ros.core.map.slam_map import Atlas
from changing_slam_ros.core.slam.tracking import Tracker
from changing_slam_ros.core.slam.tracking_config import TrackingConfig

PERIOD_NS = 33_333_333  # 30 Hz


def _motion(deg: float, t: tuple[float, float, float]) -> np.ndarray:
    r, _ = cv2.Rodrigues(np.deg2rad(deg) * np.array([0.2, 1.0, 0.1]) / np.linalg.norm([0.2, 1.0, 0.1]))
    return make_pose(r, np.array(t))


def test_scale_motion_multiplies_angle_and_translation() -> None:
    m = _motion(3.0, (0.01, -0.002, 0.004))
    np.testing.assert_allclose(scale_motion(m, 1.0), m, atol=1e-12)
    np.testing.assert_allclose(scale_motion(m, 0.0), np.eye(4), atol=1e-12)
    three = scale_motion(m, 3.0)
    rvec, _ = cv2.Rodrigues(three[:3, :3])
    assert np.rad2deg(np.linalg.norm(rvec)) == pytest.approx(9.0, abs=1e-9)
    np.testing.assert_allclose(three, m @ m @ m, atol=1e-12)  # the same screw motion, three times
    np.testing.assert_allclose(scale_motion(scale_motion(m, 0.5), 2.0), m, atol=1e-12)
    tiny = make_pose(np.eye(3), np.array([0.01, 0.0, -0.02]))  # no rotation: translation scales
    np.testing.assert_allclose(scale_motion(tiny, 2.5)[:3, 3], [0.025, 0.0, -0.05], atol=1e-12)


def _tracker(tol: float, velocity: np.ndarray, last_stamp_ns: int) -> Tracker:
    tracker = Tracker(Atlas(), FeatureConfig(), TrackingConfig(velocity_rescale_tolerance=tol))
    tracker.velocity = velocity
    tracker.velocity_dt_s = PERIOD_NS * 1e-9
    tracker.last_frame = SimpleNamespace(stamp_ns=last_stamp_ns)  # type: ignore[assignment]
    return tracker


def test_prediction_covers_the_dropped_frames() -> None:
    v = _motion(3.0, (0.01, 0.0, 0.005))  # a 90 deg/s pan at 30 Hz
    t0 = 10**12
    tracker = _tracker(0.25, v, t0)
    two_later = tracker._motion(SimpleNamespace(stamp_ns=t0 + 3 * PERIOD_NS))  # type: ignore[arg-type]
    np.testing.assert_allclose(two_later, scale_motion(v, 3.0), atol=1e-6)  # two frames dropped: three periods
    # An ordinary step (stamp jitter inside the tolerance) uses the last motion as is, bit for bit (ORB-SLAM)
    assert tracker._motion(SimpleNamespace(stamp_ns=t0 + int(1.2 * PERIOD_NS))) is v  # type: ignore[arg-type]
    # A negative tolerance never scales
    off = _tracker(-1.0, v, t0)
    assert off._motion(SimpleNamespace(stamp_ns=t0 + 3 * PERIOD_NS)) is v  # type: ignore[arg-type]
