"""gtsam solver settings for local BA on real keyframe windows: CPU and final error per setting; asserts nothing.

    .venv/bin/python bench/bench_local_ba_solver.py capture BAG --config sim --windows FILE
    .venv/bin/python bench/bench_local_ba_solver.py compare FILE [FILE ...] [--repeats 3] [--settings a,b,...]

`capture` runs `changing-slam run BAG` in this process with `local_ba.optimise` wrapped: every local BA's graph
and initial values are stored (gtsam's own serialisation) in FILE (a pickle) while the run goes on unchanged.
`compare` re-solves each stored window with each solver setting (`SETTINGS`) and prints, per setting, the thread
CPU of the solve (construction included, min of `--repeats`), the final error against the default's (the cost
gtsam minimises: robust whitened reprojection error plus the fixed poses' priors) and the largest pose / point
change against the default's result. The settings alternate window by window so load drifts hit all alike.
"""

from __future__ import annotations

import argparse
import pickle
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gtsam
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from changing_slam_ros.core.backend import local_ba  # noqa: E402

_L_CHR = ord("l")


def _capture(bag: str, config: str, out: Path, windows: Path) -> None:
    from changing_slam_ros.commands import run as run_cmd

    stored: list[dict[str, Any]] = []
    inner = local_ba.optimise

    def recording(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, params: gtsam.LevenbergMarquardtParams,
                  stop: Callable[[], bool] | None = None) -> tuple[gtsam.Values, int, bool]:
        stored.append({"graph": graph.serialize(), "values": values.serialize(), "iterations": params.getMaxIterations()})
        return inner(graph, values, params, stop)

    inner_gtsam = local_ba._solve_gtsam

    def recording_gtsam(slam_map: Any, local: Any, fixed: Any, keep_pts: Any, obs: Any, cam: Any, cfg: Any, *rest: Any) -> Any:
        problem = local_ba.schur_problem(slam_map, local, fixed, keep_pts, obs, cam, cfg)
        n = len(stored)
        out = inner_gtsam(slam_map, local, fixed, keep_pts, obs, cam, cfg, *rest)
        if len(stored) > n:
            stored[-1]["problem"] = problem
            stored[-1]["keys"] = (local_ba.pose_keys(np.asarray(local + fixed)).tolist(), local_ba.point_keys(keep_pts).tolist())
        return out

    local_ba.optimise = recording  # type: ignore[assignment]
    local_ba._solve_gtsam = recording_gtsam  # type: ignore[assignment]
    parser = argparse.ArgumentParser()
    run_cmd.add_arguments(parser)
    run_cmd.main(parser.parse_args([bag, "--config", config, "--out", str(out), "--quiet", "--no-plot"]))
    tmp = windows.with_suffix(".tmp")
    tmp.write_bytes(pickle.dumps(stored))
    tmp.rename(windows)
    print(f"{len(stored)} local BA windows -> {windows}")


def _keys(values: gtsam.Values) -> tuple[list[int], list[int]]:
    points, poses = [], []
    for k in values.keys():
        (points if gtsam.Symbol(k).chr() == _L_CHR else poses).append(k)
    return points, poses


