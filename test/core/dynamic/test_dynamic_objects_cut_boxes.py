"""A static chair entering the image at its border must not be called dynamic (`cut_box_border_px`,
`dynamic_min_sigmas`).

While a box is cut by the image border its keypoints' centroid is the centroid of the visible part, which
slides with the border. On the PUC-like renders the EKF fed with those centroids called three chairs DYNAMIC
at their third measurement (0.74-0.88 m/s), and the object layer then skipped them where they were in full
view. Here a camera slides sideways at 0.6 m/s past a chair 2 m away: the visible part's centroid moves at
about 0.3 m/s in the world while the box is cut, twice the chair's DOC threshold (0.15 m/s).
"""

from __future__ import annotations

import numpy as np
import pytest

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.dynamic.detector import CHAIR_CLASS_ID, Detection
from changing_slam_ros.core.dynamic.dynamic_objects import DynamicObjectsConfig, DynamicObjectTracker, ObjectMotion
from changing_slam_ros.core.geometry.se3 import make_pose
from changing_slam_ros.errors import ConfigError

CAM = CameraIntrinsics(320, 240, 267.7, 269.6, 160.0, 123.8)
DT_NS = 33_333_333
WALL_M = 4.0
CAMERA_SPEED_MPS = 0.6
CHAIR_CENTRE = np.array([1.45, 0.2, 2.0])  # beyond the right border at frame 0
CHAIR_SIZE_M = (0.5, 0.7)
FRAMES = 60
CHAIR_CORNERS = CHAIR_CENTRE + np.c_[np.random.default_rng(1).uniform(-0.24, 0.24, (80, 1)),
                                     np.random.default_rng(2).uniform(-0.34, 0.34, (80, 1)), np.zeros((80, 1))]


def camera_pose(k: int) -> np.ndarray:
    """Camera-to-world: sliding along +x, looking down +z at the wall."""
    return make_pose(np.eye(3), np.array([CAMERA_SPEED_MPS * k * DT_NS * 1e-9, 0.0, 0.0]))


def frame(k: int, rng: np.random.Generator) -> tuple[np.ndarray, Detection | None, np.ndarray, bool]:
    """Depth (H, W), the chair's detection (box 10 % larger than the chair, clipped to the image, max
    exclusive like the oracle detector's; None while out of view), keypoints (N, 2): 80 fixed corners on the
    chair and 400 random ones, and whether
    the box is cut by the image border."""
    c = CHAIR_CENTRE - camera_pose(k)[:3, 3]
    w, h = CHAIR_SIZE_M
    u0, u1 = CAM.fx * (c[0] - w / 2) / c[2] + CAM.cx, CAM.fx * (c[0] + w / 2) / c[2] + CAM.cx
    v0, v1 = CAM.fy * (c[1] - h / 2) / c[2] + CAM.cy, CAM.fy * (c[1] + h / 2) / c[2] + CAM.cy
    depth = np.full((CAM.height, CAM.width), WALL_M, np.float32)
    det, cut = None, False
    if u0 < CAM.width - 4:
        depth[max(int(v0), 0): int(v1), max(int(u0), 0): min(int(u1), CAM.width)] = c[2]
        mu, mv = 0.1 * (u1 - u0), 0.1 * (v1 - v0)
        box = (max(u0 - mu, 0.0), max(v0 - mv, 0.0), min(u1 + mu, float(CAM.width)), min(v1 + mv, float(CAM.height)))
        det = Detection(box, CHAIR_CLASS_ID, 0.9)
        cut = box[2] >= CAM.width
    depth += rng.normal(0.0, 0.003, depth.shape).astype(np.float32)
    on_chair = CHAIR_CORNERS - camera_pose(k)[:3, 3]  # the chair's corners: the same points in every frame
    px = np.c_[CAM.fx * on_chair[:, 0] / on_chair[:, 2] + CAM.cx, CAM.fy * on_chair[:, 1] / on_chair[:, 2] + CAM.cy]
    px = px[(px[:, 0] >= 0) & (px[:, 0] < CAM.width - 1)]
    kps = np.vstack([px, rng.uniform([0, 0], [CAM.width - 1, CAM.height - 1], (400, 2))])  # and the wall's
    return depth, det, kps, cut


def run(config: DynamicObjectsConfig) -> list[tuple[bool, ObjectMotion]]:
    """(box cut, verdict after the frame's update) per frame with the chair in view."""
    rng = np.random.default_rng(7)
    tracker = DynamicObjectTracker(CAM, config)
    out = []
    for k in range(FRAMES):
        depth, det, kps, cut = frame(k, rng)
        res = tracker.process(k * DT_NS, kps, depth, [det] if det is not None else [], camera_pose(k))
        if det is not None:
            out.append((cut, res.objects[0].motion))
    return out


def test_a_static_chair_entering_at_the_border_is_never_dynamic_and_static_once_whole() -> None:
    verdicts = run(DynamicObjectsConfig(cut_box_border_px=1.0, dynamic_min_sigmas=1.0))
    n_cut = sum(cut for cut, _ in verdicts)
    assert n_cut >= 15 and len(verdicts) - n_cut >= 20  # a long entry, then a long full view
    assert all(m != ObjectMotion.DYNAMIC for _, m in verdicts)
    assert all(m == ObjectMotion.UNKNOWN for cut, m in verdicts if cut)  # no measurement while cut
    whole = [m for cut, m in verdicts if not cut]
    assert all(m == ObjectMotion.STATIC for m in whole[10:])


def test_measuring_cut_boxes_calls_the_entering_chair_dynamic() -> None:
    """The failure the setting avoids: with every box measured the same chair is called dynamic while it
    enters, and still is several frames after it is whole."""
    verdicts = run(DynamicObjectsConfig(cut_box_border_px=0.0, dynamic_min_sigmas=1.0))
    assert any(m == ObjectMotion.DYNAMIC for cut, m in verdicts if cut)
    whole = [m for cut, m in verdicts if not cut]
    assert whole[0] == ObjectMotion.DYNAMIC


def test_a_speed_within_a_sigma_of_the_threshold_is_no_verdict() -> None:
    """Whole views only: with `dynamic_min_sigmas` 0 the third measurement (velocity sigma near 0.8 m/s) calls
    the chair dynamic on a centimetre of centroid jitter."""
    whole = [m for cut, m in run(DynamicObjectsConfig(cut_box_border_px=1.0, dynamic_min_sigmas=0.0)) if not cut]
    assert ObjectMotion.DYNAMIC in whole[:10]
    assert whole[-1] == ObjectMotion.STATIC


def test_bad_settings_are_named() -> None:
    with pytest.raises(ConfigError, match="cut_box_border_px"):
        DynamicObjectsConfig(cut_box_border_px=-1.0)
    with pytest.raises(ConfigError, match="dynamic_min_sigmas"):
        DynamicObjectsConfig(dynamic_min_sigmas=-0.5)
