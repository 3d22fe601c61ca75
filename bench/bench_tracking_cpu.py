"""CPU per frame of the tracking path, per stage: prints figures, asserts nothing.

    .venv/bin/python bench/bench_tracking_cpu.py [--data redkitchen|walking|PATH] [--frames N]
        [--baseline REF] [--repeats R] [--cprofile N] [--json FILE] [--tree DIR]

Runs `SlamSystem` (as `changing-slam run` does: loop closing on; on the simulated walking scene the
dynamic stage with the simulator's oracle boxes) and measures the thread CPU time
(`time.thread_time`, not wall time: the machine is shared) of each stage of `SlamSystem.process`.
Time is exclusive: a stage called inside another (pose optimisation inside local-map tracking) is
counted once, in the innermost stage. Stages:

The rows and the method: `main`. `--segmentation both` runs this tree with `dynamic.segmentation` on and off,
alternating, and prints the ratio on / off per stage and the segmentation's own CPU per frame.
"""

from __future__ import annotations

import argparse
import dataclasses
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

DATA = {
    "redkitchen": (REPO.parent / "shared/data/7scenes_redkitchen", "7scenes", False),
    "walking": (Path("/tmp/sim_cache/walking_xyz_640x480_s0_f300_people3"), "sim", True),
}
STAGES = ("features", "dynamic", "matching", "pose_opt", "local_map", "keyframe", "reloc", "other")
NON_TRACKING = ("local_mapping", "objects", "loop_closing")


def _instrument(system: Any, clock: StageClock) -> None:
    """Wrap the stages' methods on the instances (the library's classes stay untouched)."""
    wrap = clock.patch
    tr = system.tracker
    wrap(tr, "_track_frame_to_frame", "matching")
    wrap(tr, "_optimise", "pose_opt")
    wrap(tr, "_track_local_map", "local_map")
    wrap(tr, "_need_keyframe", "keyframe")
    wrap(tr, "_make_keyframe", "keyframe")
    wrap(tr, "_relocalise", "reloc")
    wrap(system, "_after_objects", "objects")
    wrap(system.mapper, "process", "local_mapping")
    wrap(system.loop_closer, "process", "loop_closing")
    wrap(system.loop_closer, "detect_merge_in", "loop_closing")
    wrap(system.dynamic_filter, "before_tracking", "dynamic")
    wrap(system.dynamic_filter, "after_tracking", "dynamic")
    wrap(system, "process", "other")
    original = system._extractor_for

    def extractor_for(camera: Any) -> Any:
        ex = original(camera)
        if not getattr(ex, "_bench_wrapped", False):
            ex.extract = clock.wrap(ex.extract, "features")
            ex._bench_wrapped = True
        return ex

    system._extractor_for = extractor_for


