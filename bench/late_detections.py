"""The graph's real-time detection cadence, replayed offline and deterministically: camera ATE per carry setting.

At 1x the detection node cannot keep up with 30 Hz tracking: it takes the newest image when it is free (~10 Hz on
two cores), and its boxes reach tracking ~0.1-0.2 s after the image. Tracking does not wait: a frame without its
own detections uses the newest earlier ones carried forward (`core.late_detections`). This bench runs the offline
system (`changing-slam run`'s SlamSystem, the shipped config) on a bag with exactly that cadence: the detector's
boxes of frame j (j = 0, EVERY, 2 EVERY, ...) become usable at frame j + DELAY, and every frame uses the newest
usable set carried forward with the setting under test. Unlike a 1x graph run it is repeatable (no scheduling,
no dropped frames), so carry settings can be compared on the same footing; the row "every frame, no delay" is
the offline run itself. Prints a table, never asserts.

    nice .venv/bin/python bench/late_detections.py /tmp/rt/wxyz30s.mcap --config sim \\
        --cadences 3:4 3:3 2:4 4:5 3:5 --settings grow1 grow0.5 grow0.5+extrapolate

A setting is `grow<G>` (grow_widths_per_s G) with `+extrapolate` to move boxes on at their edges' velocity.
Detections are computed once per bag (every frame) and reused by every row.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from changing_slam_ros.commands import run as run_command  # noqa: E402
from changing_slam_ros.commands.dynamic_options import dynamic_setup  # noqa: E402
from changing_slam_ros.commands.objects_options import object_layer_setup  # noqa: E402
from changing_slam_ros.core.detector import Detection, DetectionSet  # noqa: E402
from changing_slam_ros.core.late_detections import CarryConfig, carried_forward  # noqa: E402
from changing_slam_ros.eval.ate import ate  # noqa: E402
from changing_slam_ros.io.dataset import open_dataset  # noqa: E402
from changing_slam_ros.io.dataset_config import settings_from_mapping  # noqa: E402


def parse_setting(text: str) -> CarryConfig:
    """'grow0.5+extrapolate' -> CarryConfig(grow_widths_per_s=0.5, extrapolate=True)."""
    parts = text.split("+")
    if not parts[0].startswith("grow"):
        raise SystemExit(f"--settings {text}: expected grow<G>[+extrapolate], e.g. grow0.5+extrapolate")
    try:
        grow = float(parts[0][4:])
    except ValueError as err:
        raise SystemExit(f"--settings {text}: {parts[0][4:]!r} is not a number") from err
    unknown = set(parts[1:]) - {"extrapolate"}
    if unknown:
        raise SystemExit(f"--settings {text}: unknown option(s) {sorted(unknown)}; only +extrapolate")
    return CarryConfig(grow_widths_per_s=grow, extrapolate="extrapolate" in parts[1:])


def parse_cadence(text: str) -> tuple[int, int]:
    try:
        every, delay = (int(v) for v in text.split(":"))
    except ValueError as err:
        raise SystemExit(f"--cadences {text}: expected EVERY:DELAY in frames, e.g. 3:4") from err
    if every < 1 or delay < 0:
        raise SystemExit(f"--cadences {text}: EVERY >= 1 and DELAY >= 0")
    return every, delay


def run_once(args: argparse.Namespace, frames: list, dets: list[DetectionSet], every: int, delay: int,
             carry: CarryConfig | None) -> tuple[float, int]:  # fmt: skip
    """ATE (m) and frames tracked with this cadence and carry (carry None: every frame its own detections)."""
    data, where = args.config_data, args.config_where
    ns = run_command_args(args.bag, "unused", args.config)  # the run's options; nothing is written
    dyn = dynamic_setup(ns, data, where)
    closing = run_command._loop_closing(data, where)
    system = run_command.SlamSystem(run_command.system_config_from_mapping(data, where), loop_closer=closing,
                                    keyframe_index=closing, dynamic_filter=dyn.filter,
                                    object_layer=object_layer_setup(ns, data, where))  # fmt: skip
    newest: DetectionSet | None = None
    previous: DetectionSet | None = None
    for i, frame in enumerate(frames):
        used: tuple[Detection, ...] | None
        if carry is None:
            used = dets[i].detections
        else:
            j = i - delay
            if j >= 0 and j % every == 0:
                previous, newest = newest, dets[j]
            used = carried_forward(newest, frame.stamp_ns, carry, previous) if newest is not None else None
            if delay == 0 and j >= 0 and j % every == 0:
                used = dets[i].detections  # the frame's own detections, in time
        system.process(frame, used)
    return float(ate(args.groundtruth, system.final_trajectory()).stats.rmse), system.n_tracked()


def run_command_args(bag: str, out: str, config: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    run_command.add_arguments(parser)
    return parser.parse_args([bag, "--out", out, "--config", config, "--quiet"])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bag", help="bag or dataset folder with ground truth")
    parser.add_argument("--config", default="sim", help="config name or file (default sim)")
    parser.add_argument("--cadences", nargs="+", default=["3:4", "3:3", "2:4", "4:5", "3:5"], metavar="EVERY:DELAY",
                        help="detector on every EVERY-th frame, its boxes usable DELAY frames later")
    parser.add_argument("--settings", nargs="+", default=["grow1", "grow0.5", "grow0.5+extrapolate"],
                        help="carry settings, grow<G>[+extrapolate]")
    args = parser.parse_args()
    cadences = [parse_cadence(c) for c in args.cadences]
    settings = {s: parse_setting(s) for s in args.settings}
    path = run_command.find_config(args.config)
    data = run_command.load_yaml(path)
    args.config_data, args.config_where = data, str(path)  # read once, used by every run
    source = open_dataset(args.bag, settings_from_mapping(data, str(path)))
    if source.groundtruth is None:
        raise SystemExit(f"{args.bag}: no ground truth")
    args.groundtruth = source.groundtruth
    frames = list(source)
    dyn = dynamic_setup(run_command_args(args.bag, "unused", args.config), data, str(path))
    if dyn.detector is None:
        raise SystemExit(f"{args.config}: the config's dynamic filter uses no detector")
    t0 = time.perf_counter()
    dets = [dyn.detector.detect(f.rgb, f.stamp_ns) for f in frames]
    print(f"{args.bag}: {len(frames)} frames, detections in {time.perf_counter() - t0:.0f} s", flush=True)
    base, tracked = run_once(args, frames, dets, 1, 0, None)
    print(f"every frame, no delay (offline): ATE {100 * base:.2f} cm, {tracked}/{len(frames)} tracked", flush=True)
    table: dict[str, list[float]] = {s: [] for s in settings}
    for every, delay in cadences:
        for name, carry in settings.items():
            err, tracked = run_once(args, frames, dets, every, delay, carry)
            table[name].append(err)
            lost = f", {len(frames) - tracked} lost" if tracked < len(frames) else ""
            print(f"  every {every} delay {delay}  {name:22s} ATE {100 * err:.2f} cm (x{err / base:.2f}){lost}", flush=True)
    print("\n| setting | " + " | ".join(f"{e}:{d}" for e, d in cadences) + " | mean cm (x offline) |")
    print("|---|" + "---|" * (len(cadences) + 1))
    for name, errs in table.items():
        mean = statistics.fmean(errs)
        print(f"| {name} | " + " | ".join(f"{100 * e:.2f}" for e in errs) + f" | {100 * mean:.2f} (x{mean / base:.2f}) |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
