"""The occupancy grid as a Nav2 `map_server` pair: `<name>.pgm` (binary P5) and `<name>.yaml`.

`write_nav2_map` writes trinary images as `map_saver` does (occupied 0, free 254, unknown 205) with thresholds
that decode them back exactly under map_server's rule (`read_nav2_map`: occ = (255 - pixel) / 255, or
pixel / 255 with `negate`; occupied above `occupied_thresh`, free below `free_thresh`, unknown between).
The image's first row is the grid's last (top of the map), as map_server expects; `origin` is the outer corner
of the bottom-left cell, [x, y, yaw] in the grid's frame. Each file is replaced atomically, the image first,
so the yaml never names a missing or partial image.

The grid frame is the floor frame of the grid (z up, on the floor), not the SLAM map frame (the first camera's
optical frame); its pose in the map frame is kept under an extra key, `floor_pose_in_map` (x y z qx qy qz qw),
which map_server ignores.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import yaml

from changing_slam_ros.errors import MapFileError
from changing_slam_ros.io.atomic import atomic_write_bytes, atomic_write_text

OCCUPIED_PX, FREE_PX, UNKNOWN_PX = 0, 254, 205
OCCUPIED_THRESH = 0.65
FREE_THRESH = 0.1  # 205 decodes to 0.196: unknown; 254 to 0.004: free
YAML_KEYS = ("image", "mode", "resolution", "origin", "negate", "occupied_thresh", "free_thresh")


@dataclass(frozen=True)
class Nav2Map:
    """A decoded pair: `occupancy` (H, W) int8 (100, 0, -1), row 0 the bottom of the map; the yaml's values."""

    occupancy: npt.NDArray[np.int8]
    resolution_m: float
    origin_xyyaw: tuple[float, float, float]
    yaml: dict[str, Any]


def pgm_bytes(occupancy: npt.NDArray[np.integer]) -> bytes:
    """Binary PGM (P5, maxval 255) of a grid (H, W) with row 0 at the bottom: 100 -> 0, 0 -> 254, else 205."""
    occ = np.asarray(occupancy)
    img = np.full(occ.shape, UNKNOWN_PX, np.uint8)
    img[occ == 100] = OCCUPIED_PX
    img[occ == 0] = FREE_PX
    h, w = img.shape
    return f"P5\n{w} {h}\n255\n".encode("ascii") + np.ascontiguousarray(img[::-1]).tobytes()


def write_nav2_map(yaml_path: str | Path, occupancy: npt.NDArray[np.integer], resolution_m: float,
                   origin_xyyaw: tuple[float, float, float], extra: dict[str, Any] | None = None) -> tuple[Path, Path]:
    """Write `<stem>.pgm` and `yaml_path` (see the module doc); `extra` keys go into the yaml after map_server's.
    Returns (image path, yaml path)."""
    yaml_path = Path(yaml_path)
    image = yaml_path.with_suffix(".pgm")
    atomic_write_bytes(image, pgm_bytes(occupancy))
    doc: dict[str, Any] = {
        "image": image.name, "mode": "trinary", "resolution": float(resolution_m),
        "origin": [float(v) for v in origin_xyyaw], "negate": 0,
        "occupied_thresh": OCCUPIED_THRESH, "free_thresh": FREE_THRESH,
    }  # fmt: skip
    doc.update(extra or {})
    atomic_write_text(yaml_path, yaml.safe_dump(doc, sort_keys=False, default_flow_style=None))
    return image, yaml_path


def read_pgm(path: str | Path) -> npt.NDArray[np.uint8]:
    """A binary (P5) 8-bit PGM as (H, W) uint8, top row first; comments in the header are skipped."""
    data = Path(path).read_bytes()
    fields: list[bytes] = []
    pos = 0
    while len(fields) < 4:
        while pos < len(data) and data[pos : pos + 1].isspace():
            pos += 1
        if data[pos : pos + 1] == b"#":
            pos = data.index(b"\n", pos) + 1
            continue
        end = pos
        while end < len(data) and not data[end : end + 1].isspace():
            end += 1
        fields.append(data[pos:end])
        pos = end
    pos += 1  # the single whitespace byte after maxval
    if fields[0] != b"P5":
        raise MapFileError(f"{path}: not a binary PGM (magic {fields[0]!r})")
    w, h, maxval = (int(f) for f in fields[1:])
    if maxval != 255 or len(data) - pos != w * h:
        raise MapFileError(f"{path}: expected {w}x{h} bytes of maxval 255, got {len(data) - pos} (maxval {maxval})")
    return np.frombuffer(data, np.uint8, w * h, pos).reshape(h, w)


def read_nav2_map(yaml_path: str | Path) -> Nav2Map:
    """Decode a pair as `nav2_map_server` does in trinary mode (the only mode written here)."""
    yaml_path = Path(yaml_path)
    doc = yaml.safe_load(yaml_path.read_text(encoding="utf-8"))
    missing = [k for k in YAML_KEYS if k not in doc]
    if missing:
        raise MapFileError(f"{yaml_path}: missing map_server keys {missing}")
    if doc["mode"] != "trinary":
        raise MapFileError(f"{yaml_path}: mode {doc['mode']!r}, expected trinary")
    image = Path(doc["image"])
    img = read_pgm(image if image.is_absolute() else yaml_path.parent / image)
    shade = img.astype(np.float64) / 255.0
    occ_p = shade if int(doc["negate"]) else 1.0 - shade
    out = np.full(img.shape, -1, np.int8)
    out[occ_p > float(doc["occupied_thresh"])] = 100
    out[occ_p < float(doc["free_thresh"])] = 0
    x, y, yaw = (float(v) for v in doc["origin"])
    return Nav2Map(out[::-1].copy(), float(doc["resolution"]), (x, y, yaw), doc)


def write_grid(yaml_path: str | Path, grid: Any, cfg: Any) -> tuple[Path, Path]:
    """Write a `core.map.occupancy_grid.OccupancyGrid` as the pair (`cfg`: its `GridConfig`), with the floor
    frame's pose in the map frame and the floor estimate under extra keys."""
    from changing_slam_ros.core.geometry.se3 import rot_to_quat

    T = grid.T_map_floor
    q = rot_to_quat(T[:3, :3])
    extra = {
        "floor_pose_in_map": [round(float(v), 9) for v in (*T[:3, 3], *q)],
        "floor_support_points": int(grid.floor.n_support),
        "keyframes": int(grid.n_views),
    }
    return write_nav2_map(yaml_path, grid.occupancy(cfg), grid.resolution_m,
                          (float(grid.origin_xy[0]), float(grid.origin_xy[1]), 0.0), extra)
