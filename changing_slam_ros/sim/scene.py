"""MJCF generation: a room of textured static parts, actors on mocap bodies, lights and the camera rig.

Every part becomes a mesh with explicit texture coordinates (boxes: one quad per face, cylinders: a
side strip and two caps) so a photo maps onto each face the way we choose, tiled at a metric scale or
stretched once. Textures are passed to MuJoCo in memory (`assets`), never through temporary files.
Actors are mocap bodies, so posing them is writing `data.mocap_pos/quat`; an absent actor is parked
under the floor. The camera sits on its own mocap body; MuJoCo cameras look along -z with y up.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.se3 import rot_to_quat
from changing_slam_ros.sim.actors import Actor, Part, Shape
from changing_slam_ros.sim.textures import texture_emission, texture_png

F64 = npt.NDArray[np.float64]

PARK_POSITION_M = (0.0, 0.0, -50.0)  # where absent actors wait: under the floor, beyond the far plane
CYLINDER_SEGMENTS = 24


@dataclass(frozen=True)
class Light:
    """A spot light on the ceiling, pointing along `dir` (straight down by default); colour (r, g, b) diffuse
    intensity."""

    pos_m: tuple[float, float, float]
    diffuse: tuple[float, float, float]
    cast_shadow: bool = False
    dir: tuple[float, float, float] = (0.0, 0.0, -1.0)


@dataclass(frozen=True)
class Room:
    """Static geometry (walls, floor, shelves, posters) in world coordinates (z up), and its lights."""

    parts: tuple[Part, ...]
    lights: tuple[Light, ...]
    size_m: tuple[float, float, float]
    ambient: float | None = None  # the headlight's ambient level; None = SceneSpec's


@dataclass(frozen=True)
class SceneSpec:
    """Everything MJCF needs: room, actors, camera field of view (vertical, degrees), framebuffer size."""

    room: Room
    actors: tuple[Actor, ...]
    fovy_deg: float
    width: int
    height: int
    shadows: bool = False
    ambient: float = 0.38


@dataclass
class Mjcf:
    """The generated model text and the in-memory files it refers to."""

    xml: str
    assets: dict[str, bytes] = field(default_factory=dict)


def _fmt(values: npt.ArrayLike) -> str:
    return " ".join(f"{v:.6g}" for v in np.asarray(values, dtype=np.float64).ravel())


def box_mesh(half_size_m: tuple[float, float, float], tile_m: float | None) -> tuple[F64, F64, npt.NDArray[np.int64]]:
    """Box mesh centred at the origin: vertices (24, 3), texcoords (24, 2), faces (12, 3).

    Each face is a quad seen upright from outside (side faces: image up = +z; top/bottom: up = +y).
    """
    h = np.asarray(half_size_m, dtype=np.float64)
    verts, uvs, faces = [], [], []
    axes = np.eye(3)
    for axis in range(3):
        for sign in (1.0, -1.0):
            n = sign * axes[axis]
            up = axes[2] if axis != 2 else axes[1] * sign
            right = np.cross(up, n)
            w_m = 2 * float(np.abs(right) @ h)
            h_m = 2 * float(np.abs(up) @ h)
            su, sv = (1.0, 1.0) if tile_m is None else (w_m / tile_m, h_m / tile_m)
            base = len(verts)
            for s, t in ((0, 0), (1, 0), (1, 1), (0, 1)):
                verts.append(n * h[axis] + right * (s - 0.5) * w_m + up * (t - 0.5) * h_m)
                uvs.append((s * su, (1 - t) * sv))
            faces += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
    return np.array(verts), np.array(uvs), np.array(faces, dtype=np.int64)


def cylinder_mesh(radius_m: float, half_height_m: float, tile_m: float | None) -> tuple[F64, F64, npt.NDArray[np.int64]]:
    """Cylinder (axis z) centred at the origin: a side strip wrapped once around, and two fan caps."""
    n = CYLINDER_SEGMENTS
    circumference = 2 * np.pi * radius_m
    su, sv = (1.0, 1.0) if tile_m is None else (circumference / tile_m, 2 * half_height_m / tile_m)
    verts, uvs, faces = [], [], []
    for i in range(n + 1):  # side, with a duplicated seam column
        a = 2 * np.pi * i / n
        for t in (0, 1):
            verts.append((radius_m * np.cos(a), radius_m * np.sin(a), (t - 0.5) * 2 * half_height_m))
            uvs.append((i / n * su, (1 - t) * sv))
    for i in range(n):
        b = 2 * i
        faces += [(b, b + 2, b + 3), (b, b + 3, b + 1)]
    for z_sign in (1.0, -1.0):
        centre = len(verts)
        verts.append((0.0, 0.0, z_sign * half_height_m))
        uvs.append((0.5, 0.5))
        for i in range(n):
            a = 2 * np.pi * i / n
            verts.append((radius_m * np.cos(a), radius_m * np.sin(a), z_sign * half_height_m))
            uvs.append((0.5 + 0.5 * np.cos(a), 0.5 - 0.5 * np.sin(a)))
        for i in range(n):
            j, k = centre + 1 + i, centre + 1 + (i + 1) % n
            faces.append((centre, j, k) if z_sign > 0 else (centre, k, j))
    return np.array(verts), np.array(uvs), np.array(faces, dtype=np.int64)


ELLIPSOID_SEGMENTS = (24, 12)  # around z, pole to pole


def ellipsoid_mesh(half_size_m: tuple[float, float, float], tile_m: float | None) -> tuple[F64, F64, npt.NDArray[np.int64]]:
    """Ellipsoid with semi-axes `half_size_m` centred at the origin, as a latitude-longitude grid.

    The texture wraps once around z with its horizontal centre (u = 0.5) facing +x and its top at the
    top pole, seen upright and unmirrored from the front; with `tile_m` it repeats at that metric scale.
    """
    n_lon, n_lat = ELLIPSOID_SEGMENTS
    a, b, c = half_size_m
    su, sv = (1.0, 1.0) if tile_m is None else (np.pi * (a + b) / tile_m, np.pi * c / tile_m)
    verts, uvs, faces = [], [], []
    for j in range(n_lat + 1):  # top pole (j = 0) to bottom pole
        theta = np.pi * j / n_lat
        for i in range(n_lon + 1):  # duplicated seam column at the back (-x)
            phi = 2 * np.pi * i / n_lon - np.pi
            verts.append((a * np.sin(theta) * np.cos(phi), b * np.sin(theta) * np.sin(phi), c * np.cos(theta)))
            uvs.append((i / n_lon * su, j / n_lat * sv))
    row = n_lon + 1
    for j in range(n_lat):
        for i in range(n_lon):
            p, q = j * row + i, (j + 1) * row + i
            faces += [(p, q, q + 1), (p, q + 1, p + 1)]
    return np.array(verts), np.array(uvs), np.array(faces, dtype=np.int64)


def _mesh_xml(name: str, part: Part) -> str:
    if part.shape is Shape.CYLINDER:
        v, uv, f = cylinder_mesh(part.half_size_m[0], part.half_size_m[2], part.tile_m)
    elif part.shape is Shape.ELLIPSOID:
        v, uv, f = ellipsoid_mesh(part.half_size_m, part.tile_m)
    else:
        v, uv, f = box_mesh(part.half_size_m, part.tile_m)
    return f'<mesh name="{name}" vertex="{_fmt(v)}" texcoord="{_fmt(uv)}" face="{_fmt(f)}"/>'


def _geom_xml(mesh: str, part: Part, group: int) -> str:
    if part.yaw_rad:
        q = rot_to_quat(part.rotation())  # (x, y, z, w); MuJoCo wants (w, x, y, z)
        turn = f'quat="{_fmt([q[3], q[0], q[1], q[2]])}" '
    else:
        turn = f'euler="0 {_fmt(-part.pitch_rad)} 0" ' if part.pitch_rad else ""
    return (f'<geom name="{mesh}" type="mesh" mesh="{mesh}" material="mat_{part.texture}" '
            f'pos="{_fmt(part.offset_m)}" {turn}group="{group}" contype="0" conaffinity="0"/>')


def _emission(texture: str) -> str:
    e = texture_emission(texture)
    return f' emission="{e:.6g}"' if e > 0 else ""


def actor_body_name(index: int) -> str:
    return f"actor{index}"


CAMERA_BODY = "camera_rig"
CAMERA_NAME = "camera"


def build_mjcf(spec: SceneSpec) -> Mjcf:
    """Generate the MJCF text and its texture assets for `spec`."""
    textures = sorted({p.texture for p in spec.room.parts} | {p.texture for a in spec.actors for p in a.parts})
    assets = {f"{t}.png": texture_png(t) for t in textures}
    meshes: list[str] = []
    world_geoms: list[str] = []
    for i, part in enumerate(spec.room.parts):
        name = f"room{i}"
        meshes.append(_mesh_xml(name, part))
        world_geoms.append(_geom_xml(name, part, 0))
    bodies: list[str] = []
    for a_idx, actor in enumerate(spec.actors):
        geoms = []
        for p_idx, part in enumerate(actor.parts):
            name = f"{actor_body_name(a_idx)}_part{p_idx}"
            meshes.append(_mesh_xml(name, part))
            geoms.append(_geom_xml(name, part, 1))
        bodies.append(f'<body name="{actor_body_name(a_idx)}" mocap="true" pos="{_fmt(PARK_POSITION_M)}">'
                      + "".join(geoms) + "</body>")
    lights = [
        f'<light name="light{i}" pos="{_fmt(l.pos_m)}" dir="{_fmt(l.dir)}" directional="false" '
        f'diffuse="{_fmt(l.diffuse)}" specular="0.08 0.08 0.08" attenuation="1 0.03 0.01" cutoff="80" '
        f'exponent="2" castshadow="{"true" if (spec.shadows and l.cast_shadow) else "false"}"/>'
        for i, l in enumerate(spec.room.lights)
    ]
    tex_xml = "".join(f'<texture name="tex_{t}" type="2d" file="{t}.png"/>' for t in textures)
    mat_xml = "".join(
        f'<material name="mat_{t}" texture="tex_{t}" specular="0.12" shininess="0.25"{_emission(t)}/>'
        for t in textures
    )
    amb = spec.ambient if spec.room.ambient is None else spec.room.ambient
    xml = f"""<mujoco model="changing_slam_sim">
  <compiler angle="radian"/>
  <option><flag contact="disable" gravity="disable"/></option>
  <statistic extent="10" center="0 0 1"/>
  <visual>
    <global offwidth="{spec.width}" offheight="{spec.height}"/>
    <quality shadowsize="2048" offsamples="0"/>
    <map znear="0.002" zfar="3"/>
    <headlight ambient="{amb} {amb} {amb}" diffuse="0.18 0.18 0.18" specular="0 0 0"/>
  </visual>
  <asset>{tex_xml}{mat_xml}{''.join(meshes)}</asset>
  <worldbody>
    {''.join(lights)}
    {''.join(world_geoms)}
    {''.join(bodies)}
    <body name="{CAMERA_BODY}" mocap="true" pos="0 0 1">
      <camera name="{CAMERA_NAME}" pos="0 0 0" quat="1 0 0 0" fovy="{spec.fovy_deg:.9g}"/>
    </body>
  </worldbody>
</mujoco>
"""
    return Mjcf(xml=xml, assets=assets)
