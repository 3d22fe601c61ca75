"""Class-agnostic movers in the running system (Dai et al. 2021): feature tracks, windowed segmentation,
object targets tracked by object-level BA and merged by the overlap check.

Per frame, around camera tracking (`DynamicFilter` calls it): `before_tracking` matches the frame's keypoints
to the live feature tracks (ORB, Lowe ratio) and flags as moving the keypoints on a moving object or a target
of the last segmentation (camera tracking uses static points only). `after_tracking(T_world_cam)` stores the
frame's measurements, tracks every live object by motion-only object BA (eq. 7), refines it by full object BA
(eq. 11) at keyposes, and every `window_step_frames` frames segments a window of `window_frames` frames
(eq. 5); each target becomes a `MovingObject` that eq. 12 merges into the objects it overlaps. `tracks()`
gives every object followed long enough as a `MovingObjectTrack`. Camera poses are tracking's (online), held
fixed by the object BA as in the paper.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field, replace

import cv2
import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.movers.object_merging import MergeConfig, merge_objects
from changing_slam_ros.core.movers.object_tracking import (
    FrameObjectMeasurements,
    MovingObject,
    MovingObjectTrack,
    ObjectTracker,
    ObjectTrackingConfig,
    objects_from_segmentation,
)
from changing_slam_ros.core.features.orb_features import Features
from changing_slam_ros.core.movers.point_correlation import CorrelationWindow, SegmentationConfig, SegmentationResult, segment
from changing_slam_ros.core.geometry.se3 import invert, transform_points
from changing_slam_ros.errors import ConfigError

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
BoolArr = npt.NDArray[np.bool_]


def _window_segmentation() -> SegmentationConfig:
    # The paper's two-frame (tracking) mode with the graph bounded to 500 points (the rest labelled from it)
    # and two Gauss-Newton iterations: on unknown_mover (720 frames) the third changed no flag and no
    # track and cost 8 ms of the 44 ms per window (`bench/bench_movers.py`).
    return replace(SegmentationConfig.two_frame(), max_points=500, iterations_per_round=2)


@dataclass(frozen=True)
class MoverConfig:
    """YAML section `dynamic: movers:`.

    - `enabled`: run the class-agnostic mover tracking (off: no tracks, nothing flagged).
    - `window_frames`, `window_step_frames`: a segmentation window holds `window_frames` frames spaced
      `window_step_frames` apart, the newest being the current frame. Default 2 x 3: the
      paper's two-frame mode on frames 0.1 s apart at 30 Hz. On unknown_mover's ORB tracks (ground-truth
      poses, 14 windows from 3.3 s) that gave precision 1.00 / recall 0.66 of the box points in the window;
      5 frames 1 apart 0.98 / 0.47, 5 frames 3 apart 0.68 / 0.45 (box tracks rarely live 0.4 s).
    - `segment_every_frames`: the segmentation runs on every n-th frame (1: every frame, the paper's
      tracking mode; its targets' points are then dropped in the frame itself). Default 2: on unknown_mover
      (720 frames, system run) 1 gave moving-keypoint P 0.966 / R 0.968, object ATE 1.46 cm, and 2 gave
      P 0.973 / R 0.967, 0.65 cm at about 0.78x the stage's CPU time per frame (`bench/bench_movers.py`);
      the live objects' models flag their points on the frames in between.
    - `idle_segment_every_frames`: the cadence while the stage is idle (no live object, and the last
      segmentation put no point on a target); 0 = `segment_every_frames`. A static scene then costs the
      feature tracks and one segmentation every n frames; a new mover is found at most n - 1 frames later.
      Default 4: on unknown_mover (no mover for the first 4.5 s) 326 windows instead of 359 with the same
      flags and tracks.
    - `spread_px`, `spread_depth_m`: a keypoint within `spread_px` pixels and `spread_depth_m` depth of a
      keypoint flagged by its track is flagged too (keypoints new on the object have no track history
      yet; 0 = off).
    - `model_radius_m`: a keypoint whose back-projection (predicted camera pose) lies within this distance
      of a point of a live object's model, at the object's pose extrapolated to the frame, is moving too
      (0 = off).
    - `match_ratio`: Lowe ratio of the descriptor match that extends a feature track; `max_hamming`,
      `max_shift_px`: largest descriptor distance and image displacement of such a match.
    - `min_object_points`: object targets with fewer points measured in the newest frame are not tracked.
    - `max_lost_frames`: an object not tracked for this many frames is retired (kept for export, no longer
      tracked nor flagged).
    - `min_track_frames`: objects tracked in fewer frames are not exported (short-lived fragments).
    - `segmentation`, `tracking`, `merging`: the point-correlation, object-tracking and eq. 12 settings.
      `merging.overlap_tolerance` defaults to 0.5 here (beyond the paper's d > 0): a new target that is a
      new face of a tracked object touches it without interleaving, see `object_merging`.
    """

    enabled: bool = False
    window_frames: int = 2
    window_step_frames: int = 3
    match_ratio: float = 0.8
    max_hamming: int = 64
    max_shift_px: float = 80.0
    segment_every_frames: int = 2
    idle_segment_every_frames: int = 4
    min_object_points: int = 6
    spread_px: float = 20.0
    model_radius_m: float = 0.03
    spread_depth_m: float = 0.08
    max_lost_frames: int = 15
    min_track_frames: int = 10
    segmentation: SegmentationConfig = field(default_factory=_window_segmentation)
    tracking: ObjectTrackingConfig = field(default_factory=ObjectTrackingConfig)
    merging: MergeConfig = field(default_factory=lambda: MergeConfig(overlap_tolerance=0.5))

    def __post_init__(self) -> None:
        if self.window_frames < 2 or self.window_step_frames < 1 or self.segment_every_frames < 1:
            raise ConfigError(
                f"dynamic.movers: window_frames must be >= 2, window_step_frames and segment_every_frames >= 1, "
                f"got {self.window_frames}, {self.window_step_frames}, {self.segment_every_frames}"
            )
        if self.idle_segment_every_frames < 0:
            raise ConfigError(f"dynamic.movers.idle_segment_every_frames: expected >= 0, got {self.idle_segment_every_frames}")
        if not 0.0 < self.match_ratio <= 1.0:
            raise ConfigError(f"dynamic.movers.match_ratio: expected 0 < r <= 1, got {self.match_ratio}")


def spread_flags(flagged: BoolArr, px: F64, depth_m: F64, radius_px: float, depth_tol_m: float) -> BoolArr:
    """(N,) `flagged` plus keypoints with depth within `radius_px` and `depth_tol_m` of a flagged keypoint."""
    from scipy.spatial import cKDTree  # type: ignore[import-untyped]

    src = np.flatnonzero(flagged & (depth_m > 0))
    if len(src) == 0:
        return flagged.copy()
    pairs = cKDTree(px).query_ball_tree(cKDTree(px[src]), radius_px)
    rows = np.repeat(np.arange(len(px)), [len(p) for p in pairs])
    cols = src[np.concatenate([np.asarray(p, dtype=np.int64) for p in pairs])] if len(rows) else np.zeros(0, np.int64)
    near = (depth_m[rows] > 0) & (np.abs(depth_m[rows] - depth_m[cols]) <= depth_tol_m)
    out = flagged.copy()
    out[rows[near]] = True
    return out


class FeatureTracks:
    """Persistent ids for keypoints: each frame's keypoints matched to the tracks alive in the previous one."""

    def __init__(self, config: MoverConfig) -> None:
        self.config = config
        self._matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
        self._ids = np.zeros(0, dtype=np.int64)  # track id per alive track
        self._desc = np.zeros((0, 32), dtype=np.uint8)
        self._px = np.zeros((0, 2))
        self._next_id = 0

    def associate(self, keypoints_px: F64, descriptors: npt.NDArray[np.uint8], depths_m: F64) -> I64:
        """Track id (N,) of each keypoint; -1 for keypoints without depth that no track reached."""
        cfg = self.config
        n = len(keypoints_px)
        ids = np.full(n, -1, dtype=np.int64)
        if len(self._ids) and n >= 2:
            pairs = [p for p in self._matcher.knnMatch(self._desc, descriptors, k=2) if len(p) == 2]
            if pairs:
                m = np.array([(a.queryIdx, a.trainIdx, a.distance, b.distance) for a, b in pairs])
                t, j = m[:, 0].astype(np.int64), m[:, 1].astype(np.int64)
                ok = (m[:, 2] < cfg.match_ratio * m[:, 3]) & (m[:, 2] <= cfg.max_hamming)
                ok &= np.linalg.norm(keypoints_px[j] - self._px[t], axis=1) <= cfg.max_shift_px
                t, j, dist = t[ok], j[ok], m[ok, 2]
                order = np.lexsort((t, dist))  # one track per keypoint: the closest descriptor wins
                _, first = np.unique(j[order], return_index=True)
                ids[j[order[first]]] = self._ids[t[order[first]]]
        new = (ids < 0) & (depths_m > 0)
        ids[new] = np.arange(self._next_id, self._next_id + int(new.sum()))
        self._next_id += int(new.sum())
        alive = ids >= 0
        self._ids, self._desc, self._px = ids[alive], descriptors[alive].copy(), keypoints_px[alive].copy()
        return ids


@dataclass
class _Pending:
    stamp_ns: int
    ids: I64
    keypoints_px: F64
    depths_m: F64
    camera: CameraIntrinsics


class MoverTracker:
    """The class-agnostic mover loop of one sequence (see the module docstring)."""

    def __init__(self, config: MoverConfig | None = None) -> None:
        self.config = config or MoverConfig()
        self._tracks = FeatureTracks(self.config)
        span = (self.config.window_frames - 1) * self.config.window_step_frames
        self._history: deque[FrameObjectMeasurements] = deque(maxlen=span)  # the frames before the current
        self._poses: deque[F64] = deque(maxlen=2)  # last two tracked camera poses, for the prediction
        self._pending: _Pending | None = None
        self._segmented: tuple[CorrelationWindow, SegmentationResult] | None = None
        self._tracker: ObjectTracker | None = None
        self._camera: CameraIntrinsics | None = None
        self.live: list[MovingObject] = []
        self.retired: list[MovingObject] = []
        self._last_tracked: dict[int, int] = {}  # object id -> frame count when last tracked
        self._segmented_moving: I64 = np.zeros(0, dtype=np.int64)  # track ids on targets, last segmentation
        self._next_object_id = 1
        self._frames = 0
        self.segmentation_ms: list[float] = []

    def before_tracking(self, stamp_ns: int, features: Features, camera: CameraIntrinsics) -> BoolArr:
        """(N,) keypoints of the frame on a moving object: on a target of this frame's segmentation (two
        frames in tracking, the current pose predicted at constant velocity), or points of a live object."""
        cfg = self.config
        ids = self._tracks.associate(features.keypoints_px, features.descriptors, features.depths_m)
        pending = _Pending(stamp_ns, ids, features.keypoints_px, features.depths_m, camera)
        self._pending, self._segmented = pending, None
        T_pred = self._predicted_pose()
        idle = not self.live and len(self._segmented_moving) == 0
        every = cfg.idle_segment_every_frames if idle and cfg.idle_segment_every_frames > 0 else cfg.segment_every_frames
        due = (self._frames + 1) % every == 0
        if due and T_pred is not None and len(self._history) == self._history.maxlen:
            self._camera = camera
            current = self._measurements(pending, T_pred)
            frames = list(self._history)[:: cfg.window_step_frames] + [current]
            window, result = self._segment(frames)
            self._segmented = (window, result)
            self._segmented_moving = window.point_ids[result.dynamic_mask]
        moving_ids = np.concatenate([self._segmented_moving] + [o.point_ids for o in self.live])
        moving = (ids >= 0) & np.isin(ids, moving_ids)
        if cfg.model_radius_m > 0.0 and T_pred is not None and self.live:
            moving |= self._on_live_objects(features, camera, T_pred, stamp_ns)
        if cfg.spread_px > 0.0 and moving.any():
            moving = spread_flags(moving, features.keypoints_px, features.depths_m, cfg.spread_px, cfg.spread_depth_m)
        return np.asarray(moving, dtype=np.bool_)

    def after_tracking(self, T_world_cam: F64 | None) -> None:
        """The frame's camera-to-world pose from tracking (None when it failed: the frame is skipped)."""
        pending, self._pending = self._pending, None
        segmented, self._segmented = self._segmented, None
        if pending is None or T_world_cam is None:
            self._poses.clear()
            return
        T = np.asarray(T_world_cam, np.float64)
        self._frames += 1
        tracker = self._object_tracker(pending.camera)
        frame = self._measurements(pending, T)
        for obj in self.live:
            result = tracker.track(obj, self._associate(obj, frame))
            if result.tracked:
                self._last_tracked[obj.object_id] = self._frames
                if result.is_keypose and tracker.optimise_due(obj):
                    tracker.optimise(obj)
        self._retire_lost()
        if segmented is not None:  # targets become objects, with the tracked (not the predicted) pose
            window, result = segmented
            window = CorrelationWindow(window.point_ids, window.points_cam, np.concatenate([window.T_world_cam[:-1], T[None]]), window.camera)
            self._add_targets(window, result, frame.stamp_ns)
        self._history.append(frame)
        self._poses.append(T)

    @staticmethod
    def _measurements(pending: _Pending, T_world_cam: F64) -> FrameObjectMeasurements:
        ok = (pending.ids >= 0) & (pending.depths_m > 0)
        points_cam = pending.camera.backproject(pending.keypoints_px[ok], pending.depths_m[ok])
        return FrameObjectMeasurements(pending.stamp_ns, T_world_cam, pending.ids[ok], points_cam)

    def _on_live_objects(self, features: Features, camera: CameraIntrinsics, T_world_cam: F64, stamp_ns: int) -> BoolArr:
        """(N,) keypoints whose back-projection lies within `model_radius_m` of a live object's model
        point, the object at its pose predicted for `stamp_ns` (keypoints new on the object have no track)."""
        from scipy.spatial import cKDTree  # type: ignore[import-untyped]

        on = np.zeros(len(features), dtype=bool)
        has_depth = features.depths_m > 0
        if not has_depth.any():
            return on
        world = transform_points(T_world_cam, camera.backproject(features.keypoints_px[has_depth], features.depths_m[has_depth]))
        idx = np.flatnonzero(has_depth)
        for obj in self.live:
            if not obj.poses or len(obj.points_obj) < self.config.min_object_points:
                continue
            local = transform_points(invert(obj.predict(stamp_ns)), world)
            dist, _ = cKDTree(obj.points_obj).query(local, k=1, distance_upper_bound=self.config.model_radius_m)
            on[idx[np.isfinite(dist)]] = True
        return on

    def _associate(self, obj: MovingObject, frame: FrameObjectMeasurements) -> FrameObjectMeasurements:
        """The frame's measurements of `obj`: keypoints on its points' feature tracks, plus keypoints whose
        back-projection lies within `model_radius_m` of one of its model points at its extrapolated pose
        (relabelled with that point's id; one keypoint per point, the nearest). Feature tracks on a turning
        object are short; this keeps an object tracked once the tracks it was made of have died."""
        from scipy.spatial import cKDTree  # type: ignore[import-untyped]

        radius = self.config.model_radius_m
        if radius <= 0.0 or not obj.poses or len(frame.point_ids) == 0:
            return frame
        by_id = obj.index_of(frame.point_ids)
        local = transform_points(invert(obj.predict(frame.stamp_ns)), transform_points(frame.T_world_cam, frame.points_cam))
        dist, nn = cKDTree(obj.points_obj).query(local, k=1, distance_upper_bound=radius)
        candidate = (by_id < 0) & np.isfinite(dist) & ~np.isin(nn, by_id[by_id >= 0])
        cand = np.flatnonzero(candidate)
        cand = cand[np.argsort(dist[cand], kind="stable")]
        _, first = np.unique(nn[cand], return_index=True)  # the nearest keypoint per model point
        chosen = cand[first]
        ids = frame.point_ids.copy()
        ids[chosen] = obj.point_ids[nn[chosen]]
        use = by_id >= 0
        use[chosen] = True
        return FrameObjectMeasurements(frame.stamp_ns, frame.T_world_cam, ids[use], frame.points_cam[use])

    def _predicted_pose(self) -> F64 | None:
        if not self._poses:
            return None
        last = self._poses[-1]
        return last if len(self._poses) < 2 else last @ (invert(self._poses[0]) @ last)

    def _object_tracker(self, camera: CameraIntrinsics) -> ObjectTracker:
        if self._tracker is None or camera != self._camera or self._tracker.camera != camera:
            self._tracker = ObjectTracker(camera, self.config.tracking)
            self._camera = camera
        return self._tracker

    def _retire_lost(self) -> None:
        keep = []
        for obj in self.live:
            if self._frames - self._last_tracked.get(obj.object_id, self._frames) > self.config.max_lost_frames:
                self.retired.append(obj)
            else:
                keep.append(obj)
        self.live = keep

    def _segment(self, frames: list[FrameObjectMeasurements]) -> tuple[CorrelationWindow, SegmentationResult]:
        assert self._camera is not None
        all_ids = np.unique(np.concatenate([f.point_ids for f in frames]))
        points_cam = np.full((len(frames), len(all_ids), 3), np.nan)
        for k, f in enumerate(frames):
            points_cam[k, np.searchsorted(all_ids, f.point_ids)] = f.points_cam
        window = CorrelationWindow(all_ids, points_cam, np.stack([f.T_world_cam for f in frames]), self._camera)
        t0 = time.process_time()
        result = segment(window, self.config.segmentation)
        self.segmentation_ms.append((time.process_time() - t0) * 1e3)
        return window, result

    def _add_targets(self, window: CorrelationWindow, result: SegmentationResult, stamp_ns: int) -> None:
        """New objects from the targets, merged (eq. 12) into the live objects they overlap.

        A live object not tracked in this frame (too few of its points matched) takes part at its pose
        predicted at constant velocity; the prediction is kept only when a target merged into it (it is
        the pose the new points were attached with), so the object goes on with the target's points.
        """
        cfg = self.config
        new = objects_from_segmentation(result, window, stamp_ns, self._next_object_id, min_points=cfg.min_object_points)
        self._next_object_id += len(new)
        if not new:
            return
        for obj in new:
            self._last_tracked[obj.object_id] = self._frames
        predicted = {}
        for obj in self.live:
            if stamp_ns not in obj.poses and obj.poses:
                obj.poses[stamp_ns] = obj.predict(stamp_ns)
                predicted[obj.object_id] = len(obj.point_ids)
        merged = merge_objects(self.live + new, stamp_ns, cfg.merging)
        for obj in merged:
            if obj.object_id in predicted and len(obj.point_ids) == predicted[obj.object_id]:
                del obj.poses[stamp_ns]  # nothing merged into it: drop the prediction
            elif obj.object_id in predicted:
                self._last_tracked[obj.object_id] = self._frames
            obj.bound_model(cfg.tracking.max_model_points)
        self.live = merged

    def objects(self) -> list[MovingObject]:
        """Every object so far (live and retired), by id."""
        return sorted(self.live + self.retired, key=lambda o: o.object_id)

    def tracks(self) -> list[MovingObjectTrack]:
        """The objects tracked in at least `min_track_frames` frames, as exportable tracks."""
        return [o.to_track() for o in self.objects() if len(o.poses) >= self.config.min_track_frames]

