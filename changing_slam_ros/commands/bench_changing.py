"""`changing-slam bench changing --seeds A-B`: the changing-room family rendered, run and scored per seed.

Per seed, under ROOT/seed_NNNN/: `scene/` (`random_changing`), `control/` (`random_changing_control`: the same
seed without its changes), `run/` and `control_run/` (`changing-slam run`, default config unless --config).
Renders and runs that exist are reused unless --rerun. Each seed's semantic map is scored against the final
lap (`eval.changing_bench`); a line per seed and a summary are printed, ROOT/changing_bench.json holds every
figure and ROOT/changing_bench.png plots them. Tuning seeds 0-9, evaluation seeds 200-229: tune on the first,
report the second.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from pathlib import Path

from changing_slam_ros.errors import EvalError, SimError, SlamError

DEFAULT_WIDTH, DEFAULT_HEIGHT = 320, 240


def parse_seeds(text: str) -> list[int]:
    """'0-9', '200-229', '1,4,7' or a mix ('0-2,9') -> the seeds in order; EvalError on anything else."""
    seeds: list[int] = []
    try:
        for part in text.split(","):
            a, sep, b = part.strip().partition("-")
            lo, hi = int(a), int(b) if sep else int(a)
            if lo < 0 or hi < lo:
                raise ValueError(part)
            seeds += range(lo, hi + 1)
    except ValueError as err:
        raise EvalError(f"--seeds {text!r}: expected A-B or A,B,... of non-negative integers") from err
    return seeds


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seeds", required=True, help="seeds: A-B, A,B,C (tuning 0-9, evaluation 200-229)")
    parser.add_argument("--root", type=Path, default=Path("out/bench_changing"), help="working folder")
    parser.add_argument("--config", default=None, help="config for `changing-slam run` (default: the defaults)")
    parser.add_argument("--width", type=int, default=DEFAULT_WIDTH, help=f"image width (default {DEFAULT_WIDTH})")
    parser.add_argument("--height", type=int, default=DEFAULT_HEIGHT, help=f"image height (default {DEFAULT_HEIGHT})")
    parser.add_argument("--no-control", action="store_true", help="skip the control render and run (no ATE ratio)")
    parser.add_argument("--rerun", action="store_true", help="run SLAM again where a run exists")
    parser.add_argument("--match-on", choices=("centroid", "box_center"), default="centroid",
                        help="estimate position matched to ground truth (default centroid)")
    parser.add_argument("--json", type=Path, default=None, help="results JSON (default ROOT/changing_bench.json)")
    parser.add_argument("--no-plot", action="store_true", help="skip ROOT/changing_bench.png")


def render(name: str, seed: int, out: Path, width: int, height: int) -> float:
    """Render `name` for `seed` into `out` unless it is there; seconds spent."""
    if (out / "changing_truth.json").is_file():
        return 0.0
    from changing_slam_ros.sim.scenarios import build_scenario
    from changing_slam_ros.sim.sequence import RenderOptions, simulate

    t0 = time.perf_counter()
    simulate(build_scenario(name, seed), out, RenderOptions(width=width, height=height), seed)
    return time.perf_counter() - t0


def run_slam(scene: Path, out: Path, config: str | None, rerun: bool) -> float:
    """`changing-slam run SCENE --out OUT` in a child process unless OUT/metrics.json exists; seconds spent."""
    if not rerun and (out / "metrics.json").is_file():
        return 0.0
    cmd = [sys.executable, "-m", "changing_slam_ros.cli", "run", str(scene), "--out", str(out), "--quiet", "--no-plot"]
    if config:
        cmd += ["--config", config]
    t0 = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        tail = (done.stderr.strip().splitlines() or ["no output"])[-1]
        raise EvalError(f"changing-slam run {scene} failed ({done.returncode}): {tail}")
    return time.perf_counter() - t0


def bench_seed(args: argparse.Namespace, seed: int) -> tuple[object, float]:
    """Render, run and score one seed; (SeedResult, seconds)."""
    from changing_slam_ros.eval.changing_bench import SeedResult, score_run

    folder = args.root / f"seed_{seed:04d}"
    t0 = time.perf_counter()
    try:
        render("random_changing", seed, folder / "scene", args.width, args.height)
        run_slam(folder / "scene", folder / "run", args.config, args.rerun)
        control = None
        if not args.no_control:
            render("random_changing_control", seed, folder / "control", args.width, args.height)
            run_slam(folder / "control", folder / "control_run", args.config, args.rerun)
            control = folder / "control_run"
        result = score_run(seed, folder / "scene", folder / "run", control, match_on=args.match_on)
    except (SlamError, SimError) as err:
        result = SeedResult(seed, None, 0, 0, math.nan, math.nan, 0, 0, error=str(err))
    return result, time.perf_counter() - t0


def _line(r: object, seconds: float) -> str:
    from changing_slam_ros.eval.changing_bench import SeedResult

    assert isinstance(r, SeedResult)
    if r.score is None:
        return f"seed {r.seed:4d}  failed: {r.error}"
    s = r.score
    return (f"seed {r.seed:4d}  recall {s.n_matched_present}/{s.n_present} precision {len(s.matches)}/{s.n_active}"
            f"  stale {len(s.stale)} pictures {len(s.spurious_pictures)} other {len(s.spurious_other)}"
            f"  ATE {100 * r.ate_m:.2f} cm control {100 * r.control_ate_m:.2f} cm (x{r.ate_ratio:.2f})"
            f"  loops {r.loops} wrong {r.wrong_loops}  tracked {r.frames_tracked}/{r.frames}"
            f"  changes {','.join(r.changes) or '-'}  missed {','.join(s.missed) or '-'}  ({seconds:.0f} s)")


def main(args: argparse.Namespace) -> int:
    from changing_slam_ros.eval.changing_bench import summarise
    from changing_slam_ros.io.atomic import atomic_write_text

    seeds = parse_seeds(args.seeds)
    if args.width < 16 or args.height < 16:
        raise EvalError(f"--width/--height {args.width}x{args.height}: expected at least 16x16")
    args.root.mkdir(parents=True, exist_ok=True)
    results = []
    for seed in seeds:
        result, seconds = bench_seed(args, seed)
        print(_line(result, seconds), flush=True)
        results.append(result)
    summary = summarise(results)  # type: ignore[arg-type]
    print("summary: " + json.dumps(summary))
    out = args.json or args.root / "changing_bench.json"
    doc = {"seeds": args.seeds, "config": args.config or "defaults", "size": [args.width, args.height],
           "match_on": args.match_on, "summary": summary, "per_seed": [r.to_dict() for r in results]}  # type: ignore[attr-defined]
    atomic_write_text(out, json.dumps(doc, indent=1, default=float) + "\n")
    print(f"results: {out}")
    if not args.no_plot:
        from changing_slam_ros.eval.changing_bench_plot import plot_changing_bench

        png = out.with_suffix(".png")
        plot_changing_bench(results, png, title=f"changing-room family, seeds {args.seeds}")  # type: ignore[arg-type]
        print(f"plot: {png}")
    return 0
