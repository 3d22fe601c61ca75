"""Loop closing: the component behind the `loop_closing` node (ORB-SLAM's LoopClosing thread, RGB-D, SE(3)).

`LoopCloser.process` finds a loop through each new keyframe (its docstring has the steps) and returns a
`LoopCorrection`; it never writes into keyframes except through `update_poses`. The map owner applies the
correction (and fuses the duplicated points listed in it), then reports poses back with `update_poses` when
keyframes are copies (ROS transport). `detect_merge` finds places shared by two maps of the Atlas (applied by
`core.slam.map_merging.merge_maps`); `relocalise` serves tracking when it is lost. `SlamMapLoopClosing` (end
of module) binds all this to the offline runner's `core.map.slam_map`.
"""

from __future__ import annotations

from collections import ChainMap
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.backend.global_ba import GlobalBAConfig, GlobalBAResult, global_bundle_adjust
from changing_slam_ros.core.backend.pose_graph import (
    EdgeKind,
    PoseGraphConfig,
    PoseGraphEdge,
    correct_points,
    essential_graph_edges,
    optimise_pose_graph,
    relative_edges,
)
from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.features.frame import Frame
from changing_slam_ros.core.slam.geometric_verification import Verification, VerificationConfig, verify
from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.map.keyframe_database import Covisibility, KeyframeDatabase, loop_feature_mask
from changing_slam_ros.core.map.map_point import PointStore
from changing_slam_ros.core.slam.place_recognition import (
    ConsistencyChecker,
    DriftCheck,
    DriftGateConfig,
    Relocalisation,
    RelocalisationConfig,
    check_drift,
    neighbours,
    path_travelled,
    relocalise,
)
from changing_slam_ros.core.geometry.se3 import invert
from changing_slam_ros.core.map.slam_map import Atlas, SlamMap
from changing_slam_ros.core.features.vocabulary import Vocabulary, l1_score

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class LoopConfig:
    """YAML section `loop:` (nested `verification:`, `pose_graph:`, `relocalisation:`)."""

    enabled: bool = True
    min_keyframes_in_map: int = 10  # ORB-SLAM: no loop detection in a map with fewer keyframes
    min_keyframes_between_loops: int = 10  # ORB-SLAM: mLastLoopKFid + 10
    consistency_threshold: int = 3  # ORB-SLAM mnCovisibilityConsistencyTh
    covisibility_group_size: int = 10  # best covisible keyframes accumulated per candidate
    min_score_floor: float = 0.0  # lower bound on the candidate score (ORB-SLAM uses the covisible minimum only)
    max_verified_candidates: int = 5
    verification: VerificationConfig = field(default_factory=VerificationConfig)
    drift_gate: DriftGateConfig = field(default_factory=DriftGateConfig)  # verified loop vs odometry drift
    pose_graph: PoseGraphConfig = field(default_factory=PoseGraphConfig)
    relocalisation: RelocalisationConfig = field(default_factory=RelocalisationConfig)


@dataclass(frozen=True)
class LoopCorrection:
    """A closed loop (mirrors msg LoopCorrection).

    - `query_kf_id`, `match_kf_id`, `map_id`: the new keyframe, the old one it re-observes, their map;
    - `T_match_query` (4, 4): verified pose of the query camera in the match camera's frame;
    - `num_inliers`: verified 3D-3D inliers; `keypoint_matches` (M, 2) int64 their keypoint indices (match, query);
    - `corrected_poses`: keyframe id -> corrected T_world_cam (4, 4), every keyframe of the map;
    - `corrected_points`: point id -> corrected world position (3,), every point passed in;
    - `fused_points`: (query point id, match point id) pairs of the same physical point mapped twice: the map
      owner replaces the first by the second (ORB-SLAM's loop fusion);
    - `pose_corrections`: keyframe id -> T_new @ T_old^-1 (4, 4), to move frames tracked against a keyframe.
    """

    query_kf_id: int
    match_kf_id: int
    map_id: int
    T_match_query: F64
    num_inliers: int
    keypoint_matches: npt.NDArray[np.int64]
    corrected_poses: dict[int, F64]
    corrected_points: dict[int, F64]
    fused_points: list[tuple[int, int]]
    pose_corrections: dict[int, F64]


