"""`changing-slam eval ate|rpe|report GT EST`: parse arguments, call `changing_slam_ros.eval`, print.

    changing-slam eval ate GT EST [--max-diff D] [--offset S] [--sim3] [--no-align] [--json] [--plot PNG]
    changing-slam eval rpe GT EST [--delta 1] [--delta-unit frames|seconds] [--pairs auto|all|consecutive] ...
    changing-slam eval report GT EST [--out metrics.json]     (ATE + RPE per frame + RPE per second)
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from changing_slam_ros.errors import EvalError
from changing_slam_ros.eval.association import DEFAULT_MAX_DIFF_S

_STAT_ROWS = ("rmse", "mean", "median", "std", "min", "max")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="metric", required=True, metavar="METRIC")
    specs = (
        ("ate", "absolute trajectory error (translation after alignment)"),
        ("rpe", "relative pose error (translation m, rotation deg)"),
        ("report", "ATE, RPE per frame and RPE per second as one JSON report"),
    )
    for name, help_text in specs:
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.add_argument("gt", metavar="GT", help="ground-truth trajectory (TUM format)")
        p.add_argument("est", metavar="EST", help="estimated trajectory (TUM format)")
        p.add_argument("--max-diff", type=float, default=DEFAULT_MAX_DIFF_S, metavar="D",
                       help=f"max stamp difference for association, s (default {DEFAULT_MAX_DIFF_S})")
        p.add_argument("--offset", type=float, default=0.0, metavar="S",
                       help="offset added to the estimate's stamps, s (default 0)")
        p.add_argument("--sim3", action="store_true",
                       help="also estimate the scale (Sim(3) alignment; for monocular estimates)")
        if name == "report":
            p.add_argument("--out", metavar="JSON", help="write the report to this file (atomically)")
            p.add_argument("--per-pose", action="store_true", help="include per-pose errors")
            continue
        p.add_argument("--json", action="store_true", help="print JSON instead of a table")
        p.add_argument("--plot", metavar="PNG", help="write a PNG figure")
        if name == "ate":
            p.add_argument("--no-align", action="store_true",
                           help="compare raw positions without alignment")
            p.add_argument("--plane", default="xy", help="axes of the top view (default xy)")
        else:
            p.add_argument("--delta", type=float, default=1.0, help="pair distance (default 1)")
            p.add_argument("--delta-unit", choices=("frames", "seconds"), default="frames",
                           help="unit of --delta (default frames)")
            p.add_argument("--pairs", choices=("auto", "all", "consecutive"), default="auto",
                           help="all pairs (i, i+delta) or consecutive ones (0,d), (d,2d)...; "
                                "auto: consecutive for frames (as evo), all for seconds (as TUM)")
            p.add_argument("--delta-tol", type=float, default=0.1,
                           help="relative tolerance on a time delta (default 0.1)")


def main(args: argparse.Namespace) -> int:
    from changing_slam_ros.io.tum_trajectory import read_tum_trajectory

    if args.metric == "report":
        from changing_slam_ros.eval.report import evaluate_files

        report = evaluate_files(args.gt, args.est, args.max_diff, args.offset, args.sim3,
                                per_pose=args.per_pose)
        text = json.dumps(report, indent=2) + "\n"
        if args.out:
            from changing_slam_ros.io.atomic import atomic_write_text

            try:
                atomic_write_text(args.out, text)
            except OSError as err:
                raise EvalError(f"{args.out}: cannot write report ({err.strerror or err})") from err
            print(_report_summary(report))
        else:
            print(text, end="")
        return 0

    gt = read_tum_trajectory(args.gt)
    est = read_tum_trajectory(args.est)
    if args.metric == "ate":
        return _run_ate(args, gt, est)
    return _run_rpe(args, gt, est)


def _run_ate(args: argparse.Namespace, gt: Any, est: Any) -> int:
    from changing_slam_ros.eval.ate import ate

    res = ate(gt, est, args.max_diff, args.offset, align=not args.no_align, sim3=args.sim3,
              gt_name=args.gt, est_name=args.est)
    if args.plot:
        from changing_slam_ros.eval.plots import plot_ate

        plot_ate(res, args.plot, gt_full=gt, plane=args.plane, title=f"{_name(args.est)} vs {_name(args.gt)}")
    if args.json:
        print(json.dumps({"gt": args.gt, "est": args.est, **res.to_dict()}, indent=2))
        return 0
    alignment = res.to_dict()["alignment"]
    lines = [
        f"ATE  {args.est}  vs  {args.gt}",
        _assoc_line(len(res.association), len(est), len(gt), args.max_diff, args.offset),
        f"  alignment   {alignment}" + (f", scale {res.alignment.scale:.6f}" if res.sim3 else ""),
        "  translation error (m)",
        *(f"    {k:<7}{getattr(res.stats, k):12.6f}" for k in _STAT_ROWS),
    ]
    if args.plot:
        lines.append(f"  plot        {args.plot}")
    print("\n".join(lines))
    return 0


def _run_rpe(args: argparse.Namespace, gt: Any, est: Any) -> int:
    from changing_slam_ros.eval.rpe import DeltaUnit, rpe

    unit = DeltaUnit(args.delta_unit)
    all_pairs = args.pairs == "all" or (args.pairs == "auto" and unit is DeltaUnit.SECONDS)
    res = rpe(gt, est, args.delta, unit, all_pairs, args.delta_tol, args.max_diff, args.offset,
              sim3=args.sim3, gt_name=args.gt, est_name=args.est)
    if args.plot:
        from changing_slam_ros.eval.plots import plot_rpe

        plot_rpe(res, args.plot, title=f"RPE {_name(args.est)} vs {_name(args.gt)}, delta {args.delta:g} {unit.value}")
    if args.json:
        print(json.dumps({"gt": args.gt, "est": args.est, **res.to_dict()}, indent=2))
        return 0
    lines = [
        f"RPE  {args.est}  vs  {args.gt}",
        _assoc_line(len(res.association), len(est), len(gt), args.max_diff, args.offset),
        f"  pairs       {len(res.pairs)} ({'all' if all_pairs else 'consecutive'}), "
        f"delta {args.delta:g} {unit.value}" + (f", Sim(3) scale {res.alignment.scale:.6f}"
                                                if res.sim3 else ""),
        f"    {'':<7}{'trans (m)':>12}{'rot (deg)':>12}",
        *(f"    {k:<7}{getattr(res.trans, k):12.6f}{getattr(res.rot, k):12.6f}" for k in _STAT_ROWS),
    ]
    if args.plot:
        lines.append(f"  plot        {args.plot}")
    print("\n".join(lines))
    return 0


def _name(path: str) -> str:
    return Path(path).name


def _assoc_line(n: int, n_est: int, n_gt: int, max_diff: float, offset: float) -> str:
    return (f"  associated  {n} poses (estimate {n_est}, ground truth {n_gt}; "
            f"max diff {max_diff:g} s, offset {offset:g} s)")


def _report_summary(report: dict[str, Any]) -> str:
    ate = report["ate"]
    parts = [f"ATE rmse {ate['rmse']:.6f} m over {report['associated_poses']} poses"]
    for key, label in (("rpe_per_frame", "RPE/frame"), ("rpe_per_second", "RPE/s")):
        r = report.get(key)
        if r:
            parts.append(f"{label} rmse {r['translation_m']['rmse']:.6f} m "
                         f"{r['rotation_deg']['rmse']:.4f} deg")
    return "; ".join(parts)
