"""What the SLAM system keeps per frame: the sample looped with its stamps moved on, allocation sites by growth.

    .venv/bin/python bench/memory_per_frame.py [--source bags/sim_walking_changing.mcap] [--config sim]
        [--warm-up 5] [--passes 3] [--top 25] [--detections model|oracle|none] [--localize]

Builds `SlamSystem` as `changing-slam run` does (config, dynamic filter, object layer, loop closing) and feeds
the source's frames `--warm-up` times, then `--passes` times more, counted (each pass's stamps moved on by the
source's length, frame indices counting on, detections computed once and reused), all of it under `tracemalloc`
(what the counted passes free of the warm-up's allocations counts too). After each pass the map's size is
printed; at the end the allocation sites (file:line) that grew over the counted passes, with their bytes per
counted frame, largest first, and the total. The map keeps changing a little in every pass (keyframes made and
culled, arrays that double), which blurs that total; `--localize` switches to localisation after the warm-up
(`Mode.LOCALIZATION`: the map is only read), so that only what tracking keeps per frame is left. Once the map
has stopped growing, what is left is what the system keeps per frame. Prints figures, asserts nothing.
"""

from __future__ import annotations

import argparse
import dataclasses
import gc
import sys
import tracemalloc
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]


def build(source_path: str, config: str, detections: str) -> tuple[Any, list[Any], list[Any]]:
    """The system, the source's frames and each frame's detections (as `commands/run.py` builds them)."""
    from changing_slam_ros.commands import run as run_cmd
    from changing_slam_ros.commands.dynamic_options import dynamic_setup
    from changing_slam_ros.commands.objects_options import object_layer_setup
    from changing_slam_ros.config import load_config
    from changing_slam_ros.core.system import SlamSystem
    from changing_slam_ros.io.dataset import open_dataset
    from changing_slam_ros.io.dataset_config import settings_from_mapping

    parser = argparse.ArgumentParser()
    run_cmd.add_arguments(parser)
    args = parser.parse_args([source_path, "--out", "/dev/null", "--config", config, "--detections", detections])
    data, where = load_config(config)
    system_config = run_cmd.system_config_from_mapping(data, where)
    closing = run_cmd._loop_closing(data, where)
    dynamic = dynamic_setup(args, data, where)
    objects = object_layer_setup(args, data, where)
    system = SlamSystem(system_config, loop_closer=closing, keyframe_index=closing, dynamic_filter=dynamic.filter,
                        object_layer=objects)  # fmt: skip
    frames = list(open_dataset(source_path, settings_from_mapping(data, where)))
    dets = [dynamic.detections_for(f) for f in frames]
    return system, frames, dets


def feed(system: Any, frames: list[Any], dets: list[Any], pass_index: int) -> None:
    """One pass of the frames, stamps moved on by `pass_index` source lengths, indices counting on."""
    step = frames[1].stamp_ns - frames[0].stamp_ns if len(frames) > 1 else 0
    span = frames[-1].stamp_ns - frames[0].stamp_ns + step
    n = len(frames)
    for i, (f, d) in enumerate(zip(frames, dets, strict=True)):
        system.process(dataclasses.replace(f, stamp_ns=f.stamp_ns + pass_index * span, index=pass_index * n + i), d)


def map_size(system: Any) -> str:
    atlas = system.atlas
    pts = sum(int((~m.points.bad[: m.points.size]).sum()) for m in atlas.maps)
    return f"{atlas.n_keyframes} keyframes, {pts} points in {len(atlas.maps)} maps"


def _site(frame: Any) -> str:
    where = Path(frame.filename)
    try:
        where = where.relative_to(REPO)
    except ValueError:
        pass
    return f"{where}:{frame.lineno}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--source", default=str(REPO / "bags/sim_walking_changing.mcap"))
    ap.add_argument("--config", default="sim")
    ap.add_argument("--detections", default="model", choices=("model", "oracle", "none"))
    ap.add_argument("--warm-up", type=int, default=5, help="passes before the counted ones (the map grows meanwhile)")
    ap.add_argument("--passes", type=int, default=3, help="passes counted after the warm-up")
    ap.add_argument("--top", type=int, default=25, help="allocation sites listed")
    ap.add_argument("--depth", type=int, default=1, help="traceback frames per allocation: > 1 groups by the whole "
                    "traceback and names the innermost frame of this package too")
    ap.add_argument("--localize", action="store_true", help="localisation only after the warm-up (the map is read)")
    args = ap.parse_args(argv)

    tracemalloc.start(args.depth)
    system, frames, dets = build(args.source, args.config, args.detections)
    n = len(frames)
    for p in range(args.warm_up):
        feed(system, frames, dets, p)
        print(f"warm-up pass {p + 1}: {map_size(system)}", flush=True)
    if args.localize:
        from changing_slam_ros.core.slam.localization import Mode

        system.set_mode(Mode.LOCALIZATION)
    gc.collect()
    first = tracemalloc.take_snapshot()
    for p in range(args.warm_up, args.warm_up + args.passes):
        feed(system, frames, dets, p)
        gc.collect()
        traced, _ = tracemalloc.get_traced_memory()
        print(f"counted pass {p - args.warm_up + 1}: {map_size(system)}; traced {traced / 1e6:.2f} MB", flush=True)
    last = tracemalloc.take_snapshot()
    tracemalloc.stop()
    n_traced = n * args.passes
    stats = last.compare_to(first, "lineno" if args.depth == 1 else "traceback")
    stats.sort(key=lambda s: -s.size_diff)
    total = sum(s.size_diff for s in stats)
    print(f"\n{n_traced} counted frames; growth {total / 1e6:.3f} MB = {total / n_traced:.0f} bytes per frame")
    print(f"{'bytes/frame':>11} {'blocks/frame':>12}  site")
    for s in stats[: args.top]:
        tb = list(s.traceback)[::-1]  # innermost first
        ours = [f for f in tb if "changing_slam_ros" in f.filename]
        via = f" <- {_site(ours[0])}" if ours and ours[0] is not tb[0] else ""
        print(f"{s.size_diff / n_traced:11.1f} {s.count_diff / n_traced:12.2f}  {_site(tb[0])}{via}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
