"""`changing-slam bench changing`: the changing-room family rendered, run and scored per seed (a helper of
`commands/bench.py`, which parses the arguments shared with `bench dynamic`).

Per seed, on the seed-bench harness (`eval/seed_bench.py`): `random_changing` and `random_changing_control`
rendered into the cache (keyed by the drawn parameters and render options), the default pipeline run on both
(plus `--full-args`) into OUT/runs/s<seed>_changing and s<seed>_control, and the run's semantic map scored
against the last lap (`eval/changing_bench.py`). A line per seed and a summary are printed; OUT/changing_bench.json
is rewritten after every finished seed and OUT/changing_bench.png plots the figures. Tuning seeds 0-9,
evaluation seeds 200-229.

With `--sessions` the seed's render is also cut before its first change and run as two sessions (the first session:
`--max-frames K` into s<seed>_session1; the second session: `--start-frame K --map-in` the first session's map into
s<seed>_session2), and the second session's change report is scored against the truth's changes
(`eval/change_sessions.py`): one more line per seed with each verdict against the truth, and the change-report
figures in the summary. It is an option because it adds two runs that together cover the render once (about
half the benchmark's time again, the control included); the single-run figures do not depend on it.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import shlex
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path
from typing import Any

from changing_slam_ros.errors import SimError, SlamError
from changing_slam_ros.eval.change_sessions import SessionResult, failed_sessions, score_sessions, split_of
from changing_slam_ros.eval.changing_bench import SeedResult, score_run, summarise

SCENARIO, CONTROL = "random_changing", "random_changing_control"


def bench_seed(args: argparse.Namespace, seed: int, cache: Path) -> SeedResult:
    """Render, run and score one seed; a seed that fails is returned with its error and no score (its sessions,
    with `--sessions`, still run and are scored once the render exists)."""
    from changing_slam_ros.eval.seed_bench import SeedBenchSpec, render_cached, run_slam

    spec = SeedBenchSpec(SCENARIO, None if args.no_control else CONTROL, args.width, args.height, args.frames)
    extra = tuple(shlex.split(args.full_args))
    runs = args.out / "runs"
    try:
        scene = render_cached(spec, SCENARIO, seed, cache)
    except (SlamError, SimError) as err:
        return SeedResult(seed, None, 0, 0, math.nan, math.nan, 0, 0, error=str(err))
    try:
        run_slam(scene, runs / f"s{seed}_changing", True, extra, reuse=args.reuse_runs)
        control = None
        if not args.no_control:
            control_scene = render_cached(spec, CONTROL, seed, cache)
            run_slam(control_scene, runs / f"s{seed}_control", True, extra, reuse=args.reuse_runs)
            control = runs / f"s{seed}_control"
        result = score_run(seed, scene, runs / f"s{seed}_changing", control, match_on=args.match_on)
    except (SlamError, SimError) as err:
        result = SeedResult(seed, None, 0, 0, math.nan, math.nan, 0, 0, error=str(err))
    if args.sessions:
        result = dataclasses.replace(result, sessions=bench_sessions(seed, scene, runs, extra, args.reuse_runs))
    return result


def bench_sessions(seed: int, scene: Path, runs: Path, extra: tuple[str, ...], reuse: bool) -> SessionResult:
    """Run the render as two sessions cut before its first change and score the second session's change report."""
    from changing_slam_ros.eval.seed_bench import run_slam

    split, frames = 0, 0
    first, second = runs / f"s{seed}_session1", runs / f"s{seed}_session2"
    try:
        split, frames, _ = split_of(scene)
        run_slam(scene, first, True, extra + ("--max-frames", str(split)), reuse=reuse)
        run_slam(scene, second, True, extra + ("--start-frame", str(split), "--map-in", str(first / "map.npz")),
                 reuse=reuse)
        return score_sessions(seed, scene, first, second)
    except (SlamError, OSError, ValueError) as err:
        return failed_sessions(seed, str(err), split, frames)


def format_seed(r: SeedResult) -> str:
    """One seed's line, and with the two-session mode a second one for its change report."""
    return _map_line(r) + ("" if r.sessions is None else "\n" + format_sessions(r.sessions))


