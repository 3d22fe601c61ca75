"""`changing-slam simulate SCENARIO --out DIR`: render a dynamic / changing scenario with ground truth."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from changing_slam_ros.errors import SimError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scenario", nargs="?", help="scenario name (see --list)")
    parser.add_argument("--list", action="store_true", help="list the scenarios and exit")
    parser.add_argument("--control", action="store_true",
                        help="render the scenario's control (SCENARIO_control: the same scene without movers)")
    parser.add_argument("--out", type=Path, help="output folder (TUM layout plus ground truth)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--frames", type=int, default=None, help="render only the first N frames")
    parser.add_argument("--fps", type=float, default=None, help="frame rate (default: the scenario's)")
    parser.add_argument("--width", type=int, default=640, help="image width (default 640)")
    parser.add_argument("--height", type=int, default=480, help="image height (default 480)")
    parser.add_argument("--shadows", action="store_true", help="cast shadows (about 4x slower)")
    parser.add_argument("--sensor", choices=("scenario", "exact", "kinect", "realsense"), default="scenario",
                        help="sensor model: the scenario's own (default; exact for the hand-made scenarios), "
                             "exact, or Kinect- / RealSense-like noise, holes, blur and exposure changes")
    parser.add_argument("--mcap", type=Path, default=None,
                        help="also write an mcap (Image, CameraInfo, ground-truth PoseStamped) to this file")
    parser.add_argument("--jpeg-quality", type=int, default=90, help="JPEG quality of the mcap's colour (default 90)")
    parser.add_argument("--raw-mcap", action="store_true",
                        help="mcap with raw rgb8 / 32FC1 images instead of JPEG / 16-bit PNG")
    parser.add_argument("--contact-sheet", type=Path, default=None, metavar="PNG",
                        help="write one labelled frame of every scenario to this PNG and exit")
    parser.add_argument("--quiet", action="store_true", help="no progress output")


def main(args: argparse.Namespace) -> int:
    from changing_slam_ros.sim.scenarios import SCENARIOS, build_scenario

    if args.list:
        width = max(len(n) for n in SCENARIOS)
        for name, info in SCENARIOS.items():
            print(f"{name:<{width}}  {info.description}")
        return 0
    if args.contact_sheet is not None:
        from changing_slam_ros.sim.contact_sheet import write_contact_sheet

        write_contact_sheet(args.contact_sheet, args.seed)
        print(f"contact sheet: {args.contact_sheet}")
        return 0
    if not args.scenario:
        raise SimError("no scenario given; run `changing-slam simulate --list` to see them")
    if args.out is None:
        raise SimError("--out DIR is required")
    from changing_slam_ros.sim.sequence import RenderOptions, simulate

    name = args.scenario
    if args.control and not name.endswith("_control"):
        name = f"{name}_control"
        if name not in SCENARIOS:
            raise SimError(f"--control: scenario {args.scenario!r} has no control ({name} is not a scenario)")
    scenario = build_scenario(name, args.seed)
    from changing_slam_ros.sim.sensor_model import preset

    sensor = None if args.sensor == "scenario" else preset(args.sensor)
    options = RenderOptions(width=args.width, height=args.height, frames=args.frames, fps=args.fps,
                            shadows=args.shadows, sensor=sensor)

    def progress(done: int, total: int) -> None:
        if not args.quiet and (done == total or done % 25 == 0):
            print(f"\r{scenario.name}: {done}/{total} frames", end="" if done < total else "\n",
                  file=sys.stderr, flush=True)

    result = simulate(scenario, args.out, options, args.seed, progress)
    print(f"{scenario.name}: {result.n_frames} frames {args.width}x{args.height} -> {result.out_dir} "
          f"(render {result.render_ms_per_frame:.1f} ms/frame, total {result.total_s:.1f} s)")
    if args.mcap is not None:
        from changing_slam_ros.sim.bag import write_sim_mcap

        if not 1 <= args.jpeg_quality <= 100:
            raise SimError(f"--jpeg-quality {args.jpeg_quality}: expected 1..100")
        write_sim_mcap(args.out, args.mcap, compress=not args.raw_mcap, jpeg_quality=args.jpeg_quality)
        print(f"mcap: {args.mcap}")
    return 0
