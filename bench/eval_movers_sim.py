"""Class-agnostic movers against the simulator's ground truth (prints, never asserts).

Two uses:

    # run the system on a simulated folder (movers on) and score it: moving-keypoint precision/recall
    # against the instance masks, each exported object's trajectory against the mover's, camera ATE
    .venv/bin/python bench/eval_movers_sim.py SIM_DIR [--frames N] [--config YAML] [--out DIR]

    # score an existing `changing-slam run` output (moving_objects.json) against SIM_DIR
    .venv/bin/python bench/eval_movers_sim.py SIM_DIR --run-dir RUN_DIR

The rows and the method: `main`.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from changing_slam_ros.core.movers.object_tracking import MovingObjectTrack  # noqa: E402
from changing_slam_ros.eval.moving_objects import (  # noqa: E402
    ObjectTruth, camera_alignment, object_errors_m, read_sim_movers,
)


def the_mover(sim_dir: Path) -> ObjectTruth:
    movers = read_sim_movers(sim_dir)
    if len(movers) != 1:
        raise SystemExit(f"{sim_dir}/objects.json: expected one moving object of class -1, found {len(movers)}")
    return movers[0]


def score_objects(tracks: list[MovingObjectTrack], S: np.ndarray, sim_dir: Path) -> None:
    truth = the_mover(sim_dir)
    print(f"objects exported: {len(tracks)}; mover carried in {int(truth.moving_frames().sum())} frames")
    t0 = truth.stamps_ns[0]
    for t in sorted(tracks, key=lambda t: -len(t.stamps_ns)):
        err = object_errors_m(t, S, truth)
        rmse = float(np.sqrt(np.mean(err**2))) if len(err) else float("nan")
        print(f"  object {t.object_id} (class {t.class_id}): {len(t.stamps_ns)} poses, "
              f"{(t.first_stamp_ns - t0) * 1e-9:.2f}-{(t.last_stamp_ns - t0) * 1e-9:.2f} s, "
              f"{t.n_points} points; ATE vs the mover {100 * rmse:.2f} cm (max {100 * err.max(initial=0):.2f} cm)")


def run_system(args: argparse.Namespace) -> None:
    from changing_slam_ros.commands.run import system_config_from_mapping
    from changing_slam_ros.config import load_yaml, section
    from changing_slam_ros.core.dynamic.dynamic_filter import DynamicConfig, DynamicFilter
    from changing_slam_ros.core.system import SlamSystem
    from changing_slam_ros.io.dataset import open_dataset
    from changing_slam_ros.io.dataset_config import settings_from_mapping
    from changing_slam_ros.io.moving_objects_file import write_moving_objects
    from changing_slam_ros.io.tum_trajectory import write_tum_trajectory

    sim_dir = Path(args.sim_dir)
    data = load_yaml(Path(args.config))
    source = open_dataset(str(sim_dir), settings_from_mapping(data, args.config))
    dyn_cfg = section(DynamicConfig, data.get("dynamic"), f"{args.config}: dynamic")
    filt = DynamicFilter(dyn_cfg)
    system = SlamSystem(system_config_from_mapping(data, args.config), dynamic_filter=filt)
    seen: list[np.ndarray] = []
    cpu_ms: list[float] = []
    original, original_after = filt.before_tracking, filt.after_tracking

    def recording(rgbd, features, detections):  # type: ignore[no-untyped-def]
        c0 = time.process_time()
        out = original(rgbd, features, detections)
        cpu_ms.append((time.process_time() - c0) * 1e3)
        seen.append(features.keypoints_px.copy())
        seen.append(features.depths_m.copy())
        return out

    def recording_after(T):  # type: ignore[no-untyped-def]
        c0 = time.process_time()
        original_after(T)
        cpu_ms[-1] += (time.process_time() - c0) * 1e3

    filt.before_tracking = recording  # type: ignore[method-assign]
    filt.after_tracking = recording_after  # type: ignore[method-assign]
    truth = the_mover(sim_dir)
    mask_id, moving_gt = truth.mask_id, truth.moving_frames()
    masks = sorted((sim_dir / "masks").glob("*.png"))
    n = min(args.frames or len(source), len(source))
    tp = fp = fn = 0
    tp_all = fp_all = fn_all = 0
    t0 = time.perf_counter()
    for k, rgbd in enumerate(source):
        if k >= n:
            break
        out = system.process(rgbd, None)
        px, depth = seen[-2], seen[-1]
        flagged = out.dynamic.moving if out.dynamic is not None else np.zeros(len(px), bool)
        mask = cv2.imread(str(masks[k]), cv2.IMREAD_UNCHANGED)
        c = np.clip(np.rint(px[:, 0]).astype(int), 0, mask.shape[1] - 1)
        r = np.clip(np.rint(px[:, 1]).astype(int), 0, mask.shape[0] - 1)
        on = (mask[r, c] == mask_id) & (depth > 0)
        f = flagged & (depth > 0)
        a, b, d = int(np.sum(f & on)), int(np.sum(f & ~on)), int(np.sum(on & ~f))
        tp_all, fp_all, fn_all = tp_all + a, fp_all + b, fn_all + d
        if moving_gt[k]:
            tp, fp, fn = tp + a, fp + b, fn + d
    wall = time.perf_counter() - t0
    print(f"{sim_dir.name}: {n} frames, {system.n_tracked()} tracked, {wall:.0f} s wall")
    for name, (a, b, d) in (("carried frames", (tp, fp, fn)), ("all frames", (tp_all, fp_all, fn_all))):
        print(f"  moving keypoints, {name}: precision {a / max(a + b, 1):.3f} recall {a / max(a + d, 1):.3f} "
              f"(TP {a}, FP {b}, FN {d})")
    movers = filt.movers
    assert movers is not None, "dynamic.movers.enabled must be true in the config"
    if movers.segmentation_ms:
        ms = np.array(movers.segmentation_ms)
        print(f"  segmentation: {len(ms)} windows, CPU ms median {np.median(ms):.0f}, p90 {np.percentile(ms, 90):.0f}")
    print(f"  dynamic filter + movers CPU ms per frame: median {np.median(cpu_ms):.0f}, p90 {np.percentile(cpu_ms, 90):.0f}; "
          f"filter wall ms per frame (median): {np.median(filt.frames_ms):.1f}; "
          f"tracking total ms per frame (median): {np.median(system.timings_ms['total']):.0f}")
    online = system.online_trajectory()
    gt_cam = source.groundtruth
    S, cam_ate = camera_alignment(gt_cam, online)
    final_ate = camera_alignment(gt_cam, system.final_trajectory())[1]
    print(f"  camera ATE: online {100 * cam_ate:.2f} cm, final {100 * final_ate:.2f} cm")
    tracks = movers.tracks()
    if args.out:
        out = Path(args.out)
        write_moving_objects(out, tracks)
        write_tum_trajectory(out / "trajectory_online.txt", online)
    score_objects(tracks, S, sim_dir)


def score_run_dir(args: argparse.Namespace) -> None:
    from changing_slam_ros.io.dataset import open_dataset
    from changing_slam_ros.io.moving_objects_file import read_moving_objects
    from changing_slam_ros.io.tum_trajectory import read_tum_trajectory

    run = Path(args.run_dir)
    sim_dir = Path(args.sim_dir)
    gt_cam = open_dataset(str(sim_dir), "sim").groundtruth
    S, cam_ate = camera_alignment(gt_cam, read_tum_trajectory(run / "trajectory_online.txt"))
    print(f"{run}: online camera ATE {100 * cam_ate:.2f} cm")
    score_objects(read_moving_objects(run / "moving_objects.json"), S, sim_dir)


def main() -> int:
    """Parse the options, measure, print the table.

    Counting (the first use): every keypoint with depth of every frame while the mover is carried (its
    ground-truth pose changes between neighbouring frames) is positive when the instance mask under it is
    the mover's; "flagged" = `DynamicFrame.moving` (the keypoints camera tracking was not allowed to use
    because the mover tracker put them on a moving object). Precision = flagged on the mover / flagged;
    recall = flagged on the mover / on the mover.

    Object error: each exported object's poses E_k (SLAM world) are mapped to the ground-truth world by the
    SE(3) alignment S of the online camera trajectory (object BA used the online camera poses); the object
    frame differs from the simulator's by a constant rigid Y (our origin is the centre of the segmented
    points), estimated as the mean of G_k^-1 S E_k; error_k = |position of S E_k - position of G_k Y|.
    """
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sim_dir", help="folder written by `changing-slam simulate unknown_mover`")
    parser.add_argument("--frames", type=int, default=0, help="frames to run (0 = all)")
    parser.add_argument("--config", default=str(REPO / "config" / "sim.yaml"),
                        help="YAML with `dynamic: movers: enabled: true` (and the camera)")
    parser.add_argument("--out", help="write moving_objects.json and the trajectories here")
    parser.add_argument("--run-dir", help="score this `changing-slam run` output instead of running")
    args = parser.parse_args()
    if args.run_dir:
        score_run_dir(args)
    else:
        run_system(args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
