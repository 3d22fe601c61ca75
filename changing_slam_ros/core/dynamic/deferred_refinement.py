"""Deferred pose refinement: a frame's final pose estimated again once the detections around it are in.

In real time a frame is tracked with earlier detections carried forward (`core.late_detections`), so keypoints on
a person outside a carried box reach its pose optimisation. When the detections of an image *after* the frame
arrive, every recently tracked frame between two consecutive detection sets is *bracketed*: its person boxes are
interpolated between the two sets (`interpolated_boxes`), its matched keypoints classified again with them
(`person_matches`, §4.1 with repopulation), and its pose optimised again (`optimised_pose`) on its matches less
those on a person, re-expressed in the map as it stands then (`current_map`; after `settle_s`, once local mapping
has adjusted the keyframes around it, which is most of the gain). The result replaces the frame's pose relative to
its reference keyframe: the final trajectory changes; the live one, the map and the published poses do not.
`DeferredRefinement` keeps the ring of tracked frames (`TrackedFrameMatches`: matches, poses, and the depth image
until bracketed; at most `max_frames`, forgotten after `max_age_s` unbracketed). A refined pose is kept when at
least `min_inliers` stay inliers and it moves less than `max_correction_m` / `max_correction_deg`.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.dynamic.detector import Detection, DetectionSet, iou_matrix
from changing_slam_ros.core.map.keyframe import KeypointClass
from changing_slam_ros.core.dynamic.keypoint_classification import KeypointClassificationConfig, classify_keypoints
from changing_slam_ros.core.dynamic.late_detections import grown_box
from changing_slam_ros.core.geometry.pose_optimizer import PinholeStereo, PoseObservations, optimize_pose
from changing_slam_ros.core.geometry.se3 import invert
from changing_slam_ros.errors import ConfigError

F64 = npt.NDArray[np.float64]
F32 = npt.NDArray[np.float32]
BoolArr = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class RefinementConfig:
    """YAML `tracking: deferred_refinement:` (see the module doc).

    - `enabled`: keep tracked frames and refine them when the detections after them arrive (real time only:
      a caller that tracks every frame with its own detections never hands a detection set over, and nothing is
      kept before the first set). On: in the replay of the graph's 1x cadence (`bench/late_detections.py`,
      `+refine`) it lowered the final ATE in 19 of 20 runs on three 30 Hz walking bags and the sample (means
      wxyz30s 1.06 -> 1.02 cm, walking_halfsphere 1.35 -> 1.31, walking_rpy 0.62 -> 0.60, sample 0.93 -> 0.89)
      for ~1.1 ms of CPU per 30 Hz frame.
    - `max_age_s`, `max_frames`: the ring of tracked frames (seconds behind the newest frame, count).
    - `max_bracket_gap_s`: two detection sets further apart do not bracket the frames between them.
    - `class_ids`: the classes whose boxes are interpolated (person: the a-priori dynamic class; the carried
      boxes are of these classes too, `CarryConfig.class_ids`).
    - `match_min_iou`: least IoU of a box of the earlier set and one of the later set to pair them.
    - `interpolated_grow_widths_per_s`: a paired box grows by this much of its size per side per second of the
      time to the nearer set; `carried_grow_widths_per_s`: a box of one set only, per second from that set.
    - `min_inliers`: fewer inliers after the new optimisation keep the tracked pose.
    - `max_correction_m`, `max_correction_deg`: a refined pose further from the tracked one is not used.
    - `pose_rounds`, `pose_iterations`: the optimisation's outlier rounds and iterations per round (tracking's).
    - `current_map`: optimise every bracketed frame again in the map as it is then (see the module doc); off: only
      frames with matches on a person, at once when bracketed, against the map as it was when tracked.
    - `settle_s`: with `current_map`, a bracketed frame is optimised again this long after it was tracked (the map
      around it bundle-adjusted meanwhile; `SlamSystem.settle_refinement` at the end of a run does the rest); 0 = at
      once when bracketed. 1 s: on wxyz30s (3:4 / 3:3) 0.5 / 1 / 2 / 4 s gave 0.93 / 0.92 / 0.90 / 0.89 and 0.94 /
      0.90 / 0.90 / 0.91 cm, on walking_rpy 0.59 / 0.59 / 0.61 / 0.61 and 0.56 / 0.56 / 0.62 / 0.62 (0.58 / 0.58
      without).
    """

    enabled: bool = True
    max_age_s: float = 0.6
    max_frames: int = 128
    max_bracket_gap_s: float = 0.5
    class_ids: tuple[int, ...] = (0,)
    match_min_iou: float = 0.1
    interpolated_grow_widths_per_s: float = 0.25
    carried_grow_widths_per_s: float = 0.5
    min_inliers: int = 30
    max_correction_m: float = 0.05
    max_correction_deg: float = 3.0
    pose_rounds: int = 4
    pose_iterations: int = 6
    current_map: bool = True
    settle_s: float = 1.0

    def __post_init__(self) -> None:
        where = "tracking.deferred_refinement"
        if self.max_age_s <= 0.0 or self.max_frames < 1:
            raise ConfigError(f"{where}: max_age_s must be > 0 and max_frames >= 1, got {self.max_age_s}, {self.max_frames}")
        if self.max_bracket_gap_s <= 0.0:
            raise ConfigError(f"{where}.max_bracket_gap_s: expected > 0, got {self.max_bracket_gap_s}")
        if self.interpolated_grow_widths_per_s < 0.0 or self.carried_grow_widths_per_s < 0.0:
            raise ConfigError(f"{where}: grow rates must be >= 0")
        if self.settle_s < 0.0:
            raise ConfigError(f"{where}.settle_s: expected >= 0, got {self.settle_s}")
        if self.pose_rounds < 1 or self.pose_iterations < 1:
            raise ConfigError(f"{where}: pose_rounds and pose_iterations must be >= 1")


@dataclass(frozen=True)
class TrackedFrameMatches:
    """One tracked frame as refinement needs it, M matches (the inliers of tracking's last optimisation).

    - `record_index`: the frame's index in the caller's trajectory records (`SlamSystem.records`);
    - `T_world_cam` (4, 4): the pose as tracked (online); `T_ref_cam` (4, 4): the same relative to the reference
      keyframe as tracked (what the final trajectory composes with the keyframe's final pose);
    - `raw_px` (M, 2) keypoints as detected (the detector's image coordinates), `uv_px` (M, 2) undistorted,
      `u_right_px` (M,) virtual right coordinate (< 0: no depth), `inv_sigma2` (M,) pyramid-level weights;
    - `point_ids` (M,) map point ids, `points_w` (M, 3) their positions (m) when the frame was tracked;
    - `depth_m` (H, W) float32 the frame's depth image (0 = no reading), for the boxes' depth statistics;
    - `camera`: intrinsics and virtual baseline of the projection;
    - `map_id`, `ref_kf_id`: the map and reference keyframe the frame was tracked in and against;
    - `person` (M,) bool: the matches on a person, once the frame is bracketed (None before; the depth image is
      let go then).
    """

    stamp_ns: int
    record_index: int
    T_world_cam: F64
    T_ref_cam: F64
    raw_px: F64
    uv_px: F64
    u_right_px: F64
    inv_sigma2: F64
    point_ids: npt.NDArray[np.int64]
    points_w: F64
    depth_m: F32 | None
    camera: PinholeStereo
    map_id: int = 0
    ref_kf_id: int = -1
    person: BoolArr | None = None

    def __len__(self) -> int:
        return len(self.point_ids)

    @property
    def nbytes(self) -> int:
        """Bytes held by the match arrays (the depth image is shared with the frame: not counted)."""
        arrays = (self.raw_px, self.uv_px, self.u_right_px, self.inv_sigma2, self.point_ids, self.points_w)
        return int(sum(a.nbytes for a in arrays))

    def in_map(self, T_world_cam: F64, keep: npt.NDArray[np.bool_], points_w: F64) -> TrackedFrameMatches:
        """The frame re-expressed in the map as it is now: pose (4, 4), the matches `keep` (M,) bool of it with their
        points now at `points_w` (K, 3), K = keep.sum()."""
        return replace(self, T_world_cam=T_world_cam, raw_px=self.raw_px[keep], uv_px=self.uv_px[keep],
                       u_right_px=self.u_right_px[keep], inv_sigma2=self.inv_sigma2[keep],
                       point_ids=self.point_ids[keep], points_w=points_w,
                       person=None if self.person is None else self.person[keep])  # fmt: skip


MapNow = Callable[[TrackedFrameMatches], "TrackedFrameMatches | None"]  # a frame in the map as it is now, or None


@dataclass(frozen=True)
class RefinedPose:
    """A frame's pose after refinement: `T_world_cam` and `T_ref_cam` (4, 4) replace the tracked ones in the final
    trajectory; `n_person` matches left out (now on a person), `n_inliers` of the rest; `translation_m`,
    `rotation_deg` how far it moved from the tracked pose."""

    stamp_ns: int
    record_index: int
    T_world_cam: F64
    T_ref_cam: F64
    n_person: int
    n_inliers: int
    translation_m: float
    rotation_deg: float


@dataclass
class RefinementStats:
    """Counters over a run: frames kept, bracketed, optimised again, refined (kept) and rejected, matches left out
    as on a person, and the process CPU time (ms) of all the ring's calls."""

    frames_added: int = 0
    frames_bracketed: int = 0
    frames_optimised: int = 0
    frames_refined: int = 0
    frames_rejected: int = 0
    matches_dropped: int = 0
    cpu_ms: float = 0.0


def interpolated_boxes(
    before: DetectionSet | None, after: DetectionSet, stamp_ns: int, cfg: RefinementConfig, width: int = 0, height: int = 0
) -> tuple[Detection, ...]:
    """The boxes of `cfg.class_ids` for an image stamped `stamp_ns` between `before` and `after` (stamps
    before.stamp_ns < stamp_ns <= after.stamp_ns; `before` None: `after`'s boxes carried back): paired boxes
    interpolated, unpaired ones carried, each grown as the module doc says and kept inside a `width` x `height`
    image (0: not clipped)."""
    b_dets = [d for d in after.detections if d.class_id in cfg.class_ids]
    if stamp_ns == after.stamp_ns:
        return tuple(b_dets)
    a_dets = [] if before is None else [d for d in before.detections if d.class_id in cfg.class_ids]
    t_a = stamp_ns if before is None else before.stamp_ns
    span_ns = max(after.stamp_ns - t_a, 1)
    since_a_s = (stamp_ns - t_a) * 1e-9
    until_b_s = (after.stamp_ns - stamp_ns) * 1e-9
    pairs = _pairs(a_dets, b_dets, cfg.match_min_iou)
    out: list[Detection] = []
    paired_a = {i for i, _ in pairs}
    paired_b = {j for _, j in pairs}
    w = (stamp_ns - t_a) / span_ns
    for i, j in pairs:
        a = np.asarray(a_dets[i].box_xyxy, dtype=np.float64)
        b = np.asarray(b_dets[j].box_xyxy, dtype=np.float64)
        box = (1.0 - w) * a + w * b
        grow = cfg.interpolated_grow_widths_per_s * min(since_a_s, until_b_s)
        out.append(Detection(grown_box(box, grow, width, height), b_dets[j].class_id, max(a_dets[i].score, b_dets[j].score)))
    for i, d in enumerate(a_dets):
        if i not in paired_a:
            box = grown_box(d.box_xyxy, cfg.carried_grow_widths_per_s * since_a_s, width, height)
            out.append(Detection(box, d.class_id, d.score))
    for j, d in enumerate(b_dets):
        if j not in paired_b:
            box = grown_box(d.box_xyxy, cfg.carried_grow_widths_per_s * until_b_s, width, height)
            out.append(Detection(box, d.class_id, d.score))
    return tuple(out)


def person_matches(frame: TrackedFrameMatches, boxes: tuple[Detection, ...], classification: KeypointClassificationConfig) -> BoolArr:
    """(M,) the frame's matches on a person in `boxes` (dynamic, or of a box whose keypoints are not used: §4.1 with
    repopulation on the frame's depth image)."""
    if not boxes or len(frame) == 0 or frame.depth_m is None:
        return np.zeros(len(frame), dtype=bool)
    cls = classify_keypoints(frame.raw_px, frame.depth_m, boxes, classification)
    return np.asarray((cls.kp_classes == KeypointClass.DYNAMIC) | (cls.kp_classes == KeypointClass.UNUSED))


def optimised_pose(frame: TrackedFrameMatches, person: BoolArr, cfg: RefinementConfig) -> RefinedPose | None:
    """`frame`'s pose optimised again from its pose without the matches `person` (M,); None when fewer than
    `min_inliers` stay inliers or it moves further than `max_correction_m` / `max_correction_deg`."""
    keep = ~person
    if int(keep.sum()) < cfg.min_inliers:
        return None
    obs = PoseObservations(frame.points_w[keep], frame.uv_px[keep], frame.u_right_px[keep], frame.inv_sigma2[keep])
    res = optimize_pose(invert(frame.T_world_cam), obs, frame.camera, rounds=cfg.pose_rounds, iterations=cfg.pose_iterations)
    if res.n_inliers < cfg.min_inliers:
        return None
    T_world_cam = invert(res.T_cam_world)
    T_cam_correction = invert(frame.T_world_cam) @ T_world_cam  # the change, in the tracked camera's frame
    moved_m = float(np.linalg.norm(T_cam_correction[:3, 3]))
    cos = float(np.clip((np.trace(T_cam_correction[:3, :3]) - 1.0) / 2.0, -1.0, 1.0))
    turned_deg = math.degrees(math.acos(cos))
    if moved_m > cfg.max_correction_m or turned_deg > cfg.max_correction_deg:
        return None
    return RefinedPose(frame.stamp_ns, frame.record_index, T_world_cam, frame.T_ref_cam @ T_cam_correction,
                       int(person.sum()), res.n_inliers, moved_m, turned_deg)  # fmt: skip


def refine_frame(
    frame: TrackedFrameMatches,
    boxes: tuple[Detection, ...],
    cfg: RefinementConfig,
    classification: KeypointClassificationConfig,
) -> tuple[RefinedPose | None, int]:
    """`frame`'s pose optimised again, in the map as tracked, without its matches on a person in `boxes`; returns
    the refined pose (None: nothing on a person, or the optimisation not trusted) and the number of those matches."""
    person = person_matches(frame, boxes, classification)
    n_person = int(person.sum())
    if n_person == 0:
        return None, 0
    return optimised_pose(frame, person, cfg), n_person


class DeferredRefinement:
    """The ring of recently tracked frames and the detection sets seen. `add` each tracked frame, hand each detection
    set over with `on_detections` as it arrives, and `settle_all` at the end of the run; each returns the frames
    refined. `now` (optional in each) re-expresses a frame in the map as it is then (`current_map`)."""

    def __init__(self, config: RefinementConfig, classification: KeypointClassificationConfig | None = None) -> None:
        self.config = config
        self.classification = classification or KeypointClassificationConfig()
        self._frames: deque[TrackedFrameMatches] = deque()  # by stamp
        self._sets: list[DetectionSet] = []  # by stamp, those within max_age_s + max_bracket_gap_s of the newest
        self.stats = RefinementStats()

    def __len__(self) -> int:
        return len(self._frames)

    @property
    def nbytes(self) -> int:
        """Bytes of the ring's match arrays (depth images not counted: shared with the frames)."""
        return sum(f.nbytes for f in self._frames)

    def add(self, frame: TrackedFrameMatches, now: MapNow | None = None) -> list[RefinedPose]:
        """Keep `frame`. Frames not bracketed within `max_age_s` are forgotten; bracketed frames `settle_s` older
        than it (or beyond `max_frames`) are settled: optimised again in the map as it is now and forgotten. When a
        later detection set is in already (the frame waited in a queue while the detector went past it), `frame` is
        bracketed at once; when its own set is in, it was tracked with it and is left as it is (lossless: every
        frame)."""
        c0 = time.process_time()
        cfg = self.config
        out: list[RefinedPose] = []
        self._frames.append(frame)
        self.stats.frames_added += 1
        unbracketed_ns = frame.stamp_ns - round(cfg.max_age_s * 1e9)
        settled_ns = frame.stamp_ns - round(cfg.settle_s * 1e9)
        kept: deque[TrackedFrameMatches] = deque()
        n_over = max(len(self._frames) - cfg.max_frames, 0)
        for k, f in enumerate(self._frames):
            if f.person is None:
                if f.stamp_ns >= unbracketed_ns and k >= n_over:
                    kept.append(f)
            elif f.stamp_ns <= settled_ns or k < n_over:
                out += self._optimised(f, now)
            else:
                kept.append(f)
        self._frames = kept
        later = [s for s in self._sets if s.stamp_ns >= frame.stamp_ns]
        if later and later[0].stamp_ns != frame.stamp_ns:
            out += self._bracket(len(self._frames) - 1, self._set_before(later[0].stamp_ns), later[0], now)
        self.stats.cpu_ms += (time.process_time() - c0) * 1e3
        return out

    @property
    def has_detections(self) -> bool:
        """Whether a detection set was handed over yet (before that no frame can be bracketed)."""
        return bool(self._sets)

    def on_detections(self, detections: DetectionSet, now: MapNow | None = None) -> list[RefinedPose]:
        """A detection set has arrived: the kept frames it brackets with the set before it (and, when it came
        out of order, those it brackets with the set after it) are classified again; with `settle_s` 0 (or
        `current_map` off, or no `now`) they are refined at once and returned, else they wait to be settled."""
        c0 = time.process_time()
        stamps = [s.stamp_ns for s in self._sets]
        if detections.stamp_ns in stamps:
            return []
        self._sets.append(detections)
        self._sets.sort(key=lambda s: s.stamp_ns)
        newest = self._sets[-1].stamp_ns
        keep_ns = round((self.config.max_age_s + self.config.max_bracket_gap_s) * 1e9)
        self._sets = [s for s in self._sets if s.stamp_ns >= newest - keep_ns]
        out: list[RefinedPose] = []
        before = self._set_before(detections.stamp_ns)
        later = [s for s in self._sets if s.stamp_ns > detections.stamp_ns]
        brackets = [(before, detections)] + ([(detections, later[0])] if later else [])
        for lo, hi in brackets:
            lo_ns = lo.stamp_ns if lo is not None else hi.stamp_ns - 1
            for k, frame in enumerate(self._frames):
                if lo_ns < frame.stamp_ns <= hi.stamp_ns and frame.person is None:
                    out += self._bracket(k, lo, hi, now)
        self.stats.cpu_ms += (time.process_time() - c0) * 1e3
        return out

    def settle_all(self, now: MapNow | None = None) -> list[RefinedPose]:
        """The end of the run: every bracketed frame still waiting is optimised again in the map as it is now."""
        c0 = time.process_time()
        out: list[RefinedPose] = []
        for f in self._frames:
            if f.person is not None:
                out += self._optimised(f, now)
        self._frames = deque(f for f in self._frames if f.person is None)
        self.stats.cpu_ms += (time.process_time() - c0) * 1e3
        return out

    def _set_before(self, stamp_ns: int) -> DetectionSet | None:
        """The newest set before `stamp_ns` within `max_bracket_gap_s`, else None."""
        earlier = [s for s in self._sets if s.stamp_ns < stamp_ns]
        if not earlier or (stamp_ns - earlier[-1].stamp_ns) * 1e-9 > self.config.max_bracket_gap_s:
            return None
        return earlier[-1]

    def _waits(self, now: MapNow | None) -> bool:
        """Whether a bracketed frame waits `settle_s` to be optimised again (else: at once)."""
        return self.config.settle_s > 0.0 and self.config.current_map and now is not None

    def _bracket(self, k: int, before: DetectionSet | None, after: DetectionSet, now: MapNow | None) -> list[RefinedPose]:
        """Frame `k` of the ring between `before` and `after`: its matches on a person found (the depth image is then
        let go); optimised again at once unless it waits to be settled."""
        frame = self._frames[k]
        if (before is None and frame.stamp_ns != after.stamp_ns) or frame.depth_m is None:
            return []  # not bracketed: only the set's own frame is refined without a set before it
        self.stats.frames_bracketed += 1
        h, w = frame.depth_m.shape[:2]
        boxes = interpolated_boxes(before, after, frame.stamp_ns, self.config, w, h)
        frame = replace(frame, person=person_matches(frame, boxes, self.classification), depth_m=None)
        self._frames[k] = frame
        if self._waits(now):
            return []
        return self._optimised(frame, now)

    def _optimised(self, frame: TrackedFrameMatches, now: MapNow | None) -> list[RefinedPose]:
        """A bracketed frame optimised again without its matches on a person (in the map as it is now when
        `current_map` and `now`); [] when nothing changes or the result is not trusted."""
        assert frame.person is not None
        n_person = int(frame.person.sum())
        moved = now(frame) if now is not None and self.config.current_map else None
        if n_person == 0 and moved is None:
            return []  # the same matches in the same map: the tracked pose
        self.stats.frames_optimised += 1
        self.stats.matches_dropped += n_person
        refined = optimised_pose(moved or frame, moved.person if moved is not None else frame.person, self.config)
        if refined is None:
            self.stats.frames_rejected += 1
            return []
        self.stats.frames_refined += 1
        return [replace(refined, n_person=n_person)]


def _pairs(a: list[Detection], b: list[Detection], min_iou: float) -> list[tuple[int, int]]:
    """Greedy pairs (i, j) of boxes of `a` and `b`, same class, highest IoU first, IoU >= `min_iou`."""
    if not a or not b:
        return []
    iou = iou_matrix(np.array([d.box_xyxy for d in a], dtype=np.float64), np.array([d.box_xyxy for d in b], dtype=np.float64))
    same = np.array([[da.class_id == db.class_id for db in b] for da in a])
    iou = np.where(same, iou, -1.0)
    pairs: list[tuple[int, int]] = []
    while True:
        i, j = np.unravel_index(int(np.argmax(iou)), iou.shape)
        if iou[i, j] < min_iou:
            return pairs
        pairs.append((int(i), int(j)))
        iou[i, :] = -1.0
        iou[:, j] = -1.0
