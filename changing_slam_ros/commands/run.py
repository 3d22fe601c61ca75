"""`changing-slam run SOURCE --out DIR [--config YAML]`: the SLAM pipeline offline, every frame processed.

    changing-slam run SOURCE --out DIR [--config NAME|FILE] [--max-frames N] [--no-loop] [--no-plot] [--quiet]
        [--detections none|model|oracle] [--detections-file FILE] [--no-dynamic] [ablation switches]
(dynamic-scene options: see `commands/dynamic_options.py`).

SOURCE is anything `io.dataset.open_dataset` reads (TUM-layout folder, 7-Scenes, ROS 1/2 bag, mcap).
DIR receives:
- `trajectory.txt`         final poses (TUM), each frame re-expressed from its reference keyframe;
- `trajectory_online.txt`  poses as tracking estimated them live;
- `keyframes.txt`          keyframe poses (TUM);
- `map.npz`                the map (versioned, see `MAP_FORMAT_VERSION`);
- `metrics.json`           frames tracked, keyframes, loops, speed; ATE / RPE when ground truth exists;
- `timing.json`            per-stage milliseconds (count, mean, p50, p90, p99, max);
- `trajectory.png`         the final trajectory against ground truth (when it exists).
The run is deterministic for a given config (single-threaded OpenCV, seeded RNG, frames in order).
"""

from __future__ import annotations

import argparse
import io
import json
import queue
import threading
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from changing_slam_ros.commands.dynamic_options import add_dynamic_arguments, dynamic_setup
from changing_slam_ros.commands.objects_options import (
    LoopLog, add_object_arguments, object_layer_setup, object_map_arrays, write_object_outputs,
)
from changing_slam_ros.config import find_config, load_yaml, section
from changing_slam_ros.core.local_mapping import MappingConfig
from changing_slam_ros.core.orb_features import FeatureConfig
from changing_slam_ros.core.rgbd_frame import RgbdFrame
from changing_slam_ros.core.slam_map import Atlas
from changing_slam_ros.core.system import SlamSystem, SystemConfig
from changing_slam_ros.core.tracking import TrackingConfig
from changing_slam_ros.errors import EvalError
from changing_slam_ros.io.atomic import atomic_write_bytes, atomic_write_text
from changing_slam_ros.io.tum_trajectory import write_tum_trajectory

MAP_FORMAT_VERSION = 1


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("source", metavar="SOURCE", help="TUM-layout folder, ROS 1/2 bag or mcap file")
    parser.add_argument("--out", required=True, metavar="DIR", help="output folder (created if missing)")
    parser.add_argument("--config", metavar="NAME|FILE", help="config YAML (sections camera, dataset, features, tracking, mapping, loop)")
    parser.add_argument("--max-frames", type=int, default=0, metavar="N", help="stop after N frames (0 = all)")
    parser.add_argument("--no-loop", action="store_true", help="disable loop closing")
    parser.add_argument("--no-plot", action="store_true", help="skip trajectory.png")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    add_dynamic_arguments(parser)
    add_object_arguments(parser)


