"""CPU per keyframe of local mapping, per stage, in `changing-slam run`: prints figures, asserts nothing.

    .venv/bin/python bench/bench_local_mapping_cpu.py BAG [--config sim] [--baseline REF] [--runs 2]
        [--cprofile N] [--current DIR] [--baseline-config NAME|FILE]

Each run is `changing-slam run BAG --config NAME --out TMP` in a child process (this checkout, and with
`--baseline` a `git archive REF` of it, alternating) with local mapping's stages wrapped from outside (the
library is not changed for it), timed in thread CPU time (`time.thread_time_ns`, not wall time: the machine is
shared), with OPENBLAS_NUM_THREADS=1 as in the graph (`changing-slam graph` sets it for its nodes). Time is exclusive: a stage called inside another is counted in the innermost one only. Stages:

Per tree: the median over runs of ms per keyframe per stage, keyframes, ATE and the sha256 of trajectory.txt
(an exact change keeps it).

The rows and the method: `main`.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from stage_clock import StageClock  # noqa: E402
from git_tree import alternating_runs  # noqa: E402

STAGES = ("create", "triangulate", "fuse", "fuse_search", "refresh", "connections", "cull_points", "segmentation", "ba_build",
          "ba_factors", "ba_chi2", "ba_solve", "cull_keyframes", "other")


class _TimedOptimizer:
    """A gtsam optimizer whose `optimize` / `iterate` calls are timed as `ba_solve`."""

    def __init__(self, inner: Any, clock: StageClock) -> None:
        self._inner = inner
        self.optimize = clock.wrap(inner.optimize, "ba_solve")
        self.iterate = clock.wrap(inner.iterate, "ba_solve")

    def __getattr__(self, name: str) -> Any:
        return getattr(self._inner, name)


def _instrument(clock: StageClock) -> None:
    """Wrap the stages in this (child) process: class attributes and module-level names."""
    import types

    from changing_slam_ros.core.slam import local_mapping as lm
    from changing_slam_ros.core.slam import map_fusion
    from changing_slam_ros.core.map import slam_map
    from changing_slam_ros.core import system
    from changing_slam_ros.core.backend import local_ba

    wrap = clock.patch
    wrap(lm.LocalMapper, "process", "other")
    wrap(lm.LocalMapper, "_create_points", "create")
    wrap(lm.LocalMapper, "_triangulate", "triangulate")
    wrap(lm.LocalMapper, "_fuse", "fuse")
    wrap(lm.LocalMapper, "_cull_points", "cull_points")
    wrap(lm.LocalMapper, "_cull_keyframes", "cull_keyframes")
    wrap(lm, "segment_keyframe_window", "segmentation")
    wrap(lm, "refresh_points", "refresh")
    wrap(map_fusion, "refresh_points", "refresh")
    wrap(map_fusion, "search_by_projection", "fuse_search")
    wrap(lm, "local_bundle_adjust", "ba_build")
    wrap(local_ba, "add_reprojection_factors", "ba_factors")
    wrap(local_ba, "reprojection_chi2", "ba_chi2")
    wrap(slam_map.SlamMap, "update_connections", "connections")
    wrap(system.SlamSystem, "_after_objects", "objects")
    gt = local_ba.gtsam
    proxy = types.ModuleType("gtsam_timed")
    proxy.__dict__.update(gt.__dict__)
    lmo = gt.LevenbergMarquardtOptimizer
    # Construction (initial error, COLAMD ordering) is solver work too.
    proxy.LevenbergMarquardtOptimizer = clock.wrap(lambda *a: _TimedOptimizer(lmo(*a), clock), "ba_solve")  # type: ignore[attr-defined]
    local_ba.gtsam = proxy
    if hasattr(local_ba, "schur_lm"):  # the numpy solver (mapping.ba_solver: schur) is solver work too
        schur = types.ModuleType("schur_lm_timed")
        schur.__dict__.update(local_ba.schur_lm.__dict__)
        schur.solve = clock.wrap(local_ba.schur_lm.solve, "ba_solve")  # type: ignore[attr-defined]
        local_ba.schur_lm = schur


def run_child(bag: str, config: str, out: Path, cprofile: int) -> dict[str, Any]:
    """One instrumented `changing-slam run` in this process; per-keyframe CPU ms per stage."""
    from changing_slam_ros.commands import run as run_cmd

    clock = StageClock()
    _instrument(clock)
    parser = argparse.ArgumentParser()
    run_cmd.add_arguments(parser)
    args = parser.parse_args([bag, "--config", config, "--out", str(out), "--quiet", "--no-plot"])
    prof = None
    if cprofile:
        import cProfile

        prof = cProfile.Profile()
        prof.enable()
    run_cmd.main(args)
    if prof is not None:
        prof.disable()
    n_kf = clock.calls.get("other", 0)
    per_kf = {k: v / 1e6 / max(n_kf, 1) for k, v in clock.ns.items()}
    metrics = json.loads((out / "metrics.json").read_text()) if (out / "metrics.json").exists() else {}
    res: dict[str, Any] = {
        "keyframes_mapped": n_kf,
        "ms_per_keyframe": per_kf,
        "trajectory_sha256": hashlib.sha256((out / "trajectory.txt").read_bytes()).hexdigest(),
        "ate_cm": round(100 * metrics["ate_rmse_m"], 3) if metrics.get("ate_rmse_m") is not None else None,
    }
    if prof is not None:
        import io
        import pstats

        s = io.StringIO()
        pstats.Stats(prof, stream=s).sort_stats("tottime").print_stats(cprofile)
        res["cprofile"] = s.getvalue()
    return res


def run_tree(tree: Path, bag: str, config: str, cprofile: int = 0) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="bench_lm_") as tmp:
        env = {**os.environ, "PYTHONPATH": str(tree), "OPENBLAS_NUM_THREADS": "1"}  # as the graph's nodes
        cmd = [sys.executable, __file__, bag, "--config", config, "--child", tmp, "--cprofile", str(cprofile)]
        subprocess.run(cmd, check=True, env=env, cwd=tree)
        return json.loads((Path(tmp) / "bench.json").read_text())


def mapping_ms(res: dict[str, Any]) -> float:
    return sum(res["ms_per_keyframe"].get(k, 0.0) for k in STAGES)


def report(name: str, runs: list[dict[str, Any]]) -> dict[str, float]:
    med = {k: statistics.median(r["ms_per_keyframe"].get(k, 0.0) for r in runs) for k in (*STAGES, "objects")}
    med["mapping"] = statistics.median(mapping_ms(r) for r in runs)
    print(f"{name}: keyframes {[r['keyframes_mapped'] for r in runs]}, ATE cm {[r['ate_cm'] for r in runs]}, "
          f"trajectory.txt sha256 {sorted({r['trajectory_sha256'][:16] for r in runs})}")
    return med


def main() -> int:
    """Parse the options, measure, print the table.

    - `create`: points from depth (`LocalMapper._create_points`); `triangulate`: from depth-less keypoints;
    - `fuse`: fusion with the covisible keyframes (`_fuse` without the two below); `fuse_search`: its projection
      searches (`matcher.search_by_projection` with the keyframe's k-d tree built); `refresh`: descriptors, normals and
      scale distances of the touched points (`map_fusion.refresh_points`, called by fusion and triangulation);
    - `connections`: covisibility updates; `cull_points`, `segmentation`, `cull_keyframes`;
    - `ba_build`: local BA outside the solver and the two helpers below (window, observations, values, write
      back, outlier erasure); `ba_factors`: building the gtsam factors; `ba_chi2`: the two reprojection-error
      passes; `ba_solve`: gtsam's Levenberg-Marquardt (construction, i.e. initial error and ordering, included),
      or with `mapping.ba_solver: schur` the numpy solver (`schur_lm.solve`);
    - `other`: the rest of `LocalMapper.process`; `mapping` = the sum of the above (what the local_mapping node's
      `LocalMapper` costs per keyframe); `objects`: the object layer per keyframe (`SlamSystem._after_objects`).
    """
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bag")
    parser.add_argument("--config", default="sim")
    parser.add_argument("--baseline", metavar="REF", help="git ref to compare with (git archive into a temp folder)")
    parser.add_argument("--baseline-config", metavar="NAME|FILE", help="config of the baseline runs (default: --config)")
    parser.add_argument("--runs", type=int, default=1)
    parser.add_argument("--cprofile", type=int, default=0, metavar="N", help="print cProfile's top N (own time) of "
                        "one extra run of this tree (overhead included)")  # fmt: skip
    parser.add_argument("--current", metavar="DIR", default=str(REPO),
                        help="source tree measured as 'current' (default: this checkout)")
    parser.add_argument("--child", metavar="DIR", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        sys.path.insert(0, os.environ.get("PYTHONPATH", str(REPO)))
        res = run_child(args.bag, args.config, Path(args.child) / "out", args.cprofile)
        (Path(args.child) / "bench.json").write_text(json.dumps(res))
        return 0
    bag = str(Path(args.bag).resolve())
    base_config = args.baseline_config or args.config
    cur_runs, base_runs = alternating_runs(
        args.baseline, Path(args.current), args.runs,
        lambda tree: run_tree(tree, bag, args.config if tree == Path(args.current) else base_config))
    print(f"{bag}, config {args.config} (baseline {args.baseline_config or args.config}), {args.runs} run(s) per tree; "
          "thread CPU ms per keyframe, median of runs")
    cur = report("current", cur_runs)
    base = report(f"baseline {args.baseline}", base_runs) if base_runs else None
    if base is not None:
        same = {r["trajectory_sha256"] for r in cur_runs} == {r["trajectory_sha256"] for r in base_runs}
        print(f"trajectory.txt byte-identical to the baseline: {'yes' if same else 'NO'}")
    print(f"{'stage (CPU ms/keyframe)':<26}{'current':>9}" + (f"{'baseline':>10}{'ratio':>8}" if base else ""))
    for k in (*STAGES, "mapping", "objects"):
        line = f"{k:<26}{cur[k]:>9.1f}"
        if base is not None:
            line += f"{base[k]:>10.1f}" + (f"{cur[k] / base[k]:>8.2f}" if base[k] > 0 else f"{'-':>8}")
        print(line)
    if args.cprofile:
        print(run_tree(Path(args.current), bag, args.config, args.cprofile)["cprofile"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
