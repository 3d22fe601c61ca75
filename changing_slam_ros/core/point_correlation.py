"""Point-correlation segmentation of map points into the static scene and moving object targets.

Dai et al. 2021, Section 3.2 (after Dai et al. 2020, "RGB-D SLAM in dynamic environments using point
correlations"):

1. Build a graph of adjacent points with a 3D Delaunay tetrahedralisation of the points (eq. 2: an edge
   l_ij joins points i and j).
2. Remove inconsistent edges. The point positions P (world frame) are estimated from the *relative*
   measurements of every edge in every frame (eqs. 3-5)::

       z_ijk = y_ik - y_jk                                          (eq. 4)
       min_P  sum_ijk || z_ijk - [g(T_k p_i) - g(T_k p_j)] ||_huber  (eq. 5)

   with y = g(p_cam) = [u, v, d] the RGB-D observation of eq. 1 and T_k the (known) world-to-camera
   pose of frame k. Measurements with a large error are flagged as outliers and left out of the next
   optimisation round (as ORB-SLAM does); an edge whose every measurement is an outlier is inconsistent
   and removed.
3. Connected components of the remaining graph; the component of largest convex-hull volume is the static
   scene, every other component with enough points is an object target.

Two modes: two frames (tracking, fast movers) and a window of K > 2 frames (local mapping, slow movers);
see `SegmentationConfig.two_frame` and `SegmentationConfig.multi_frame` for why they differ in one
threshold. Where we go beyond the paper, `SegmentationConfig` says so and how to switch it off: a weak
anchor of each point on its measured position (eq. 5 alone has flat directions), the triangle support
of kept edges (one surviving edge would join an object to the static scene), and an optional
viewing-cone volume for picking the static component.

Everything is vectorised over measurements; each Gauss-Newton step solves one block-sparse (3M x 3M)
system by preconditioned conjugate gradients. Camera pose errors do not change the result: an error in
one frame's pose moves all of that frame's points by the same rigid transform, like a common motion.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import numpy.typing as npt
import scipy.sparse as sp  # type: ignore[import-untyped]
from scipy.sparse.csgraph import connected_components  # type: ignore[import-untyped]
from scipy.sparse.linalg import cg  # type: ignore[import-untyped]
from scipy.spatial import ConvexHull, Delaunay, QhullError  # type: ignore[import-untyped]

from changing_slam_ros.core.camera import CameraIntrinsics
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


def hull_volume_m3(points: F64) -> float:
    """Volume of the convex hull of points (N, 3); 0.0 when fewer than 4 or degenerate (coplanar)."""
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) < 4:
        return 0.0
    try:
        return float(ConvexHull(pts).volume)
    except QhullError:
        return 0.0


@dataclass(frozen=True)
class DelaunayGraph:
    """Adjacency of points from a Delaunay triangulation.

    - `edges`: (E, 2) int64 point indices, i < j, unique.
    - `triangles`: (T, 3) int64 indices into `edges` of the three sides of each Delaunay triangle
      (faces of the tetrahedra); empty when the points are collinear.
    """

    edges: I64
    triangles: I64


def delaunay_graph(points: F64) -> DelaunayGraph:
    """Graph of the 3D Delaunay tetrahedralisation of points (N, 3).

    Falls back to a 2D triangulation in the two principal axes for (nearly) coplanar points and to a
    chain along the first axis for collinear ones.
    """
    n = len(points)
    no_triangles = np.empty((0, 3), dtype=np.int64)
    if n < 2:
        return DelaunayGraph(np.empty((0, 2), dtype=np.int64), no_triangles)
    simplices: npt.NDArray[np.int32] | None = None
    if n >= 5:
        try:
            simplices = Delaunay(points, qhull_options="Qbb Qc Qz Q12").simplices
        except QhullError:
            simplices = None
    if simplices is None:
        centred = points - points.mean(axis=0)
        _, _, vt = np.linalg.svd(centred, full_matrices=False)
        try:
            simplices = Delaunay(centred @ vt[:2].T).simplices
        except (QhullError, ValueError):
            order = np.argsort(centred @ vt[0])
            edges = np.sort(np.stack([order[:-1], order[1:]], axis=1), axis=1).astype(np.int64)
            return DelaunayGraph(edges, no_triangles)
    nv = simplices.shape[1]
    # Every triple of a simplex's vertices is a triangle; sides are coded i * n + j with i < j.
    faces = ([0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3])[: 1 if nv == 3 else 4]
    tri = _sort_rows3(np.concatenate([simplices[:, f] for f in faces]).astype(np.int64))
    # Unique triangles through one integer key per vertex triple (faces are shared by two tetrahedra).
    tri_keys = np.unique((tri[:, 0] * n + tri[:, 1]) * n + tri[:, 2])
    tri = np.stack([tri_keys // (n * n), (tri_keys // n) % n, tri_keys % n], axis=1)
    sides = np.stack([tri[:, 0] * n + tri[:, 1], tri[:, 0] * n + tri[:, 2], tri[:, 1] * n + tri[:, 2]], axis=1)
    codes, inverse = np.unique(sides, return_inverse=True)
    edges = np.stack([codes // n, codes % n], axis=1).astype(np.int64)
    return DelaunayGraph(edges, inverse.reshape(-1, 3).astype(np.int64))


def _sort_rows3(t: I64) -> I64:
    """Each row of (T, 3) ascending: a three-element sorting network on columns (np.sort per row is slow)."""
    a, b, c = t[:, 0], t[:, 1], t[:, 2]
    a, b = np.minimum(a, b), np.maximum(a, b)
    b, c = np.minimum(b, c), np.maximum(b, c)
    a, b = np.minimum(a, b), np.maximum(a, b)
    return np.stack([a, b, c], axis=1)


def triangle_supported(graph: DelaunayGraph, consistent: BoolArr, min_triangles: int) -> BoolArr:
    """(E,) True for consistent edges that are a side of `min_triangles` triangles with three consistent sides.

    A rigid body's interior edges lie in many such triangles; an edge that bridges two differently moving
    bodies but happens to pass the test (e.g. a point whose own displacement is below the noise) does not,
    because the third vertex of each of its triangles lies on one body only.
    """
    if len(graph.triangles) == 0:
        return consistent.copy()
    good = np.all(consistent[graph.triangles], axis=1)
    support = np.bincount(graph.triangles[good].ravel(), minlength=len(graph.edges))
    return consistent & (support >= min_triangles)


def _observation(points_cam: F64, camera: CameraIntrinsics, model: str) -> F64:
    """The RGB-D observation g(p) (N, 3) of points (N, 3) in the camera frame: [u, v, d] or [x, y, z]."""
    if model == "point_3d":
        return points_cam.copy()
    x, y, z = points_cam[:, 0], points_cam[:, 1], points_cam[:, 2]
    return np.stack([camera.fx * x / z + camera.cx, camera.fy * y / z + camera.cy, z], axis=1)


def _observation_sigma(points_cam: F64, camera: CameraIntrinsics, cfg: SegmentationConfig) -> F64:
    """Per-component std (N, 3) of y = g(p) for measured points (N, 3), in the units of the model."""
    z = points_cam[:, 2]
    sigma_d = np.maximum(cfg.depth_sigma_coeff_per_m * z * z, cfg.depth_sigma_min_m)
    if cfg.observation_model == "point_3d":
        return np.stack([cfg.sigma_px * z / camera.fx, cfg.sigma_px * z / camera.fy, sigma_d], axis=1)
    return np.stack([np.full_like(z, cfg.sigma_px), np.full_like(z, cfg.sigma_px), sigma_d], axis=1)


@dataclass
class _Problem:
    """The measurements of eq. 4, flattened: one row per (edge, frame) with both points observed."""

    edge: I64  # (Q,) edge index
    i: I64  # (Q,) first point (index into the optimised points)
    j: I64  # (Q,) second point
    z_meas: F64  # (Q, 3) y_ik - y_jk
    whiten: F64  # (Q, 3) 1 / std of each component of z_ijk
    frame: I64  # (Q,) frame of the measurement
    R_cam_world: F64  # (K, 3, 3) world-to-camera rotation of each frame
    t_cam_world: F64  # (K, 3)


def _jacobian_world(points_cam: F64, r_cam_world: F64, camera: CameraIntrinsics, model: str) -> F64:
    """d g(R p + t) / d p (Q, 3, 3) = dg/dp_cam R for camera-frame points (Q, 3) and rotations (Q, 3, 3).

    Written row by row: the pixel rows of dg/dp_cam have two non-zeros each, the depth row is (0, 0, 1).
    """
    if model == "point_3d":
        return r_cam_world
    inv_z = 1.0 / points_cam[:, 2:3]
    r0, r1, r2 = r_cam_world[:, 0, :], r_cam_world[:, 1, :], r_cam_world[:, 2, :]
    row0 = camera.fx * inv_z * (r0 - points_cam[:, 0:1] * inv_z * r2)
    row1 = camera.fy * inv_z * (r1 - points_cam[:, 1:2] * inv_z * r2)
    return np.stack([row0, row1, r2], axis=1)


def _residuals(points_world: F64, prob: _Problem, camera: CameraIntrinsics, model: str) -> tuple[F64, F64, F64]:
    """Whitened residuals r (Q, 3) of eq. 5 and their Jacobians wrt p_i and p_j, each (Q, 3, 3)."""
    # Camera-frame point, observation and Jacobian once per (frame, point), then gathered per measurement:
    # a point takes part in about seven edges, so this is several times less work than per measurement.
    m = len(points_world)
    p_cam = (np.einsum("kab,mb->kma", prob.R_cam_world, points_world) + prob.t_cam_world[:, None, :]).reshape(-1, 3)
    with np.errstate(divide="ignore", invalid="ignore"):  # points behind a frame they are not measured in
        g = _observation(p_cam, camera, model)
        jac = _jacobian_world(p_cam, np.repeat(prob.R_cam_world, m, axis=0), camera, model)
    qi, qj = prob.frame * m + prob.i, prob.frame * m + prob.j
    w = prob.whiten[:, :, None]
    res = prob.whiten * (prob.z_meas - (g[qi] - g[qj]))
    d_pi = -w * jac[qi]
    d_pj = w * jac[qj]
    return res, d_pi, d_pj


class _NormalEquations:
    """The (3M, 3M) normal matrix of eq. 5 plus anchors, in 3x3 blocks (BSR): one diagonal block per point
    and two off-diagonal blocks per edge. The block layout, and the sparse 0/1 matrices that sum the
    per-measurement blocks into it, are fixed per problem and built once."""

    def __init__(self, edges: I64, prob: _Problem, m: int) -> None:
        n_edges = len(edges)
        block_row = np.concatenate([np.arange(m), edges[:, 0], edges[:, 1]])
        block_col = np.concatenate([np.arange(m), edges[:, 1], edges[:, 0]])
        self.order = np.lexsort((block_col, block_row))
        self.indices = block_col[self.order].astype(np.int32)
        self.indptr = np.searchsorted(block_row[self.order], np.arange(m + 1)).astype(np.int32)
        self.m, self.n_edges = m, n_edges
        self.i, self.j, self.edge = prob.i, prob.j, prob.edge
        q = len(prob.edge)
        ones, rows = np.ones(q), np.arange(q)
        # (size, Q) summation matrices: one sparse product replaces nine bincounts per block sum.
        self.sum_i = sp.csr_matrix((ones, (prob.i, rows)), shape=(m, q))
        self.sum_j = sp.csr_matrix((ones, (prob.j, rows)), shape=(m, q))
        self.sum_edge = sp.csr_matrix((ones, (prob.edge, rows)), shape=(n_edges, q))

    def matrix(self, d_pi: F64, d_pj: F64, weights: F64, anchor_info: F64) -> tuple[sp.bsr_matrix, F64]:
        """H = sum_q w_q J_q^T J_q + diag(anchor information) for Jacobian blocks (Q, 3, 3), weights (Q,).

        Also returns H's diagonal blocks (M, 3, 3), the block-Jacobi preconditioner.
        """
        wd_pi_t = np.swapaxes(weights[:, None, None] * d_pi, 1, 2)
        q = len(weights)
        ii = np.matmul(wd_pi_t, d_pi).reshape(q, 9)
        jj = np.matmul(np.swapaxes(weights[:, None, None] * d_pj, 1, 2), d_pj).reshape(q, 9)
        ij = np.matmul(wd_pi_t, d_pj).reshape(q, 9)
        diag = np.asarray(self.sum_i @ ii + self.sum_j @ jj).reshape(self.m, 3, 3)
        diag += anchor_info[:, None, None] * np.eye(3)
        off = np.asarray(self.sum_edge @ ij).reshape(self.n_edges, 3, 3)
        blocks = np.concatenate([diag, off, np.swapaxes(off, 1, 2)])[self.order]
        shape = (3 * self.m, 3 * self.m)
        return sp.bsr_matrix((blocks, self.indices, self.indptr), shape=shape), diag

    def gradient(self, d_pi: F64, d_pj: F64, weighted_res: F64) -> F64:
        """sum_q J_q^T w_q r_q per point (M, 3) for weighted residuals (Q, 3)."""
        g_i = np.einsum("qai,qa->qi", d_pi, weighted_res)
        g_j = np.einsum("qai,qa->qi", d_pj, weighted_res)
        return np.asarray(self.sum_i @ g_i + self.sum_j @ g_j)


def _gauss_newton_step(
    points_world: F64,
    anchor_world: F64,
    anchor_info: F64,
    prob: _Problem,
    normal: _NormalEquations,
    residuals: tuple[F64, F64, F64],
    weights: F64,
    rtol: float = 1e-3,
) -> F64:
    """One IRLS Gauss-Newton update of all points (M, 3) for the weighted residuals plus the anchors.

    `anchor_world` (M, 3) and `anchor_info` (M,) (isotropic information, 1/m^2) are the point anchors;
    `residuals` is `_residuals` at `points_world`, `weights` (Q,) the IRLS weights.
    """
    m = len(points_world)
    res, d_pi, d_pj = residuals
    hessian, block_diag = normal.matrix(d_pi, d_pj, weights, anchor_info)
    gradient = normal.gradient(d_pi, d_pj, weights[:, None] * res)
    gradient += anchor_info[:, None] * (points_world - anchor_world)
    # H is symmetric positive definite (the anchors make it so) and well conditioned once each point's
    # 3x3 block is inverted: block-Jacobi preconditioned conjugate gradients beat a sparse LU here.
    inv_blocks = np.linalg.inv(block_diag)
    precond = sp.bsr_matrix((inv_blocks, np.arange(m), np.arange(m + 1)), shape=hessian.shape)
    delta, _ = cg(hessian, -gradient.ravel(), M=precond, rtol=rtol, maxiter=500)
    return np.asarray(points_world + delta.reshape(m, 3), dtype=np.float64)


def _huber_weights(chi: F64, delta: float) -> F64:
    """IRLS weights of the Huber norm for whitened residual norms (Q,)."""
    return np.where(chi <= delta, 1.0, delta / np.maximum(chi, 1e-12))


def _build_problem(window: CorrelationWindow, keep: I64, edges: I64, cfg: SegmentationConfig) -> _Problem:
    """Measurements of every edge (indices into `keep`) in every frame where both points are seen."""
    obs = window.observed[:, keep]  # (K, M')
    both = obs[:, edges[:, 0]] & obs[:, edges[:, 1]]  # (K, E)
    frame, edge = np.nonzero(both)
    i, j = edges[edge, 0], edges[edge, 1]
    pts = window.points_cam[:, keep]
    pi, pj = pts[frame, i], pts[frame, j]
    gi = _observation(pi, window.camera, cfg.observation_model)
    gj = _observation(pj, window.camera, cfg.observation_model)
    var = _observation_sigma(pi, window.camera, cfg) ** 2 + _observation_sigma(pj, window.camera, cfg) ** 2
    T_cam_world = np.linalg.inv(window.T_world_cam)
    return _Problem(
        edge=edge.astype(np.int64),
        i=i,
        j=j,
        z_meas=gi - gj,
        whiten=1.0 / np.sqrt(var),
        frame=frame.astype(np.int64),
        R_cam_world=np.ascontiguousarray(T_cam_world[:, :3, :3]),
        t_cam_world=np.ascontiguousarray(T_cam_world[:, :3, 3]),
    )


def _anchor_information(window: CorrelationWindow, keep: I64, cfg: SegmentationConfig) -> F64:
    """Isotropic information (M',) in 1/m^2 of each point's measured position: K_i / mean 3D variance."""
    cfg = replace(cfg, observation_model="point_3d")
    pts = window.points_cam[:, keep]
    obs = window.observed[:, keep]
    flat = np.where(obs[..., None], pts, 1.0).reshape(-1, 3)
    var = (_observation_sigma(flat, window.camera, cfg) ** 2).mean(axis=1).reshape(obs.shape)
    mean_var = np.where(obs, var, 0.0).sum(axis=0) / np.maximum(obs.sum(axis=0), 1)
    return np.asarray(obs.sum(axis=0) / mean_var, dtype=np.float64)


def _median_world(world: F64, observed: BoolArr) -> F64:
    """Per-coordinate median over frames of measured world points (K, M, 3) where observed (K, M)."""
    masked = np.where(observed[..., None], world, np.nan)
    return np.asarray(np.nanmedian(masked, axis=0), dtype=np.float64)


def optimise_correlations(
    window: CorrelationWindow, keep: I64, edges: I64, cfg: SegmentationConfig
) -> tuple[F64, F64, I64]:
    """Solve eq. 5 for the points `keep` (indices into the window) connected by `edges` (E, 2).

    Returns the optimised world positions (M', 3), the per-edge inlier fraction (E,) after the last
    round, and the number of measurements per edge (E,).
    """
    world = window.points_world()[:, keep]
    obs = window.observed[:, keep]
    # Per-coordinate median of the measured world positions (the mean for two frames): robust to one bad
    # measurement when K >= 3, and for two frames it puts a moving point midway, where both measurements
    # of an edge to a static neighbour are equally (in)consistent.
    init = _median_world(world, obs)
    anchor_info = cfg.anchor_weight * _anchor_information(window, keep, cfg)
    prob = _build_problem(window, keep, edges, cfg)
    normal = _NormalEquations(edges, prob, len(keep))
    n_meas = np.bincount(prob.edge, minlength=len(edges)).astype(np.int64)
    points = init.copy()
    active = np.ones(len(prob.edge), dtype=bool)
    residuals = _residuals(points, prob, window.camera, cfg.observation_model)
    for _ in range(cfg.rounds):
        for _ in range(cfg.iterations_per_round):
            weights = _huber_weights(np.linalg.norm(residuals[0], axis=1), cfg.huber_delta) * active
            points = _gauss_newton_step(points, init, anchor_info, prob, normal, residuals, weights, cfg.cg_rtol)
            residuals = _residuals(points, prob, window.camera, cfg.observation_model)
        chi2 = np.einsum("qa,qa->q", residuals[0], residuals[0])
        if cfg.outlier_dof_correction:
            n = n_meas[prob.edge]
            chi2 = chi2 * n / np.maximum(n - 1, 1)
        active = chi2 <= cfg.outlier_chi2
    inliers = np.bincount(prob.edge, weights=active.astype(float), minlength=len(edges))
    fraction = inliers / np.maximum(n_meas, 1)
    return points, fraction, n_meas


def _nearest_labels(points: F64, labels: I64, queries: F64, radius_m: float) -> I64:
    """Label (Q,) of each query point's nearest point (N, 3) within `radius_m`, else unassigned."""
    from scipy.spatial import cKDTree  # type: ignore[import-untyped]

    dist, idx = cKDTree(points).query(queries, k=1, distance_upper_bound=radius_m)
    found = np.isfinite(dist)
    out = np.full(len(queries), UNASSIGNED_LABEL, dtype=np.int64)
    out[found] = labels[idx[found]]
    return out


def segment(window: CorrelationWindow, cfg: SegmentationConfig) -> SegmentationResult:
    """Split the window's points into the static scene (label 0) and object targets (labels 1..G).

    Steps of Section 3.2: (1) Delaunay graph of the points seen at least twice, at their median measured
    world position; (2) eq. 5 with outlier rounds, inconsistent edges removed; (3) connected components,
    the one with the largest volume (`cfg.static_volume`) is static.
    """
    m = len(window.point_ids)
    labels = np.full(m, UNASSIGNED_LABEL, dtype=np.int64)
    positions = np.full((m, 3), np.nan)
    obs = window.observed
    seen_twice = np.flatnonzero(obs.sum(axis=0) >= 2)
    keep = seen_twice
    if 0 < cfg.max_points < len(seen_twice):  # bound the graph; the rest is labelled from it at the end
        keep = seen_twice[np.unique(np.linspace(0, len(seen_twice) - 1, cfg.max_points).round().astype(np.int64))]
    empty = SegmentationResult(
        window.point_ids, labels, positions, np.empty((0, 2), np.int64), np.empty(0, bool), np.empty(0)
    )
    if len(keep) < 4:
        return empty

    # (1) graph of adjacent points, at their median measured world position.
    kobs = obs[:, keep]
    median_world = _median_world(window.points_world()[:, seen_twice], obs[:, seen_twice])
    in_graph = np.isin(seen_twice, keep)
    graph = delaunay_graph(median_world[in_graph])
    edges = graph.edges
    common = (kobs[:, edges[:, 0]] & kobs[:, edges[:, 1]]).sum(axis=0)
    usable = common >= cfg.min_common_frames
    if not usable.any():
        return empty

    # (2) robust optimisation of eq. 5; an edge is inconsistent when (nearly) all its measurements are outliers.
    points, used_fraction, _ = optimise_correlations(window, keep, edges[usable], cfg)
    fraction = np.zeros(len(edges))
    fraction[usable] = used_fraction
    consistent = usable & (fraction > cfg.inconsistent_inlier_fraction)
    if cfg.min_supporting_triangles > 0:
        consistent = triangle_supported(graph, consistent, cfg.min_supporting_triangles)

    # (3) connected components of the consistent graph; the largest volume is the static scene.
    mk = len(keep)
    kept = edges[consistent]
    adjacency = sp.coo_matrix((np.ones(len(kept)), (kept[:, 0], kept[:, 1])), shape=(mk, mk))
    n_comp, comp = connected_components(adjacency, directed=False)
    sizes = np.bincount(comp, minlength=n_comp)
    candidates = np.flatnonzero(sizes >= 4)
    if len(candidates) == 0:
        candidates = np.array([int(np.argmax(sizes))])
    apex = window.T_world_cam[:, :3, 3] if cfg.static_volume == "view_cone" else np.empty((0, 3))
    volumes = np.array([hull_volume_m3(np.vstack([points[comp == c], apex])) for c in candidates])
    # Ties (degenerate hulls) go to the component with more points.
    static_comp = int(candidates[np.lexsort((sizes[candidates], volumes))[-1]])
    klabels = np.full(mk, UNASSIGNED_LABEL, dtype=np.int64)
    klabels[comp == static_comp] = STATIC_LABEL
    targets = [c for c in np.argsort(-sizes, kind="stable") if c != static_comp and sizes[c] >= cfg.min_target_points]
    vols = [hull_volume_m3(points[comp == static_comp])]
    for g, c in enumerate(targets, start=1):
        klabels[comp == c] = g
        vols.append(hull_volume_m3(points[comp == c]))
    labels[keep] = klabels
    positions[keep] = points
    if not in_graph.all():
        rest = seen_twice[~in_graph]
        labels[rest] = _nearest_labels(median_world[in_graph], klabels, median_world[~in_graph], cfg.label_rest_radius_m)
    return SegmentationResult(
        point_ids=window.point_ids,
        labels=labels,
        positions_world=positions,
        edges=keep[edges],
        edge_consistent=consistent,
        inlier_fraction=fraction,
        component_volumes_m3=tuple(vols),
    )
