"""Shared test helpers: where the workspace data lives, and small fakes."""

from __future__ import annotations

import os
import signal
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


def default_sigint() -> None:
    """`preexec_fn` of a child that a test stops with SIGINT: a suite started in the background (`make test &`)
    passes SIGINT on as ignored, and Python then installs no KeyboardInterrupt; the child gets the default action
    back, as at a terminal."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


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


def write_bag_with_one_bad_image(path: Path, bad_index: int = 4, frames: int = 6) -> int:
    """The first `frames` frames of the fr1 sample bag (`bags/tum_fr1_xyz_first10.mcap`), the colour image of frame
    `bad_index` cut to 10 bytes of pixel data (its step and size still claim 640x480). Returns that frame's stamp
    in nanoseconds."""
    import numpy as np

    from changing_slam_ros.io.camera_info import camera_info_fields
    from changing_slam_ros.io.dataset import open_dataset
    from changing_slam_ros.io.image_codec import depth_image_fields
    from changing_slam_ros.io.mcap_writer import CAMERA_INFO, IMAGE, RgbdMcapWriter

    stamp = 0
    with RgbdMcapWriter(path) as w:
        for i, frame in enumerate(open_dataset(REPO / "bags" / "tum_fr1_xyz_first10.mcap", "tum_fr1")):
            if i == frames:
                break
            if i != bad_index:
                w.write_frame(frame)
                continue
            t, stamp = w.typestore.types, frame.stamp_ns
            header = t["std_msgs/msg/Header"](t["builtin_interfaces/msg/Time"](*divmod(stamp, 10**9)), "camera")
            info = t[CAMERA_INFO](header, **camera_info_fields(frame.camera), binning_x=0, binning_y=0,
                                  roi=t["sensor_msgs/msg/RegionOfInterest"](0, 0, 0, 0, False))  # fmt: skip
            bad = t[IMAGE](header, 480, 640, "rgb8", 0, 640 * 3, np.zeros(10, np.uint8))
            w.write_message(w.info_topic, CAMERA_INFO, info, stamp)
            w.write_message(w.rgb_topic, IMAGE, bad, stamp)
            w.write_message(w.depth_topic, IMAGE, t[IMAGE](header, **depth_image_fields(frame.depth_m, "32FC1")), stamp)
    return stamp
