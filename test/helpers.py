"""Shared test helpers: where the workspace data lives, and small fakes."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("CHANGING_SLAM_SHARED", REPO.parent / "shared"))
DATA = SHARED / "data"
FR1_XYZ_10 = DATA / "tum_fr1_xyz_first10"
REDKITCHEN = DATA / "7scenes_redkitchen"
TUM_REFERENCE = DATA / "tum_reference_trajectories"
FR3_WALKING_FRAMES = DATA / "tum_fr3_walking_frames"
MODELS = SHARED / "models"


def require(path: Path) -> Path:
    """Skip the calling test cleanly when a workspace data folder is absent."""
    if not path.exists():
        pytest.skip(f"workspace data not available: {path}")
    return path


def spin_until(executor, condition: Callable[[], object], timeout_s: float = 10.0) -> bool:  # noqa: ANN001
    """Spin an rclpy executor in bounded steps until `condition()` holds or `timeout_s` passes."""
    deadline = time.monotonic() + timeout_s
    while not condition() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    return bool(condition())


def lossless_player(ros_context, bag: Path):  # noqa: ANN001, ANN201 - rclpy types only where ROS is installed
    """A bag_player node replaying `bag` at 2x, lossless (waits for tracking's ack of each colour frame)."""
    from rclpy.parameter import Parameter

    from changing_slam_ros.nodes.bag_player_node import BagPlayerNode

    return BagPlayerNode(context=ros_context, parameter_overrides=[
        Parameter("bag", value=str(bag)), Parameter("rate", value=2.0), Parameter("lossless", value=True),
        Parameter("ack_topics", value=["/camera/rgb/image_color"]), Parameter("ack_timeout_s", value=60.0),
    ])  # fmt: skip
