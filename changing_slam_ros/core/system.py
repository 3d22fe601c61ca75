"""The SLAM system: features -> tracking -> local mapping -> loop closing, deterministically per frame.

This is the offline wiring of the same components the ROS nodes wrap. Every frame is fully
processed before the next one (a keyframe is mapped, bundle-adjusted and offered to loop closing
before tracking sees the next frame), so a run is reproducible for a given config.

Trajectories: the *online* pose is what tracking estimated for the frame at the time; the *final*
pose is re-expressed from the frame's reference keyframe after all optimisation
(T_world_cam = T_world_ref(final) @ T_ref_cam), as ORB-SLAM saves its trajectory. With late detections (real
time) and `tracking.deferred_refinement` on, a frame's T_ref_cam is replaced by its refined pose once the detection
sets around it are in (`refine_with_detections`, `core.deferred_refinement`); the online pose stays.
"""

from __future__ import annotations

import time
from collections import defaultdict
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

import cv2
import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.dynamic.deferred_refinement import DeferredRefinement, RefinedPose, TrackedFrameMatches
from changing_slam_ros.core.dynamic.detector import Detection, DetectionSet
from changing_slam_ros.core.dynamic.dynamic_filter import DynamicFilter, DynamicFrame
from changing_slam_ros.core.features.frame import Frame
from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.map.keyframe_grid import keyframe_scan, map_grid, object_views
from changing_slam_ros.core.map.occupancy_grid import GridConfig, OccupancyGrid
from changing_slam_ros.core.map.floor_start import FloorStart, level_first_pose
from changing_slam_ros.core.slam.local_mapping import LocalMapper, MappingConfig, MappingStats
from changing_slam_ros.core.slam.initial_pose import PoseHint
from changing_slam_ros.core.slam.localization import Mode, Sightings
from changing_slam_ros.core.slam.loop_closing import MapMerge
from changing_slam_ros.core.slam.map_merging import MergeResult, merge_maps, move_frame
from changing_slam_ros.core.objects.map_object import MapObject
from changing_slam_ros.core.objects.object_evidence import keyframe_thumbnail
from changing_slam_ros.core.objects.object_layer import ObjectLayer, ObjectLayerResult, SavedObjectMap
from changing_slam_ros.core.recent_values import RecentValues
from changing_slam_ros.core.features.orb_features import FeatureConfig, Features, OrbExtractor
from changing_slam_ros.core.geometry.pose_optimizer import PinholeStereo
from changing_slam_ros.core.features.rgbd_frame import RgbdFrame
from changing_slam_ros.core.geometry.se3 import invert
from changing_slam_ros.core.map.slam_map import Atlas, SlamMap
from changing_slam_ros.core.slam.frame_records import FrameRecords
from changing_slam_ros.core.slam.tracking import KeyframeCandidates, Tracker, TrackingState, TrackResult
from changing_slam_ros.core.slam.tracking_config import TrackingConfig
from changing_slam_ros.core.geometry.trajectory import Trajectory
from changing_slam_ros.errors import ConfigError

F64 = npt.NDArray[np.float64]


class LoopCloser(Protocol):
    """The seam for the loop-closing component: offered every new keyframe after local mapping.

    Returns True when it corrected the map (keyframe poses and points moved).
    """

    def process(self, kf: Keyframe, slam_map: SlamMap) -> bool: ...


class KeyframeIndex(KeyframeCandidates, Protocol):
    """A keyframe database (bag-of-words): fed every keyframe, asked for relocalisation candidates."""

    def add(self, kf: Keyframe) -> None: ...

    def erase(self, kf_id: int) -> None: ...


@dataclass(frozen=True)
class SystemConfig:
    """The YAML sections this system reads: `features`, `tracking`, `mapping`, `grid` (parsed at the edge)."""

    features: FeatureConfig = field(default_factory=FeatureConfig)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    mapping: MappingConfig = field(default_factory=MappingConfig)
    grid: GridConfig = field(default_factory=GridConfig)


