"""Object tracking with one extended Kalman filter per MapObject (Changing-SLAM §4.4, eqs. 1-13).

State (eq. 1): x = [x y z vx vy vz] of the object's centroid in the world frame, metres and m/s.
Prediction (eqs. 2-4): constant velocity, F = [[I, dt I], [0, I]], Q from the random-acceleration model
(eqs. 5-6) Q = G diag(sigma_a^2) G^T with G = [dt^2/2 I, dt I]^T and sigma_a per class (person 0.5,
chair 0.02, others 0.01 m/s^2). P0 = I.
Measurement (eq. 8): the centroid in the camera frame, from the object's keypoints: their mean pixel
back-projected at their (median) depth. Model (eq. 9): h(x) = R_cw p + t_cw, the world -> camera transform
of the position (T_cam_world = inverse of the camera pose); its Jacobian is H = [R_cw 0].
The filter itself is filterpy's `ExtendedKalmanFilter` (eqs. 7, 10-13). F and Q depend on the frame gap only, so
each filter keeps them per gap (a 30 Hz stream alternates two, 33.333 and 33.334 ms) instead of building them
on every prediction: the same matrices, so the same results bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
from filterpy.kalman import ExtendedKalmanFilter

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.dynamic.detector import CHAIR_CLASS_ID, PERSON_CLASS_ID
from changing_slam_ros.core.dynamic.keypoint_classification import median_1d
from changing_slam_ros.core.geometry.se3 import invert
from changing_slam_ros.errors import ConfigError

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class ObjectEkfConfig:
    """`object_ekf` config section.

    - `sigma_a_mps2` / `default_sigma_a_mps2`: random-acceleration standard deviation per class (paper:
      person 0.5, chair 0.02, others 0.01), the same on x, y and z.
    - `measurement_sigma_m`: standard deviation of the measured centroid on the camera's x, y, z (R's
      diagonal; the paper does not give it). The centroid of a changing keypoint set wanders by a few cm.
    - `initial_position_sigma_m`, `initial_velocity_sigma_mps`: P0's diagonal (paper: P0 = I).
    - `max_dt_s`: a gap longer than this restarts the filter from the next measurement.
    """

    sigma_a_mps2: dict[int, float] = field(default_factory=lambda: {PERSON_CLASS_ID: 0.5, CHAIR_CLASS_ID: 0.02})
    default_sigma_a_mps2: float = 0.01
    measurement_sigma_m: tuple[float, float, float] = (0.03, 0.03, 0.03)
    initial_position_sigma_m: float = 1.0
    initial_velocity_sigma_mps: float = 1.0
    max_dt_s: float = 2.0

    def __post_init__(self) -> None:
        if len(self.measurement_sigma_m) != 3 or min(self.measurement_sigma_m) <= 0.0:
            raise ConfigError(f"object_ekf.measurement_sigma_m: expected 3 positive values, got {self.measurement_sigma_m}")
        if self.default_sigma_a_mps2 <= 0.0 or min(self.sigma_a_mps2.values(), default=1.0) <= 0.0:
            raise ConfigError("object_ekf.sigma_a_mps2: values must be positive")

    def sigma_a(self, class_id: int) -> float:
        return self.sigma_a_mps2.get(class_id, self.default_sigma_a_mps2)


def transition_matrix(dt_s: float) -> F64:
    """F (6, 6) of eq. 3."""
    f = np.eye(6)
    f[0:3, 3:6] = dt_s * np.eye(3)
    return f


def process_noise(dt_s: float, sigma_a_mps2: float) -> F64:
    """Q (6, 6) of the random-acceleration model, eqs. 5-6."""
    g = np.vstack([0.5 * dt_s**2 * np.eye(3), dt_s * np.eye(3)])  # (6, 3)
    return g @ (sigma_a_mps2**2 * np.eye(3)) @ g.T


def measurement_model(x: F64, T_cam_world: F64) -> F64:
    """h(x) of eq. 9: the state's position (x (6,) or (6, 1)) in the camera frame, (3, 1)."""
    p = np.asarray(x, dtype=np.float64).reshape(6)[:3]
    return (T_cam_world[:3, :3] @ p + T_cam_world[:3, 3]).reshape(3, 1)


def measurement_jacobian(x: F64, T_cam_world: F64) -> F64:
    """H (3, 6) = d h / d x = [R_cw 0]."""
    h = np.zeros((3, 6))
    h[:, :3] = T_cam_world[:3, :3]
    return h