def _schur_ordering(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> gtsam.Ordering:
    """All points, then the poses (the Schur complement's order), points in key order, poses by COLAMD last."""
    points, poses = _keys(values)
    return gtsam.Ordering.ColamdConstrainedLastNonlinearFactorGraph(graph, gtsam.KeyVector(poses))


def _hand_ordering(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> gtsam.Ordering:
    points, poses = _keys(values)
    o = gtsam.Ordering()
    for k in points + poses:
        o.push_back(k)
    return o


def _params(iterations: int, **kw: Any) -> gtsam.LevenbergMarquardtParams:
    p = gtsam.LevenbergMarquardtParams()
    p.setMaxIterations(iterations)
    if "solver" in kw:
        p.setLinearSolverType(kw["solver"])
    if kw.get("diagonal"):
        p.setDiagonalDamping(True)
    if "lambda0" in kw:
        p.setlambdaInitial(kw["lambda0"])
    if "ordering_type" in kw:
        p.setOrderingType(kw["ordering_type"])
    return p


SETTINGS: dict[str, dict[str, Any]] = {
    "default": {},
    "schur_colamd": {"ordering": _schur_ordering},
    "schur_hand": {"ordering": _hand_ordering},
    "seq_chol": {"solver": "SEQUENTIAL_CHOLESKY"},
    "seq_chol_schur": {"solver": "SEQUENTIAL_CHOLESKY", "ordering": _hand_ordering},
    "metis": {"ordering_type": "METIS"},
    "cholmod": {"solver": "CHOLMOD"},
    "diag_damping": {"diagonal": True},
    "lambda1e-3": {"lambda0": 1e-3},
}


def _solve(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, iterations: int,
           setting: dict[str, Any]) -> tuple[gtsam.Values, float, int, int]:
    kw = {k: v for k, v in setting.items() if k != "ordering"}
    t0 = time.thread_time_ns()
    params = _params(iterations, **kw)
    if "ordering" in setting:
        params.setOrdering(setting["ordering"](graph, values))
    opt = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    result = opt.optimize()
    ms = (time.thread_time_ns() - t0) / 1e6
    return result, ms, opt.iterations(), opt.getInnerIterations() if hasattr(opt, "getInnerIterations") else -1


def _schur_values(w: dict[str, Any], values: gtsam.Values, res: Any) -> gtsam.Values:
    """gtsam Values of a `schur_lm` result (fixed poses as they were), to evaluate the graph's own error on it."""
    from changing_slam_ros.core.backend import schur_lm  # noqa: F401

    out = gtsam.Values()
    pose_keys, point_keys = w["keys"]
    n_free = len(res.T_world_cam)
    for i, k in enumerate(pose_keys):
        out.insert(k, gtsam.Pose3(res.T_world_cam[i]) if i < n_free else values.atPose3(k))
    for i, k in enumerate(point_keys):
        out.insertPoint3(k, res.points[i])
    return out


def _max_change(a: gtsam.Values, b: gtsam.Values) -> tuple[float, float]:
    """Largest translation difference of poses and of points between two results (m)."""
    points, poses = _keys(a)
    dp = max((np.linalg.norm(a.atPose3(k).translation() - b.atPose3(k).translation()) for k in poses), default=0.0)
    dl = max((np.linalg.norm(a.atPoint3(k) - b.atPoint3(k)) for k in points), default=0.0)
    return float(dp), float(dl)


def _compare_schur(files: list[Path], repeats: int) -> None:
    """gtsam's LM (default settings) against `schur_lm` on the same windows: CPU and the graph's final error."""
    from changing_slam_ros.core.backend import schur_lm

    ms_g, ms_s, rel, dpose, dpoint, it_g, it_s, start = [], [], [], [], [], [], [], []
    for f in files:
        for w in pickle.loads(f.read_bytes()):
            if "problem" not in w:
                continue
            graph = gtsam.NonlinearFactorGraph()
            graph.deserialize(w["graph"])
            values = gtsam.Values()
            values.deserialize(w["values"])
            best_g = best_s = float("inf")
            for _ in range(repeats):
                try:
                    ref, ms, itg, _ = _solve(graph, values, w["iterations"], SETTINGS["default"])
                except RuntimeError:
                    ref = None
                    break
                best_g = min(best_g, ms)
                t0 = time.thread_time_ns()
                res = schur_lm.solve(w["problem"], schur_lm.LMSettings(iterations=w["iterations"]))
                best_s = min(best_s, (time.thread_time_ns() - t0) / 1e6)
            if ref is None:
                continue
            mine = _schur_values(w, values, res)
            e0, e_ref, e_mine = graph.error(values), graph.error(ref), graph.error(mine)
            start.append(e0)
            ms_g.append(best_g)
            ms_s.append(best_s)
            rel.append(e_mine / e_ref - 1.0)
            dp, dl = _max_change(mine, ref)
            dpose.append(dp)
            dpoint.append(dl)
            it_g.append(itg)
            it_s.append(res.iterations)
            print(f"  window {len(ms_g):3d}: error {e0:10.1f} -> gtsam {e_ref:10.3f} schur {e_mine:10.3f} "
                  f"(own {res.error_after:10.3f}), iterations {itg} / {res.iterations}, ms {best_g:6.1f} / {best_s:6.1f}")
    print(f"{len(ms_g)} windows: thread CPU ms per solve (min of {repeats}) gtsam {statistics.mean(ms_g):.1f}, "
          f"schur {statistics.mean(ms_s):.1f} (ratio {statistics.mean(ms_s) / statistics.mean(ms_g):.2f}); final error "
          f"schur / gtsam - 1: mean {statistics.mean(rel):.2e}, min {min(rel):.2e}, max {max(rel):.2e}; largest "
          f"change against gtsam's result: poses {1e3 * max(dpose):.3f} mm, points {1e3 * max(dpoint):.3f} mm; "
          f"iterations mean {statistics.mean(it_g):.2f} / {statistics.mean(it_s):.2f}")


def _compare(files: list[Path], names: list[str], repeats: int) -> None:
    rows: dict[str, dict[str, list[float]]] = {n: {"ms": [], "rel_err": [], "dpose": [], "dpoint": [], "it": []} for n in names}
    n_win = 0
    for f in files:
        for w in pickle.loads(f.read_bytes()):
            graph = gtsam.NonlinearFactorGraph()
            graph.deserialize(w["graph"])
            values = gtsam.Values()
            values.deserialize(w["values"])
            try:
                ref, _, _, _ = _solve(graph, values, w["iterations"], SETTINGS["default"])
            except RuntimeError:
                continue
            n_win += 1
            e_ref = graph.error(ref)
            best = {n: float("inf") for n in names}
            results: dict[str, tuple[gtsam.Values, int]] = {}
            for _ in range(repeats):
                for n in names:
                    try:
                        res, ms, it, _ = _solve(graph, values, w["iterations"], SETTINGS[n])
                    except RuntimeError:
                        res, ms, it = values, float("nan"), -1
                    best[n] = min(best[n], ms)
                    results[n] = (res, it)
            for n in names:
                res, it = results[n]
                rows[n]["ms"].append(best[n])
                rows[n]["rel_err"].append(graph.error(res) / e_ref - 1.0)
                dp, dl = _max_change(res, ref)
                rows[n]["dpose"].append(dp)
                rows[n]["dpoint"].append(dl)
                rows[n]["it"].append(it)
    print(f"{n_win} windows from {[str(f) for f in files]}, thread CPU ms per solve (min of {repeats}), "
          f"final error relative to the default's")
    base = statistics.mean(rows[names[0]]["ms"])
    print(f"{'setting':<16}{'ms mean':>9}{'ratio':>7}{'err mean':>11}{'err max':>11}{'err min':>11}"
          f"{'dpose max mm':>14}{'dpoint max mm':>15}{'iters':>7}")
    for n in names:
        r = rows[n]
        ms = statistics.mean(r["ms"])
        print(f"{n:<16}{ms:>9.2f}{ms / base:>7.2f}{statistics.mean(r['rel_err']):>11.2e}{max(r['rel_err']):>11.2e}"
              f"{min(r['rel_err']):>11.2e}{1e3 * max(r['dpose']):>14.4f}{1e3 * max(r['dpoint']):>15.4f}"
              f"{statistics.mean(r['it']):>7.2f}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="cmd", required=True)
    cap = sub.add_parser("capture")
    cap.add_argument("bag")
    cap.add_argument("--config", default="sim")
    cap.add_argument("--windows", required=True, type=Path)
    cap.add_argument("--out", type=Path, default=None)
    cmp_ = sub.add_parser("compare")
    cmp_.add_argument("files", nargs="+", type=Path)
    cmp_.add_argument("--repeats", type=int, default=3)
    cmp_.add_argument("--settings", default=",".join(SETTINGS), help="comma-separated names of SETTINGS, or 'schur': "
                      "gtsam's LM against the numpy Schur-complement LM (`schur_lm`)")
    args = parser.parse_args()
    if args.cmd == "capture":
        import tempfile

        with tempfile.TemporaryDirectory(prefix="bench_ba_cap_") as tmp:
            _capture(args.bag, args.config, args.out or Path(tmp), args.windows)
        return 0
    if args.settings == "schur":
        _compare_schur(args.files, args.repeats)
        return 0
    names = args.settings.split(",")
    if names[0] != "default":
        names = ["default", *names]
    _compare(args.files, names, args.repeats)
    return 0


if __name__ == "__main__":
    sys.exit(main())