@dataclass
class FrameOutput:
    """What `SlamSystem.process` returns for one frame."""

    state: TrackingState
    T_world_cam: F64 | None
    n_inliers: int
    n_keypoints: int
    keyframe: Keyframe | None
    mapping: MappingStats | None
    loop_corrected: bool
    timings_ms: dict[str, float]
    dynamic: DynamicFrame | None = None  # the dynamic filter's verdict on the frame's keypoints (before subsetting)
    objects: ObjectLayerResult | None = None  # the object layer's work on this frame's new keyframe
    relocalised: bool = False  # tracking was lost and found the map again on this frame (the pose jumps)
    new_map: bool = False  # this frame started a new map in the Atlas (poses from here are in its frame)
    objects_seen: tuple[int, ...] = ()  # localisation: MapObjects present at their mapped place (`Sightings`)


class SlamSystem:
    """Feed `RgbdFrame`s in order with `process`; read trajectories and timings afterwards."""

    def __init__(
        self,
        config: SystemConfig | None = None,
        loop_closer: LoopCloser | None = None,
        keyframe_index: KeyframeIndex | None = None,
        dynamic_filter: DynamicFilter | None = None,
        object_layer: ObjectLayer | None = None,
    ) -> None:
        self.config = config or SystemConfig()
        cv2.setNumThreads(1)
        cv2.setRNGSeed(0)
        self.atlas = Atlas()
        self.tracker = Tracker(self.atlas, self.config.features, self.config.tracking, keyframe_index)
        self.mapper = LocalMapper(self.atlas, self.config.features, self.config.mapping)
        self.loop_closer = loop_closer
        self.keyframe_index = keyframe_index
        self.dynamic_filter = dynamic_filter
        self.object_layer = object_layer  # MapObjects and beliefs (Changing-SLAM §4); None = every point stays active
        self._extractor: OrbExtractor | None = None
        self._camera: CameraIntrinsics | None = None
        self.records = FrameRecords()  # one per frame, for the trajectories written at the end
        self.timings_ms: dict[str, RecentValues] = defaultdict(RecentValues)  # per stage, the recent frames' ms
        self.n_loops = 0
        self.n_withheld_used = 0  # frames that tracked with an undecided object's keypoints (`map_view_min_matches`)
        self.merges: list[MergeResult] = []
        refine = self.config.tracking.deferred_refinement
        self.n_forgotten_points = 0
        self.owns_map = True  # False on tracking's replica in the split graph: the map owner edits the map
        self._flag_counts: dict[int, dict[int, int]] = {}  # map id -> point id -> frames its keypoint was flagged
        self.refinement: DeferredRefinement | None = None  # real time with late detections: final poses refined
        if refine.enabled and dynamic_filter is not None:
            self.refinement = DeferredRefinement(refine, dynamic_filter.config.tracker_config().classification)
        self.mode = Mode.MAPPING
        self.sightings = Sightings()  # localisation: the map's objects seen at their mapped place, per frame
        self.loaded_objects: dict[int, list[MapObject]] = {}  # localisation from a saved map: its objects, as saved
        self.keep_grid_scans = self.config.grid.enabled  # new keyframes keep a depth scan for the occupancy grid
        # `tracking.level_from_floor`: the first pose from the floor in view, unless a first pose or a map is given
        self._level_pending = self.config.tracking.level_from_floor
        self.floor_start: FloorStart | None = None  # the floor the map was levelled on

    def set_mode(self, mode: Mode) -> None:
        """`Mode.LOCALIZATION`: from the next frame on the map is only read (`core/slam/localization.py`);
        needs a map with keyframes. `Mode.MAPPING`: SLAM again (a lost tracker may then start a new map)."""
        if mode is Mode.LOCALIZATION and self.atlas.n_keyframes == 0:
            raise ConfigError("localization mode needs a map: load one (--map-in / map_file) or map first")
        self.mode = mode
        self.tracker.localization = mode is Mode.LOCALIZATION

    def set_pose_hint(self, hint: PoseHint | None) -> None:
        """Relocalise near `hint` (an initial pose in the current map, `core/slam/initial_pose.py`) from the next
        frame on; None drops it. Needs a map with keyframes."""
        if hint is not None and not self.atlas.current.keyframes:
            raise ConfigError("initial pose: no map to relocalise in (load a map or map first)")
        self.tracker.set_pose_hint(hint)

    def set_first_pose(self, T_world_cam: F64) -> None:  # noqa: N803
        """Where the first camera sits in the world frame the map is built in (identity unless set: the world is
        the first camera's optical frame). A robot sets its camera mounting `T_base_cam` here, so the world is the
        base's frame at the start: z up when the base stands level, as REP-105 wants of `map` and as Nav2 reads an
        occupancy grid (x, y and yaw only). Before the first keyframe (not with a loaded map, whose frame stays);
        later maps of the Atlas start where the last one left off, in this same frame."""
        if self.atlas.n_keyframes:
            raise RuntimeError("set_first_pose must be called before the first keyframe")
        T = np.asarray(T_world_cam, np.float64)  # noqa: N806
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ConfigError(f"first pose: expected a finite 4x4 pose, got shape {T.shape}")
        self.tracker.last_good_pose = T.copy()
        self._level_pending = False  # a given mounting wins over the floor

    def _level_on_floor(self, rgbd: RgbdFrame) -> None:
        """Before the first keyframe: start the map level on the floor in view (`core.map.floor_start`); tried on
        each frame until one starts the map, which stays in the optical frame when none showed a floor."""
        start = level_first_pose(rgbd.depth_m, rgbd.camera)
        if start is not None:
            self.tracker.last_good_pose = start.T_floor_cam.copy()
            self.floor_start = start
        elif self.floor_start is not None:  # an earlier frame's floor, not this one's: back to the optical frame
            self.tracker.last_good_pose = np.eye(4)
            self.floor_start = None

    def start_from_map(self, atlas: Atlas, next_keyframe_id: int,
                       objects: dict[int, SavedObjectMap] | None = None, mode: Mode = Mode.MAPPING) -> None:
        """Multi-session: continue a saved Atlas (`io.map_file.load_map`) before the first frame. The keyframe
        index gets every loaded keyframe (bag-of-words rebuilt from its descriptors, inactive points masked),
        tracking relocalises against `atlas.current` first (`TrackingConfig.loaded_map_grace_s`), and the object
        layer starts from the saved objects and beliefs. Poses stay in the loaded map's frame.
        `Mode.LOCALIZATION`: the map is only read from the first frame on; the saved objects are kept as they are
        (`loaded_objects`, for `sightings`) instead of starting a new object-layer session, which would decay
        their beliefs and the active flags of their points."""
        if self.records:
            raise RuntimeError("start_from_map must be called before the first frame")
        self.atlas.adopt(atlas)
        self._level_pending = False  # poses stay in the loaded map's frame
        if mode is Mode.LOCALIZATION:
            self.loaded_objects = {map_id: list(saved.objects) for map_id, saved in (objects or {}).items()}
        elif self.object_layer is not None and self.object_layer.enabled:  # first: it may deactivate points
            for map_id, saved in (objects or {}).items():
                self.object_layer.load_objects(map_id, saved, next_keyframe_id, self.atlas.maps[map_id].points)
        refresh = getattr(self.loop_closer, "refresh_active_points", None)
        for m in self.atlas.maps:
            if self.keyframe_index is not None:
                for kf_id in sorted(m.keyframes):
                    self.keyframe_index.add(m.keyframes[kf_id])
            if refresh is not None:
                refresh(m)
        self.tracker.start_from_map(next_keyframe_id)
        self.set_mode(mode)

    def map_objects(self, map_id: int) -> list[MapObject]:
        """The MapObjects of a map: as loaded for localisation, else the object layer's."""
        if map_id in self.loaded_objects:
            return self.loaded_objects[map_id]
        return [] if self.object_layer is None else self.object_layer.objects(map_id)

    def _extractor_for(self, camera: CameraIntrinsics) -> OrbExtractor:
        if self._extractor is None or camera != self._camera:
            self._extractor = OrbExtractor(self.config.features, camera)
            self._camera = camera
        return self._extractor

    def process(self, rgbd: RgbdFrame, detections: tuple[Detection, ...] | list[Detection] | None = None) -> FrameOutput:
        t0 = time.perf_counter()
        feats = self._extractor_for(rgbd.camera).extract(rgbd.rgb, rgbd.depth_m)
        t1 = time.perf_counter()
        dyn = None
        n_depth = -1
        if self.dynamic_filter is not None:  # drop keypoints on people and moving objects before tracking
            dyn = self.dynamic_filter.before_tracking(rgbd, feats, detections)
            dyn = self._withheld_seeing_map(rgbd, feats, dyn)
            n_depth = int(np.count_nonzero(feats.depths_m > 0))
            feats = feats.subset(dyn.keep)
            self.timings_ms["dynamic"].append(dyn.ms)
            self._forget(dyn.moving_points)
        frame = Frame(rgbd.stamp_ns, len(self.records), rgbd.camera, feats,  # own counter: input order
                      n_depth_extracted=n_depth)
        if self._level_pending and not self.atlas.n_keyframes:
            self._level_on_floor(rgbd)
        res: TrackResult = self.tracker.track(frame)
        if dyn is not None:
            self._after_dynamic(dyn, res, frame)
            if (self.object_layer is not None and res.state == TrackingState.OK and res.new_keyframe is None
                    and self.object_layer.wants_keyframe(self.atlas.current.id, dyn.objects, res.T_world_cam, rgbd.camera)):
                self.tracker.request_keyframe()  # an object the map has not seen: a keyframe soon, while in view
        self._record(frame, res)  # relative to the reference keyframe, before mapping moves it
        seen: list[int] = []
        if self.mode is Mode.LOCALIZATION and res.state == TrackingState.OK:
            seen = self.sightings.update(frame.stamp_ns, res.T_world_cam, rgbd.camera, rgbd.depth_m,
                                         self.map_objects(self.atlas.current.id))  # fmt: skip
        if self.refinement is not None:
            self._keep_for_refinement(frame, rgbd, res)
        t2 = time.perf_counter()
        stats = None
        corrected = False
        if res.new_keyframe is not None:
            stats = self.mapper.process(res.new_keyframe)
            if self.keyframe_index is not None:
                for k in stats.culled_keyframes:
                    self.keyframe_index.erase(k)
                self.keyframe_index.add(res.new_keyframe)
        objects = None
        if res.new_keyframe is not None and self.object_layer is not None and res.new_keyframe.id in self.atlas.current.keyframes:
            objects = self._after_objects(res.new_keyframe, rgbd, dyn)
        if res.new_keyframe is not None and self.keep_grid_scans and res.new_keyframe.id in self.atlas.current.keyframes:
            self.keep_grid_scan(res.new_keyframe, rgbd.depth_m, dyn.objects if dyn is not None else (), objects)
        t3 = time.perf_counter()
        if res.new_keyframe is not None and self.loop_closer is not None and res.new_keyframe.id in self.atlas.current.keyframes:
            corrected = bool(self.loop_closer.process(res.new_keyframe, self.atlas.current))
            self.n_loops += int(corrected)
        if res.new_keyframe is not None and not corrected and len(self.atlas.live_maps()) > 1:
            self._try_merge(res.new_keyframe)
        t4 = time.perf_counter()
        if res.new_keyframe is not None:
            self._reanchor_last_frame()
        timings = {
            "features": (t1 - t0) * 1e3,
            "tracking": (t2 - t0) * 1e3,  # includes feature extraction, as ORB-SLAM reports it
            "local_mapping": (t3 - t2) * 1e3,
            "loop_closing": (t4 - t3) * 1e3,
            "total": (t4 - t0) * 1e3,
        }
        for k, v in timings.items():
            self.timings_ms[k].append(v)
        if res.new_keyframe is not None:
            self.timings_ms["local_mapping_per_keyframe"].append(timings["local_mapping"])
        return FrameOutput(res.state, res.T_world_cam, res.n_inliers, len(feats), res.new_keyframe, stats, corrected, timings, dyn,
                           objects, relocalised=res.relocalised, new_map=res.new_map, objects_seen=tuple(seen))

    def _withheld_seeing_map(self, rgbd: RgbdFrame, feats: Features, dyn: DynamicFrame) -> DynamicFrame:
        """`dyn` with its withheld keypoints (undecided objects) kept when the kept ones alone match fewer than
        `dynamic.map_view_min_matches` map points at the predicted pose and the withheld ones make up the count
        with points the map held before their object was first detected (`DynamicConfig`)."""
        need = self.dynamic_filter.config.map_view_min_matches if self.dynamic_filter is not None else 0
        if need <= 0 or dyn.withheld is None or dyn.withheld_since_ns is None or self.tracker.state != TrackingState.OK:
            return dyn
        idx = len(self.records)
        kept, _ = self.tracker.matches_at_prediction(Frame(rgbd.stamp_ns, idx, rgbd.camera, feats.subset(dyn.keep)))
        if len(kept) >= need:
            return dyn
        rows = np.flatnonzero(dyn.withheld)
        kp, pid = self.tracker.matches_at_prediction(Frame(rgbd.stamp_ns, idx, rgbd.camera, feats.subset(dyn.withheld)))
        if len(kept) + len(kp) < need:
            return dyn
        # A point born in a keyframe no later than the last one before the object's first detection was the room
        # (or the still object) before the box came; one mapped since may lie on the object itself.
        kfs = self.atlas.current.keyframes
        kf_ids = np.fromiter(kfs, np.int64, len(kfs))
        stamps = np.array([kfs[k].stamp_ns for k in kf_ids.tolist()], np.int64)
        since = dyn.withheld_since_ns[rows[kp]]
        last_before = np.full(len(kp), -1, np.int64)
        for s in np.unique(since).tolist():
            earlier = kf_ids[stamps < s]
            last_before[since == s] = earlier.max() if len(earlier) else -1
        old = np.asarray(self.atlas.current.points.first_kf[pid]) <= last_before
        if len(kept) + int(np.count_nonzero(old)) < need:
            return dyn
        self.n_withheld_used += 1
        self.dynamic_filter.withheld_used(dyn)
        return replace(dyn, keep=dyn.keep | dyn.withheld)

    def _try_merge(self, kf: Keyframe) -> None:
        """A place of an older map seen from the current one: weld the maps (`map_merging`); frame records,
        tracking's last frame, local mapping's recent points and the keyframe database follow."""
        detect = getattr(self.loop_closer, "detect_merge_in", None)
        if detect is None or not self.config.mapping.merge.enabled or kf.id not in self.atlas.current.keyframes:
            return
        merge = detect(kf, self.atlas)
        if merge is None:
            return
        result = self.apply_merge(merge)
        self.loop_closer.maps_merged(result.moved_keyframes, result.into_map_id)  # type: ignore[union-attr]
        self.follow_merge(result)

    def apply_merge(self, merge: MapMerge) -> MergeResult:
        """The map owner's part of a merge: weld the maps (`map_merging.merge_maps`) and move local mapping's
        recent points. (The split graph's map owner calls this too: `nodes.split_backend.MapOwner`.)"""
        result = merge_maps(self.atlas, merge, self.mapper.scales, self.config.features.bf_m_px,
                            self.config.mapping.merge, self.mapper.ba_config())
        self.mapper.points_moved(result.from_map_id, result.into_map_id, result.point_id_offset)
        if self.object_layer is not None:  # the merged-away map's objects move with its keyframes
            self.object_layer.maps_merged(result.from_map_id, result.into_map_id, result.T_into_from,
                                          result.point_id_offset, self.atlas.maps[result.into_map_id].points)
        self.atlas.maps[result.into_map_id].order_spanning_tree()  # the order replicas rebuild
        return result

    def follow_merge(self, result: MergeResult) -> None:
        """Tracking's part of a merge the Atlas went through: frame records of the merged-away map name the
        merged one, the last frame (pose, point ids) and the last good pose move into it. (The split graph's
        tracking calls this on the owner's merge update: `nodes.split_backend.TrackingSide`.)"""
        self.records.rename_map(result.from_map_id, result.into_map_id)
        if self.tracker.last_frame is not None:
            move_frame(self.tracker.last_frame, result)
        self.tracker.last_good_pose = result.T_into_from @ self.tracker.last_good_pose
        self.merges.append(result)

    def _after_objects(self, kf: Keyframe, rgbd: RgbdFrame, dyn: DynamicFrame | None) -> ObjectLayerResult:
        """The object layer on a mapped keyframe (before loop closing, so that it sees the points this keyframe
        deactivated); the loop closer re-indexes keyframes whose points changed state."""
        assert self.object_layer is not None
        out = self.object_layer.after_keyframe(kf, self.atlas.current, rgbd.depth_m, dyn.objects if dyn is not None else (),
                                               thumbnail=_thumbnail(rgbd))
        refresh = getattr(self.loop_closer, "refresh_active_points", None)
        if out.active_flags_changed and refresh is not None:
            refresh(self.atlas.current)
        self.timings_ms["objects_per_keyframe"].append(out.ms)
        return out

    def keep_grid_scan(self, kf: Keyframe, depth_m: npt.NDArray[np.floating] | None, short_term_objects: Any,
                       layer_result: ObjectLayerResult | None) -> None:
        """A mapped keyframe keeps its depth scan for the occupancy grid (`core.map.keyframe_grid`), its points
        labelled with the dynamic objects and the MapObjects the object layer just gave them."""
        objs = {o.id: o for o in self.map_objects(kf.map_id)}
        kf.grid_scan = keyframe_scan(kf, depth_m, self.config.grid, short_term_objects,
                                     object_views(layer_result, objs))

    def occupancy_grid(self, map_id: int | None = None) -> OccupancyGrid | None:
        """The occupancy grid of a map (the current one by default) from its keyframes' scans at their current poses
        and its objects' current beliefs; None when no keyframe keeps a scan."""
        m = self.atlas.current if map_id is None else self.atlas.maps[map_id]
        return map_grid(m, self.config.grid, self.map_objects(m.id))

    def _forget(self, moving_points: tuple[tuple[int, npt.NDArray[np.int64]], ...]) -> None:
        """Map points that earlier frames matched to keypoints found on a mover, in `forget_moving_points`
        frames, leave the map (their observations too) before tracking could match them again."""
        if not self.owns_map:
            return
        m = self.atlas.current
        assert self.dynamic_filter is not None
        need = self.dynamic_filter.config.forget_moving_points
        for map_id, ids in moving_points:
            if map_id != m.id:
                continue
            ids = np.unique(ids[ids < m.points.size])
            counts = self._flag_counts.setdefault(map_id, {})
            for pid in ids[~m.points.bad[ids]].tolist():
                counts[pid] = counts.get(pid, 0) + 1
                if counts[pid] >= need:
                    m.erase_point(pid)
                    del counts[pid]  # a bad point is never counted again
                    self.n_forgotten_points += 1

    def _after_dynamic(self, dyn: DynamicFrame, res: TrackResult, frame: Frame) -> None:
        """The object EKFs get the tracked pose and the map points tracking matched (in the frame's full keypoint
        order); a new keyframe keeps its keypoints' classes and object ids."""
        assert self.dynamic_filter is not None
        ok = res.state == TrackingState.OK
        ids = None
        if ok and self.dynamic_filter.config.forget_moving_points > 0:  # only forgetting reads them
            ids = np.full(len(dyn.keep), -1, np.int64)
            ids[np.flatnonzero(dyn.keep)] = np.where(frame.outliers, -1, frame.point_ids)
        self.dynamic_filter.after_tracking(res.T_world_cam if ok else None, ids, self.atlas.current.id)
        if res.new_keyframe is not None and len(res.new_keyframe) == int(dyn.keep.sum()):
            res.new_keyframe.kp_classes = dyn.kp_classes[dyn.keep]
            res.new_keyframe.object_ids = dyn.object_ids[dyn.keep]

    def _record(self, frame: Frame, res: TrackResult) -> None:
        m = self.atlas.current
        T_ref_cam = None
        if res.new_keyframe is not None and frame.ref_kf_id == res.new_keyframe.id:
            T_ref_cam = np.eye(4)  # the frame is its own (not yet mapped) keyframe
        elif res.state == TrackingState.OK and frame.T_world_cam is not None and frame.ref_kf_id >= 0:
            T_ref_cam = invert(m.pose_of(frame.ref_kf_id)) @ frame.T_world_cam
        self.records.append(frame.stamp_ns, frame.index, res.state, m.id, frame.ref_kf_id, T_ref_cam, frame.T_world_cam)

    def refine_with_detections(self, detections: DetectionSet) -> list[RefinedPose]:
        """A frame's detections have arrived after tracking went past it (real time): the tracked frames they
        bracket with the set before get their final pose refined (`core.deferred_refinement`; nothing when
        `tracking.deferred_refinement` is off), at once or `settle_s` later (then `process` and, at the end,
        `settle_refinement` apply it). The online poses, the map and tracking's state stay as they were."""
        if self.refinement is None:
            return []
        refined = self.refinement.on_detections(detections, self._in_current_map)
        self._apply_refined(refined)
        return refined

    def settle_refinement(self) -> list[RefinedPose]:
        """The end of a run (before the final trajectory is written): the bracketed frames still waiting to settle
        are optimised again in the map as it is now (`tracking.deferred_refinement.settle_s`)."""
        if self.refinement is None:
            return []
        refined = self.refinement.settle_all(self._in_current_map)
        self._apply_refined(refined)
        return refined

    def _in_current_map(self, frame: TrackedFrameMatches) -> TrackedFrameMatches | None:
        """`frame` as the map is now: its reference keyframe's current pose composed with the tracked relative pose,
        its matched points where they are now (culled ones left out); None after a merge moved its map."""
        rec = self.records[frame.record_index]
        if rec.map_id != frame.map_id or rec.ref_kf_id != frame.ref_kf_id:
            return None
        m = self.atlas.maps[rec.map_id]
        if rec.ref_kf_id not in m.keyframes and rec.ref_kf_id not in m.removed:
            return None
        pts = m.points
        ok = frame.point_ids < pts.size
        ok[ok] = ~pts.bad[frame.point_ids[ok]]
        return frame.in_map(m.pose_of(rec.ref_kf_id) @ frame.T_ref_cam, ok, pts.positions[frame.point_ids[ok]].copy())

    def _keep_for_refinement(self, frame: Frame, rgbd: RgbdFrame, res: TrackResult) -> None:
        """A tracked frame's matches go into the refinement ring (keyframes not: their pose is the keyframe's, which
        local BA refines)."""
        assert self.refinement is not None
        rec = self.records[-1]
        if not self.refinement.has_detections:  # none handed over yet (offline: never): no frame can be bracketed
            return
        if res.state != TrackingState.OK or res.new_keyframe is not None or rec.T_ref_cam is None or frame.T_world_cam is None:
            return
        idx = np.flatnonzero(frame.point_ids >= 0)
        f, cam = frame.features, frame.camera
        ids = frame.point_ids[idx]
        kept = TrackedFrameMatches(
            frame.stamp_ns, len(self.records) - 1, frame.T_world_cam.copy(), rec.T_ref_cam.copy(), f.raw_px[idx],
            f.keypoints_px[idx], f.u_right[idx], self.tracker.inv_sigma2[f.octaves[idx]], ids,
            self.atlas.current.points.positions[ids].copy(), rgbd.depth_m,
            PinholeStereo(cam.fx, cam.fy, cam.cx, cam.cy, self.config.features.bf_m_px), rec.map_id, rec.ref_kf_id,
        )
        self._apply_refined(self.refinement.add(kept, self._in_current_map))

    def _apply_refined(self, refined: list[RefinedPose]) -> None:
        for r in refined:
            rec = self.records[r.record_index]
            if rec.stamp_ns == r.stamp_ns and rec.T_ref_cam is not None:
                rec.T_ref_cam = r.T_ref_cam

    def _reanchor_last_frame(self) -> None:
        """After BA or a loop correction moved keyframes, move the last frame with its reference
        keyframe (ORB-SLAM `UpdateLastFrame`) so the motion model predicts in the corrected map."""
        rec = self.records[-1]
        last = self.tracker.last_frame
        T_ref_cam = rec.T_ref_cam  # noqa: N806
        if T_ref_cam is None or last is None or last.T_world_cam is None:
            return
        m = self.atlas.maps[rec.map_id]
        if rec.ref_kf_id in m.keyframes or rec.ref_kf_id in m.removed:
            last.T_world_cam = m.pose_of(rec.ref_kf_id) @ T_ref_cam
            self.tracker.last_good_pose = last.T_world_cam

    # Results ------------------------------------------------------------------------------------
    def online_trajectory(self) -> Trajectory:
        recs = list(self.records.online_poses())
        return Trajectory.from_poses(
            np.array([stamp_ns * 1e-9 for stamp_ns, _ in recs]), np.array([T for _, T in recs]).reshape(-1, 4, 4)
        )

    def final_trajectory(self) -> Trajectory:
        stamps, poses = [], []
        for stamp_ns, map_id, ref_kf_id, T_ref_cam in self.records.relative_poses():  # noqa: N806
            poses.append(self.atlas.maps[map_id].pose_of(ref_kf_id) @ T_ref_cam)
            stamps.append(stamp_ns * 1e-9)
        return Trajectory.from_poses(np.array(stamps), np.array(poses).reshape(-1, 4, 4))

    def keyframe_trajectory(self) -> Trajectory:
        kfs = sorted((kf for m in self.atlas.maps for kf in m.keyframes.values()), key=lambda k: k.stamp_ns)
        return Trajectory.from_poses(
            np.array([k.stamp_ns * 1e-9 for k in kfs]), np.array([k.T_world_cam for k in kfs]).reshape(-1, 4, 4)
        )

    def n_tracked(self) -> int:
        return self.records.n_in_state(TrackingState.OK)

    def timing_summary(self) -> dict[str, dict[str, float]]:
        """Per stage (milliseconds): count, mean and max of the whole run; p50, p90, p99 of its last
        `RECENT_CAPACITY` values (`core.recent_values`: every value of a shorter run)."""
        return {k: v.summary() for k, v in self.timings_ms.items()}


def _thumbnail(rgbd: RgbdFrame) -> npt.NDArray[np.uint8] | None:
    """The keyframe thumbnail of a colour frame (`object_evidence`); None for a grey or empty image."""
    rgb = np.asarray(rgbd.rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8 or rgb.size == 0:
        return None
    return keyframe_thumbnail(rgb)
