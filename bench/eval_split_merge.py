"""Atlas map merge through the split graph's sides vs the offline runner (prints figures, never asserts).

7-Scenes redkitchen frames 0-319 then 400-699 (tracking is lost at the jump, a new map starts, the camera later
revisits the first map), config `7scenes` with `tracking.lost_frames_new_map` 5: the three sides of the split
graph chained in the lossless order (`nodes.split_chains.ChainedGraph`: loop closing finds the merge, the map
owner applies it, the replicas take the merged map) and `SlamSystem` offline, frame by frame.

With `--delays N [N ...]`, the same sequence also in real-time order, once per delay (`DelayedChain` with its
loop side and provisional points: every owner update, the merge's included, reaches tracking and loop closing N
frames after the owner started it, and tracking never waits), so that keyframes of the merged-away map are in
flight when the merge is applied: what each side moved into the merged map, whether the owner mapped every
packet once, and the ATE.

    .venv/bin/python bench/eval_split_merge.py [--no-merge] [--delays 3 10 30]
"""

from __future__ import annotations

import argparse
import copy
import time

import numpy as np

from changing_slam_ros.eval.ate import ate
from changing_slam_ros.io.dataset import open_dataset
from changing_slam_ros.nodes.slam_backend import BackendConfig, build_backend, load_backend_config
from changing_slam_ros.nodes.split_chains import ChainedGraph, DelayedChain

REDKITCHEN = "../shared/data/7scenes_redkitchen"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=REDKITCHEN)
    ap.add_argument("--no-merge", action="store_true", help="mapping.merge.enabled false (two maps at the end)")
    ap.add_argument("--delays", type=int, nargs="*", default=[], help="also in real-time order with these lags (frames)")
    args = ap.parse_args()
    base = load_backend_config("7scenes")
    data = copy.deepcopy(base.data)
    data.setdefault("tracking", {})["lost_frames_new_map"] = 5
    data.setdefault("mapping", {}).setdefault("merge", {})["enabled"] = not args.no_merge
    cfg = BackendConfig(data, base.where)
    source = open_dataset(args.data, "7scenes")
    chained, offline = ChainedGraph.build(cfg), build_backend(cfg).system
    delayed = {d: DelayedChain.build(cfg, d, provisional=True, loop=True) for d in args.delays}
    delayed_merge_frame = {d: -1 for d in args.delays}
    merge_frame, n, t_split, t_off = -1, 0, 0.0, 0.0
    for i, rgbd in enumerate(source):
        if i >= 700:
            break
        if 320 <= i < 400:
            continue
        t0 = time.process_time()
        chained.process(rgbd)
        t1 = time.process_time()
        offline.process(rgbd)
        t_split += t1 - t0
        t_off += time.process_time() - t1
        n += 1
        if merge_frame < 0 and chained.tracking.n_merges:
            merge_frame = i
        for d, g in delayed.items():
            g.process(rgbd)
            if delayed_merge_frame[d] < 0 and g.tracking.n_merges:
                delayed_merge_frame[d] = i
    tracking = chained.tracking.system
    a, b = tracking.final_trajectory(), offline.final_trajectory()
    same = np.array_equal(a.stamps_s, b.stamps_s) and np.array_equal(np.array(a.poses()), np.array(b.poses()))
    print(f"frames {n}; merge found at dataset frame {merge_frame} (split), offline merges {len(offline.merges)}")
    for name, atlas in (("owner", chained.owner.atlas), ("tracking", tracking.atlas), ("loop", chained.loop.atlas),
                        ("offline", offline.atlas)):  # fmt: skip
        print(f"  {name:9s} live maps {[m.id for m in atlas.live_maps()]}, merged_into {atlas.merged_into}, "
              f"keyframes {atlas.n_keyframes}")
    if chained.owner.merges:
        r = chained.owner.merges[0]
        print(f"  owner's merge: map {r.from_map_id} -> {r.into_map_id}, {len(r.moved_keyframes)} keyframes moved, "
              f"{r.n_fused} points fused")
    print(f"split final trajectory {len(a)} poses, ATE {ate(source.groundtruth, a).stats.rmse * 100:.2f} cm; "
          f"offline {len(b)} poses, ATE {ate(source.groundtruth, b).stats.rmse * 100:.2f} cm; identical: {same}")
    print(f"CPU s (process time, noisy on a shared machine): split chain {t_split:.1f}, offline {t_off:.1f}")
    for d, g in delayed.items():
        g.finish()
        t = g.tracking.system
        traj = t.final_trajectory()
        live = [[m.id for m in atlas.live_maps()] for atlas in (g.owner.atlas, t.atlas, g.loop.atlas)]
        once = g.sent == g.mapped and len(set(g.sent)) == len(g.sent)
        print(f"real time, lag {d} frames: merges applied {len(g.owner.merges)} (tracking took it at dataset frame "
              f"{delayed_merge_frame[d]}), live maps owner/tracking/loop {live}; in flight at the merge: tracking "
              f"{g.tracking.n_moved_keyframes} keyframes + {g.tracking.n_moved_provisional} provisional points moved, "
              f"loop side {g.loop.n_moved_keyframes} keyframes, owner {g.owner.log.n_moved} late packets moved; "
              f"{len(g.sent)} packets sent, each mapped once in order: {once}; {len(traj)} poses, "
              f"ATE {ate(source.groundtruth, traj).stats.rmse * 100:.2f} cm")  # fmt: skip


if __name__ == "__main__":
    main()