@dataclass
class LoopStats:
    """Counters over `process` calls, for benchmarks and logs: keyframes offered, queries made, keyframes
    with candidates, consistent candidates verified, verifications rejected, loops closed."""

    keyframes: int = 0
    queries: int = 0
    with_candidates: int = 0
    verified: int = 0
    rejected: int = 0
    rejected_drift: int = 0  # verified, but the correction is implausible for the path travelled (DriftGate)
    loops: int = 0


@dataclass(frozen=True)
class MapMerge:
    """A place seen in two maps of the Atlas (ORB-SLAM3 merge detection): keyframe `query_kf_id` of map
    `query_map_id` re-observes keyframe `match_kf_id` of map `match_map_id`.

    `T_match_query` (4, 4) is the verified relative pose of the two cameras; `T_matchworld_queryworld` (4, 4)
    maps the query map's world frame into the match map's (apply it to every pose and point of the query map
    to express it in the match map). `keypoint_matches` (M, 2) int64 pairs (match, query) as in LoopCorrection.
    """

    query_kf_id: int
    match_kf_id: int
    query_map_id: int
    match_map_id: int
    T_match_query: F64
    T_matchworld_queryworld: F64
    num_inliers: int
    keypoint_matches: npt.NDArray[np.int64]


class LoopCloser:
    """Owns the keyframe database and the loop edges; `process` has the steps."""

    def __init__(self, config: LoopConfig, vocabulary: Vocabulary) -> None:
        self.config = config
        self.database = KeyframeDatabase(vocabulary, config.covisibility_group_size)
        self._keyframes: dict[int, Keyframe] = {}
        self._masks: dict[int, npt.NDArray[np.bool_]] = {}
        self._consistency = ConsistencyChecker(config.consistency_threshold)
        self._merge_consistency = ConsistencyChecker(config.consistency_threshold)
        self._loop_edges: list[tuple[int, int]] = []  # (match, query) pairs of accepted loops
        self._last_loop_kf_id = -(10**9)
        self.stats = LoopStats()
        self.last_drift_check: DriftCheck | None = None  # of the latest verified candidate

    # ------------------------------------------------------------------ bookkeeping
    @property
    def keyframes(self) -> Mapping[int, Keyframe]:
        return self._keyframes

    @property
    def loop_edges(self) -> list[tuple[int, int]]:
        return list(self._loop_edges)

    def erase(self, kf_id: int) -> None:
        """Forget a culled keyframe."""
        self.database.erase(kf_id)
        self._keyframes.pop(kf_id, None)
        self._masks.pop(kf_id, None)

    def update_poses(self, poses: Mapping[int, F64]) -> None:
        """Set T_world_cam of held keyframes (map updates from local mapping, or an applied correction)."""
        for kf_id, T in poses.items():
            kf = self._keyframes.get(kf_id)
            if kf is not None:
                kf.T_world_cam = np.asarray(T, np.float64)

    def add(self, keyframe: Keyframe, active_mask: npt.NDArray[np.bool_] | None = None) -> None:
        """Index a keyframe without looking for a loop (maps loaded from disk, keyframes of other maps)."""
        mask = loop_feature_mask(keyframe) if active_mask is None else np.asarray(active_mask, bool)
        self._keyframes[keyframe.id] = keyframe
        self._masks[keyframe.id] = mask
        self.database.add(keyframe, mask)

    def set_active_mask(self, kf_id: int, active_mask: npt.NDArray[np.bool_]) -> bool:
        """Re-index a held keyframe with a new feature mask (object states changed: Changing-SLAM §4.6 points of
        objects whose belief dropped leave place recognition). Returns whether anything changed."""
        kf = self._keyframes.get(kf_id)
        mask = np.asarray(active_mask, bool)
        if kf is None or np.array_equal(self._masks[kf_id], mask):
            return False
        self.add(kf, mask)
        return True

    # ------------------------------------------------------------------ loop closing
    def process(
        self,
        keyframe: Keyframe,
        covisibility: Covisibility,
        spanning_parent: Mapping[int, int | None],
        point_positions: Mapping[int, F64],
        active_mask: npt.NDArray[np.bool_] | None = None,
        point_reference_kf: Mapping[int, int] | None = None,
    ) -> LoopCorrection | None:
        """Add a new keyframe and close a loop through it if there is one.

        Steps:
        1. quantises its static, active features and indexes it in the keyframe database;
        2. after `min_keyframes_in_map` keyframes and `min_keyframes_between_loops` since the last loop, asks the
           database for loop candidates scoring at least as well as the keyframe's worst covisible neighbour;
        3. keeps candidates whose covisibility group stays consistent over `consistency_threshold` keyframes;
        4. verifies them geometrically with depth (`geometric_verification.verify`) and checks the correction against
           the drift expected over the path between the two keyframes (`place_recognition.check_drift`); the first
           that passes both is the loop;
        5. moves the keyframe and its covisible neighbours by the loop correction (initial guess), optimises the
           essential graph (spanning tree + strong covisibility + past loop edges + this loop's connections between
           the two neighbourhoods) with GTSAM, and moves every map point with its reference keyframe.

        `covisibility`: id -> covisible ids (or {id: shared points}, best first); `spanning_parent`: id -> parent
        id (None for a map's first keyframe); `point_positions`: point id -> world (3,). `active_mask` (N,) bool
        keeps keypoints allowed in place recognition (default: not DYNAMIC/UNUSED). `point_reference_kf` maps a
        point to the keyframe it moves with (default: the oldest held keyframe observing it).
        """
        mask = loop_feature_mask(keyframe) if active_mask is None else np.asarray(active_mask, bool)
        stored = self._masks.get(keyframe.id)
        if stored is None or not np.array_equal(stored, mask):  # not indexed yet (or its mask changed)
            self.add(keyframe, mask)
        cfg = self.config
        self.stats.keyframes += 1
        if not cfg.enabled:
            return None
        in_map = sum(1 for k in self._keyframes.values() if k.map_id == keyframe.map_id)
        if in_map <= cfg.min_keyframes_in_map or keyframe.id < self._last_loop_kf_id + cfg.min_keyframes_between_loops:
            return None
        # 2. candidates scoring at least as well as the worst covisible neighbour
        self.stats.queries += 1
        connected = [k for k in neighbours(covisibility, keyframe.id) if k in self.database]
        bow = self.database.bow(keyframe.id)
        scores = [l1_score(bow, self.database.bow(k)) for k in connected]
        min_score = max(min(scores) if scores else 0.0, cfg.min_score_floor)
        candidates = self.database.loop_candidates(keyframe.id, connected, min_score, covisibility)
        if not candidates:
            self._consistency.reset()
            return None
        # 3. temporal consistency of candidate groups
        self.stats.with_candidates += 1
        consistent = self._consistency.update(candidates, covisibility)
        consistent = sorted(consistent, key=lambda c: (-c.accumulated_score, c.keyframe_id))
        # 4. geometric verification
        for cand in consistent[: cfg.max_verified_candidates]:
            match = self._keyframes.get(cand.keyframe_id)
            if match is None:
                continue
            v = verify(match, keyframe, cfg.verification, self._masks[match.id], self._masks[keyframe.id])
            self.stats.verified += 1
            if v is not None:
                drift = self._drift_check(match, keyframe, v)
                self.last_drift_check = drift
                if not drift.accepted:
                    self.stats.rejected_drift += 1
                    v = None
            self.stats.rejected += int(v is None)
            if v is not None:
                self.stats.loops += 1
                correction = self._correct(keyframe, match, v, covisibility, spanning_parent, point_positions,
                                           point_reference_kf)
                self._loop_edges.append((match.id, keyframe.id))  # as ORB-SLAM, only the pair is kept
                self._last_loop_kf_id = keyframe.id
                self._consistency.reset()
                return correction
        return None

    def _drift_check(self, match: Keyframe, query: Keyframe, v: Verification) -> DriftCheck:
        """The verified loop against the drift expected over the path from `match` to `query` (held keyframes of
        their map, in id order: the trajectory between them as currently estimated)."""
        lo, hi = sorted((match.id, query.id))
        chain = [self._keyframes[k].T_world_cam for k in sorted(self._keyframes)
                 if lo <= k <= hi and self._keyframes[k].map_id == query.map_id]
        path_m, turn_deg = path_travelled(chain)
        T_est = invert(match.T_world_cam) @ query.T_world_cam
        return check_drift(T_est, v.T_a_b, path_m, turn_deg, self.config.drift_gate)

    def _correct(
        self,
        query: Keyframe,
        match: Keyframe,
        v: Verification,
        covisibility: Covisibility,
        spanning_parent: Mapping[int, int | None],
        point_positions: Mapping[int, F64],
        point_reference_kf: Mapping[int, int] | None,
    ) -> LoopCorrection:
        map_id = query.map_id
        before = {k: kf.T_world_cam.copy() for k, kf in self._keyframes.items() if kf.map_id == map_id}
        # 5a. the loop says where the query really is; move it and its covisible neighbours rigidly
        T_world_query = before[match.id] @ v.T_a_b
        shift = T_world_query @ invert(before[query.id])
        initial = dict(before)
        for k in [query.id, *neighbours(covisibility, query.id)]:
            if k in initial:
                initial[k] = shift @ before[k]
        # 5b. essential graph measured on the poses before the correction, plus every loop edge
        parents = {c: p for c, p in spanning_parent.items() if c in before}
        cov = {k: covisibility[k] for k in before if k in covisibility}
        edges: list[PoseGraphEdge] = essential_graph_edges(before, parents, cov, self.config.pose_graph.min_covisibility_weight)
        edges += relative_edges(before, [e for e in self._loop_edges if e[0] in before and e[1] in before], EdgeKind.LOOP)
        edges.append(PoseGraphEdge(match.id, query.id, v.T_a_b, EdgeKind.LOOP))
        # 5c. ORB-SLAM's loop connections: every keyframe around the query (already moved) is tied to every
        #     keyframe around the match. One edge alone would lose against the chain plus its parallel
        #     covisibility edges and leave part of the drift in the loop.
        query_side = [k for k in [query.id, *neighbours(covisibility, query.id)] if k in before]
        match_side = [k for k in [match.id, *neighbours(covisibility, match.id, self.config.covisibility_group_size)]
                      if k in before and k not in query_side]
        for m in match_side:
            for q in query_side:
                if (m, q) != (match.id, query.id):
                    edges.append(PoseGraphEdge(m, q, invert(before[m]) @ initial[q], EdgeKind.LOOP))
        origin = min(before)
        after = optimise_pose_graph(initial, edges, origin, self.config.pose_graph)
        # 5d. map points follow their reference keyframe
        refs = dict(point_reference_kf) if point_reference_kf is not None else self._reference_keyframes(point_positions)
        points = correct_points(point_positions, refs, before, after)
        fused = self._fused_points(match, query, v.matches)
        return LoopCorrection(
            query_kf_id=query.id,
            match_kf_id=match.id,
            map_id=map_id,
            T_match_query=v.T_a_b,
            num_inliers=v.num_inliers,
            keypoint_matches=v.matches,
            corrected_poses=after,
            corrected_points=points,
            fused_points=fused,
            pose_corrections={k: after[k] @ invert(before[k]) for k in before},
        )

    def _reference_keyframes(self, point_positions: Mapping[int, F64]) -> dict[int, int]:
        refs: dict[int, int] = {}
        for kf_id in sorted(self._keyframes):
            kf = self._keyframes[kf_id]
            for pid in kf.point_ids[kf.point_ids >= 0].tolist():
                if pid not in refs and pid in point_positions:
                    refs[pid] = kf_id
        return refs

    @staticmethod
    def _fused_points(match: Keyframe, query: Keyframe, matches: npt.NDArray[np.int64]) -> list[tuple[int, int]]:
        out = []
        for i_m, i_q in matches.tolist():
            pm, pq = int(match.point_ids[i_m]), int(query.point_ids[i_q])
            if pm >= 0 and pq >= 0 and pm != pq:
                out.append((pq, pm))
        return out

    # ------------------------------------------------------------------ map merging
    def detect_merge(self, keyframe: Keyframe, covisibility: Covisibility) -> MapMerge | None:
        """Does an (already added) keyframe show a place of another map? Same steps as a loop: database
        candidates from other maps, consistency over `consistency_threshold` keyframes, verification.
        The caller (the Atlas owner) merges the maps with `T_matchworld_queryworld`."""
        if keyframe.id not in self._keyframes:
            self.add(keyframe)
        candidates = self.database.merge_candidates(keyframe.id, covisibility)
        if not candidates:
            self._merge_consistency.reset()
            return None
        consistent = self._merge_consistency.update(candidates, covisibility)
        for cand in sorted(consistent, key=lambda c: (-c.accumulated_score, c.keyframe_id))[
            : self.config.max_verified_candidates
        ]:
            match = self._keyframes.get(cand.keyframe_id)
            if match is None:
                continue
            v = verify(match, keyframe, self.config.verification, self._masks[match.id], self._masks[keyframe.id])
            if v is None:
                continue
            self._merge_consistency.reset()
            return MapMerge(
                query_kf_id=keyframe.id,
                match_kf_id=match.id,
                query_map_id=keyframe.map_id,
                match_map_id=match.map_id,
                T_match_query=v.T_a_b,
                T_matchworld_queryworld=match.T_world_cam @ v.T_a_b @ invert(keyframe.T_world_cam),
                num_inliers=v.num_inliers,
                keypoint_matches=v.matches,
            )
        return None

    def set_map(self, kf_id: int, map_id: int) -> None:
        """Record that a keyframe now belongs to another map (after a merge)."""
        kf = self._keyframes.get(kf_id)
        if kf is not None:
            kf.map_id = map_id
        self.database.set_map(kf_id, map_id)

    # ------------------------------------------------------------------ relocalisation
    def relocalise(
        self,
        keypoints_px: npt.NDArray[np.floating],
        descriptors: npt.NDArray[np.uint8],
        camera: CameraIntrinsics,
        point_positions: Mapping[int, F64],
        covisibility: Covisibility,
        map_id: int | None = None,
        active_mask: npt.NDArray[np.bool_] | None = None,
    ) -> Relocalisation | None:
        """Pose of a lost frame against the held keyframes (see `place_recognition.relocalise`)."""
        return relocalise(
            keypoints_px, descriptors, camera, self.database, self._keyframes, point_positions, covisibility,
            self.config.relocalisation, map_id, active_mask,
        )


