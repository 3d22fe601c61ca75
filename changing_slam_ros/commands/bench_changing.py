"""`changing-slam bench changing`: the changing-room family rendered, run and scored per seed (a helper of
`commands/bench.py`, which parses the arguments shared with `bench dynamic`).

Per seed, on the seed-bench harness (`eval/seed_bench.py`): `random_changing` and `random_changing_control`
rendered into the cache (keyed by the drawn parameters and render options), the default pipeline run on both
(plus `--full-args`) into OUT/runs/s<seed>_changing and s<seed>_control, and the run's semantic map scored
against the last lap (`eval/changing_bench.py`). A line per seed and a summary are printed; OUT/changing_bench.json
is rewritten after every finished seed and OUT/changing_bench.png plots the figures. Tuning seeds 0-9,
evaluation seeds 200-229.
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path
from typing import Any

from changing_slam_ros.errors import SimError, SlamError
from changing_slam_ros.eval.changing_bench import SeedResult, score_run, summarise

SCENARIO, CONTROL = "random_changing", "random_changing_control"


def bench_seed(args: argparse.Namespace, seed: int, cache: Path) -> SeedResult:
    """Render, run and score one seed; a seed that fails is returned with its error and no score."""
    from changing_slam_ros.eval.seed_bench import SeedBenchSpec, render_cached, run_slam

    spec = SeedBenchSpec(SCENARIO, None if args.no_control else CONTROL, args.width, args.height, args.frames)
    extra = tuple(shlex.split(args.full_args))
    runs = args.out / "runs"
    try:
        scene = render_cached(spec, SCENARIO, seed, cache)
        run_slam(scene, runs / f"s{seed}_changing", True, extra, reuse=args.reuse_runs)
        control = None
        if not args.no_control:
            control_scene = render_cached(spec, CONTROL, seed, cache)
            run_slam(control_scene, runs / f"s{seed}_control", True, extra, reuse=args.reuse_runs)
            control = runs / f"s{seed}_control"
        return score_run(seed, scene, runs / f"s{seed}_changing", control, match_on=args.match_on)
    except (SlamError, SimError) as err:
        return SeedResult(seed, None, 0, 0, math.nan, math.nan, 0, 0, error=str(err))


def format_seed(r: SeedResult) -> str:
    """One seed's line."""
    if r.score is None:
        return f"seed {r.seed:4d}  failed: {r.error}"
    s = r.score
    return (f"seed {r.seed:4d}  recall {s.n_matched_present}/{s.n_present}  precision {len(s.matches)}/{s.n_active}"
            f"  stale {len(s.stale)}  pictures {len(s.spurious_pictures)}  other {len(s.spurious_other)}"
            f"  ATE {100 * r.ate_m:.2f} cm  control {100 * r.control_ate_m:.2f} cm  (x{r.ate_ratio:.2f})"
            f"  loops {r.loops} wrong {r.wrong_loops}  tracked {r.frames_tracked}/{r.frames}"
            f"  changes {','.join(r.changes) or '-'}"
            f"  missed {','.join(f'{n}({why})' for n, why in r.missed_reasons) or '-'}")


def format_summary(s: dict[str, Any]) -> str:
    """The summary as text."""
    m = s["seeds_meeting"]
    n = s["scored"]
    return (f"{s['scored']}/{s['seeds']} seeds scored (failed: {s['failed'] or 'none'})\n"
            f"recall mean {s['recall_mean']:.3f} (pooled {s['recall_pooled']:.3f} of {s['present']} objects), "
            f"precision mean {s['precision_mean']:.3f} (pooled {s['precision_pooled']:.3f} of {s['active']} active)\n"
            f"stale {s['stale']}, pictures mapped {s['spurious_pictures']}, other spurious {s['spurious_other']}, "
            f"wrong loops {s['wrong_loops']}; ATE median {s['ate_cm_median']:.2f} cm, ATE / control median "
            f"{s['ate_ratio_median']:.2f}, worst {s['ate_ratio_max']:.2f}\n"
            f"seeds meeting the targets (of {n}): recall>=0.9 {m['recall']}, precision>=0.9 {m['precision']}, "
            f"no stale {m['no_stale']}, no picture {m['no_picture']}, ATE<=1.3x control {m['ate_ratio']}, "
            f"no wrong loop {m['no_wrong_loop']}\n"
            "missed objects by reason: " + ", ".join(f"{k} {v}" for k, v in s["missed_reasons"].items()))


def run_changing_bench(args: argparse.Namespace) -> int:
    """The `bench changing` command on the arguments `commands/bench.py` parsed."""
    from changing_slam_ros.eval.seed_bench import parse_seeds
    from changing_slam_ros.io.atomic import atomic_write_text

    seeds = parse_seeds(args.seeds)
    cache = args.cache or args.out.parent / "sim_cache"
    args.out.mkdir(parents=True, exist_ok=True)
    out = args.out / "changing_bench.json"
    results: list[SeedResult] = []
    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        for future in as_completed([pool.submit(bench_seed, args, s, cache) for s in seeds]):
            result = future.result()
            print(format_seed(result), flush=True)
            results.append(result)
            results.sort(key=lambda r: r.seed)
            doc = {"scenario": SCENARIO, "control": None if args.no_control else CONTROL, "seeds": seeds,
                   "complete": len(results) == len(seeds), "size": [args.width, args.height],
                   "full_args": args.full_args, "match_on": args.match_on, "summary": summarise(results),
                   "per_seed": [r.to_dict() for r in results]}
            atomic_write_text(out, json.dumps(doc, indent=1) + "\n")
    print(format_summary(summarise(results)))
    from changing_slam_ros.eval.changing_bench_plot import plot_changing_bench

    plot_changing_bench(results, args.out / "changing_bench.png", title=f"changing-room family, seeds {args.seeds}")
    print(f"results in {args.out} (changing_bench.json, changing_bench.png)")
    return 0
