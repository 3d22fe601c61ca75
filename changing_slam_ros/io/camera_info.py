"""`sensor_msgs/CameraInfo` and the ROS camera-calibration YAML (`camera_info.yaml`) <-> CameraIntrinsics.

Messages are duck-typed: ROS 2 / rclpy field names (`k`, `d`) and rosbags' ROS 1 names (`K`, `D`)
are both accepted. Intrinsics come from K (the camera matrix of the raw image); distortion models
`plumb_bob` (k1 k2 p1 p2 k3) and `rational_polynomial` (k1 k2 p1 p2 k3 k4 k5 k6, OpenCV order)
are kept as given; any other model must carry all-zero coefficients.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.errors import BagError, DatasetError, read_utf8, yaml_error
from changing_slam_ros.io.atomic import atomic_write_text

SUPPORTED_MODELS = ("plumb_bob", "rational_polynomial")


def _field(msg: Any, name: str) -> Any:
    for candidate in (name, name.upper()):
        if hasattr(msg, candidate):
            return getattr(msg, candidate)
    raise AttributeError(name)


def intrinsics_from_values(
    width: int, height: int, k: Any, d: Any, model: str, where: str, error: type[Exception]
) -> CameraIntrinsics:
    """Validate raw CameraInfo values and build intrinsics; `error` is raised naming `where`."""
    k_arr = np.asarray(k, dtype=np.float64).reshape(-1)
    if k_arr.size != 9:
        raise error(f"{where}: camera matrix has {k_arr.size} values, expected 9 (row-major 3x3)")
    fx, fy, cx, cy = float(k_arr[0]), float(k_arr[4]), float(k_arr[2]), float(k_arr[5])
    if not (fx > 0 and fy > 0 and np.isfinite([fx, fy, cx, cy]).all()):
        raise error(f"{where}: camera matrix has fx={fx}, fy={fy}; expected a calibrated camera (fx, fy > 0)")
    if int(width) <= 0 or int(height) <= 0:
        raise error(f"{where}: image size {width}x{height}, expected positive width and height")
    dist = tuple(float(x) for x in np.asarray(d, dtype=np.float64).reshape(-1))
    model = str(model or "")
    if model not in SUPPORTED_MODELS and any(abs(x) > 0 for x in dist):
        raise error(
            f"{where}: distortion model '{model}' unsupported; expected {' or '.join(SUPPORTED_MODELS)} "
            "(or all-zero coefficients)"
        )
    if not any(abs(x) > 0 for x in dist):
        dist = (0.0, 0.0, 0.0, 0.0, 0.0)
    return CameraIntrinsics(int(width), int(height), fx, fy, cx, cy, dist)


def intrinsics_from_camera_info(msg: Any, topic: str = "camera_info") -> CameraIntrinsics:
    """CameraInfo message (ROS 2 `k`/`d` or ROS 1 `K`/`D` field names) -> CameraIntrinsics."""
    try:
        k, d = _field(msg, "k"), _field(msg, "d")
        width, height, model = msg.width, msg.height, msg.distortion_model
    except AttributeError as err:
        raise BagError(f"{topic}: not a sensor_msgs/CameraInfo (no field {err})") from err
    return intrinsics_from_values(width, height, k, d, model, topic, BagError)


def camera_info_fields(camera: CameraIntrinsics) -> dict[str, Any]:
    """CameraIntrinsics -> CameraInfo field values (ROS 2 names; header, binning and roi left out)."""
    d = np.asarray(camera.dist, dtype=np.float64)
    k = camera.K.reshape(-1)
    p = np.zeros((3, 4))
    p[:3, :3] = camera.K
    return {
        "height": camera.height,
        "width": camera.width,
        "distortion_model": _model_for(camera.dist),
        "d": d,
        "k": k,
        "r": np.eye(3).reshape(-1),
        "p": p.reshape(-1),
    }


def _model_for(dist: tuple[float, ...]) -> str:
    return "rational_polynomial" if len(dist) == 8 else "plumb_bob"


# -- camera_info.yaml --------------------------------------------------------------------------
def read_camera_info_yaml(path: str | os.PathLike[str]) -> CameraIntrinsics:
    """Read a ROS camera-calibration YAML (as written by camera_calibration / camera_info_manager)."""
    p = Path(path)
    text = read_utf8(p, DatasetError, what="camera calibration", noun="camera calibration")
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise DatasetError(yaml_error(p, err)) from err
    if not isinstance(data, dict):
        raise DatasetError(f"{p}: expected a camera calibration mapping, got {type(data).__name__}")
    for key in ("image_width", "image_height", "camera_matrix"):
        if key not in data:
            raise DatasetError(f"{p}: missing key '{key}' (ROS camera calibration YAML)")
    k = _matrix(data["camera_matrix"], 3, 3, f"{p}: camera_matrix")
    dist_block = data.get("distortion_coefficients")
    d = _matrix(dist_block, 1, None, f"{p}: distortion_coefficients") if dist_block is not None else []
    model = data.get("distortion_model", "plumb_bob")
    return intrinsics_from_values(
        data["image_width"], data["image_height"], k, d, model, str(p), DatasetError
    )


def _matrix(block: Any, rows: int, cols: int | None, where: str) -> list[float]:
    if not isinstance(block, dict) or "data" not in block:
        raise DatasetError(f"{where}: expected a mapping with rows, cols and data")
    values = block["data"]
    if not isinstance(values, list) or not all(
        isinstance(v, (int, float)) and not isinstance(v, bool) for v in values
    ):
        raise DatasetError(f"{where}: data must be a list of numbers")
    r = block.get("rows", rows)
    c = block.get("cols", len(values) if cols is None else cols)
    if r * c != len(values) or (cols is not None and (r, c) != (rows, cols)):
        raise DatasetError(f"{where}: rows={r} cols={c} with {len(values)} values, expected {rows}x{cols or 'n'}")
    return [float(v) for v in values]


def format_camera_info_yaml(camera: CameraIntrinsics, camera_name: str = "camera") -> str:
    f = camera_info_fields(camera)

    def block(rows: int, cols: int, values: Any) -> dict[str, Any]:
        return {"rows": rows, "cols": cols, "data": [float(v) for v in np.asarray(values).reshape(-1)]}

    data = {
        "image_width": camera.width,
        "image_height": camera.height,
        "camera_name": camera_name,
        "camera_matrix": block(3, 3, f["k"]),
        "distortion_model": f["distortion_model"],
        "distortion_coefficients": block(1, len(f["d"]), f["d"]),
        "rectification_matrix": block(3, 3, f["r"]),
        "projection_matrix": block(3, 4, f["p"]),
    }
    return str(yaml.safe_dump(data, sort_keys=False, default_flow_style=None))


def write_camera_info_yaml(
    path: str | os.PathLike[str], camera: CameraIntrinsics, camera_name: str = "camera"
) -> None:
    """Write atomically in the ROS camera-calibration YAML format."""
    atomic_write_text(path, format_camera_info_yaml(camera, camera_name))
