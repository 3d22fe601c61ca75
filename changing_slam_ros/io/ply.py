"""Map points as a PLY point cloud (binary little endian), as CloudCompare, Open3D and MeshLab read it.

`map_point_cloud` selects the points of one map of an Atlas (not culled; active ones unless asked otherwise)
with their per-point labels; `write_ply` writes any such columns, atomically (a failure leaves an existing file
as it was). Each vertex has `x y z` (float, metres, in the map's frame) and the extra properties given.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.map.slam_map import Atlas
from changing_slam_ros.errors import MapFileError
from changing_slam_ros.io.atomic import atomic_write_bytes

# numpy dtype -> PLY type name
_PLY_TYPES = {np.dtype("<f4"): "float", np.dtype("<f8"): "double", np.dtype("<i4"): "int",
              np.dtype("<u4"): "uint", np.dtype("<i2"): "short", np.dtype("<u2"): "ushort",
              np.dtype("u1"): "uchar", np.dtype("i1"): "char"}  # fmt: skip


@dataclass
class PointCloud:
    """Points (N, 3) and named per-point columns (N,) each."""

    xyz: npt.NDArray[np.float64]
    columns: dict[str, npt.NDArray[np.generic]]

    def __len__(self) -> int:
        return len(self.xyz)


def map_point_cloud(atlas: Atlas, map_id: int | None = None, inactive: bool = False) -> PointCloud:
    """The points of map `map_id` (None: the current map) that are not culled, and only the active ones unless
    `inactive`: position, `active` (0/1), `observations` (keyframes seeing it), `class_id`, `object_id` (-1: none)."""
    maps = {m.id: m for m in atlas.maps}
    if map_id is None:
        map_id = atlas.current.id
    if map_id not in maps:
        raise MapFileError(f"no map {map_id} in the file (maps: {', '.join(str(i) for i in sorted(maps))})")
    points = maps[map_id].points
    keep = ~points.bad[: points.size] & (True if inactive else points.active[: points.size])
    ids = np.flatnonzero(keep)
    return PointCloud(points.positions[ids].astype(np.float64), {
        "active": points.active[ids].astype("u1"),
        "observations": points.n_obs(ids).astype("<u4"),
        "class_id": points.class_id[ids].astype("<i4"),
        "object_id": points.object_id[ids].astype("<i4"),
    })  # fmt: skip


def write_ply(path: str | Path, cloud: PointCloud, comment: str = "") -> None:
    """`cloud` as a binary little-endian PLY file at `path`, written atomically."""
    fields = [("x", np.dtype("<f4")), ("y", np.dtype("<f4")), ("z", np.dtype("<f4"))]
    fields += [(name, np.asarray(col).dtype.newbyteorder("<")) for name, col in cloud.columns.items()]
    for name, dtype in fields:
        if dtype not in _PLY_TYPES:
            raise ValueError(f"PLY property {name}: no PLY type for {dtype}")
    rows = np.zeros(len(cloud), dtype=fields)
    xyz = np.asarray(cloud.xyz, dtype=np.float64).reshape(-1, 3)
    rows["x"], rows["y"], rows["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    for name, col in cloud.columns.items():
        rows[name] = col
    header = ["ply", "format binary_little_endian 1.0"]
    header += [f"comment {line}" for line in comment.splitlines() if line]
    header += [f"element vertex {len(cloud)}"]
    header += [f"property {_PLY_TYPES[dtype]} {name}" for name, dtype in fields]
    header += ["end_header"]
    atomic_write_bytes(path, ("\n".join(header) + "\n").encode("ascii") + rows.tobytes())
