"""Intrinsics a dataset ships beside its images, and the comparison of two cameras that should be one.

A run's camera comes from one place (the config, a `camera_info.yaml`, a bag's CameraInfo); the data or a
loaded map may carry another. `compare_cameras` says how two cameras differ, beyond calibration noise, and a
`CameraMismatch` is what a reader or the run reports for the console and metrics.json. 7-Scenes ships
`camera-intrinsics.txt` (the 3x3 camera matrix, whitespace-separated, no image size): `read_intrinsics_txt`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.errors import DatasetError, read_utf8

FOCAL_TOLERANCE = 0.01  # relative: calibrations of one camera agree to well under 1 %
CENTRE_TOLERANCE = 0.01  # of the image width / height
DIST_TOLERANCE = 0.01  # largest difference of one distortion coefficient
# What a ROS driver publishes without a calibration file (TUM's own bags carry it): not a calibration.
ROS_DEFAULT_CAMERA = CameraIntrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)


def describe_camera(cam: CameraIntrinsics) -> str:
    """'640x480 fx 585 fy 585 cx 320 cy 240' (distortion added when non-zero)."""
    text = f"{cam.width}x{cam.height} fx {cam.fx:g} fy {cam.fy:g} cx {cam.cx:g} cy {cam.cy:g}"
    return text + (f" dist {[round(d, 4) for d in cam.dist]}" if cam.has_distortion else "")


def compare_cameras(data: CameraIntrinsics, other: CameraIntrinsics, scale: bool = True) -> list[str]:
    """How `other` differs from `data` beyond the tolerances above, one phrase per field ('fx 517.3 vs 585').

    With `scale`, `other` is first scaled to `data`'s image size (a config for 640x480 on 320x240 images is the
    same camera when everything halves); without it a different size is itself a difference."""
    original, scaled_from = other, ""
    if (other.width, other.height) != (data.width, data.height):
        same_aspect = other.width * data.height == other.height * data.width
        if not scale or not same_aspect:
            return [f"size {other.width}x{other.height} vs {data.width}x{data.height}"]
        scaled_from = f"{other.width}x{other.height}"
        other = other.scaled(data.width, data.height)
    out: list[str] = []
    for name in ("fx", "fy"):
        a, b = getattr(data, name), getattr(other, name)
        if abs(a - b) > FOCAL_TOLERANCE * a:
            out.append(f"{name} {b:g} vs {a:g}")
    for name, size in (("cx", data.width), ("cy", data.height)):
        a, b = getattr(data, name), getattr(other, name)
        if abs(a - b) > CENTRE_TOLERANCE * size:
            out.append(f"{name} {b:g} vs {a:g}")
    n = max(len(data.dist), len(other.dist))
    da, db = list(data.dist) + [0.0] * (n - len(data.dist)), list(other.dist) + [0.0] * (n - len(other.dist))
    if max((abs(a - b) for a, b in zip(da, db)), default=0.0) > DIST_TOLERANCE:
        out.append(f"dist {[round(d, 4) for d in db]} vs {[round(d, 4) for d in da]}")
    if out and other is not original:
        out.append(f"{scaled_from} values scaled to {data.width}x{data.height}")
    return out


@dataclass(frozen=True)
class CameraMismatch:
    """Two cameras that should agree and do not.

    - `data_source` / `data`: the camera the data (or the loaded map) carries, and where it was read;
    - `other_source` / `other`: the camera it was compared with (the config's, or this run's);
    - `used`: which of the two the run uses;
    - `differences`: `compare_cameras(data, other)`.
    """

    data_source: str
    data: CameraIntrinsics
    other_source: str
    other: CameraIntrinsics
    used: str
    differences: tuple[str, ...]

    def message(self) -> str:
        return (f"camera of {self.other_source} disagrees with {self.data_source}: {', '.join(self.differences)}; "
                f"using {self.used}")  # fmt: skip

    def as_dict(self) -> dict[str, Any]:
        def fields(cam: CameraIntrinsics) -> dict[str, Any]:
            return {"width": cam.width, "height": cam.height, "fx": cam.fx, "fy": cam.fy, "cx": cam.cx,
                    "cy": cam.cy, "dist": list(cam.dist)}  # fmt: skip

        return {"data_source": self.data_source, "data": fields(self.data), "other_source": self.other_source,
                "other": fields(self.other), "used": self.used, "differences": list(self.differences)}  # fmt: skip


def check_cameras(data_source: str, data: CameraIntrinsics, other_source: str, other: CameraIntrinsics | None,
                  used: str, scale: bool = True) -> CameraMismatch | None:  # fmt: skip
    """A `CameraMismatch` when `other` (None = nothing to compare) differs from `data`, else None."""
    if other is None:
        return None
    differences = compare_cameras(data, other, scale)
    if not differences:
        return None
    return CameraMismatch(data_source, data, other_source, other, used, tuple(differences))


def first_keyframe_camera(keyframes: dict[int, Any]) -> CameraIntrinsics | None:
    """The camera of a loaded map's first keyframe (`SlamMap.keyframes`), None when it has none."""
    return keyframes[min(keyframes)].camera if keyframes else None


def map_camera_mismatch(map_name: str, map_camera: CameraIntrinsics | None,
                        camera: CameraIntrinsics) -> CameraMismatch | None:  # fmt: skip
    """This run's `camera` against the one a loaded map was made with (sizes are not scaled: a map's features and
    depths belong to its image size)."""
    if map_camera is None:
        return None
    return check_cameras(f"the loaded map {map_name}", map_camera, "this run", camera, "this run's camera", False)


def read_intrinsics_txt(path: Path, width: int, height: int) -> CameraIntrinsics:
    """7-Scenes' `camera-intrinsics.txt`: a 3x3 camera matrix, three numbers a row; the file gives no image
    size, so `width` x `height` (the config's) is assumed. DatasetError naming the file and line."""
    text = read_utf8(path, DatasetError)
    rows = [(i, line.split()) for i, line in enumerate(text.splitlines(), start=1) if line.strip()]
    if len(rows) != 3 or any(len(r) != 3 for _, r in rows):
        raise DatasetError(f"{path}: expected a 3x3 camera matrix (three rows of three numbers)")
    k: list[float] = []
    for lineno, row in rows:
        try:
            k += [float(v) for v in row]
        except ValueError:
            raise DatasetError(f"{path}:{lineno}: camera matrix values must be numbers") from None
    fx, cx, fy, cy = k[0], k[2], k[4], k[5]
    if not all(math.isfinite(v) for v in k) or fx <= 0 or fy <= 0:
        raise DatasetError(f"{path}: camera matrix has fx={fx}, fy={fy}; expected finite values, fx and fy > 0")
    return CameraIntrinsics(width, height, fx, fy, cx, cy)
