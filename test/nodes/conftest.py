"""Fixtures for in-process node tests: an isolated rclpy context, bags written by the tests themselves."""

from __future__ import annotations

import os
import random
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers import FR1_XYZ_10, require

S = 1_000_000_000


@pytest.fixture
def ros_context(monkeypatch):
    """A fresh rclpy Context on a random DDS domain, discovery limited to this machine; shut down after."""
    rclpy = pytest.importorskip("rclpy")
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    domain = random.Random(os.getpid() ^ id(monkeypatch)).randint(100, 200)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain)
    try:
        yield context
    finally:
        context.try_shutdown()


@dataclass
class Fr1Bag:
    """A ROS 2 bag of the first fr1_xyz frames: rgb8 colour, 32FC1 depth, CameraInfo."""

    path: Path
    rgb_stamps_ns: list[int]  # header stamps = log times of the colour images
    depth_stamps_ns: list[int]
    first_rgb: np.ndarray  # (H, W, 3) uint8 RGB of frame 0, for pixel checks


def _stamp(store, ns: int):  # noqa: ANN001, ANN202 - rosbags dataclass
    return store.types["builtin_interfaces/msg/Time"](sec=ns // S, nanosec=ns % S)


def write_fr1_bag(path: Path, n: int = 10, scale: int = 1, storage: str = "mcap") -> Fr1Bag:
    """Write n fr1_xyz frames (downscaled by `scale`) to a ROS 2 bag with rosbags."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    from changing_slam_ros.io.image_codec import depth_image_fields, rgb_image_fields

    root = require(FR1_XYZ_10)
    rows = [ln.split() for ln in (root / "associations.txt").read_text().splitlines() if ln and ln[0] != "#"]
    store = get_typestore(Stores.ROS2_JAZZY)
    t = store.types
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    rgb_ns, depth_ns, first = [], [], None
    with Writer(path, version=9, storage_plugin=plugin) as w:
        c_rgb = w.add_connection("/camera/rgb/image_color", "sensor_msgs/msg/Image", typestore=store)
        c_depth = w.add_connection("/camera/depth/image", "sensor_msgs/msg/Image", typestore=store)
        c_info = w.add_connection("/camera/rgb/camera_info", "sensor_msgs/msg/CameraInfo", typestore=store)
        for t_rgb, f_rgb, t_depth, f_depth in rows[:n]:
            bgr = cv2.imread(str(root / f_rgb), cv2.IMREAD_COLOR)
            rgb = np.ascontiguousarray(bgr[::scale, ::scale, ::-1])
            depth = cv2.imread(str(root / f_depth), cv2.IMREAD_UNCHANGED)[::scale, ::scale].astype(np.float32) / 5000
            first = rgb if first is None else first
            ns_rgb, ns_depth = round(float(t_rgb) * S), round(float(t_depth) * S)
            hdr = t["std_msgs/msg/Header"](stamp=_stamp(store, ns_rgb), frame_id="openni_rgb_optical_frame")
            img = t["sensor_msgs/msg/Image"](header=hdr, **rgb_image_fields(rgb))
            w.write(c_rgb, ns_rgb, store.serialize_cdr(img, "sensor_msgs/msg/Image"))
            h, wd = rgb.shape[:2]
            info = t["sensor_msgs/msg/CameraInfo"](
                header=hdr, height=h, width=wd, distortion_model="plumb_bob", d=np.zeros(5),
                k=np.array([517.3 / scale, 0, 318.6 / scale, 0, 516.5 / scale, 255.3 / scale, 0, 0, 1]),
                r=np.eye(3).ravel(), p=np.zeros(12), binning_x=0, binning_y=0,
                roi=t["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
            )  # fmt: skip
            w.write(c_info, ns_rgb + 1, store.serialize_cdr(info, "sensor_msgs/msg/CameraInfo"))
            dhdr = t["std_msgs/msg/Header"](stamp=_stamp(store, ns_depth), frame_id="openni_rgb_optical_frame")
            dimg = t["sensor_msgs/msg/Image"](header=dhdr, **depth_image_fields(depth))
            w.write(c_depth, ns_depth, store.serialize_cdr(dimg, "sensor_msgs/msg/Image"))
            rgb_ns.append(ns_rgb)
            depth_ns.append(ns_depth)
    assert first is not None
    return Fr1Bag(path, rgb_ns, depth_ns, first)


@pytest.fixture
def fr1_bag_writer():
    """`write_fr1_bag(path, n, scale, storage)` for tests that need their own variant."""
    return write_fr1_bag


@pytest.fixture
def fr1_bag(tmp_path) -> Fr1Bag:
    return write_fr1_bag(tmp_path / "fr1_bag", n=10, scale=1)