def run_once(data: str, frames: int, cprofile: int = 0, segmentation: bool | None = None) -> dict[str, Any]:
    """One run in this process (the package imported from sys.path); per-frame CPU ms per stage."""
    from changing_slam_ros.commands.run import _loop_closing, system_config_from_mapping
    from changing_slam_ros.config import find_config, load_yaml, section
    from changing_slam_ros.core.dynamic.dynamic_filter import DynamicConfig, DynamicFilter
    from changing_slam_ros.core.system import SlamSystem
    from changing_slam_ros.io.dataset import open_dataset
    from changing_slam_ros.io.dataset_config import settings_from_mapping
    from changing_slam_ros.io.detections_file import find_detections_file, read_detections_file

    source_path, config_name, dynamic = DATA.get(data, (Path(data), "sim", True))
    path = find_config(config_name)
    cfg = load_yaml(path)
    source = open_dataset(str(source_path), settings_from_mapping(cfg, str(path)))
    closing = _loop_closing(cfg, str(path))
    dyn_cfg = section(DynamicConfig, cfg.get("dynamic"), f"{path}: dynamic")
    if segmentation is not None:
        dyn_cfg = dataclasses.replace(dyn_cfg, segmentation=segmentation)
    flt = DynamicFilter(dyn_cfg) if dynamic else None
    oracle = read_detections_file(find_detections_file(source_path)) if dynamic else None
    system = SlamSystem(system_config_from_mapping(cfg, str(path)), loop_closer=closing, keyframe_index=closing,
                        dynamic_filter=flt)
    clock = StageClock()
    _instrument(system, clock)
    n = min(frames, len(source)) if frames else len(source)
    prof = None
    if cprofile:
        import cProfile

        prof = cProfile.Profile()
    for i, rgbd in enumerate(source):
        if i >= n:
            break
        dets = oracle.for_stamp(rgbd.stamp_ns) if oracle is not None else None
        if prof is not None:
            prof.enable()
        system.process(rgbd, dets)
        if prof is not None:
            prof.disable()
    digest = hashlib.sha256()
    for rec in system.records:
        digest.update(b"-" if rec.T_world_cam_online is None else rec.T_world_cam_online.tobytes())
    per_frame = {k: v / 1e6 / n for k, v in clock.ns.items()}
    out: dict[str, Any] = {
        "frames": n,
        "tracked": system.n_tracked(),
        "keyframes": system.atlas.n_keyframes,
        "ms_per_frame": per_frame,
        "online_sha256": digest.hexdigest(),
    }
    seg_ms = getattr(flt, "segmentation_cpu_ms", None) if flt is not None else None
    if seg_ms:
        out["segmentation_cpu_ms"] = {"median": statistics.median(seg_ms), "mean": statistics.fmean(seg_ms),
                                      "p90": sorted(seg_ms)[int(0.9 * (len(seg_ms) - 1))]}
    gt = source.groundtruth
    if gt is not None and system.n_tracked() >= 3:
        from changing_slam_ros.eval.ate import ate

        out["ate_cm"] = ate(gt, system.final_trajectory()).stats.rmse * 100
        out["ate_online_cm"] = ate(gt, system.online_trajectory()).stats.rmse * 100
    if prof is not None:
        import io
        import pstats

        s = io.StringIO()
        pstats.Stats(prof, stream=s).sort_stats("tottime").print_stats(cprofile)
        out["cprofile"] = s.getvalue()
    return out


def tracking_ms(res: dict[str, Any]) -> float:
    return sum(res["ms_per_frame"].get(k, 0.0) for k in STAGES)


def run_tree(tree: Path, data: str, frames: int, segmentation: bool | None = None) -> dict[str, Any]:
    """The benchmark on another source tree, in a child process with PYTHONPATH=tree."""
    with tempfile.NamedTemporaryFile(suffix=".json") as f:
        env = {**os.environ, "PYTHONPATH": str(tree), "OPENBLAS_NUM_THREADS": "1"}
        extra = [] if segmentation is None else ["--segmentation", "on" if segmentation else "off"]
        subprocess.run([sys.executable, __file__, "--tree", str(tree), "--data", data, "--frames", str(frames),
                        "--json", f.name, "--quiet", *extra], check=True, env=env)
        return json.loads(Path(f.name).read_text())


