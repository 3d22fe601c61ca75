"""A benchmark over the seeds of a simulated scenario family: render (cached), run, score, summarise.

For each seed: render the scenario and its control (cached by a hash of the scenario's drawn parameters and
the render options), run the plain engine (`changing-slam run --no-dynamic`) and the full default pipeline on
both, in parallel jobs, and score the full run's moving keypoints per cue (`keypoint_scores`). CPU ms per
frame come from serial runs only: with one job the runs themselves, with more a serial re-run of the first
`timing_seeds` seeds. Every step is a `changing-slam` subprocess, so runs are isolated and the same as a
user's. `SeedBenchSpec` names the family, so other families (changing scenes) reuse the harness.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from changing_slam_ros.errors import EvalError
from changing_slam_ros.eval.keypoint_scores import CUES, CueScore, mover_coverage, score_keypoints
from changing_slam_ros.io.atomic import atomic_write_text

RUN_KINDS = ("plain", "full", "control_plain", "control_full")


@dataclass(frozen=True)
class SeedBenchSpec:
    """Which family, how it is rendered, and the extra `changing-slam run` arguments of the full pipeline."""

    scenario: str
    control: str | None
    width: int = 640
    height: int = 480
    frames: int | None = None
    fps: float | None = None
    full_args: tuple[str, ...] = ()

    def render_args(self) -> list[str]:
        out = ["--width", str(self.width), "--height", str(self.height)]
        if self.frames is not None:
            out += ["--frames", str(self.frames)]
        if self.fps is not None:
            out += ["--fps", str(self.fps)]
        return out


@dataclass
class RunResult:
    """One `changing-slam run`: ATE RMSE (None if it could not be evaluated), frames, CPU."""

    ate_rmse_m: float | None
    frames: int
    frames_tracked: int
    cpu_ms_per_frame: float
    wall_s: float

    @property
    def lost(self) -> int:
        return self.frames - self.frames_tracked


@dataclass
class SeedResult:
    seed: int
    runs: dict[str, RunResult]
    keypoints: dict[str, CueScore] = field(default_factory=dict)
    coverage_median: float = 0.0
    coverage_max: float = 0.0
    description: str = ""

    def ratio(self, a: str, b: str) -> float | None:
        ra, rb = self.runs.get(a), self.runs.get(b)
        if ra is None or rb is None or ra.ate_rmse_m is None or rb.ate_rmse_m is None or rb.ate_rmse_m <= 0:
            return None
        return ra.ate_rmse_m / rb.ate_rmse_m


def parse_seeds(text: str) -> list[int]:
    """'100-129' or '0-9,12,15' -> the seeds, in order; EvalError naming --seeds on bad input."""
    seeds: list[int] = []
    try:
        for part in (p.strip() for p in text.split(",")):
            if "-" in part:
                a, b = part.split("-", 1)
                lo, hi = int(a), int(b)
                if hi < lo:
                    raise ValueError(part)
                seeds += list(range(lo, hi + 1))
            else:
                seeds.append(int(part))
    except ValueError as err:
        raise EvalError(f"--seeds {text!r}: expected ranges like 100-129 or 0-9,12") from err
    if not seeds or min(seeds) < 0:
        raise EvalError(f"--seeds {text!r}: expected non-negative seeds")
    return seeds


def _cli() -> list[str]:
    return [sys.executable, "-m", "changing_slam_ros.cli"]


def _call(args: list[str], log: Path) -> None:
    log.parent.mkdir(parents=True, exist_ok=True)
    with open(log, "w") as fh:
        rc = subprocess.run(args, stdout=fh, stderr=subprocess.STDOUT, env=os.environ.copy(), check=False).returncode
    if rc != 0:
        tail = log.read_text().strip().splitlines()[-1:] or ["(no output)"]
        raise EvalError(f"{' '.join(args[3:6])}: exit {rc}: {tail[0]} (log {log})")


def sequence_key(spec: SeedBenchSpec, name: str, seed: int) -> str:
    """Cache key of one render: the scenario's drawn parameters, description and the render options."""
    from changing_slam_ros.sim.scenarios import build_scenario

    scenario = build_scenario(name, seed)
    doc = {"name": name, "seed": seed, "description": scenario.description, "params": scenario.parameters,
           "sensor": scenario.sensor.as_dict(), "render": spec.render_args(), "n": scenario.n_frames()}
    digest = hashlib.sha1(json.dumps(doc, sort_keys=True, default=str).encode()).hexdigest()[:12]
    return f"{name}_s{seed}_{spec.width}x{spec.height}_{digest}"


