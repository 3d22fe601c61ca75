"""Render a scenario frame by frame, pass each frame through the sensor model, and write it out: the
simulator's top-level loop. Ground truth (poses, masks, oracle boxes) comes from the exact render."""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from changing_slam_ros.errors import SimError
from changing_slam_ros.io.atomic import atomic_write_text
from changing_slam_ros.sim.oracle import oracle_detections
from changing_slam_ros.sim.renderer import SimRenderer
from changing_slam_ros.sim.scenarios import Scenario
from changing_slam_ros.sim.scene import SceneSpec
from changing_slam_ros.sim.sensor_model import SensorModel, frame_rng
from changing_slam_ros.sim.writer import SequenceWriter

DEFAULT_START_STAMP_NS = 1_700_000_000_000_000_000  # first frame's stamp; TUM-like absolute seconds


@dataclass(frozen=True)
class RenderOptions:
    """Image size, how many frames (None = the whole scenario), rate override, shadows, first stamp, and the
    sensor (None = the scenario's own)."""

    width: int = 640
    height: int = 480
    frames: int | None = None
    fps: float | None = None
    shadows: bool = False
    start_stamp_ns: int = DEFAULT_START_STAMP_NS
    min_box_pixels: int = 40
    sensor: SensorModel | None = None


@dataclass(frozen=True)
class SimulationResult:
    out_dir: Path
    n_frames: int
    render_ms_per_frame: float  # rendering only (two passes), mean over frames after the first
    total_s: float


def frame_stamps_ns(n_frames: int, fps: float, start_stamp_ns: int) -> list[int]:
    """Stamps of frames 0..n-1 at `fps`, rounded to whole microseconds so TUM text files are exact."""
    return [start_stamp_ns + int(round(k * 1e6 / fps)) * 1000 for k in range(n_frames)]


def simulate(scenario: Scenario, out_dir: Path, options: RenderOptions, seed: int,
             progress: Callable[[int, int], None] | None = None) -> SimulationResult:
    """Render `scenario` into `out_dir` (see `writer.py` for the layout)."""
    if options.width < 16 or options.height < 16:
        raise SimError(f"image size {options.width}x{options.height}: expected at least 16x16")
    fps = options.fps or scenario.fps
    if fps <= 0:
        raise SimError(f"--fps {fps}: expected a positive rate")
    n_total = int(np.floor(scenario.duration_s * fps + 1e-9))
    n = n_total if options.frames is None else min(options.frames, n_total)
    if n <= 0:
        raise SimError(f"--frames {options.frames}: expected at least 1 frame")
    stamps = frame_stamps_ns(n, fps, options.start_stamp_ns)
    sensor = options.sensor if options.sensor is not None else scenario.sensor
    sensor.validate()
    spec = SceneSpec(scenario.room, scenario.actors, scenario.fovy_deg, options.width, options.height,
                     shadows=options.shadows)
    t_start = time.perf_counter()
    render_s: list[float] = []
    with SimRenderer(spec) as renderer:
        writer = SequenceWriter(Path(out_dir), scenario, renderer.camera, seed)
        for k, stamp in enumerate(stamps):
            t_s = (stamp - options.start_stamp_ns) * 1e-9
            T_world_cam = scenario.camera.pose_at(t_s)
            if T_world_cam is None:
                raise SimError(f"scenario {scenario.name}: no camera pose at {t_s:.3f} s")
            poses = [a.track.pose_at(t_s) for a in scenario.actors]
            t0 = time.perf_counter()
            frame = renderer.render(T_world_cam, poses)
            render_s.append(time.perf_counter() - t0)
            dets = oracle_detections(frame.instance_ids, scenario.actors, options.min_box_pixels)
            if not sensor.is_exact():
                t_prev_s = (stamps[k - 1] - options.start_stamp_ns) * 1e-9 if k > 0 else t_s
                T_prev = scenario.camera.pose_at(t_prev_s) if k > 0 else None
                frame = sensor.apply(frame, renderer.camera, frame_rng(seed, k), t_s, T_world_cam, T_prev,
                                     t_s - t_prev_s)
            writer.add_frame(stamp, frame, T_world_cam, poses, dets)
            if progress is not None:
                progress(k + 1, n)
        writer.finish(options.start_stamp_ns)
    if not sensor.is_exact():  # an exact render keeps the scenario's folder as it always was
        atomic_write_text(Path(out_dir) / "sensor.json", json.dumps(sensor.as_dict(), indent=1) + "\n")
    if scenario.parameters:
        atomic_write_text(Path(out_dir) / "scenario.json", json.dumps(
            {"scenario": scenario.name, "seed": seed, "parameters": scenario.parameters}, indent=1) + "\n")
    timed = render_s[1:] if len(render_s) > 1 else render_s
    return SimulationResult(Path(out_dir), n, 1000.0 * float(np.mean(timed)), time.perf_counter() - t_start)
