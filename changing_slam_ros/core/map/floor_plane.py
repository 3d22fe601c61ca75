"""The floor of a map: its up direction and height, from depth points in the map frame (`estimate_floor`).

The map frame is the first camera's optical frame, so "up" has to be found. The cameras' own up axes (-y of
each optical frame) give a hint good to a few tens of degrees for a robot or a hand-held camera (a camera
pitched down 20 degrees is 20 degrees off); the floor is the large plane within that tolerance with the least
of the scene below it, found by RANSAC and refined by least squares. Without such a plane (the floor out of
view) the lowest points stand in and `n_support` is 0, which callers report.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
LOW_QUANTILES = (0.05, 0.25)


@dataclass(frozen=True)
class FloorEstimate:
    """The floor plane {x : up . x = height} in the map frame; `up` (3,) unit; `n_support` points within
    `inlier_m` of it (0 when no floor was found and the lowest points stand in)."""

    up: F64
    height: float
    n_support: int

    def frame(self, forward_hint: F64 | None = None) -> F64:
        """T_map_floor (4, 4): z along `up`, origin on the floor below the map origin, x along `forward_hint`
        laid onto the floor. By default the hint is the map's z (the first camera's viewing direction, in a map
        built in that camera's optical frame), or the map's x where the map's z lies within 25 degrees of the
        floor's normal (a z-up map, built in a robot base's frame: its x is the base's forward; a camera that
        looks down more steeply than 65 degrees at the start gets the same)."""
        z = self.up / np.linalg.norm(self.up)
        if forward_hint is None:
            f = np.array([1.0, 0.0, 0.0]) if abs(z[2]) > np.cos(np.deg2rad(25.0)) else np.array([0.0, 0.0, 1.0])
        else:
            f = np.asarray(forward_hint, float).reshape(3)
        x = f - (f @ z) * z
        if np.linalg.norm(x) < 1e-6:  # looking straight down: any horizontal axis
            x = np.array([1.0, 0.0, 0.0]) - z[0] * z
        x /= np.linalg.norm(x)
        T = np.eye(4)
        T[:3, 0], T[:3, 1], T[:3, 2] = x, np.cross(z, x), z
        T[:3, 3] = self.height * z
        return T


def camera_up_hint(poses_world_cam: F64) -> F64:
    """The mean up axis (-y of the optical frame) of camera poses (N, 4, 4), unit; the map's -y when none."""
    poses = np.asarray(poses_world_cam, float).reshape(-1, 4, 4)
    if not len(poses):
        return np.array([0.0, -1.0, 0.0])
    up = -poses[:, :3, 1].sum(axis=0)
    n = np.linalg.norm(up)
    return up / n if n > 1e-9 else np.array([0.0, -1.0, 0.0])


def estimate_floor(points_w: F64, up_hint: F64, inlier_m: float = 0.03, min_fraction: float = 0.01,
                   max_below_fraction: float = 0.02, max_tilt_deg: float = 35.0, iterations: int = 200,
                   max_points: int = 20000, seed: int = 0) -> FloorEstimate | None:
    """The floor under `points_w` (N, 3, map frame), `up_hint` (3,) roughly up. RANSAC planes whose normal lies
    within `max_tilt_deg` of the hint, that hold at least `min_fraction` of the points within `inlier_m` and have at
    most `max_below_fraction` below compete, `iterations` drawn from each of the lowest `LOW_QUANTILES` of the
    points along the hint; the floor is the one with the fewest points below it (a floor has the room above it; a
    table top has its legs and the floor below), refined by least squares on its inliers. Hypotheses are scored on
    at most `max_points` points (a seeded subsample). Without such a plane the lowest points (along the hint) stand
    in, with `n_support` 0. None for fewer than 3 points."""
    pts = np.asarray(points_w, float).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if len(pts) < 3:
        return None
    hint = np.asarray(up_hint, float).reshape(3)
    hint = hint / np.linalg.norm(hint)
    rng = np.random.default_rng(seed)
    sample = pts[rng.choice(len(pts), max_points, replace=False)] if len(pts) > max_points else pts
    need = max(3, int(np.ceil(min_fraction * len(sample))))
    cos_max = np.cos(np.radians(max_tilt_deg))
    # hypotheses from the lowest points along the hint: a floor seen only far off is a few percent of a room's
    # points, and three of them would seldom be drawn from all
    h = sample @ hint
    tri = np.concatenate([pool[rng.integers(0, len(pool), size=(iterations, 3))]
                          for pool in (sample[h <= np.quantile(h, q)] for q in LOW_QUANTILES)])
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norms = np.linalg.norm(normals, axis=1)
    ok = norms > 1e-12
    normals[ok] /= norms[ok, None]
    normals *= np.where(normals @ hint < 0, -1.0, 1.0)[:, None]
    ok &= normals @ hint >= cos_max
    best: tuple[int, int, F64, float] | None = None  # (points below, -support, normal, height)
    for n, p0 in zip(normals[ok], tri[ok, 0]):
        signed = sample @ n - p0 @ n
        support = int((np.abs(signed) <= inlier_m).sum())
        if support < need:
            continue
        key = (int((signed < -inlier_m).sum()), -support)
        if key[0] > max_below_fraction * len(sample):
            continue
        if best is None or key < best[:2]:
            best = (key[0], key[1], n, float(p0 @ n))
    if best is None:
        low = float(np.percentile(pts @ hint, 0.5))
        return FloorEstimate(hint, low, 0)
    up, height = best[2], best[3]
    for _ in range(2):  # least squares on the inliers of all points
        near = pts[np.abs(pts @ up - height) <= inlier_m]
        centre = near.mean(axis=0)
        normal = np.linalg.svd(near - centre, full_matrices=False)[2][2]
        up = normal if normal @ hint >= 0 else -normal
        height = float(centre @ up)
    support = int((np.abs(pts @ up - height) <= inlier_m).sum())
    return FloorEstimate(up, height, support)