def render_cached(spec: SeedBenchSpec, name: str, seed: int, cache_dir: Path) -> Path:
    """The rendered folder of `name` at `seed`, rendering it unless the cache holds a complete one."""
    folder = Path(cache_dir) / sequence_key(spec, name, seed)
    if (folder / ".complete").exists():
        return folder
    tmp = folder.with_name(folder.name + ".partial")
    shutil.rmtree(tmp, ignore_errors=True)
    _call(_cli() + ["simulate", name, "--seed", str(seed), "--out", str(tmp), "--quiet"] + spec.render_args(),
          Path(cache_dir) / "logs" / f"{folder.name}.log")
    atomic_write_text(tmp / ".complete", "")
    shutil.rmtree(folder, ignore_errors=True)
    tmp.rename(folder)
    return folder


def run_slam(sequence: Path, out_dir: Path, full: bool, extra: tuple[str, ...] = (), keypoint_log: bool = False,
             reuse: bool = False) -> RunResult:
    """`changing-slam run` on `sequence` into `out_dir`: the plain engine, or the full default pipeline."""
    metrics_path = Path(out_dir) / "metrics.json"
    if not (reuse and metrics_path.exists()):
        args = _cli() + ["run", str(sequence), "--out", str(out_dir), "--quiet", "--no-plot"]
        args += list(extra) if full else ["--no-dynamic"]
        if full and keypoint_log:
            args += ["--keypoint-log", str(Path(out_dir) / "keypoints.npz")]
        try:
            _call(args, Path(out_dir).with_suffix(".log"))
        except EvalError:
            if not metrics_path.exists():  # a run that tracked nothing exits 1 but writes its metrics: a figure
                raise
    m = json.loads(metrics_path.read_text())
    ate = m.get("ate_rmse_m")
    return RunResult(None if ate is None or (isinstance(ate, float) and math.isnan(ate)) else float(ate),
                     int(m["frames"]), int(m["frames_tracked"]), float(m.get("cpu_ms_per_frame", math.nan)),
                     float(m["wall_s"]))


