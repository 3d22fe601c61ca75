"""A structured-light / stereo RGB-D sensor model applied to exactly rendered frames.

Depth is disturbed in inverse depth, where a triangulating sensor measures: Gaussian noise of sigma
`inv_depth_sigma_per_m` (1/m) gives sigma_z = k z^2 with k the same number (Kinect k = 0.0012-0.0019 /m),
then 1/z is quantised in steps of `inv_depth_step_per_m` (the disparity quantum divided by f * baseline).
Holes: the projector's shadow beside near-over-far edges (width f * b (1/z_near - 1/z_far) px, computed
with a running maximum along each row), mixed pixels on both sides of a depth discontinuity, dark
surfaces that return too little light, blob dropouts, and everything outside [min_range, max_range].
Colour: exposure gain slowly varying over time, motion blur along the image motion of the view centre
during the exposure, and Gaussian plus shot noise. Instance ids stay exact (ground truth).
Everything random comes from the Generator passed in, so a seed fixes the result.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.geometry.se3 import invert
from changing_slam_ros.errors import SimError
from changing_slam_ros.sim.renderer import RenderedFrame

F64 = npt.NDArray[np.float64]
F32 = npt.NDArray[np.float32]
U8 = npt.NDArray[np.uint8]

BLOB_CELL_PX = 8  # dark-surface and dropout holes come in blobs about this size, not as salt noise


@dataclass(frozen=True)
class SensorModel:
    """Parameters of one RGB-D sensor; the defaults are an exact sensor (`is_exact()`)."""

    name: str = "exact"
    # depth
    inv_depth_sigma_per_m: float = 0.0  # k: sigma of 1/z (1/m), i.e. sigma_z = k z^2 metres
    inv_depth_step_per_m: float = 0.0  # quantum of 1/z (1/m); 0 = no quantisation
    min_range_m: float = 0.0
    max_range_m: float = math.inf
    baseline_m: float = 0.0  # projector / second imager offset along +x; 0 = no occlusion shadow
    edge_jump_rel: float = 0.0  # a neighbour farther by this fraction of z marks a discontinuity; 0 = off
    edge_hole_px: int = 0  # mixed pixels removed on each side of a discontinuity
    dark_level: float = 0.0  # grey level (0-255) below which a surface may return no depth
    dark_hole_prob: float = 0.0  # chance that a dark blob returns nothing
    dropout_prob: float = 0.0  # chance that any blob returns nothing
    # colour
    colour_sigma: float = 0.0  # Gaussian read noise, grey levels
    shot_noise: float = 0.0  # shot noise: sigma = shot_noise * sqrt(level)
    exposure_s: float = 0.0  # shutter time for motion blur; 0 = no blur
    exposure_amp: float = 0.0  # log-gain amplitude of the slow exposure changes (0.2 = about +-20 %)
    exposure_period_s: float = 7.0
    exposure_phase_rad: float = 0.0

    def is_exact(self) -> bool:
        return self == SensorModel(name=self.name)

    def as_dict(self) -> dict[str, Any]:
        return {k: (None if isinstance(v, float) and math.isinf(v) else v)
                for k, v in dataclasses.asdict(self).items()}

    def validate(self) -> None:
        """SimError naming the first parameter out of its range."""
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if isinstance(v, (int, float)) and not isinstance(v, bool) and v < 0:
                raise SimError(f"sensor {self.name}: {f.name} = {v}: expected >= 0")
        for f in ("dark_hole_prob", "dropout_prob"):
            if getattr(self, f) > 1.0:
                raise SimError(f"sensor {self.name}: {f} = {getattr(self, f)}: expected a probability in [0, 1]")
        if self.max_range_m <= self.min_range_m:
            raise SimError(f"sensor {self.name}: max_range_m {self.max_range_m} <= min_range_m {self.min_range_m}")
        if self.exposure_period_s <= 0:
            raise SimError(f"sensor {self.name}: exposure_period_s {self.exposure_period_s}: expected > 0")

    # --- the whole frame ---
    def apply(self, frame: RenderedFrame, camera: CameraIntrinsics, rng: np.random.Generator, t_s: float,
              T_world_cam: F64 | None = None, T_world_cam_prev: F64 | None = None,
              dt_s: float = 0.0) -> RenderedFrame:
        """The frame as this sensor would return it. `T_world_cam_prev` (4, 4), `dt_s` earlier, gives the
        camera's motion for the blur; without it there is no blur. Input arrays are not modified."""
        if self.is_exact():
            return frame
        depth = self.depth(frame.depth_m, frame.rgb, camera, rng)
        rgb = frame.rgb
        if self.exposure_s > 0 and T_world_cam is not None and T_world_cam_prev is not None and dt_s > 0:
            rgb = motion_blur(rgb, blur_vector_px(camera, T_world_cam_prev, T_world_cam, dt_s, self.exposure_s,
                                                  _median_depth(frame.depth_m)))
        rgb = self.colour(rgb, rng, t_s)
        return RenderedFrame(rgb=rgb, depth_m=depth, instance_ids=frame.instance_ids)

    # --- depth ---
    def depth(self, depth_m: F32, rgb: U8, camera: CameraIntrinsics, rng: np.random.Generator) -> F32:
        """Measured depth (H, W) float32 metres, 0 = no reading, from the exact `depth_m`."""
        z = np.asarray(depth_m, dtype=np.float64)
        valid = z > 0
        holes = ~valid
        if self.baseline_m > 0:
            holes |= projector_shadow(z, camera.fx * self.baseline_m)
        if self.edge_jump_rel > 0 and self.edge_hole_px > 0:
            holes |= depth_edges(z, self.edge_jump_rel, self.edge_hole_px)
        h, w = z.shape
        if self.dark_hole_prob > 0 and self.dark_level > 0:
            grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
            holes |= (grey < self.dark_level) & _blobs(rng, h, w, self.dark_hole_prob)
        if self.dropout_prob > 0:
            holes |= _blobs(rng, h, w, self.dropout_prob)
        inv = np.zeros_like(z)
        inv[valid] = 1.0 / z[valid]
        if self.inv_depth_sigma_per_m > 0:
            inv += self.inv_depth_sigma_per_m * rng.standard_normal(size=z.shape, dtype=np.float32)
        if self.inv_depth_step_per_m > 0:
            inv = np.round(inv / self.inv_depth_step_per_m) * self.inv_depth_step_per_m
        out = np.zeros_like(z)
        ok = valid & ~holes & (inv > 0)
        out[ok] = 1.0 / inv[ok]
        out[(out < self.min_range_m) | (out > self.max_range_m)] = 0.0
        return out.astype(np.float32)

    # --- colour ---
    def gain_at(self, t_s: float) -> float:
        """Exposure gain at `t_s`: exp of two slow sinusoids (an auto-exposure hunting as the view changes)."""
        if self.exposure_amp == 0:
            return 1.0
        w = 2 * math.pi / self.exposure_period_s
        s = math.sin(w * t_s + self.exposure_phase_rad) + 0.5 * math.sin(2.7 * w * t_s + 2 * self.exposure_phase_rad)
        return math.exp(self.exposure_amp * s / 1.5)

    def colour(self, rgb: U8, rng: np.random.Generator, t_s: float) -> U8:
        """Exposure gain, then Gaussian read noise and shot noise, clipped to uint8."""
        gain = self.gain_at(t_s)
        if gain == 1.0 and self.colour_sigma == 0 and self.shot_noise == 0:
            return rgb
        x = rgb.astype(np.float32) * np.float32(gain)
        if self.colour_sigma > 0 or self.shot_noise > 0:
            level = x.mean(axis=2, keepdims=True)  # shot noise from the pixel's brightness, per channel draw
            sigma = np.sqrt(np.float32(self.colour_sigma ** 2) + np.float32(self.shot_noise ** 2) * level)
            x += sigma * _unit_noise(rng, x.shape)
        return np.clip(np.rint(x), 0, 255).astype(np.uint8)


