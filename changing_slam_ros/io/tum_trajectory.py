"""TUM trajectory files: `timestamp tx ty tz qx qy qz qw` per line, `#` comments, camera-to-world."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from changing_slam_ros.core.geometry.trajectory import Trajectory
from changing_slam_ros.errors import EvalError, read_utf8
from changing_slam_ros.io.atomic import atomic_write_text


def read_tum_trajectory(path: str | os.PathLike[str]) -> Trajectory:
    """Read a TUM trajectory; raise EvalError naming the file and line on malformed input.

    Separators may be spaces, tabs or commas (as evo accepts). Rows are returned sorted by stamp.
    """
    p = Path(path)
    text = read_utf8(p, EvalError, noun="trajectory")
    rows: list[list[float]] = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        parts = s.replace(",", " ").split()
        if len(parts) != 8:
            raise EvalError(
                f"{p}:{lineno}: expected 8 columns 'timestamp tx ty tz qx qy qz qw', got {len(parts)}"
            )
        try:
            rows.append([float(x) for x in parts])
        except ValueError as err:
            raise EvalError(f"{p}:{lineno}: not a number ({err})") from err
    if not rows:
        raise EvalError(f"{p}: trajectory is empty (no pose lines)")
    a = np.array(rows, dtype=np.float64)
    if not np.all(np.isfinite(a)):
        bad = int(np.argmax(~np.all(np.isfinite(a), axis=1)))
        raise EvalError(f"{p}: non-finite value in pose row {bad + 1}")
    norms = np.linalg.norm(a[:, 4:8], axis=1)
    if np.any(norms < 1e-9):
        raise EvalError(f"{p}: zero quaternion in pose row {int(np.argmin(norms)) + 1}")
    return Trajectory(a[:, 0], a[:, 1:4], a[:, 4:8] / norms[:, None]).sorted()


def format_tum_trajectory(traj: Trajectory) -> str:
    lines = ["# timestamp tx ty tz qx qy qz qw"]
    for t, p, q in zip(traj.stamps_s, traj.positions, traj.quats_xyzw):
        lines.append(
            f"{t:.6f} {p[0]:.9f} {p[1]:.9f} {p[2]:.9f} {q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}"
        )
    return "\n".join(lines) + "\n"


def write_tum_trajectory(path: str | os.PathLike[str], traj: Trajectory) -> None:
    """Write atomically: a failure never truncates an existing file."""
    atomic_write_text(path, format_tum_trajectory(traj))
