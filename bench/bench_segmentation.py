"""Speed and accuracy of the Dai et al. pieces: point-correlation segmentation, object BA, overlap merging.

Prints, never asserts. Scenes are the synthetic ones of the unit tests (a room of static points and two
rigid cubes; a box on a 6-DoF path), so the figures are reproducible:

    .venv/bin/python bench/bench_segmentation.py [--runs 5] [--static 800] [--object 100] [--sim] [--loop] [--seed 0]

Wall and CPU milliseconds are both printed: on a shared machine the wall time includes waiting.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Callable

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(REPO), str(REPO / "test" / "core")]

from test_object_tracking import CAMERA, object_sequence  # noqa: E402  (scene builders of the tests)
from test_point_correlation import make_scene, precision_recall  # noqa: E402

from changing_slam_ros.core.movers.object_merging import MergeConfig, overlapping_groups  # noqa: E402
from changing_slam_ros.core.movers.object_tracking import MovingObject, ObjectTracker, ObjectTrackingConfig  # noqa: E402
from changing_slam_ros.core.movers.point_correlation import SegmentationConfig, segment  # noqa: E402
from changing_slam_ros.core.geometry.se3 import invert, transform_points  # noqa: E402


def timed(fn: Callable[[], object], runs: int) -> tuple[object, float, float]:
    """Result of the last run, median wall ms and median CPU ms over `runs` (after one warm-up)."""
    result = fn()
    wall, cpu = [], []
    for _ in range(runs):
        w0, c0 = time.perf_counter(), time.process_time()
        result = fn()
        wall.append((time.perf_counter() - w0) * 1e3)
        cpu.append((time.process_time() - c0) * 1e3)
    return result, statistics.median(wall), statistics.median(cpu)


def bench_segmentation(args: argparse.Namespace) -> None:
    print("point-correlation segmentation (precision/recall of moving points; unassigned counts as missed)")
    fast = [np.array([0.06, 0.0, 0.0]), np.array([0.0, 0.05, -0.04])]
    slow = [np.array([0.03, 0.0, 0.0]), np.array([0.0, 0.025, -0.015])]
    two, multi = SegmentationConfig.two_frame(), SegmentationConfig.multi_frame()
    cases = [
        ("two-frame", 2, fast, 0.05, 0.03, two),
        ("two-frame, <=500", 2, fast, 0.05, 0.03, replace(two, max_points=500)),
        ("5-frame window", 5, slow, 0.08, 0.01, multi),
        ("5-frame, <=500", 5, slow, 0.08, 0.01, replace(multi, max_points=500)),
    ]
    for name, k, steps, outliers, spin, cfg in cases:
        rng = np.random.default_rng(0)
        window, truth, _ = make_scene(
            rng, k, steps, np.array([0.03, 0.0, 0.01]), n_static=args.static, n_object=args.object,
            outlier_rate=outliers, spin_rad_per_frame=spin,
        )
        result, wall, cpu = timed(lambda: segment(window, cfg), args.runs)
        precision, recall = precision_recall(result.dynamic_mask, truth > 0)  # type: ignore[attr-defined]
        seen = int((window.observed.sum(axis=0) >= 2).sum())
        print(
            f"  {name:17s} points {len(truth):5d} (seen twice {seen}), edges {len(result.edges):5d}, "  # type: ignore[attr-defined]
            f"{outliers:.0%} outlier measurements: {wall:7.1f} ms wall, {cpu:7.1f} ms CPU; "
            f"targets {result.num_targets}, P {precision:.3f} R {recall:.3f}"  # type: ignore[attr-defined]
        )


def bench_object_tracking(args: argparse.Namespace) -> None:
    print("object tracking (80-point box, 30 frames, 5 % outliers)")
    T_true, _, frames, _ = object_sequence(30, seed=0)
    tracker = ObjectTracker(CAMERA, ObjectTrackingConfig())

    def run(optimise: bool) -> tuple[MovingObject, list[float], list[float]]:
        first = frames[0]
        obj = MovingObject.create(1, first.point_ids, transform_points(first.T_world_cam, first.points_cam), first.stamp_ns, first)
        track_ms, ba_ms = [], []
        for frame in frames[1:]:
            t0 = time.process_time()
            result = tracker.track(obj, frame)
            track_ms.append((time.process_time() - t0) * 1e3)
            if optimise and result.is_keypose:
                t0 = time.process_time()
                tracker.optimise(obj)
                ba_ms.append((time.process_time() - t0) * 1e3)
        return obj, track_ms, ba_ms

    for optimise in (False, True):
        obj, track_ms, ba_ms = run(optimise)
        offset = invert(T_true[0]) @ obj.poses[frames[0].stamp_ns]
        err = [np.linalg.norm(obj.poses[f.stamp_ns][:3, 3] - (T_true[k] @ offset)[:3, 3]) for k, f in enumerate(frames)]
        label = "eq. 7 + eq. 11 at keyposes" if optimise else "eq. 7 only               "
        ba = f", full BA {statistics.median(ba_ms):.1f} ms CPU median over {len(ba_ms)}" if ba_ms else ""
        print(
            f"  {label}: trajectory RMSE {1e3 * np.sqrt(np.mean(np.square(err))):.2f} mm, "
            f"motion-only BA {statistics.median(track_ms):.1f} ms CPU per frame{ba}"
        )


def bench_unknown_mover(args: argparse.Namespace) -> None:
    """Segmentation on the simulator's unknown_mover over the carried part, every second from 4 s to 19 s.

    "oracle": ORB keypoints of the first frame followed by their true motion; "ORB tracks": frame-to-frame
    ORB matching (wrong matches and outline corners with background depth included).
    """
    from test_point_correlation_sim import oracle_window, tracked_window

    from changing_slam_ros.sim.renderer import SimRenderer
    from changing_slam_ros.sim.scenarios import build_scenario
    from changing_slam_ros.sim.scene import SceneSpec

    scenario = build_scenario("unknown_mover", args.seed)
    spec = SceneSpec(scenario.room, scenario.actors, scenario.fovy_deg, 640, 480)
    box_track = scenario.actors[scenario.actor_index("parcel")].track
    rng = np.random.default_rng(args.seed)
    print(f"unknown_mover (seed {args.seed}), windows starting every second from 4 s to 19 s")
    two, five = SegmentationConfig.two_frame(), SegmentationConfig.multi_frame()
    modes = [
        ("oracle, 2 frames 1/15 s apart", oracle_window, 2, 2 / 30, two),
        ("oracle, 5 frames 0.2 s apart ", oracle_window, 5, 0.2, five),
        ("ORB tracks, 2 frames 0.2 s   ", tracked_window, 2, 0.2, two),
        ("ORB tracks, 5 frames 0.1 s   ", tracked_window, 5, 0.1, five),
    ]
    with SimRenderer(spec) as renderer:
        for name, make, k, dt, cfg in modes:
            tp = fp = n_box = 0
            cpu: list[float] = []
            missed: list[str] = []
            for t in np.arange(4.0, 20.0, 1.0):
                times = [float(t) + dt * i for i in range(k)]
                sim = make(renderer, scenario, times, rng)
                c0 = time.process_time()
                result = segment(sim.window, cfg)
                cpu.append((time.process_time() - c0) * 1e3)
                box = sim.on_box & (sim.window.observed.sum(axis=0) >= 2)
                tp += int(np.sum(result.dynamic_mask & box))
                fp += int(np.sum(result.dynamic_mask & ~sim.on_box))
                n_box += int(box.sum())
                if box.any() and not (result.dynamic_mask & box).any():
                    moved = np.linalg.norm(box_track.pose_at(times[-1])[:3, 3] - box_track.pose_at(times[0])[:3, 3])
                    missed.append(f"{t:.0f} s ({100 * moved:.1f} cm)")
            print(
                f"  {name}: P {tp / max(tp + fp, 1):.3f} R {tp / max(n_box, 1):.3f} over {len(cpu)} windows, "
                f"{statistics.median(cpu):.0f} ms CPU median; box missed at: {', '.join(missed) or 'none'}"
            )


def bench_dai_loop(args: argparse.Namespace) -> None:
    """The whole Dai loop on unknown_mover as a stand-alone prototype (the system's loop is
    `core/movers/mover_tracking.py`, scored by `bench/eval_movers_sim.py`): ORB tracks at
    30 Hz (ground-truth camera poses), a 5-keyframe segmentation every 0.1 s whose targets become objects,
    eq. 12 merging into the objects tracked at that stamp, eq. 7 every frame and eq. 11 at keyposes.

    A track's ground truth is the instance under its first keypoint; a background track that a wrong
    match hands over to the box therefore counts as "not on the box" although it then moves with it.
    """
    import cv2
    from test_point_correlation_sim import render_at

    from changing_slam_ros.core.movers.object_merging import merge_objects
    from changing_slam_ros.core.movers.object_tracking import FrameObjectMeasurements, objects_from_segmentation
    from changing_slam_ros.core.movers.point_correlation import CorrelationWindow
    from changing_slam_ros.sim.renderer import SimRenderer
    from changing_slam_ros.sim.scenarios import build_scenario
    from changing_slam_ros.sim.scene import SceneSpec

    scenario = build_scenario("unknown_mover", args.seed)
    mover = scenario.actor_index("parcel")
    rng = np.random.default_rng(args.seed)
    orb, matcher = cv2.ORB_create(1500), cv2.BFMatcher(cv2.NORM_HAMMING)
    step, n_key, fps, t0 = 3, 5, 30.0, 6.0
    n_frames = int(args.loop_seconds * fps)
    desc = np.zeros((0, 32), np.uint8)
    alive = np.zeros(0, dtype=bool)
    on_box = np.zeros(0, dtype=bool)
    history: list[FrameObjectMeasurements] = []
    objects: list[MovingObject] = []
    truth: dict[int, np.ndarray] = {}
    seg_cpu: list[float] = []
    spec = SceneSpec(scenario.room, scenario.actors, scenario.fovy_deg, 640, 480)
    with SimRenderer(spec) as renderer:
        cam = renderer.camera
        tracker = ObjectTracker(cam, ObjectTrackingConfig())
        for k in range(n_frames):
            t = t0 + k / fps
            stamp = int(round(t * 1e9))
            T_world_cam, poses, frame = render_at(renderer, scenario, t)
            truth[stamp] = poses[mover]
            kps, dk = orb.detectAndCompute(cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY), None)
            uv = np.array([kp.pt for kp in kps])
            col, row = np.round(uv).astype(int).T
            z = frame.depth_m[row, col].astype(np.float64)
            used = np.zeros(len(kps), dtype=bool)
            ids: list[int] = []
            slots: list[int] = []
            tracks = np.flatnonzero(alive)
            alive[:] = False
            if len(tracks):
                for pair in matcher.knnMatch(desc[tracks], dk, k=2):
                    if len(pair) < 2 or pair[0].distance >= 0.8 * pair[1].distance:
                        continue
                    i, j = tracks[pair[0].queryIdx], pair[0].trainIdx
                    if not used[j] and z[j] > 0:
                        used[j], alive[i], desc[i] = True, True, dk[j]
                        ids.append(int(i))
                        slots.append(int(j))
            new = np.flatnonzero(~used & (z > 0))
            ids += list(range(len(desc), len(desc) + len(new)))
            slots += new.tolist()
            desc = np.vstack([desc, dk[new]])
            alive = np.r_[alive, np.ones(len(new), dtype=bool)]
            on_box = np.r_[on_box, frame.instance_ids[row[new], col[new]] == mover + 1]
            depth = z[slots] + rng.normal(0.0, 1.425e-3 * z[slots] ** 2)
            meas = FrameObjectMeasurements(stamp, T_world_cam, np.array(ids, np.int64), cam.backproject(uv[slots], depth))
            history.append(meas)
            for obj in objects:
                result = tracker.track(obj, meas)
                if result.tracked and result.is_keypose:
                    tracker.optimise(obj)
            if k >= step * (n_key - 1) and k % step == 0:
                frames = [history[k - step * i] for i in range(n_key)][::-1]
                all_ids = np.unique(np.concatenate([f.point_ids for f in frames]))
                points_cam = np.full((n_key, len(all_ids), 3), np.nan)
                for a, f in enumerate(frames):
                    points_cam[a, np.searchsorted(all_ids, f.point_ids)] = f.points_cam
                window = CorrelationWindow(all_ids, points_cam, np.stack([f.T_world_cam for f in frames]), cam)
                c0 = time.process_time()
                seg = segment(window, SegmentationConfig.multi_frame())
                seg_cpu.append((time.process_time() - c0) * 1e3)
                next_id = 1 + max((o.object_id for o in objects), default=0)
                objects = merge_objects(objects + objects_from_segmentation(seg, window, stamp, next_id), stamp, MergeConfig())
    print(f"Dai loop on unknown_mover (seed {args.seed}), {args.loop_seconds:.0f} s from {t0:.0f} s at 30 Hz: "
          f"{len(objects)} objects, segmentation {statistics.median(seg_cpu):.0f} ms CPU median")
    for obj in sorted(objects, key=lambda o: -len(o.poses))[:5]:
        stamps = sorted(obj.poses)
        offset = invert(truth[stamps[0]]) @ obj.poses[stamps[0]]
        err = [np.linalg.norm(obj.poses[st][:3, 3] - (truth[st] @ offset)[:3, 3]) for st in stamps]
        travel = np.linalg.norm(truth[stamps[-1]][:3, 3] - truth[stamps[0]][:3, 3])
        print(f"  object {obj.object_id}: {len(obj.point_ids)} points, {on_box[obj.point_ids].mean():.0%} first seen on the box; "
              f"tracked {len(stamps)}/{n_frames} frames over {travel:.2f} m of box travel; position RMSE against "
              f"the box {1e3 * np.sqrt(np.mean(np.square(err))):.1f} mm (max {1e3 * max(err):.1f} mm)")


def bench_merging(args: argparse.Namespace) -> None:
    rng = np.random.default_rng(0)
    sets = [rng.normal([x, 0.0, 1.5], 0.1, (100, 3)) for x in np.linspace(0.0, 3.0, 10)]
    groups, wall, cpu = timed(lambda: overlapping_groups(sets, MergeConfig()), args.runs)
    print(f"overlap checking, 10 targets of 100 points: {wall:.1f} ms wall, {cpu:.1f} ms CPU, {len(groups)} groups")  # type: ignore[arg-type]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5, help="timed runs per case (median reported)")
    parser.add_argument("--static", type=int, default=800, help="static points in the segmentation scene")
    parser.add_argument("--object", type=int, default=100, help="points per moving cube")
    parser.add_argument("--sim", action="store_true", help="also run on the simulator's unknown_mover (renders)")
    parser.add_argument("--seed", type=int, default=0, help="scenario seed for --sim and --loop")
    parser.add_argument("--loop", action="store_true", help="prototype of the whole Dai loop on unknown_mover")
    parser.add_argument("--loop-seconds", type=float, default=6.0, help="simulated seconds for --loop")
    args = parser.parse_args()
    bench_segmentation(args)
    if args.sim:
        bench_unknown_mover(args)
    if args.loop:
        bench_dai_loop(args)
    bench_object_tracking(args)
    bench_merging(args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
