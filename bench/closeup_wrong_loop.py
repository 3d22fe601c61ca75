"""Which safeguard stops a loop closed on a moved object? `one_chair_closeup`, six ways.

`one_chair_closeup` (sim/scenarios.py) puts the printed chair with the teddy bear 0.7 m ahead of the robot's first
corner (A, facing east) and moves it, out of view, 0.7 m ahead of the second corner (B, facing north): the last
views before each corner show the chair as large and from the same side, against different walls. An engine that
uses the chair's points for place recognition can verify a loop between a B view and an A view whose relative pose
is the chair's, 90 deg and about a metre off the truth.

    changing-slam simulate one_chair_closeup --out ROOT/one_chair_closeup --seed 0 --width 320 --height 240
    nice -n 10 .venv/bin/python bench/closeup_wrong_loop.py --root ROOT [--rerun] [--modes plain objects ...]

Runs go to ROOT/runs/one_chair_closeup-MODE[-nogate]; existing metrics.json files are reused unless --rerun.

The rows and the method: `main`.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

MODE_ARGS = {
    "plain": ["--detections", "none", "--no-dynamic", "--no-objects"],
    "no-objects": ["--detections", "oracle", "--no-objects"],
    "objects": ["--detections", "oracle", "--objects"],
}
NO_GATE_YAML = "loop:\n  drift_gate:\n    enabled: false\n"


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "changing_slam_ros.cli", *args]


def run(root: Path, scenario: str, mode: str, gate: bool, rerun: bool) -> dict[str, Any]:
    out = root / "runs" / f"{scenario}-{mode}{'' if gate else '-nogate'}"
    metrics = out / "metrics.json"
    if rerun or not metrics.is_file():
        extra: list[str] = []
        if not gate:
            cfg = root / "no_drift_gate.yaml"
            cfg.write_text(NO_GATE_YAML)
            extra = ["--config", str(cfg)]
        subprocess.run(_cli("run", str(root / scenario), "--out", str(out), *MODE_ARGS[mode], *extra, "--quiet"),
                       check=True)
    result: dict[str, Any] = json.loads(metrics.read_text())
    return result


def _angle_deg(T: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(T[:3, :3]) - 1.0) / 2.0, -1.0, 1.0))))


def chair_hypothesis_error(scenario: Any, t_match: float, t_query: float, actor: str = "chair") -> tuple[float, float]:
    """Error (m, deg) against the ground truth of the relative pose that a match on `actor` alone would give."""
    from changing_slam_ros.core.geometry.se3 import invert

    cam_m, cam_q = scenario.camera.pose_at(t_match), scenario.camera.pose_at(t_query)
    track = scenario.actors[scenario.actor_index(actor)].track
    obj_m, obj_q = track.pose_at(t_match), track.pose_at(t_query)
    truth = invert(cam_m) @ cam_q
    on_object = invert(cam_m) @ obj_m @ invert(obj_q) @ cam_q  # the object taken as fixed
    d = invert(truth) @ on_object
    return float(np.linalg.norm(d[:3, 3])), _angle_deg(d)


def main() -> int:
    """Parse the options, measure, print the table.

    Three modes as in `bench/changing_scenes.py` (plain: no detections, no dynamic filter, no layer; no-objects:
    oracle detections and the dynamic filter, no layer; objects: the object layer on), each with the loop drift gate
    (`loop.drift_gate`) on (default config) and off (`--config` with `loop: {drift_gate: {enabled: false}}`).

    Per run: ATE (final trajectory, SE(3)-aligned, as `changing-slam run` reports it), loops accepted and wrong
    (> 10 cm or 5 deg from the ground-truth relative pose of the two keyframes), and per loop its frames, its error and
    the error the *chair hypothesis* would have: the relative pose that makes the chair at A in the match view
    coincide with the chair at B in the query view (ground-truth poses). A loop whose error is close to that
    hypothesis's and far from zero was verified on the moved chair. Prints, never asserts.
    """
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", type=Path, default=Path("/tmp/closeup"))
    ap.add_argument("--scenario", default="one_chair_closeup")
    ap.add_argument("--modes", nargs="+", default=list(MODE_ARGS), choices=list(MODE_ARGS))
    ap.add_argument("--gates", nargs="+", default=["on", "off"], choices=["on", "off"])
    ap.add_argument("--rerun", action="store_true")
    args = ap.parse_args()
    from changing_slam_ros.sim.scenarios import build_scenario

    scenario = build_scenario(args.scenario, 0)
    t0 = None
    gt = args.root / args.scenario / "groundtruth.txt"
    if gt.is_file():  # stamps in the files are offset; the first ground-truth stamp is t = 0
        first = next(line for line in gt.read_text().splitlines() if line and not line.startswith("#"))
        t0 = float(first.split()[0])
    print("| mode | drift gate | tracked | ATE cm | loops | wrong | loops: match s -> query s, error cm / deg "
          "(chair hypothesis cm / deg) |")
    print("|---|---|---|---|---|---|---|")
    for mode in args.modes:
        for gate in args.gates:
            m = run(args.root, args.scenario, mode, gate == "on", args.rerun)
            loops = m.get("loops", {})
            cells = []
            for lp in loops.get("loops", []):
                tm, tq = lp["match_stamp_s"], lp["query_stamp_s"]
                if t0 is not None:
                    tm, tq = tm - t0, tq - t0
                    hm, hd = chair_hypothesis_error(scenario, tm, tq)
                    hyp = f"{100 * hm:.0f} / {hd:.0f}"
                else:
                    hyp = "-"
                cells.append(f"{tm:.1f} -> {tq:.1f}: {100 * lp['error_m']:.1f} / {lp['error_deg']:.1f} ({hyp})")
            ate = 100 * float(m.get("ate_rmse_m", math.nan))
            print(f"| {mode} | {gate} | {m['frames_tracked']}/{m['frames']} | {ate:.1f} | {loops.get('accepted', 0)} "
                  f"| {loops.get('wrong', 0)} | {'; '.join(cells) or '-'} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
