"""A room for relocalisation tests: one wall whose texture repeats every 2.5 m along x, rendered (colour and depth)
from any camera pose, and a map of it (`map_wall`: a camera sliding 3.2 m along it, past both copies)."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from changing_slam_ros.core.features.rgbd_frame import RgbdFrame
from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.geometry.se3 import make_pose
from changing_slam_ros.core.slam.localization import Mode
from changing_slam_ros.core.system import SlamSystem
from changing_slam_ros.io.map_file import load_map, save_map

CAM = CameraIntrinsics(width=320, height=240, fx=250.0, fy=250.0, cx=159.5, cy=119.5)
WALL_Z_M = 1.6  # the wall: the plane z = 1.6 m of the world (the first camera looks along +z at it)
PERIOD_M = 2.5  # its texture repeats along x with this period
PX_PER_M = 160.0
S = 1_000_000_000


def wall_texture(seed: int = 3) -> np.ndarray:
    """One period of the wall (2.5 m x 3 m) as a grey image: blobs at several scales and random rectangles."""
    rng = np.random.default_rng(seed)
    w, h = int(PERIOD_M * PX_PER_M), int(3.0 * PX_PER_M)
    img = np.zeros((h, w), np.float32)
    for cells in (6, 14, 32, 70):
        noise = rng.random((max(2, cells * h // w), cells)).astype(np.float32)
        img += cv2.resize(noise, (w, h), interpolation=cv2.INTER_CUBIC) / cells ** 0.3
    img = (img - img.min()) / (img.max() - img.min()) * 160 + 40
    for _ in range(120):
        x, y = int(rng.integers(0, w - 20)), int(rng.integers(0, h - 20))
        cv2.rectangle(img, (x, y), (x + int(rng.integers(6, 20)), y + int(rng.integers(6, 20))),
                      float(rng.integers(0, 255)), -1)  # fmt: skip
    return img.astype(np.uint8)


TEXTURE = wall_texture()


def rot_y(deg: float) -> np.ndarray:
    a = math.radians(deg)
    return np.array([[math.cos(a), 0.0, math.sin(a)], [0.0, 1.0, 0.0], [-math.sin(a), 0.0, math.cos(a)]])


def render(T_world_cam: np.ndarray, stamp_ns: int, index: int) -> RgbdFrame:  # noqa: N803
    """The wall seen from `T_world_cam`: colour from the periodic texture, depth along the optical axis."""
    u, v = np.meshgrid(np.arange(CAM.width, dtype=np.float64), np.arange(CAM.height, dtype=np.float64))
    rays = np.stack([(u - CAM.cx) / CAM.fx, (v - CAM.cy) / CAM.fy, np.ones_like(u)], axis=-1)
    rays_w = rays @ T_world_cam[:3, :3].T
    s = (WALL_Z_M - T_world_cam[2, 3]) / rays_w[..., 2]
    points = T_world_cam[:3, 3] + s[..., None] * rays_w
    map_x = (np.mod(points[..., 0], PERIOD_M) * PX_PER_M).astype(np.float32)
    map_y = ((points[..., 1] + 1.5) * PX_PER_M).astype(np.float32)
    grey = cv2.remap(TEXTURE, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
    return RgbdFrame(stamp_ns=stamp_ns, rgb=np.repeat(grey[..., None], 3, axis=2), depth_m=s.astype(np.float32),
                     camera=CAM, index=index)  # fmt: skip


def map_wall(path: Path) -> Path:
    """The wall mapped by a camera sliding 3.2 m along it (both copies of the texture), saved to `path`."""
    system = SlamSystem()
    xs = np.arange(0.0, 3.2 + 1e-9, 0.05)
    for i, x in enumerate(xs):
        system.process(render(make_pose(np.eye(3), np.array([x, 0.0, 0.0])), i * S // 10, i))
    assert system.n_tracked() == len(xs) and len(system.atlas.maps) == 1
    save_map(path, system.atlas, None, system.tracker.next_kf_id)
    return path


def localiser(path) -> SlamSystem:  # noqa: ANN001
    loaded = load_map(path)
    system = SlamSystem()
    system.start_from_map(loaded.atlas, loaded.next_keyframe_id, loaded.objects, Mode.LOCALIZATION)
    return system


def truth(copy: int) -> np.ndarray:
    """The query camera: 6 deg turned, 5 cm down and 10 cm closer, at x = 0.4 m in copy 0 or 1 of the texture."""
    return make_pose(rot_y(6.0), np.array([0.4 + copy * PERIOD_M, 0.05, 0.1]))


def off_by(T: np.ndarray, metres: float, degrees: float) -> np.ndarray:  # noqa: N803
    """`T` moved by `metres` (along x and z equally) and turned by `degrees` about y."""
    step = metres / math.sqrt(2.0)
    return make_pose(T[:3, :3] @ rot_y(degrees), T[:3, 3] + np.array([step, 0.0, -step]))