def centroid_measurement(
    keypoints_px: npt.NDArray[np.floating], depths_m: npt.NDArray[np.floating], camera: CameraIntrinsics
) -> F64 | None:
    """Eq. 8: the object's centroid (3,) in the camera frame from its keypoints (K, 2) and depths (K,);
    keypoints without depth (0) are skipped, None when none has depth."""
    kps = np.asarray(keypoints_px, dtype=np.float64).reshape(-1, 2)
    d = np.asarray(depths_m, dtype=np.float64).reshape(-1)
    ok = d > 0.0
    if not ok.any():
        return None
    mu_x, mu_y = kps[ok].mean(axis=0)
    z = median_1d(d[ok])
    return np.array([(mu_x - camera.cx) * z / camera.fx, (mu_y - camera.cy) * z / camera.fy, z])


MODEL_CACHE_SIZE = 4  # (F, Q) pairs an ObjectEkf keeps, by frame gap; cleared when full


class ObjectEkf:
    """EKF of one MapObject's centroid, started from its first measurement."""

    def __init__(
        self,
        class_id: int,
        z_cam: F64,
        T_world_cam: F64,
        stamp_ns: int,
        config: ObjectEkfConfig | None = None,
    ) -> None:
        self.config = config or ObjectEkfConfig()
        self.class_id = class_id
        self.sigma_a_mps2 = self.config.sigma_a(class_id)
        self._ekf = ExtendedKalmanFilter(dim_x=6, dim_z=3)
        self._ekf.R = np.diag(np.square(self.config.measurement_sigma_m))
        self._models: dict[int, tuple[F64, F64]] = {}  # frame gap (ns) -> (F, Q) of eqs. 3 and 5-6
        self._start(z_cam, T_world_cam, stamp_ns)

    def _start(self, z_cam: F64, T_world_cam: F64, stamp_ns: int) -> None:
        p_world = T_world_cam[:3, :3] @ np.asarray(z_cam, dtype=np.float64).reshape(3) + T_world_cam[:3, 3]
        self._ekf.x = np.concatenate([p_world, np.zeros(3)]).reshape(6, 1)
        self._ekf.P = np.diag(
            [self.config.initial_position_sigma_m**2] * 3 + [self.config.initial_velocity_sigma_mps**2] * 3
        )
        self.stamp_ns = stamp_ns
        self.n_updates = 1

    def predict(self, stamp_ns: int) -> None:
        """Eqs. 2-4 up to `stamp_ns` (no-op for the same or an older stamp)."""
        gap_ns = stamp_ns - self.stamp_ns
        dt_s = gap_ns * 1e-9
        if dt_s <= 0.0:
            return
        model = self._models.get(gap_ns)
        if model is None:
            if len(self._models) >= MODEL_CACHE_SIZE:
                self._models.clear()
            model = self._models[gap_ns] = (transition_matrix(dt_s), process_noise(dt_s, self.sigma_a_mps2))
        self._ekf.F, self._ekf.Q = model  # filterpy's predict reads them, never writes them
        self._ekf.predict()
        self.stamp_ns = stamp_ns

    def update(self, z_cam: F64, T_world_cam: F64, stamp_ns: int) -> F64:
        """Predict to `stamp_ns`, then correct with the centroid `z_cam` (3,) measured from the camera at
        pose `T_world_cam` (4, 4); returns the innovation (3,) (eq. 7). A gap over `max_dt_s` restarts."""
        if (stamp_ns - self.stamp_ns) * 1e-9 > self.config.max_dt_s:
            self._start(z_cam, T_world_cam, stamp_ns)
            return np.zeros(3)
        self.predict(stamp_ns)
        T_cam_world = invert(np.asarray(T_world_cam, dtype=np.float64))
        z = np.asarray(z_cam, dtype=np.float64).reshape(3, 1)
        self._ekf.update(z, measurement_jacobian, measurement_model, args=(T_cam_world,), hx_args=(T_cam_world,))
        self.n_updates += 1
        return np.asarray(self._ekf.y, dtype=np.float64).reshape(3)

    @property
    def x(self) -> F64:
        """State (6,): position (m) then velocity (m/s), world frame."""
        return np.asarray(self._ekf.x, dtype=np.float64).reshape(6).copy()

    @property
    def P(self) -> F64:  # noqa: N802 - the paper's name
        """State covariance (6, 6)."""
        return np.asarray(self._ekf.P, dtype=np.float64).copy()

    @property
    def position_world(self) -> F64:
        return self.x[:3]

    @property
    def velocity_world(self) -> F64:
        return self.x[3:]

    @property
    def speed_mps(self) -> float:
        return float(np.linalg.norm(self._ekf.x.reshape(6)[3:]))  # a view: no copy of the state

    @property
    def velocity_sigma_mps(self) -> float:
        """Largest standard deviation of the velocity estimate (sqrt of P_vv's largest eigenvalue)."""
        return float(np.sqrt(np.linalg.eigvalsh(self._ekf.P[3:, 3:])[-1]))
