"""Mover stage speed (`dynamic.movers`): this code against an earlier revision, in one run (prints, never asserts).

    .venv/bin/python bench/bench_movers.py SIM_DIR [--frames 720] [--baseline REV] [--inputs FILE.npz]

The replay feeds both the poses recorded with this checkout's tracking; flags that agree everywhere mean the
system's run (tracking only sees the flags) is the same with either.

The rows and the method: `main`.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from changing_slam_ros.core.features.orb_features import Features  # noqa: E402
from git_tree import archive_tree  # noqa: E402


def record_inputs(sim_dir: Path, frames: int, out: Path) -> None:
    """Run the system with movers on and save the mover stage's per-frame inputs to `out` (npz)."""
    from changing_slam_ros.commands.run import system_config_from_mapping
    from changing_slam_ros.config import load_yaml, section
    from changing_slam_ros.core.dynamic.dynamic_filter import DynamicConfig, DynamicFilter
    from changing_slam_ros.core.system import SlamSystem
    from changing_slam_ros.io.atomic import atomic_open
    from changing_slam_ros.io.dataset import open_dataset
    from changing_slam_ros.io.dataset_config import settings_from_mapping

    config = REPO / "config" / "sim.yaml"
    data = load_yaml(config)
    data["dynamic"] = {**(data.get("dynamic") or {}), "movers": {"enabled": True}}
    source = open_dataset(str(sim_dir), settings_from_mapping(data, str(config)))
    filt = DynamicFilter(section(DynamicConfig, data.get("dynamic"), f"{config}: dynamic"))
    system = SlamSystem(system_config_from_mapping(data, str(config)), dynamic_filter=filt)
    movers = filt.movers
    assert movers is not None
    rec: dict[str, list[Any]] = {"stamp_ns": [], "kp": [], "desc": [], "depth": [], "T": []}
    before, after = movers.before_tracking, movers.after_tracking

    def recording_before(stamp_ns: int, features: Features, camera: Any) -> Any:
        rec["stamp_ns"].append(stamp_ns)
        rec["kp"].append(features.keypoints_px.copy())
        rec["desc"].append(features.descriptors.copy())
        rec["depth"].append(features.depths_m.copy())
        return before(stamp_ns, features, camera)

    def recording_after(T: Any) -> None:
        rec["T"].append(np.full((4, 4), np.nan) if T is None else np.asarray(T, np.float64))
        after(T)

    movers.before_tracking = recording_before  # type: ignore[method-assign]
    movers.after_tracking = recording_after  # type: ignore[method-assign]
    camera = None
    for k, rgbd in enumerate(source):
        if k >= frames:
            break
        camera = rgbd.camera
        system.process(rgbd, None)
    assert camera is not None
    sizes = np.array([len(p) for p in rec["kp"]])
    with atomic_open(out, "wb") as fh:
        np.savez(
            fh, stamp_ns=np.array(rec["stamp_ns"], np.int64), sizes=sizes, kp=np.concatenate(rec["kp"]),
            desc=np.concatenate(rec["desc"]), depth=np.concatenate(rec["depth"]), T=np.stack(rec["T"]),
            camera=np.array([camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy]),
        )  # fmt: skip


def baseline_package(rev: str, tmp: Path) -> str:
    """`changing_slam_ros` at git revision `rev`, importable as `changing_slam_ros_base` from `tmp`."""
    archive_tree(rev, tmp, "changing_slam_ros")
    pkg = tmp / "changing_slam_ros_base"
    (tmp / "changing_slam_ros").rename(pkg)
    for path in pkg.rglob("*.py"):
        path.write_text(path.read_text().replace("changing_slam_ros.", "changing_slam_ros_base."))
    sys.path.insert(0, str(tmp))
    return "changing_slam_ros_base"


def features_of(kp: np.ndarray, desc: np.ndarray, depth: np.ndarray) -> Features:
    n = len(kp)
    zeros = np.zeros(n)
    return Features(kp, kp, np.zeros(n, np.int64), zeros, zeros, desc, depth, np.full(n, -1.0))