def main(args: argparse.Namespace) -> int:
    from changing_slam_ros.io.dataset import open_dataset
    from changing_slam_ros.io.dataset_config import load_dataset_settings, settings_from_mapping

    data: dict[str, Any] = {}
    where = "defaults"
    if args.config:
        path = find_config(args.config)
        data = load_yaml(path)
        where = str(path)
        settings = settings_from_mapping(data, where)
    else:
        settings = load_dataset_settings(None)
    config = system_config_from_mapping(data, where)
    source = open_dataset(args.source, settings)
    closing = None if args.no_loop else _loop_closing(data, where)
    dynamic = dynamic_setup(args, data, where)
    objects = object_layer_setup(args, data, where)
    system = SlamSystem(config, loop_closer=closing, keyframe_index=closing, dynamic_filter=dynamic.filter,
                        object_layer=objects)
    loops = LoopLog()

    n_total = len(source) if not args.max_frames else min(args.max_frames, len(source))
    t0 = time.perf_counter()
    for rgbd in _progress(_prefetch(source, n_total), n_total, args.quiet):
        if system.process(rgbd, dynamic.detections_for(rgbd)).loop_corrected:
            loops.record(closing, system)
    wall_s = time.perf_counter() - t0

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    final = system.final_trajectory()
    online = system.online_trajectory()
    write_tum_trajectory(out / "trajectory.txt", final)
    write_tum_trajectory(out / "trajectory_online.txt", online)
    write_tum_trajectory(out / "keyframes.txt", system.keyframe_trajectory())
    save_map(out / "map.npz", system.atlas, object_map_arrays(objects))
    timing = system.timing_summary()
    metrics: dict[str, Any] = {
        "source": str(args.source),
        "config": where,
        "frames": len(system.records),
        "frames_tracked": system.n_tracked(),
        "keyframes": system.atlas.n_keyframes,
        "maps": len(system.atlas.maps),
        "map_points": int(sum(int(m.points.usable().sum()) for m in system.atlas.maps)),
        "loops_closed": system.n_loops,
        "wall_s": wall_s,
        "fps": len(system.records) / wall_s if wall_s > 0 else 0.0,
        "tracking_ms_median": timing.get("tracking", {}).get("p50", 0.0),
        "dynamic": dynamic.summary(),
    }
    gt = source.groundtruth
    if gt is not None and len(final) >= 3:
        metrics.update(_evaluate(gt, final, online, out, args.no_plot))
    metrics["loops"] = loops.evaluate(gt)
    metrics["objects"] = write_object_outputs(out, objects, final, gt, args.source, args.no_plot)
    atomic_write_text(out / "metrics.json", json.dumps(metrics, indent=2) + "\n")
    atomic_write_text(out / "timing.json", json.dumps(timing, indent=2) + "\n")
    line = (
        f"{metrics['frames_tracked']}/{metrics['frames']} frames tracked, {metrics['keyframes']} keyframes, "
        f"{metrics['loops_closed']} loops, {metrics['fps']:.1f} fps, tracking median {metrics['tracking_ms_median']:.1f} ms"
    )
    if "ate_rmse_m" in metrics:
        line += f", ATE RMSE {metrics['ate_rmse_m'] * 100:.2f} cm (online {metrics['ate_online_rmse_m'] * 100:.2f} cm)"
    print(line)
    print(f"results in {out}")
    return 0


def system_config_from_mapping(data: dict[str, Any], where: str) -> SystemConfig:
    """The `features`, `tracking` and `mapping` sections of a parsed config (defaults when absent)."""
    return SystemConfig(
        section(FeatureConfig, data.get("features"), f"{where}: features"),
        section(TrackingConfig, data.get("tracking"), f"{where}: tracking"),
        section(MappingConfig, data.get("mapping"), f"{where}: mapping"),
    )


def _loop_closing(data: dict[str, Any], where: str) -> Any:
    from changing_slam_ros.core.loop_closing import LoopCloser, LoopConfig, SlamMapLoopClosing
    from changing_slam_ros.core.vocabulary import Vocabulary

    cfg = section(LoopConfig, data.get("loop"), f"{where}: loop")
    if not cfg.enabled:
        return None
    return SlamMapLoopClosing(LoopCloser(cfg, Vocabulary.load()))


def _prefetch(source: Iterable[RgbdFrame], n: int, depth: int = 8) -> Iterator[RgbdFrame]:
    """Decode frames on a reader thread (image decoding releases the GIL) while SLAM runs; order kept."""
    q: queue.Queue[Any] = queue.Queue(maxsize=depth)
    done = object()
    stop = threading.Event()

    def reader() -> None:
        try:
            for i, frame in enumerate(source):
                if i >= n or stop.is_set():
                    break
                q.put(frame)
        except BaseException as err:  # noqa: BLE001 - re-raised on the main thread
            q.put(err)
        q.put(done)

    thread = threading.Thread(target=reader, name="frame-reader", daemon=True)
    thread.start()
    try:
        while True:
            item = q.get()
            if item is done:
                break
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        while thread.is_alive():
            try:
                q.get_nowait()
            except queue.Empty:
                thread.join(0.05)


