"""CPU of the loop-closing core per keyframe and per bag frame in `changing-slam run`: prints figures, asserts nothing.

    .venv/bin/python bench/bench_loop_closing_cpu.py BAG [--config sim] [--baseline REF] [--runs 2]
        [--cprofile N] [--current DIR] [--max-frames N]

Each run is `changing-slam run BAG --config NAME --out TMP` in a child process (this checkout, and with
`--baseline` a `git archive REF` of it, alternating) with the loop-closing binding's calls wrapped from outside
(the library is not changed for it), timed in thread CPU time (`bench/stage_clock.py`), OPENBLAS_NUM_THREADS=1
as in the graph. Time is exclusive (a stage inside another counts in the innermost only). Stages, all of the
`SlamMapLoopClosing` that `SlamSystem` drives (the loop_closing node runs the same calls on its replica):

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
from git_tree import alternating_runs  # noqa: E402
from stage_clock import StageClock  # noqa: E402

STAGES = ("add", "quantise", "bow", "refresh", "active_mask", "process", "query", "verify", "correct", "apply",
          "global_ba", "merge", "erase", "msg_in", "replica", "apply_delta", "snapshot", "msg_out")


class _GatedClock(StageClock):
    """A StageClock whose wrapped functions time only while `active` (split mode: the loop side's calls, not the
    same functions called by the tracking side's relocalisation index)."""

    active = True

    def wrap(self, fn: Any, label: str) -> Any:
        timed = super().wrap(fn, label)

        def gated(*args: Any, **kwargs: Any) -> Any:
            return timed(*args, **kwargs) if self.active else fn(*args, **kwargs)

        return gated


class _Digests:
    """Running sha256 of query results and of the loops found."""

    def __init__(self) -> None:
        self.queries = hashlib.sha256()
        self.loops = hashlib.sha256()
        self.n_queries = 0
        self.n_loops = 0
        self.keyframes = 0  # `LoopCloser.process` calls


def _instrument(clock: StageClock, digests: _Digests) -> None:
    """Wrap the stages in this (child) process: class attributes and module-level names."""
    import numpy as np

    from changing_slam_ros.core.map import keyframe_database as kdb
    from changing_slam_ros.core.slam import loop_closing as lc
    from changing_slam_ros.core.features import vocabulary as voc

    wrap = clock.patch
    wrap(lc.SlamMapLoopClosing, "add", "add")
    wrap(lc.SlamMapLoopClosing, "erase", "erase")
    wrap(lc.SlamMapLoopClosing, "refresh_active_points", "refresh")
    wrap(lc.SlamMapLoopClosing, "process", "process")
    wrap(lc.SlamMapLoopClosing, "find_loop", "process")  # the split graph's loop side calls it for `process`
    wrap(lc.SlamMapLoopClosing, "detect_merge_in", "merge")
    wrap(lc.SlamMapLoopClosing, "candidates", "reloc")
    wrap(lc, "_active_mask", "active_mask")
    wrap(lc, "verify", "verify")
    wrap(lc.LoopCloser, "_correct", "correct")
    wrap(lc, "apply_correction", "apply")
    wrap(lc, "global_bundle_adjust", "global_ba")
    wrap(voc.Vocabulary, "transform", "quantise")
    wrap(voc.Vocabulary, "_bow_from_words", "bow")  # the name before the word cache
    wrap(voc.Vocabulary, "bow_from_words", "bow")
    query = clock.wrap(kdb.KeyframeDatabase._query, "query")  # noqa: SLF001 - timed from outside

    def digest_query(*args: Any, **kwargs: Any) -> Any:
        out = query(*args, **kwargs)
        digests.n_queries += 1
        digests.queries.update(repr([(c.keyframe_id, c.score, c.accumulated_score) for c in out]).encode())
        return out

    kdb.KeyframeDatabase._query = digest_query  # type: ignore[method-assign]
    process = lc.LoopCloser.process

    def digest_loop(self: Any, *args: Any, **kwargs: Any) -> Any:
        digests.keyframes += 1
        corr = process(self, *args, **kwargs)
        if corr is not None:
            digests.n_loops += 1
            digests.loops.update(f"{corr.query_kf_id} {corr.match_kf_id} ".encode())
            digests.loops.update(np.ascontiguousarray(corr.T_match_query).tobytes())
        return corr

    lc.LoopCloser.process = digest_loop  # type: ignore[method-assign]


def run_child(bag: str, config: str, out: Path, cprofile: int, max_frames: int, split: bool) -> dict[str, Any]:
    """One instrumented `changing-slam run` in this process; CPU ms per keyframe per stage."""
    from changing_slam_ros.commands import run as run_cmd

    clock = _GatedClock()
    clock.active = not split
    digests = _Digests()
    _instrument(clock, digests)
    parser = argparse.ArgumentParser()
    run_cmd.add_arguments(parser)
    argv = [bag, "--config", config, "--out", str(out), "--quiet", "--no-plot"]
    if max_frames:
        argv += ["--max-frames", str(max_frames)]
    args = parser.parse_args(argv)
    prof = None
    if cprofile:
        import cProfile

        prof = cProfile.Profile()
        prof.enable()
    n_frames = _run_split(clock, argv, out) if split else run_cmd.main(args)
    if prof is not None:
        prof.disable()
    n_kf = digests.keyframes
    metrics = json.loads((out / "metrics.json").read_text()) if (out / "metrics.json").exists() else {}
    res: dict[str, Any] = {
        "keyframes": n_kf,
        "frames": metrics.get("frames", n_frames),
        "refresh_calls": clock.calls.get("refresh", 0),
        "ms_per_keyframe": {k: v / 1e6 / max(n_kf, 1) for k, v in clock.ns.items()},
        "ms_total": {k: v / 1e6 for k, v in clock.ns.items()},
        "trajectory_sha256": hashlib.sha256((out / "trajectory.txt").read_bytes()).hexdigest(),
        "keyframes_sha256": hashlib.sha256((out / "keyframes.txt").read_bytes()).hexdigest(),
        "queries": digests.n_queries,
        "queries_sha256": digests.queries.hexdigest(),
        "loops": digests.n_loops,
        "loops_sha256": digests.loops.hexdigest(),
    }
    if prof is not None:
        import io
        import pstats

        s = io.StringIO()
        pstats.Stats(prof, stream=s).sort_stats("tottime").print_stats(cprofile)
        res["cprofile"] = s.getvalue()
    return res


def _run_split(clock: _GatedClock, argv: list[str], out: Path) -> int:
    """The chained sides over the bag, loop side's messages round-tripped through CDR; returns the frame count.
    Writes trajectory.txt and keyframes.txt of the tracking side as `changing-slam run` does."""
    import copy

    from rclpy.serialization import deserialize_message, serialize_message

    from changing_slam_msgs.msg import Keyframe as KeyframeMsg
    from changing_slam_msgs.msg import MapUpdate as MapUpdateMsg
    from changing_slam_ros.commands import run as run_cmd
    from changing_slam_ros.commands.dynamic_options import dynamic_setup
    from changing_slam_ros.io.dataset import open_dataset
    from changing_slam_ros.io.dataset_config import settings_from_mapping
    from changing_slam_ros.io.tum_trajectory import write_tum_trajectory
    from changing_slam_ros.nodes import replication_conversions as rc
    from changing_slam_ros.nodes import split_backend as sb
    from changing_slam_ros.nodes.slam_backend import load_backend_config

    parser = argparse.ArgumentParser()
    run_cmd.add_arguments(parser)
    args = parser.parse_args(argv)
    cfg = load_backend_config(args.config)
    dynamic = dynamic_setup(args, cfg.data, cfg.where)
    source = open_dataset(args.source, settings_from_mapping(cfg.data, cfg.where))
    try:
        from changing_slam_ros.nodes.split_chains import ChainedGraph
    except ImportError:  # a baseline tree where it lives in split_backend
        ChainedGraph = sb.ChainedGraph  # noqa: N806
    chain = ChainedGraph.build(cfg)
    assert chain.loop is not None
    loop = chain.loop
    clock.patch(loop, "on_keyframe", "replica")
    clock.patch(loop, "on_update", "replica")
    clock.patch(sb, "apply_delta", "apply_delta")
    clock.patch(sb, "apply_merge", "apply_delta")
    clock.patch(sb, "snapshot", "snapshot")
    clock.patch(sb, "diff", "snapshot")
    msg_in = clock.wrap(lambda f, data, t, topic: f(deserialize_message(data, t), topic), "msg_in")
    msg_out = clock.wrap(lambda r, m: serialize_message(rc.loop_result_to_msg(r, 0, "map", m)), "msg_out")

    class _WireLoop:
        """The loop side as the node sees it: each input arrives as CDR bytes, each verdict leaves as one."""

        def on_keyframe(self, packet: Any) -> None:
            data = serialize_message(rc.packet_to_msg(packet, "map"))
            clock.active = True
            loop.on_keyframe(msg_in(rc.packet_from_msg, data, KeyframeMsg, "/tracking/keyframes"))
            clock.active = False

        def on_update(self, update: Any) -> Any:
            data = serialize_message(rc.update_to_msg(update, 0, "map"))
            clock.active = True
            result = loop.on_update(msg_in(rc.update_from_msg, data, MapUpdateMsg, "/local_mapping/map_updates"))
            if result is not None:
                msg_out(result, update.delta.map_id)
            clock.active = False
            return copy.deepcopy(result)  # what the owner gets comes from the wire too

    chain.loop = _WireLoop()  # type: ignore[assignment]
    n = 0
    for rgbd in source:
        if args.max_frames and n >= args.max_frames:
            break
        chain.process(rgbd, dynamic.detections_for(rgbd))
        n += 1
    system = chain.tracking.system
    out.mkdir(parents=True, exist_ok=True)
    write_tum_trajectory(out / "trajectory.txt", system.final_trajectory())
    write_tum_trajectory(out / "keyframes.txt", system.keyframe_trajectory())
    return n


def run_tree(tree: Path, bag: str, config: str, cprofile: int = 0, max_frames: int = 0,
             split: bool = False) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="bench_lc_") as tmp:
        env = {**os.environ, "PYTHONPATH": str(tree), "OPENBLAS_NUM_THREADS": "1"}  # as the graph's nodes
        cmd = [sys.executable, __file__, bag, "--config", config, "--child", tmp, "--cprofile", str(cprofile),
               "--max-frames", str(max_frames)] + (["--split"] if split else [])
        subprocess.run(cmd, check=True, env=env, cwd=tree)
        return json.loads((Path(tmp) / "bench.json").read_text())