def score(sim_dir: Path, rec: Any, n: int, flags: list[np.ndarray], tracker: Any) -> str:
    """Moving-keypoint precision / recall over the carried frames and each exported track's ATE against the
    simulated mover (the counting of `bench/eval_movers_sim.py`, on the replayed flags and the recorded poses)."""
    from changing_slam_ros.core.geometry.trajectory import Trajectory
    from changing_slam_ros.eval.moving_objects import camera_alignment, object_errors_m, read_sim_movers
    from changing_slam_ros.io.dataset import open_dataset

    (truth,) = read_sim_movers(sim_dir)
    moving_gt = truth.moving_frames()
    masks = sorted((sim_dir / "masks").glob("*.png"))
    ends = np.concatenate([[0], np.cumsum(rec["sizes"])])
    tp = fp = fn = 0
    for k in range(n):
        if not moving_gt[k]:
            continue
        px, depth = rec["kp"][ends[k] : ends[k + 1]], rec["depth"][ends[k] : ends[k + 1]]
        mask = cv2.imread(str(masks[k]), cv2.IMREAD_UNCHANGED)
        c = np.clip(np.rint(px[:, 0]).astype(int), 0, mask.shape[1] - 1)
        r = np.clip(np.rint(px[:, 1]).astype(int), 0, mask.shape[0] - 1)
        on = (mask[r, c] == truth.mask_id) & (depth > 0)
        f = flags[k] & (depth > 0)
        tp, fp, fn = tp + int(np.sum(f & on)), fp + int(np.sum(f & ~on)), fn + int(np.sum(on & ~f))
    ok = ~np.isnan(rec["T"][:n]).any(axis=(1, 2))
    online = Trajectory.from_poses(rec["stamp_ns"][:n][ok].astype(np.float64) * 1e-9, rec["T"][:n][ok])
    S, _ = camera_alignment(open_dataset(str(sim_dir), "sim").groundtruth, online)
    ates = []
    for t in tracker.tracks():
        err = object_errors_m(t, S, truth)
        ates.append(f"{len(t.stamps_ns)} poses {100 * np.sqrt(np.mean(err**2)):.2f} cm")
    return f"P {tp / max(tp + fp, 1):.3f} R {tp / max(tp + fn, 1):.3f} (carried frames); tracks: {'; '.join(ates)}"


