"""Per-frame cost of keypoint classification + repopulation + association + object EKFs (prints, never asserts).

A rendered 640x480 scene: wall, two persons, two chairs (one pushed) and a tv, 1000 random keypoints, a
camera sliding sideways; the target is <= 5 ms per frame added to tracking.

    .venv/bin/python bench/bench_dynamic.py [--frames 300] [--keypoints 1000]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.dynamic.detector import Detection
from changing_slam_ros.core.dynamic.dynamic_objects import DynamicObjectTracker
from changing_slam_ros.core.geometry.se3 import make_pose

CAM = CameraIntrinsics(640, 480, 535.4, 539.2, 320.1, 247.6)
# class id, centre (x, y, z) m, size (w, h) m, velocity (vx, vy, vz) m/s
OBJECTS = [
    (0, (-0.4, 0.0, 1.8), (0.5, 1.6), (0.3, 0.0, 0.0)),
    (0, (0.5, 0.0, 2.4), (0.5, 1.6), (0.0, 0.0, 0.0)),
    (56, (-0.9, 0.4, 2.2), (0.5, 0.8), (0.0, 0.0, 0.0)),
    (56, (0.9, 0.4, 2.0), (0.5, 0.8), (-0.2, 0.0, 0.0)),
    (62, (0.0, -0.3, 2.9), (0.6, 0.4), (0.0, 0.0, 0.0)),
]


def render(k: int, rng: np.random.Generator, n_kps: int) -> tuple[np.ndarray, list[Detection], np.ndarray, np.ndarray]:
    t = k / 30.0
    cam_x = 0.1 * np.sin(t)
    depth = np.full((CAM.height, CAM.width), 3.5, np.float32)
    dets = []
    for cls, c0, (w, h), v in sorted(OBJECTS, key=lambda o: -o[1][2]):
        c = np.array(c0) + np.array(v) * t - np.array([cam_x, 0.0, 0.0])
        u0, u1 = CAM.fx * (c[0] - w / 2) / c[2] + CAM.cx, CAM.fx * (c[0] + w / 2) / c[2] + CAM.cx
        v0, v1 = CAM.fy * (c[1] - h / 2) / c[2] + CAM.cy, CAM.fy * (c[1] + h / 2) / c[2] + CAM.cy
        depth[max(int(v0), 0) : max(int(v1), 0), max(int(u0), 0) : max(int(u1), 0)] = c[2]
        mu, mv = 0.1 * (u1 - u0), 0.1 * (v1 - v0)
        box = (max(u0 - mu, 0.0), max(v0 - mv, 0.0), min(u1 + mu, 639.0), min(v1 + mv, 479.0))
        if box[2] > box[0] and box[3] > box[1]:
            dets.append(Detection(box, cls, 0.9))
    depth += rng.normal(0.0, 0.005, depth.shape).astype(np.float32)
    kps = rng.uniform([0, 0], [639, 479], (n_kps, 2))
    return depth, dets, kps, make_pose(np.eye(3), np.array([cam_x, 0.0, 0.0]))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--keypoints", type=int, default=1000)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    frames = [render(k, rng, args.keypoints) for k in range(args.frames)]
    tracker = DynamicObjectTracker(CAM)
    t_cls, t_upd, cpu, kept = [], [], [], []
    for k, (depth, dets, kps, pose) in enumerate(frames):
        c0 = time.thread_time()
        t0 = time.perf_counter()
        tracker.classify(k * 33_333_333, kps, depth, dets)
        t1 = time.perf_counter()
        res = tracker.update(pose)
        t2 = time.perf_counter()
        cpu.append((time.thread_time() - c0) * 1e3)
        t_cls.append((t1 - t0) * 1e3)
        t_upd.append((t2 - t1) * 1e3)
        kept.append(res.use_for_tracking.mean())
    total = [a + b for a, b in zip(t_cls, t_upd)]
    q = statistics.quantiles(total, n=10)
    print(f"{args.frames} frames, {args.keypoints} keypoints, {len(OBJECTS)} objects, 640x480 depth")
    print(f"  classification + repopulation + association: median {statistics.median(t_cls):.2f} ms")
    print(f"  object EKF update + DOC verdicts:             median {statistics.median(t_upd):.2f} ms")
    print(f"  total per frame: median {statistics.median(total):.2f} ms, p90 {q[8]:.2f} ms, max {max(total):.2f} ms")
    print(f"  CPU time of this thread per frame (less sensitive to other load): median {statistics.median(cpu):.2f} ms")
    print(f"  load average while running: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    print(f"  keypoints kept for tracking: {100 * statistics.mean(kept):.1f} %")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
