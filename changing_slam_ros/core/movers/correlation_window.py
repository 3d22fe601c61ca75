"""The inputs and outputs of the point-correlation segmentation (Dai et al. 2021, Section 3.2).

`SegmentationConfig` (its thresholds and where it goes beyond the paper), `CorrelationWindow` (M map points
measured over K frames) and `SegmentationResult` (labels, optimised positions, the graph's edges). Both the
segmentation (`point_correlation`) and its eq. 5 solver (`correlation_optimiser`) use them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.errors import ConfigError

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
BoolArr = npt.NDArray[np.bool_]

STATIC_LABEL = 0
UNASSIGNED_LABEL = -1

OBSERVATION_MODELS = ("pixel_depth", "point_3d")
STATIC_VOLUMES = ("hull", "view_cone")


@dataclass(frozen=True)
class SegmentationConfig:
    """Parameters of the point-correlation segmentation (units in the names; chi2 values are whitened).

    - `observation_model`: "pixel_depth" is the paper's g(p) = [u, v, d] (pixels, pixels, metres);
      "point_3d" uses the back-projected point [x, y, z] in the camera frame (metres).
    - `sigma_px`: std of a keypoint's pixel position. `depth_sigma_coeff_per_m`: std of depth is
      coeff * d^2 (structured-light sensors; Khoshelham & Elberink 2012 give 1.425e-3 / m), never
      below `depth_sigma_min_m`. The measurement z_ijk has the sum of both points' covariances.
    - `huber_delta`: Huber threshold on the whitened residual norm (sqrt of chi2(3, 0.95) = 2.796).
    - `outlier_chi2`: a measurement whose whitened squared error exceeds this is an outlier
      (chi2(3 dof, 95 %) = 7.815, ORB-SLAM's value for RGB-D).
    - `rounds`, `iterations_per_round`: optimise, flag outliers, re-optimise without them.
    - `cg_rtol`: relative residual at which each Gauss-Newton step's conjugate-gradient solve stops. The
      step only needs to be good enough for the next linearisation: 1e-3 gave the same labels as 1e-5 in
      the unit and simulator tests at about half the iterations.
    - `max_points`: bound on the points entering the graph (0 = no bound). Above it, points are kept on
      a uniform stride of the window's order (the caller's keypoint order, which is spread over the
      image); the others are labelled afterwards from their nearest graph point (`label_rest_radius_m`).
    - `label_rest_radius_m`: a point left out by `max_points` takes the label of its nearest segmented
      point (3D, median world position) when that lies within this distance, else stays unassigned.
    - `anchor_weight`: weight of a quadratic anchor of every point on its measured world position (median
      over frames), relative to the information of its own RGB-D measurements (K_i / variance). Eq. 5 only
      sees differences: a global translation of all points leaves it unchanged (exactly for "point_3d",
      nearly for "pixel_depth"), and so does shifting a whole moving group anywhere along its path, where
      the Huber cost is flat. Inside local BA, where the paper runs the segmentation, every point is also
      held by its absolute measurements (eq. 9); the anchor stands for those terms. It fixes the gauge
      and keeps a moving group midway along its path, where the all-outliers rule can see it. At 1.0 it
      holds a point whose median is corrupted by one bad measurement too firmly for the Huber-weighted
      edges to pull it back; at 0.01 the flat Huber directions drift; 0.1 works on both.
    - `inconsistent_inlier_fraction`: an edge is removed when at most this fraction of its measurements
      are inliers. 0.0 is the paper's rule (removed only when every measurement is an outlier).
    - `min_common_frames`: edges whose points are seen together in fewer frames carry no correlation
      evidence and are left out of the graph.
    - `min_target_points`: smaller non-static components are left unassigned (label -1), not targets.
    - `min_supporting_triangles`: our addition to the paper. One surviving edge is enough to join a
      moving object to the static scene in the graph search, so an edge is kept only when it is a side
      of at least this many Delaunay triangles whose three sides are all consistent (rigid triangles).
      0 gives the paper's plain rule.
    - `outlier_dof_correction`: our addition, off by default (the paper's test). A measurement's residual
      at the optimum is smaller than its noise because the points were fitted to it: for an edge measured
      in n frames (and points held by that edge alone) its covariance is (n - 1) / n of the measurement's.
      On, chi2 is scaled by n / (n - 1) before the `outlier_chi2` test. It matters for n = 2 (x2): a
      point seen in two keyframes of the window then breaks its edges when its two measurements differ by
      2.8 (not 4) standard deviations of their difference (a box pushed 3 cm/s toward the camera moves 3 cm
      in depth between keyframes 1 s apart: about 3 such deviations at 1.8 m).
    - `static_volume`: how "the component with the largest volume" is measured. "hull" (the paper): the
      convex hull of the component's points. A flat background (a wall) has almost no hull volume, so a
      box in front of it can win; "view_cone" adds the window's camera centres to each hull, i.e. the
      volume of the viewing cone the component fills, which favours what is far and wide.
    - `noise_from_edges` ("edge_test" only): the depth model above is a Kinect's; a noisier sensor (a RealSense
      has two to three times its depth noise) makes static edges fail the test. On, when the median whitened
      error of a frame's edges exceeds the median of chi2(3) (2.366), every covariance is scaled up by their
      ratio: most edges join static points (a mover breaks only the edges that cross its outline), so the
      median measures the sensor's noise, not the movers'. Never scaled down: the model stays the floor. Off
      by default: on the randomised dynamic family it raised the class-agnostic precision of moving keypoints
      (evaluation seeds 0.89 -> 0.93) and cut lost frames (107 -> 75) but not the ATE (median 3.22 -> 3.58 cm;
      docs/results.md).
    """

    observation_model: str = "pixel_depth"
    sigma_px: float = 1.0
    depth_sigma_coeff_per_m: float = 1.425e-3
    depth_sigma_min_m: float = 0.002
    huber_delta: float = 2.796
    outlier_chi2: float = 7.815
    rounds: int = 2
    iterations_per_round: int = 3
    cg_rtol: float = 1e-3
    max_points: int = 0
    label_rest_radius_m: float = 0.1
    anchor_weight: float = 0.1
    inconsistent_inlier_fraction: float = 0.0
    min_common_frames: int = 2
    min_target_points: int = 5
    min_supporting_triangles: int = 2
    outlier_dof_correction: bool = False
    static_volume: str = "hull"
    noise_from_edges: bool = False

    def __post_init__(self) -> None:
        if self.observation_model not in OBSERVATION_MODELS:
            raise ConfigError(
                f"segmentation.observation_model: expected one of {OBSERVATION_MODELS}, "
                f"got {self.observation_model!r}"
            )
        if self.static_volume not in STATIC_VOLUMES:
            raise ConfigError(
                f"segmentation.static_volume: expected one of {STATIC_VOLUMES}, got {self.static_volume!r}"
            )
        positive = ("sigma_px", "depth_sigma_min_m", "huber_delta", "outlier_chi2", "anchor_weight")
        for name in positive:
            if not getattr(self, name) > 0.0:
                raise ConfigError(f"segmentation.{name}: expected > 0, got {getattr(self, name)!r}")
        if not 0.0 <= self.inconsistent_inlier_fraction < 1.0:
            raise ConfigError(
                "segmentation.inconsistent_inlier_fraction: expected 0 <= f < 1, "
                f"got {self.inconsistent_inlier_fraction!r}"
            )
        if not 0.0 < self.cg_rtol < 1.0 or self.max_points < 0:
            raise ConfigError(
                f"segmentation: cg_rtol must be in (0, 1) and max_points >= 0, got {self.cg_rtol!r}, {self.max_points!r}"
            )
        if self.rounds < 1 or self.iterations_per_round < 1 or self.min_common_frames < 2:
            raise ConfigError(
                "segmentation: rounds and iterations_per_round must be >= 1, min_common_frames >= 2"
            )

    @classmethod
    def two_frame(cls) -> "SegmentationConfig":
        """Tracking mode (fast movers): the paper's rule, an edge goes when both measurements are outliers.

        With two frames and points initialised at the mean of their two world-frame measurements, an edge
        between a static and a moving point has error d/2 in each frame (d: the displacement), so both
        become outliers once d exceeds about twice the threshold. One outlier round: with two frames a
        second round (re-optimising without the outliers) changed no label in our tests and doubles the cost.
        """
        return cls(inconsistent_inlier_fraction=0.0, rounds=1)

    @classmethod
    def multi_frame(cls) -> "SegmentationConfig":
        """Local-mapping mode (slow movers over a window of K keyframes).

        For a steadily moving object the Huber optimum of the static-to-object offset sits near the middle
        of its path, so the middle frames of a crossing edge stay inliers and the paper's literal rule
        would keep it. We remove an edge when at most half its measurements are inliers; a static point
        with one bad measurement in K >= 3 frames still keeps its edges.
        """
        return cls(inconsistent_inlier_fraction=0.5)


@dataclass(frozen=True)
class CorrelationWindow:
    """Measurements of M map points over K frames, the input of the segmentation.

    - `point_ids`: (M,) int64 map point ids.
    - `points_cam`: (K, M, 3) float64, metres, each point in the optical frame of camera k as measured
      from depth (back-projected keypoint); NaN where the point is not observed in frame k.
    - `T_world_cam`: (K, 4, 4) camera-to-world poses of the K frames (from tracking / local BA).
    - `camera`: intrinsics, for the pixel+depth observation model and the pixel noise.
    """

    point_ids: I64
    points_cam: F64
    T_world_cam: F64
    camera: CameraIntrinsics

    def __post_init__(self) -> None:
        k, m = self.points_cam.shape[:2]
        if self.points_cam.shape != (k, m, 3) or self.T_world_cam.shape != (k, 4, 4):
            raise ValueError(
                f"CorrelationWindow: points_cam must be (K, M, 3) and T_world_cam (K, 4, 4), got "
                f"{self.points_cam.shape} and {self.T_world_cam.shape}"
            )
        if self.point_ids.shape != (m,):
            raise ValueError(f"CorrelationWindow: point_ids must be ({m},), got {self.point_ids.shape}")
        if k < 2:
            raise ValueError(f"CorrelationWindow: needs at least two frames, got {k}")

    @classmethod
    def from_pixels(
        cls,
        point_ids: I64,
        pixels: F64,
        depths_m: F64,
        T_world_cam: F64,
        camera: CameraIntrinsics,
    ) -> "CorrelationWindow":
        """Build from undistorted keypoints (K, M, 2) and their depths (K, M); depth <= 0 or NaN: unseen."""
        k, m = depths_m.shape
        valid = np.isfinite(depths_m) & (depths_m > 0) & np.all(np.isfinite(pixels), axis=2)
        pts = camera.backproject(pixels.reshape(-1, 2), np.where(valid, depths_m, 1.0).reshape(-1))
        pts = pts.reshape(k, m, 3)
        pts[~valid] = np.nan
        return cls(np.asarray(point_ids, dtype=np.int64), pts, np.asarray(T_world_cam, float), camera)

    @property
    def observed(self) -> BoolArr:
        """(K, M) True where point m is measured in frame k (finite, positive depth)."""
        z = self.points_cam[..., 2]
        seen: BoolArr = np.isfinite(z) & (z > 0) & np.all(np.isfinite(self.points_cam), axis=2)
        return seen

    def points_world(self) -> F64:
        """(K, M, 3) measured points in the world frame, NaN where unobserved."""
        rot = self.T_world_cam[:, :3, :3]
        trans = self.T_world_cam[:, :3, 3]
        world: F64 = np.einsum("kab,kmb->kma", rot, self.points_cam) + trans[:, None, :]
        return world


@dataclass(frozen=True)
class SegmentationResult:
    """Outcome of one segmentation.

    - `point_ids`: (M,) as in the input window.
    - `labels`: (M,) int: 0 static scene, 1..G object target g (largest first), -1 unassigned (seen in
      fewer than two frames, or in a component too small to be a target).
    - `positions_world`: (M, 3) metres, optimised positions (eq. 5), NaN for points not optimised.
    - `edges`: (E, 2) indices into the M points, the Delaunay graph of the points seen at least twice.
    - `edge_consistent`: (E,) False for removed edges (inconsistent, never co-observed often enough, or
      without triangle support).
    - `inlier_fraction`: (E,) fraction of an edge's measurements that are inliers.
    - `component_volumes_m3`: convex-hull volume of the static scene followed by targets 1..G (points
      only, whichever `static_volume` chose the static scene).
    """

    point_ids: I64
    labels: I64
    positions_world: F64
    edges: I64
    edge_consistent: BoolArr
    inlier_fraction: F64
    component_volumes_m3: tuple[float, ...] = field(default=())

    @property
    def num_targets(self) -> int:
        return int(self.labels.max(initial=0))

    @property
    def static_mask(self) -> BoolArr:
        return np.asarray(self.labels == STATIC_LABEL, dtype=np.bool_)

    @property
    def dynamic_mask(self) -> BoolArr:
        """(M,) True for points of any object target."""
        return self.labels > STATIC_LABEL

    def target_indices(self) -> list[I64]:
        """Indices (into the M points) of each object target 1..G."""
        return [np.flatnonzero(self.labels == g) for g in range(1, self.num_targets + 1)]
