"""The Nav2 map_server pair (`io.nav2_map`): written, parsed back as map_server does (P5 header, yaml keys, trinary
thresholds), cell for cell; a grid from `core.map.occupancy_grid` keeps its origin and floor pose."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from changing_slam_ros.errors import MapFileError
from changing_slam_ros.io.nav2_map import YAML_KEYS, read_nav2_map, read_pgm, write_grid, write_nav2_map


def test_pair_round_trips_as_map_server_reads_it(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    occ = rng.choice(np.array([-1, 0, 100], np.int8), size=(37, 53))
    image, doc_path = write_nav2_map(tmp_path / "grid.yaml", occ, 0.05, (-1.25, 2.5, 0.0), {"keyframes": 3})
    assert image == tmp_path / "grid.pgm" and sorted(p.name for p in tmp_path.iterdir()) == ["grid.pgm", "grid.yaml"]
    raw = image.read_bytes()
    assert raw.startswith(b"P5\n53 37\n255\n") and len(raw) == len(b"P5\n53 37\n255\n") + 37 * 53
    doc = yaml.safe_load(doc_path.read_text())
    assert list(doc)[: len(YAML_KEYS)] == list(YAML_KEYS) and doc["image"] == "grid.pgm" and doc["keyframes"] == 3
    back = read_nav2_map(doc_path)
    np.testing.assert_array_equal(back.occupancy, occ)
    assert back.resolution_m == 0.05 and back.origin_xyyaw == (-1.25, 2.5, 0.0)
    img = read_pgm(image)  # the top row of the image is the grid's last row
    assert img[0, 0] == {-1: 205, 0: 254, 100: 0}[int(occ[-1, 0])]


def test_a_grid_keeps_its_origin_and_floor_pose(tmp_path: Path) -> None:
    from changing_slam_ros.core.map.floor_plane import FloorEstimate
    from changing_slam_ros.core.map.occupancy_grid import GridConfig, OccupancyGrid

    cfg = GridConfig()
    floor = FloorEstimate(np.array([0.0, -1.0, 0.0]), 1.1, 500)
    lo = np.zeros((4, 6), np.float32)
    lo[1, 2], lo[2, 3] = 2.0, -2.0
    grid = OccupancyGrid(lo, 0.1, np.array([-0.3, 0.2]), floor.frame(), floor, 5)
    _, doc_path = write_grid(tmp_path / "map_grid.yaml", grid, cfg)
    back = read_nav2_map(doc_path)
    np.testing.assert_array_equal(back.occupancy, grid.occupancy(cfg))
    assert back.origin_xyyaw == pytest.approx((-0.3, 0.2, 0.0))
    x, y, z, qx, qy, qz, qw = back.yaml["floor_pose_in_map"]
    assert (x, y, z) == pytest.approx(tuple(floor.frame()[:3, 3]))
    assert np.linalg.norm([qx, qy, qz, qw]) == pytest.approx(1.0)


def test_foreign_files_are_refused(tmp_path: Path) -> None:
    (tmp_path / "a.pgm").write_bytes(b"P2\n2 2\n255\n0 0 0 0\n")
    with pytest.raises(MapFileError, match="not a binary PGM"):
        read_pgm(tmp_path / "a.pgm")
    (tmp_path / "a.yaml").write_text("image: a.pgm\nresolution: 0.05\n")
    with pytest.raises(MapFileError, match="missing map_server keys"):
        read_nav2_map(tmp_path / "a.yaml")