# ---------------------------------------------------------------------- binding to the offline map
class SlamMapLoopClosing:
    """`LoopCloser` bound to `core.slam_map.SlamMap`, the offline runner's map. It fits both seams of
    `core.system.SlamSystem`: `process(kf, slam_map) -> bool` (loop_closer) and `add` / `erase` /
    `candidates(frame, slam_map)` (keyframe_index), so one object serves as both:

        closing = SlamMapLoopClosing(LoopCloser(config.loop, Vocabulary.load()))
        SlamSystem(config, loop_closer=closing, keyframe_index=closing)

    On a loop it applies the correction to the map: keyframe poses, point positions and normals, fusion of
    the duplicated points, the loop edge, and fresh covisibility links around the query; then, when given a
    `GlobalBAConfig`, a global bundle adjustment (`backend.global_ba`). The latest
    correction is kept in `last_correction` (tracking moves its last frame with `pose_corrections`).
    For the Atlas, `detect_merge_in(kf, atlas)` looks for a place of another map and `maps_merged` moves the
    database entries after `SlamSystem` applied the merge (`core.map_merging`).
    """

    def __init__(self, closer: LoopCloser, max_candidates: int = 6, global_ba: GlobalBAConfig | None = None) -> None:
        self.closer = closer
        self.max_candidates = max_candidates
        self.global_ba = global_ba  # None: no global BA after a loop
        self.last_correction: LoopCorrection | None = None
        self.last_global_ba: GlobalBAResult | None = None

    # keyframe index seam
    def add(self, kf: Keyframe) -> None:
        self.closer.add(kf)

    def erase(self, kf_id: int) -> None:
        self.closer.erase(kf_id)

    def candidates(self, frame: Frame, slam_map: SlamMap) -> list[int]:
        """Relocalisation candidates of `frame` among `slam_map`'s keyframes, best first."""
        db = self.closer.database
        bow = db.vocabulary.transform(frame.features.descriptors).bow
        found = db.relocalisation_candidates(bow, slam_map.covisibility, slam_map.id)
        ranked = sorted(found, key=lambda c: (-c.score, c.keyframe_id))
        return [c.keyframe_id for c in ranked if c.keyframe_id in slam_map.keyframes][: self.max_candidates]

    def refresh_active_points(self, slam_map: SlamMap) -> int:
        """Re-index the map's keyframes whose features see points deactivated (or reactivated) since they were
        indexed; call after object states change. Returns how many keyframes were re-indexed."""
        n = 0
        for kf_id, kf in slam_map.keyframes.items():
            if kf_id in self.closer.keyframes:
                n += int(self.closer.set_active_mask(kf_id, _active_mask(kf, slam_map.points)))
        return n

    # map merging seam (`core.system.SlamSystem` applies the merge with `core.map_merging.merge_maps`)
    def detect_merge_in(self, kf: Keyframe, atlas: Atlas) -> MapMerge | None:
        """Does keyframe `kf` of the current map show a place of another map of `atlas`? (`LoopCloser.detect_merge`)"""
        return self.closer.detect_merge(kf, ChainMap(*(m.covisibility for m in atlas.maps)))

    def maps_merged(self, moved_keyframes: Iterable[int], into_map_id: int) -> None:
        """Keyframes now belong to map `into_map_id` (after a merge): the database follows."""
        for k in moved_keyframes:
            self.closer.set_map(k, into_map_id)

    # loop closer seam
    def process(self, kf: Keyframe, slam_map: SlamMap) -> bool:
        """Close a loop through `kf` if there is one (`find_loop`) and write it into the map (`apply_loop`)."""
        correction = self.find_loop(kf, slam_map)
        if correction is None:
            return False
        self.apply_loop(slam_map, correction)
        return True

    def find_loop(self, kf: Keyframe, slam_map: SlamMap) -> LoopCorrection | None:
        """The loop through `kf`, or None; reads the map and changes only the closer's own state (its index,
        consistency groups, loop edges): the map is as it was until `apply_loop`."""
        # keyframes culled from the map without `erase` (when this object is not also the keyframe index)
        gone = [k for k, held in self.closer.keyframes.items() if held.map_id == slam_map.id and k not in slam_map.keyframes]
        for k in gone:
            self.closer.erase(k)
        points = slam_map.points
        return self.closer.process(
            kf, slam_map.covisibility, slam_map.parent, _PointPositions(points), _active_mask(kf, points),
            _ReferenceKeyframes(points),
        )

    def apply_loop(self, slam_map: SlamMap, correction: LoopCorrection) -> None:
        """Write a correction from `find_loop` into the map (then global BA when configured)."""
        apply_correction(slam_map, correction)
        if self.global_ba is not None:
            self.last_global_ba = global_bundle_adjust(slam_map, self.global_ba)
        self.closer.update_poses({k: held.T_world_cam for k, held in slam_map.keyframes.items()})
        self.last_correction = correction


