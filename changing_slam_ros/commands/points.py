"""`changing-slam points MAP OUT.ply`: the map points of a saved map as a PLY point cloud.

    changing-slam points RUN/map.npz OUT.ply [--map-id N] [--inactive]

MAP is a map file of `changing-slam run` or the graph (`map.npz`). The points of one map of its Atlas (the
current one unless `--map-id`), in that map's frame, go to OUT.ply (binary little endian, `io.ply`) with per-point
`active`, `observations`, `class_id` and `object_id`, for CloudCompare, Open3D or MeshLab. Culled points are left
out; inactive ones (on objects that left the room) too unless `--inactive`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from changing_slam_ros.errors import ConfigError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("map", metavar="MAP", help="map file (map.npz) of `changing-slam run` or the graph")
    parser.add_argument("out", metavar="OUT.ply", help="PLY file to write (replaced atomically)")
    parser.add_argument("--map-id", type=int, default=None, help="map of the Atlas to export (default: current)")
    parser.add_argument("--inactive", action="store_true",
                        help="also the inactive points (objects that left; `active` 0 in the file)")  # fmt: skip


def main(args: argparse.Namespace) -> int:
    from changing_slam_ros.io.map_file import load_map
    from changing_slam_ros.io.output_dir import check_output_file
    from changing_slam_ros.io.ply import map_point_cloud, write_ply

    out = Path(args.out)
    if out.suffix.lower() != ".ply":
        raise ConfigError(f"{out}: output must be a .ply file")
    check_output_file(out, "OUT.ply")
    atlas = load_map(args.map).atlas
    map_id = atlas.current.id if args.map_id is None else args.map_id
    cloud = map_point_cloud(atlas, map_id, inactive=args.inactive)
    write_ply(out, cloud, comment=f"changing_slam_ros map points: {args.map}, map {map_id}, frame of that map")
    inactive = int((cloud.columns["active"] == 0).sum())
    print(f"wrote {out}: {len(cloud)} points of map {map_id}" + (f" ({inactive} inactive)" if args.inactive else ""))
    return 0