def _map_line(r: SeedResult) -> str:
    if r.score is None:
        return f"seed {r.seed:4d}  failed: {r.error}"
    s = r.score
    return (f"seed {r.seed:4d}  recall {s.n_matched_present}/{s.n_present}  precision {len(s.matches)}/{s.n_active}"
            f"  stale {len(s.stale)}  pictures {len(s.spurious_pictures)}  other {len(s.spurious_other)}"
            f"  ATE {100 * r.ate_m:.2f} cm  control {100 * r.control_ate_m:.2f} cm  (x{r.ate_ratio:.2f})"
            f"  loops {r.loops} wrong {r.wrong_loops}  tracked {r.frames_tracked}/{r.frames}"
            f"  changes {','.join(r.changes) or '-'}"
            f"  missed {','.join(f'{n}({why})' for n, why in r.missed_reasons) or '-'}")


def format_sessions(r: SessionResult) -> str:
    """One seed's change report against its truth: each truth's verdict, then the reports that matched none."""
    head = f"seed {r.seed:4d}  sessions {r.split_frame}+{r.frames - r.split_frame} frames"
    if r.score is None:
        return f"{head}  failed: {r.error}"
    s = r.score
    if r.relocalised is not None:
        head += "  relocalised" if r.relocalised else "  NOT relocalised in the first session's map"
    verdicts = []
    for i, t in enumerate(s.truths):
        j = s.truth_match[i]
        if j is None:
            verdicts.append(f"{t.describe()}: missed ({s.miss_reasons[i]})")
            continue
        move = next(((d, p) for k, d, p in s.moves if k == i), None)
        verdicts.append(f"{t.describe()}: ok" + ("" if move is None else
                                                 f" (distance off {move[0]:.2f} m, place off {move[1]:.2f} m)"))
    used = {j for j in s.truth_match if j is not None}
    extra = [f"{c.describe()} ({'first seen' if j in s.first_seen else 'false'})"
             for j, c in enumerate(s.reported) if j not in used]
    return f"{head}  truth: {'; '.join(verdicts) or '-'}  other reports: {'; '.join(extra) or '-'}"


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
            "missed objects by reason: " + ", ".join(f"{k} {v}" for k, v in s["missed_reasons"].items())
            + ("" if "changes" not in s else "\n" + format_change_summary(s["changes"])))


def _pr(k: dict[str, Any]) -> str:
    return (f"P {k['correct']}/{k['reported']} R {k['matched']}/{k['truths']} (mapped before "
            f"{k['matched_mapped_before']}/{k['mapped_before']}, both sides {k['matched_mapped_both']}/{k['mapped_both']})")


def format_change_summary(c: dict[str, Any]) -> str:
    """The change-report figures of the summary."""
    m = c["moves"]
    met = ", ".join(f"{k} {'n/a' if v is None else 'yes' if v else 'no'}" for k, v in c["targets_met"].items())
    return (f"change report over {c['seeds']} seeds (failed: {c['failed'] or 'none'}, not relocalised: "
            f"{c['not_relocalised'] or 'none'}; places within {c['radius_m']} m):\n"
            + "".join(f"  {k:<8} {_pr(v)}\n" for k, v in c["kinds"].items())
            + f"moves matched {m['matched']}: distance off median {m['displacement_error']['median_m']:.2f} m, "
            f"max {m['displacement_error']['max_m']:.2f} m, {m['displacement_error']['within_tolerance']} within "
            f"{m['tolerance_m']} m; new place off median {m['place_error']['median_m']:.2f} m, "
            f"{m['place_error']['within_tolerance']} within {m['tolerance_m']} m; first-seen additions "
            f"{c['first_seen']}\nmissed changes by reason: " + ", ".join(f"{k} {v}" for k, v in c["miss_reasons"].items())
            + f"\nchange-report targets (P and R >= 0.9, moves within {m['tolerance_m']} m): {met}")


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
                   "full_args": args.full_args, "match_on": args.match_on, "sessions": args.sessions,
                   "summary": summarise(results),
                   "per_seed": [r.to_dict() for r in results]}
            atomic_write_text(out, json.dumps(doc, indent=1) + "\n")
    print(format_summary(summarise(results)))
    from changing_slam_ros.eval.changing_bench_plot import plot_changing_bench

    plot_changing_bench(results, args.out / "changing_bench.png", title=f"changing-room family, seeds {args.seeds}")
    print(f"results in {args.out} (changing_bench.json, changing_bench.png)")
    return 0