def parse_sets(items: list[str]) -> dict[str, Any]:
    """KEY=VALUE overrides of `MoverConfig` (dotted keys reach nested sections), values parsed as YAML."""
    import yaml

    out: dict[str, Any] = {}
    for item in items:
        key, _, value = item.partition("=")
        node = out
        parts = key.split(".")
        for part in parts[:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = yaml.safe_load(value)
    return out


def merged(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """`base` with `over` applied, nested mappings merged key by key."""
    out = dict(base)
    for key, value in over.items():
        out[key] = merged(out[key], value) if isinstance(value, dict) and isinstance(out.get(key), dict) else value
    return out


def _import_core(package: str, module: str) -> Any:
    """`package.core.<group>.<name>`, or `package.core.<name>` in a baseline tree whose core/ is flat."""
    try:
        return importlib.import_module(f"{package}.core.{module}")
    except ModuleNotFoundError:
        return importlib.import_module(f"{package}.core.{module.rsplit('.', 1)[-1]}")


def main() -> int:
    """Parse the options, measure, print the table.

    1. Inputs: the system (`config/sim.yaml` with `dynamic: movers: enabled: true`, no detector) runs once on
       SIM_DIR (e.g. `changing-slam simulate unknown_mover --out SIM_DIR`) and the mover stage's inputs are recorded
       per frame: keypoints, descriptors, depths and the pose camera tracking returned. `--inputs FILE.npz` keeps
       them (recorded when the file is absent, reused when present).
    2. Replay: a `MoverTracker` of this checkout and one of `--baseline` (its `changing_slam_ros` package taken
       from git into a temporary folder under another name) get the same inputs, frame by frame in turn, so load
       from other processes hits both alike. Printed: process CPU ms per frame (median, p90, mean) of each, the
       segmentation's share, and whether the two flag the same keypoints as moving and export the same tracks.
       `--variant 'KEY=VALUE ...'` adds a tracker of this checkout with those `MoverConfig` settings (repeatable;
       `--baseline none` leaves the baseline out); `--score` scores each against SIM_DIR's ground truth
       (moving-keypoint precision / recall, object ATE; see `score`).
    """
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sim_dir", help="a simulated folder with a mover, e.g. unknown_mover")
    parser.add_argument("--frames", type=int, default=720)
    parser.add_argument("--baseline", default="5cfa88c", help="git revision to compare with (default: before this work)")
    parser.add_argument("--inputs", help="npz of recorded inputs (written when absent)")
    parser.add_argument("--variant", action="append", default=[], metavar="'KEY=VALUE ...'",
                        help="one more tracker of this checkout with these MoverConfig settings, e.g. segment_every_frames=2")
    parser.add_argument("--score", action="store_true", help="also score both against SIM_DIR's ground truth")
    args = parser.parse_args()
    cv2.setNumThreads(1)  # as SlamSystem does

    from changing_slam_ros.config import section
    from changing_slam_ros.core.geometry.camera import CameraIntrinsics
    from changing_slam_ros.core.movers.mover_tracking import MoverConfig, MoverTracker

    # Overrides go onto the default MoverConfig's values, nested sections included: a YAML-style section
    # alone would rebuild e.g. `segmentation` from SegmentationConfig's class defaults, not the stage's.
    defaults = dataclasses.asdict(MoverConfig(enabled=True))
    variants = {v: section(MoverConfig, merged(defaults, parse_sets(v.split())), f"bench_movers --variant {v}") for v in args.variant}

    with tempfile.TemporaryDirectory(prefix="bench-movers-") as tmp_dir:
        tmp = Path(tmp_dir)
        inputs = Path(args.inputs) if args.inputs else tmp / "inputs.npz"
        if not inputs.is_file():
            t0 = time.perf_counter()
            record_inputs(Path(args.sim_dir), args.frames, inputs)
            print(f"recorded the mover stage's inputs of {args.sim_dir} in {time.perf_counter() - t0:.0f} s: {inputs}")
        rec = np.load(inputs)
        w, h, fx, fy, cx, cy = rec["camera"]
        camera = CameraIntrinsics(int(w), int(h), float(fx), float(fy), float(cx), float(cy))
        runs: dict[str, tuple[Any, Any]] = {}
        if args.baseline != "none":
            base_name = baseline_package(args.baseline, tmp)
            base_mod = _import_core(base_name, "movers.mover_tracking")
            base_cam_mod = _import_core(base_name, "geometry.camera")
            base_camera = base_cam_mod.CameraIntrinsics(int(w), int(h), float(fx), float(fy), float(cx), float(cy))
            runs[f"baseline {args.baseline}"] = (base_mod.MoverTracker(base_mod.MoverConfig(enabled=True)), base_camera)
        runs["this checkout"] = (MoverTracker(MoverConfig(enabled=True)), camera)
        for v, config in variants.items():
            runs[v] = (MoverTracker(config), camera)
        cpu = {name: [] for name in runs}
        flags: dict[str, list[np.ndarray]] = {name: [] for name in runs}
        ends = np.concatenate([[0], np.cumsum(rec["sizes"])])
        n = min(args.frames, len(rec["stamp_ns"]))
        for k in range(n):
            sl = slice(ends[k], ends[k + 1])
            feats = features_of(rec["kp"][sl], rec["desc"][sl], rec["depth"][sl])
            T = rec["T"][k]
            T_arg = None if np.isnan(T).any() else T
            for name, (tracker, cam) in runs.items():
                c0 = time.process_time()
                flags[name].append(tracker.before_tracking(int(rec["stamp_ns"][k]), feats, cam))
                tracker.after_tracking(T_arg)
                cpu[name].append((time.process_time() - c0) * 1e3)
        print(f"{Path(args.sim_dir).name}: {n} frames replayed, ~{int(np.median(rec['sizes']))} keypoints a frame")
        ref = next(iter(runs))
        for name, (tracker, _) in runs.items():
            ms, seg = np.array(cpu[name]), np.array(tracker.segmentation_ms)
            print(
                f"  {name:24s} CPU ms/frame median {np.median(ms):6.1f}, p90 {np.percentile(ms, 90):6.1f}, "
                f"mean {ms.mean():6.1f} (x{np.median(ms) / np.median(cpu[ref]):.2f}, mean x{ms.mean() / np.mean(cpu[ref]):.2f} of the first); "
                f"segmentation median {np.median(seg):5.1f} ms in {len(seg)} windows"
            )
        for name in list(runs)[1:]:
            a, b = flags[ref], flags[name]
            differ = [k for k in range(n) if not np.array_equal(a[k], b[k])]
            n_diff = sum(int(np.sum(a[k] != b[k])) for k in differ)
            print(f"  {name}: moving flags differ from {ref}'s in {len(differ)} of {n} frames ({n_diff} keypoints; "
                  f"{ref} flagged {sum(int(f.sum()) for f in a)})")
            ta, tb = runs[ref][0].tracks(), runs[name][0].tracks()
            if len(ta) == len(tb) and all(np.array_equal(x.stamps_ns, y.stamps_ns) for x, y in zip(ta, tb)):
                dev = max((float(np.abs(x.T_world_obj - y.T_world_obj).max()) for x, y in zip(ta, tb)), default=0.0)
                print(f"    tracks: same stamps, largest pose element difference {dev:.2e}")
            else:
                print("    tracks differ in number or stamps")
        if args.score:
            for name, (tracker, _) in runs.items():
                print(f"  {name:24s} {score(Path(args.sim_dir), rec, n, flags[name], tracker)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
