"""CPU per process of `changing-slam graph` runs, this tree against a baseline commit, alternating (prints only).

    .venv/bin/python bench/bench_graph_cpu.py BAG [--config sim] [--baseline REF] [--runs 2] [--lossless]
        [--work /tmp/bench_graph_cpu]

Each run starts `python -m changing_slam_ros graph BAG --out ...` from a tree (this checkout, and with
--baseline a `git archive REF` of it, run with PYTHONPATH set to that tree) and samples, from outside, the user +
system CPU of every node process (`/proc/<pid>/stat`, every 0.05 s) from the moment the graph prints that it
plays until the player exits. Measuring from outside works the same on trees older than the graph's own
`cpu_s_during_play`; it counts the player's start-up (~0.9 s) too. Runs alternate between the trees so
that other load on a shared machine hits both alike. Per tree it prints the median over runs of: CPU ms per bag
frame per process and in total (budget at 30 Hz on two cores: 66 ms), tracking CPU per tracked frame,
detection CPU per detection, poses, latency median and ATE. Wall-clock figures (poses, latency) at 1x depend
on the machine's load; CPU figures much less.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

from changing_slam_ros.commands.process_cpu import process_cpu_s
from git_tree import archive_tree

REPO = Path(__file__).resolve().parents[1]
NODE_PREFIX = b"changing_slam_ros.nodes."


def _children(pid: int) -> dict[str, int]:
    """Node name -> pid of the graph's child processes (`python -m changing_slam_ros.nodes.<name>_node`)."""
    out: dict[str, int] = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
            if int(stat[stat.rfind(")") + 2 :].split()[1]) != pid:
                continue
            cmd = Path(f"/proc/{entry}/cmdline").read_bytes().split(b"\0")
        except (OSError, ValueError, IndexError):
            continue
        module = next((c for c in cmd if c.startswith(NODE_PREFIX)), None)
        if module is not None:
            out[module[len(NODE_PREFIX) :].decode().removesuffix("_node")] = int(entry)
    return out


def _playing(line: str) -> bool:
    return "up after" in line and "playing" in line


def start_graph(
    argv: list[str], tree: Path, ready: Callable[[str], bool] = _playing, extra_env: dict[str, str] | None = None
) -> tuple[subprocess.Popen, threading.Event, list[str], threading.Thread]:
    """Start `changing-slam graph` (`argv`) from `tree` (with `extra_env` added to the environment); a thread collects
    its output lines into the returned list and sets the event at the first line `ready` accepts (by default the
    one saying the graph is up and playing its bag)."""
    env = dict(os.environ, PYTHONPATH=str(tree), **(extra_env or {}))
    proc = subprocess.Popen(argv, cwd=tree, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    playing = threading.Event()
    log: list[str] = []

    def read() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            log.append(line)
            if ready(line):
                playing.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    return proc, playing, log, reader


def run_graph(tree: Path, bag: str, out: Path, config: str, lossless: bool, extra: tuple[str, ...] = ()) -> dict:
    """One graph run from `tree` (`extra`: more `graph` options); returns its graph_summary.json plus
    `play_cpu_s` (node -> CPU s)."""
    argv = [sys.executable, "-m", "changing_slam_ros", "graph", bag, "--out", str(out), "--config", config]
    argv += (["--lossless"] if lossless else []) + list(extra)
    proc, playing, log, reader = start_graph(argv, tree)
    at_play: dict[str, float] = {}
    last: dict[str, float] = {}
    player_seen = player_done = False
    while proc.poll() is None:
        kids = _children(proc.pid)
        if playing.is_set() and not player_done:
            for name, pid in kids.items():
                cpu = process_cpu_s(pid)
                if cpu is None:
                    continue
                at_play.setdefault(name, 0.0 if name == "bag_player" else cpu)
                last[name] = cpu
            if "bag_player" in kids:
                player_seen = True
            elif player_seen:
                player_done = True
        time.sleep(0.05)
    reader.join(5.0)
    if proc.returncode != 0:
        raise SystemExit(f"graph from {tree} failed ({proc.returncode}):\n{''.join(log[-20:])}")
    summary = json.loads((out / "graph_summary.json").read_text())
    summary["play_cpu_s"] = {name: last[name] - at_play.get(name, 0.0) for name in last}
    return summary


def figures(s: dict) -> dict[str, float]:
    """The printed figures of one run."""
    frames = s["colour_frames_in_bag"]
    cpu = s["play_cpu_s"]
    out = {f"{name} ms/frame": 1e3 * v / frames for name, v in sorted(cpu.items())}
    out["total ms/frame"] = 1e3 * sum(cpu.values()) / frames
    out["tracking ms/tracked frame"] = 1e3 * cpu.get("tracking", 0.0) / max(1, s.get("frames_processed") or 0)
    if s.get("detections_received"):
        out["detection ms/detection"] = 1e3 * cpu.get("detection", 0.0) / s["detections_received"]
    out["poses"] = float(s["poses_published"])
    out["latency median ms"] = float(s.get("latency_ms_median") or float("nan"))
    out["ATE cm"] = 100.0 * float(s.get("ate_rmse_m") or float("nan"))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("bag")
    parser.add_argument("--config", default="sim")
    parser.add_argument("--baseline", default="", metavar="REF", help="git commit to compare against (archived)")
    parser.add_argument("--runs", type=int, default=2, help="runs per tree (alternating)")
    parser.add_argument("--lossless", action="store_true")
    parser.add_argument("--work", default="", help="folder for the runs and the archived tree (default: a temp dir)")
    a = parser.parse_args()
    work = Path(a.work or tempfile.mkdtemp(prefix="bench_graph_cpu_"))
    work.mkdir(parents=True, exist_ok=True)
    trees = {"this tree": REPO}
    if a.baseline:
        base = work / "baseline_tree"
        if not base.is_dir():
            archive_tree(a.baseline, base)
        trees = {f"baseline {a.baseline}": base, **trees}
    results: dict[str, list[dict[str, float]]] = {name: [] for name in trees}
    bag = str(Path(a.bag).resolve())
    for i in range(a.runs):
        for name, tree in trees.items():
            out = work / f"run_{name.split()[0]}_{i}"
            s = run_graph(tree, bag, out, a.config, a.lossless)
            results[name].append(figures(s))
            print(f"{name} run {i + 1}: " + ", ".join(f"{k} {v:.1f}" for k, v in results[name][-1].items()),
                  flush=True)  # fmt: skip
    keys = sorted({k for runs in results.values() for r in runs for k in r}, key=lambda k: ("/" not in k, k))
    print(f"\nmedian over {a.runs} run(s), {bag}, {'lossless' if a.lossless else '1x'}:")
    print(f"{'':28s}" + "".join(f"{name:>24s}" for name in results))
    for k in keys:
        row = [statistics.median([r[k] for r in runs if k in r]) if any(k in r for r in runs) else float("nan")
               for runs in results.values()]  # fmt: skip
        print(f"{k:28s}" + "".join(f"{v:24.1f}" for v in row))


if __name__ == "__main__":
    main()