def best(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Per stage, the smallest per-frame mean over the runs."""
    keys = set().union(*(r["ms_per_frame"] for r in runs))
    out = dict(runs[0])
    out["ms_per_frame"] = {k: min(r["ms_per_frame"].get(k, 0.0) for r in runs) for k in keys}
    return out


def report(cur: dict[str, Any], base: dict[str, Any] | None) -> None:
    print(f"frames {cur['frames']}, tracked {cur['tracked']}, keyframes {cur['keyframes']}"
          + (f", ATE {cur['ate_cm']:.2f} cm (online {cur['ate_online_cm']:.2f})" if "ate_cm" in cur else ""))
    if base is not None:
        print(f"baseline: tracked {base['tracked']}, keyframes {base['keyframes']}"
              + (f", ATE {base['ate_cm']:.2f} cm (online {base['ate_online_cm']:.2f})" if "ate_cm" in base else ""))
        same = cur["online_sha256"] == base["online_sha256"]
        print(f"online trajectory bit-identical to the baseline: {'yes' if same else 'NO'}")
    print(f"{'stage (CPU ms/frame)':<22}{'current':>9}" + (f"{'baseline':>10}{'ratio':>8}" if base else ""))
    rows = [*STAGES, "tracking", *NON_TRACKING]
    for k in rows:
        c = tracking_ms(cur) if k == "tracking" else cur["ms_per_frame"].get(k, 0.0)
        line = f"{k:<22}{c:>9.2f}"
        if base is not None:
            b = tracking_ms(base) if k == "tracking" else base["ms_per_frame"].get(k, 0.0)
            line += f"{b:>10.2f}" + (f"{c / b:>8.2f}" if b > 0 else f"{'-':>8}")
        print(line)


def main() -> int:
    """Parse the options, measure, print the table.

    - `features`: ORB extraction, undistortion, depth lookup (`OrbExtractor.extract`);
    - `dynamic`: the dynamic stage before and after tracking (keypoint classification, object EKFs);
    - `matching`: frame-to-frame projection search (+ reference-keyframe fallback);
    - `pose_opt`: every pose optimisation;
    - `local_map`: local keyframes, local points and their projection search;
    - `keyframe`: keyframe decision and creation;
    - `reloc`: relocalisation (matching + PnP; its optimisation and local map go to their stages);
    - `other`: the rest of `process` outside local mapping, objects and loop closing (feature subset,
      frame records, re-anchoring);
    - `tracking` = the sum of the above: the per-frame CPU of the tracking thread;
    - `local_mapping`, `objects`, `loop_closing`: per frame, for scale (not part of tracking).

    `--baseline REF` extracts `git archive REF` into a temporary folder and runs the same benchmark on it
    (`--tree`), alternating runs, then prints the ratio current / baseline per stage and whether the two
    online trajectories are bit-identical (an exact rewrite keeps them so). With `--repeats R` each stage
    takes its smallest per-frame mean over R runs (CPU time only grows under contention).
    `--cprofile N` prints cProfile's top N functions by own time over one extra run (overhead included).
    """
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default="redkitchen", help="redkitchen, walking, or a TUM folder (sim config)")
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--baseline", metavar="REF", help="git ref to compare with (git archive into a temp folder)")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--cprofile", type=int, default=0, metavar="N")
    parser.add_argument("--json", metavar="FILE")
    parser.add_argument("--tree", metavar="DIR", help="import changing_slam_ros from DIR (used for the baseline)")
    parser.add_argument("--current", metavar="DIR", default=str(REPO),
                        help="source tree measured as 'current' (default: this checkout)")
    parser.add_argument("--quiet", action="store_true")
    parser.add_argument("--segmentation", choices=("config", "on", "off", "both"), default="config",
                        help="dynamic.segmentation: from the config, forced on/off, or both (on vs off, ratio)")
    args = parser.parse_args()
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    sys.path.insert(0, str(Path(args.tree) if args.tree else REPO))

    seg = None if args.segmentation == "config" else args.segmentation == "on"
    if args.json:  # child mode: one run, figures to a file
        res = run_once(args.data, args.frames, segmentation=seg)
        Path(args.json).write_text(json.dumps(res))
        return 0
    if args.segmentation == "both":  # segmentation on vs off, alternating runs of this tree
        on_runs, off_runs = [], []
        for _ in range(args.repeats):
            on_runs.append(run_tree(Path(args.current), args.data, args.frames, True))
            off_runs.append(run_tree(Path(args.current), args.data, args.frames, False))
        print(f"data {args.data}, {args.frames} frames, {args.repeats} run(s) each; 'current' = dynamic.segmentation "
              "on, 'baseline' = off; thread CPU time, best of runs per stage")
        report(best(on_runs), best(off_runs))
        for r in on_runs:
            print("segmentation CPU ms per frame (matching included):", r.get("segmentation_cpu_ms"))
        return 0
    cur_runs, base_runs = alternating_runs(args.baseline, Path(args.current), args.repeats,
                                           lambda tree: run_tree(tree, args.data, args.frames))
    print(f"data {args.data}, {args.frames} frames, {args.repeats} run(s) each; thread CPU time, best of runs per stage")
    report(best(cur_runs), best(base_runs) if base_runs else None)
    if args.cprofile:
        res = run_once(args.data, args.frames, cprofile=args.cprofile)
        print(res["cprofile"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
