"""Should a mapped object have been seen from this keyframe? (Changing-SLAM §4.6-4.7, the vicinity search)

An object "should have been seen" when its centroid, transformed into the camera, lies in front of the
camera within range, projects inside the image, would look large enough to be detected and is not
occluded according to the measured depth (the tests are in `check_visibility`). A window with no valid
depth counts as "unknown" and the object is not expected (no evidence either way).

When an object was removed, the camera sees what stood behind it (a wall, the floor), which is
farther than the centroid: the object is expected and missed, and its belief drops.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.objects.map_object import ObjectMapConfig
from changing_slam_ros.core.geometry.se3 import invert

F64 = npt.NDArray[np.float64]


class Visibility(enum.Enum):
    """Why an object is or is not expected in a view."""

    VISIBLE = "visible"
    BEHIND_CAMERA = "behind_camera"
    OUT_OF_RANGE = "out_of_range"
    OUT_OF_IMAGE = "out_of_image"
    TOO_SMALL = "too_small"
    OCCLUDED = "occluded"
    NO_DEPTH = "no_depth"


@dataclass(frozen=True)
class VisibilityCheck:
    """The verdict, the centroid's pixel (u, v) and depth (m), and the measured depth there (0 = none)."""

    visibility: Visibility
    pixel_uv: tuple[float, float]
    centroid_depth_m: float
    measured_depth_m: float

    @property
    def expected(self) -> bool:
        return self.visibility is Visibility.VISIBLE


def check_visibility(centroid_w: F64, T_world_cam: F64, camera: CameraIntrinsics,
                     depth_m: npt.NDArray[np.floating] | None, config: ObjectMapConfig,
                     box_size_m: F64 | None = None) -> VisibilityCheck:
    """Visibility of a centroid (3,) from the optical-frame camera pose T_world_cam (4, 4).

    `depth_m` (H, W) metres, 0 = invalid, registered to `camera`; None skips the occlusion test (then a
    centroid in the frustum and range counts as visible). `box_size_m` (3,): the object's box; half its
    largest side is added to the occlusion tolerance, and it drives the size test (None skips both).

    Tests, in order:

    1. the centroid lies in front of the camera within [min_range_m, max_range_m] along the optical axis;
    2. it projects inside the image with `margin_px` to spare on every side;
    3. the object would look large enough to be detected: its box covers at least
       `min_projected_area(config, camera)` pixels at that depth ((fx / z)^2 times its two largest sides): a
       fraction of the image (`min_projected_area_fraction`), at least `min_projected_area_px`;
    4. it is not occluded: the measured depth around that pixel (median of the valid depths in a
       (2 w + 1)^2 window) is not much closer than the centroid:
           depth_measured >= z_centroid - (occlusion_tolerance_m + half the object's largest box side).
       The tolerance includes the object's half-size because when the object is there, the camera
       measures its front surface, which is closer than its centroid. A window with no valid depth
       counts as "unknown" and the object is not expected.
    """
    p_c = invert(np.asarray(T_world_cam, float)) @ np.append(np.asarray(centroid_w, float), 1.0)
    z = float(p_c[2])
    if z <= 1e-6:
        return VisibilityCheck(Visibility.BEHIND_CAMERA, (float("nan"), float("nan")), z, 0.0)
    u = camera.fx * p_c[0] / z + camera.cx
    v = camera.fy * p_c[1] / z + camera.cy
    uv = (float(u), float(v))
    if not config.min_range_m <= z <= config.max_range_m:
        return VisibilityCheck(Visibility.OUT_OF_RANGE, uv, z, 0.0)
    m = config.margin_px
    if not (m <= u <= camera.width - 1 - m and m <= v <= camera.height - 1 - m):
        return VisibilityCheck(Visibility.OUT_OF_IMAGE, uv, z, 0.0)
    half_extent_m = 0.0
    if box_size_m is not None:
        sides = np.sort(np.asarray(box_size_m, float).reshape(3))
        half_extent_m = 0.5 * float(sides[2])
        if (camera.fx / z) * (camera.fy / z) * float(sides[1] * sides[2]) < min_projected_area(config, camera):
            return VisibilityCheck(Visibility.TOO_SMALL, uv, z, 0.0)
    if depth_m is None:
        return VisibilityCheck(Visibility.VISIBLE, uv, z, 0.0)
    measured = window_depth_m(depth_m, u, v, config.depth_window_px)
    if measured <= 0.0:
        return VisibilityCheck(Visibility.NO_DEPTH, uv, z, 0.0)
    if measured < z - (config.occlusion_tolerance_m + half_extent_m):
        return VisibilityCheck(Visibility.OCCLUDED, uv, z, measured)
    return VisibilityCheck(Visibility.VISIBLE, uv, z, measured)


def min_projected_area(config: ObjectMapConfig, camera: CameraIntrinsics) -> float:
    """Smallest projected box (pixels) of an object that counts as expected in an image of `camera`'s size."""
    return max(config.min_projected_area_fraction * camera.width * camera.height, config.min_projected_area_px)


def window_depth_m(depth_m: npt.NDArray[np.floating], u: float, v: float, half_window_px: int) -> float:
    """Median of the valid (> 0, finite) depths (H, W) in the window around pixel (u, v); 0 if none."""
    h, w = depth_m.shape[:2]
    cu, cv = int(round(u)), int(round(v))
    r = max(0, int(half_window_px))
    patch = np.asarray(depth_m[max(0, cv - r): min(h, cv + r + 1), max(0, cu - r): min(w, cu + r + 1)], float)
    valid = patch[np.isfinite(patch) & (patch > 0.0)]
    return float(np.median(valid)) if valid.size else 0.0


def depth_from_keypoints(keypoints_px: npt.NDArray[np.floating], depths_m: npt.NDArray[np.floating],
                         camera: CameraIntrinsics, radius_px: int = 6) -> npt.NDArray[np.float32]:
    """A sparse depth image (H, W) float32 from a keyframe's keypoints (N, 2) and depths (N,), 0 = none:
    each keypoint with depth > 0 fills a (2 r + 1)^2 square, the nearest depth winning where squares overlap.
    For callers that keep no depth image per keyframe; the occlusion test then reads keypoint depths."""
    out = np.full((camera.height, camera.width), np.inf, np.float32)
    kp = np.asarray(keypoints_px, float).reshape(-1, 2)
    d = np.asarray(depths_m, float).reshape(-1)
    ok = np.isfinite(d) & (d > 0)
    r = max(0, int(radius_px))
    for (u, v), z in zip(kp[ok], d[ok]):
        cu, cv = int(round(u)), int(round(v))
        x0, x1 = max(0, cu - r), min(camera.width, cu + r + 1)
        y0, y1 = max(0, cv - r), min(camera.height, cv + r + 1)
        if x0 < x1 and y0 < y1:
            np.minimum(out[y0:y1, x0:x1], np.float32(z), out=out[y0:y1, x0:x1])
    out[~np.isfinite(out)] = 0.0
    return out
