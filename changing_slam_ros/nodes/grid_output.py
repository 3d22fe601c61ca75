"""local_mapping's occupancy grid: `~/grid` (nav_msgs/OccupancyGrid, transient local) and the saved map_server pair.

The grid is rebuilt from every keyframe's depth scan at the keyframe's current pose (`core.map.keyframe_grid`), so a
loop correction moves it; a rebuild costs milliseconds per keyframe, so it runs at most every `grid_period_s` and
only while someone subscribes: on a keyframe or a loop when the period has passed, else from a steady timer once the
period is over (the last change before a pause is not left out). The message's origin is the full pose of the
first cell in the map frame, on the estimated floor: in the map's x-y plane when the map is z-up (tracking with a
`base_frame`, `SlamSystem.set_first_pose`), tilted when the map is the first camera's optical frame. The saved
pair is in the floor frame (`io.nav2_map`).
"""

from __future__ import annotations

import array
import dataclasses
import time
from pathlib import Path
from collections.abc import Callable
from typing import Any

import numpy as np
from nav_msgs.msg import OccupancyGrid as OccupancyGridMsg
from rclpy.clock import Clock, ClockType
from rclpy.node import Node

from changing_slam_ros.core.map.occupancy_grid import GridConfig, OccupancyGrid
from changing_slam_ros.nodes.conversions import make_header, matrix_to_pose
from changing_slam_ros.nodes.node_help import ParamSpec
from changing_slam_ros.nodes.qos_profiles import LATCHED

FROM_CONFIG = -1.0

GRID_PARAMETERS: tuple[ParamSpec, ...] = (
    ("grid_period_s", 5.0, "shortest time between two ~/grid messages (each rebuilds the grid from every "
                           "keyframe's depth scan); 0 = no ~/grid"),
    ("grid.resolution_m", FROM_CONFIG, "occupancy grid cell size (m); -1 = the config's grid.resolution_m"),
    ("grid.min_height_m", FROM_CONFIG, "points this high above the estimated floor and higher are obstacles; "
                                       "-1 = the config's grid.min_height_m"),
    ("grid.max_height_m", FROM_CONFIG, "points higher than this above the floor are not obstacles (the robot "
                                       "passes under them); -1 = the config's grid.max_height_m"),
)  # fmt: skip


def grid_config(base: GridConfig, params: dict[str, Any]) -> GridConfig:
    """The config's grid section with the node's grid.* parameters over it (those not left at -1)."""
    over = {k: float(params[f"grid.{k}"]) for k in ("resolution_m", "min_height_m", "max_height_m")
            if float(params[f"grid.{k}"]) != FROM_CONFIG}  # fmt: skip
    return dataclasses.replace(base, **over) if over else base


def grid_to_msg(grid: OccupancyGrid, cfg: GridConfig, stamp_ns: int, frame_id: str) -> OccupancyGridMsg:
    msg = OccupancyGridMsg(header=make_header(stamp_ns, frame_id))
    h, w = grid.shape
    msg.info.map_load_time = msg.header.stamp
    msg.info.resolution = float(grid.resolution_m)
    msg.info.width, msg.info.height = int(w), int(h)
    msg.info.origin = matrix_to_pose(grid.origin_in_map())
    msg.data = array.array("b", grid.occupancy(cfg).reshape(-1).tobytes())
    return msg


class GridOutput:
    """Publishes `~/grid` for a map owner (`split_backend.MapOwner`) and writes the pair beside a saved map."""

    def __init__(self, node: Node, params: dict[str, Any], frame_id: str, owner_of: Callable[[], Any]) -> None:
        self.node = node
        self.owner_of = owner_of  # the node's current map owner (~/load_map replaces it)
        self.period_s = float(params["grid_period_s"])
        self.frame_id = frame_id
        self.params = params
        self.pub = node.create_publisher(OccupancyGridMsg, "~/grid", LATCHED)
        self._last_s = -1e9
        self._stamp_ns = 0  # of the last change: the grid's header stamp
        self.pending = False  # the map changed since the last grid went out
        self.published = 0
        self.build_ms: list[float] = []
        if self.period_s > 0:
            node.create_timer(self.period_s, self._tick, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _tick(self) -> None:
        if self.pending:
            self.on_change(-1)

    def config(self, owner: Any) -> GridConfig:
        return grid_config(owner.backend.system.config.grid, self.params)

    def build(self, owner: Any) -> tuple[OccupancyGrid | None, GridConfig]:
        cfg = self.config(owner)
        system = owner.backend.system
        t0 = time.perf_counter()
        grid = None
        if cfg.enabled:
            from changing_slam_ros.core.map.keyframe_grid import map_grid

            m = system.atlas.current
            grid = map_grid(m, cfg, system.map_objects(m.id))
        self.build_ms.append((time.perf_counter() - t0) * 1e3)
        return grid, cfg

    def on_change(self, stamp_ns: int, force: bool = False) -> None:
        """The map changed (a keyframe mapped, a loop applied, a map loaded; `stamp_ns` -1: a timer tick, the last
        stamp stays): a new grid when one is due, at once with `force`."""
        self.pending = True
        if stamp_ns >= 0:
            self._stamp_ns = stamp_ns
        now = time.monotonic()
        if self.period_s <= 0 or (not force and now - self._last_s < self.period_s):
            return
        if self.pub.get_subscription_count() == 0 and not force:
            return
        grid, cfg = self.build(self.owner_of())
        self._last_s = now
        self.pending = False
        if grid is None:
            return
        self.pub.publish(grid_to_msg(grid, cfg, self._stamp_ns, self.frame_id))
        self.published += 1

    def save_beside(self, owner: Any, map_path: Path) -> Path | None:
        """Write `<map stem>_grid.yaml` / `.pgm` next to a saved map (None: no scans or the grid off)."""
        from changing_slam_ros.io.nav2_map import write_grid

        grid, cfg = self.build(owner)
        if grid is None:
            return None
        _, doc = write_grid(map_path.with_name(map_path.stem + "_grid.yaml"), grid, cfg)
        return doc

    def stats(self) -> dict[str, Any]:
        ms = np.asarray(self.build_ms)
        return {"grids_published": self.published,
                "grid_build_ms_median": float(np.median(ms)) if len(ms) else None}  # fmt: skip
