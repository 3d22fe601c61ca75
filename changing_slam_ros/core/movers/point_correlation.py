"""Point-correlation segmentation of map points into the static scene and moving object targets (Dai et al.
2021, §3.2, after Dai et al. 2020): (1) a graph of adjacent points by 3D Delaunay tetrahedralisation (eq. 2);
(2) inconsistent edges removed: point positions are estimated from the *relative* measurements of every edge in
every frame (eqs. 3-5, z_ijk = y_ik - y_jk with y = g(p_cam) = [u, v, d]; solved in `correlation_optimiser`),
measurements with a large error are left out of the next round, and an edge whose every measurement is an
outlier is removed; (3) connected components: the largest convex-hull volume is the static scene, every other
component with enough points an object target. Camera pose errors do not change the result: a pose error moves
all of that frame's points by one rigid transform, like a common motion. Two modes, two frames (tracking) and
K > 2 frames (local mapping): `SegmentationConfig.two_frame` / `multi_frame`. Beyond the paper, each switchable
in `SegmentationConfig`: a weak anchor of each point on its measured position, triangle support of kept edges,
an optional viewing-cone volume. The graph is built in `delaunay_graph`; `correlation_window` holds the
configuration, input window and result; this module holds `segment`. `edge_test` is the closed-form
two-frame alternative the dynamic filter uses by default.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import scipy.sparse as sp  # type: ignore[import-untyped]
from scipy.sparse.csgraph import connected_components  # type: ignore[import-untyped]

from changing_slam_ros.core.movers.correlation_optimiser import median_world, optimise_correlations
from changing_slam_ros.core.movers.delaunay_graph import delaunay_graph, hull_volume_m3, triangle_supported
from changing_slam_ros.core.movers.correlation_window import (  # noqa: F401 (re-exported: the segmentation API)
    OBSERVATION_MODELS, STATIC_LABEL, STATIC_VOLUMES, UNASSIGNED_LABEL, CorrelationWindow, SegmentationConfig,
    SegmentationResult,
)

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
BoolArr = npt.NDArray[np.bool_]


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
    median_pos = median_world(window.points_world()[:, seen_twice], obs[:, seen_twice])
    in_graph = np.isin(seen_twice, keep)
    graph = delaunay_graph(median_pos[in_graph])
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
        labels[rest] = _nearest_labels(median_pos[in_graph], klabels, median_pos[~in_graph], cfg.label_rest_radius_m)
    return SegmentationResult(
        point_ids=window.point_ids,
        labels=labels,
        positions_world=positions,
        edges=keep[edges],
        edge_consistent=consistent,
        inlier_fraction=fraction,
        component_volumes_m3=tuple(vols),
    )
