"""Side by side with ORB-SLAM3 RGB-D on the same frames, in one run: wall time, ratio, ATE, our time per stage.

    .venv/bin/python bench/bench_orbslam3.py [SOURCE] [--config NAME] [--max-frames N] [--work DIR]
        [--orb-python .venv-orbslam3/bin/python] [--no-plain] [--ours-args "..."]

Prints only (a shared machine's load moves wall times; the ratio is taken between runs of the same invocation,
one after the other on an otherwise idle machine). Steps:

1. The frames are read once through our own reader (`open_dataset` with `--config`) and written as colour PNG and
   16-bit depth PNG (1/5000 m) with a frame list, so both systems see the same pixels and the same depth.
2. ORB-SLAM3 runs in its own virtual environment (`--orb-python`; set it up with `make orbslam3-venv`:
   `pyorbslam3`, GPL-3.0, never a dependency of this package) through `bench/orbslam3_runner.py`, with a
   settings file written from the same camera (ORB-SLAM3's TUM RGB-D settings otherwise: 1000 ORB features,
   8 levels at 1.2, FAST 20 / 7, ThDepth 40 with bf = 0.08 fx) and a DBoW2 vocabulary written from our shipped
   one (`tools/orbslam3_vocabulary.py`; its hash is printed) since ORB-SLAM3's own is a download.
3. `changing-slam run SOURCE --config NAME` with the default pipeline, and with `--no-dynamic` (the plain engine)
   unless `--no-plain`; their `metrics.json` wall time (the same clock span: first frame read to last output of
   the frame loop) and `timing.json` stages.
4. ATE of every final trajectory against the source's ground truth (SE(3) alignment, `eval.ate`).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shlex
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from changing_slam_ros.config import find_config, load_yaml  # noqa: E402
from changing_slam_ros.core.geometry.camera import CameraIntrinsics  # noqa: E402
from changing_slam_ros.eval.ate import ate  # noqa: E402
from changing_slam_ros.io.dataset import RgbdSource, open_dataset  # noqa: E402
from changing_slam_ros.io.dataset_config import settings_from_mapping  # noqa: E402
from changing_slam_ros.io.tum_trajectory import read_tum_trajectory  # noqa: E402

DEPTH_FACTOR = 5000.0
STAGES = ("features", "tracking", "dynamic", "local_mapping_per_keyframe", "objects", "loop_closing")


def export_frames(source: RgbdSource, n: int, out: Path) -> tuple[Path, CameraIntrinsics, float]:
    """Frames 0..n-1 as PNGs and `frames.txt`; returns (the list, the camera, the frame rate)."""
    out.mkdir(parents=True, exist_ok=True)
    lines: list[str] = []
    stamps: list[float] = []
    camera: CameraIntrinsics | None = None
    for i, frame in enumerate(source):
        if i >= n:
            break
        camera = frame.camera
        colour, depth = out / f"{i:06d}_rgb.png", out / f"{i:06d}_depth.png"
        cv2.imwrite(str(colour), cv2.cvtColor(np.asarray(frame.rgb), cv2.COLOR_RGB2BGR))
        d = np.clip(np.round(np.asarray(frame.depth_m, np.float64) * DEPTH_FACTOR), 0, 65535).astype(np.uint16)
        cv2.imwrite(str(depth), d)
        lines.append(f"{frame.stamp_ns * 1e-9:.9f} {colour} {depth}")
        stamps.append(frame.stamp_ns * 1e-9)
    if camera is None:
        raise SystemExit("bench_orbslam3: the source has no frames")
    listing = out / "frames.txt"
    listing.write_text("\n".join(lines) + "\n")
    fps = (len(stamps) - 1) / (stamps[-1] - stamps[0]) if len(stamps) > 1 and stamps[-1] > stamps[0] else 30.0
    return listing, camera, fps


def settings_yaml(c: CameraIntrinsics, fps: float, n_features: int) -> str:
    """ORB-SLAM3's settings (its older, flat format) for an RGB-D camera with our intrinsics."""
    k1, k2, p1, p2, k3 = (tuple(c.dist) + (0.0,) * 5)[:5]
    keys = {
        "Camera.type": '"PinHole"', "Camera.fx": c.fx, "Camera.fy": c.fy, "Camera.cx": c.cx, "Camera.cy": c.cy,
        "Camera.k1": k1, "Camera.k2": k2, "Camera.p1": p1, "Camera.p2": p2, "Camera.k3": k3,
        "Camera.width": c.width, "Camera.height": c.height, "Camera.fps": round(fps, 3),
        "Camera.RGB": 0, "Camera.bf": 0.08 * c.fx, "ThDepth": 40.0, "DepthMapFactor": DEPTH_FACTOR,
        "ORBextractor.nFeatures": n_features, "ORBextractor.scaleFactor": 1.2, "ORBextractor.nLevels": 8,
        "ORBextractor.iniThFAST": 20, "ORBextractor.minThFAST": 7,
        "Viewer.KeyFrameSize": 0.05, "Viewer.KeyFrameLineWidth": 1.0, "Viewer.GraphLineWidth": 0.9,
        "Viewer.PointSize": 2.0, "Viewer.CameraSize": 0.08, "Viewer.CameraLineWidth": 3.0,
        "Viewer.ViewpointX": 0.0, "Viewer.ViewpointY": -0.7, "Viewer.ViewpointZ": -1.8, "Viewer.ViewpointF": 500.0,
    }  # fmt: skip
    return "%YAML:1.0\n" + "".join(f"{k}: {v}\n" for k, v in keys.items())


