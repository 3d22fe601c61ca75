"""Object-level bundle adjustment with gtsam (Dai et al. 2021, eqs. 7, 10 and 11).

The paper's camera-frame prediction of point n of object g in frame k is ``T_k^c (T_k^g)^-1 T_0^g p_n^g``
(T^c, T^g world-to-camera and world-to-object). We store the object's points in its own frame, p_obj =
T_0^g p_n^g, and its poses as T_world_obj_k = (T_k^g)^-1: the prediction is ``T_cam_world_k T_world_obj_k p_obj``.

The camera poses come from camera tracking and are held fixed, so we optimise, for each frame, the
camera pose *seen from the object*, X(k) = T_obj_cam_k = T_world_obj_k^-1 T_world_cam_k. This is a
one-to-one change of variables (T_world_obj_k = T_world_cam_k X(k)^-1) that turns object BA into
ordinary static BA in the object frame, so gtsam's own factors apply: variables X(k) `Pose3` (camera in
the object frame) and L(n) `Point3` (object point, object frame, m), one bearing-range factor per RGB-D
measurement (`_Measurements`), outlier rounds as ORB-SLAM's (`_optimise_rounds`). Motion-only BA (eq. 7):
one X, the shape held by tight point priors; full object BA (eq. 11, `full_object_ba`): all keyposes and
points, a prior on the reference keypose X(0) fixing the gauge.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
import numpy.typing as npt
from gtsam.symbol_shorthand import L, X

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.geometry.se3 import invert

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
BoolArr = npt.NDArray[np.bool_]

CHI2_3DOF_95 = 7.815


@dataclass(frozen=True)
class ObjectBAConfig:
    """Noise and solver settings of object BA.

    - `sigma_px`: keypoint std in pixels (bearing std = sigma_px / fx radians).
    - `depth_sigma_coeff_per_m`, `depth_sigma_min_m`: depth std = max(coeff * d^2, min), metres.
    - `huber_k`: Huber threshold on the whitened 3-vector error.
    - `outlier_chi2`: chi2 above which a measurement is dropped between rounds.
    - `rounds`, `max_iterations`: outlier rounds and Levenberg-Marquardt iterations per round.
    - `gauge_sigma_rad`, `gauge_sigma_m`: std of the gauge prior on the reference keypose and of the
      priors that hold the points in motion-only BA (tiny: they are constraints, not information).
    """

    sigma_px: float = 1.0
    depth_sigma_coeff_per_m: float = 1.425e-3
    depth_sigma_min_m: float = 0.002
    huber_k: float = float(np.sqrt(CHI2_3DOF_95))
    outlier_chi2: float = CHI2_3DOF_95
    rounds: int = 2
    max_iterations: int = 15
    gauge_sigma_rad: float = 1e-6
    gauge_sigma_m: float = 1e-6


@dataclass(frozen=True)
class ObjectObservations:
    """The RGB-D measurements of one object's points in one frame.

    - `stamp_ns`: frame stamp.
    - `T_world_cam`: (4, 4) camera-to-world pose of the frame (fixed in object BA).
    - `point_index`: (N,) int64 indices into the object's points.
    - `points_cam`: (N, 3) metres, back-projected keypoints (u, v, depth) in the camera optical frame.
    """

    stamp_ns: int
    T_world_cam: F64
    point_index: I64
    points_cam: F64

    def __post_init__(self) -> None:
        n = len(self.point_index)
        if self.points_cam.shape != (n, 3) or self.T_world_cam.shape != (4, 4):
            raise ValueError(
                f"ObjectObservations: point_index ({n},) needs points_cam ({n}, 3) and T_world_cam (4, 4); "
                f"got {self.points_cam.shape} and {self.T_world_cam.shape}"
            )


@dataclass(frozen=True)
class MotionOnlyResult:
    """Eq. 7: `T_world_obj` (4, 4), `inliers` (N,) per observation, `rms_chi2` of the inliers."""

    T_world_obj: F64
    inliers: BoolArr
    rms_chi2: float


@dataclass(frozen=True)
class FullObjectBAResult:
    """Eq. 11: `points_obj` (P, 3), `T_world_obj` (K, 4, 4) per keypose, `inliers` per keypose (N_k,)."""

    points_obj: F64
    T_world_obj: F64
    inliers: list[BoolArr]


def _measurement_noise(points_cam: F64, camera: CameraIntrinsics, cfg: ObjectBAConfig) -> tuple[F64, F64]:
    """Bearing std (N,) radians and range std (N,) metres of back-projected RGB-D measurements (N, 3)."""
    depth = points_cam[:, 2]
    ray_norm = np.linalg.norm(points_cam, axis=1) / depth
    sigma_depth = np.maximum(cfg.depth_sigma_coeff_per_m * depth**2, cfg.depth_sigma_min_m)
    sigma_bearing = np.full(len(depth), cfg.sigma_px / min(camera.fx, camera.fy))
    return sigma_bearing, sigma_depth * ray_norm


class _Measurements:
    """Bearing-range factors of one frame, with their sigmas kept for the chi2 test.

    One `BearingRangeFactor3D` per RGB-D measurement: the keypoint's bearing (from u, v) and its range (from the
    depth), i.e. the 3D observation model the paper uses for object BA. Noise order (bearing tangent 1, bearing
    tangent 2, range): sigma_px / f radians twice, then the depth noise (coeff * d^2, metres) scaled to range.
    Huber kernel on the whitened error, k = sqrt(chi2(3, 0.95)).
    """

    def __init__(self, pose_key: int, obs: ObjectObservations, camera: CameraIntrinsics, cfg: ObjectBAConfig):
        self.pose_key = pose_key
        self.obs = obs
        self.sigma_b, self.sigma_r = _measurement_noise(obs.points_cam, camera, cfg)
        self.ranges = np.linalg.norm(obs.points_cam, axis=1)
        huber = gtsam.noiseModel.mEstimator.Huber.Create(cfg.huber_k)
        self.factors = [
            gtsam.BearingRangeFactor3D(
                pose_key,
                L(int(n)),
                gtsam.Unit3(obs.points_cam[q]),
                float(self.ranges[q]),
                gtsam.noiseModel.Robust.Create(
                    huber,
                    gtsam.noiseModel.Diagonal.Sigmas(
                        np.array([self.sigma_b[q], self.sigma_b[q], self.sigma_r[q]])
                    ),
                ),
            )
            for q, n in enumerate(obs.point_index)
        ]

    def chi2(self, values: gtsam.Values, points: "_PointTable | None" = None) -> F64:
        """Whitened squared error (N,) of every measurement at `values` (no robust kernel).

        Vectorised: the bearing error is the angle between predicted and measured rays, which is the norm
        of gtsam's Unit3 tangent error to first order. `points`: the values' points, read once for all frames.
        """
        T_cam_obj = invert(values.atPose3(self.pose_key).matrix())
        table = points or _PointTable.of(values)
        pts = table.points[np.searchsorted(table.index, self.obs.point_index)].reshape(-1, 3)
        pred = pts @ T_cam_obj[:3, :3].T + T_cam_obj[:3, 3]
        pred_range = np.linalg.norm(pred, axis=1)
        cos = np.sum(pred * self.obs.points_cam, axis=1) / np.maximum(pred_range * self.ranges, 1e-12)
        angle = np.arccos(np.clip(cos, -1.0, 1.0))
        return np.asarray((angle / self.sigma_b) ** 2 + ((pred_range - self.ranges) / self.sigma_r) ** 2)


@dataclass(frozen=True)
class _PointTable:
    """The Point3 values L(n) of a `gtsam.Values`: point indices n (ascending) and positions (P, 3)."""

    index: I64
    points: F64

    @classmethod
    def of(cls, values: gtsam.Values) -> "_PointTable":
        keys = [gtsam.Symbol(k) for k in values.keys()]
        index = np.array([k.index() for k in keys if chr(k.chr()) == "l"], dtype=np.int64)
        # extractPoint3 returns the points in key order, which is ascending n for the keys L(n).
        return cls(index, np.asarray(gtsam.utilities.extractPoint3(values), dtype=np.float64).reshape(-1, 3))


def _optimise_rounds(
    base: gtsam.NonlinearFactorGraph, frames: list[_Measurements], initial: gtsam.Values, cfg: ObjectBAConfig
) -> tuple[gtsam.Values, list[BoolArr]]:
    """Optimise, drop measurements above the chi2 threshold (chi2(3, 0.95)), repeat (ORB-SLAM's outlier rounds);
    returns values and per-frame inliers."""
    inliers = [np.ones(len(f.factors), dtype=bool) for f in frames]
    values = initial
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(cfg.max_iterations)
    for _ in range(cfg.rounds):
        graph = gtsam.NonlinearFactorGraph(base)
        for frame, keep in zip(frames, inliers):
            for factor, ok in zip(frame.factors, keep):
                if ok:
                    graph.add(factor)
        values = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
        table = _PointTable.of(values)
        inliers = [f.chi2(values, table) <= cfg.outlier_chi2 for f in frames]
    return values, inliers


def _pose_obj_cam(T_world_obj: F64, T_world_cam: F64) -> gtsam.Pose3:
    return gtsam.Pose3(invert(T_world_obj) @ T_world_cam)


def _world_obj(x_obj_cam: gtsam.Pose3, T_world_cam: F64) -> F64:
    return np.asarray(T_world_cam @ invert(x_obj_cam.matrix()), dtype=np.float64)


def motion_only_object_ba(
    points_obj: F64,
    obs: ObjectObservations,
    T_world_obj_init: F64,
    camera: CameraIntrinsics,
    cfg: ObjectBAConfig,
) -> MotionOnlyResult:
    """Eq. 7: the object's pose in one frame from its known points (P, 3) and this frame's measurements."""
    # 1. The shape is known: every observed point enters as a variable held by a tight prior
    #    (sigma gauge_sigma_m, metres on x y z), which makes it a constant for the solver.
    base = gtsam.NonlinearFactorGraph()
    initial = gtsam.Values()
    point_noise = gtsam.noiseModel.Isotropic.Sigma(3, cfg.gauge_sigma_m)
    for n in np.unique(obs.point_index):
        base.add(gtsam.PriorFactorPoint3(L(int(n)), points_obj[n], point_noise))
        initial.insert(L(int(n)), points_obj[n])
    # 2. The single unknown: the camera pose in the object frame, from the initial object pose.
    initial.insert(X(0), _pose_obj_cam(T_world_obj_init, obs.T_world_cam))
    # 3. One bearing-range factor per measurement, Huber kernel, outlier rounds.
    frame = _Measurements(X(0), obs, camera, cfg)
    values, inliers = _optimise_rounds(base, [frame], initial, cfg)
    chi2 = frame.chi2(values)[inliers[0]]
    return MotionOnlyResult(
        T_world_obj=_world_obj(values.atPose3(X(0)), obs.T_world_cam),
        inliers=inliers[0],
        rms_chi2=float(np.sqrt(np.mean(chi2))) if len(chi2) else float("nan"),
    )


def full_object_ba(
    points_obj_init: F64,
    keyposes: list[ObjectObservations],
    T_world_obj_init: F64,
    camera: CameraIntrinsics,
    cfg: ObjectBAConfig,
) -> FullObjectBAResult:
    """Eq. 11: refine the object's points (P, 3) and its K keyposes (K, 4, 4) together.

    `keyposes[0]` is the reference keypose (the paper's T_0^g): its object pose is held by the gauge prior.
    Points observed in no keypose keep their initial position.
    """
    if len(keyposes) != len(T_world_obj_init):
        raise ValueError(f"full_object_ba: {len(keyposes)} keyposes but {len(T_world_obj_init)} initial poses")
    base = gtsam.NonlinearFactorGraph()
    initial = gtsam.Values()
    # 1. Keypose variables X(k): the camera seen from the object, from the initial object poses.
    for k, obs in enumerate(keyposes):
        initial.insert(X(k), _pose_obj_cam(T_world_obj_init[k], obs.T_world_cam))
    # 2. Gauge: eq. 11 is unchanged when every object pose is moved by the same rigid G and every point
    #    by G^-1 (the object frame is arbitrary). The paper holds the reference pose T_0^g; we do the
    #    same with a tight prior on X(0). Sigmas: rotation first (rad, rad, rad), then translation (m).
    #    Depth fixes the scale, so there is no scale gauge.
    gauge = gtsam.noiseModel.Diagonal.Sigmas(np.array([cfg.gauge_sigma_rad] * 3 + [cfg.gauge_sigma_m] * 3))
    base.add(gtsam.PriorFactorPose3(X(0), initial.atPose3(X(0)), gauge))
    # 3. Point variables L(n), object frame, metres.
    seen = np.unique(np.concatenate([obs.point_index for obs in keyposes]))
    for n in seen:
        initial.insert(L(int(n)), points_obj_init[n])
    # 4. Bearing-range factors of every keypose, Huber kernel, outlier rounds.
    frames = [_Measurements(X(k), obs, camera, cfg) for k, obs in enumerate(keyposes)]
    values, inliers = _optimise_rounds(base, frames, initial, cfg)
    points = np.array(points_obj_init, dtype=np.float64, copy=True)
    for n in seen:
        points[n] = values.atPoint3(L(int(n)))
    poses = np.stack([_world_obj(values.atPose3(X(k)), obs.T_world_cam) for k, obs in enumerate(keyposes)])
    return FullObjectBAResult(points_obj=points, T_world_obj=poses, inliers=inliers)


def align_points(points_obj: F64, points_world: F64) -> F64:
    """Closed-form rigid T_world_obj (4, 4) mapping points_obj (N, 3) onto points_world (N, 3) (Kabsch).

    The initial guess of eq. 7 before the robust refinement; needs N >= 3 non-collinear points.
    """
    mu_o = points_obj.mean(axis=0)
    mu_w = points_world.mean(axis=0)
    cov = (points_world - mu_w).T @ (points_obj - mu_o)
    u, _, vt = np.linalg.svd(cov)
    d = np.sign(np.linalg.det(u @ vt))
    rot = u @ np.diag([1.0, 1.0, d]) @ vt
    out = np.eye(4)
    out[:3, :3] = rot
    out[:3, 3] = mu_w - rot @ mu_o
    return out
