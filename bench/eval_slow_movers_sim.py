"""The local-mapping segmentation (slow movers) against the simulator's ground truth (prints, never asserts).

    .venv/bin/python bench/eval_slow_movers_sim.py SIM_DIR [--config YAML] [--frames N] [--movers]

Runs `SlamSystem` (no detector, loop closing off: the code `changing-slam run SIM_DIR --config YAML
--detections none --no-loop` runs; `--movers` adds the dynamic filter with the config's `dynamic:` section)
and prints:

The rows and the method: `main`.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import changing_slam_ros.core.slam.local_mapping as local_mapping  # noqa: E402
from changing_slam_ros.eval.moving_objects import ObjectTruth, camera_alignment, read_sim_movers  # noqa: E402


def main() -> int:
    """Parse the options, measure, print the table.

    - per keyframe segmentation window: the window's map points; a point is positive when the instance mask
      under its keypoint, in the newest window keyframe that measures it, is the mover's and the mover moved more
      than --moved-m between the point's first and last measurement in the window (a point on the box seen only
      while it rests is a correct static point: a negative, also counted on its own); flagged = put on an object
      target (culled). Precision, recall over the windows in which the mover moves (between the window's first
      and last keyframe) and over every window of the run (a point counts once per window it is in); and per
      map point: of the points positive in some window, the share culled (in that window or a later one);
    - tracking: per frame while the mover moves, the share of the pose's inlier matches that lie on the mover
      (what `mapping.segmentation` is there to keep out);
    - CPU ms per keyframe of the segmentation step (window building + eq. 5), and local mapping's wall ms;
    - camera ATE (online and final trajectory, SE(3) chordal alignment as `eval.moving_objects`).
    With `mapping.segmentation.enabled` false, only the tracking and ATE lines mean anything.
    """
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sim_dir", help="folder written by `changing-slam simulate slow_mover` (or another with one class -1 mover)")
    parser.add_argument("--config", default=str(REPO / "config" / "sim.yaml"))
    parser.add_argument("--frames", type=int, default=0, help="frames to run (0 = all)")
    parser.add_argument("--movers", action="store_true", help="run the dynamic filter of the config's `dynamic:` section")
    parser.add_argument("--moved-m", type=float, default=0.01,
                        help="a window counts as 'the mover moves' when it moved this far between its first and last keyframe")
    parser.add_argument("--detail", action="store_true", help="per window while the mover moves: its points by label")
    args = parser.parse_args()

    from changing_slam_ros.commands.run import system_config_from_mapping
    from changing_slam_ros.config import load_yaml, section
    from changing_slam_ros.core.dynamic.dynamic_filter import DynamicConfig, DynamicFilter
    from changing_slam_ros.core.system import SlamSystem
    from changing_slam_ros.core.slam.tracking import TrackingState
    from changing_slam_ros.io.dataset import open_dataset
    from changing_slam_ros.io.dataset_config import settings_from_mapping

    sim_dir = Path(args.sim_dir)
    data = load_yaml(Path(args.config))
    source = open_dataset(str(sim_dir), settings_from_mapping(data, args.config))
    filt = DynamicFilter(section(DynamicConfig, data.get("dynamic"), f"{args.config}: dynamic")) if args.movers else None
    system = SlamSystem(system_config_from_mapping(data, args.config), dynamic_filter=filt)
    movers = read_sim_movers(sim_dir)
    if len(movers) > 1:
        raise SystemExit(f"{sim_dir}/objects.json: expected at most one moving object of class -1, found {len(movers)}")
    if not movers:  # a control: a still stand-in, so that every flag counts as a false one
        doc_stamps = np.array(json.loads((sim_dir / "objects.json").read_text())["stamps_ns"], dtype=np.int64)
        poses = np.repeat(np.eye(4)[None], len(doc_stamps), axis=0)
        movers = [ObjectTruth("none", -1, -999, doc_stamps, poses)]
    truth = movers[0]
    moving_gt = truth.moving_frames()
    masks = sorted((sim_dir / "masks").glob("*.png"))
    frame_of_stamp = {int(s): i for i, s in enumerate(truth.stamps_ns)}

    def frame_index(stamp_ns: int) -> int:
        k = frame_of_stamp.get(int(stamp_ns))
        return int(np.argmin(np.abs(truth.stamps_ns - stamp_ns))) if k is None else k  # nearest when rounded

    def mask_of(stamp_ns: int) -> np.ndarray:
        return cv2.imread(str(masks[frame_index(stamp_ns)]), cv2.IMREAD_UNCHANGED)

    # Wrap the step to read the window's keypoints before it culls them.
    counts = {"moving": np.zeros(3, int), "all": np.zeros(3, int)}  # TP, FP, FN
    counts_rest = np.zeros(2, int)  # mover points seen only while it rested: flagged, all
    ever_positive: set[int] = set()  # point level: ids positive in some window; ids culled; ids flagged while negative
    culled: set[int] = set()
    culled_negative: set[int] = set()
    seg_ms: list[float] = []
    windows = {"n": 0, "targets": 0, "still": 0, "vetoed": 0}
    real = local_mapping.segment_keyframe_window

    def wrapped(slam_map, kf_id, cfg):  # type: ignore[no-untyped-def]
        from changing_slam_ros.core.movers.keyframe_segmentation import window_keyframes

        kf_ids = window_keyframes(slam_map, kf_id, cfg.window_keyframes)
        before = {k: slam_map.keyframes[k].point_ids.copy() for k in kf_ids}
        res = real(slam_map, kf_id, cfg)
        if res is None:
            return res
        seg_ms.append(res.ms)
        windows["n"] += 1
        windows["targets"] += res.n_targets
        windows["still"] += res.n_still_targets
        windows["vetoed"] += int(not res.trusted)
        m = len(res.point_ids)
        on_mover = np.zeros(m, bool)
        n_obs = np.zeros(m, int)
        first_seen = np.full(m, -1)  # frame index of the point's oldest and newest window measurement
        last_seen = np.full(m, -1)
        located = np.zeros(m, bool)
        for k in reversed(kf_ids):  # newest observation first
            kf = slam_map.keyframes[k]
            ids = before[k]
            rows = np.flatnonzero(ids >= 0)
            col = np.searchsorted(res.point_ids, ids[rows])
            hit = (col < m) & (res.point_ids[np.minimum(col, m - 1)] == ids[rows])
            rows, col = rows[hit], col[hit]
            measured = (kf.depths_m[rows] > 0) & (kf.depths_m[rows] <= cfg.max_depth_m)
            rows, col = rows[measured], col[measured]
            n_obs[col] += 1
            f = frame_index(kf.stamp_ns)
            last_seen[col] = np.where(last_seen[col] < 0, f, last_seen[col])
            first_seen[col] = f
            new = ~located[col]
            rows, col = rows[new], col[new]
            mask = mask_of(kf.stamp_ns)
            px = kf.keypoints_px[rows]
            c = np.clip(np.rint(px[:, 0]).astype(int), 0, mask.shape[1] - 1)
            r = np.clip(np.rint(px[:, 1]).astype(int), 0, mask.shape[0] - 1)
            on_mover[col] = mask[r, c] == truth.mask_id
            located[col] = True
        # Positive: on the mover, and the mover moved > --moved-m between the point's first and last
        # measurement in the window (a point on the box seen only while it rests is a correct static point).
        seen = first_seen >= 0
        travel = np.zeros(m)
        travel[seen] = np.linalg.norm(truth.T_world_obj[last_seen[seen], :3, 3] - truth.T_world_obj[first_seen[seen], :3, 3], axis=1)
        positive = on_mover & (travel > args.moved_m)
        flagged = res.labels > 0 if res.trusted else np.zeros(m, bool)
        tally = np.array([np.sum(flagged & positive), np.sum(flagged & ~positive), np.sum(~flagged & positive)])
        first, last = (frame_index(slam_map.keyframes[k].stamp_ns) for k in (kf_ids[0], kf_ids[-1]))
        moved = np.linalg.norm(truth.T_world_obj[last, :3, 3] - truth.T_world_obj[first, :3, 3]) > args.moved_m
        counts["all"] += tally
        ever_positive.update(res.point_ids[positive].tolist())
        culled.update(res.point_ids[flagged].tolist())
        culled_negative.update(res.point_ids[flagged & ~positive].tolist())
        counts_rest[:] += [np.sum(flagged & on_mover & ~positive), int(np.sum(on_mover & ~positive))]
        if moved:
            counts["moving"] += tally
            if args.detail:
                lab = res.labels[positive]
                print(f"    kf {kf_id}: window {res.window_kf_ids}, {res.n_points} points, {int(on_mover.sum())} on the mover, "
                      f"{int(positive.sum())} of them moved while seen: static {int(np.sum(lab == 0))}, unassigned "
                      f"{int(np.sum(lab < 0))}, target {int(np.sum(lab > 0))}; off the mover flagged "
                      f"{int(np.sum(flagged & ~on_mover))}; measurements of the moved points "
                      f"{np.bincount(n_obs[positive], minlength=6)[2:].tolist()} (2..)")
        return res

    local_mapping.segment_keyframe_window = wrapped  # type: ignore[assignment]
    n = min(args.frames or len(source), len(source))
    share: list[float] = []
    for k, rgbd in enumerate(source):
        if k >= n:
            break
        out = system.process(rgbd, None)
        frame = system.tracker.last_frame
        if moving_gt[k] and out.state == TrackingState.OK and frame is not None:
            inl = frame.point_ids >= 0
            inl &= ~frame.outliers
            mask = mask_of(rgbd.stamp_ns)
            px = frame.features.keypoints_px[inl]
            c = np.clip(np.rint(px[:, 0]).astype(int), 0, mask.shape[1] - 1)
            r = np.clip(np.rint(px[:, 1]).astype(int), 0, mask.shape[0] - 1)
            share.append(float(np.mean(mask[r, c] == truth.mask_id)) if len(px) else 0.0)
    local_mapping.segment_keyframe_window = real  # type: ignore[assignment]

    kfs = len(system.timings_ms.get("local_mapping_per_keyframe", []))
    print(f"{sim_dir.name}: {n} frames, {system.n_tracked()} tracked, {kfs} keyframes")
    print(f"  mover points seen only while it rested (correct static points, counted as negatives): "
          f"{counts_rest[0]} of {counts_rest[1]} flagged")
    for name, (tp, fp, fn) in counts.items():
        label = "windows while the mover moves" if name == "moving" else "all windows"
        print(f"  moving map points, {label}: precision {tp / max(tp + fp, 1):.3f} recall {tp / max(tp + fn, 1):.3f} "
              f"(TP {tp}, FP {fp}, FN {fn})")
    tp_ids = len(ever_positive & culled)
    print(f"  point level: {len(ever_positive)} map points moved with the mover while measured in a window, "
          f"{tp_ids} of them culled (recall {tp_ids / max(len(ever_positive), 1):.3f}); culled {len(culled)} in all, "
          f"{len(culled_negative - ever_positive)} never positive (precision {tp_ids / max(len(culled), 1):.3f})")
    print(f"  windows segmented {windows['n']}, targets {windows['targets']} (culled unless vetoed), targets that did not "
          f"move {windows['still']} (kept), vetoed windows {windows['vetoed']}")
    if seg_ms:
        a = np.array(seg_ms)
        print(f"  segmentation step CPU ms per keyframe: median {np.median(a):.0f}, p90 {np.percentile(a, 90):.0f}, max {a.max():.0f}")
    lm = np.array(system.timings_ms.get("local_mapping_per_keyframe", [0.0]))
    print(f"  local mapping wall ms per keyframe: median {np.median(lm):.0f}, p90 {np.percentile(lm, 90):.0f}")
    if share:
        s = np.array(share)
        print(f"  tracking inliers on the mover while it moves: mean {100 * s.mean():.1f} %, p90 {100 * np.percentile(s, 90):.1f} % "
              f"({len(s)} frames)")
    gt = source.groundtruth
    online = camera_alignment(gt, system.online_trajectory())[1]
    final = camera_alignment(gt, system.final_trajectory())[1]
    print(f"  camera ATE: online {100 * online:.3f} cm, final {100 * final:.3f} cm")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
