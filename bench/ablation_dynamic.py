"""Ablation of the dynamic-scene filter on simulated walking scenarios: camera ATE and fraction of keypoints kept per row.

Rows (cumulative, `DynamicConfig` switches): plain (dynamic handling off) / +detection_filtering /
+repopulation / +ekf_doc / +segmentation, with the simulator's oracle boxes and/or the shipped
SSD-MobileNetV2 (`--detections oracle model`). Model detections are computed once per scenario and
reused by every row. Prints a table, never asserts.

Scenarios must be rendered first, e.g.

    changing-slam simulate walking_xyz --out /tmp/sim/walking_xyz --seed 0
    nice -n 10 .venv/bin/python bench/ablation_dynamic.py --root /tmp/sim --frames 300 \
        [--scenarios walking_xyz ...] [--detections oracle model] [--rows plain +ekf_doc] [--jobs 2] [--json out.json]

ATE is the RMSE of the final trajectory (each frame re-expressed from its reference keyframe) after SE(3)
alignment to ground truth, over the frames tracked; "lost" counts frames not tracked. Loop closing is off.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from changing_slam_ros.core.dynamic.detector import Detection, Detector, DetectorConfig  # noqa: E402
from changing_slam_ros.core.dynamic.dynamic_filter import DynamicConfig, DynamicFilter  # noqa: E402
from changing_slam_ros.core.system import SlamSystem  # noqa: E402
from changing_slam_ros.eval.ate import ate  # noqa: E402
from changing_slam_ros.io.dataset import open_dataset  # noqa: E402
from changing_slam_ros.io.detections_file import find_detections_file, read_detections_file  # noqa: E402

WALKING = ["walking_xyz", "walking_static", "walking_rpy", "walking_halfsphere", "sitting_xyz"]
ROWS: dict[str, DynamicConfig | None] = {
    "plain": None,
    "+detection_filtering": DynamicConfig(repopulation=False, ekf_doc=False, segmentation=False),
    "+repopulation": DynamicConfig(repopulation=True, ekf_doc=False, segmentation=False),
    "+ekf_doc": DynamicConfig(repopulation=True, ekf_doc=True, segmentation=False),
    "+segmentation": DynamicConfig(repopulation=True, ekf_doc=True, segmentation=True),
    # Beyond the paper: +ekf_doc with missed person boxes held for 10 frames (for the real detector).
    "+segmentation+spread25": DynamicConfig(segmentation=True, segmentation_spread_px=25.0),
    "+ekf_doc+hold10": DynamicConfig(repopulation=True, ekf_doc=True, segmentation=False, detection_hold_frames=10),
}


def run_once(folder: Path, n_frames: int, config: DynamicConfig | None,
             detections: dict[int, tuple[Detection, ...]]) -> dict[str, Any]:
    """One SLAM run over the first `n_frames` frames; ATE, tracking and keypoint figures."""
    source = open_dataset(folder, "sim")
    flt = DynamicFilter(config) if config is not None else None
    system = SlamSystem(dynamic_filter=flt)
    t0 = time.perf_counter()
    n = 0
    for rgbd in source:
        if n >= n_frames:
            break
        system.process(rgbd, detections.get(rgbd.stamp_ns, ()))
        n += 1
    wall_s = time.perf_counter() - t0
    gt = source.groundtruth
    assert gt is not None
    final = system.final_trajectory()
    rmse = ate(gt, final).stats.rmse if len(final) >= 3 else float("nan")
    return {
        "frames": n,
        "tracked": system.n_tracked(),
        "maps": len(system.atlas.maps),
        "ate_m": float(rmse),
        "kept": flt.kept_fraction() if flt is not None else 1.0,
        "dynamic_ms_median": float(np.median(flt.frames_ms)) if flt is not None and flt.frames_ms else 0.0,
        "fps": n / wall_s if wall_s > 0 else 0.0,
    }


def model_detections(folder: Path, n_frames: int, detector: Detector,
                     cache_dir: Path | None) -> tuple[dict[int, tuple[Detection, ...]], float]:
    """The detector's output on the first `n_frames` colour images and its median ms per frame, cached
    in `cache_dir` per folder, frame count and model file (the model is deterministic)."""
    cache = None
    if cache_dir is not None:
        cache = cache_dir / f"{folder.resolve().as_posix().strip('/').replace('/', '_')}_{n_frames}_{detector.model_path.stem}.json"
        if cache.is_file():
            doc = json.loads(cache.read_text())
            frames = {int(k): tuple(Detection(tuple(d[0]), int(d[1]), float(d[2])) for d in v)  # type: ignore[arg-type]
                      for k, v in doc["frames"].items()}
            return frames, float(doc["ms"])
    out: dict[int, tuple[Detection, ...]] = {}
    ms = []
    for k, rgbd in enumerate(open_dataset(folder, "sim")):
        if k >= n_frames:
            break
        out[rgbd.stamp_ns] = detector.detect(rgbd.rgb, rgbd.stamp_ns).detections
        ms.append(detector.last_inference_ms)
    median_ms = float(np.median(ms)) if ms else 0.0
    if cache is not None:
        cache.parent.mkdir(parents=True, exist_ok=True)
        rows = {str(k): [[list(d.box_xyxy), d.class_id, d.score] for d in v] for k, v in out.items()}
        cache.write_text(json.dumps({"ms": median_ms, "frames": rows}))
    return out, median_ms


def _run_task(task: tuple[str, Path, int, str, str, dict[int, tuple[Detection, ...]]]) -> dict[str, Any]:
    name, folder, n_frames, det_name, row, dets = task
    r = run_once(folder, n_frames, ROWS[row], dets)
    r.update(scenario=name, detections="-" if row == "plain" else det_name, row=row)
    return r


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=Path("/tmp/sim"), help="folder holding one rendered folder per scenario")
    parser.add_argument("--scenarios", nargs="+", default=WALKING)
    parser.add_argument("--frames", type=int, default=300, help="first N frames of each scenario (30 fps)")
    parser.add_argument("--detections", nargs="+", choices=["oracle", "model"], default=["oracle", "model"])
    parser.add_argument("--rows", nargs="+", choices=list(ROWS), default=list(ROWS))
    parser.add_argument("--jobs", type=int, default=1, help="SLAM runs in parallel (processes)")
    parser.add_argument("--json", type=Path, default=None, help="also write every row here")
    parser.add_argument("--model-cache", type=Path, default=Path(tempfile.gettempdir()) / "changing_slam_bench_detections",
                        help="where model detections are cached between runs ('' = no cache)")
    args = parser.parse_args()

    detector = Detector(DetectorConfig()) if "model" in args.detections else None
    tasks = []
    for name in args.scenarios:
        folder = args.root / name
        for det_name in args.detections:
            if det_name == "model":
                assert detector is not None
                dets, det_ms = model_detections(folder, args.frames, detector, args.model_cache if str(args.model_cache) else None)
                print(f"{name}: model detector {det_ms:.1f} ms/frame median (when computed)", flush=True)
            else:
                dets = read_detections_file(find_detections_file(folder)).frames
            for row in args.rows:
                if row == "plain" and det_name != args.detections[0]:
                    continue  # plain ignores detections: one run per scenario
                tasks.append((name, folder, args.frames, det_name, row, {} if row == "plain" else dets))
    if args.jobs > 1:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(args.jobs) as pool:
            results = []
            for r in pool.map(_run_task, tasks):
                results.append(r)
                print(f"done: {r['scenario']} {r['detections']} {r['row']} {100 * r['ate_m']:.2f} cm", flush=True)
    else:
        results = [_run_task(t) for t in tasks]
    header = (f"{'scenario':19s} {'detections':10s} {'row':22s} {'ATE cm':>7s} {'x lower':>8s} {'lost':>5s} "
              f"{'maps':>4s} {'kept %':>6s} {'dyn ms':>6s} {'fps':>5s}")
    print(header, flush=True)
    plain = {r["scenario"]: r["ate_m"] for r in results if r["row"] == "plain"}
    for r in results:
        ratio = plain.get(r["scenario"], float("nan")) / r["ate_m"] if r["ate_m"] > 0 else float("nan")
        r["x_lower"] = ratio
        print(f"{r['scenario']:19s} {r['detections']:10s} {r['row']:22s} {100 * r['ate_m']:7.2f} {ratio:8.1f} "
              f"{r['frames'] - r['tracked']:5d} {r['maps']:4d} {100 * r['kept']:6.1f} "
              f"{r['dynamic_ms_median']:6.1f} {r['fps']:5.1f}", flush=True)
    if args.json is not None:
        args.json.write_text(json.dumps(results, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
