"""`changing-slam run SOURCE --out DIR [--config YAML]`: the SLAM pipeline offline, every frame processed.

    changing-slam run SOURCE --out DIR [--config NAME|FILE] [--start-frame N] [--max-frames N] [--no-loop]
        [--no-plot] [--quiet]
        [--map-in PREVIOUS/map.npz] [--detections none|model|oracle] [--detections-file FILE] [--no-dynamic]
        [--strict] [--serial] [ablation switches]
(dynamic-scene options: see `commands/dynamic_options.py`).

SOURCE is anything `io.dataset.open_dataset` reads (TUM-layout folder, 7-Scenes, ROS 1/2 bag, mcap). DIR
receives the trajectories, keyframes, the map (`map.npz`), metrics and timing (see `main`). With
`--map-in PREVIOUS/map.npz` the run continues a saved map (multi-session; see `multi_session_summary`). With the object layer
on, a `--map-in` run ends with the "what changed" report against the loaded map (`changes.json`,
`changes.png`; `commands/changes.py`), one printed line per change and its counts in metrics.json `changes`.
`--start-frame N` skips the source's first N frames and numbers the rest from 0, as a later session's own
recording would be: with `--map-in` a recording cut in two replays as two sessions.
The run is deterministic for a given config (single-threaded OpenCV, seeded RNG, frames in order, each frame
tracked with its own detections whether the detector runs ahead on its own thread or, `--serial`, in turn).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import numpy.typing as npt

from changing_slam_ros.commands.dynamic_options import add_dynamic_arguments, dynamic_setup
from changing_slam_ros.commands.frame_pipeline import FramePipeline
from changing_slam_ros.commands.objects_options import (
    LoopLog, add_object_arguments, object_layer_setup, write_object_outputs,
)
from changing_slam_ros.config import load_config, section
from changing_slam_ros.core.slam.local_mapping import MappingConfig
from changing_slam_ros.core.features.orb_features import FeatureConfig
from changing_slam_ros.core.features.rgbd_frame import RgbdFrame
from changing_slam_ros.core.system import SlamSystem, SystemConfig
from changing_slam_ros.core.slam.tracking_config import TrackingConfig
from changing_slam_ros.core.slam.localization import Mode
from changing_slam_ros.errors import ConfigError, EvalError, OutputError
from changing_slam_ros.io.atomic import atomic_write_text
from changing_slam_ros.io.bag_reader import SkippedMessage
from changing_slam_ros.io.camera_check import CameraMismatch, first_keyframe_camera, map_camera_mismatch
from changing_slam_ros.io.map_file import LoadedMap, load_map, save_map
from changing_slam_ros.io.output_dir import OutputDir
from changing_slam_ros.provenance import run_provenance
from changing_slam_ros.commands.changes import write_change_outputs
from changing_slam_ros.core.objects.change_report import compare_maps
from changing_slam_ros.core.objects.object_evidence import EvidenceConfig, ObjectEvidence, evidence_of, map_up
from changing_slam_ros.core.objects.object_layer import ObjectLayer
from changing_slam_ros.io.change_report_file import summary_lines
from changing_slam_ros.io.moving_objects_file import write_moving_objects
from changing_slam_ros.io.tum_trajectory import write_tum_trajectory

T = TypeVar("T")

def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("source", metavar="SOURCE", help="TUM-layout folder, ROS 1/2 bag or mcap file")
    parser.add_argument("--out", required=True, metavar="DIR", help="output folder (created if missing)")
    parser.add_argument("--config", metavar="NAME|FILE", help="config YAML (sections camera, dataset, features, tracking, mapping, loop)")
    parser.add_argument("--start-frame", type=int, default=0, metavar="N", help="skip the first N frames of "
                        "SOURCE (0 = none); the frames read are numbered from 0, like a recording of their own")
    parser.add_argument("--max-frames", type=int, default=0, metavar="N", help="stop after N frames (0 = all)")
    parser.add_argument("--no-loop", action="store_true", help="disable loop closing")
    parser.add_argument("--no-plot", action="store_true", help="skip trajectory.png")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--map-in", metavar="MAP", help="start from a map saved by an earlier run (its DIR/map.npz): "
                        "relocalise in it first (tracking.loaded_map_grace_s), poses in its frame, objects and "
                        "beliefs carried over")
    parser.add_argument("--localization", action="store_true", help="with --map-in: localisation only, the "
                        "loaded map is never changed (no keyframes, points or objects added or moved, no loops; "
                        "beliefs not updated); object_sightings.json lists the map's objects seen at their place")
    parser.add_argument("--strict", action="store_true", help="stop at the first malformed message of a bag "
                        "(default: skip its frame with a warning naming topic and stamp, counted in metrics.json "
                        "skipped_messages)")
    parser.add_argument("--keypoint-log", type=Path, default=None, metavar="FILE",
                        help="write every frame's keypoints and the dynamic stage's verdict on each to FILE (.npz; "
                             "see commands/keypoint_log.py), for scoring against ground-truth masks")
    parser.add_argument("--serial", action="store_true", help="detect each frame just before tracking it, on "
                        "the same thread (default: the detector runs on the next frames on its own thread while "
                        "the current one is tracked; every frame gets its own detections either way, so both give "
                        "the same results)")
    add_dynamic_arguments(parser)
    add_object_arguments(parser)


def main(args: argparse.Namespace) -> int:
    """Run SLAM over every frame of `args.source` and write into `args.out`:

    - `trajectory.txt`         final poses (TUM), each frame re-expressed from its reference keyframe;
    - `trajectory_online.txt`  poses as tracking estimated them live;
    - `keyframes.txt`          keyframe poses (TUM);
    - `map.npz`                the map (versioned, `io.map_file`): every map of the Atlas with keyframes, points,
                               graph and object map; `--map-in` starts a later run from it;
    - `grid.pgm`, `grid.yaml`  the current map's 2-D occupancy grid as a Nav2 map_server pair (`io.nav2_map`; with
                               `grid: enabled`, the default), in the floor frame, its pose in the map under
                               `floor_pose_in_map`;
    - `metrics.json`           frames tracked, keyframes, loops, speed; ATE / RPE when ground truth exists;
    - `timing.json`            per-stage milliseconds (count, mean, max; p50, p90, p99 of the last 32768 values,
                               `core.recent_values`: of every frame in a shorter run);
    - `trajectory.png`         the final trajectory against ground truth (when it exists);
    - `moving_objects.json`, `moving_objects/object_<id>.txt`  moving objects and their trajectories (TUM), with
                               `dynamic: movers: enabled: true` (`io.moving_objects_file`);
    - `object_sightings.json`  with `--localization`: the loaded map's objects found at their mapped place (frames
                               in view, present, missing; `core/slam/localization.Sightings`). The map is only read
                               there, so `map.npz` is the loaded file byte for byte.
    """
    from changing_slam_ros.io.dataset import open_dataset
    from changing_slam_ros.io.dataset_config import load_dataset_settings, settings_from_mapping

    data: dict[str, Any] = {}
    where = "defaults"
    if args.config:
        data, where = load_config(args.config)
        settings = settings_from_mapping(data, where)
    else:
        settings = load_dataset_settings(None)
    config = system_config_from_mapping(data, where)
    if args.localization and not args.map_in:
        raise ConfigError("--localization needs --map-in: the map to localise in")
    if args.start_frame < 0:
        raise ConfigError(f"--start-frame {args.start_frame}: expected a frame count >= 0")
    loaded = load_map(args.map_in) if args.map_in else None  # a bad map fails before any frame is read
    skips = SkipLog()
    source = open_dataset(args.source, settings, strict=args.strict, on_skip=skips.add)
    if args.start_frame >= len(source):
        raise ConfigError(f"--start-frame {args.start_frame}: {args.source} has {len(source)} frames")
    out_dir = OutputDir.prepare(args.out, "--out")  # checked (and staged) before the first frame
    mismatches = camera_mismatches(source, loaded, args.map_in)
    for mismatch in mismatches:  # said before the first frame, recorded in metrics.json at the end
        print(f"run: warning: {mismatch.message()}", file=sys.stderr)
    try:
        code = _run(args, data, where, config, loaded, source, out_dir.work, mismatches, skips)
        out_dir.commit()
    except BaseException as err:
        kept = out_dir.abandon()
        if kept is not None:
            print(f"run: stopped; partial results kept in {kept} ({args.out} unchanged)", file=sys.stderr)
        if isinstance(err, OSError):
            raise OutputError(f"--out {args.out}: results not written: {err}") from err
        raise
    print(f"results in {out_dir.target}")
    return code


def _staged(path: Path, target: Path, work: Path) -> Path:
    """`path`, or where it goes in the staging folder `work` when it lies inside `--out` (`target`): a file
    written straight into `--out` would be lost when the staging folder takes its place."""
    try:
        return work / path.resolve().relative_to(target.resolve())
    except ValueError:
        return path


def camera_mismatches(source: Any, loaded: LoadedMap | None, map_in: str | None) -> list[CameraMismatch]:
    """Where the run's camera disagrees with the intrinsics the data ships (the reader's `camera_mismatch`) or
    with the camera a `--map-in` map was made with (its current map's first keyframe)."""
    found = [getattr(source, "camera_mismatch", None)]
    if loaded is not None:
        found.append(map_camera_mismatch(str(map_in), first_keyframe_camera(loaded.atlas.current.keyframes),
                                         source.camera))  # fmt: skip
    return [m for m in found if m is not None]


def _run(args: argparse.Namespace, data: dict[str, Any], where: str, config: SystemConfig, loaded: Any,
         source: Any, out: Path, mismatches: list[CameraMismatch], skips: SkipLog) -> int:
    """Process every frame and write the results into `out` (the staging folder of `OutputDir`)."""
    closing = None if args.no_loop else _loop_closing(data, where)
    dynamic = dynamic_setup(args, data, where)
    objects = object_layer_setup(args, data, where)
    keypoint_log = None
    if args.keypoint_log is not None and dynamic.filter is not None:
        from changing_slam_ros.commands.keypoint_log import KeypointLog

        keypoint_log = KeypointLog(dynamic.filter)
    system = SlamSystem(config, loop_closer=closing, keyframe_index=closing,
                        dynamic_filter=keypoint_log or dynamic.filter,  # type: ignore[arg-type]
                        object_layer=objects)
    session = SessionChanges.start(loaded, objects) if loaded is not None else None  # before the layer moves beliefs
    if loaded is not None:
        system.start_from_map(loaded.atlas, loaded.next_keyframe_id, loaded.objects,
                              Mode.LOCALIZATION if args.localization else Mode.MAPPING)
    loops = LoopLog()

    n_left = len(source) - args.start_frame
    n_total = n_left if not args.max_frames else min(args.max_frames, n_left)
    t0 = time.perf_counter()
    cpu0 = time.process_time()  # every thread of this process: the reader, OpenCV, the detector's
    overlap = not args.serial and dynamic.detector is not None
    with FramePipeline(frames_from(source, args.start_frame), n_total, dynamic.detections_for,
                       overlap=overlap) as frames:
        for rgbd, detections in _progress(frames, n_total, args.quiet):
            if system.process(rgbd, detections).loop_corrected:
                loops.record(closing, system)
    wall_s = time.perf_counter() - t0
    cpu_s = time.process_time() - cpu0
    if keypoint_log is not None:
        keypoint_log.write(_staged(Path(args.keypoint_log), Path(args.out), out))

    final = system.final_trajectory()
    online = system.online_trajectory()
    write_tum_trajectory(out / "trajectory.txt", final)
    write_tum_trajectory(out / "trajectory_online.txt", online)
    write_tum_trajectory(out / "keyframes.txt", system.keyframe_trajectory())
    # Localisation: the object layer never ran, so the objects go back as they were read.
    saved_objects = loaded.objects if args.localization and loaded is not None else objects
    save_map(out / "map.npz", system.atlas, saved_objects, system.tracker.next_kf_id)
    grid = system.occupancy_grid()
    if grid is not None:
        from changing_slam_ros.io.nav2_map import write_grid

        write_grid(out / "grid.yaml", grid, system.config.grid)
    timing = system.timing_summary()
    metrics: dict[str, Any] = {
        "source": str(args.source),
        "config": where,
        "frames": len(system.records),
        "frames_tracked": system.n_tracked(),
        "poses_refused_by_motion_gate": system.tracker.n_gated,
        "frames_reaimed_by_rotation_vote": system.tracker.n_vote_aimed,
        "poses_refused_for_jumping": system.tracker.n_jumps_refused,
        "frames_tracked_with_withheld_keypoints": system.n_withheld_used,
        "keyframes": system.atlas.n_keyframes,
        "maps": len(system.atlas.maps),
        "map_points": int(sum(int(m.points.usable().sum()) for m in system.atlas.maps)),
        "loops_closed": system.n_loops,
        "wall_s": wall_s,
        "detection_overlapped": overlap,
        "fps": len(system.records) / wall_s if wall_s > 0 else 0.0,
        "tracking_ms_median": timing.get("tracking", {}).get("p50", 0.0),
        "cpu_ms_per_frame": 1e3 * cpu_s / len(system.records) if system.records else 0.0,
        "dynamic": dynamic.summary(),
        "provenance": run_provenance(data, where, options=vars(args)),
    }
    if system.config.tracking.level_from_floor and not args.map_in:
        fs = system.floor_start
        metrics["level_from_floor"] = {"levelled": fs is not None,
                                       "camera_height_m": round(fs.height_m, 4) if fs else None,
                                       "camera_pitch_deg": round(fs.pitch_deg, 2) if fs else None}  # fmt: skip
    if args.map_in:
        metrics["multi_session"] = multi_session_summary(system, args.map_in)
    if args.localization:
        sightings = [s.as_dict() for _, s in sorted(system.sightings.by_object.items())]
        atomic_write_text(out / "object_sightings.json", json.dumps(sightings, indent=2) + "\n")
        metrics["localization"] = {"objects_seen": len(sightings), "frames_lost": len(system.records) - system.n_tracked()}
    if session is not None and objects is not None and objects.enabled:
        metrics["changes"] = session.finish(objects, out, (str(args.map_in), str(out / "map.npz")), args.no_plot)
    gt = source.groundtruth
    if gt is not None and len(final) >= 3:
        metrics.update(evaluate(gt, final, online, out, args.no_plot))
    metrics["loops"] = loops.evaluate(gt)
    if grid is not None:
        occ = grid.occupancy(system.config.grid)
        metrics["grid"] = {"width": int(occ.shape[1]), "height": int(occ.shape[0]),
                           "resolution_m": grid.resolution_m, "occupied_cells": int((occ == 100).sum()),
                           "free_cells": int((occ == 0).sum()), "floor_support_points": grid.floor.n_support}  # fmt: skip
    metrics["objects"] = write_object_outputs(out, objects, final, gt, args.source, args.no_plot)
    movers = dynamic.filter.movers if dynamic.filter is not None else None
    if movers is not None:  # class-agnostic moving objects (Dai et al.) and their trajectories
        metrics["moving_objects"] = write_moving_objects(out, movers.tracks())
    metrics["camera_mismatch"] = [m.as_dict() for m in mismatches]
    metrics["skipped_messages"] = skips.summary()
    late = run_warnings(metrics)
    metrics["warnings"] = [m.message() for m in mismatches] + late
    atomic_write_text(out / "metrics.json", json.dumps(metrics, indent=2) + "\n")
    atomic_write_text(out / "timing.json", json.dumps(timing, indent=2) + "\n")
    for warning in late:
        print(f"run: warning: {warning}", file=sys.stderr)
    line = (
        f"{metrics['frames_tracked']}/{metrics['frames']} frames tracked, {metrics['keyframes']} keyframes, "
        f"{metrics['loops_closed']} loops, {metrics['fps']:.1f} fps, tracking median {metrics['tracking_ms_median']:.1f} ms"
    )
    if "ate_rmse_m" in metrics:
        line += f", ATE RMSE {metrics['ate_rmse_m'] * 100:.2f} cm (online {metrics['ate_online_rmse_m'] * 100:.2f} cm)"
    print(line)
    return 1 if metrics["frames_tracked"] == 0 else 0  # nothing useful produced


def run_warnings(metrics: dict[str, Any]) -> list[str]:
    """What the console and metrics.json `warnings` say about a run that produced little: no frame tracked, or a
    loaded map never relocalised in."""
    out = []
    if metrics["frames"] and metrics["frames_tracked"] == 0:
        out.append(f"0 of {metrics['frames']} frames tracked: check the config's camera and dataset.depth_scale "
                   "against the data")  # fmt: skip
    skipped = metrics.get("skipped_messages", {})
    if skipped.get("count"):
        topics = ", ".join(f"{n} on {t}" for t, n in skipped["by_topic"].items())
        out.append(f"{skipped['count']} malformed message(s) skipped ({topics}); --strict stops at the first")
    if not metrics.get("level_from_floor", {"levelled": True})["levelled"]:
        out.append("tracking.level_from_floor: no floor in view when the map started; the map is the first camera's "
                   "optical frame (z forward, y down)")  # fmt: skip
    ms = metrics.get("multi_session")
    if ms is not None and not ms["relocalised"]:
        out.append(f"never relocalised in the loaded map {ms['map_in']}; a new map was started (a map of another "
                   "scene, or made with another camera?)")  # fmt: skip
    return out


class SkipLog:
    """The malformed messages the reader skipped: the first `PRINTED` said on the console as they come, all
    counted per topic for metrics.json `skipped_messages`."""

    PRINTED = 10

    def __init__(self) -> None:
        self.skipped: list[SkippedMessage] = []

    def add(self, skipped: SkippedMessage) -> None:
        self.skipped.append(skipped)
        if len(self.skipped) <= self.PRINTED:
            more = "; further ones only counted" if len(self.skipped) == self.PRINTED else ""
            print(f"run: warning: {skipped.message()}{more}", file=sys.stderr)

    def summary(self) -> dict[str, Any]:
        by_topic: dict[str, int] = {}
        for s in self.skipped:
            by_topic[s.topic] = by_topic.get(s.topic, 0) + 1
        first = [{"topic": s.topic, "stamp_ns": s.stamp_ns, "reason": s.reason} for s in self.skipped[:self.PRINTED]]
        return {"count": len(self.skipped), "by_topic": by_topic, "first": first}


@dataclass
class SessionChanges:
    """The object map a multi-session run started from (evidence records taken before the layer decays the
    beliefs, and the thumbnails), for the change report at the end of the run."""

    map_id: int
    before: list[ObjectEvidence]
    thumbnails: dict[int, npt.NDArray[np.uint8]]

    @classmethod
    def start(cls, loaded: LoadedMap, layer: ObjectLayer | None) -> SessionChanges | None:
        map_id = loaded.atlas.current.id
        if layer is None or not layer.enabled or map_id not in loaded.objects:
            return None
        saved = loaded.objects[map_id]
        return cls(map_id, [evidence_of(o, _evidence_config(layer)) for o in saved.objects], dict(saved.thumbnails))

    def finish(self, layer: ObjectLayer, out: Path, names: tuple[str, str], no_plot: bool) -> dict[str, int]:
        """Write `changes.json` / `changes.png` to `out` and print the changes; returns the counts."""
        after = layer.objects(self.map_id)
        # `after` is every object the continued map holds, of any belief: one missing was withdrawn, not removed
        report = compare_maps(self.before, [evidence_of(o, _evidence_config(layer)) for o in after],
                              absent_is_withdrawn=True)
        write_change_outputs(out, report, map_up(after), self.thumbnails, layer.saved_objects(self.map_id).thumbnails,
                             names, not no_plot)
        for line in summary_lines(report):
            print(f"change: {line}")
        return report.counts()


def _evidence_config(layer: ObjectLayer) -> EvidenceConfig:
    cfg = layer.config.association
    return EvidenceConfig(cfg.semantic_min_belief, cfg.min_points)


def multi_session_summary(system: SlamSystem, map_in: str) -> dict[str, Any]:
    """metrics.json `multi_session`: the loaded map and when tracking relocalised in it (frame index, seconds after
    the first frame; None when it never did and a new map was started).

    With `--map-in` the run continues the saved Atlas: every frame first tries relocalisation against the saved
    current map (for `tracking.loaded_map_grace_s`, 2 s by default, then a new map is started), trajectories are
    in the saved map's frame, and the object layer starts from the saved objects and beliefs."""
    i = system.tracker.loaded_map_relocalised_index
    out: dict[str, Any] = {"map_in": str(map_in), "relocalised": i >= 0, "relocalised_frame": i if i >= 0 else None,
                           "relocalised_after_s": None}
    if i >= 0 and system.records:
        out["relocalised_after_s"] = (system.records[i].stamp_ns - system.records[0].stamp_ns) * 1e-9
    return out


def system_config_from_mapping(data: dict[str, Any], where: str) -> SystemConfig:
    """The `features`, `tracking`, `mapping` and `grid` sections of a parsed config (defaults when absent)."""
    from changing_slam_ros.core.map.occupancy_grid import GridConfig

    return SystemConfig(
        section(FeatureConfig, data.get("features"), f"{where}: features"),
        section(TrackingConfig, data.get("tracking"), f"{where}: tracking"),
        section(MappingConfig, data.get("mapping"), f"{where}: mapping"),
        section(GridConfig, data.get("grid"), f"{where}: grid"),
    )


def _loop_closing(data: dict[str, Any], where: str) -> Any:
    from changing_slam_ros.core.slam.loop_closing import LoopCloser, LoopConfig, SlamMapLoopClosing
    from changing_slam_ros.core.features.vocabulary import Vocabulary

    cfg = section(LoopConfig, data.get("loop"), f"{where}: loop")
    if not cfg.enabled:
        return None
    return SlamMapLoopClosing(LoopCloser(cfg, Vocabulary.load()))


def frames_from(source: Any, start: int) -> Iterator[RgbdFrame]:
    """The frames of `source` from index `start` on, renumbered from 0 (tracking counts frames by index: a
    keyframe's age, the frame before). A source that reads frames by index (`frame(i)`, a TUM folder) skips
    the first ones unread; a bag is read through and its earlier frames dropped by their own index, so a
    skipped malformed message does not shift the cut."""
    if start == 0:
        yield from source
        return
    by_index = getattr(source, "frame", None)
    frames = (by_index(i) for i in range(start, len(source))) if callable(by_index) else iter(source)
    for frame in frames:
        if frame.index >= start:
            yield dataclasses.replace(frame, index=frame.index - start)


def _progress(frames: Iterable[T], total: int, quiet: bool) -> Iterator[T]:
    if quiet:
        yield from frames
        return
    from tqdm import tqdm

    yield from tqdm(frames, total=total, unit="frame", desc="slam")


def evaluate(gt: Any, final: Any, online: Any, out: Path, no_plot: bool) -> dict[str, Any]:
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
