"""The renderer's geometry: exact intrinsics (markers land where the pinhole model says) and metric depth."""

from __future__ import annotations

import numpy as np
import pytest

from changing_slam_ros.sim.actors import Actor, Part, Shape
from changing_slam_ros.sim.camera_path import look_at
from changing_slam_ros.sim.renderer import SimRenderer, fovy_for_focal, intrinsics_for
from changing_slam_ros.sim.scene import Light, Room, SceneSpec
from changing_slam_ros.sim.track import Track, pose_xyz_rpy

W, H = 320, 240


def _wall_room(distance_m: float) -> Room:
    """One big textured wall facing the camera at y = distance_m, camera at the origin looking +y."""
    wall = Part((20.0, 0.05, 20.0), (0.0, distance_m + 0.05, 0.0), "brick", 1.0)
    return Room((wall,), (Light((0.0, 0.0, 3.0), (0.6, 0.6, 0.6)),), (10.0, 10.0, 10.0))


def _camera_at_origin_looking_y() -> np.ndarray:
    return look_at(np.zeros(3), np.array([0.0, 1.0, 0.0]))


def test_intrinsics_follow_mujoco_fovy_with_centre_at_half_pixel() -> None:
    cam = intrinsics_for(640, 480, fovy_for_focal(480, 525.0))
    assert cam.fx == pytest.approx(525.0, abs=1e-9)
    assert cam.fy == pytest.approx(525.0, abs=1e-9)
    assert (cam.cx, cam.cy) == (319.5, 239.5)


def test_discs_are_drawn_where_the_pinhole_model_projects_their_centres() -> None:
    """Thin discs parallel to the image plane (their images are discs centred on the projection of their
    centres): the centroid of each one's mask pixels is within 0.1 px of the pinhole projection, near the
    image centre and near its corners, which pins fx, fy, cx and cy."""
    T_world_cam = _camera_at_origin_looking_y()
    centres_cam = np.array([[0.0, 0.0, 2.0], [-1.15, -0.75, 2.0], [1.2, 0.8, 2.1], [1.0, -0.7, 1.8],
                            [-0.95, 0.65, 1.7], [0.35, 0.1, 1.6]])
    actors = []
    for i, c in enumerate(centres_cam):
        world = T_world_cam[:3, :3] @ c + T_world_cam[:3, 3]
        disc = Part((0.14, 0.14, 0.001), (0.0, 0.0, 0.0), "moon", None, Shape.CYLINDER)
        # the disc's axis (its z) along the optical axis (world +y)
        actors.append(Actor(f"m{i}", -1, (disc,), Track.static(pose_xyz_rpy(*world, roll=np.pi / 2))))
    spec = SceneSpec(_wall_room(4.0), tuple(actors), fovy_for_focal(H, 200.0), W, H)
    with SimRenderer(spec) as r:
        frame = r.render(T_world_cam, [a.track.pose_at(0.0) for a in actors])
        cam = r.camera
    expected = cam.project(centres_cam)
    errors, errors_wrong_centre = [], []
    for i in range(len(actors)):
        rows, cols = np.nonzero(frame.instance_ids == i + 1)
        assert rows.size > 300, f"disc {i} not drawn"
        centroid = np.array([cols.mean(), rows.mean()])
        errors.append(np.linalg.norm(centroid - expected[i]))
        errors_wrong_centre.append(np.linalg.norm(centroid - (expected[i] + 0.5)))
    assert max(errors) < 0.1
    assert min(errors_wrong_centre) > 0.6  # a cx = W/2, cy = H/2 convention would be caught


def test_depth_is_metric_distance_along_the_optical_axis() -> None:
    """A wall parallel to the image plane at 2.5 m reads 2.5 m in every pixel, not the ray length."""
    spec = SceneSpec(_wall_room(2.5), (), fovy_for_focal(H, 200.0), W, H)
    with SimRenderer(spec) as r:
        frame = r.render(_camera_at_origin_looking_y(), [])
    assert frame.depth_m.dtype == np.float32
    assert np.abs(frame.depth_m - 2.5).max() < 2e-4
    assert (frame.instance_ids == 0).all()


def test_backprojected_depth_of_a_tilted_wall_lies_on_the_wall_plane() -> None:
    """Camera yawed 30 degrees and rolled 10: every back-projected pixel lies on the plane y = 3 m."""
    spec = SceneSpec(_wall_room(3.0), (), fovy_for_focal(H, 250.0), W, H)
    T_world_cam = look_at(np.zeros(3), np.array([np.sin(0.5), np.cos(0.5), 0.1]), roll_rad=np.radians(10))
    with SimRenderer(spec) as r:
        frame = r.render(T_world_cam, [])
        cam = r.camera
    v, u = np.mgrid[0:H, 0:W]
    pts_cam = cam.backproject(np.c_[u.ravel(), v.ravel()].astype(float), frame.depth_m.ravel().astype(float))
    pts_world = pts_cam @ T_world_cam[:3, :3].T + T_world_cam[:3, 3]
    assert (frame.depth_m > 0).all()
    assert np.abs(pts_world[:, 1] - 3.0).max() < 1e-4
    # the same with the principal point half a pixel off misses the plane by millimetres
    off = cam.backproject(np.c_[u.ravel() + 0.5, v.ravel() + 0.5].astype(float), frame.depth_m.ravel().astype(float))
    off_world = off @ T_world_cam[:3, :3].T + T_world_cam[:3, 3]
    assert np.abs(off_world[:, 1] - 3.0).max() > 2e-3


def test_absent_actor_is_not_drawn_and_rendering_is_repeatable() -> None:
    part = Part((0.2, 0.2, 0.2), (0.0, 0.0, 0.0), "coffee")
    actor = Actor("box", 41, (part,), Track.static(pose_xyz_rpy(0.0, 2.0, 0.0)))
    spec = SceneSpec(_wall_room(4.0), (actor,), fovy_for_focal(H, 200.0), W, H)
    T = _camera_at_origin_looking_y()
    with SimRenderer(spec) as r:
        a = r.render(T, [actor.track.pose_at(0.0)])
        b = r.render(T, [None])
        c = r.render(T, [actor.track.pose_at(0.0)])
    assert (a.instance_ids == 1).sum() > 1000
    assert (b.instance_ids == 1).sum() == 0
    assert np.array_equal(a.rgb, c.rgb) and np.array_equal(a.depth_m, c.depth_m)
    # the box's front face is 0.2 m nearer than its centre (2.0 m): 1.8 m
    assert np.median(a.depth_m[a.instance_ids == 1]) == pytest.approx(1.8, abs=1e-3)