def _unit_noise(rng: np.random.Generator, shape: tuple[int, ...]) -> F32:
    """Zero-mean unit-variance noise, nearly Gaussian: the sum of three uniform bytes (Irwin-Hall), about
    five times cheaper to draw than normal deviates for a full colour image."""
    total = rng.integers(0, 256, size=shape, dtype=np.uint8).astype(np.int16)
    total += rng.integers(0, 256, size=shape, dtype=np.uint8)
    total += rng.integers(0, 256, size=shape, dtype=np.uint8)
    # a uniform byte has variance (256^2 - 1) / 12; three of them sum to mean 382.5
    return (total.astype(np.float32) - np.float32(382.5)) * np.float32(1.0 / math.sqrt(3 * (256 ** 2 - 1) / 12))


def _median_depth(depth_m: F32) -> float:
    valid = depth_m[depth_m > 0]
    return float(np.median(valid)) if valid.size else 2.0


def _blobs(rng: np.random.Generator, h: int, w: int, prob: float) -> npt.NDArray[np.bool_]:
    """A random mask (H, W) covering about `prob` of the image in blobs of roughly BLOB_CELL_PX."""
    gh, gw = max(2, h // BLOB_CELL_PX + 2), max(2, w // BLOB_CELL_PX + 2)
    field = rng.random((gh, gw)).astype(np.float32)
    up = cv2.resize(field, (w, h), interpolation=cv2.INTER_LINEAR)
    # the upsampled field is no longer uniform; threshold at its own quantile for the stated coverage
    if prob >= 1.0:
        return np.ones((h, w), dtype=bool)
    return up > np.quantile(up[::4, ::4], 1.0 - prob)  # a subsample's quantile is close enough, and cheap


def projector_shadow(z: F64, f_times_b_px_m: float) -> npt.NDArray[np.bool_]:
    """Pixels (H, W) the projector cannot light: it sits `b` to the camera's right, so a near surface hides
    the far surface just right of it. A pixel at column u with disparity d = f b / z is seen by the projector
    at u + d; it is shadowed when some pixel left of it in the row lands farther right (running maximum)."""
    h, w = z.shape
    d = np.zeros_like(z)
    valid = z > 0
    d[valid] = f_times_b_px_m / z[valid]
    p = np.arange(w, dtype=np.float64)[None, :] + d
    p[~valid] = -np.inf  # no surface: casts no shadow
    reach = np.maximum.accumulate(p, axis=1)
    prev = np.concatenate([np.full((h, 1), -np.inf), reach[:, :-1]], axis=1)
    return valid & (prev > p + 0.5)


def depth_edges(z: F64, jump_rel: float, width_px: int) -> npt.NDArray[np.bool_]:
    """Pixels within `width_px` of a depth discontinuity (a 4-neighbour differing by more than
    `jump_rel` of the nearer depth), on both sides: the mixed pixels a real sensor drops."""
    edge = np.zeros(z.shape, dtype=bool)
    for axis in (0, 1):
        a = np.swapaxes(z, 0, axis)
        jump = np.abs(np.diff(a, axis=0)) > jump_rel * np.minimum(a[1:], a[:-1])
        e = np.zeros(a.shape, dtype=bool)
        e[1:] |= jump
        e[:-1] |= jump
        edge |= np.swapaxes(e, 0, axis)
    if width_px > 1:
        k = np.ones((2 * width_px - 1, 2 * width_px - 1), dtype=np.uint8)
        edge = cv2.dilate(edge.astype(np.uint8), k).astype(bool)
    return edge


def blur_vector_px(camera: CameraIntrinsics, T_world_prev: F64, T_world_cam: F64, dt_s: float, exposure_s: float,
                   depth_m: float) -> tuple[float, float]:
    """Image motion (dx, dy) in pixels of the view centre, at `depth_m`, during the `exposure_s` before the
    frame, assuming the camera moved at constant speed from `T_world_prev` (dt_s earlier)."""
    frac = min(1.0, exposure_s / dt_s)
    T_prev_cam = invert(T_world_prev) @ T_world_cam  # current camera in the previous one
    p_cam = np.array([0.0, 0.0, depth_m, 1.0])
    p_prev = T_prev_cam @ p_cam
    if p_prev[2] <= 1e-6:
        return 0.0, 0.0
    u_prev = camera.fx * p_prev[0] / p_prev[2]
    v_prev = camera.fy * p_prev[1] / p_prev[2]
    # the centre pixel moves from (u_prev, v_prev) to (0, 0) relative to the principal point over dt
    return float(-u_prev * frac), float(-v_prev * frac)


def motion_blur(rgb: U8, vector_px: tuple[float, float]) -> U8:
    """Average of the image over a straight motion `vector_px` (dx, dy): a line kernel."""
    dx, dy = vector_px
    length = math.hypot(dx, dy)
    if length < 1.0:
        return rgb
    n = int(math.ceil(length)) | 1  # odd kernel size, centred
    kernel = np.zeros((n, n), dtype=np.float32)
    c = n // 2
    for s in np.linspace(-0.5, 0.5, 4 * n + 1):  # sample the segment densely, centred on the kernel
        kernel[int(round(c + s * dy)), int(round(c + s * dx))] += 1.0
    kernel /= kernel.sum()
    return cv2.filter2D(rgb, -1, kernel, borderType=cv2.BORDER_REPLICATE)


# --- presets and per-seed draws ---

EXACT = SensorModel()


def kinect_like(k_per_m: float = 0.0015, max_range_m: float = 4.5) -> SensorModel:
    """A Kinect v1 / Xtion-like structured-light sensor (TUM RGB-D's): 7.5 cm baseline, 1/8 px disparity
    steps at f = 580 px (1/z quantum 0.125 / (580 * 0.075) per metre), 0.5 m minimum range."""
    return SensorModel(
        name="kinect", inv_depth_sigma_per_m=k_per_m, inv_depth_step_per_m=0.125 / (580.0 * 0.075),
        min_range_m=0.5, max_range_m=max_range_m, baseline_m=0.075, edge_jump_rel=0.06, edge_hole_px=2,
        dark_level=30.0, dark_hole_prob=0.5, dropout_prob=0.01, colour_sigma=2.0, shot_noise=0.35,
        exposure_s=0.012, exposure_amp=0.15, exposure_period_s=8.0,
    )


def realsense_like(k_per_m: float = 0.003, max_range_m: float = 6.0) -> SensorModel:
    """A RealSense D435-like active stereo sensor: 5 cm baseline, subpixel 1/16 px steps at f = 385 px,
    0.2 m minimum range, more noise with distance than a Kinect, fewer dark-surface holes."""
    return SensorModel(
        name="realsense", inv_depth_sigma_per_m=k_per_m, inv_depth_step_per_m=(1.0 / 16) / (385.0 * 0.05),
        min_range_m=0.2, max_range_m=max_range_m, baseline_m=0.05, edge_jump_rel=0.05, edge_hole_px=1,
        dark_level=20.0, dark_hole_prob=0.3, dropout_prob=0.005, colour_sigma=2.5, shot_noise=0.4,
        exposure_s=0.008, exposure_amp=0.1, exposure_period_s=6.0,
    )


PRESETS = {"exact": lambda: EXACT, "kinect": kinect_like, "realsense": realsense_like}


def preset(name: str) -> SensorModel:
    """A named sensor: exact, kinect or realsense; SimError for other names."""
    try:
        return PRESETS[name]()
    except KeyError as err:
        raise SimError(f"sensor {name!r}: unknown; known: {', '.join(PRESETS)}") from err


def draw_sensor(rng: np.random.Generator) -> SensorModel:
    """A sensor for one random scene: exact (1 in 5), Kinect-like or RealSense-like, each parameter drawn
    around its preset (noise k, range, holes, colour noise, shutter time, exposure hunting)."""
    kind = rng.choice(["exact", "kinect", "kinect", "realsense", "realsense"])
    if kind == "exact":
        return EXACT
    base = kinect_like(float(rng.uniform(0.0012, 0.0019)), float(rng.uniform(4.5, 6.0))) if kind == "kinect" else \
        realsense_like(float(rng.uniform(0.002, 0.004)), float(rng.uniform(5.0, 8.0)))
    return dataclasses.replace(
        base,
        dark_hole_prob=float(rng.uniform(0.2, 0.7)), dropout_prob=float(rng.uniform(0.0, 0.02)),
        colour_sigma=float(rng.uniform(1.0, 4.0)), shot_noise=float(rng.uniform(0.2, 0.6)),
        exposure_s=float(rng.uniform(0.004, 0.02)), exposure_amp=float(rng.uniform(0.0, 0.25)),
        exposure_period_s=float(rng.uniform(4.0, 12.0)), exposure_phase_rad=float(rng.uniform(0, 2 * np.pi)),
    )


def frame_rng(seed: int, frame_index: int) -> np.random.Generator:
    """The sensor's random stream for one frame: fixed by the seed and the frame index alone, so rendering
    the first N frames gives the same first N frames as a longer render."""
    return np.random.default_rng([int(seed) & 0xFFFFFFFF, 0x5E_45_0B, int(frame_index)])