def run_ours(source: str, config: str, n: int, out: Path, extra: list[str]) -> dict[str, object]:
    argv = [sys.executable, "-m", "changing_slam_ros", "run", source, "--config", config, "--out", str(out),
            "--quiet", "--no-plot", *(["--max-frames", str(n)] if n else []), *extra]  # fmt: skip
    done = subprocess.run(argv, cwd=REPO, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"changing-slam run failed ({done.returncode}): {done.stderr.strip()[-500:]}")
    metrics = json.loads((out / "metrics.json").read_text())
    timing = json.loads((out / "timing.json").read_text())
    return {"wall_s": metrics["wall_s"], "frames": metrics["frames"], "posed": metrics["frames_tracked"],
            "trajectory": out / "trajectory.txt", "timing": timing}  # fmt: skip


def ate_cm(gt: object, path: Path) -> float | None:
    if gt is None or not path.is_file() or path.stat().st_size == 0:
        return None
    return 100.0 * ate(gt, read_tum_trajectory(path)).stats.rmse  # type: ignore[arg-type]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source", nargs="?", default=str(REPO.parent / "shared/data/7scenes_redkitchen"))
    parser.add_argument("--config", default="7scenes")
    parser.add_argument("--max-frames", type=int, default=0, help="0 = every frame")
    parser.add_argument("--work", type=Path, default=Path("/tmp/bench_orbslam3"))
    parser.add_argument("--orb-python", type=Path, default=REPO / ".venv-orbslam3" / "bin" / "python")
    parser.add_argument("--no-plain", action="store_true", help="skip the run with --no-dynamic")
    parser.add_argument("--ours-args", default="", help="more arguments for changing-slam run (one string)")
    a = parser.parse_args()
    if not a.orb_python.is_file():
        raise SystemExit(f"{a.orb_python}: no ORB-SLAM3 environment (make orbslam3-venv)")

    cfg_path = find_config(a.config)
    data = load_yaml(cfg_path)
    source = open_dataset(a.source, settings_from_mapping(data, str(cfg_path)))
    n = len(source) if not a.max_frames else min(a.max_frames, len(source))
    print(f"source {a.source} ({n} frames, config {a.config}); work {a.work}", flush=True)
    listing, camera, fps = export_frames(source, n, a.work / "frames")
    n_features = int((data.get("features") or {}).get("n_features", 1000))
    settings = a.work / "orbslam3.yaml"
    settings.write_text(settings_yaml(camera, fps, n_features))
    vocabulary = a.work / "vocabulary.txt"
    subprocess.run([sys.executable, str(REPO / "tools" / "orbslam3_vocabulary.py"), "--out", str(vocabulary)],
                   check=True, capture_output=True)  # fmt: skip
    voc_hash = hashlib.sha256(vocabulary.read_bytes()).hexdigest()[:16]

    orb_final, orb_online = a.work / "orbslam3_trajectory.txt", a.work / "orbslam3_online.txt"
    done = subprocess.run([str(a.orb_python), str(REPO / "bench" / "orbslam3_runner.py"), str(listing), str(settings),
                           str(vocabulary), str(orb_final), str(orb_online)], capture_output=True, text=True)  # fmt: skip
    if done.returncode != 0:
        raise SystemExit(f"ORB-SLAM3 failed ({done.returncode}): {done.stderr.strip()[-800:]}")
    orb = json.loads(done.stdout.strip().splitlines()[-1])

    runs = {"default": run_ours(a.source, a.config, n, a.work / "ours_default", shlex.split(a.ours_args))}
    if not a.no_plain:
        runs["--no-dynamic"] = run_ours(a.source, a.config, n, a.work / "ours_plain", ["--no-dynamic", *shlex.split(a.ours_args)])
    gt = source.groundtruth
    rows = [("ORB-SLAM3 RGB-D", orb["wall_s"], orb["posed"], ate_cm(gt, orb_final), ate_cm(gt, orb_online))]
    for name, r in runs.items():
        rows.append((f"changing-slam run {name}", r["wall_s"], r["posed"], ate_cm(gt, r["trajectory"]), None))  # type: ignore[arg-type]
    print(f"\nORB-SLAM3 settings {settings} (features {n_features}); vocabulary {voc_hash} "
          f"(ours, {vocabulary.stat().st_size // 1024} KiB); vocabulary load {orb['vocabulary_load_s']:.1f} s, not timed")  # fmt: skip
    print(f"{'run':<40} {'wall s':>7} {'fps':>6} {'x ORB':>6} {'posed':>9} {'ATE cm':>7}")
    for name, wall, posed, ate_final, ate_online in rows:
        online = f" (online {ate_online:.2f})" if ate_online is not None else ""
        ate_s = f"{ate_final:7.2f}" if ate_final is not None else "      -"
        print(f"{name:<40} {wall:7.1f} {n / wall:6.1f} {wall / orb['wall_s']:6.2f} {posed:>4}/{n:<4} {ate_s}{online}")
    for name, r in runs.items():
        t = r["timing"]
        parts = [f"{s} {t[s]['p50']:.1f}" for s in STAGES if s in t]  # type: ignore[index]
        print(f"ours {name}, median ms: " + ", ".join(parts))
    summary = {"source": a.source, "frames": n, "config": a.config, "vocabulary_sha256_16": voc_hash,
               "orbslam3": orb, "ours": {k: {"wall_s": v["wall_s"], "posed": v["posed"]} for k, v in runs.items()},
               "ate_cm": {name: ate_final for name, _, _, ate_final, _ in rows}}  # fmt: skip
    (a.work / "bench_orbslam3.json").write_text(json.dumps(summary, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
