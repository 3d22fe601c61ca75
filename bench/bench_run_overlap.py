"""Wall time of `changing-slam run` with the detector overlapped with tracking against `--serial`: prints figures.

    .venv/bin/python bench/bench_run_overlap.py [--frames N] [--repeat R] [--threads 2,1]

For each source (the bundled walking sample with `--config sim`, then 7-Scenes redkitchen with `--config 7scenes`,
its first N frames) and each onnxruntime intra-op thread count in `--threads`, runs `--serial` and the overlapped
default alternately, R times each, each run a fresh process; prints the median wall time of the frame loop
(metrics.json `wall_s`, model loading excluded), CPU per frame, serial / overlapped ratio, and whether the
trajectories (trajectory.txt) of all runs of a source and thread count are byte for byte the same. The default
dynamic settings (shipped fp32 SSD detector on every frame) and loop closing are on; plots off.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from changing_slam_ros.config import find_config, load_yaml  # noqa: E402

SHARED = Path(os.environ.get("CHANGING_SLAM_SHARED", REPO.parent / "shared"))


def config_with_threads(name: str, threads: int, folder: Path) -> Path:
    """The shipped config `name` with `detector.intra_op_threads` set, written into `folder`."""
    data = load_yaml(find_config(name))
    data["detector"] = {**(data.get("detector") or {}), "intra_op_threads": threads}
    path = folder / f"{name}_threads{threads}.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return path


def one_run(source: Path, config: Path, frames: int, serial: bool, out: Path) -> dict[str, float | bytes]:
    cmd = [sys.executable, "-m", "changing_slam_ros.cli", "run", str(source), "--out", str(out), "--config",
           str(config), "--quiet", "--no-plot", "--max-frames", str(frames)] + (["--serial"] if serial else [])
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, env={**os.environ, "PYTHONPATH": str(REPO)})
    metrics = json.loads((out / "metrics.json").read_text())
    return {"wall_s": metrics["wall_s"], "cpu_ms": metrics["cpu_ms_per_frame"], "frames": metrics["frames"],
            "ate_cm": metrics.get("ate_rmse_m", float("nan")) * 100, "trajectory": (out / "trajectory.txt").read_bytes()}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=300, help="frames of redkitchen (the sample is run whole)")
    parser.add_argument("--repeat", type=int, default=1, help="runs of each mode, alternating")
    parser.add_argument("--threads", default="2,1", help="onnxruntime intra-op thread counts to compare")
    args = parser.parse_args()
    sources = [(REPO / "bags" / "sim_walking_changing.mcap", "sim", 0),
               (SHARED / "data" / "7scenes_redkitchen", "7scenes", args.frames)]
    print(f"load average at start: {os.getloadavg()[0]:.2f}, {os.cpu_count()} CPUs")
    print(f"{'source':<28} {'threads':>7} {'frames':>6} {'serial s':>9} {'overlap s':>9} {'ratio':>6} "
          f"{'cpu ms/f ser/ovl':>17} {'ATE cm':>7} identical")
    with tempfile.TemporaryDirectory(prefix="bench_overlap_") as tmp:
        folder = Path(tmp)
        for source, config_name, frames in sources:
            if not source.exists():
                print(f"{source}: missing, skipped")
                continue
            for threads in (int(t) for t in args.threads.split(",")):
                config = config_with_threads(config_name, threads, folder)
                runs: dict[bool, list[dict[str, float | bytes]]] = {True: [], False: []}
                for r in range(args.repeat):
                    for serial in (True, False):
                        out = folder / f"{config_name}_{threads}_{serial}_{r}"
                        runs[serial].append(one_run(source, config, frames, serial, out))
                wall = {mode: statistics.median(float(x["wall_s"]) for x in rs) for mode, rs in runs.items()}
                cpu = {mode: statistics.median(float(x["cpu_ms"]) for x in rs) for mode, rs in runs.items()}
                same = len({x["trajectory"] for rs in runs.values() for x in rs}) == 1
                print(f"{source.name:<28} {threads:>7} {runs[True][0]['frames']:>6} {wall[True]:>9.2f} "
                      f"{wall[False]:>9.2f} {wall[True] / wall[False]:>6.2f} {cpu[True]:>8.1f}/{cpu[False]:<8.1f} "
                      f"{float(runs[False][0]['ate_cm']):>7.2f} {'yes' if same else 'NO'}", flush=True)
    print(f"load average at end: {os.getloadavg()[0]:.2f} ({time.strftime('%H:%M:%S')})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
