"""Map replication packets <-> messages: KeyframePacket <-> Keyframe, MapUpdate <-> MapUpdate, LoopResult <->
LoopCorrection, MapDelta <-> MapDelta (see `core.map_replication`). Arrays cross as flat typed arrays."""

from __future__ import annotations

import array
from typing import Any

import numpy as np
import numpy.typing as npt

from changing_slam_msgs.msg import Keyframe as KeyframeMsg
from changing_slam_msgs.msg import LoopCorrection as LoopCorrectionMsg
from changing_slam_msgs.msg import MapDelta as MapDeltaMsg
from changing_slam_msgs.msg import MapUpdate as MapUpdateMsg
from changing_slam_ros.core.replication.map_replication import (
    POINT_COLUMNS,
    KeyframePacket,
    KeyframeRows,
    LoopResult,
    MapDelta,
    MapUpdate,
    ObjectRows,
    PointCounters,
    PointRows,
    RemovedRows,
)
from changing_slam_ros.errors import BagError
from changing_slam_ros.nodes.conversions import (
    depth_to_image,
    image_to_depth_m,
    keyframe_from_msg,
    keyframe_to_msg,
    loop_correction_from_msg,
    loop_correction_to_msg,
    make_header,
    matrix_to_pose,
)

# numpy dtype -> array.array type code (bool[] fields take a list of bools).
_CODES = {np.dtype(np.int64): "q", np.dtype(np.int8): "b", np.dtype(np.uint8): "B", np.dtype(np.float64): "d"}
# KeyframeRows fields and their message names / dtypes.
_KF_FIELDS = (
    ("ids", np.int64), ("poses", np.float64), ("n_keypoints", np.int64), ("point_ids", np.int64),
    ("kp_classes", np.int8), ("object_ids", np.int64), ("cov_counts", np.int64), ("cov_ids", np.int64),
    ("cov_weights", np.int64), ("parents", np.int64), ("child_counts", np.int64), ("child_ids", np.int64),
    ("loop_counts", np.int64), ("loop_ids", np.int64),
)  # fmt: skip
_OBJECT_WIDTH = 52


def _put(values: Any, dtype: Any) -> Any:
    a = np.ascontiguousarray(np.asarray(values, dtype=dtype)).reshape(-1)
    if a.dtype == np.bool_:
        return a.tolist()
    return array.array(_CODES[a.dtype], a.tobytes())


def _get(values: Any, dtype: Any) -> npt.NDArray[Any]:
    if np.dtype(dtype) == np.bool_:
        return np.array(list(values), dtype=bool)
    return np.frombuffer(bytes(memoryview(values)) if not isinstance(values, bytes | bytearray) else values,
                         dtype=dtype).copy()  # fmt: skip


# -- MapDelta --------------------------------------------------------------------------------------------
def delta_to_msg(d: MapDelta) -> MapDeltaMsg:
    msg = MapDeltaMsg(map_id=int(d.map_id), origin_keyframe_id=int(d.origin_kf_id), n_points=int(d.n_points))
    for name, dtype in _KF_FIELDS:
        setattr(msg, f"kf_{name}", _put(getattr(d.keyframes, name), dtype))
    msg.removed_ids = _put(d.removed.ids, np.int64)
    msg.removed_parents = _put(d.removed.parents, np.int64)
    msg.removed_t_parent_kf = _put(d.removed.T_parent_kf, np.float64)
    p = d.points
    msg.pt_ids = _put(p.ids, np.int64)
    for name, _, dtype in POINT_COLUMNS:
        setattr(msg, f"pt_{name}", _put(p.columns[name], dtype))
    msg.pt_obs_counts = _put(p.obs_counts, np.int64)
    msg.pt_obs_kf_ids = _put(p.obs_kf_ids, np.int64)
    msg.pt_obs_kp_indices = _put(p.obs_kp_indices, np.int64)
    return msg


def delta_from_msg(msg: Any, topic: str) -> MapDelta:
    """MapDelta message -> core MapDelta; BagError when its arrays disagree in length."""
    kf = {name: _get(getattr(msg, f"kf_{name}"), dtype) for name, dtype in _KF_FIELDS}
    k = len(kf["ids"])
    kf["poses"] = kf["poses"].reshape(-1, 4, 4)
    ids = _get(msg.pt_ids, np.int64)
    m = len(ids)
    cols = {}
    for name, shape, dtype in POINT_COLUMNS:
        a = _get(getattr(msg, f"pt_{name}"), dtype)
        width = int(np.prod(shape)) if shape else 1
        if len(a) != m * width:
            raise BagError(f"{topic}: map delta: pt_{name} has {len(a)} values for {m} points (expected {m * width})")
        cols[name] = a.reshape((m,) + shape)
    checks = {
        "kf_poses": (len(kf["poses"]), k), "kf_n_keypoints": (len(kf["n_keypoints"]), k),
        "kf_point_ids": (len(kf["point_ids"]), int(kf["n_keypoints"].sum())),
        "kf_cov_ids": (len(kf["cov_ids"]), int(kf["cov_counts"].sum())), "kf_parents": (len(kf["parents"]), k),
    }  # fmt: skip
    bad = {f: v for f, v in checks.items() if v[0] != v[1]}
    if bad:
        raise BagError(f"{topic}: map delta: array lengths disagree: "
                       + ", ".join(f"{f} {a} (expected {b})" for f, (a, b) in bad.items()))  # fmt: skip
    removed = RemovedRows(_get(msg.removed_ids, np.int64), _get(msg.removed_parents, np.int64),
                          _get(msg.removed_t_parent_kf, np.float64).reshape(-1, 4, 4))  # fmt: skip
    points = PointRows(ids, cols, _get(msg.pt_obs_counts, np.int64), _get(msg.pt_obs_kf_ids, np.int64),
                       _get(msg.pt_obs_kp_indices, np.int64))  # fmt: skip
    return MapDelta(int(msg.map_id), int(msg.origin_keyframe_id), int(msg.n_points), KeyframeRows(**kf), removed, points)


