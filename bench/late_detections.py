"""The graph's real-time detection cadence, replayed offline and deterministically: camera ATE per carry setting.

At 1x the detection node cannot keep up with 30 Hz tracking: it takes the newest image when it is free (~10 Hz on
two cores), and its boxes reach tracking ~0.1-0.2 s after the image. Tracking does not wait: a frame without its
own detections uses the newest earlier ones carried forward (`core.dynamic.late_detections`). This bench runs the offline
system (`changing-slam run`'s SlamSystem, the shipped config) on a bag with exactly that cadence: the detector's
boxes of frame j (j = 0, EVERY, 2 EVERY, ...) become usable at frame j + DELAY, and every frame uses the newest
usable set carried forward with the setting under test. Repeatable, unlike a 1x graph run. Prints a table,
never asserts.

    nice .venv/bin/python bench/late_detections.py /tmp/rt/wxyz30s.mcap --config sim \\
        --cadences 3:4 3:3 2:4 4:5 3:5 --settings grow1 grow0.5 grow0.5+extrapolate

The rows and the method: `main`.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from changing_slam_ros.commands import run as run_command  # noqa: E402
from changing_slam_ros.commands.dynamic_options import dynamic_setup  # noqa: E402
from changing_slam_ros.commands.objects_options import object_layer_setup  # noqa: E402
from changing_slam_ros.core.dynamic.box_flow import FlowImage  # noqa: E402
from changing_slam_ros.core.dynamic.detector import Detection, DetectionSet  # noqa: E402
from changing_slam_ros.core.dynamic.deferred_refinement import RefinementConfig  # noqa: E402
from changing_slam_ros.core.dynamic.late_detections import CarryConfig, carried_forward  # noqa: E402
from changing_slam_ros.eval.ate import ate  # noqa: E402
from changing_slam_ros.io.dataset import open_dataset  # noqa: E402
from changing_slam_ros.io.dataset_config import settings_from_mapping  # noqa: E402


def parse_setting(text: str) -> tuple[CarryConfig, RefinementConfig | None]:
    """'grow0.5+extrapolate' -> CarryConfig(grow_widths_per_s=0.5, extrapolate=True); '+flow0.25' adds
    flow=True, flow_grow_widths_per_s=0.25; '+refine[G]' the deferred refinement (None without it)."""
    parts = text.split("+")
    if not parts[0].startswith("grow"):
        raise SystemExit(f"--settings {text}: expected grow<G>[+extrapolate][+flow<F>][+refine[tracked][G]], e.g. grow0.5+flow0.25")
    cfg = CarryConfig(grow_widths_per_s=_number(text, parts[0][4:]), flow=False)  # +flow<F> switches it on
    refine = None
    for part in parts[1:]:
        if part == "extrapolate":
            cfg = dataclasses.replace(cfg, extrapolate=True)
        elif part == "hull":
            cfg = dataclasses.replace(cfg, flow_hull=True)
        elif part.startswith("flow"):
            cfg = dataclasses.replace(cfg, flow=True, flow_grow_widths_per_s=_number(text, part[4:]))
        elif part.startswith("refine"):
            refine = RefinementConfig(enabled=True, class_ids=cfg.class_ids)
            rest = part[6:]
            if rest.startswith("tracked"):  # in the map as tracked, only frames with matches on a person
                refine, rest = dataclasses.replace(refine, current_map=False), rest[7:]
            if rest:
                refine = dataclasses.replace(refine, interpolated_grow_widths_per_s=_number(text, rest))
        else:
            raise SystemExit(f"--settings {text}: unknown option {part!r}; only +extrapolate, +flow<F>, +hull, +refine[tracked][G]")
    return cfg, refine


def _number(text: str, value: str) -> float:
    try:
        return float(value)
    except ValueError as err:
        raise SystemExit(f"--settings {text}: {value!r} is not a number") from err


def parse_cadence(text: str) -> tuple[int, int, int]:
    """'3:4' -> (every 3, delay 4, phase 0); '3:4:1' -> the detector on frames 1, 4, 7, ... (another run of the same
    cadence: the replays are chaotic, so more runs of one cadence say more than one)."""
    try:
        values = [int(v) for v in text.split(":")]
        every, delay = values[:2]
        phase = values[2] if len(values) == 3 else 0
        if len(values) not in (2, 3):
            raise ValueError(text)
    except ValueError as err:
        raise SystemExit(f"--cadences {text}: expected EVERY:DELAY[:PHASE] in frames, e.g. 3:4") from err
    if every < 1 or delay < 0 or not 0 <= phase < every:
        raise SystemExit(f"--cadences {text}: EVERY >= 1, DELAY >= 0 and 0 <= PHASE < EVERY")
    return every, delay, phase


@dataclasses.dataclass
class RunResult:
    """One replay: final and online ATE (m), frames tracked, CPU ms per carried frame (`carried_forward`) and per
    detection set handed to the refinement, and the refinement's counters (None without it)."""

    ate_m: float
    online_ate_m: float
    tracked: int
    carry_cpu_ms: list[float]
    refine_cpu_ms: list[float]
    refine_stats: object | None


