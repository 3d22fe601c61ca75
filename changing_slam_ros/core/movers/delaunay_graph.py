"""The graph of adjacent points of the point-correlation segmentation (Dai et al. 2021, Section 3.2, eq. 2).

A 3D Delaunay tetrahedralisation of the points gives the edges l_ij; the faces of its tetrahedra give the
triangles used for our triangle-support test; and the convex-hull volume picks the static component.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.spatial import ConvexHull, Delaunay, QhullError  # type: ignore[import-untyped]

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
BoolArr = npt.NDArray[np.bool_]


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
