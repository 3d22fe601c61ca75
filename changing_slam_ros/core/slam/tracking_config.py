"""The `tracking:` config section: thresholds and windows of `core.slam.tracking.Tracker`."""

from __future__ import annotations

from dataclasses import dataclass, field

from changing_slam_ros.core.dynamic.deferred_refinement import RefinementConfig
from changing_slam_ros.core.slam.motion_gate import MotionGateConfig
from changing_slam_ros.core.slam.rotation_vote import RotationVoteConfig
from changing_slam_ros.core.slam.still_camera import StillCameraConfig
from changing_slam_ros.errors import ConfigError


@dataclass(frozen=True)
class TrackingConfig:
    """YAML section `tracking:`.

    - `min_init_points`: keypoints with depth in the image needed to start a map (counted before the dynamic
      stage drops keypoints on movers: the test is for a view with enough texture);
      `min_init_kept_points`: of them, the ones tracking is given that are needed too. A person standing in the
      first view then delays the map only when the rest of the view is nearly bare: on the randomised dynamic
      family's tuning seeds 0-59, a person close in front of a gravel wall took the first 15 frames' poses
      when the kept keypoints had to reach `min_init_points` (seed 44).
    - `radius_motion_px`, `radius_local_px`, `radius_reloc_px`: projection search windows at level 0.
    - `min_motion_inliers`, `min_local_inliers`, `min_reloc_inliers`: acceptance thresholds (ORB-SLAM: -, 30, 50).
    - `n_local_keyframes`: keyframes whose points form the local map.
    - `keyframe_ratio`: new keyframe when inliers < ratio * well-observed points of the reference (0.75).
    - `min_frames_between_keyframes`, `max_frames_between_keyframes`: keyframe spacing bounds.
    - `close_tracked_min`, `close_untracked_min`: ORB-SLAM's "need close points" rule (100 / 70).
    - `max_time_gap_s`: a larger (or negative) stamp step invalidates the motion model.
    - `velocity_rescale_tolerance`: the constant-velocity prediction is the last frame-to-frame motion, scaled
      by the ratio of this frame's stamp step to that motion's when the two differ by more than this fraction
      (frames dropped in real time, gaps in a recording); within it the motion is used as is (ORB-SLAM). A
      negative value never scales.
    - `n_reloc_candidates`: keyframes tried per relocalisation; `lost_frames_new_map`: failures before a new map.
    - `loaded_map_grace_s`: a session started from a saved map (`Tracker.start_from_map`) tries relocalisation
      against it on every frame for this long (seconds from the first frame) before it starts a new map.
    - `initial_pose_timeout_s`: an initial pose (`Tracker.set_pose_hint`, `core/slam/initial_pose.py`) limits
      relocalisation to its surroundings for this long (seconds of frames); then the whole map is searched again.
    - `pose_iterations_per_round`: Gauss-Newton iterations at most in each of the pose optimisation's four
      rounds (each round also stops when the step is negligible). 2 saves ~20 % of the pose optimisation's CPU
      with the ATE unchanged on six sequences, but test_changing_system's moved chair then gets no map object at
      its new place, so it stays 6.
    - `motion_pose_rounds`: rounds of the frame-to-frame pose optimisation (the local-map one that follows always
      runs four, ORB-SLAM's count); the first two use the Huber kernel. 2 was ATE-neutral on the same six
      sequences but saved only ~0.25 ms per frame (within the benchmark's noise), so it stays 4.
    - `busy_mapping_weak_ratio`: ORB-SLAM's keyframe rule when local mapping is busy (`Tracker.mapping_idle`
      False, set by a caller whose mapping runs elsewhere: the real-time graph): a keyframe then needs
      `max_frames_between_keyframes` frames since the last one, or tracking weak (inliers under this fraction of
      the reference keyframe's points) or short of close points, as ORB-SLAM's c1a / c1c; an idle mapper takes one
      whenever the ratio rule holds (c1b). 0 = insert as if idle. Offline and lossless, mapping is always idle.
    - `object_keyframe_min_frames`: a keyframe asked for by the object layer (`Tracker.request_keyframe`: a whole
      detection of an object the object map does not explain yet, so that an object seen briefly between two
      keyframes still reaches the map) is taken once this many frames have passed since the last keyframe.
    - `deferred_refinement`: real time with late detections, a tracked frame's pose in the final trajectory is
      optimised again once the detection sets before and after it are in (`core.deferred_refinement`; on, inert
      offline and lossless where every frame has its own detections).
    - `motion_gate`: a pose that implies an impossible camera speed, or lies far off the track's prediction, is
      refused (`core.slam.motion_gate`): tracked again from the prediction, else the frame gets no pose.
    - `rotation_vote`: a motion-model prediction the projection search could not follow (a turn that starts or
      stops between two frames) is re-aimed by a vote over the image displacements of the last frame's points
      (`core.slam.rotation_vote`) and searched again before the reference-keyframe fallback.
    - `motion_max_jump_m`: a tracked pose whose camera centre lies farther than this from the constant-velocity
      prediction's (when a velocity is known) is refused as the motion gate refuses one, also with the gate off:
      tracked again from the prediction, else the frame gets no pose (0: off, the default). Such a pose took a
      shifted copy of a repeated wall pattern on the few matches left where a robot starts to drive or turn,
      0.4-1.2 m off; 0.15 (the vote's own `max_translation_m`) mends three of the four changing rooms whose camera
      failed that way. Off by default because where a mover has already bent the velocity the refusals end in a
      lost track and a relocalisation (results.md: one dynamic tuning seed 2.4 -> 47 cm, 82 more frames without a
      pose over 60 seeds).
    - `still_camera`: a camera that stood still keeps to the background its last pose explains (`still_camera`).
    - `level_from_floor`: a new map starts level on the floor in the first depth image (`core.map.floor_start`):
      z up, origin on the floor below the first camera; the optical frame where none shows. For a camera without a
      robot mounting; a given first pose (`SlamSystem.set_first_pose`) or a loaded map wins.
    """

    min_init_points: int = 300
    min_init_kept_points: int = 150
    radius_motion_px: float = 12.0
    radius_local_px: float = 7.0
    radius_reloc_px: float = 10.0
    min_motion_inliers: int = 20
    min_local_inliers: int = 30
    min_reloc_inliers: int = 50
    n_local_keyframes: int = 20
    keyframe_ratio: float = 0.75
    min_frames_between_keyframes: int = 0
    max_frames_between_keyframes: int = 30
    close_tracked_min: int = 100
    close_untracked_min: int = 70
    max_time_gap_s: float = 0.5
    velocity_rescale_tolerance: float = 0.25
    n_reloc_candidates: int = 6
    lost_frames_new_map: int = 30
    loaded_map_grace_s: float = 2.0
    initial_pose_timeout_s: float = 10.0
    level_from_floor: bool = False
    busy_mapping_weak_ratio: float = 0.25
    pose_iterations_per_round: int = 6
    motion_pose_rounds: int = 4
    object_keyframe_min_frames: int = 10
    deferred_refinement: RefinementConfig = field(default_factory=RefinementConfig)
    motion_gate: MotionGateConfig = field(default_factory=MotionGateConfig)
    rotation_vote: RotationVoteConfig = field(default_factory=RotationVoteConfig)
    motion_max_jump_m: float = 0.0
    still_camera: StillCameraConfig = field(default_factory=StillCameraConfig)

    def __post_init__(self) -> None:
        if self.pose_iterations_per_round < 1:
            raise ConfigError(f"tracking.pose_iterations_per_round: expected >= 1, got {self.pose_iterations_per_round}")
        if not self.motion_max_jump_m >= 0.0:
            raise ConfigError(f"tracking.motion_max_jump_m: expected >= 0 (0: off), got {self.motion_max_jump_m}")
        if self.motion_pose_rounds < 1:
            raise ConfigError(f"tracking.motion_pose_rounds: expected >= 1, got {self.motion_pose_rounds}")
