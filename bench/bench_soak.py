"""Soak: `changing-slam graph` on the sample bag looped for N minutes at 1x; node memory and drops over time (prints only).

    .venv/bin/python bench/bench_soak.py [--bag bags/sim_walking_changing.mcap] [--config sim] [--minutes 10]
        [--rate 1] [--sample-s 10] [--warmup-s 60] [--work /tmp/bench_soak]

The graph plays the bag `--loop N` times (N passes covering the minutes; the player shifts each pass by the bag's
duration, so time runs forward), in real time. Every `--sample-s` seconds the resident memory of every node
process is read from outside (`/proc/<pid>/status` VmRSS; a restarted node counts its new process). Printed: per
node the memory after warm-up (the first sample after `--warmup-s`), half way and at the end of playback, the growth
in % (the baseline is the same run's post-warm-up sample; the peak while the graph drains and writes its outputs
after playback is printed apart) and in MiB over each half (a leak grows as much in both; memory
that levels off grows less in the second; with `--work` the samples go to `memory_samples.json` there); drops
per minute in each pass (the bag's colour frames of the pass without a pose in trajectory.txt, by stamp), and the
last pass against the second (the first pass builds the map); and whether the outputs are complete (exit 0,
trajectory, map, semantic map, summary). No timed assert: a shared machine's load moves the drops; memory much
less.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

from bench_graph_cpu import _children, start_graph

REPO = Path(__file__).resolve().parents[1]


def rss_mib(pid: int) -> float | None:
    """Resident memory of `pid` in MiB (VmRSS), or None when it is gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        return None
    return None


def run_soak(bag: str, config: str, passes: int, rate: float, out: Path, sample_s: float,
             timeout_s: float) -> tuple[int, list[tuple[float, dict[str, float]]], list[str]]:  # fmt: skip
    """The graph run: its exit code, the memory samples (seconds since playback began, node -> MiB), its output."""
    argv = [sys.executable, "-m", "changing_slam_ros", "graph", bag, "--out", str(out), "--config", config,
            "--loop", str(passes), "--rate", str(rate), "--timeout", str(timeout_s)]  # fmt: skip
    proc, playing, log, reader = start_graph(argv, REPO)
    samples: list[tuple[float, dict[str, float]]] = []
    t_play: float | None = None
    next_s = 0.0
    while proc.poll() is None:
        if playing.is_set():
            t_play = time.monotonic() if t_play is None else t_play
            now = time.monotonic() - t_play
            if now >= next_s:
                mem = {name: rss_mib(pid) for name, pid in _children(proc.pid).items()}
                samples.append((now, {k: v for k, v in mem.items() if v is not None}))
                next_s += sample_s
        time.sleep(0.2)
    reader.join(5.0)
    return proc.returncode, samples, log


