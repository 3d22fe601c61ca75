"""The dynamic-scene stage of tracking: which keypoints of a frame may be used to estimate the camera pose.

Per frame, before the pose is estimated, it combines (1) the frame's detections (a detector or the
simulator's oracle boxes, from the caller); (2) keypoint classification with repopulation (Changing-SLAM
§4.1, `keypoint_classification`); (3) short-term association, one EKF per object and the dynamic-object
classification (§4.3-4.5, `dynamic_objects`): persons and moving objects dropped, objects found static
used, undecided ones when too few others are left (`min_kept_keypoints`); (4) the class-agnostic two-frame
segmentation of Dai et al. 2021 against earlier frames, by the closed-form edge test (`movers/edge_test`)
or the paper's eq. 5 (`movers/point_correlation`): any object target is dropped, whatever its class; (5) the
free-space check (`movers/free_space_check`): keypoints in space an earlier frame saw empty are dropped too.

`before_tracking` returns a `DynamicFrame`; `after_tracking(T_world_cam)` feeds the tracked pose to the
EKFs and the segmentation's history. The current pose of the segmentation is a constant-velocity
prediction: a pose error moves all points rigidly, which changes adjacent points' relative positions only
by the rotation error times the (short) edge length.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field, replace

import cv2
import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.recent_values import RecentValues
from changing_slam_ros.core.dynamic.detector import Detection, box_area_px
from changing_slam_ros.core.dynamic.dynamic_objects import DynamicObjectsConfig, DynamicObjectTracker, ObjectMotion, ObjectState
from changing_slam_ros.core.map.keyframe import KeypointClass
from changing_slam_ros.core.movers.edge_test import edge_test_segment, match_nearby
from changing_slam_ros.core.movers.flag_vote import FlagVoteConfig, vote_flags
from changing_slam_ros.core.movers.free_space_check import FreeSpaceConfig, free_space_violations, near_surface
from changing_slam_ros.core.movers.mover_tracking import MoverConfig, MoverTracker
from changing_slam_ros.core.features.orb_features import Features
from changing_slam_ros.core.movers.point_correlation import CorrelationWindow, SegmentationConfig, segment
from changing_slam_ros.core.features.rgbd_frame import RgbdFrame
from changing_slam_ros.core.geometry.se3 import invert
from changing_slam_ros.errors import ConfigError

F64 = npt.NDArray[np.float64]
BoolArr = npt.NDArray[np.bool_]

SEGMENTATION_METHODS = ("edge_test", "correlation")
NEVER = 10**9  # `min_updates` of an EKF that never gives a verdict: movable objects stay filtered


@dataclass(frozen=True)
class DynamicConfig:
    """YAML section `dynamic:`.

    - `enabled`: false = the plain engine, every keypoint used.
    - `detection_filtering`: keypoints inside detected boxes take the box's class (person dynamic, other
      classes movable) and are dropped; off = detections ignored.
    - `repopulation`: §4.1 repopulation (background keypoints inside a box kept as static).
    - `ekf_doc`: per-object EKF and dynamic-object classification; off = movable objects are never
      found static, so their keypoints are always dropped.
    - `segmentation`: two-frame point-correlation segmentation (Dai et al.); its object targets' keypoints
      are dropped whatever their class. On by default: it catches the movers the detector misses (a person
      cut by the border, too close or in an unusual pose; objects of no COCO class).
    - `segmentation_method`: "edge_test" (`movers/edge_test.py`: each Delaunay edge's rigidity tested in
      closed form, matches searched around each keypoint's predicted position) or "correlation" (the
      paper's eq. 5 solved by Gauss-Newton, `movers/point_correlation.py`, with brute-force matching;
      about ten times the CPU).
    - `segmentation_gap_frames`: the segmentation compares the frame with the one this many frames earlier
      (a person moves ~3 cm per frame at 30 fps; 0.1 s makes the motion clear of depth noise).
    - `segmentation_carry_frames`: a keypoint matched (in the segmentation's own short-gap matching) to one
      flagged at most this many frames earlier stays flagged. 0 = off, the default: 12 took sitting_xyz
      from 0.49 to 0.94 cm (flags on the seated people's surroundings outlive them).
    - `segmentation_long_gap_frames` / `segmentation_long_every`: "edge_test" also compares every
      `segmentation_long_every`-th frame with the one `segmentation_long_gap_frames` earlier (12: 0.4 s at
      30 Hz, where slower movers clear the depth noise; with `segmentation_carry_frames` its flags reach the
      frames between). 0 = off, the default: a third more CPU, and with the carry sitting_xyz 0.65 cm
      against 0.49 without either; it did not free the map of a board in view from frame 0.
    - `segmentation_max_hamming`: ORB descriptor distance accepted for a match between the two frames.
    - `segmentation_max_shift_px`: largest image displacement of a match (wrong matches across the image
      are left out); for "edge_test", the search radius around the predicted position.
    - `segmentation_search_k`: "edge_test" compares each keypoint with this many earlier keypoints nearest
      to its predicted position (the search's cost; a fast mover's match may lie beyond them).
    - `segmentation_min_matches`: fewer matches = no segmentation in that frame.
    - `segmentation_spread_px` / `segmentation_spread_depth_m`: a keypoint within this image distance (in
      pixels of a 640-wide image, scaled with the width) and depth difference of a flagged one is flagged too
      (only matched keypoints can be flagged, about half of a walking person's; 0 = off). In a frame where
      that would leave tracking fewer than `min_kept_keypoints` keypoints with depth, the spread yields.
    - `flag_vote`: the keypoints the segmentation did not test take the verdict of the tested keypoints around
      them in 3-D (`movers/flag_vote.py`); a tested keypoint keeps its own. It yields as the spread does. Off
      by default: on the randomised dynamic family's tuning seeds 0-59 (radius 0.25 m) it took the ATE p90 from
      19.7 to 11.0 cm, but the worst seed from 54.5 to 67.3 cm and the lost frames from 153 to 168, since it
      also multiplies the test's own false alarms (a piece of static wall cut off as a target).
    - `detection_hold_frames`: a box of a `hold_class_ids` class that the detector stops reporting is kept
      for this many frames, grown by `detection_hold_grow_px` per side per missed frame. A real detector
      misses a person in single frames, or names a close one "chair" or "teddy bear" every other frame
      (the held person box then keeps its keypoints dynamic); 0 = off, the paper's behaviour. 6 (0.2 s at
      30 Hz): on the randomised dynamic family's tuning seeds 0-9 it took the ATE median / p90 / worst from
      2.95 / 17.3 / 108 cm to 1.54 / 7.0 / 23.4 cm (3 frames: 2.96 / 9.5 / 42 cm), recall of moving keypoints
      0.75 -> 0.84, controls unchanged.
    - `fixed_class_ids`: COCO classes of fixed furniture and appliances (bed 59, dining table 60, toilet 61,
      oven 69, sink 71, refrigerator 72) whose boxes are ignored, so their keypoints stay static background.
      Beyond the paper, which treats every non-person box as movable: on real kitchens the detector calls
      the counter a "dining table" covering ~44 % of the image (7-Scenes redkitchen, 24 of 40 sampled
      frames), and filtering it as a new movable object cost the static run 4.5 -> 11 cm ATE. Set `[]`
      for the paper's behaviour.
    - `min_kept_keypoints` / `keep_undecided`: keypoints of detected movable objects that no cue has seen
      move yet (EKF verdict UNKNOWN, not flagged by the segmentation) are used when fewer than
      `min_kept_keypoints` keypoints with depth are kept otherwise (`tracking.min_init_points` is 300), or
      always with `keep_undecided`. The paper filters them until the EKF finds them static: a still object
      filling the first view then stops initialisation, and one whose box is cut by the image border gets
      no EKF update and stays filtered while in view. Used always, they cost slow_mover 0.11 -> 0.16 cm.
      Needs `ekf_doc`. `min_kept_keypoints: 0` and `keep_undecided: false` = the paper.
    - `undecided_view_fraction`: an undecided object whose box covers at least this fraction of the image is used
      too (0: off, the default). A detection that fills most of the view is seldom a thing that moves (a wall
      photo called a clock over two thirds of the image lost the camera of a randomised changing room, 114 cm;
      0.5 brought it to 3.6 cm), and leaving it out leaves tracking the edges of the view, where the map may have
      nothing; the class-agnostic cues still drop its keypoints that move. Off by default because a close person
      the detector calls a chair is such a box too (results.md: randomised dynamic tuning seed 2, 54 -> 66 cm).
    - `map_view_min_matches`: whether the kept keypoints can see the map, rather than how many there are. When
      tracking is OK and the kept keypoints match fewer than this many of the last frame's map points projected
      at the predicted pose (`Tracker.matches_at_prediction`), while the keypoints of undecided objects (not
      flagged as moving by any cue) make up the count with map points the map held before their object was
      first detected, those keypoints are used for this frame: they sit where the room was before the box came
      (a wall photo the detector named a clock over two thirds of the view lost the camera of a randomised
      changing room, 114 cm; 50 brought it to 5.1 cm). A mover matches no map point at the prediction, nor one
      mapped while it was in view. 0 = off, the default (results.md: randomised families).
    - `objects`: the `DynamicObjectTracker` settings (classification, association, EKF, DOC thresholds).
    - `correlation`: the point-correlation settings (default: `SegmentationConfig.two_frame()`).
    - `free_space_check` / `free_space_gap_frames`: keypoints that lie where the frame this many frames earlier
      measured empty space (in front of its depth surface) are moving, whatever their class
      (`movers/free_space_check.py`, DynaSLAM's multi-view depth check on the keypoints); `free_space` holds its
      window, tolerances and neighbour support. On by default: on the randomised dynamic family it took the
      class-agnostic cues from 0.76 / 0.12 to 0.90 / 0.35 precision / recall of moving keypoints and the p90 ATE
      from 31 to 17 cm (evaluation seeds, settings fixed before measuring), for under 1 ms per frame.
    - `forget_moving_points`: a map point that earlier frames matched to a keypoint the segmentation now puts
      on a mover, this many times, leaves the map with its observations (0 = off, the default). A keypoint
      left out of tracking passes its point's id on through the segmentation's own matches, so a point is
      tested again while its keypoint is flagged. A slow mover of no COCO class that no cue flags in every
      frame otherwise keeps its map points, local BA moves them with it, and tracking follows it (tuning
      seed 10, a tripod camera and a pushed cart: 21.79 -> 2.20 cm with 2). On tuning seeds 0-29 with
      `correlation.noise_from_edges` ATE median / p90 / worst 1.93 / 20.56 / 25.86 -> 2.14 / 16.36 / 25.17
      cm (12 seeds better, 7 worse), controls about the same; on evaluation seeds 100-129 3.22 / 16.08 /
      32.51 -> 3.62 / 16.45 / 42.84 cm (fewer lost frames, 107 -> 83), so it stays off. Offline and
      in the in-process backend only: in the split graph the map belongs to local_mapping, and tracking's
      replica does not edit it.
    - `movers`: class-agnostic mover tracking (Dai et al.: feature tracks, windowed segmentation, object BA,
      eq. 12 merging; `core/movers/mover_tracking.py`); its moving keypoints are dropped too. Off by default.
    """

    enabled: bool = True
    detection_filtering: bool = True
    repopulation: bool = True
    ekf_doc: bool = True
    segmentation: bool = True
    segmentation_method: str = "edge_test"
    segmentation_gap_frames: int = 3
    segmentation_carry_frames: int = 0
    segmentation_long_gap_frames: int = 0
    segmentation_long_every: int = 3
    segmentation_max_hamming: int = 50
    segmentation_max_shift_px: float = 80.0
    segmentation_search_k: int = 24
    segmentation_min_matches: int = 30
    segmentation_spread_px: float = 0.0
    segmentation_spread_depth_m: float = 0.3
    flag_vote: FlagVoteConfig = field(default_factory=FlagVoteConfig)
    detection_hold_frames: int = 6
    detection_hold_grow_px: float = 8.0
    hold_class_ids: tuple[int, ...] = (0,)
    fixed_class_ids: tuple[int, ...] = (59, 60, 61, 69, 71, 72)
    min_kept_keypoints: int = 300
    keep_undecided: bool = False
    undecided_view_fraction: float = 0.0
    map_view_min_matches: int = 0
    forget_moving_points: int = 0
    objects: DynamicObjectsConfig = field(default_factory=DynamicObjectsConfig)
    correlation: SegmentationConfig = field(default_factory=SegmentationConfig.two_frame)
    free_space_check: bool = True
    free_space_gap_frames: int = 10
    free_space: FreeSpaceConfig = field(default_factory=FreeSpaceConfig)
    movers: MoverConfig = field(default_factory=MoverConfig)

    def __post_init__(self) -> None:
        if self.segmentation_gap_frames < 1:
            raise ConfigError(f"dynamic.segmentation_gap_frames: expected >= 1, got {self.segmentation_gap_frames}")
        if self.segmentation_method not in SEGMENTATION_METHODS:
            raise ConfigError(
                f"dynamic.segmentation_method: expected one of {SEGMENTATION_METHODS}, got {self.segmentation_method!r}"
            )
        if min(self.segmentation_long_gap_frames, self.segmentation_carry_frames) < 0 or self.segmentation_long_every < 1:
            raise ConfigError("dynamic: segmentation_long_gap_frames and segmentation_carry_frames must be >= 0, "
                              "segmentation_long_every >= 1")
        if self.forget_moving_points < 0:
            raise ConfigError(f"dynamic.forget_moving_points: expected >= 0 (0 = off), got {self.forget_moving_points}")
        if self.free_space_gap_frames < 1:
            raise ConfigError(f"dynamic.free_space_gap_frames: expected >= 1, got {self.free_space_gap_frames}")
        if not 0.0 <= self.undecided_view_fraction <= 1.0:
            raise ConfigError("dynamic.undecided_view_fraction: expected 0..1 (0: off), "
                              f"got {self.undecided_view_fraction}")
        if self.map_view_min_matches < 0:
            raise ConfigError(f"dynamic.map_view_min_matches: expected >= 0 (0: off), got {self.map_view_min_matches}")
        if self.segmentation_min_matches < 5:
            raise ConfigError(f"dynamic.segmentation_min_matches: expected >= 5, got {self.segmentation_min_matches}")

    def tracker_config(self) -> DynamicObjectsConfig:
        """The object tracker's settings with the ablation switches applied."""
        cfg = self.objects
        if not self.repopulation:
            cfg = replace(cfg, classification=replace(cfg.classification, repopulation=False))
        if not self.ekf_doc:
            cfg = replace(cfg, min_updates=NEVER)
        return cfg


@dataclass(frozen=True)
class DynamicFrame:
    """The stage's verdict on one frame with N keypoints (in the order of the input `Features`).

    - `keep` (N,) bool: keypoints tracking may use;
    - `kp_classes` (N,) int8 `KeypointClass`; `object_ids` (N,) int64 MapObject id, -1 background;
    - `moving` (N,) bool: keypoints of a segmentation object target (all False when it is off);
    - `objects`: the detected objects' states in this frame (before this frame's EKF update);
    - `ms`: milliseconds spent in the stage (classification, association, EKF, segmentation);
    - `moving_points`: (map id, map point ids) that earlier frames matched to keypoints the segmentation now
      finds on a mover (`forget_moving_points`);
    - `withheld` (N,) bool or None: keypoints of undecided objects left out of `keep` that no cue flagged as
      moving (`map_view_min_matches` may give them to tracking; None when it is off); `withheld_since_ns` (N,): the stamp of the
      frame that first detected each one's object (0 elsewhere).
    """

    keep: BoolArr
    kp_classes: npt.NDArray[np.int8]
    object_ids: npt.NDArray[np.int64]
    moving: BoolArr
    objects: tuple[ObjectState, ...]
    ms: float
    moving_points: tuple[tuple[int, npt.NDArray[np.int64]], ...] = ()
    withheld: BoolArr | None = None
    withheld_since_ns: npt.NDArray[np.int64] | None = None

    @property
    def kept_fraction(self) -> float:
        return float(self.keep.mean()) if len(self.keep) else 1.0


@dataclass
class _Past:
    keypoints_px: F64
    descriptors: npt.NDArray[np.uint8]
    depths_m: F64
    T_world_cam: F64 | None
    flag_age: npt.NDArray[np.int64]  # (N,) frames since the segmentation flagged the keypoint (NEVER: not)
    near_surface: npt.NDArray[np.float32] | None = None  # the free-space check's min-filtered depth (when on)
    point_ids: npt.NDArray[np.int64] | None = None  # (N,) map point tracking matched to each keypoint, -1 none
    map_id: int = -1  # the map those ids belong to


class DynamicFilter:
    """Per-frame keypoint filter for tracking; one instance per sequence (it keeps object and frame history)."""

    def __init__(self, config: DynamicConfig | None = None) -> None:
        self.config = config or DynamicConfig()
        self._tracker: DynamicObjectTracker | None = None
        self._camera: CameraIntrinsics | None = None
        self._history: deque[_Past] = deque(
            maxlen=max(self.config.segmentation_gap_frames, self.config.segmentation_long_gap_frames,
                       self.config.free_space_gap_frames if self.config.free_space_check else 1, 1)
        )
        self._n_frames = 0
        self._pending_age: npt.NDArray[np.int64] | None = None
        self._poses: deque[F64] = deque(maxlen=2)  # last two tracked poses, for the prediction
        self._pending: _Past | None = None
        self._moving_points: list[tuple[int, npt.NDArray[np.int64]]] = []  # this frame's, for `DynamicFrame`
        self._inherited: npt.NDArray[np.int64] | None = None
        self._inherited_map = -1
        self._classified = False
        self._matcher = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True)
        self.n_keypoints = 0
        self.n_kept = 0
        # per frame, the recent ones kept (`core.recent_values`): wall ms of the filter, thread CPU of the
        # segmentation (matching included) and of the free-space check (its filter included)
        self.frames_ms = RecentValues()
        self.segmentation_cpu_ms = RecentValues()
        self.free_space_cpu_ms = RecentValues()
        self._held: list[tuple[Detection, int]] = []  # (box, frames since last reported)
        self._first_seen: dict[int, tuple[int, int]] = {}  # object id -> (first, last) stamp detected
        self._movers = MoverTracker(self.config.movers) if self.config.movers.enabled else None

    @property
    def movers(self) -> MoverTracker | None:
        """The class-agnostic mover tracker (None when `movers.enabled` is off)."""
        return self._movers

    @property
    def objects(self) -> DynamicObjectTracker | None:
        """The object tracker (None before the first frame or when detection filtering is off)."""
        return self._tracker

    def _movable(self, detections: tuple[Detection, ...] | list[Detection] | None) -> tuple[Detection, ...]:
        """The frame's detections less those of `fixed_class_ids` (treated as static background)."""
        fixed = self.config.fixed_class_ids
        return tuple(d for d in (detections or ()) if d.class_id not in fixed)

    def before_tracking(
        self, rgbd: RgbdFrame, features: Features, detections: tuple[Detection, ...] | list[Detection] | None
    ) -> DynamicFrame:
        """Classify the N keypoints of `features` (extracted from `rgbd`) with the frame's detections."""
        t0 = time.perf_counter()
        cfg = self.config
        n = len(features)
        near: npt.NDArray[np.float32] | None = None  # the free-space check's min-filtered depth, kept in the history
        keep = np.ones(n, dtype=bool)
        classes = np.full(n, KeypointClass.STATIC, dtype=np.int8)
        object_ids = np.full(n, -1, dtype=np.int64)
        moving = np.zeros(n, dtype=bool)
        spread_only = np.zeros(n, dtype=bool)  # flagged by the segmentation's spread or vote alone
        objects: tuple[ObjectState, ...] = ()
        withheld: BoolArr | None = None
        self._classified = False
        if cfg.enabled:
            if cfg.segmentation:
                c0 = time.thread_time()
                moving, spread_only = self._segment(features, rgbd.camera)
                self.segmentation_cpu_ms.append((time.thread_time() - c0) * 1e3)
            if cfg.free_space_check:
                c0 = time.thread_time()
                near = near_surface(rgbd.depth_m, 640, cfg.free_space.window_px)
                moving |= self._free_space(rgbd, features, near)
                self.free_space_cpu_ms.append((time.thread_time() - c0) * 1e3)
            if self._movers is not None:
                moving |= self._movers.before_tracking(rgbd.stamp_ns, features, rgbd.camera)
            if cfg.detection_filtering:
                tracker = self._tracker_for(rgbd.camera)
                res = tracker.classify(
                    rgbd.stamp_ns, features.raw_px, rgbd.depth_m, self._with_held(self._movable(detections)),
                    moving_mask=moving if cfg.segmentation or cfg.free_space_check or self._movers is not None else None,
                )
                self._classified = True
                keep = res.use_for_tracking.copy()
                classes = res.classification.kp_classes.astype(np.int8)
                object_ids = res.kp_object_ids.copy()
                objects = res.objects
            if spread_only.any():
                # The spread yields where it would leave tracking short of keypoints with depth.
                if np.count_nonzero(keep & ~moving & (features.depths_m > 0)) < cfg.min_kept_keypoints:
                    moving &= ~spread_only
            keep &= ~moving
            short = int(np.count_nonzero(keep & (features.depths_m > 0))) < cfg.min_kept_keypoints
            if cfg.detection_filtering and cfg.ekf_doc:
                view = float(rgbd.camera.width * rgbd.camera.height)
                undecided = [o.object_id for o in objects if o.motion == ObjectMotion.UNKNOWN and (
                    cfg.keep_undecided or short or 0.0 < cfg.undecided_view_fraction * view <= box_area_px(o.box_xyxy))]
                keep |= (classes == KeypointClass.MOVABLE) & np.isin(object_ids, undecided) & ~moving
                if cfg.map_view_min_matches > 0:  # what the map-view check may give to tracking
                    unknown = [o.object_id for o in objects if o.motion == ObjectMotion.UNKNOWN]
                    withheld = (classes == KeypointClass.MOVABLE) & np.isin(object_ids, unknown) & ~moving & ~keep
                    self._note_sightings(rgbd.stamp_ns, objects)
        age = self._pending_age if self._pending_age is not None else np.full(n, NEVER, dtype=np.int64)
        self._pending = _Past(features.keypoints_px, features.descriptors, features.depths_m, None, age, near)
        self._pending_age = None
        self._n_frames += 1
        ms = (time.perf_counter() - t0) * 1e3
        self.n_keypoints += n
        self.n_kept += int(keep.sum())
        self.frames_ms.append(ms)
        found, self._moving_points = tuple(self._moving_points), []
        since = None
        if withheld is not None and withheld.any():
            since = np.zeros(n, np.int64)
            rows = np.flatnonzero(withheld)
            since[rows] = [self._first_seen[int(i)][0] for i in object_ids[rows]]
        else:
            withheld = None
        return DynamicFrame(keep, classes, object_ids, moving, objects, ms, found, withheld, since)

    def after_tracking(self, T_world_cam: F64 | None, point_ids: npt.NDArray[np.int64] | None = None,
                       map_id: int = -1) -> None:
        """The frame's camera-to-world pose (4, 4) from tracking, None when tracking failed; `point_ids` (N,) the
        map point (of map `map_id`) tracking matched to each of the frame's N keypoints, -1 none."""
        if self._classified and T_world_cam is not None and self._tracker is not None:
            self._tracker.update_filters(T_world_cam)  # the frame's result is not needed: skip building it
        self._classified = False
        if self._movers is not None:
            self._movers.after_tracking(T_world_cam)
        if self._pending is not None:
            self._pending.T_world_cam = None if T_world_cam is None else np.array(T_world_cam, dtype=np.float64)
            if point_ids is not None and self._inherited is not None and self._inherited_map == map_id \
                    and len(self._inherited) == len(point_ids):
                point_ids = np.where(point_ids >= 0, point_ids, self._inherited)
            self._pending.point_ids, self._pending.map_id = point_ids, map_id
            self._history.append(self._pending)
            self._pending = None
        self._inherited = None
        if T_world_cam is None:
            self._poses.clear()
        else:
            self._poses.append(np.array(T_world_cam, dtype=np.float64))

    def _note_sightings(self, stamp_ns: int, objects: tuple[ObjectState, ...]) -> None:
        """Remember when each object was first detected; objects unseen for a minute are forgotten."""
        for o in objects:
            first, _ = self._first_seen.get(o.object_id, (stamp_ns, stamp_ns))
            self._first_seen[o.object_id] = (first, stamp_ns)
        if len(self._first_seen) > 256:
            self._first_seen = {k: v for k, v in self._first_seen.items() if stamp_ns - v[1] < 60_000_000_000}

    def withheld_used(self, frame: DynamicFrame) -> None:
        """Tracking used the withheld keypoints of `frame`, the verdict `before_tracking` just returned
        (`map_view_min_matches`): they count as kept."""
        if frame.withheld is not None:
            self.n_kept += int(np.count_nonzero(frame.withheld & ~frame.keep))

    def kept_fraction(self) -> float:
        """Fraction of all keypoints so far that tracking was allowed to use."""
        return self.n_kept / self.n_keypoints if self.n_keypoints else 1.0

    def _with_held(self, detections: tuple[Detection, ...]) -> tuple[Detection, ...]:
        """The frame's detections plus held boxes of earlier frames that none of them overlaps."""
        cfg = self.config
        if cfg.detection_hold_frames <= 0:
            return detections
        fresh = [d for d in detections if d.class_id in cfg.hold_class_ids]
        held: list[tuple[Detection, int]] = [(d, 0) for d in fresh]
        for old, age in self._held:
            if age + 1 > cfg.detection_hold_frames or any(_iou(old, d) > 0.1 for d in fresh if d.class_id == old.class_id):
                continue
            held.append((old, age + 1))
        self._held = held
        g = cfg.detection_hold_grow_px
        extra = tuple(
            Detection((d.box_xyxy[0] - g * a, d.box_xyxy[1] - g * a, d.box_xyxy[2] + g * a, d.box_xyxy[3] + g * a), d.class_id, d.score)
            for d, a in held if a > 0
        )
        return detections + extra

    def _tracker_for(self, camera: CameraIntrinsics) -> DynamicObjectTracker:
        if self._tracker is None or camera != self._camera:
            self._tracker = DynamicObjectTracker(camera, self.config.tracker_config())
            self._camera = camera
        return self._tracker

    def _predicted_pose(self) -> F64 | None:
        if not self._poses:
            return None
        last = self._poses[-1]
        if len(self._poses) < 2:
            return last
        return last @ (invert(self._poses[0]) @ last)  # constant velocity

    def _free_space(self, rgbd: RgbdFrame, features: Features, near: npt.NDArray[np.float32]) -> BoolArr:
        """(N,) keypoints in space the frame `free_space_gap_frames` back saw empty (`movers/free_space_check`);
        none before that frame exists with a pose, or without a predicted pose now. `near`: this frame's own
        min-filtered depth (compared with the earlier frame's shape)."""
        cfg = self.config
        gap = cfg.free_space_gap_frames
        T_now = self._predicted_pose()
        if len(self._history) < gap or T_now is None:
            return np.zeros(len(features), dtype=bool)
        past = self._history[-gap]
        if past.T_world_cam is None or past.near_surface is None or past.near_surface.shape != near.shape:
            return np.zeros(len(features), dtype=bool)
        return free_space_violations(features.keypoints_px, features.depths_m, T_now, past.near_surface,
                                     past.T_world_cam, rgbd.camera, cfg.free_space)  # fmt: skip

    def _segment(self, features: Features, camera: CameraIntrinsics) -> tuple[BoolArr, BoolArr]:
        """(N,) keypoints of the frame that the two-frame segmentation puts on an object target, and (N,) those
        of them flagged by `segmentation_spread_px` or `flag_vote` alone.

        Against the frame `segmentation_gap_frames` back on every frame; with "edge_test" and
        `segmentation_long_gap_frames`, also against that frame on every `segmentation_long_every`-th frame,
        for movers too slow to clear the depth noise in the short gap (a board carried at 0.3 m/s 1 m ahead
        of a wall 3 m away moves 3 cm in 0.1 s, about twice the noise of its edges to the wall). A keypoint
        matched in the short gap to one flagged at most `segmentation_carry_frames` frames earlier stays
        flagged: a mover's keypoints that the test misses in one frame (a broken triangle, a wrong match)
        were often caught in an earlier one.
        """
        cfg = self.config
        n = len(features)
        moving = np.zeros(n, dtype=bool)
        age = np.full(n, NEVER, dtype=np.int64)  # frames since a test flagged the keypoint (carried by matches)
        tested = np.zeros(n, dtype=bool)
        T_now = self._predicted_pose()
        gaps = [cfg.segmentation_gap_frames]
        long_gap = cfg.segmentation_long_gap_frames
        if cfg.segmentation_method == "edge_test" and long_gap > 0 and self._n_frames % cfg.segmentation_long_every == 0:
            gaps.append(long_gap)
        for gap in gaps:
            if len(self._history) < gap or T_now is None or n == 0:
                break
            past = self._history[-gap]
            q, t, flagged = self._segment_pair(features, past, T_now, camera)
            moving[q[flagged]] = True
            tested[q] = True
            if cfg.forget_moving_points > 0 and past.point_ids is not None:
                ids = past.point_ids[t]
                if flagged.any():
                    self._moving_points.append((past.map_id, ids[flagged & (ids >= 0)]))
                if gap == cfg.segmentation_gap_frames:  # a keypoint left out of tracking keeps its point's id
                    self._inherited = np.full(n, -1, np.int64)
                    self._inherited[q] = ids
                    self._inherited_map = past.map_id
            if gap == cfg.segmentation_gap_frames and cfg.segmentation_carry_frames > 0:  # the earlier flags
                carried = past.flag_age[t] + gap
                fresh = carried <= cfg.segmentation_carry_frames
                age[q[fresh]] = np.minimum(age[q[fresh]], carried[fresh])
        age[moving] = 0
        self._pending_age = age
        moving |= age <= cfg.segmentation_carry_frames
        if cfg.segmentation_spread_px > 0.0 and moving.any():
            radius_px = cfg.segmentation_spread_px * camera.width / 640.0
            spread = _spread(moving, features, radius_px, cfg.segmentation_spread_depth_m)
            return spread, spread & ~moving
        if cfg.flag_vote.enabled and moving.any():
            voted = vote_flags(moving, tested, features.keypoints_px, features.depths_m, camera, cfg.flag_vote)
            return moving | voted, voted
        return moving, np.zeros(n, dtype=bool)

    def _segment_pair(
        self, features: Features, past: _Past, T_now: F64, camera: CameraIntrinsics
    ) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64], BoolArr]:
        """Matches (current indices q, earlier indices t) with depth in both frames and which of them lie on
        an object target; empty when too few."""
        cfg = self.config
        none = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, bool))
        if past.T_world_cam is None or len(past.descriptors) == 0:
            return none
        if cfg.segmentation_method == "edge_test":
            q, t = self._match_nearby(features, past, T_now, camera)
        else:
            q, t = self._match_brute_force(features, past)
        ok = (features.depths_m[q] > 0) & (past.depths_m[t] > 0)
        q, t = q[ok], t[ok]
        if len(q) < cfg.segmentation_min_matches:
            return none
        pixels = np.stack([past.keypoints_px[t], features.keypoints_px[q]])  # (2, M, 2)
        depths = np.stack([past.depths_m[t], features.depths_m[q]])  # (2, M)
        poses = np.stack([past.T_world_cam, T_now])  # (2, 4, 4)
        if cfg.segmentation_method == "edge_test":
            return q, t, edge_test_segment(pixels, depths, poses, camera, cfg.correlation).moving
        window = CorrelationWindow.from_pixels(np.arange(len(q)), pixels, depths, poses, camera)
        return q, t, segment(window, cfg.correlation).dynamic_mask

    def _match_brute_force(self, features: Features, past: _Past) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
        """Cross-checked brute-force matches (current indices, earlier indices) within the distance and shift bounds."""
        cfg = self.config
        matches = self._matcher.match(features.descriptors, past.descriptors)
        q = np.array([m.queryIdx for m in matches], dtype=np.int64)
        t = np.array([m.trainIdx for m in matches], dtype=np.int64)
        if not matches:
            return q, t
        dist = np.array([m.distance for m in matches])
        shift = np.linalg.norm(features.keypoints_px[q] - past.keypoints_px[t], axis=1)
        ok = (dist <= cfg.segmentation_max_hamming) & (shift <= cfg.segmentation_max_shift_px)
        return q[ok], t[ok]

    def _match_nearby(
        self, features: Features, past: _Past, T_now: F64, camera: CameraIntrinsics
    ) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
        """Mutual best matches searched around where each current keypoint with depth would be in the
        earlier image if it were static (predicted pose); a mover's match lies within the search radius."""
        assert past.T_world_cam is not None
        cfg = self.config
        T_past_now = invert(past.T_world_cam) @ T_now
        z = features.depths_m
        with np.errstate(divide="ignore", invalid="ignore"):
            pts = camera.backproject(features.keypoints_px, np.where(z > 0, z, np.nan)) @ T_past_now[:3, :3].T
            predicted = camera.project(pts + T_past_now[:3, 3])
        return match_nearby(features.keypoints_px, features.descriptors, past.keypoints_px, past.descriptors,
                            predicted, cfg.segmentation_max_shift_px, cfg.segmentation_max_hamming,
                            cfg.segmentation_search_k)


