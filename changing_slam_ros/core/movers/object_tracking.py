"""Moving object targets and their 6-DoF tracking (Dai et al. 2021, Sections 3.2.3, 3.3.2 and 3.5.1).

A `MovingObject` is created from an object target of the segmentation: its frame has its origin at the
centre of the target's points and the world's axes (the paper's T_0^g), and its points are stored in
that frame. Each new frame, the object's matched points give its pose by motion-only object BA (eq. 7,
initialised by a closed-form alignment of the measured points); when the object has moved or turned
enough since the last keypose, or too few of its points are still tracked, the frame becomes a keypose,
and full object BA (eq. 11) refines the points and the keyposes of a sliding window.

Poses are object-to-world `T_world_obj` (4, 4), stamps in nanoseconds.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.backend.object_ba import (
    ObjectBAConfig,
    ObjectObservations,
    align_points,
    full_object_ba,
    motion_only_object_ba,
)
from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.movers.point_correlation import CorrelationWindow, SegmentationResult
from changing_slam_ros.core.geometry.se3 import invert, make_pose, rotation_angle_rad, transform_points
from changing_slam_ros.core.geometry.trajectory import Trajectory
from changing_slam_ros.errors import ConfigError

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


@dataclass(frozen=True)
class ObjectTrackingConfig:
    """Keypose policy and object BA settings.

    - `min_tracked_points`: fewer matched points than this and the frame's pose is not estimated.
    - `keypose_translation_m`, `keypose_rotation_rad`: motion since the last keypose that makes a keypose.
    - `keypose_tracked_ratio`: a keypose is also made when fewer than this fraction of the points seen in
      the last keypose are tracked ("the tracked features change significantly").
    - `window_keyposes`: keyposes in the sliding window of full object BA (the reference keypose is
      always kept, as it holds the gauge). An object keeps only these keyposes' measurements (older ones
      can never enter the window again, also not after a merge: see `MovingObject.keep_keyposes`).
    - `optimise_every_keyposes`: full object BA (eq. 11) runs at every n-th keypose of an object (1: at
      every keypose, the paper). The keyposes in between still enter the window; motion-only BA (eq. 7)
      tracks every frame either way. Default 3: on unknown_mover a keypose is made at ~80 % of the frames
      (the tracked-ratio test) and eq. 11 was half the mover stage's CPU time; with 3 (and the bound
      below) the stage took 0.64x the CPU at P 0.991 / R 0.960 and 0.70 cm object ATE (1: P 0.974 /
      R 0.967, 0.61 cm; 4: 1.84 cm).
    - `max_model_points`: beyond the paper, a bound on an object's model (0 = none). Merged targets add
      points every few frames (unknown_mover: 1400 points after 24 s, so association, merging and eq. 7
      grew with it); above the bound, the points seen in fewest keyposes of the window go (the newest
      kept on ties), never those of the reference keypose (see `MovingObject.bound_model`). Default 500.
    - `gate_m`, `gate_m_per_s`, `gate_rad`, `gate_rad_per_s`: beyond the paper, a motion gate. A pose from
      eq. 7 further than gate_m + gate_m_per_s * dt (or turned more than gate_rad + gate_rad_per_s * dt)
      from the pose extrapolated at constant velocity (dt since the last pose) is rejected (the frame is
      not tracked), and a full BA (eq. 11) that moves a keypose by more than gate_m or gate_rad is not
      applied. On unknown_mover a wrong eq. 7 solution turned the box by 40 degrees in one frame and
      spoilt the rest of its trajectory. 0 for gate_m switches the gate off.
    - `ba`: noise model and solver of object BA.
    """

    min_tracked_points: int = 6
    keypose_translation_m: float = 0.05
    keypose_rotation_rad: float = 0.1
    keypose_tracked_ratio: float = 0.7
    window_keyposes: int = 8
    optimise_every_keyposes: int = 3
    max_model_points: int = 500
    gate_m: float = 0.03
    gate_m_per_s: float = 0.5
    gate_rad: float = 0.2
    gate_rad_per_s: float = 1.0
    ba: ObjectBAConfig = field(default_factory=ObjectBAConfig)

    def __post_init__(self) -> None:
        if self.min_tracked_points < 3:
            raise ConfigError(f"object_tracking.min_tracked_points: expected >= 3, got {self.min_tracked_points}")
        if self.window_keyposes < 2:
            raise ConfigError(f"object_tracking.window_keyposes: expected >= 2, got {self.window_keyposes}")
        if self.optimise_every_keyposes < 1 or self.max_model_points < 0:
            raise ConfigError(
                "object_tracking: optimise_every_keyposes must be >= 1 and max_model_points >= 0, got "
                f"{self.optimise_every_keyposes}, {self.max_model_points}"
            )


@dataclass(frozen=True)
class MovingObjectTrack:
    """A moving object and its trajectory, as the system exports and publishes it.

    - `object_id`: unique within the run; `class_id`: COCO 0-based class, -1 for a class-agnostic target.
    - `stamps_ns`: (N,) int64 ascending, the frames where the object's pose was estimated.
    - `T_world_obj`: (N, 4, 4) object-to-world poses (map frame: the SLAM world), object frame origin at
      the centre of its points when it was first segmented, axes the world's then.
    - `n_points`: points of the object's model.
    """

    object_id: int
    class_id: int
    stamps_ns: I64
    T_world_obj: F64
    n_points: int

    def __post_init__(self) -> None:
        n = len(self.stamps_ns)
        if self.T_world_obj.shape != (n, 4, 4):
            raise ValueError(f"MovingObjectTrack {self.object_id}: {n} stamps need T_world_obj ({n}, 4, 4), got {self.T_world_obj.shape}")
        if n and np.any(np.diff(self.stamps_ns) <= 0):
            raise ValueError(f"MovingObjectTrack {self.object_id}: stamps_ns must be strictly increasing")

    @property
    def first_stamp_ns(self) -> int:
        return int(self.stamps_ns[0])

    @property
    def last_stamp_ns(self) -> int:
        return int(self.stamps_ns[-1])

    def trajectory(self) -> Trajectory:
        return Trajectory.from_poses(self.stamps_ns.astype(np.float64) * 1e-9, self.T_world_obj)


@dataclass
class MovingObject:
    """One object target.

    - `object_id`: unique id.
    - `point_ids`: (P,) int64 map point ids of its points.
    - `points_obj`: (P, 3) metres, the points in the object frame.
    - `poses`: stamp_ns -> T_world_obj (4, 4) for every frame where the object was tracked.
    - `keyposes`: the keypose measurements, oldest (the reference) first.
    - `keyposes_since_optimise`: keyposes added since the last full object BA (eq. 11).
    """

    object_id: int
    point_ids: I64
    points_obj: F64
    poses: dict[int, F64] = field(default_factory=dict)
    keyposes: list[ObjectObservations] = field(default_factory=list)
    keyposes_since_optimise: int = 0

    @classmethod
    def create(
        cls,
        object_id: int,
        point_ids: I64,
        points_world: F64,
        stamp_ns: int,
        frame: "FrameObjectMeasurements | None" = None,
    ) -> "MovingObject":
        """New target from its points (P, 3) in the world at `stamp_ns` (the paper's T_0^g: their centre).

        `frame`, the measurements of the creation frame, becomes the reference keypose when given.
        """
        centre = points_world.mean(axis=0)
        obj = cls(object_id, np.asarray(point_ids, dtype=np.int64), points_world - centre)
        obj.poses[stamp_ns] = make_pose(np.eye(3), centre)
        if frame is not None:
            idx = obj.index_of(frame.point_ids)
            hit = idx >= 0
            obj.keyposes.append(ObjectObservations(stamp_ns, frame.T_world_cam, idx[hit], frame.points_cam[hit]))
        return obj

    @property
    def stamps_ns(self) -> list[int]:
        return sorted(self.poses)

    def last_pose(self) -> tuple[int, F64]:
        stamp = max(self.poses)
        return stamp, self.poses[stamp]

    def points_world(self, stamp_ns: int) -> F64:
        """The object's points (P, 3) in the world at a tracked stamp."""
        return transform_points(self.poses[stamp_ns], self.points_obj)

    def trajectory(self) -> Trajectory:
        """Object-to-world poses over time (TUM convention: origin of the object frame, orientation)."""
        stamps = self.stamps_ns
        return Trajectory.from_poses(np.array(stamps, dtype=np.float64) * 1e-9, np.stack([self.poses[s] for s in stamps]))

    def to_track(self, class_id: int = -1) -> MovingObjectTrack:
        """The object's trajectory so far as an immutable `MovingObjectTrack`."""
        stamps = self.stamps_ns
        poses = np.stack([self.poses[s] for s in stamps]) if stamps else np.zeros((0, 4, 4))
        return MovingObjectTrack(self.object_id, class_id, np.array(stamps, dtype=np.int64), poses, len(self.point_ids))

    def predict(self, stamp_ns: int, max_ratio: float = 3.0) -> F64:
        """T_world_obj (4, 4) at `stamp_ns` from the last two poses at constant (linear and angular) velocity.

        The extrapolation covers at most `max_ratio` times the interval between those two poses.
        """
        from scipy.spatial.transform import Rotation  # type: ignore[import-untyped]

        stamps = [s for s in self.stamps_ns if s < stamp_ns] or self.stamps_ns
        last = self.poses[stamps[-1]].copy()
        if len(stamps) >= 2:
            prev = self.poses[stamps[-2]]
            ratio = min((stamp_ns - stamps[-1]) / (stamps[-1] - stamps[-2]), max_ratio)
            last[:3, 3] += (last[:3, 3] - prev[:3, 3]) * ratio
            turn = Rotation.from_matrix(prev[:3, :3].T @ last[:3, :3]).as_rotvec() * ratio
            last[:3, :3] = last[:3, :3] @ Rotation.from_rotvec(turn).as_matrix()
        return last

    def keep_keyposes(self, window: int) -> None:
        """Drop the keyposes that no full-BA window of `window` keyposes can hold again: all but the reference
        and the newest `window - 1`. Exact: a merge (`object_merging.fuse_into`) sorts the keyposes of both
        objects by stamp, and the newest `window - 1` of the union are among each object's newest."""
        if len(self.keyposes) > window:
            self.keyposes = self.keyposes[:1] + self.keyposes[-(window - 1) :]

    def bound_model(self, max_points: int) -> None:
        """Keep at most `max_points` points (0: no bound): those seen in the most keyposes, the newest (last
        added) first on ties, and always the reference keypose's points (they tie the gauge of eq. 11 to
        the rest). Keyposes lose the measurements of dropped points; poses are unchanged."""
        n = len(self.point_ids)
        if max_points <= 0 or n <= max_points:
            return
        seen = np.zeros(n, dtype=np.int64)
        for kp in self.keyposes:
            seen += np.bincount(kp.point_index, minlength=n)
        in_ref = np.zeros(n, dtype=bool)
        if self.keyposes:
            in_ref[self.keyposes[0].point_index] = True
        order = np.lexsort((np.arange(n), seen, in_ref))  # ascending priority: keep the tail
        keep = np.sort(order[-max(max_points, int(in_ref.sum())) :])
        new_index = np.full(n, -1, dtype=np.int64)
        new_index[keep] = np.arange(len(keep))
        self.point_ids, self.points_obj = self.point_ids[keep], self.points_obj[keep]
        kept = []
        for kp in self.keyposes:
            idx = new_index[kp.point_index]
            ok = idx >= 0
            kept.append(ObjectObservations(kp.stamp_ns, kp.T_world_cam, idx[ok], kp.points_cam[ok]))
        self.keyposes = kept

    def index_of(self, point_ids: I64) -> I64:
        """Indices (N,) into this object's points of `point_ids` (N,); -1 where a point is not the object's."""
        order = np.argsort(self.point_ids)
        pos = np.searchsorted(self.point_ids, point_ids, sorter=order)
        pos = np.clip(pos, 0, len(order) - 1)
        found = self.point_ids[order[pos]] == point_ids
        return np.where(found, order[pos], -1).astype(np.int64)


@dataclass(frozen=True)
class FrameObjectMeasurements:
    """Matched points of one frame that may belong to objects.

    - `stamp_ns`, `T_world_cam` (4, 4): the frame and its camera-to-world pose from camera tracking.
    - `point_ids`: (N,) map point ids of the matched keypoints.
    - `points_cam`: (N, 3) metres, their back-projection (u, v, depth) in the camera frame.
    """

    stamp_ns: int
    T_world_cam: F64
    point_ids: I64
    points_cam: F64


@dataclass(frozen=True)
class TrackResult:
    """Outcome of tracking one object in one frame: `tracked` False when too few points were matched."""

    tracked: bool
    n_points: int
    n_inliers: int
    is_keypose: bool
    T_world_obj: F64 | None


class ObjectTracker:
    """Tracks `MovingObject`s frame by frame (eq. 7) and refines them at keyposes (eq. 11)."""

    def __init__(self, camera: CameraIntrinsics, config: ObjectTrackingConfig) -> None:
        self.camera = camera
        self.config = config

    def observations(self, obj: MovingObject, frame: FrameObjectMeasurements) -> ObjectObservations:
        """The subset of the frame's measurements that hit the object's points."""
        idx = obj.index_of(frame.point_ids)
        hit = idx >= 0
        return ObjectObservations(frame.stamp_ns, frame.T_world_cam, idx[hit], frame.points_cam[hit])

    def track(self, obj: MovingObject, frame: FrameObjectMeasurements) -> TrackResult:
        """Estimate the object's pose in `frame` (eq. 7) and decide whether it is a keypose."""
        obs = self.observations(obj, frame)
        n = len(obs.point_index)
        if n < self.config.min_tracked_points:
            return TrackResult(False, n, 0, False, None)
        # Initial pose: closed-form alignment of the object's points with their measured world positions,
        # refined robustly by motion-only object BA.
        world = transform_points(frame.T_world_cam, obs.points_cam)
        init = align_points(obj.points_obj[obs.point_index], world)
        result = motion_only_object_ba(obj.points_obj, obs, init, self.camera, self.config.ba)
        n_in = int(result.inliers.sum())
        if n_in < self.config.min_tracked_points or not self._within_gate(obj, frame.stamp_ns, result.T_world_obj):
            return TrackResult(False, n, n_in, False, None)
        obj.poses[frame.stamp_ns] = result.T_world_obj
        # A keypose keeps all the frame's measurements, not only eq. 7's inliers: a point whose shape is
        # still wrong fails eq. 7 in every frame, and only full BA (with its own outlier rounds) can fix it.
        keypose = self._is_keypose(obj, obs, result.T_world_obj)
        if keypose:
            obj.keyposes.append(obs)
            obj.keep_keyposes(self.config.window_keyposes)
            obj.keyposes_since_optimise += 1
        return TrackResult(True, n, n_in, keypose, result.T_world_obj)

    def optimise_due(self, obj: MovingObject) -> bool:
        """Whether full object BA is due after this keypose (see `optimise_every_keyposes`)."""
        return obj.keyposes_since_optimise >= self.config.optimise_every_keyposes

    def _within_gate(self, obj: MovingObject, stamp_ns: int, T_world_obj: F64) -> bool:
        """The motion gate (see `ObjectTrackingConfig`) against the pose extrapolated to `stamp_ns`."""
        cfg = self.config
        earlier = [s for s in obj.poses if s < stamp_ns]
        if cfg.gate_m <= 0.0 or not earlier:
            return True
        dt = (stamp_ns - max(earlier)) * 1e-9
        delta = invert(obj.predict(stamp_ns)) @ T_world_obj
        return bool(
            np.linalg.norm(delta[:3, 3]) <= cfg.gate_m + cfg.gate_m_per_s * dt
            and rotation_angle_rad(delta[:3, :3]) <= cfg.gate_rad + cfg.gate_rad_per_s * dt
        )

    def _is_keypose(self, obj: MovingObject, obs: ObjectObservations, T_world_obj: F64) -> bool:
        if not obj.keyposes:
            return True
        last = obj.keyposes[-1]
        T_last = obj.poses[last.stamp_ns]
        delta = invert(T_last) @ T_world_obj
        moved = np.linalg.norm(delta[:3, 3]) > self.config.keypose_translation_m
        turned = rotation_angle_rad(delta[:3, :3]) > self.config.keypose_rotation_rad
        tracked = np.isin(last.point_index, obs.point_index).mean() < self.config.keypose_tracked_ratio
        return bool(moved or turned or tracked)

    def optimise(self, obj: MovingObject) -> None:
        """Full object BA (eq. 11) over the reference keypose and the latest keyposes; updates in place."""
        obj.keyposes_since_optimise = 0
        if len(obj.keyposes) < 2:
            return
        window = [obj.keyposes[0]] + obj.keyposes[1:][-(self.config.window_keyposes - 1) :]
        init = np.stack([obj.poses[kp.stamp_ns] for kp in window])
        result = full_object_ba(obj.points_obj, window, init, self.camera, self.config.ba)
        if self.config.gate_m > 0.0:
            for before, after in zip(init, result.T_world_obj):
                delta = invert(before) @ after
                if np.linalg.norm(delta[:3, 3]) > self.config.gate_m or rotation_angle_rad(delta[:3, :3]) > self.config.gate_rad:
                    return  # a keypose jumped: keep the previous estimate
        obj.points_obj = result.points_obj
        for kp, pose in zip(window, result.T_world_obj):
            obj.poses[kp.stamp_ns] = pose


def objects_from_segmentation(
    result: SegmentationResult,
    window: CorrelationWindow,
    stamp_ns: int,
    first_id: int,
    frame_index: int = -1,
    min_points: int = 6,
) -> list[MovingObject]:
    """One new `MovingObject` per object target of a segmentation (Section 3.2.3).

    Each is created in frame `frame_index` of the window (the newest by default; `stamp_ns` is its stamp)
    from the target's points measured there, which also become its reference keypose. Ids count up from
    `first_id`; targets with fewer than `min_points` points measured in that frame are skipped.
    """
    k = frame_index % len(window.T_world_cam)
    T_world_cam = window.T_world_cam[k]
    objects: list[MovingObject] = []
    for target in result.target_indices():
        idx = target[window.observed[k, target]]
        if len(idx) < min_points:
            continue
        ids = window.point_ids[idx]
        points_cam = window.points_cam[k, idx]
        frame = FrameObjectMeasurements(stamp_ns, T_world_cam, ids, points_cam)
        world = transform_points(T_world_cam, points_cam)
        objects.append(MovingObject.create(first_id + len(objects), ids, world, stamp_ns, frame))
    return objects
