"""A physical bound on camera motion between accepted poses: a pose estimate that implies an impossible speed
is a wrong estimate, not a motion.

When a mover fills most of the view, or only a few matches survive, pose optimisation can lock onto the
wrong points and return a pose far from the last one, or carry the camera along with the mover. A camera
carried by a person or a robot has bounded speed and acceleration, so two checks:
- speed: the step from the last accepted pose within `max_speed_m_s` / `max_turn_deg_s` over the stamp step;
- innovation: the position within reach of a prediction from the mean velocity of the last accepted steps.
  The reach is the acceleration bound plus three times the track's own typical innovation (median of the
  recent ones), so a noisy depth sensor widens it and a clean track keeps it tight: a capture by a mover
  shows as a sudden innovation many times the usual one.
A refused pose is not written into the trajectory or the map (tracking tries again from the prediction,
then skips the frame; `core.slam.tracking`).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.se3 import invert, rotation_angle_rad
from changing_slam_ros.errors import ConfigError

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class MotionGateConfig:
    """YAML `tracking.motion_gate:`.

    - `enabled`: check every tracked pose (speed and innovation) and every relocalised one (speed, from
      the last accepted pose). Off by default: it helps where a mover fills the view on some scenes and
      costs lost frames and wrong relocalisations on others (results.md, randomised dynamic scenes).
    - `max_speed_m_s`, `max_turn_deg_s`: the fastest camera motion taken as real (a fast hand-held swing is
      ~2 m/s and ~300 deg/s).
    - `max_accel_m_s2`: the largest change of velocity; `velocity_steps`: accepted steps averaged into the
      predicting velocity. Ground truth of hand-held TUM fr1 / fr2 sequences at 30 Hz stays within 1 cm of
      such a prediction.
    - `innovation_sigmas`, `innovation_history`: the reach adds this many times the median innovation of
      the last `innovation_history` accepted frames.
    - `slack_m`, `slack_deg`: added to every bound, for pose noise and stamp jitter.
    - `max_refused_frames`: frames in a row that may be refused while tracking carries on from the last
      accepted pose; one more and tracking is lost (relocalisation).
    - `window_s`: relocalisation more than this long after the last accepted pose is not checked (the
      camera may have been carried anywhere meanwhile).
    - `relocalisation`: check a relocalised pose's speed from the last accepted pose even with the gate off: a
      relocalisation that puts the camera further from where it was than `max_speed_m_s` allows matched a
      look-alike place or a part of the map a mover had bent, and tracking on from it bends the map further.
    """

    enabled: bool = False
    max_speed_m_s: float = 3.0
    max_turn_deg_s: float = 360.0
    max_accel_m_s2: float = 20.0
    velocity_steps: int = 5
    innovation_sigmas: float = 3.0
    innovation_history: int = 30
    slack_m: float = 0.03
    slack_deg: float = 5.0
    max_refused_frames: int = 5
    window_s: float = 2.0
    relocalisation: bool = True

    def __post_init__(self) -> None:
        for name in ("max_speed_m_s", "max_turn_deg_s", "max_accel_m_s2", "innovation_sigmas", "slack_m",
                     "slack_deg", "window_s"):  # fmt: skip
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0:
                raise ConfigError(f"tracking.motion_gate.{name}: expected a finite value >= 0, got {v}")
        for name, least in (("velocity_steps", 1), ("innovation_history", 1), ("max_refused_frames", 0)):
            if int(getattr(self, name)) < least:
                raise ConfigError(f"tracking.motion_gate.{name}: expected >= {least}, got {getattr(self, name)}")


@dataclass(frozen=True)
class MotionCheck:
    """A pose against the gate: `ok`; the step from the last accepted pose; the innovation (distance from the
    predicted position, 0 without a prediction) and its reach."""

    ok: bool
    step_m: float
    turn_deg: float
    innovation_m: float = 0.0
    reach_m: float = float("inf")


def _between(T_a: F64, T_b: F64) -> tuple[float, float]:  # noqa: N803
    rel = invert(T_a) @ T_b
    return float(np.linalg.norm(rel[:3, 3])), float(np.degrees(rotation_angle_rad(rel[:3, :3])))


def check_speed(cfg: MotionGateConfig, T_world_prev: F64, T_world_now: F64, dt_s: float,  # noqa: N803
                relocalised: bool = False) -> MotionCheck:
    """Is the move from `T_world_prev` to `T_world_now` (camera-to-world, 4x4) within the speed bound over `dt_s`?
    Always yes with the gate off, except for a `relocalised` pose with `cfg.relocalisation`."""
    step, turn = _between(T_world_prev, T_world_now)
    dt = max(float(dt_s), 0.0)
    ok = step <= cfg.max_speed_m_s * dt + cfg.slack_m and turn <= cfg.max_turn_deg_s * dt + cfg.slack_deg
    return MotionCheck(ok or not (cfg.enabled or (relocalised and cfg.relocalisation)), step, turn)


class MotionGate:
    """The gate of one track: the accepted poses' recent positions and innovations (`accept`), checks of a new
    pose against them (`check`), and `reset` when the track breaks (lost, new map, time gap)."""

    def __init__(self, cfg: MotionGateConfig) -> None:
        self.cfg = cfg
        self._track: deque[tuple[int, F64]] = deque(maxlen=cfg.velocity_steps + 1)  # (stamp ns, pose)
        self._innovations: deque[float] = deque(maxlen=cfg.innovation_history)

    def reset(self) -> None:
        self._track.clear()
        self._innovations.clear()

    @property
    def last(self) -> tuple[int, F64] | None:
        return self._track[-1] if self._track else None

    def check(self, T_world_now: F64, stamp_ns: int) -> MotionCheck:  # noqa: N803
        """The speed check from the last accepted pose and, with two or more accepted poses, the innovation."""
        if not self._track:
            return MotionCheck(True, 0.0, 0.0)
        t_last, T_last = self._track[-1]
        dt = (stamp_ns - t_last) * 1e-9
        speed = check_speed(self.cfg, T_last, T_world_now, dt)
        innovation, reach = self._innovation(T_world_now, stamp_ns)
        ok = speed.ok and innovation <= reach
        return MotionCheck(ok or not self.cfg.enabled, speed.step_m, speed.turn_deg, innovation, reach)

    def accept(self, T_world: F64, stamp_ns: int) -> None:  # noqa: N803
        """An accepted pose extends the track; its innovation joins the noise estimate."""
        innovation, _ = self._innovation(T_world, stamp_ns)
        if len(self._track) >= 2:
            self._innovations.append(innovation)
        self._track.append((stamp_ns, np.array(T_world, dtype=np.float64)))

    def _innovation(self, T_world_now: F64, stamp_ns: int) -> tuple[float, float]:  # noqa: N803
        if len(self._track) < 2:
            return 0.0, float("inf")
        (t0, T0), (t1, T1) = self._track[0], self._track[-1]
        span = (t1 - t0) * 1e-9
        dt = (stamp_ns - t1) * 1e-9
        if span <= 0 or dt < 0:
            return 0.0, float("inf")
        predicted = T1[:3, 3] + (T1[:3, 3] - T0[:3, 3]) * (dt / span)
        innovation = float(np.linalg.norm(T_world_now[:3, 3] - predicted))
        typical = float(np.median(self._innovations)) if self._innovations else 0.0
        reach = self.cfg.slack_m + 0.5 * self.cfg.max_accel_m_s2 * dt * dt + self.cfg.innovation_sigmas * typical
        return innovation, reach