def run_seed_bench(spec: SeedBenchSpec, seeds: list[int], out_dir: Path, cache_dir: Path, jobs: int = 1,
                   timing_seeds: int = 2, reuse_runs: bool = False,
                   progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Render, run and score every seed (one seed per job: its renders, then its runs); returns, and writes to
    out_dir/bench.json, the per-seed figures and the summary. bench.json is rewritten after every finished
    seed (`complete` false until the end), so an interrupted benchmark leaves the seeds it finished."""
    say = progress or (lambda _msg: None)
    out_dir, cache_dir = Path(out_dir), Path(cache_dir)
    kinds = [k for k in RUN_KINDS if spec.control or not k.startswith("control")]
    folders: dict[tuple[str, int], Path] = {}

    def one_seed(seed: int) -> SeedResult:
        folders[(spec.scenario, seed)] = render_cached(spec, spec.scenario, seed, cache_dir)
        if spec.control:
            folders[(spec.control, seed)] = render_cached(spec, spec.control, seed, cache_dir)
        result = SeedResult(seed, {})
        for kind in kinds:
            name = spec.control if kind.startswith("control") else spec.scenario
            assert name is not None
            result.runs[kind] = run_slam(folders[(name, seed)], out_dir / "runs" / f"s{seed}_{kind}",
                                         kind.endswith("full"), spec.full_args, keypoint_log=(kind == "full"),
                                         reuse=reuse_runs)
        seq = folders[(spec.scenario, seed)]
        result.keypoints = score_keypoints(seq, out_dir / "runs" / f"s{seed}_full" / "keypoints.npz")
        result.coverage_median, result.coverage_max = mover_coverage(seq)
        result.description = _description(seq)
        say(f"seed {seed}: plain {_cm(result.runs['plain'].ate_rmse_m)}, full {_cm(result.runs['full'].ate_rmse_m)}"
            f" ({result.runs['plain'].lost} / {result.runs['full'].lost} lost)")
        return result

    results: list[SeedResult] = []
    with ThreadPoolExecutor(max_workers=max(1, jobs)) as pool:
        for future in as_completed([pool.submit(one_seed, s) for s in seeds]):
            results.append(future.result())
            results.sort(key=lambda r: r.seed)
            _write(out_dir, spec, seeds, jobs, results, None)
    cpu = _cpu_figures(spec, seeds, folders, {(r.seed, k): v for r in results for k, v in r.runs.items()},
                       out_dir, jobs, timing_seeds, reuse_runs)
    return _write(out_dir, spec, seeds, jobs, results, cpu)


def _write(out_dir: Path, spec: SeedBenchSpec, seeds: list[int], jobs: int, results: list[SeedResult],
           cpu: dict[str, Any] | None) -> dict[str, Any]:
    doc = {"scenario": spec.scenario, "control": spec.control, "seeds": seeds, "complete": cpu is not None,
           "jobs": jobs, "render": spec.render_args(), "full_args": list(spec.full_args),
           "per_seed": [_seed_dict(r) for r in results], "summary": summarise(results), "cpu_ms_per_frame": cpu}
    atomic_write_text(out_dir / "bench.json", json.dumps(doc, indent=1) + "\n")
    return doc


def _description(seq: Path) -> str:
    try:
        return str(json.loads((seq / "objects.json").read_text()).get("description", ""))
    except (OSError, ValueError):
        return ""


def _cpu_figures(spec: SeedBenchSpec, seeds: list[int], folders: dict[tuple[str, int], Path],
                 runs: dict[tuple[int, str], RunResult], out_dir: Path, jobs: int, timing_seeds: int,
                 reuse: bool) -> dict[str, Any]:
    """CPU ms per frame of the plain engine and the full pipeline, from serial runs only."""
    if jobs <= 1:
        source = "the benchmark's own runs (one job at a time)"
        plain = [runs[(s, "plain")].cpu_ms_per_frame for s in seeds]
        full = [runs[(s, "full")].cpu_ms_per_frame for s in seeds]
    else:
        chosen = seeds[: max(1, timing_seeds)]
        source = f"serial re-runs of seeds {chosen}"
        plain, full = [], []
        for s in chosen:
            seq = folders[(spec.scenario, s)]
            plain.append(run_slam(seq, out_dir / "timing" / f"s{s}_plain", False, reuse=reuse).cpu_ms_per_frame)
            full.append(run_slam(seq, out_dir / "timing" / f"s{s}_full", True, spec.full_args,
                                 reuse=reuse).cpu_ms_per_frame)
    return {"source": source, "plain_median": _round(float(np.median(plain))),
            "full_median": _round(float(np.median(full))), "plain": [_round(v) for v in plain],
            "full": [_round(v) for v in full]}


def _round(v: float | None, nd: int = 4) -> float | None:
    return None if v is None or math.isnan(v) else round(v, nd)


def _cm(v: float | None) -> str:
    return "n/a" if v is None else f"{100 * v:.2f} cm"


def _seed_dict(r: SeedResult) -> dict[str, Any]:
    return {
        "seed": r.seed, "description": r.description,
        "runs": {k: {"ate_rmse_m": _round(v.ate_rmse_m, 6), "frames": v.frames, "lost": v.lost,
                     "cpu_ms_per_frame": _round(v.cpu_ms_per_frame, 2), "wall_s": round(v.wall_s, 2)}
                 for k, v in r.runs.items()},
        "ratio_full_to_plain": _round(r.ratio("full", "plain")),
        "ratio_control_full_to_plain": _round(r.ratio("control_full", "control_plain")),
        "keypoints": {c: s.as_dict() for c, s in r.keypoints.items()},
        "mover_coverage": {"median": round(r.coverage_median, 4), "max": round(r.coverage_max, 4)},
    }


def _stats(values: list[float]) -> dict[str, float | None]:
    if not values:
        return {"median": None, "p90": None, "worst": None}
    a = np.asarray(values)
    return {"median": _round(float(np.median(a)), 6), "p90": _round(float(np.percentile(a, 90)), 6),
            "worst": _round(float(a.max()), 6)}


def summarise(results: list[SeedResult]) -> dict[str, Any]:
    """ATE statistics over seeds per run kind, lost frames, ratios, and keypoint scores summed over seeds."""
    out: dict[str, Any] = {}
    for kind in RUN_KINDS:
        vals = [r.runs[kind].ate_rmse_m for r in results if kind in r.runs]
        if not vals:
            continue
        finite = [v for v in vals if v is not None]
        out[kind] = {"ate_rmse_m": _stats(finite), "not_evaluated": len(vals) - len(finite),
                     "lost_frames": int(sum(r.runs[kind].lost for r in results)),
                     "seeds_with_lost_frames": int(sum(r.runs[kind].lost > 0 for r in results))}
    ratios = [v for v in (r.ratio("full", "plain") for r in results) if v is not None]
    controls = [v for v in (r.ratio("control_full", "control_plain") for r in results) if v is not None]
    out["ratio_full_to_plain"] = _stats(ratios)
    out["ratio_control_full_to_plain"] = _stats(controls)
    big = [r for r in results if (r.runs["plain"].ate_rmse_m or 0.0) > 0.20]
    out["plain_over_20cm"] = {"seeds": [r.seed for r in big],
                              "full_20x_lower": [r.seed for r in big if (r.ratio("full", "plain") or 1.0) <= 0.05]}
    totals = {c: CueScore(sum(r.keypoints[c].tp for r in results if c in r.keypoints),
                          sum(r.keypoints[c].fp for r in results if c in r.keypoints),
                          sum(r.keypoints[c].fn for r in results if c in r.keypoints)) for c in CUES}
    out["keypoints"] = {c: s.as_dict() for c, s in totals.items()}
    return out