def run_once(args: argparse.Namespace, frames: list, dets: list[DetectionSet], cadence: tuple[int, int, int],
             carry: CarryConfig | None, images: list[FlowImage], refine: RefinementConfig | None = None) -> RunResult:  # fmt: skip
    """One replay with this cadence and carry (carry None: every frame its own detections); `refine`: the deferred
    refinement's settings (None: off). `images`: each frame's grey and depth, for +flow."""
    data, where = args.config_data, args.config_where
    ns = run_command_args(args.bag, "unused", args.config)  # the run's options; nothing is written
    dyn = dynamic_setup(ns, data, where)
    closing = run_command._loop_closing(data, where)
    config = run_command.system_config_from_mapping(data, where)
    if refine is not None:
        config = dataclasses.replace(config, tracking=dataclasses.replace(config.tracking, deferred_refinement=refine))
    system = run_command.SlamSystem(config, loop_closer=closing,
                                    keyframe_index=closing, dynamic_filter=dyn.filter,
                                    object_layer=object_layer_setup(ns, data, where))  # fmt: skip
    every, delay, phase = cadence
    newest: DetectionSet | None = None
    previous: DetectionSet | None = None
    newest_index = -1
    cpu_ms: list[float] = []
    refine_ms: list[float] = []
    for i, frame in enumerate(frames):
        used: tuple[Detection, ...] | None
        if carry is None:
            used = dets[i].detections
        else:
            j = i - delay
            detected = j >= phase and (j - phase) % every == 0
            if detected:
                previous, newest, newest_index = newest, dets[j], j
                if refine is not None:  # the set arrives: the tracked frames it brackets are refined
                    c0 = time.process_time()
                    system.refine_with_detections(dets[j])
                    refine_ms.append(1e3 * (time.process_time() - c0))
            used = None
            if newest is not None:
                pair = (images[newest_index], images[i]) if carry.flow else None
                c0 = time.process_time()
                used = carried_forward(newest, frame.stamp_ns, carry, previous, pair)
                if used is not None:
                    cpu_ms.append(1e3 * (time.process_time() - c0))
            if delay == 0 and detected:
                used = dets[i].detections  # the frame's own detections, in time
        system.process(frame, used)
    system.settle_refinement()  # the end of the run (as the tracking node before it writes trajectory.txt)
    final = float(ate(args.groundtruth, system.final_trajectory()).stats.rmse)
    online = float(ate(args.groundtruth, system.online_trajectory()).stats.rmse)
    stats = None if system.refinement is None else system.refinement.stats
    return RunResult(final, online, system.n_tracked(), cpu_ms, refine_ms, stats)


