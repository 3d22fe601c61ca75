"""The slow_mover scenario (a box pushed at 3 cm/s: the local-mapping segmentation's case) and its control."""

from __future__ import annotations

import numpy as np

from changing_slam_ros.core.geometry.se3 import invert
from changing_slam_ros.sim.scenarios import SLOW_MOVER_SPEED_M_S, build_scenario


def _positions(s, ts: np.ndarray) -> np.ndarray:  # type: ignore[no-untyped-def]
    box = s.actors[s.actor_index("parcel")]
    return np.array([box.track.pose_at(float(t))[:3, 3] for t in ts])


def test_slow_mover_pushes_a_box_of_no_class_at_a_few_cm_per_second() -> None:
    s = build_scenario("slow_mover", 0)
    box = s.actors[s.actor_index("parcel")]
    assert box.class_id == -1 and box.moving
    dt = 3 / s.fps  # the tracking-side two-frame mode compares frames 3 apart
    ts = np.arange(0.0, s.duration_s - dt, dt)
    step = np.linalg.norm(np.diff(_positions(s, np.append(ts, ts[-1] + dt)), axis=0), axis=1)
    assert step[ts < 4.0 - dt].max() < 1e-9 and step[ts > 20.0].max() < 1e-9  # at rest before and after
    pushed = (ts > 4.0) & (ts < 20.0 - dt)
    np.testing.assert_allclose(step[pushed], SLOW_MOVER_SPEED_M_S * dt, rtol=0.02)  # 3 mm per 0.1 s
    assert 0.4 < np.linalg.norm(_positions(s, np.array([20.0]))[0] - _positions(s, np.array([4.0]))[0]) < 0.55
    cam = [invert(s.camera.pose_at(float(t))) for t in ts]
    depth = [(c[:3, :3] @ p + c[:3, 3])[2] for c, p in zip(cam, _positions(s, ts))]
    assert 1.0 < min(depth) and max(depth) < 2.5  # in front of the camera throughout


def test_slow_mover_control_keeps_the_box_still_on_the_same_camera_path() -> None:
    s, c = build_scenario("slow_mover", 0), build_scenario("slow_mover_control", 0)
    assert [a.name for a in s.actors] == [a.name for a in c.actors] and not c.actors[c.actor_index("parcel")].moving
    for t in np.arange(0.0, s.duration_s, 0.5):
        assert np.array_equal(s.camera.pose_at(t), c.camera.pose_at(t))
        np.testing.assert_array_equal(_positions(c, np.array([t])), _positions(s, np.array([0.0])))