# -- keyframe packets --------------------------------------------------------------------------------------
def packet_to_msg(p: KeyframePacket, frame_id: str) -> KeyframeMsg:
    msg = keyframe_to_msg(p.keyframe, frame_id)
    msg.counter_point_ids = _put(p.counters.ids, np.int64)
    msg.counter_n_visible = _put(p.counters.n_visible, np.int64)
    msg.counter_n_found = _put(p.counters.n_found, np.int64)
    msg.counter_last_seen_frame = _put(p.counters.last_seen_frame, np.int64)
    others = list(p.other_counters.items())
    msg.other_counter_map_ids = [int(k) for k, _ in others]
    msg.other_counter_lengths = _put([len(c.ids) for _, c in others], np.int64)
    for f in ("point_ids", "n_visible", "n_found", "last_seen_frame"):
        attr = "ids" if f == "point_ids" else f
        setattr(msg, f"other_counter_{f}", _put(np.concatenate([getattr(c, attr) for _, c in others])
                                                if others else [], np.int64))  # fmt: skip
    if p.depth_m is not None:
        msg.depth = depth_to_image(p.depth_m.astype(np.float32), p.keyframe.stamp_ns, frame_id)
    o = ObjectRows.of(p.objects)
    rows = np.column_stack([o.ids, o.class_ids, o.boxes, o.positions, o.velocities, o.speeds, o.motion, o.n_updates,
                            o.is_new, o.covariances]) if len(o.ids) else np.zeros((0, _OBJECT_WIDTH))  # fmt: skip
    msg.short_term_objects = _put(rows, np.float64)
    return msg


def packet_from_msg(msg: Any, topic: str) -> KeyframePacket:
    kf = keyframe_from_msg(msg, topic)
    counters = PointCounters(*(_get(getattr(msg, f), np.int64) for f in (
        "counter_point_ids", "counter_n_visible", "counter_n_found", "counter_last_seen_frame")))
    if not len(counters.ids) == len(counters.n_visible) == len(counters.n_found) == len(counters.last_seen_frame):
        raise BagError(f"{topic}: keyframe {kf.id}: counter arrays disagree in length")
    others = _other_counters(msg, f"{topic}: keyframe {kf.id}")
    depth = image_to_depth_m(msg.depth, topic) if msg.depth.height > 0 else None
    flat = _get(msg.short_term_objects, np.float64)
    if len(flat) % _OBJECT_WIDTH:
        raise BagError(f"{topic}: keyframe {kf.id}: short_term_objects has {len(flat)} values, not {_OBJECT_WIDTH}K")
    r = flat.reshape(-1, _OBJECT_WIDTH)
    rows = ObjectRows(r[:, 0].astype(np.int64), r[:, 1].astype(np.int64), r[:, 2:6], r[:, 6:9], r[:, 9:12], r[:, 12],
                      r[:, 13].astype(np.int64), r[:, 14].astype(np.int64), r[:, 15] > 0.5, r[:, 16:52])  # fmt: skip
    return KeyframePacket(kf, counters, depth, rows.states(), others)


def _other_counters(msg: Any, what: str) -> dict[int, PointCounters]:
    map_ids = [int(v) for v in msg.other_counter_map_ids]
    lengths = _get(msg.other_counter_lengths, np.int64)
    cols = [_get(getattr(msg, f"other_counter_{f}"), np.int64)
            for f in ("point_ids", "n_visible", "n_found", "last_seen_frame")]  # fmt: skip
    if len(lengths) != len(map_ids) or np.any(lengths < 0) or any(len(c) != int(lengths.sum()) for c in cols):
        raise BagError(f"{what}: other_counter arrays disagree in length")
    ends = np.cumsum(lengths).tolist()
    starts = [0, *ends[:-1]] if ends else []
    return {k: PointCounters(*(c[a:b].copy() for c in cols)) for k, a, b in zip(map_ids, starts, ends, strict=True)}


