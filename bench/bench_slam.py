"""Speed and memory of the RGB-D SLAM core: prints figures, asserts nothing.

    .venv/bin/python bench/bench_slam.py [SOURCE] [--config NAME] [--max-frames N] [--no-loop] [--triangulation on|off]

Prints the median / p90 tracking time per frame (feature extraction + tracking, as ORB-SLAM
reports it), local mapping per keyframe, the whole-run rate in frames per second (frames decoded
on a reader thread, as `changing-slam run` does), the final ATE when ground truth exists, and the
resident memory added per keyframe (RSS growth over the run / keyframes).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from changing_slam_ros.commands.frame_pipeline import FramePipeline  # noqa: E402
from changing_slam_ros.commands.run import _loop_closing, system_config_from_mapping  # noqa: E402
from changing_slam_ros.config import find_config, load_yaml  # noqa: E402
from changing_slam_ros.core.system import SlamSystem  # noqa: E402
from changing_slam_ros.io.dataset import open_dataset  # noqa: E402
from changing_slam_ros.io.dataset_config import settings_from_mapping  # noqa: E402


def rss_mib() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source", nargs="?", default=str(REPO.parent / "shared/data/7scenes_redkitchen"))
    parser.add_argument("--config", default="7scenes")
    parser.add_argument("--max-frames", type=int, default=0)
    parser.add_argument("--no-loop", action="store_true")
    parser.add_argument("--triangulation", choices=("on", "off"), help="override mapping.triangulation.enabled")
    args = parser.parse_args()

    path = find_config(args.config)
    data = load_yaml(path)
    if args.triangulation is not None:
        mapping = data.setdefault("mapping", None) or {}
        mapping["triangulation"] = {**(mapping.get("triangulation") or {}), "enabled": args.triangulation == "on"}
        data["mapping"] = mapping
    source = open_dataset(args.source, settings_from_mapping(data, str(path)))
    closing = None if args.no_loop else _loop_closing(data, str(path))
    system = SlamSystem(system_config_from_mapping(data, str(path)), loop_closer=closing, keyframe_index=closing)
    n = len(source) if not args.max_frames else min(args.max_frames, len(source))
    rss0 = rss_mib()
    t0 = time.perf_counter()
    with FramePipeline(source, n, lambda frame: None, overlap=False) as frames:
        for frame, _ in frames:
            system.process(frame)
    wall = time.perf_counter() - t0
    rss1 = rss_mib()
    t = system.timing_summary()
    n_kf = max(system.atlas.n_keyframes, 1)
    print(f"source              {args.source} ({n} frames, config {args.config})")
    print(f"frames tracked      {system.n_tracked()}/{len(system.records)}, keyframes {system.atlas.n_keyframes}, loops {system.n_loops}")
    print(f"tracking ms         median {t['tracking']['p50']:.1f}  p90 {t['tracking']['p90']:.1f}  (features median {t['features']['p50']:.1f})")
    if "local_mapping_per_keyframe" in t:
        lm = t["local_mapping_per_keyframe"]
        print(f"local mapping ms/kf median {lm['p50']:.1f}  p90 {lm['p90']:.1f}")
    print(f"loop closing ms     mean per frame {t['loop_closing']['mean']:.1f}  max {t['loop_closing']['max']:.1f}")
    print(f"whole run           {wall:.1f} s, {len(system.records) / wall:.1f} fps")
    print(f"resident memory     {rss1:.0f} MiB at end, +{rss1 - rss0:.0f} MiB over the run, {(rss1 - rss0) / n_kf * 1024:.0f} KiB per keyframe")
    made = sum(len(c) for chunks in system.mapper.triangulated.values() for c in chunks)
    print(f"triangulated points made {made}, alive at the end {system.mapper.n_triangulated_alive()}")
    print(f"maps                {len(system.atlas.live_maps())} holding keyframes of {len(system.atlas.maps)}, merges {len(system.merges)}")
    gt = source.groundtruth
    if gt is not None and system.n_tracked() >= 3:
        from changing_slam_ros.eval.ate import ate

        print(f"ATE RMSE            final {ate(gt, system.final_trajectory()).stats.rmse * 100:.2f} cm, "
              f"online {ate(gt, system.online_trajectory()).stats.rmse * 100:.2f} cm")
    return 0


if __name__ == "__main__":
    sys.exit(main())
