"""Furniture looks: one look per seed, standing on their support at real sizes; the plain catalogue unchanged."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from changing_slam_ros.errors import SimError
from changing_slam_ros.sim import actors as cat
from changing_slam_ros.sim.actors import Actor, Part, Shape
from changing_slam_ros.sim.furniture import LOOKS, look_parts, rod
from changing_slam_ros.sim.random_changing import KIND_SUPPORT, draw_changing_room
from changing_slam_ros.sim.room import default_room
from changing_slam_ros.sim.scenarios import build_scenario
from changing_slam_ros.sim.scene import SceneSpec, build_mjcf
from changing_slam_ros.sim.textures import load_texture
from changing_slam_ros.sim.track import PoseKey, Track, pose_xyz_rpy

# (min, max) overall height in metres of each kind (a wall item: its diameter or screen height)
HEIGHT_M = {"chair": (0.75, 1.1), "couch": (0.75, 0.95), "potted_plant": (0.5, 1.4), "suitcase": (0.6, 1.3),
            "monitor": (0.35, 0.6), "bottle": (0.2, 0.36), "wall_clock": (0.24, 0.36), "wall_tv": (0.33, 0.6)}


def _box(parts: tuple[Part, ...]) -> tuple[np.ndarray, np.ndarray]:
    corners = np.concatenate([p.corners_m() for p in parts])
    return corners.min(axis=0), corners.max(axis=0)


@pytest.mark.parametrize("kind", sorted(LOOKS))
def test_a_look_is_fixed_by_its_seed_and_two_seeds_differ(kind: str) -> None:
    for style in LOOKS[kind][0]:
        a = look_parts(kind, style, np.random.default_rng(4))
        assert a == look_parts(kind, style, np.random.default_rng(4))
        assert a != look_parts(kind, style, np.random.default_rng(5))


@pytest.mark.parametrize("kind", sorted(LOOKS))
def test_every_look_stands_on_its_support_at_a_real_size(kind: str) -> None:
    lo_h, hi_h = HEIGHT_M[kind]
    for style in LOOKS[kind][0]:
        for seed in range(6):
            lo, hi = _box(look_parts(kind, style, np.random.default_rng(seed)))
            if KIND_SUPPORT[kind] == "wall":
                assert lo[0] == pytest.approx(0.0, abs=1e-6) and hi[0] < 0.08  # flat on the wall, in front of it
                assert lo_h <= hi[2] - lo[2] <= hi_h, (style, seed)
            else:
                assert -1e-6 <= lo[2] <= 0.005, (style, seed)  # on the floor or the table top, not through it
                assert lo_h <= hi[2] <= hi_h, (style, seed, hi[2])
                assert np.max(np.abs(np.r_[lo[:2], hi[:2]])) < 1.05  # footprint within a couch's half length


def test_an_unknown_style_or_kind_is_refused() -> None:
    with pytest.raises(SimError, match="unknown style 'fern'"):
        look_parts("potted_plant", "fern", np.random.default_rng(0))
    with pytest.raises(SimError, match="unknown kind 'lamp'"):
        look_parts("lamp", "plain", np.random.default_rng(0))


def test_a_rod_joins_its_two_end_points() -> None:
    a, b = (0.1, -0.2, 0.3), (0.5, 0.4, 0.9)
    p = rod(a, b, 0.02, "wood")
    axis = p.rotation() @ np.array([0.0, 0.0, p.half_size_m[2]])
    np.testing.assert_allclose(np.asarray(p.offset_m) + axis, b, atol=1e-12)
    np.testing.assert_allclose(np.asarray(p.offset_m) - axis, a, atol=1e-12)


def test_a_turned_part_is_rendered_where_its_rotation_puts_it() -> None:
    mujoco = pytest.importorskip("mujoco")
    parts = (rod((0.0, 0.0, 0.0), (0.3, -0.2, 0.5), 0.02, "wood"),
             Part((0.1, 0.1, 0.01), (0.0, 0.0, 0.0), "clock_white", None, Shape.CYLINDER, -np.pi / 2),
             Part((0.05, 0.02, 0.2), (0.1, 0.2, 0.3), "leaf_green", None, Shape.ELLIPSOID, -0.7, 2.0))
    actor = Actor("a", 0, parts, Track([PoseKey(0.0, pose_xyz_rpy(0, 0, 0))]))
    mjcf = build_mjcf(SceneSpec(default_room(), (actor,), 45.0, 64, 48))
    model = mujoco.MjModel.from_xml_string(mjcf.xml, mjcf.assets)
    for k, part in enumerate(parts):
        g = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, f"actor0_part{k}")
        m = model.geom_dataid[g]
        verts = model.mesh_vert[model.mesh_vertadr[m]:model.mesh_vertadr[m] + model.mesh_vertnum[m]]
        r = np.zeros(9)
        mujoco.mju_quat2Mat(r, model.geom_quat[g])
        in_body = verts @ r.reshape(3, 3).T + model.geom_pos[g]
        local = (in_body - np.asarray(part.offset_m)) @ part.rotation()  # back into the part's own axes
        np.testing.assert_allclose(np.abs(local).max(axis=0), part.half_size_m if part.shape is not Shape.CYLINDER
                                   else (part.half_size_m[0],) * 2 + (part.half_size_m[2],), atol=1e-4)


def test_generated_textures_are_images_and_only_screens_glow() -> None:
    leaf = load_texture("leaf_green")
    assert leaf.dtype == np.uint8 and leaf.ndim == 3 and leaf[..., 1].mean() > leaf[..., 0].mean()
    assert np.array_equal(load_texture("clock_white"), load_texture("clock_white"))
    mjcf = build_mjcf(SceneSpec(default_room(), (), 45.0, 64, 48))
    assert "emission" not in mjcf.xml  # photo textures keep their plain material


def test_the_family_draws_several_styles_of_each_kind() -> None:
    styles: dict[str, set[str]] = {}
    for seed in range(12):
        room = draw_changing_room(seed)
        for item in room.items.values():
            if item.kind != "table":
                styles.setdefault(item.kind, set()).add(item.style)
                assert item.style in LOOKS[item.kind][0]
    assert all(len(s) >= 2 for k, s in styles.items() if k in ("chair", "potted_plant", "couch")), styles


def test_the_plain_catalogue_shapes_are_unchanged() -> None:
    C = Shape.CYLINDER
    assert cat.potted_plant_parts() == (Part((0.14, 0.14, 0.15), (0.0, 0.0, 0.15), "leather", 0.2, C),
                                        Part((0.22, 0.22, 0.3), (0.0, 0.0, 0.6), "grass", 0.3, C))
    assert cat.wall_clock_parts() == (Part((0.03, 0.15, 0.15), (0.03, 0.0, 0.0), "clock", None),)
    assert cat.suitcase_parts() == (Part((0.11, 0.24, 0.33), (0.0, 0.0, 0.35), "leather", 0.25),
                                    Part((0.02, 0.07, 0.025), (0.0, 0.0, 0.705), "fabric_dark", 0.2))
    seat, back = cat.chair_parts()[-2:]
    assert seat == Part((0.22, 0.22, 0.03), (0.0, 0.0, 0.47), "leather", 0.3)
    assert back == Part((0.03, 0.22, 0.26), (-0.19, 0.0, 0.76), "leather", 0.3)


# sha256 (first 16 hex digits) of every room and actor part of the scenes built from the plain catalogue,
# recorded before the furniture looks existed: these scenes must keep rendering exactly as they did
SCENE_DIGESTS = {("static", 0): "c7cf18cf4659aa4b", ("one_chair", 0): "a9ac2ddad1c44545",
                 ("changing", 0): "c20c83a7310cdfa1", ("shift", 0): "c7cf18cf4659aa4b",
                 ("replacing", 0): "d437489b63a31f08", ("vanishing", 0): "c7cf18cf4659aa4b",
                 ("random_dynamic", 0): "d9edd8068c7bcd70", ("random_dynamic", 1): "0fc0059d6b785ea0"}


def _part_text(p: Part) -> str:
    return repr((tuple(round(v, 9) for v in p.half_size_m), tuple(round(v, 9) for v in p.offset_m), p.texture,
                 p.tile_m, p.shape.value, round(p.pitch_rad, 9), round(p.yaw_rad, 9)))


@pytest.mark.parametrize("name,seed", sorted(SCENE_DIGESTS))
def test_scenes_of_the_plain_catalogue_keep_their_parts(name: str, seed: int) -> None:
    s = build_scenario(name, seed)
    text = "\n".join([_part_text(p) for p in s.room.parts]
                     + [f"{a.name} {a.class_id} " + " ".join(_part_text(p) for p in a.parts) for a in s.actors])
    assert hashlib.sha256(text.encode()).hexdigest()[:16] == SCENE_DIGESTS[(name, seed)]