# -- map updates and loop results -----------------------------------------------------------------------
def update_to_msg(u: MapUpdate, stamp_ns: int, frame_id: str) -> MapUpdateMsg:
    """Also fills the summary fields (optimised keyframe poses, created/moved points, removals)."""
    d = u.delta
    msg = MapUpdateMsg(header=make_header(stamp_ns, frame_id), map_id=int(d.map_id), keyframe_id=int(u.keyframe_id),
                       loop_query_keyframe_id=int(u.loop_query_kf_id), objects_ran=bool(u.objects_ran),
                       active_flags_changed=bool(u.active_flags_changed), delta=delta_to_msg(d))  # fmt: skip
    msg.keyframe_ids = _put(d.keyframes.ids, np.int64)
    msg.keyframe_poses = [matrix_to_pose(T) for T in d.keyframes.poses]
    msg.removed_keyframe_ids = _put(d.removed.ids, np.int64)
    live = ~d.points.columns["bad"]
    msg.point_ids = _put(d.points.ids[live], np.int64)
    msg.point_positions = _put(d.points.columns["positions"][live], np.float64)
    msg.point_active = _put(d.points.columns["active"][live], np.bool_)
    msg.removed_point_ids = _put(d.points.ids[~live], np.int64)
    if u.merge is not None:
        r = u.merge
        msg.merged = True
        msg.merged_from_map_id = int(r.from_map_id)
        msg.merge_transform = _put(r.T_into_from, np.float64)
        msg.merge_point_id_offset = int(r.point_id_offset)
        msg.merge_moved_keyframe_ids = _put(r.moved_keyframes, np.int64)
        msg.merge_n_points_moved = int(r.n_points_moved)
        msg.merge_n_fused = int(r.n_fused)
    return msg


def _transform(values: Any, what: str) -> npt.NDArray[np.float64]:
    T = _get(values, np.float64)
    if T.shape != (16,) or not np.all(np.isfinite(T)):
        raise BagError(f"{what}: expected 16 finite values, got {T.size}")
    return T.reshape(4, 4)


def update_from_msg(msg: Any, topic: str) -> MapUpdate:
    merge = None
    if msg.merged:
        from changing_slam_ros.core.slam.map_merging import MergeResult

        if int(msg.merged_from_map_id) == int(msg.delta.map_id):
            raise BagError(f"{topic}: map merge of map {msg.delta.map_id} into itself")
        merge = MergeResult(int(msg.merged_from_map_id), int(msg.delta.map_id),
                            _transform(msg.merge_transform, f"{topic}: merge_transform"),
                            int(msg.merge_point_id_offset), tuple(_get(msg.merge_moved_keyframe_ids, np.int64).tolist()),
                            int(msg.merge_n_points_moved), int(msg.merge_n_fused), None)  # fmt: skip
    return MapUpdate(int(msg.keyframe_id), delta_from_msg(msg.delta, topic), _get(msg.removed_keyframe_ids, np.int64),
                     bool(msg.active_flags_changed), bool(msg.objects_ran), int(msg.loop_query_keyframe_id),
                     merge)  # fmt: skip


def loop_result_to_msg(r: LoopResult, stamp_ns: int, frame_id: str, map_id: int) -> LoopCorrectionMsg:
    if r.closed and r.correction is not None:
        msg = loop_correction_to_msg(r.correction, stamp_ns, frame_id)
    else:
        msg = LoopCorrectionMsg(header=make_header(stamp_ns, frame_id), map_id=int(map_id))
        msg.query_keyframe_id = int(r.query_kf_id)
        msg.match_keyframe_id = -1
    msg.closed = bool(r.closed)
    if r.delta is not None:
        msg.delta = delta_to_msg(r.delta)
    if r.merge is not None and not r.closed:
        g = r.merge
        msg.map_id = int(g.query_map_id)
        msg.match_keyframe_id = int(g.match_kf_id)
        msg.relative_pose = matrix_to_pose(g.T_match_query)
        msg.n_inliers = int(g.num_inliers)
        msg.merge = True
        msg.merge_match_map_id = int(g.match_map_id)
        msg.merge_transform = _put(g.T_matchworld_queryworld, np.float64)
        msg.merge_keypoint_matches = _put(g.keypoint_matches, np.int64)
    return msg


def loop_result_from_msg(msg: Any, topic: str) -> LoopResult:
    if not msg.closed and msg.merge:
        from changing_slam_ros.core.slam.loop_closing import MapMerge
        from changing_slam_ros.nodes.conversions import pose_to_matrix

        pairs = _get(msg.merge_keypoint_matches, np.int64)
        if len(pairs) % 2:
            raise BagError(f"{topic}: merge_keypoint_matches has {len(pairs)} values, not pairs")
        merge = MapMerge(int(msg.query_keyframe_id), int(msg.match_keyframe_id), int(msg.map_id),
                         int(msg.merge_match_map_id), pose_to_matrix(msg.relative_pose),
                         _transform(msg.merge_transform, f"{topic}: merge_transform"), int(msg.n_inliers),
                         pairs.reshape(-1, 2))  # fmt: skip
        return LoopResult(int(msg.query_keyframe_id), False, merge=merge)
    if not msg.closed:
        return LoopResult(int(msg.query_keyframe_id), False)
    return LoopResult(int(msg.query_keyframe_id), True, delta_from_msg(msg.delta, topic), loop_correction_from_msg(msg))