def run_command_args(bag: str, out: str, config: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    run_command.add_arguments(parser)
    return parser.parse_args([bag, "--out", out, "--config", config, "--quiet"])


def main() -> int:
    """Parse the options, measure, print the table.

    Unlike a 1x graph run it is repeatable (no scheduling, no dropped frames), so carry settings can be compared
    on the same footing; the row "every frame, no delay" is the offline run itself.

    A setting is `grow<G>` (grow_widths_per_s G) with `+extrapolate` to move boxes on at their edges' velocity and
    `+flow<F>` to move them by their image motion between the detections' image and the frame (`core.box_flow`)
    and grow a moved box by F widths/s instead (a box whose motion is not measured: as without +flow), e.g.
    `grow0.5+flow0.25`; `+hull` joins a moved box with where it was before growing; `+refine` (or `+refine<G>`, G the
    interpolated boxes' growth in widths/s, default 0.25) turns `tracking.deferred_refinement` on: each detection set
    is handed to `SlamSystem.refine_with_detections` when it becomes usable, so the frames it brackets with the set
    before get their final pose optimised again without the keypoints in the interpolated person boxes
    (`core.deferred_refinement`), in the map as it is then (`current_map`); `+refinetracked[G]`: only the frames with
    matches on a person, in the map as they were tracked in. Every row prints the final ATE (trajectory.txt's, what the tables compare) and the
    online one. Detections are computed once per bag (every frame) and reused by every row. With +flow the CPU time of
    `carried_forward` per carried frame (`time.process_time`) is printed too; with +refine that of the refinement per
    detection set and its counters.
    """
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bag", help="bag or dataset folder with ground truth")
    parser.add_argument("--config", default="sim", help="config name or file (default sim)")
    parser.add_argument("--cadences", nargs="+", default=["3:4", "3:3", "2:4", "4:5", "3:5"], metavar="EVERY:DELAY[:PHASE]",
                        help="detector on every EVERY-th frame, its boxes usable DELAY frames later")
    parser.add_argument("--settings", nargs="+", default=["grow1", "grow0.5", "grow0.5+extrapolate"],
                        help="carry settings, grow<G>[+extrapolate][+flow<F>[+hull]][+refine[tracked][G]]")
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
    images = [FlowImage.from_rgb(f.stamp_ns, f.rgb, f.depth_m) for f in frames]
    dyn = dynamic_setup(run_command_args(args.bag, "unused", args.config), data, str(path))
    if dyn.detector is None:
        raise SystemExit(f"{args.config}: the config's dynamic filter uses no detector")
    t0 = time.perf_counter()
    dets = [dyn.detector.detect(f.rgb, f.stamp_ns) for f in frames]
    print(f"{args.bag}: {len(frames)} frames, detections in {time.perf_counter() - t0:.0f} s", flush=True)
    offline = run_once(args, frames, dets, (1, 0, 0), None, images)
    base = offline.ate_m
    print(f"every frame, no delay (offline): ATE {100 * base:.2f} cm (online {100 * offline.online_ate_m:.2f}), "
          f"{offline.tracked}/{len(frames)} tracked", flush=True)  # fmt: skip
    table: dict[str, list[RunResult]] = {s: [] for s in settings}
    for every, delay, phase in cadences:
        for name, (carry, refine) in settings.items():
            res = run_once(args, frames, dets, (every, delay, phase), carry, images, refine)
            table[name].append(res)
            lost = f", {len(frames) - res.tracked} lost" if res.tracked < len(frames) else ""
            cpu = ""
            if carry.flow and res.carry_cpu_ms:
                cpu = f", carry CPU {statistics.fmean(res.carry_cpu_ms):.2f} ms/frame (max {max(res.carry_cpu_ms):.1f})"
            if res.refine_stats is not None:
                st = res.refine_stats
                cpu += (f", refine: {st.frames_refined}/{st.frames_optimised}/{st.frames_bracketed} frames refined/optimised/"
                        f"bracketed, {st.matches_dropped} matches dropped, CPU {st.cpu_ms / len(frames):.2f} ms per bag frame "
                        f"({statistics.fmean(res.refine_cpu_ms or [0.0]):.2f} ms per set handed over)")  # fmt: skip
            print(f"  every {every} delay {delay} phase {phase}  {name:22s} ATE {100 * res.ate_m:.2f} cm (x{res.ate_m / base:.2f}), "
                  f"online {100 * res.online_ate_m:.2f}{lost}{cpu}", flush=True)  # fmt: skip
    heads = " | ".join(":".join(str(v) for v in (c if c[2] else c[:2])) for c in cadences)
    print(f"\nfinal ATE cm (online in brackets)\n| setting | {heads} | mean cm (x offline) | online mean |")
    print("|---|" + "---|" * (len(cadences) + 2))
    for name, runs in table.items():
        mean = statistics.fmean(r.ate_m for r in runs)
        online = statistics.fmean(r.online_ate_m for r in runs)
        cells = " | ".join(f"{100 * r.ate_m:.2f} ({100 * r.online_ate_m:.2f})" for r in runs)
        print(f"| {name} | {cells} | {100 * mean:.2f} (x{mean / base:.2f}) | {100 * online:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
