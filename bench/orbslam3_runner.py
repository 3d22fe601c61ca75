"""ORB-SLAM3 RGB-D over a list of frames, timed: the other side of `bench/bench_orbslam3.py`.

Runs in its own virtual environment with `pyorbslam3` (GPL-3.0, ORB-SLAM3's Python bindings; never a dependency of
this package) and imports nothing of ours:

    .venv-orbslam3/bin/python bench/orbslam3_runner.py FRAMES SETTINGS VOCABULARY TRAJECTORY ONLINE

FRAMES: one line per frame, `stamp_s colour.png depth.png` (depth 16-bit, scale in the settings). The clock runs
from the first image read to the end of `shutdown()` (which waits for local mapping and loop closing): image
reading is inside, as it is in `changing-slam run`'s wall time; loading the vocabulary is not. Prints one JSON
line: wall seconds, frames, frames with a valid pose. TRAJECTORY: ORB-SLAM3's own final trajectory (TUM format,
`SaveTrajectoryTUM` after shutdown); ONLINE: each frame's pose as tracking returned it.
"""

from __future__ import annotations

import json
import sys
import time

import cv2
import numpy as np
import pyorbslam3 as orb


def main(argv: list[str]) -> int:
    frames_txt, settings, vocabulary, trajectory, online = argv
    frames = [line.split() for line in open(frames_txt) if line.strip()]
    t_load = time.perf_counter()
    slam = orb.Slam(vocab_file=vocabulary, settings_file=settings, sensor=orb.Sensor.RGBD, use_viewer=False)
    load_s = time.perf_counter() - t_load
    poses = []
    t0 = time.perf_counter()
    for stamp, colour, depth in frames:
        bgr = cv2.imread(colour, cv2.IMREAD_COLOR)
        d = cv2.imread(depth, cv2.IMREAD_UNCHANGED)
        if bgr is None or d is None:
            print(f"orbslam3_runner: cannot read {colour} or {depth}", file=sys.stderr)
            return 2
        result = slam.track_rgbd(bgr, d.astype(np.float32), float(stamp))
        if result.pose_valid:
            poses.append((stamp, np.asarray(result.pose_wc, np.float64)))
    slam.shutdown()
    wall_s = time.perf_counter() - t0
    slam.save_trajectory_tum(trajectory)  # final: each frame from its reference keyframe after all optimisation
    with open(online, "w") as f:  # the tracked poses as returned (later corrections not applied)
        for stamp, T in poses:
            q = _quaternion(T[:3, :3])
            f.write(f"{stamp} {T[0, 3]:.6f} {T[1, 3]:.6f} {T[2, 3]:.6f} {q[0]:.6f} {q[1]:.6f} {q[2]:.6f} {q[3]:.6f}\n")
    print(json.dumps({"wall_s": wall_s, "vocabulary_load_s": load_s, "frames": len(frames), "posed": len(poses)}))
    return 0


def _quaternion(R: np.ndarray) -> tuple[float, float, float, float]:  # noqa: N803
    """(x, y, z, w) of a rotation matrix."""
    w = np.sqrt(max(0.0, 1.0 + R[0, 0] + R[1, 1] + R[2, 2])) / 2
    x = np.sqrt(max(0.0, 1.0 + R[0, 0] - R[1, 1] - R[2, 2])) / 2
    y = np.sqrt(max(0.0, 1.0 - R[0, 0] + R[1, 1] - R[2, 2])) / 2
    z = np.sqrt(max(0.0, 1.0 - R[0, 0] - R[1, 1] + R[2, 2])) / 2
    x = np.copysign(x, R[2, 1] - R[1, 2])
    y = np.copysign(y, R[0, 2] - R[2, 0])
    z = np.copysign(z, R[1, 0] - R[0, 1])
    return float(x), float(y), float(z), float(w)


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
