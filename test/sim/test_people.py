"""The simulated people: ellipsoid meshes, limbs swung about their joints, and a rendered person whose
silhouette and face are where the body plan puts them."""

from __future__ import annotations

import numpy as np

from changing_slam_ros.sim.actors import Actor, Part, limb, person_parts, sitting_person_parts
from changing_slam_ros.sim.camera_path import look_at
from changing_slam_ros.sim.renderer import SimRenderer, fovy_for_focal
from changing_slam_ros.sim.scene import Light, Room, SceneSpec, ellipsoid_mesh
from changing_slam_ros.sim.track import Track, pose_xyz_rpy


def test_ellipsoid_mesh_lies_on_the_ellipsoid_and_faces_outwards() -> None:
    v, uv, f = ellipsoid_mesh((0.1, 0.2, 0.3), None)
    assert np.allclose(((v / [0.1, 0.2, 0.3]) ** 2).sum(axis=1), 1.0)
    tri = v[f]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    big = np.linalg.norm(normals, axis=1) > 1e-9  # the pole rows have degenerate triangles
    assert (np.einsum("ij,ij->i", normals[big], tri[big].mean(axis=1)) > 0).all()
    front = np.argmax(v[:, 0])  # the texture's horizontal centre faces +x
    assert abs(uv[front, 0] - 0.5) < 1e-9


def test_a_limb_hangs_from_its_joint_and_swings_its_bottom_forward() -> None:
    leg = limb((0.0, 0.1, 0.9), 0.8, 0.06, "denim", 0.25, pitch_rad=0.3)
    axis_bottom = np.asarray(leg.offset_m) + leg.rotation() @ np.array([0.0, 0.0, -0.4])
    axis_top = np.asarray(leg.offset_m) + leg.rotation() @ np.array([0.0, 0.0, 0.4])
    assert np.allclose(axis_top, (0.0, 0.1, 0.9))
    assert np.allclose(axis_bottom, (0.8 * np.sin(0.3), 0.1, 0.9 - 0.8 * np.cos(0.3)))


def test_people_stand_on_the_floor_at_human_size() -> None:
    for parts, height in ((person_parts("astronaut"), 1.76), (sitting_person_parts("cameraman"), 1.41)):
        actor = Actor("p", 0, parts, Track.static(np.eye(4)))
        lo, hi = actor.box_m()
        assert abs(lo[2]) < 1e-9
        assert abs(hi[2] - height) < 0.03
        assert 0.5 < hi[1] - lo[1] < 0.7  # shoulder to shoulder with the arms


def test_rendered_person_shows_a_face_above_a_body_with_two_legs() -> None:
    """A standing person 2.5 m in front of the camera, facing it: the mask is taller than wide, the head
    is skin-coloured in the middle (the face photo), and at knee height the mask has two legs."""
    W, H = 160, 240
    room = Room((Part((20.0, 0.05, 20.0), (0.0, 6.0, 0.0), "brick", 1.0),), (Light((0.0, 1.0, 3.0), (0.7, 0.7, 0.7)),),
                (10.0, 10.0, 10.0))
    person = Actor("p", 0, person_parts("astronaut", stride_rad=0.0),
                   Track.static(pose_xyz_rpy(0.0, 2.5, 0.0, yaw=-np.pi / 2)))  # facing -y, the camera
    spec = SceneSpec(room, (person,), fovy_for_focal(H, 200.0), W, H)
    T_world_cam = look_at(np.array([0.0, 0.0, 0.9]), np.array([0.0, 1.0, 0.9]))
    with SimRenderer(spec) as r:
        frame = r.render(T_world_cam, [person.track.pose_at(0.0)])
        cam = r.camera
    mask = frame.instance_ids == 1
    rows, cols = np.nonzero(mask)
    assert rows.max() - rows.min() > 2 * (cols.max() - cols.min())

    def px(x: float, z: float) -> tuple[int, int]:  # world point on the person's plane (y = 2.4) -> (u, v)
        uv = cam.project(np.array([[x, -(z - 0.9), 2.4]]))[0]
        return int(round(uv[0])), int(round(uv[1]))

    u, v = px(0.0, 1.62)
    face = frame.rgb[v - 2:v + 3, u - 2:u + 3].reshape(-1, 3).astype(float).mean(axis=0)
    assert mask[v, u] and face[0] > face[2] + 20  # skin: red over blue
    _, v_knee = px(0.0, 0.45)
    runs = np.flatnonzero(np.diff(mask[v_knee].astype(int)) == 1)
    assert len(runs) == 2  # two legs, a gap between them
