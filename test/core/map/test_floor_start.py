"""`core.map.floor_start.level_first_pose`: the first camera's pose above the floor in its depth image, on exact
synthetic depth (a camera at a known height and pitch over a floor, in front of a wall) and on views without a
floor it can trust."""

from __future__ import annotations

import numpy as np
import pytest

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.map.floor_start import level_first_pose

CAM = CameraIntrinsics(width=320, height=240, fx=262.5, fy=262.5, cx=159.5, cy=119.5)


def render_depth(height_m: float, pitch_deg: float, wall_m: float | None, floor: bool = True) -> np.ndarray:
    """Depth (240, 320) of a camera `height_m` above a floor (z = 0), looking along +x pitched `pitch_deg` down,
    with a wall at x = `wall_m` (None: no wall); readings past 8 m are 0, as a sensor's range ends."""
    p = np.radians(pitch_deg)
    fwd = np.array([np.cos(p), 0.0, -np.sin(p)])  # optical z in the world
    down = np.array([-np.sin(p), 0.0, -np.cos(p)])  # optical y (image down)
    right = np.cross(down, fwd)  # optical x
    v, u = np.mgrid[0:CAM.height, 0:CAM.width].astype(float)
    rays = ((u - CAM.cx) / CAM.fx)[..., None] * right + ((v - CAM.cy) / CAM.fy)[..., None] * down + fwd
    t = np.full(u.shape, np.inf)  # range along the ray per unit of optical depth
    if floor:
        hit = rays[..., 2] < -1e-9
        t[hit] = np.minimum(t[hit], height_m / -rays[..., 2][hit])
    if wall_m is not None:
        hit = rays[..., 0] > 1e-9
        t[hit] = np.minimum(t[hit], wall_m / rays[..., 0][hit])
    return np.where(t <= 8.0, t, 0.0).astype(np.float32)  # t is the optical depth: rays have unit z


@pytest.mark.parametrize(("height_m", "pitch_deg"), [(0.3, 0.0), (0.8, 15.0), (1.4, 30.0), (0.5, -5.0)])
def test_the_camera_height_and_pitch_come_back_from_a_floor_in_view(height_m: float, pitch_deg: float) -> None:
    start = level_first_pose(render_depth(height_m, pitch_deg, wall_m=3.0), CAM)
    assert start is not None
    assert start.height_m == pytest.approx(height_m, abs=0.005)  # the wall's foot joins the fit
    assert start.pitch_deg == pytest.approx(pitch_deg, abs=0.3)
    T = start.T_floor_cam  # noqa: N806
    assert T[:2, 3] == pytest.approx([0.0, 0.0], abs=1e-9)  # the origin lies on the floor below the camera
    assert T[1, 2] == pytest.approx(0.0, abs=1e-6) and T[0, 2] > 0.0  # x is the viewing direction on the floor
    assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0)


def test_no_floor_in_view_leaves_the_optical_frame() -> None:
    assert level_first_pose(render_depth(1.0, 0.0, wall_m=1.0, floor=False), CAM) is None  # only a wall
    assert level_first_pose(np.zeros((240, 320), np.float32), CAM) is None  # no readings


def test_a_floor_glimpsed_at_the_image_edge_is_not_trusted() -> None:
    # a camera at 1 m looking level at a wall 1.5 m off: the floor fills the few rows below the wall's foot
    depth = render_depth(1.0, 0.0, wall_m=1.5)
    assert level_first_pose(depth, CAM) is None
    assert level_first_pose(render_depth(1.0, 0.0, wall_m=4.0), CAM) is not None  # farther off, more floor


def test_a_camera_pitched_down_steeply_sees_the_floor_as_a_wall() -> None:
    assert level_first_pose(render_depth(1.0, 60.0, wall_m=None), CAM) is None  # beyond max_tilt_deg
