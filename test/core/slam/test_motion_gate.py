"""The motion gate: a pose that implies an impossible camera speed, or a sudden innovation many times the
track's usual one, is refused; real hand-held motion at 30 Hz passes."""

from __future__ import annotations

import numpy as np
import pytest

from changing_slam_ros.core.slam.motion_gate import MotionGate, MotionGateConfig, check_speed
from changing_slam_ros.errors import ConfigError
from changing_slam_ros.io.tum_trajectory import read_tum_trajectory
from helpers import DATA, require

DT_NS = 33_333_333
DT = DT_NS * 1e-9


def _pose(x: float = 0.0, yaw_deg: float = 0.0) -> np.ndarray:
    T = np.eye(4)
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    T[:2, :2] = [[c, -s], [s, c]]
    T[0, 3] = x
    return T


def test_a_metre_in_a_thirtieth_of_a_second_is_refused_and_a_centimetre_passes() -> None:
    cfg = MotionGateConfig(enabled=True)
    assert check_speed(cfg, _pose(), _pose(0.01), DT).ok
    refused = check_speed(cfg, _pose(), _pose(0.9), DT)
    assert not refused.ok and refused.step_m == pytest.approx(0.9)
    assert not check_speed(cfg, _pose(), _pose(yaw_deg=30.0), DT).ok
    assert check_speed(cfg, _pose(), _pose(0.9), 1.0).ok  # the same metre over a second is a walk
    assert check_speed(MotionGateConfig(enabled=False), _pose(), _pose(5.0), DT).ok


def test_a_relocalised_pose_is_checked_with_the_gate_off_unless_told_not_to() -> None:
    off = MotionGateConfig(enabled=False)
    assert not check_speed(off, _pose(), _pose(0.6), 5 * DT, relocalised=True).ok  # 0.6 m in 0.17 s
    assert check_speed(off, _pose(), _pose(0.3), 5 * DT, relocalised=True).ok  # 1.8 m/s: a fast hand-held swing
    assert check_speed(off, _pose(), _pose(0.6), 5 * DT).ok  # a tracked pose: the gate is off
    assert check_speed(MotionGateConfig(relocalisation=False), _pose(), _pose(0.6), 5 * DT, relocalised=True).ok


def _track(gate: MotionGate, xs: list[float]) -> int:
    for i, x in enumerate(xs):
        gate.accept(_pose(x), i * DT_NS)
    return len(xs) * DT_NS


def test_a_sudden_innovation_is_refused_on_a_clean_track_and_passes_on_a_noisy_one() -> None:
    cfg = MotionGateConfig(enabled=True)
    clean = MotionGate(cfg)
    t = _track(clean, [0.01 * i for i in range(20)])  # 0.3 m/s, noiseless
    assert clean.check(_pose(0.20), t).ok
    jump = clean.check(_pose(0.27), t)  # 7 cm off the prediction: 2.4 m/s, within the speed bound
    assert jump.step_m < cfg.max_speed_m_s * DT + cfg.slack_m and not jump.ok
    assert jump.innovation_m == pytest.approx(0.07, abs=1e-6)
    # The same 7 cm on a track whose poses scatter by +-3 cm (a noisy depth sensor) is within its reach.
    noisy = MotionGate(cfg)
    t = _track(noisy, [0.01 * i + (0.03 if i % 2 else -0.03) for i in range(20)])
    assert noisy.check(_pose(0.27), t).ok
    noisy.reset()
    assert noisy.check(_pose(5.0), t).ok  # nothing to compare with after a reset


@pytest.mark.parametrize("name", ["freiburg1_xyz-groundtruth.txt", "fr2_desk_groundtruth.txt"])
def test_real_hand_held_motion_passes_at_30_hz(name: str) -> None:
    """Ground truth of TUM sequences sampled at 30 Hz through the gate: every pose passes (the track is reset
    at fr2_desk's mocap gaps, where no sample lies within 20 ms)."""
    traj = read_tum_trajectory(require(DATA / "tum_reference_trajectories" / name))
    stamps, poses = traj.stamps_s, traj.poses()
    t = np.arange(stamps[0], stamps[-1], DT)
    idx = np.searchsorted(stamps, t).clip(0, len(stamps) - 1)
    gate = MotionGate(MotionGateConfig(enabled=True))
    n = 0
    for k, i in enumerate(idx):
        if abs(stamps[i] - t[k]) > 0.02:
            gate.reset()
            continue
        stamp_ns = k * DT_NS
        assert gate.check(poses[i], stamp_ns).ok, (name, t[k])
        gate.accept(poses[i], stamp_ns)
        n += 1
    assert n > 500


def test_negative_or_infinite_bounds_are_config_errors() -> None:
    with pytest.raises(ConfigError, match="motion_gate.max_speed_m_s"):
        MotionGateConfig(max_speed_m_s=-1.0)
    with pytest.raises(ConfigError, match="motion_gate.slack_m"):
        MotionGateConfig(slack_m=float("inf"))
    with pytest.raises(ConfigError, match="motion_gate.velocity_steps"):
        MotionGateConfig(velocity_steps=0)
