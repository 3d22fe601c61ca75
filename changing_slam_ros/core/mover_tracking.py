"""Class-agnostic movers in the running system (Dai et al. 2021): feature tracks, windowed segmentation,
object targets tracked by object-level BA and merged by the overlap check.

Per frame, around camera tracking (`DynamicFilter` calls it):

1. `before_tracking(stamp_ns, features, camera)`: the frame's keypoints are matched by ORB descriptor to
   the feature tracks alive in the previous frame (Lowe ratio, one keypoint per track), unmatched keypoints
   with depth start new tracks. A keypoint is *moving* when its track is a point of a moving object
   tracked in the last frames or was put on an object target by the last segmentation; camera tracking
   does not use it (the paper: "camera tracking uses static points only").
2. `after_tracking(T_world_cam)`: with the tracked camera pose, the frame's measurements (back-projected
   keypoints with their track ids) are stored; every live object is tracked by motion-only object BA
   (eq. 7) and refined by full object BA (eq. 11) at keyposes; every `window_step_frames` frames the
   point-correlation segmentation (eq. 5) runs over a window of `window_frames` frames that many frames
   apart (the paper's local-mapping mode, slow and fast movers alike at 30 Hz), each object target becomes a
   `MovingObject`, and eq. 12 merges it into the objects that overlap it.

`tracks()` gives every object followed long enough as a `MovingObjectTrack` (what the run exports and the
ROS side publishes). The camera pose is the one tracking estimated (online), as the paper's object BA
holds the camera poses fixed.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field, replace

import cv2
import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.camera import CameraIntrinsics
from changing_slam_ros.core.object_merging import MergeConfig, merge_objects
from changing_slam_ros.core.object_tracking import (
    FrameObjectMeasurements,
    MovingObject,
    MovingObjectTrack,
    ObjectTracker,
    ObjectTrackingConfig,
    objects_from_segmentation,
)
from changing_slam_ros.core.orb_features import Features
from changing_slam_ros.core.point_correlation import CorrelationWindow, SegmentationConfig, segment
from changing_slam_ros.errors import ConfigError

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
BoolArr = npt.NDArray[np.bool_]


def _window_segmentation() -> SegmentationConfig:
    # The paper's two-frame (tracking) mode with the graph bounded to 500 points (the rest labelled from it).
    return replace(SegmentationConfig.two_frame(), max_points=500)


@dataclass(frozen=True)
class MoverConfig:
    """YAML section `dynamic: movers:`.

    - `enabled`: run the class-agnostic mover tracking (off: no tracks, nothing flagged).
    - `window_frames`, `window_step_frames`: a segmentation window holds `window_frames` frames spaced
      `window_step_frames` apart, and one runs every `window_step_frames` frames. Default 2 x 3: the
      paper's two-frame mode on frames 0.1 s apart at 30 Hz. On unknown_mover's ORB tracks (ground-truth
      poses, 14 windows from 3.3 s) that gave precision 1.00 / recall 0.66 of the box points in the window;
      5 frames 1 apart 0.98 / 0.47, 5 frames 3 apart 0.68 / 0.45 (box tracks rarely live 0.4 s).
    - `spread_px`, `spread_depth_m`: a keypoint within `spread_px` pixels and `spread_depth_m` depth of a
      keypoint flagged by its track is flagged too (keypoints new on the object have no track history
      yet; 0 = off).
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
    min_object_points: int = 6
    spread_px: float = 20.0
    spread_depth_m: float = 0.08
    max_lost_frames: int = 15
    min_track_frames: int = 10
    segmentation: SegmentationConfig = field(default_factory=_window_segmentation)
    tracking: ObjectTrackingConfig = field(default_factory=ObjectTrackingConfig)
    merging: MergeConfig = field(default_factory=lambda: MergeConfig(overlap_tolerance=0.5))

    def __post_init__(self) -> None:
        if self.window_frames < 2 or self.window_step_frames < 1:
            raise ConfigError(
                f"dynamic.movers: window_frames must be >= 2 and window_step_frames >= 1, got "
                f"{self.window_frames}, {self.window_step_frames}"
            )
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
            for pair in self._matcher.knnMatch(self._desc, descriptors, k=2):
                if len(pair) < 2:
                    continue
                best, second = pair
                if best.distance >= cfg.match_ratio * second.distance or best.distance > cfg.max_hamming:
                    continue
                t, j = best.queryIdx, best.trainIdx
                if ids[j] >= 0 or np.linalg.norm(keypoints_px[j] - self._px[t]) > cfg.max_shift_px:
                    continue
                ids[j] = self._ids[t]
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
        span = (self.config.window_frames - 1) * self.config.window_step_frames + 1
        self._history: deque[FrameObjectMeasurements] = deque(maxlen=span)
        self._pending: _Pending | None = None
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
        """(N,) keypoints of the frame on a moving object (by their feature track)."""
        ids = self._tracks.associate(features.keypoints_px, features.descriptors, features.depths_m)
        self._pending = _Pending(stamp_ns, ids, features.keypoints_px, features.depths_m, camera)
        moving_ids = [self._segmented_moving] + [o.point_ids for o in self.live]
        moving = (ids >= 0) & np.isin(ids, np.concatenate(moving_ids))
        if self.config.spread_px > 0.0 and moving.any():
            moving = spread_flags(moving, features.keypoints_px, features.depths_m, self.config.spread_px, self.config.spread_depth_m)
        return np.asarray(moving, dtype=np.bool_)

    def after_tracking(self, T_world_cam: F64 | None) -> None:
        """The frame's camera-to-world pose from tracking (None when it failed: the frame is skipped)."""
        pending, self._pending = self._pending, None
        if pending is None or T_world_cam is None:
            return
        self._frames += 1
        tracker = self._object_tracker(pending.camera)
        ok = (pending.ids >= 0) & (pending.depths_m > 0)
        points_cam = pending.camera.backproject(pending.keypoints_px[ok], pending.depths_m[ok])
        frame = FrameObjectMeasurements(pending.stamp_ns, np.asarray(T_world_cam, np.float64), pending.ids[ok], points_cam)
        self._history.append(frame)
        for obj in self.live:
            result = tracker.track(obj, frame)
            if result.tracked:
                self._last_tracked[obj.object_id] = self._frames
                if result.is_keypose:
                    tracker.optimise(obj)
        self._retire_lost()
        if len(self._history) == self._history.maxlen and self._frames % self.config.window_step_frames == 0:
            self._segment_window(frame.stamp_ns)

    def _object_tracker(self, camera: CameraIntrinsics) -> ObjectTracker:
        if self._tracker is None or camera != self._camera:
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

    def _segment_window(self, stamp_ns: int) -> None:
        import time

        cfg = self.config
        assert self._camera is not None
        frames = list(self._history)[:: cfg.window_step_frames]
        all_ids = np.unique(np.concatenate([f.point_ids for f in frames]))
        points_cam = np.full((len(frames), len(all_ids), 3), np.nan)
        for k, f in enumerate(frames):
            points_cam[k, np.searchsorted(all_ids, f.point_ids)] = f.points_cam
        window = CorrelationWindow(all_ids, points_cam, np.stack([f.T_world_cam for f in frames]), self._camera)
        t0 = time.process_time()
        result = segment(window, cfg.segmentation)
        self.segmentation_ms.append((time.process_time() - t0) * 1e3)
        self._segmented_moving = all_ids[result.dynamic_mask]
        new = objects_from_segmentation(result, window, stamp_ns, self._next_object_id, min_points=cfg.min_object_points)
        self._next_object_id += len(new)
        for obj in new:
            self._last_tracked[obj.object_id] = self._frames
        self.live = merge_objects(self.live + new, stamp_ns, cfg.merging)

    def objects(self) -> list[MovingObject]:
        """Every object so far (live and retired), by id."""
        return sorted(self.live + self.retired, key=lambda o: o.object_id)

    def tracks(self) -> list[MovingObjectTrack]:
        """The objects tracked in at least `min_track_frames` frames, as exportable tracks."""
        return [o.to_track() for o in self.objects() if len(o.poses) >= self.config.min_track_frames]