def _active_mask(kf: Keyframe, points: PointStore) -> npt.NDArray[np.bool_]:
    """Keypoints usable for place recognition: `loop_feature_mask`, minus those on inactive map points
    (Changing-SLAM: points of objects that left the scene take no part)."""
    mask = loop_feature_mask(kf)
    seen = kf.point_ids >= 0
    mask[seen] &= points.active[kf.point_ids[seen]]
    return mask


def apply_correction(slam_map: SlamMap, correction: LoopCorrection) -> None:
    """Write a `LoopCorrection` into a `SlamMap`: poses, points (positions, normals), fusion, loop edge, links."""
    for kf_id, T in correction.corrected_poses.items():
        if kf_id in slam_map.keyframes:
            slam_map.keyframes[kf_id].T_world_cam = np.asarray(T, np.float64)
    points = slam_map.points
    if correction.corrected_points:
        ids = np.fromiter(correction.corrected_points.keys(), np.int64, len(correction.corrected_points))
        points.positions[ids] = np.stack(list(correction.corrected_points.values()))
        refs = points.ref_kf[ids]
        for ref in np.unique(refs).tolist():
            corr = correction.pose_corrections.get(ref)
            if corr is not None:
                sel = ids[refs == ref]
                points.normals[sel] = points.normals[sel] @ corr[:3, :3].T
    touched = {correction.query_kf_id}
    usable = points.usable()
    for dup, keep in correction.fused_points:
        if dup == keep or not (usable[dup] and usable[keep]):
            continue
        for kf_id, idx in list(points.observations[dup].items()):
            kf = slam_map.keyframes.get(kf_id)
            if kf is None:
                continue
            if kf_id in points.observations[keep]:
                kf.point_ids[idx] = -1
            else:
                slam_map.add_observation(keep, kf_id, idx)
            touched.add(kf_id)
        points.observations[dup] = {}
        points.set_bad(np.array([dup]))
    slam_map.loop_edges.setdefault(correction.match_kf_id, set()).add(correction.query_kf_id)
    slam_map.loop_edges.setdefault(correction.query_kf_id, set()).add(correction.match_kf_id)
    for kf_id in sorted(touched):
        if kf_id in slam_map.keyframes:
            slam_map.update_connections(kf_id)


class _PointPositions(Mapping[int, F64]):
    """Read-only id -> world position (3,) view of a PointStore's usable points (no copy)."""

    def __init__(self, points: PointStore) -> None:
        self._points = points
        self._usable = points.usable()

    def __getitem__(self, pid: int) -> F64:
        if not 0 <= pid < len(self._usable) or not self._usable[pid]:
            raise KeyError(pid)
        position: F64 = self._points.positions[pid]
        return position

    def __iter__(self) -> Iterator[int]:
        return iter(np.flatnonzero(self._usable).tolist())

    def __len__(self) -> int:
        return int(self._usable.sum())


class _ReferenceKeyframes(Mapping[int, int]):
    """Read-only id -> reference keyframe id view of a PointStore."""

    def __init__(self, points: PointStore) -> None:
        self._points = points

    def __getitem__(self, pid: int) -> int:
        if not 0 <= pid < self._points.size:
            raise KeyError(pid)
        return int(self._points.ref_kf[pid])

    def __iter__(self) -> Iterator[int]:
        return iter(range(self._points.size))

    def __len__(self) -> int:
        return self._points.size