def poses_per_pass(out: Path, bag: str, passes: int) -> tuple[list[int], int, float]:
    """Poses of trajectory.txt in each pass (by stamp: pass k is k pass periods later), the bag's colour frames
    per pass, and the pass's duration in seconds of the bag."""
    from changing_slam_ros.commands.graph import inspect_bag
    from changing_slam_ros.io.bag_messages import BagMessages
    from changing_slam_ros.io.playback import PlaybackOptions, pass_period_ns

    info = inspect_bag(bag)
    with BagMessages(bag) as b:
        period = pass_period_ns(b, PlaybackOptions(loop=True))
        start = b.start_ns
    counts = [0] * passes
    path = out / "trajectory.txt"
    lines = path.read_text().splitlines() if path.is_file() else []
    for ln in lines:
        if ln.startswith("#") or not ln.strip():
            continue
        k = (round(float(ln.split()[0]) * 1e9) - start) // period
        if 0 <= k < passes:
            counts[k] += 1
    return counts, info.colour_frames, period / 1e9


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--bag", default=str(REPO / "bags" / "sim_walking_changing.mcap"))
    parser.add_argument("--config", default="sim")
    parser.add_argument("--minutes", type=float, default=10.0, help="playing time (default 10)")
    parser.add_argument("--rate", type=float, default=1.0)
    parser.add_argument("--sample-s", type=float, default=10.0, help="seconds between memory samples")
    parser.add_argument("--warmup-s", type=float, default=60.0, help="memory baseline: first sample after this")
    parser.add_argument("--work", default="", help="output folder (default: a temp dir)")
    a = parser.parse_args()
    bag = str(Path(a.bag).resolve())
    from changing_slam_ros.commands.graph import inspect_bag

    pass_s = inspect_bag(bag).duration_s / a.rate
    passes = max(2, math.ceil(a.minutes * 60.0 / pass_s))
    out = Path(a.work or tempfile.mkdtemp(prefix="bench_soak_")) / "graph"
    print(f"soak: {bag}, {passes} passes of {pass_s:.1f} s at {a.rate}x ({passes * pass_s / 60:.1f} min), "
          f"memory every {a.sample_s:.0f} s, warm-up {a.warmup_s:.0f} s; out {out}", flush=True)  # fmt: skip
    t0 = time.monotonic()
    code, samples, log = run_soak(bag, a.config, passes, a.rate, out, a.sample_s, passes * pass_s * 3 + 600)
    print(f"graph exit {code} after {time.monotonic() - t0:.0f} s; last lines:\n  " + "  ".join(log[-4:]), flush=True)

    # Growth is read over the replay: once playback ends the nodes drain their queues and write the run's outputs
    # (the map file, the final optimisation), a peak that is not growth; it is printed on its own.
    t_stop = passes * pass_s
    playing = [(t, m) for t, m in samples if t <= t_stop] or samples
    after = [m for t, m in samples if t > t_stop]
    warm = next((m for t, m in playing if t >= a.warmup_s), playing[0][1] if playing else {})
    end = playing[-1][1] if playing else {}
    print(f"\nmemory (VmRSS MiB, {len(playing)} samples during the {t_stop:.0f} s of playback; baseline: the first "
          f"after {a.warmup_s:.0f} s)")
    # The halves tell a leak (the second grows as much as the first) from a level being reached (it grows less).
    t_end = playing[-1][0] if playing else 0.0
    t_mid = a.warmup_s + (t_end - a.warmup_s) / 2.0
    mid = next((m for t, m in samples if t >= t_mid), end)
    print(f"  {'node':<14}{'warm':>9}{'middle':>9}{'end':>9}{'max':>9}{'growth':>9}{'1st half':>10}{'2nd half':>10}")
    for name in sorted(set(warm) | set(end)):
        peak = max((m.get(name, 0.0) for _, m in playing), default=0.0)
        w, c, e = warm.get(name), mid.get(name), end.get(name)
        growth = f"{100.0 * (e - w) / w:+.1f} %" if w and e else "n/a"
        halves = f"{c - w:+10.1f}{e - c:+10.1f}" if w and c and e else f"{'n/a':>10}{'n/a':>10}"
        print(f"  {name:<14}{w or float('nan'):>9.1f}{c or float('nan'):>9.1f}{e or float('nan'):>9.1f}{peak:>9.1f}"
              f"{growth:>9}{halves}")  # fmt: skip
    if after:
        print("  after playback (draining, writing outputs), peak: " + ", ".join(
            f"{name} {max(m.get(name, 0.0) for m in after):.1f}" for name in sorted(warm) if any(name in m for m in after)))
    if a.work:  # the samples, for a plot of memory over time
        (out.parent / "memory_samples.json").write_text(json.dumps([{"t_s": t, "mib": m} for t, m in samples]) + "\n")

    counts, frames, period_s = poses_per_pass(out, bag, passes)
    minutes = period_s / a.rate / 60.0
    per_min = [(frames - c) / minutes for c in counts]
    print(f"\ndrops per minute per pass ({frames} colour frames a pass, {minutes * 60:.1f} s each):")
    print("  " + " ".join(f"{d:.0f}" for d in per_min))
    if len(per_min) >= 3:
        second, last = per_min[1], per_min[-1]
        print(f"  last pass / second pass: {last / second:.2f}" if second else f"  second pass 0, last pass {last:.0f}")

    summary_path = out / "graph_summary.json"
    s = json.loads(summary_path.read_text()) if summary_path.is_file() else {}
    wanted = ("trajectory.txt", "map.npz", "semantic_map_node.json", "graph_summary.json", "tracking_stats.json")
    missing = [n for n in wanted if not (out / n).is_file()]
    print(f"\noutputs complete: {code == 0 and not missing}" + (f" (missing {', '.join(missing)})" if missing else ""))
    if s:
        print(f"  poses {s['poses_published']}/{s['colour_frames_played']} over {s['passes']} passes, "
              f"restarts {s['restarts'] or 'none'}, keyframes {s['keyframes']}, "
              f"drops by reason {json.dumps({k: v for k, v in (s['drops_by_reason'] or {}).items() if v})}")


if __name__ == "__main__":
    main()
