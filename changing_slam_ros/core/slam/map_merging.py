"""Applying a map merge of the Atlas (ORB-SLAM3's merge, RGB-D: a rigid SE(3) welding of two maps).

When tracking stays lost, a new map is started; when loop closing later recognises a place of an older
map from the current one (`LoopCloser.detect_merge` -> `MapMerge`), `merge_maps` welds the two (its docstring
has the steps).
The caller moves whatever else refers to the source map: frame records, the tracker's last frame
(`move_frame`), the keyframe database's map ids, local mapping's recent points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.backend.local_ba import LocalBAConfig, LocalBAResult, local_bundle_adjust
from changing_slam_ros.core.features.frame import Frame
from changing_slam_ros.core.slam.loop_closing import MapMerge
from changing_slam_ros.core.slam.map_fusion import fuse_into, refresh_points, replace_point
from changing_slam_ros.core.map.map_point import PointStore
from changing_slam_ros.core.map.slam_map import Atlas, SlamMap

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


@dataclass(frozen=True)
class MergeConfig:
    """YAML section `mapping: merge:`.

    - `enabled`: look for places shared with older maps and merge (needs loop closing's place recognition).
    - `fuse_neighbours`: covisible keyframes of each side of the seam whose points are fused.
    - `fuse_radius_px`: projection search window for that fusion (level 0).
    - `welding_ba`: a local bundle adjustment around the query keyframe after the merge.
    """

    enabled: bool = True
    fuse_neighbours: int = 10
    fuse_radius_px: float = 3.0
    welding_ba: bool = True


@dataclass(frozen=True)
class MergeResult:
    """What `merge_maps` did: `from_map_id` (now empty) went into `into_map_id` with `T_into_from` (4, 4);
    its point ids were shifted by `point_id_offset`."""

    from_map_id: int
    into_map_id: int
    T_into_from: F64
    point_id_offset: int
    moved_keyframes: tuple[int, ...]
    n_points_moved: int
    n_fused: int
    ba: LocalBAResult | None


def append_points(target: PointStore, source: PointStore, T_target_source: F64) -> int:
    """Copy every row of `source` (bad ones too, so ids shift uniformly) to the end of `target`, moved by
    `T_target_source`; returns the id offset (source id i becomes offset + i)."""
    offset = target.size
    n = source.size
    if n == 0:
        return offset
    ids = target.extend_ids(offset + n)
    cols = source.column_arrays()
    for name in PointStore.COLUMNS:  # every per-point column, whatever the store holds
        getattr(target, name)[ids] = cols[name]
    R, t = T_target_source[:3, :3], T_target_source[:3, 3]
    target.positions[ids] = cols["positions"] @ R.T + t
    target.normals[ids] = cols["normals"] @ R.T
    for pid, o in zip(ids.tolist(), source.observations[:n], strict=True):
        target.observations[pid] = dict(o)
    return offset


def _reroot(slam_map: SlamMap, new_root: int) -> None:
    """Reverse the spanning-tree path from `new_root` up to its root, so that `new_root` has no parent."""
    path = [new_root]
    while path[-1] in slam_map.parent:
        path.append(slam_map.parent[path[-1]])
    for child, par in zip(path[:-1], path[1:]):
        slam_map.children.get(par, set()).discard(child)
        slam_map.parent.pop(child, None)
    for a, b in zip(path[:-1], path[1:]):
        slam_map.parent[b] = a
        slam_map.children.setdefault(a, set()).add(b)


def _fuse_seam(target: SlamMap, merge: MapMerge, query_side: list[int], match_side: list[int],
               level_scales: F64, bf_m_px: float, radius_px: float) -> int:
    """Fuse points mapped in both maps: verified keypoint matches, then projection both ways."""
    pts = target.points
    query, match = target.keyframes[merge.query_kf_id], target.keyframes[merge.match_kf_id]
    n = 0
    for i_m, i_q in np.asarray(merge.keypoint_matches, np.int64).reshape(-1, 2).tolist():
        pm, pq = int(match.point_ids[i_m]), int(query.point_ids[i_q])
        if pm < 0 or pts.bad[pm] or pm == pq:
            continue
        if pq >= 0 and not pts.bad[pq]:
            replace_point(target, pq, pm)
            n += 1
        elif query.id not in pts.observations[pm]:
            target.add_observation(pm, query.id, i_q)
    for side, other in ((query_side, match_side), (match_side, query_side)):
        theirs = target.local_point_ids(other)
        for kf_id in side:
            a, b = fuse_into(target, target.keyframes[kf_id], theirs, level_scales, bf_m_px, radius_px)
            n += a + b
            theirs = theirs[~pts.bad[theirs]]
    touched = target.local_point_ids(query_side + match_side)
    refresh_points(target, touched, level_scales)
    return n


def merge_maps(
    atlas: Atlas,
    merge: MapMerge,
    level_scales: F64,
    bf_m_px: float,
    config: MergeConfig | None = None,
    ba: LocalBAConfig | None = None,
) -> MergeResult:
    """Weld map `merge.query_map_id` into map `merge.match_map_id`. `ba` is the local BA configuration of the
    welding BA (None: no BA).

    1. every point of the current ("source") map is appended to the older ("target") map's point store,
       moved by `T_matchworld_queryworld` (positions and viewing directions); point ids shift by the target's
       size before the merge (`MergeResult.point_id_offset`);
    2. every keyframe moves by the same transform and joins the target map with its covisibility links,
       spanning tree, culled-keyframe records and loop edges (keyframe ids are global, so they do not clash);
    3. the spanning tree is joined at the seam: the source tree is re-rooted at the query keyframe, which
       becomes a child of the matched keyframe;
    4. points mapped twice around the seam are fused: the verified keypoint matches first, then a projection
       search (`map_fusion.fuse_into`) between the `fuse_neighbours` best covisible keyframes of each side;
       covisibility is recomputed there, which links the two sides;
    5. optionally a local bundle adjustment around the query keyframe ("welding BA") over both sides;
    6. the source map is left empty in the Atlas (its id stays valid; `Atlas.merged_into` records where it went)
       and the target becomes the current map.
    """
    cfg = config or MergeConfig()
    if merge.query_map_id == merge.match_map_id:
        raise ValueError(f"map merge within one map ({merge.query_map_id})")
    src, dst = atlas.maps[merge.query_map_id], atlas.maps[merge.match_map_id]
    if merge.query_kf_id not in src.keyframes or merge.match_kf_id not in dst.keyframes:
        raise ValueError(f"map merge keyframes {merge.query_kf_id} / {merge.match_kf_id} are not in maps "
                         f"{src.id} / {dst.id}")
    T = np.asarray(merge.T_matchworld_queryworld, np.float64)
    # Neighbourhoods of the seam, taken before the maps are joined.
    query_side = [merge.query_kf_id, *src.covisible(merge.query_kf_id, cfg.fuse_neighbours)]
    match_side = [merge.match_kf_id, *dst.covisible(merge.match_kf_id, cfg.fuse_neighbours)]
    # 1. Points.
    n_points = src.points.size
    offset = append_points(dst.points, src.points, T)
    # 2. Keyframes and graphs.
    _reroot(src, merge.query_kf_id)
    for kf in src.keyframes.values():
        kf.T_world_cam = T @ kf.T_world_cam
        kf.map_id = dst.id
        seen = kf.point_ids >= 0
        kf.point_ids[seen] += offset
        dst.keyframes[kf.id] = kf
    dst.covisibility.update(src.covisibility)
    dst.parent.update(src.parent)
    for k, ch in src.children.items():
        dst.children.setdefault(k, set()).update(ch)
    dst.removed.update(src.removed)  # culled keyframes: poses relative to their parents, unchanged
    for k, e in src.loop_edges.items():
        dst.loop_edges.setdefault(k, set()).update(e)
    # 3. Spanning tree joined at the seam.
    dst.parent[merge.query_kf_id] = merge.match_kf_id
    dst.children.setdefault(merge.match_kf_id, set()).add(merge.query_kf_id)
    dst.loop_edges.setdefault(merge.match_kf_id, set()).add(merge.query_kf_id)
    dst.loop_edges.setdefault(merge.query_kf_id, set()).add(merge.match_kf_id)
    # 4. Fusion at the seam, then fresh covisibility there.
    n_fused = _fuse_seam(dst, merge, query_side, match_side, level_scales, bf_m_px, cfg.fuse_radius_px)
    for k in query_side + match_side:
        if k in dst.keyframes:
            dst.update_connections(k)
    # 5. Welding BA.
    ba_result = None
    if cfg.welding_ba and ba is not None:
        ba_result = local_bundle_adjust(dst, merge.query_kf_id, ba)
        dst.update_connections(merge.query_kf_id)
    # 6. The source map is left empty; the target becomes current.
    moved = tuple(sorted(src.keyframes))
    atlas.maps[src.id] = SlamMap(src.id)
    atlas.merged_into[src.id] = dst.id
    atlas.current = dst
    return MergeResult(src.id, dst.id, T, offset, moved, n_points, n_fused, ba_result)


def move_frame(frame: Frame, result: MergeResult) -> None:
    """Express a tracked frame of the merged-away map in the merged one: pose and map point ids."""
    if frame.T_world_cam is not None:
        frame.T_world_cam = result.T_into_from @ frame.T_world_cam
    seen = frame.point_ids >= 0
    frame.point_ids[seen] += result.point_id_offset
