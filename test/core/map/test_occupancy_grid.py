"""The occupancy grid (`core.map.occupancy_grid`, `grid_scan`, `floor_plane`): exact verdicts on constructed scenes
(a floor and a wall rendered analytically, a person, an object whose belief falls). The simulator rooms are in
test_occupancy_grid_sim.py."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.map.floor_plane import camera_up_hint, estimate_floor
from changing_slam_ros.core.map.grid_scan import GridScan, ObjectView, label_objects, mark_dynamic, scan_from_depth
from changing_slam_ros.core.map.occupancy_grid import (
    FREE, OCCUPIED, UNKNOWN, GridConfig, OccupancyGrid, ScanView, build_grid, inactive_objects,
)

CAM = CameraIntrinsics(80, 60, 40.0, 40.0, 39.5, 29.5)


def level_camera(x: float, y: float, height: float, yaw: float = 0.0) -> np.ndarray:
    """A camera at (x, y, height) in a z-up world, looking along the world's (cos yaw, sin yaw, 0)."""
    fwd = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    down = np.array([0.0, 0.0, -1.0])
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = np.cross(down, fwd), down, fwd, (x, y, height)
    return T


def wall_and_floor_depth(T_world_cam: np.ndarray, wall_x: float) -> np.ndarray:
    """Depth (60, 80) of a z-up world with a floor at z = 0 and a wall x = wall_x, seen from `T_world_cam`."""
    v, u = np.mgrid[0:CAM.height, 0:CAM.width]
    rays_cam = np.stack([(u - CAM.cx) / CAM.fx, (v - CAM.cy) / CAM.fy, np.ones(u.shape)], axis=-1)
    rays_w = rays_cam @ T_world_cam[:3, :3].T
    c = T_world_cam[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        t_wall = np.where(rays_w[..., 0] > 1e-9, (wall_x - c[0]) / rays_w[..., 0], np.inf)
        t_floor = np.where(rays_w[..., 2] < -1e-9, -c[2] / rays_w[..., 2], np.inf)
    t = np.minimum(t_wall, t_floor)
    return np.where(np.isfinite(t), t, 0.0).astype(np.float32)  # z-depth: the optical-axis component of t * ray


def world_cells(grid: OccupancyGrid, cfg: GridConfig) -> tuple[np.ndarray, np.ndarray]:
    """Cell centres (N, 2) in the world and their states (N,)."""
    return grid.cell_centres_map().reshape(-1, 3)[:, :2], grid.occupancy(cfg).reshape(-1)


def test_floor_found_under_a_table_with_the_hint_20_degrees_off() -> None:
    rng = np.random.default_rng(0)
    floor = np.c_[rng.uniform(-3, 3, (4000, 2)), np.zeros(4000)]
    wall = np.c_[np.full(3000, 2.5), rng.uniform(-3, 3, 3000), rng.uniform(0, 2.5, 3000)]
    table = np.c_[rng.uniform(-0.5, 0.5, (1500, 2)), np.full(1500, 0.75)]
    world = np.vstack([floor, wall, table])
    # the map frame: an optical frame (z ahead, y down) pitched 20 degrees down and 1.1 m above the floor
    pitch = np.radians(20.0)
    R_world_map = np.array([[0.0, -np.sin(pitch), np.cos(pitch)], [-1.0, 0.0, 0.0],
                            [0.0, -np.cos(pitch), -np.sin(pitch)]])  # columns: the map's x, y, z in the world
    pts_map = (world - [0.0, 0.0, 1.1]) @ R_world_map
    true_up = R_world_map.T @ [0.0, 0.0, 1.0]
    est = estimate_floor(pts_map, np.array([0.0, -1.0, 0.0]))  # the camera's own up: 20 degrees off
    assert est is not None and est.n_support >= 3900
    assert np.degrees(np.arccos(min(1.0, est.up @ true_up))) < 0.1 and abs(est.height + 1.1) < 1e-3
    T = est.frame()
    assert np.allclose(T[:3, 2], est.up) and abs(T[:3, 3] @ est.up - est.height) < 1e-9
    # no floor in view: the lowest points stand in, reported as unsupported
    only_wall = estimate_floor(wall, np.array([0.0, 0.0, 1.0]), min_fraction=0.5)
    assert only_wall is not None and only_wall.n_support == 0
    assert np.allclose(camera_up_hint(np.array([level_camera(0, 0, 1.0)])), [0.0, 0.0, 1.0])


def test_wall_ahead_free_before_it_occupied_at_it() -> None:
    cfg = GridConfig(resolution_m=0.05, scan_columns=80)
    T = level_camera(0.0, 0.0, 0.5)
    scan = scan_from_depth(wall_and_floor_depth(T, 2.0), CAM, cfg.scan_columns, cfg.max_range_m)
    grid = build_grid([ScanView(0, T, scan)], cfg)
    # the wall's foot lies within the floor's inlier band and tilts the fit a little (0.4 degrees)
    assert grid is not None and abs(grid.floor.height) < 0.01 and grid.floor.up @ [0.0, 0.0, 1.0] > 0.9999
    xy, occ = world_cells(grid, cfg)
    ahead = np.abs(xy[:, 1]) < 0.3
    at_wall = ahead & (np.abs(xy[:, 0] - 2.0) < 0.025 + 1e-6)
    before = ahead & (xy[:, 0] > 0.9) & (xy[:, 0] < 1.85)  # the floor is seen from 0.85 m on (60 px, f 40)
    assert at_wall.sum() >= 10 and (occ[at_wall] == OCCUPIED).all()
    assert before.sum() > 100 and (occ[before] == FREE).all()
    assert (occ[ahead & (xy[:, 0] > 2.1)] == UNKNOWN).all()  # behind the wall


def test_dynamic_and_low_belief_points_are_never_obstacles_and_their_lines_of_sight_clear() -> None:
    cfg = GridConfig(resolution_m=0.05, scan_columns=80)
    T = level_camera(0.0, 0.0, 0.5)
    depth = wall_and_floor_depth(T, 2.0)
    # a person at 1.2 m in the middle third of the image
    person = np.zeros(depth.shape, bool)
    person[:, 30:50] = True
    with_person = np.where(person, np.minimum(depth, 1.2), depth).astype(np.float32)
    ghost = scan_from_depth(with_person, CAM, cfg.scan_columns, cfg.max_range_m)  # the detector missed them
    seen = scan_from_depth(with_person, CAM, cfg.scan_columns, cfg.max_range_m)
    assert mark_dynamic(seen, CAM, [(30.0, 0.0, 50.0, 60.0)], cfg.dynamic_band_m) > 0
    # flagged: the person's cells stay unknown, the wall past them is not theirs
    def at_person(views: list[ScanView], excluded: set[int] | None = None) -> np.ndarray:
        """The states of the cells where the person stood."""
        grid = build_grid(views, cfg, excluded_objects=excluded or set())
        assert grid is not None
        xy, occ = world_cells(grid, cfg)
        there = (np.abs(xy[:, 0] - 1.2) < 0.05) & (np.abs(xy[:, 1]) < 0.1)
        assert there.sum() >= 4
        return occ[there]

    assert not (at_person([ScanView(0, T, seen)]) == OCCUPIED).any()
    # missed once, then the place is seen empty: no ghost after two keyframes, free after three
    empty = ScanView(1, T, scan_from_depth(depth, CAM, cfg.scan_columns, cfg.max_range_m))
    assert (at_person([ScanView(0, T, ghost)]) == OCCUPIED).any()
    assert not (at_person([ScanView(0, T, ghost), empty, empty]) == OCCUPIED).any()
    assert (at_person([ScanView(0, T, ghost), empty, empty, empty]) == FREE).all()
    # an object's points: obstacles while it is believed, not once its belief fell
    chair = scan_from_depth(with_person, CAM, cfg.scan_columns, cfg.max_range_m)
    view = ObjectView(7, (30.0, 0.0, 50.0, 60.0), np.array([1.25, 0.0, 0.8]), np.array([0.1, 0.8, 1.6]))
    assert label_objects(chair, CAM, T, [view], cfg.object_margin_m) > 0

    @dataclass
    class Obj:
        id: int
        belief: float

    assert (at_person([ScanView(0, T, chair)], inactive_objects([Obj(7, 0.5)], 0.5)) == OCCUPIED).any()
    assert not (at_person([ScanView(0, T, chair)], inactive_objects([Obj(7, 0.3)], 0.5)) == OCCUPIED).any()


def test_grid_scan_checks_its_arrays() -> None:
    with pytest.raises(ValueError, match="3 points, 2 dynamic flags"):
        GridScan(np.zeros((3, 3)), np.zeros(2, bool), np.zeros(3, np.int64))
