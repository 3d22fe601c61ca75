"""`changing-slam bench FAMILY --seeds A-B [--jobs J] [--out DIR]`: a benchmark over a scenario family's seeds.

    changing-slam bench dynamic --seeds 100-129 [--jobs J] [--out DIR] [--cache DIR] [--frames N]
        [--width W --height H] [--timing-seeds K] [--reuse-runs] [--full-args "--config sim"]
    changing-slam bench changing --seeds 200-229 [--jobs J] [--out DIR] [--cache DIR] [--reuse-runs]
        [--full-args "--config sim"] [--no-control] [--match-on centroid|box_center] [--sessions]

`dynamic` is the `random_dynamic` family (`sim/random_dynamic.py`) with its control. Seeds 0-9 are for
tuning, 100-129 for evaluation. Prints per seed and in summary ATE, lost frames, ratios, CPU ms per frame
and moving-keypoint precision / recall per cue; writes DIR/bench.json and DIR/ate_per_seed.png.
The work lives in `eval/seed_bench.py`.
`changing` is the `random_changing` family (`sim/random_changing.py`) with its control: the default pipeline on
both, the semantic map scored against the last lap (`commands/bench_changing.py`, `eval/changing_bench.py`);
seeds 0-9 for tuning, 200-229 for evaluation; writes DIR/changing_bench.json and DIR/changing_bench.png.
With `--sessions` it also scores the "what changed" report of each seed run as two sessions.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path
from typing import Any

FAMILIES = {"dynamic": ("random_dynamic", "random_dynamic_control"),
            "changing": ("random_changing", "random_changing_control")}
TUNING_SEEDS = "0-9"
EVALUATION_SEEDS = {"dynamic": "100-129", "changing": "200-229"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("family", choices=sorted(FAMILIES),
                        help="scenario family (dynamic: random_dynamic, changing: random_changing)")
    parser.add_argument("--seeds", default=None,
                        help=f"seeds, e.g. 100-129 or 0-9,12 (tuning {TUNING_SEEDS}, evaluation "
                             f"{', '.join(f'{k} {v}' for k, v in EVALUATION_SEEDS.items())}; default the evaluation range)")
    parser.add_argument("--jobs", type=int, default=1, help="parallel renders and runs (default 1)")
    parser.add_argument("--out", type=Path, default=None, help="results folder (default out/bench_FAMILY)")
    parser.add_argument("--cache", type=Path, default=None, help="rendered sequences (default OUT/../sim_cache)")
    parser.add_argument("--frames", type=int, default=None, help="render only the first N frames of each seed")
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--timing-seeds", type=int, default=2,
                        help="with --jobs > 1, CPU figures come from serial re-runs of this many seeds (default 2)")
    parser.add_argument("--reuse-runs", action="store_true", help="keep runs whose metrics.json exists in OUT")
    parser.add_argument("--full-args", default="", help="extra `changing-slam run` arguments of the full pipeline")
    parser.add_argument("--no-control", action="store_true", help="changing: skip the control (no ATE ratio)")
    parser.add_argument("--match-on", choices=("centroid", "box_center"), default="centroid",
                        help="changing: the estimate's position matched to ground truth (default centroid)")
    parser.add_argument("--sessions", action="store_true",
                        help="changing: also run each seed as two sessions cut before its first change and score "
                             "the second session's change report against the truth's changes")


def main(args: argparse.Namespace) -> int:
    from changing_slam_ros.errors import EvalError
    from changing_slam_ros.eval.seed_bench import SeedBenchSpec, parse_seeds, run_seed_bench

    if args.jobs < 1:
        raise EvalError(f"--jobs {args.jobs}: expected at least 1")
    args.seeds = args.seeds or EVALUATION_SEEDS[args.family]
    args.out = args.out or Path(f"out/bench_{args.family}")
    if args.family == "changing":
        from changing_slam_ros.commands.bench_changing import run_changing_bench

        return run_changing_bench(args)
    seeds = parse_seeds(args.seeds)
    scenario, control = FAMILIES[args.family]
    spec = SeedBenchSpec(scenario, control, args.width, args.height, args.frames,
                         full_args=tuple(shlex.split(args.full_args)))
    cache = args.cache or args.out.parent / "sim_cache"
    doc = run_seed_bench(spec, seeds, args.out, cache, args.jobs, args.timing_seeds, args.reuse_runs,
                         progress=lambda msg: print(msg, file=sys.stderr, flush=True))
    print(format_report(doc))
    from changing_slam_ros.eval.seed_bench_plot import plot_seed_bench

    plot_seed_bench(doc, args.out / "ate_per_seed.png")
    print(f"results in {args.out} (bench.json, ate_per_seed.png)")
    return 0


def _cm(v: Any) -> str:
    return "   n/a" if v is None else f"{100 * v:6.2f}"


def _x(v: Any) -> str:
    return "  n/a" if v is None else f"{v:5.2f}"


def _pr(k: dict[str, Any]) -> str:
    p, r = k.get("precision"), k.get("recall")
    return f"{'n/a' if p is None else f'{p:.2f}'}/{'n/a' if r is None else f'{r:.2f}'}"


def format_report(doc: dict[str, Any]) -> str:
    """The per-seed table and the summary as text."""
    lines = ["seed  plain cm  full cm  full/plain  lost p/f  ctrl plain  ctrl full  ctrl ratio  cover max  "
             "P/R any   detector  ekf       agnostic"]
    for r in doc["per_seed"]:
        runs = r["runs"]
        kp = r["keypoints"]
        lines.append(
            f"{r['seed']:>4}  {_cm(runs['plain']['ate_rmse_m'])}    {_cm(runs['full']['ate_rmse_m'])}   "
            f"{_x(r['ratio_full_to_plain'])}       {runs['plain']['lost']:>3}/{runs['full']['lost']:<3}  "
            f"{_cm(runs.get('control_plain', {}).get('ate_rmse_m'))}      {_cm(runs.get('control_full', {}).get('ate_rmse_m'))}"
            f"     {_x(r['ratio_control_full_to_plain'])}       {r['mover_coverage']['max']:.2f}     "
            f"{_pr(kp['any']):<9} {_pr(kp['detector']):<9} {_pr(kp['object_ekf']):<9} {_pr(kp['class_agnostic'])}")
    s = doc["summary"]
    lines.append("")
    for kind in ("plain", "full", "control_plain", "control_full"):
        if kind in s:
            a = s[kind]["ate_rmse_m"]
            lines.append(f"{kind:<14} ATE median {_cm(a['median'])} cm, p90 {_cm(a['p90'])} cm, worst {_cm(a['worst'])} cm;"
                         f" lost frames {s[kind]['lost_frames']} ({s[kind]['seeds_with_lost_frames']} seeds)")
    rr, rc = s["ratio_full_to_plain"], s["ratio_control_full_to_plain"]
    lines.append(f"full / plain: median {_x(rr['median'])}, worst {_x(rr['worst'])}; control full / control plain: "
                 f"median {_x(rc['median'])}, worst {_x(rc['worst'])}")
    big = s["plain_over_20cm"]
    lines.append(f"plain > 20 cm on seeds {big['seeds']}; full >= 20x lower on {big['full_20x_lower']}")
    lines.append("moving keypoints, precision/recall: " + ", ".join(f"{c} {_pr(k)}" for c, k in s["keypoints"].items()))
    cpu = doc["cpu_ms_per_frame"]
    lines.append(f"CPU ms per frame ({cpu['source']}): plain {cpu['plain_median']}, full {cpu['full_median']}")
    return "\n".join(lines)