def _progress(frames: Iterator[RgbdFrame], total: int, quiet: bool) -> Iterator[RgbdFrame]:
    if quiet:
        yield from frames
        return
    from tqdm import tqdm

    yield from tqdm(frames, total=total, unit="frame", desc="slam")


def _evaluate(gt: Any, final: Any, online: Any, out: Path, no_plot: bool) -> dict[str, Any]:
    from changing_slam_ros.eval.ate import ate
    from changing_slam_ros.eval.report import evaluate

    result: dict[str, Any] = {}
    try:
        report = evaluate(gt, final, gt_name="ground truth", est_name="trajectory.txt")
        online_ate = ate(gt, online, est_name="trajectory_online.txt")
    except EvalError as err:
        return {"evaluation_error": str(err)}
    result["evaluation"] = report
    result["ate_rmse_m"] = float(report["ate"]["rmse"]) if "rmse" in report["ate"] else float("nan")
    result["ate_online_rmse_m"] = float(np.sqrt(np.mean(online_ate.errors_m**2)))
    if not no_plot:
        from changing_slam_ros.eval.plots import plot_ate

        plot_ate(ate(gt, final, est_name="trajectory.txt"), out / "trajectory.png", gt_full=gt, title="final trajectory")
    return result


def save_map(path: Path, atlas: Atlas, extra: dict[str, np.ndarray] | None = None) -> None:
    """Write the Atlas as one npz (atomic): per map, keyframes and usable points with observations.

    Arrays, prefixed `m{map_id}_`: `kf_ids` (K,), `kf_stamps_ns` (K,), `kf_poses` (K, 4, 4) camera-to-world,
    `point_ids` (P,), `point_positions` (P, 3), `point_descriptors` (P, 32), `point_active` (P,),
    `obs` (E, 3) rows (point id, keyframe id, keypoint index). Top level: `format_version`, `map_ids`, and
    the arrays of `extra` (e.g. `m{map_id}_objects_json`, the object map, from `objects_options.object_map_arrays`).
    """
    arrays: dict[str, Any] = {"format_version": np.array(MAP_FORMAT_VERSION), "map_ids": np.array([m.id for m in atlas.maps])}
    for m in atlas.maps:
        kfs = sorted(m.keyframes.values(), key=lambda k: k.id)
        pre = f"m{m.id}_"
        arrays[pre + "kf_ids"] = np.array([k.id for k in kfs], np.int64)
        arrays[pre + "kf_stamps_ns"] = np.array([k.stamp_ns for k in kfs], np.int64)
        arrays[pre + "kf_poses"] = np.array([k.T_world_cam for k in kfs]).reshape(-1, 4, 4)
        ids = np.flatnonzero(~m.points.bad[: m.points.size])
        arrays[pre + "point_ids"] = ids
        arrays[pre + "point_positions"] = m.points.positions[ids]
        arrays[pre + "point_descriptors"] = m.points.descriptors[ids]
        arrays[pre + "point_active"] = m.points.active[ids]
        obs = [(p, k, i) for p in ids.tolist() for k, i in m.points.observations[p].items()]
        arrays[pre + "obs"] = np.array(obs, np.int64).reshape(-1, 3)
    arrays.update(extra or {})
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    atomic_write_bytes(path, buf.getvalue())


def load_map_arrays(path: Path) -> dict[str, np.ndarray]:
    """Read a map written by `save_map`; raise MapFileError on a wrong or missing version."""
    from changing_slam_ros.errors import MapFileError

    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError) as err:
        raise MapFileError(f"{path}: cannot read map ({err})") from err
    if "format_version" not in arrays:
        raise MapFileError(f"{path}: not a map file (no format_version)")
    if int(arrays["format_version"]) != MAP_FORMAT_VERSION:
        raise MapFileError(f"{path}: map format version {int(arrays['format_version'])}, expected {MAP_FORMAT_VERSION}")
    return arrays