def loop_ms(res: dict[str, Any], per: str) -> float:
    total = sum(res["ms_total"].get(k, 0.0) for k in STAGES)
    return total / max(res[per], 1)


def report(name: str, runs: list[dict[str, Any]]) -> dict[str, float]:
    med = {k: statistics.median(r["ms_per_keyframe"].get(k, 0.0) for r in runs) for k in (*STAGES, "reloc")}
    med["loop"] = statistics.median(loop_ms(r, "keyframes") for r in runs)
    med["loop_per_frame"] = statistics.median(loop_ms(r, "frames") for r in runs)
    r0 = runs[0]
    print(f"{name}: keyframes {[r['keyframes'] for r in runs]}, frames {r0['frames']}, refresh calls "
          f"{[r['refresh_calls'] for r in runs]}, queries {r0['queries']}, loops {r0['loops']}")
    for key in ("trajectory_sha256", "keyframes_sha256", "queries_sha256", "loops_sha256"):
        print(f"  {key[:-7]:<11} sha256 {sorted({r[key][:16] for r in runs})}")
    return med


def main() -> int:
    """Parse the options, measure, print the table.

    - `add`: indexing a new keyframe (`SlamMapLoopClosing.add`) minus the two below; `quantise`:
      `Vocabulary.transform` (descriptor -> word through the tree); `bow`: the tf-idf histogram of words;
    - `refresh`: `refresh_active_points` (after object states change) minus `active_mask` (the per-keyframe mask of
      usable keypoints, `_active_mask`, also used by `process`) and the re-indexing it triggers (`add`/`quantise`/`bow`);
    - `process`: `SlamMapLoopClosing.process` minus `query` (the database query, `KeyframeDatabase._query`),
      `verify` (geometric verification), `correct` (pose graph, `LoopCloser._correct`), `apply` (writing a
      correction into the map) and `global_ba`; `merge`: `detect_merge_in` (Atlas); `erase`;
    - `loop` = the sum of the above: the loop_closing node's core per keyframe (its replica upkeep excluded);
    - `reloc`: `candidates` (tracking's relocalisation query on its own index), reported apart.

    With `--split` the run is the split graph's three sides chained in the lossless order in one process
    (`nodes.split_chains.ChainedGraph`, the same config and detections as `changing-slam run`), and what is timed is
    the loop_closing node's work per keyframe: the stages above on its replica plus `msg_in` (CDR deserialisation and
    `packet_from_msg` / `update_from_msg` of the keyframe packet and the map updates: each is serialised by the
    sender's conversion first, untimed), `replica` (`LoopSide.on_keyframe` / `on_update` around the core),
    `apply_delta` (the owner's delta into the replica) and `msg_out` (`loop_result_to_msg` + serialisation). Not
    included: rclpy's executor and DDS. The digests are then of the chain's tracking trajectory.

    Per tree: keyframes, frames, calls of `refresh`, the median over runs of CPU ms per keyframe per stage and of
    `loop` per bag frame, and digests: sha256 of trajectory.txt and keyframes.txt, of every loop found (query,
    match, T_match_query bytes) and of every database query's result (ids, scores, accumulated scores: equal digests
    mean identical query results, call by call).
    """
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bag")
    parser.add_argument("--config", default="sim")
    parser.add_argument("--baseline", metavar="REF", help="git ref to compare with (git archive into a temp folder)")
    parser.add_argument("--runs", type=int, default=1)
    parser.add_argument("--max-frames", type=int, default=0, help="first N frames only (0: all)")
    parser.add_argument("--split", action="store_true", help="the split graph's sides chained in-process: the "
                        "loop_closing node's work (replica, messages) besides the core")  # fmt: skip
    parser.add_argument("--cprofile", type=int, default=0, metavar="N", help="print cProfile's top N (own time) of "
                        "one extra run of this tree (overhead included)")  # fmt: skip
    parser.add_argument("--current", metavar="DIR", default=str(REPO),
                        help="source tree measured as 'current' (default: this checkout)")
    parser.add_argument("--child", metavar="DIR", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        sys.path.insert(0, os.environ.get("PYTHONPATH", str(REPO)))
        res = run_child(args.bag, args.config, Path(args.child) / "out", args.cprofile, args.max_frames, args.split)
        (Path(args.child) / "bench.json").write_text(json.dumps(res))
        return 0
    bag = str(Path(args.bag).resolve())
    cur_runs, base_runs = alternating_runs(
        args.baseline, Path(args.current), args.runs,
        lambda tree: run_tree(tree, bag, args.config, max_frames=args.max_frames, split=args.split))
    print(f"{bag}, config {args.config}, {'split chain' if args.split else 'changing-slam run'}, {args.runs} run(s) "
          "per tree; thread CPU ms per keyframe, median of runs")
    cur = report("current", cur_runs)
    base = report(f"baseline {args.baseline}", base_runs) if base_runs else None
    if base is not None:
        for key in ("trajectory_sha256", "keyframes_sha256", "queries_sha256", "loops_sha256"):
            same = {r[key] for r in cur_runs} == {r[key] for r in base_runs}
            print(f"{key[:-7]} identical to the baseline: {'yes' if same else 'NO'}")
    print(f"{'stage (CPU ms/keyframe)':<26}{'current':>9}" + (f"{'baseline':>10}{'ratio':>8}" if base else ""))
    for k in (*STAGES, "loop", "loop_per_frame", "reloc"):
        label = "loop (ms per bag frame)" if k == "loop_per_frame" else k
        line = f"{label:<26}{cur[k]:>9.2f}"
        if base is not None:
            line += f"{base[k]:>10.2f}" + (f"{cur[k] / base[k]:>8.2f}" if base[k] > 0 else f"{'-':>8}")
        print(line)
    if args.cprofile:
        print(run_tree(Path(args.current), bag, args.config, args.cprofile, args.max_frames, args.split)["cprofile"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
