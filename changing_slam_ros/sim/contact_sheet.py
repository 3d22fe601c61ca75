"""A contact sheet: one labelled frame of each scenario in a grid, to see at a glance what they look like."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt

from changing_slam_ros.io.atomic import atomic_write_bytes
from changing_slam_ros.errors import SimError
from changing_slam_ros.sim.renderer import SimRenderer
from changing_slam_ros.sim.scenarios import SCENARIOS, build_scenario
from changing_slam_ros.sim.scene import SceneSpec


def render_preview(name: str, seed: int, width: int, height: int) -> npt.NDArray[np.uint8]:
    """The scenario's preview frame (at `Scenario.preview_t_s`), (H, W, 3) RGB."""
    s = build_scenario(name, seed)
    t = s.preview_t_s
    T_world_cam = s.camera.pose_at(t)
    assert T_world_cam is not None
    with SimRenderer(SceneSpec(s.room, s.actors, s.fovy_deg, width, height)) as r:
        return r.render(T_world_cam, [a.track.pose_at(t) for a in s.actors]).rgb


def contact_sheet(names: list[str] | None = None, seed: int = 0, tile_w: int = 320, tile_h: int = 240,
                  columns: int = 4) -> npt.NDArray[np.uint8]:
    """Grid (rows * tile_h, columns * tile_w, 3) RGB of labelled preview frames."""
    names = list(SCENARIOS) if names is None else names
    tiles = []
    for name in names:
        tile = render_preview(name, seed, tile_w, tile_h).copy()
        s = build_scenario(name, seed)
        label = f"{name}  t={s.preview_t_s:.0f}s"
        cv2.rectangle(tile, (0, 0), (tile_w, 18), (0, 0, 0), -1)
        cv2.putText(tile, label, (4, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (255, 255, 255), 1, cv2.LINE_AA)
        tiles.append(tile)
    while len(tiles) % columns:
        tiles.append(np.zeros((tile_h, tile_w, 3), np.uint8))
    rows = [np.hstack(tiles[i:i + columns]) for i in range(0, len(tiles), columns)]
    return np.vstack(rows)


def write_contact_sheet(path: Path, seed: int = 0, tile_w: int = 320, tile_h: int = 240) -> None:
    ok, buf = cv2.imencode(".png", cv2.cvtColor(contact_sheet(None, seed, tile_w, tile_h), cv2.COLOR_RGB2BGR))
    if not ok:
        raise SimError(f"{path}: PNG encoding failed")
    atomic_write_bytes(path, bytes(buf.tobytes()))