def _iou(a: Detection, b: Detection) -> float:
    ax0, ay0, ax1, ay1 = a.box_xyxy
    bx0, by0, bx1, by1 = b.box_xyxy
    iw = max(0.0, min(ax1, bx1) - max(ax0, bx0))
    ih = max(0.0, min(ay1, by1) - max(ay0, by0))
    inter = iw * ih
    union = a.area_px + b.area_px - inter
    return inter / union if union > 0 else 0.0


def _spread(moving: BoolArr, features: Features, radius_px: float, depth_tol_m: float, k: int = 8) -> BoolArr:
    """(N,) `moving` plus keypoints with depth that have one of their `k` nearest flagged keypoints within
    `radius_px` and `depth_tol_m`."""
    from scipy.spatial import cKDTree  # type: ignore[import-untyped]

    src = np.flatnonzero(moving & (features.depths_m > 0))
    dst = np.flatnonzero(~moving & (features.depths_m > 0))
    if len(src) == 0 or len(dst) == 0:
        return moving
    k = min(k, len(src))
    dist, nn = cKDTree(features.keypoints_px[src]).query(features.keypoints_px[dst], k=k, distance_upper_bound=radius_px)
    dist, nn = dist.reshape(len(dst), k), nn.reshape(len(dst), k)
    near = np.isfinite(dist)
    dz = np.abs(features.depths_m[src[np.where(near, nn, 0)]] - features.depths_m[dst][:, None])
    out = moving.copy()
    out[dst[np.any(near & (dz <= depth_tol_m), axis=1)]] = True
    return out
